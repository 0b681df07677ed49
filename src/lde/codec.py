"""Raw <-> physical conversion of DBC signals (the one place it lives) and frame encoding with
automatic counters and CRCs (the "packer" of opendbc).

Bit layout. A frame's 8 bytes are read as one little-endian 64-bit word ``w_le`` (bit ``k`` of the
frame = bit ``k % 8`` of byte ``k // 8``) for Intel signals, and as a big-endian word ``w_be`` for
Motorola signals (whose DBC start bit is the MSB)::

    Intel:    raw = (w_le >> start) & (2**length - 1)
    Motorola: raw = (w_be >> (msb_pos - length + 1)) & (2**length - 1),
              msb_pos = (7 - start // 8) * 8 + start % 8
    signed:   raw -= 2**length if raw >= 2**(length - 1)
    physical = raw * scale + offset

Encoding (:class:`MessageEncoder`, :func:`encode_batch`): values in DBC physical units; a value
outside the signal's DBC range ``[minimum, maximum]`` is **saturated** at the range (then at what the
bits can hold), rounding is to nearest (half to even); NaN raises :class:`EncodeError`. A signal not
given takes physical 0 (saturated into its range). Counter and CRC/checksum signals are filled in by
the encoder, never by the caller (passing one raises). Profile 1 counters run 0..14 and wrap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import can
import cantools
import numpy as np

from .e2e import IntegrityKind, IntegrityScheme, p01_crc_batch, protect_frame, whl_spd11_checksum_batch
from .errors import LdeError
from .frames import FrameBatch, ns_to_seconds
from .profiles import Profile

__all__ = [
    "EncodeError",
    "SignalCodec",
    "MessageCodec",
    "MessageEncoder",
    "encode_batch",
    "encode_frames",
    "decode_frame",
    "si_to_dbc",
    "words_le",
]


class EncodeError(LdeError, ValueError):
    """A frame cannot be encoded: NaN value, unknown signal, or a counter/CRC passed by the caller."""


def words_le(data: np.ndarray) -> np.ndarray:
    """uint8 [n, 8] frames -> uint64 [n] little-endian words (a view when ``data`` is C-contiguous)."""
    d = np.ascontiguousarray(data, dtype=np.uint8)
    return d.view("<u8").reshape(-1)


@dataclass(frozen=True)
class SignalCodec:
    """Bit position and scaling of one DBC signal, compiled from cantools."""

    name: str
    start: int  # DBC start bit (LSB for Intel, MSB for Motorola)
    length: int
    little_endian: bool
    signed: bool
    scale: float
    offset: float
    minimum: float | None
    maximum: float | None

    @classmethod
    def from_cantools(cls, sig: cantools.database.can.Signal) -> SignalCodec:
        if sig.is_float:
            raise LdeError(f"signal {sig.name}: IEEE float signals are not supported")
        return cls(
            name=sig.name,
            start=int(sig.start),
            length=int(sig.length),
            little_endian=sig.byte_order == "little_endian",
            signed=bool(sig.is_signed),
            scale=float(sig.scale),
            offset=float(sig.offset),
            minimum=None if sig.minimum is None else float(sig.minimum),
            maximum=None if sig.maximum is None else float(sig.maximum),
        )

    @property
    def shift(self) -> int:
        """LSB position in ``w_le`` (Intel) or ``w_be`` (Motorola)."""
        if self.little_endian:
            return self.start
        return (7 - self.start // 8) * 8 + self.start % 8 - self.length + 1

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    # ---------------------------------------------------------------- decode
    def raw_batch(self, w_le: np.ndarray, w_be: np.ndarray | None = None) -> np.ndarray:
        """Raw integer values (sign-extended) -> int64 [n]."""
        w = w_le if self.little_endian else (w_be if w_be is not None else w_le.byteswap())
        raw = ((w >> np.uint64(self.shift)) & np.uint64(self.mask)).astype(np.int64)
        if self.signed:
            raw -= (raw >> (self.length - 1)) << self.length  # subtract 2**length where the sign bit is set
        return raw

    def decode_batch(self, w_le: np.ndarray, w_be: np.ndarray | None = None) -> np.ndarray:
        """Physical values (DBC units) -> float64 [n]."""
        return self.raw_batch(w_le, w_be) * self.scale + self.offset

    # ---------------------------------------------------------------- encode
    def to_raw_batch(self, phys: np.ndarray) -> np.ndarray:
        """Physical -> raw int64, saturated at the DBC range and the bit range (module docstring)."""
        x = np.asarray(phys, dtype=np.float64)
        if np.isnan(x).any():
            raise EncodeError(f"signal {self.name}: NaN cannot be encoded")
        lo = -np.inf if self.minimum is None else self.minimum
        hi = np.inf if self.maximum is None else self.maximum
        if lo < hi:
            x = np.clip(x, lo, hi)
        raw = np.rint((x - self.offset) / self.scale)
        return np.clip(raw, self.raw_min, self.raw_max).astype(np.int64)

    def to_raw(self, phys: float) -> int:
        """Scalar :meth:`to_raw_batch` (same rounding and saturation)."""
        x = float(phys)
        if math.isnan(x):
            raise EncodeError(f"signal {self.name}: NaN cannot be encoded")
        if self.minimum is not None and self.maximum is not None and self.minimum < self.maximum:
            x = min(max(x, self.minimum), self.maximum)
        r = (x - self.offset) / self.scale
        if math.isinf(r):
            r = float(self.raw_max) if r > 0 else float(self.raw_min)
        return int(min(max(round(r), self.raw_min), self.raw_max))

    def place(self, raw: int) -> int:
        """Raw value -> its bits in ``w_le`` (Intel) or ``w_be`` (Motorola)."""
        return (int(raw) & self.mask) << self.shift

    def place_batch(self, raw: np.ndarray) -> np.ndarray:
        """Vectorised :meth:`place` -> uint64 [n]."""
        return (raw.astype(np.uint64) & np.uint64(self.mask)) << np.uint64(self.shift)


class MessageCodec:
    """Signal codecs of one message of a profile, split into value signals and integrity signals."""

    def __init__(self, profile: Profile, name: str) -> None:
        spec = profile.spec(name)  # ConfigError if unknown
        msg = profile.db.get_message_by_name(name)
        self.name = name
        self.frame_id = spec.frame_id
        self.length = spec.length
        self.scheme: IntegrityScheme = spec.scheme
        self.signals: dict[str, SignalCodec] = {s.name: SignalCodec.from_cantools(s) for s in msg.signals}
        integrity_fields = set(self.scheme.counter_fields) | set(self.scheme.checksum_fields)
        self.integrity: frozenset[str] = frozenset(
            n for n, s in self.signals.items() if s.little_endian and (s.start, s.length) in integrity_fields
        )
        self.values: tuple[str, ...] = tuple(n for n in self.signals if n not in self.integrity)

    def _check_names(self, names) -> None:
        bad = [n for n in names if n in self.integrity]
        if bad:
            raise EncodeError(f"{self.name}: {bad} are filled by the encoder (counter/CRC), do not pass them")
        unknown = [n for n in names if n not in self.signals]
        if unknown:
            raise EncodeError(f"{self.name}: unknown signals {unknown}; known: {list(self.values)}")

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        """All signals of one frame in DBC physical units (integrity signals as raw numbers)."""
        w = words_le(np.frombuffer(bytes(data)[:8].ljust(8, b"\x00"), dtype=np.uint8).reshape(1, 8))
        return {n: float(s.decode_batch(w)[0]) for n, s in self.signals.items()}


class MessageEncoder:
    """Encodes one message of a profile with automatic counter and CRC/checksum (live sending, tests).

    >>> enc = MessageEncoder(load_profile("lde"), "LDE_Overlay")        # doctest: +SKIP
    >>> enc.encode({"OverlayTorque": 1.25, "Active": 1, "State": 2})    # doctest: +SKIP
    """

    def __init__(self, profile: Profile, name: str, counter_start: int = 0) -> None:
        self.codec = MessageCodec(profile, name)
        sch = self.codec.scheme
        if not 0 <= counter_start < sch.modulus or counter_start == sch.invalid_counter:
            raise EncodeError(f"{name}: counter_start {counter_start} outside 0..{sch.modulus - 1}")
        self.counter = int(counter_start)
        self._zero_raw = {n: self.codec.signals[n].to_raw(0.0) for n in self.codec.values}

    @property
    def frame_id(self) -> int:
        return self.codec.frame_id

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Physical values (DBC units) -> frame bytes (message length), counter advanced by one."""
        c = self.codec
        c._check_names(values)
        w_le = 0
        w_be = 0
        for n in c.values:
            s = c.signals[n]
            raw = s.to_raw(values[n]) if n in values else self._zero_raw[n]
            if s.little_endian:
                w_le |= s.place(raw)
            else:
                w_be |= s.place(raw)
        word = w_le | int.from_bytes(w_be.to_bytes(8, "big"), "little")
        buf = bytearray(word.to_bytes(8, "little")[: c.length])
        protect_frame(c.scheme, c.frame_id, buf, self.counter)
        self.counter = (self.counter + 1) % c.scheme.modulus
        if self.counter == c.scheme.invalid_counter:
            self.counter = (self.counter + 1) % c.scheme.modulus
        return bytes(buf)

    def message(self, values: Mapping[str, float], t_ns: int, channel: str | None = None) -> can.Message:
        """Encoded python-can message with timestamp ``t_ns`` (float seconds)."""
        return can.Message(
            timestamp=ns_to_seconds(t_ns),
            arbitration_id=self.codec.frame_id,
            is_extended_id=False,
            data=self.encode(values),
            channel=channel,
        )


