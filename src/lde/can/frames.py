"""Columnar CAN frames: :class:`FrameBatch` (numpy arrays, one row per frame).

Log readers (:mod:`lde.io`) produce a ``FrameBatch``; the batch decoder (:mod:`lde.engine.receiver`)
consumes it. Timestamps are integer nanoseconds in the log's own time base (epoch seconds for
candump logs). Logs carry microsecond timestamps as float seconds; :func:`seconds_to_ns` converts
them by rounding to the microsecond, ``round(ts * 1e6) * 1000``, so that a timestamp written back
with 6 decimals is bit-identical to the one read.

Data bytes: ``data`` is ``uint8[n, width]``, zero padded, with ``width`` at least 8 and at most 64
(CAN FD): 8 for a batch of classic frames, the longest frame's length otherwise, so that classic
logs take no more memory than before. ``dlc`` is each frame's length in bytes (0..64).

Channels: a log may hold several buses (candump's interface column, MCAP topics, python-can's
``Message.channel``). ``channel`` is a compact per-frame index into the batch's ``channels`` table of
names (``""``: a frame whose bus is not named, as in a log without an interface column).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # python-can is imported where messages are made: ~60 ms of every start-up
    import can

__all__ = [
    "FrameBatch",
    "seconds_to_ns",
    "seconds_to_ns_array",
    "ns_to_seconds",
    "ns_to_seconds_array",
    "pack_payloads",
    "merge_channels",
    "data_width",
    "MAX_DATA",
    "CLASSIC_DATA",
    "NO_CHANNELS",
]


def seconds_to_ns(ts: float) -> int:
    """Float seconds -> int nanoseconds, rounded to the microsecond: ``round(ts * 1e6) * 1000``."""
    return int(round(float(ts) * 1e6)) * 1000


def seconds_to_ns_array(ts: np.ndarray | Sequence[float]) -> np.ndarray:
    """Vectorised :func:`seconds_to_ns` -> int64 array (round half to even, like :func:`round`)."""
    a = np.asarray(ts, dtype=np.float64)
    return np.rint(a * 1e6).astype(np.int64) * 1000


def ns_to_seconds(t_ns: int) -> float:
    """Int nanoseconds -> float seconds (microsecond-exact for timestamps made by :func:`seconds_to_ns`)."""
    t = int(t_ns)
    # integer microseconds / 1e6 is the correctly rounded float of the decimal value with 6 digits
    return (t // 1000) / 1e6 + (t % 1000) * 1e-9


def ns_to_seconds_array(t_ns: np.ndarray) -> np.ndarray:
    """Vectorised :func:`ns_to_seconds` -> float64 array."""
    t = np.asarray(t_ns, dtype=np.int64)
    return (t // 1000) / 1e6 + (t % 1000) * 1e-9


#: the widest frame (CAN FD) and the width of a batch of classic frames [bytes]
MAX_DATA = 64
CLASSIC_DATA = 8
#: the channel table of a batch whose frames carry no bus name
NO_CHANNELS: tuple[str, ...] = ("",)


def data_width(longest: int) -> int:
    """The ``data`` width of a batch whose longest frame has ``longest`` bytes (8..64)."""
    return min(MAX_DATA, max(CLASSIC_DATA, int(longest)))


def merge_channels(tables: Sequence[tuple[str, ...]]) -> tuple[tuple[str, ...], list[np.ndarray | None]]:
    """One table for several batches' channel tables (names in order of first appearance) and, per
    table, the index map from its indices to the merged ones (None where it is unchanged)."""
    first = tables[0]
    if all(t == first for t in tables):
        return first, [None] * len(tables)
    names: dict[str, int] = {}
    for t in tables:
        for name in t:
            names.setdefault(name, len(names))
    merged = tuple(names)
    maps: list[np.ndarray | None] = []
    for t in tables:
        m = np.array([names[n] for n in t], np.uint16)
        maps.append(None if merged[: len(t)] == t else m)
    return merged, maps


@dataclass
class FrameBatch:
    """CAN frames as columns. All arrays have the same length ``n``.

    Attributes:
        t_ns: int64 [n], timestamps in ns in the log's time base.
        can_id: uint32 [n], arbitration id (11 or 29 bit).
        is_extended: bool [n], 29-bit identifier.
        dlc: uint8 [n], data length in bytes (0..64).
        data: uint8 [n, width], the data bytes, zero padded; ``width`` 8..64 (module doc).
        is_rx: bool [n]; False for frames lde itself sent (recordings).
        channel: uint16 [n], each frame's index into ``channels`` (not given: all 0).
        channels: the bus names (default ``("",)``: not named).
    """

    t_ns: np.ndarray
    can_id: np.ndarray
    is_extended: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    is_rx: np.ndarray
    channel: np.ndarray = field(default_factory=lambda: np.zeros(0, np.uint16))
    channels: tuple[str, ...] = NO_CHANNELS

    def __post_init__(self) -> None:
        self.t_ns = np.ascontiguousarray(self.t_ns, dtype=np.int64).reshape(-1)
        n = self.t_ns.shape[0]
        self.can_id = np.ascontiguousarray(self.can_id, dtype=np.uint32).reshape(-1)
        self.is_extended = np.ascontiguousarray(self.is_extended, dtype=np.bool_).reshape(-1)
        self.dlc = np.ascontiguousarray(self.dlc, dtype=np.uint8).reshape(-1)
        data = np.asarray(self.data, dtype=np.uint8)
        data = data.reshape(n, -1) if data.ndim != 2 or data.shape[0] != n else data
        if data.shape[1] < CLASSIC_DATA:
            data = np.pad(data, ((0, 0), (0, CLASSIC_DATA - data.shape[1])))
        if data.shape[1] > MAX_DATA:
            raise ValueError(f"FrameBatch.data is {data.shape[1]} bytes wide, at most {MAX_DATA}")
        self.data = np.ascontiguousarray(data)
        self.is_rx = np.ascontiguousarray(self.is_rx, dtype=np.bool_).reshape(-1)
        self.channel = np.ascontiguousarray(self.channel, dtype=np.uint16).reshape(-1)
        if self.channel.shape[0] == 0 and n:  # not given: every frame on the batch's first bus
            self.channel = np.zeros(n, np.uint16)
        self.channels = tuple(str(c) for c in self.channels) or NO_CHANNELS
        for name in ("can_id", "is_extended", "dlc", "is_rx", "channel"):
            if getattr(self, name).shape[0] != n:
                raise ValueError(f"FrameBatch.{name} has length {getattr(self, name).shape[0]}, expected {n}")
        if n and int(self.channel.max()) >= len(self.channels):
            raise ValueError(f"FrameBatch.channel indexes past its {len(self.channels)} channel names")

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(cls, width: int = CLASSIC_DATA) -> FrameBatch:
        """A batch with no frames."""
        return cls(
            t_ns=np.zeros(0, np.int64),
            can_id=np.zeros(0, np.uint32),
            is_extended=np.zeros(0, np.bool_),
            dlc=np.zeros(0, np.uint8),
            data=np.zeros((0, width), np.uint8),
            is_rx=np.zeros(0, np.bool_),
        )

    @classmethod
    def from_messages(cls, messages: Iterable[can.Message], sort: bool = True) -> FrameBatch:
        """Columns from python-can messages (CAN FD messages keep all their bytes; each message's
        ``channel`` becomes the frame's channel name, None: ``""``).

        Error frames and remote frames carry no data and are skipped. ``timestamp`` (float s) is
        converted with :func:`seconds_to_ns`. The result is stably sorted by time unless
        ``sort=False``.
        """
        t: list[int] = []
        ids: list[int] = []
        ext: list[bool] = []
        rx: list[bool] = []
        chan: list[int] = []
        names: dict[str, int] = {}
        payloads: list[bytes] = []
        for m in messages:
            if m.is_error_frame or m.is_remote_frame:
                continue
            raw = bytes(m.data or b"")[:MAX_DATA]
            t.append(seconds_to_ns(m.timestamp))
            ids.append(int(m.arbitration_id))
            ext.append(bool(m.is_extended_id))
            rx.append(bool(m.is_rx))
            name = "" if m.channel is None else str(m.channel)
            chan.append(names.setdefault(name, len(names)))
            payloads.append(raw)
        batch = cls(
            t_ns=np.array(t, dtype=np.int64),
            can_id=np.array(ids, dtype=np.uint32),
            is_extended=np.array(ext, dtype=np.bool_),
            dlc=np.array([len(p) for p in payloads], dtype=np.uint8),
            data=pack_payloads(payloads),
            is_rx=np.array(rx, dtype=np.bool_),
            channel=np.array(chan, dtype=np.uint16),
            channels=tuple(names) or NO_CHANNELS,
        )
        return batch.sort() if sort else batch

    def to_messages(self, channel: str | int | None = None) -> list[can.Message]:
        """Rows -> python-can messages (timestamps in float seconds). ``channel`` names every
        message's channel; None: each frame's own channel name (None where it is ``""``). A frame
        with ``dlc > 8`` becomes a CAN FD message."""
        import can

        out: list[can.Message] = []
        t_s = ns_to_seconds_array(self.t_ns)
        names = [n or None for n in self.channels]
        for i in range(len(self)):
            d = int(self.dlc[i])
            msg = can.Message(
                timestamp=float(t_s[i]),
                arbitration_id=int(self.can_id[i]),
                is_extended_id=bool(self.is_extended[i]),
                data=self.data[i, :d].tobytes(),
                is_rx=bool(self.is_rx[i]),
                is_fd=d > CLASSIC_DATA,
                channel=names[self.channel[i]] if channel is None else channel,
                check=False,
            )
            out.append(msg)
        return out

    @staticmethod
    def concat(batches: Sequence[FrameBatch], sort: bool = True) -> FrameBatch:
        """Concatenate batches (stably sorted by time unless ``sort=False``); the widest batch's
        width, the channel tables merged."""
        if not batches:
            return FrameBatch.empty()
        width = max(b.width for b in batches)
        full = [b for b in batches if len(b)] or [batches[0]]  # an empty batch's table names nothing
        names, maps = merge_channels([b.channels for b in full])
        chans = [b.channel if m is None else m[b.channel] for b, m in zip(full, maps, strict=True)]
        batches = full
        out = FrameBatch(
            t_ns=np.concatenate([b.t_ns for b in batches]),
            can_id=np.concatenate([b.can_id for b in batches]),
            is_extended=np.concatenate([b.is_extended for b in batches]),
            dlc=np.concatenate([b.dlc for b in batches]),
            data=np.concatenate([b.widened(width).data for b in batches], axis=0),
            is_rx=np.concatenate([b.is_rx for b in batches]),
            channel=np.concatenate(chans),
            channels=names,
        )
        return out.sort() if sort else out

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @property
    def width(self) -> int:
        """Bytes per row of ``data`` (8..64)."""
        return int(self.data.shape[1])

    def widened(self, width: int) -> FrameBatch:
        """This batch with ``data`` zero padded to ``width`` bytes (self when it is that wide)."""
        if width <= self.width:
            return self
        return FrameBatch(
            self.t_ns,
            self.can_id,
            self.is_extended,
            self.dlc,
            np.pad(self.data, ((0, 0), (0, width - self.width))),
            self.is_rx,
            self.channel,
            self.channels,
        )

    def channel_names(self) -> np.ndarray:
        """Each frame's channel name (object array)."""
        return np.array(self.channels, dtype=object)[self.channel]

    def is_sorted(self) -> bool:
        """True if ``t_ns`` is non-decreasing."""
        return bool(np.all(self.t_ns[1:] >= self.t_ns[:-1])) if len(self) > 1 else True

    def sort(self) -> FrameBatch:
        """Stably sorted by ``t_ns`` (frames with equal time keep their order); self if already sorted."""
        if self.is_sorted():
            return self
        order = np.argsort(self.t_ns, kind="stable")
        return self.take(order)

    def take(self, index: np.ndarray) -> FrameBatch:
        """Rows at integer ``index`` (in that order)."""
        return FrameBatch(
            t_ns=self.t_ns[index],
            can_id=self.can_id[index],
            is_extended=self.is_extended[index],
            dlc=self.dlc[index],
            data=self.data[index],
            is_rx=self.is_rx[index],
            channel=self.channel[index],
            channels=self.channels,
        )

    def rows(self, a: int, b: int) -> FrameBatch:
        """Rows ``a:b`` as views (no copy)."""
        return FrameBatch(
            self.t_ns[a:b],
            self.can_id[a:b],
            self.is_extended[a:b],
            self.dlc[a:b],
            self.data[a:b],
            self.is_rx[a:b],
            self.channel[a:b],
            self.channels,
        )

    def select(self, mask: np.ndarray) -> FrameBatch:
        """Rows where the boolean ``mask`` is True (order kept)."""
        m = np.asarray(mask, dtype=np.bool_)
        if m.shape != (len(self),):
            raise ValueError(f"FrameBatch.select: mask shape {m.shape}, expected ({len(self)},)")
        return self.take(np.flatnonzero(m))

    def __getitem__(self, key: slice | np.ndarray) -> FrameBatch:
        """``batch[a:b]``, ``batch[bool_mask]`` or ``batch[int_index]``."""
        if isinstance(key, slice):
            return self.take(np.arange(len(self))[key])
        k = np.asarray(key)
        if k.dtype == np.bool_:
            return self.select(k)
        return self.take(k)


def pack_payloads(payloads: Sequence[bytes]) -> np.ndarray:
    """Frame payloads (at most 64 bytes each) as the zero-padded ``uint8[n, width]`` of a batch."""
    n = len(payloads)
    width = data_width(max((len(p) for p in payloads), default=0))
    if width == CLASSIC_DATA:
        buf = b"".join(p.ljust(CLASSIC_DATA, b"\x00") for p in payloads)
        return np.frombuffer(buf, dtype=np.uint8).reshape(n, CLASSIC_DATA).copy()
    out = np.zeros((n, width), np.uint8)
    for i, p in enumerate(payloads):
        out[i, : len(p)] = np.frombuffer(p, np.uint8)
    return out
