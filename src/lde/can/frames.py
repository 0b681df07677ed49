"""Columnar CAN frames: :class:`FrameBatch` (numpy arrays, one row per frame).

Log readers (:mod:`lde.io`) produce a ``FrameBatch``; the batch decoder (:mod:`lde.engine.receiver`)
consumes it. Timestamps are integer nanoseconds in the log's own time base (epoch seconds for
candump logs). Logs carry microsecond timestamps as float seconds; :func:`seconds_to_ns` converts
them by rounding to the microsecond, ``round(ts * 1e6) * 1000``, so that a timestamp written back
with 6 decimals is bit-identical to the one read.

Only the first 8 data bytes are stored (``data`` is ``uint8[n, 8]``, zero padded); a CAN FD frame
longer than 8 bytes keeps its ``dlc`` (its length in bytes, 0..64) so that decoders can reject a
length that does not match the message.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
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


@dataclass
class FrameBatch:
    """CAN frames as columns. All arrays have the same length ``n``.

    Attributes:
        t_ns: int64 [n], timestamps in ns in the log's time base.
        can_id: uint32 [n], arbitration id (11 or 29 bit).
        is_extended: bool [n], 29-bit identifier.
        dlc: uint8 [n], data length in bytes (0..64).
        data: uint8 [n, 8], first 8 data bytes, zero padded.
        is_rx: bool [n]; False for frames lde itself sent (recordings).
    """

    t_ns: np.ndarray
    can_id: np.ndarray
    is_extended: np.ndarray
    dlc: np.ndarray
    data: np.ndarray
    is_rx: np.ndarray

    def __post_init__(self) -> None:
        self.t_ns = np.ascontiguousarray(self.t_ns, dtype=np.int64).reshape(-1)
        n = self.t_ns.shape[0]
        self.can_id = np.ascontiguousarray(self.can_id, dtype=np.uint32).reshape(-1)
        self.is_extended = np.ascontiguousarray(self.is_extended, dtype=np.bool_).reshape(-1)
        self.dlc = np.ascontiguousarray(self.dlc, dtype=np.uint8).reshape(-1)
        self.data = np.ascontiguousarray(self.data, dtype=np.uint8).reshape(n, 8)
        self.is_rx = np.ascontiguousarray(self.is_rx, dtype=np.bool_).reshape(-1)
        for name in ("can_id", "is_extended", "dlc", "is_rx"):
            if getattr(self, name).shape[0] != n:
                raise ValueError(f"FrameBatch.{name} has length {getattr(self, name).shape[0]}, expected {n}")

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(cls) -> FrameBatch:
        """A batch with no frames."""
        return cls(
            t_ns=np.zeros(0, np.int64),
            can_id=np.zeros(0, np.uint32),
            is_extended=np.zeros(0, np.bool_),
            dlc=np.zeros(0, np.uint8),
            data=np.zeros((0, 8), np.uint8),
            is_rx=np.zeros(0, np.bool_),
        )

    @classmethod
    def from_messages(cls, messages: Iterable[can.Message], sort: bool = True) -> FrameBatch:
        """Columns from python-can messages.

        Error frames and remote frames carry no data and are skipped. ``timestamp`` (float s) is
        converted with :func:`seconds_to_ns`. The result is stably sorted by time unless
        ``sort=False``.
        """
        t: list[int] = []
        ids: list[int] = []
        ext: list[bool] = []
        dlc: list[int] = []
        rx: list[bool] = []
        payload = bytearray()
        for m in messages:
            if m.is_error_frame or m.is_remote_frame:
                continue
            raw = bytes(m.data or b"")
            t.append(seconds_to_ns(m.timestamp))
            ids.append(int(m.arbitration_id))
            ext.append(bool(m.is_extended_id))
            dlc.append(len(raw))
            rx.append(bool(m.is_rx))
            payload += raw[:8].ljust(8, b"\x00")
        n = len(t)
        batch = cls(
            t_ns=np.array(t, dtype=np.int64),
            can_id=np.array(ids, dtype=np.uint32),
            is_extended=np.array(ext, dtype=np.bool_),
            dlc=np.array(dlc, dtype=np.uint8),
            data=np.frombuffer(bytes(payload), dtype=np.uint8).reshape(n, 8).copy(),
            is_rx=np.array(rx, dtype=np.bool_),
        )
        return batch.sort() if sort else batch

    def to_messages(self, channel: str | int | None = None) -> list[can.Message]:
        """Rows -> python-can messages (timestamps in float seconds).

        A frame with ``dlc > 8`` becomes an FD message whose ``data`` holds only the stored first 8
        bytes (the rest was never kept); its ``dlc`` is kept.
        """
        import can

        out: list[can.Message] = []
        t_s = ns_to_seconds_array(self.t_ns)
        for i in range(len(self)):
            d = int(self.dlc[i])
            msg = can.Message(
                timestamp=float(t_s[i]),
                arbitration_id=int(self.can_id[i]),
                is_extended_id=bool(self.is_extended[i]),
                data=self.data[i, : min(d, 8)].tobytes(),
                is_rx=bool(self.is_rx[i]),
                is_fd=d > 8,
                channel=channel,
                check=False,
            )
            msg.dlc = d
            out.append(msg)
        return out

    @staticmethod
    def concat(batches: Sequence[FrameBatch], sort: bool = True) -> FrameBatch:
        """Concatenate batches (stably sorted by time unless ``sort=False``)."""
        if not batches:
            return FrameBatch.empty()
        out = FrameBatch(
            t_ns=np.concatenate([b.t_ns for b in batches]),
            can_id=np.concatenate([b.can_id for b in batches]),
            is_extended=np.concatenate([b.is_extended for b in batches]),
            dlc=np.concatenate([b.dlc for b in batches]),
            data=np.concatenate([b.data for b in batches], axis=0),
            is_rx=np.concatenate([b.is_rx for b in batches]),
        )
        return out.sort() if sort else out

    # ------------------------------------------------------------------ views
    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

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