def encode_batch(
    profile: Profile, name: str, columns: Mapping[str, np.ndarray], counter_start: int = 0
) -> np.ndarray:
    """Vectorised encoding of ``n`` frames of message ``name`` -> uint8 [n, 8] (zero padded past its length).

    ``columns`` maps signal names to arrays of ``n`` physical values (scalars broadcast). Counters run
    ``counter_start, counter_start + 1, ...`` modulo the scheme's period (so the next batch continues at
    ``(counter_start + n) % modulus``); CRCs / checksums are computed per frame.
    """
    c = MessageCodec(profile, name)
    c._check_names(columns)
    n = 0
    for v in columns.values():
        n = max(n, np.size(v))
    if n == 0:
        return np.zeros((0, 8), dtype=np.uint8)
    sch = c.scheme
    if not 0 <= counter_start < sch.modulus or counter_start == sch.invalid_counter:
        raise EncodeError(f"{name}: counter_start {counter_start} outside 0..{sch.modulus - 1}")
    w_le = np.zeros(n, dtype=np.uint64)
    w_be = np.zeros(n, dtype=np.uint64)
    for sname in c.values:
        s = c.signals[sname]
        col = columns.get(sname, 0.0)
        raw = s.to_raw_batch(np.broadcast_to(np.asarray(col, dtype=np.float64), (n,)))
        if s.little_endian:
            w_le |= s.place_batch(raw)
        else:
            w_be |= s.place_batch(raw)
    w_le |= w_be.byteswap()
    counters = (counter_start + np.arange(n, dtype=np.int64)) % sch.modulus
    for start, length in sch.counter_fields:
        w_le |= (counters.astype(np.uint64) & np.uint64((1 << length) - 1)) << np.uint64(start)
        counters = counters >> length
    data = w_le.view(np.uint8).reshape(n, 8).copy()
    if c.length < 8:
        data[:, c.length :] = 0
    if sch.kind is IntegrityKind.P01:
        data[:, 0] = p01_crc_batch(c.frame_id, data, c.length)
    elif sch.kind is IntegrityKind.HYUNDAI_WHL_SPD:
        chk = whl_spd11_checksum_batch(data).astype(np.uint64)
        w = words_le(data)
        for start, length in sch.checksum_fields:
            w |= (chk & np.uint64((1 << length) - 1)) << np.uint64(start)
            chk = chk >> np.uint64(length)
        data = w.view(np.uint8).reshape(n, 8)
    return data


