"""Frames seen on a bench, decoded by DBC name.

:class:`Capture` listens on its own bench bus and keeps every frame (time, id, bytes). Asking for a
message by name gives a :class:`FrameList`: columns decoded at once by lde's codec (the one raw <->
physical conversion of :mod:`lde.can.codec`), with the E2E verdicts and counters; indexing it gives
single :class:`Frame` objects.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import overload

import can
import numpy as np

from lde.can.codec import MessageCodec
from lde.can.e2e import check_batch, read_counter_batch
from lde.can.frames import pack_payloads, seconds_to_ns
from lde.can.profiles import MessageSpec, Profile
from lde.errors import ConfigError

__all__ = ["Frame", "FrameList", "Capture"]


@dataclass(frozen=True)
class Frame:
    """One frame: ``frame["OverlayTorque"]`` is a signal in DBC physical units.

    Attributes:
        name: the DBC message name (None for an id the profile does not know).
        can_id: the arbitration id.
        t_ns: the bench time at which it was on the bus [ns].
        data: the payload.
        signals: every signal of the message in DBC units (counter and CRC as raw numbers).
        e2e_ok: the CRC / checksum is right (True where the message's scheme verifies none).
    """

    name: str | None
    can_id: int
    t_ns: int
    data: bytes
    signals: Mapping[str, float]
    e2e_ok: bool

    def __getitem__(self, signal: str) -> float:
        try:
            return self.signals[signal]
        except KeyError:
            raise KeyError(
                f"{self.name or hex(self.can_id)} has no signal {signal!r}; it has {list(self.signals)}"
            ) from None


class FrameList(Sequence[Frame]):
    """The frames of one message, oldest first, with their columns (numpy) decoded at once.

    Args:
        name: the DBC message name (None: an id the profile does not know).
        can_id: the arbitration id.
        spec: the profile's message spec (None: no decoding, no E2E check).
        codec: lde's codec of the message (None with ``spec``).
        t_ns: int64 [n] bench times.
        data: uint8 [n, 8] payloads, zero padded.
        dlc: uint8 [n] lengths.
    """

    def __init__(
        self,
        name: str | None,
        can_id: int,
        spec: MessageSpec | None,
        codec: MessageCodec | None,
        t_ns: np.ndarray,
        data: np.ndarray,
        dlc: np.ndarray,
    ) -> None:
        self.name = name
        self.can_id = can_id
        self.spec = spec
        self.codec = codec
        self.t_ns = t_ns
        self.data = data
        self.dlc = dlc

    @property
    def label(self) -> str:
        return self.name or f"0x{self.can_id:X}"

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    @overload
    def __getitem__(self, i: int) -> Frame: ...
    @overload
    def __getitem__(self, i: slice) -> FrameList: ...
    def __getitem__(self, i: int | slice) -> Frame | FrameList:
        if isinstance(i, slice):
            return self._take(np.arange(len(self))[i])
        k = range(len(self))[i]  # IndexError like a list
        payload = bytes(self.data[k, : int(self.dlc[k])])
        signals = {s: float(v[k]) for s, v in self._columns.items()}
        return Frame(self.name, self.can_id, int(self.t_ns[k]), payload, signals, bool(self.e2e_ok[k]))

    def __iter__(self) -> Iterator[Frame]:
        for k in range(len(self)):
            yield self[k]

    def __repr__(self) -> str:
        return f"<FrameList {self.label}: {len(self)} frames>"

    def _take(self, idx: np.ndarray) -> FrameList:
        return FrameList(
            self.name, self.can_id, self.spec, self.codec, self.t_ns[idx], self.data[idx], self.dlc[idx]
        )

    def since(self, t_ns: int) -> FrameList:
        """The frames at or after bench time ``t_ns``."""
        return self._take(np.flatnonzero(self.t_ns >= int(t_ns)))

    @property
    def t(self) -> np.ndarray:
        """Bench times [s] (float; :attr:`t_ns` is exact)."""
        return self.t_ns / 1e9

    @cached_property
    def _columns(self) -> dict[str, np.ndarray]:
        if self.codec is None:
            return {}
        d = np.ascontiguousarray(self.data, dtype=np.uint8)
        return {n: s.decode_batch(d) for n, s in self.codec.signals.items()}

    def signal(self, name: str) -> np.ndarray:
        """One signal of every frame [DBC physical units] as a float array."""
        cols = self._columns
        if name not in cols:
            raise ConfigError(f"{self.label} has no signal {name!r}; it has {list(cols)}")
        return cols[name]

    @cached_property
    def e2e_ok(self) -> np.ndarray:
        """bool [n]: the CRC / checksum of each frame is right (all True where nothing is verified)."""
        if self.spec is None or len(self) == 0:
            return np.ones(len(self), np.bool_)
        ok = check_batch(self.spec.scheme, self.spec.frame_id, self.data, self.spec.length)
        return ok & (self.dlc == self.spec.length)

    @cached_property
    def counters(self) -> np.ndarray:
        """int64 [n]: the E2E / alive counter of each frame (empty without a spec)."""
        if self.spec is None or len(self) == 0:
            return np.zeros(0, np.int64)
        return np.asarray(read_counter_batch(self.spec.scheme, self.data), np.int64)


class Capture:
    """Every frame on the bench's bus, from its own bench bus; decoded by the profile's DBC names."""

    def __init__(self, bus: can.BusABC, profile: Profile) -> None:
        self.bus = bus
        self.profile = profile
        self._t: dict[int, list[int]] = {}
        self._data: dict[int, list[bytes]] = {}
        self._codecs: dict[str, MessageCodec] = {}
        self.count = 0

    def drain(self) -> int:
        """Take the frames that have arrived; returns how many."""
        n = 0
        for msg in self.bus:
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            i = msg.arbitration_id
            if i not in self._t:
                self._t[i] = []
                self._data[i] = []
            self._t[i].append(seconds_to_ns(msg.timestamp))
            self._data[i].append(bytes(msg.data))
            n += 1
        self.count += n
        return n

    def resolve(self, message: str | int) -> tuple[str | None, int, MessageSpec | None]:
        """(name, id, spec) of a DBC message name or a CAN id."""
        if isinstance(message, str):
            spec = self.profile.spec(message)  # ConfigError names the known messages
            return message, spec.frame_id, spec
        for spec in (*self.profile.messages.values(), *self.profile.outputs.values()):
            if spec.frame_id == int(message):
                return spec.name, spec.frame_id, spec
        return None, int(message), None

    def count_of(self, can_id: int) -> int:
        return len(self._t.get(can_id, ()))

    def frames(self, message: str | int, start: int = 0) -> FrameList:
        """The frames of ``message`` (DBC name or CAN id) captured so far, from the ``start``-th on."""
        self.drain()
        can_id = self.resolve(message)[1]
        return self._list(can_id, self._t.get(can_id, [])[start:], self._data.get(can_id, [])[start:])

    def decode(self, msg: can.Message) -> Frame:
        """One frame, decoded (it is not kept)."""
        fl = self._list(msg.arbitration_id, [seconds_to_ns(msg.timestamp)], [bytes(msg.data)])
        return fl[0]

    def _list(self, can_id: int, ts: list[int], raw: list[bytes]) -> FrameList:
        name, can_id, spec = self.resolve(can_id)
        data = pack_payloads(raw)
        dlc = np.array([len(b) for b in raw], np.uint8)
        codec = None
        if spec is not None and name is not None:
            codec = self._codecs.get(name)
            if codec is None:
                codec = self._codecs[name] = MessageCodec(self.profile, name)
        return FrameList(name, can_id, spec, codec, np.asarray(ts, np.int64), data, dlc)

    def summary(self) -> str:
        """``name: count`` of every id seen (for error messages)."""
        self.drain()
        parts = []
        for i in sorted(self._t):
            name, _, _ = self.resolve(i)
            parts.append(f"{name or hex(i)}: {len(self._t[i])}")
        return ", ".join(parts) or "no frames"