def encode_frames(
    profile: Profile,
    name: str,
    t_ns: np.ndarray,
    columns: Mapping[str, np.ndarray],
    counter_start: int = 0,
) -> FrameBatch:
    """:func:`encode_batch` as a :class:`FrameBatch` at times ``t_ns`` (11-bit id, dlc = message length)."""
    t = np.asarray(t_ns, dtype=np.int64).reshape(-1)
    n = t.shape[0]
    cols = {k: np.broadcast_to(np.asarray(v, dtype=np.float64), (n,)) for k, v in columns.items()}
    if not cols:  # all signals at their default (physical 0)
        cols = {MessageCodec(profile, name).values[0]: np.zeros(n)}
    data = encode_batch(profile, name, cols, counter_start) if n else np.zeros((0, 8), dtype=np.uint8)
    spec = profile.spec(name)
    return FrameBatch(
        t_ns=t,
        can_id=np.full(n, spec.frame_id, dtype=np.uint32),
        is_extended=np.zeros(n, dtype=np.bool_),
        dlc=np.full(n, spec.length, dtype=np.uint8),
        data=data,
        is_rx=np.ones(n, dtype=np.bool_),
    )


def decode_frame(profile: Profile, name: str, data: bytes | bytearray) -> dict[str, float]:
    """All signals of one frame of message ``name`` in DBC physical units (no integrity check)."""
    return MessageCodec(profile, name).decode(data)


def si_to_dbc(
    profile: Profile, message: str, si: Mapping[str, float | np.ndarray]
) -> dict[str, float | np.ndarray]:
    """Estimator inputs in SI -> the signals of input message ``message`` in DBC units.

    ``si`` maps input names (``column_torque``, ``speed``, ...) fed by ``message`` to SI values or arrays;
    an input derived from several signals (the mean of four wheel speeds) gives each of them the value.
    Inputs of other messages raise :class:`EncodeError`. Use with :func:`encode_batch` /
    :class:`MessageEncoder` so unit conversions live only in the profile.
    """
    spec = profile.spec(message)
    out: dict[str, float | np.ndarray] = {}
    for name, value in si.items():
        if name not in spec.inputs:
            raise EncodeError(f"input {name!r} is not carried by {message} (it carries {list(spec.inputs)})")
        im = profile.inputs[name]
        v = im.to_dbc(value)
        for sig in im.signals:
            out[sig] = v
    return out
