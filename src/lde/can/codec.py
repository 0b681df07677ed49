"""Raw <-> physical conversion of DBC signals (the one place it lives) and frame encoding with
automatic counters and CRCs (the "packer" of opendbc).

Bit layout (:mod:`lde.can.bitfield`, the one packer): a signal is a field of the frame's bytes (up
to 64 for CAN FD) at its packer position ``pos`` (Intel: the DBC start bit; Motorola: the MSB-first
index of its LSB)::

    raw       = bits of the field (bitfield.get_bits)
    signed:   raw -= 2**length if raw >= 2**(length - 1)
    physical  = raw * scale + offset

Encoding (:class:`MessageEncoder`, :func:`encode_batch`, and the engine's output frames, all through
the compiled :func:`encode_row`): values in DBC physical units; a value outside the signal's DBC
range ``[minimum, maximum]`` is **saturated** at the range (then at what the bits can hold),
rounding is to nearest (half to even); NaN raises :class:`EncodeError` (the compiled kernels are
only given finite values). A signal not given takes physical 0 (saturated into its range). Counter
and CRC/checksum signals are filled in by the encoder, never by the caller (passing one raises).
Profile 1 counters run 0..14 and wrap.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import TYPE_CHECKING

import numpy as np
from numba import njit

from lde.can.bitfield import field_pos, get_bits, put_bits
from lde.can.e2e import IntegrityScheme, protect_row
from lde.can.frames import FrameBatch, data_width, ns_to_seconds
from lde.can.profiles import Profile, SignalDef
from lde.errors import LdeError

if TYPE_CHECKING:  # python-can (~35-110 ms to import) only where can.Message objects are made
    import can
    import cantools

__all__ = [
    "EncodeError",
    "SignalCodec",
    "MessageLayout",
    "MessageCodec",
    "MessageEncoder",
    "encode_batch",
    "encode_frames",
    "encode_row",
    "encode_word",
    "decode_frame",
    "si_to_dbc",
]


class EncodeError(LdeError, ValueError):
    """A frame cannot be encoded: NaN value, unknown signal, or a counter/CRC passed by the caller."""


# ------------------------------------------------------------------------- compiled conversions


@njit(cache=True, inline="always")
def raw_value(data, pos, nbits, little_endian, signed):  # pragma: no cover - compiled
    """Raw integer value of one signal (sign-extended) of the frame bytes ``data``."""
    raw = np.int64(get_bits(data, pos, nbits, little_endian))
    if signed and nbits < 64 and (raw >> (nbits - 1)) & 1:
        raw -= np.int64(1) << nbits
    return raw


@njit(cache=True, inline="always")
def phys_to_raw(x, lo, hi, scale, offset, nbits, signed):  # pragma: no cover - compiled
    """Physical (finite) -> raw int64, saturated at the DBC range [lo, hi] (ignored unless lo < hi)
    and then at the bit range; rounding half to even."""
    if lo < hi:
        x = min(max(x, lo), hi)
    if signed:
        rmin = -(np.int64(1) << (nbits - 1))
        rmax = (np.int64(1) << (nbits - 1)) - 1
    else:
        rmin = np.int64(0)
        rmax = (np.int64(1) << nbits) - 1 if nbits < 63 else np.int64(9223372036854775807)
    r = (x - offset) / scale
    if r >= rmax:
        return rmax
    if r <= rmin:
        return rmin
    return np.int64(np.rint(r))


@njit(cache=True, inline="always")
def encode_row(
    values,
    pos,
    nbits,
    little_endian,
    signed,
    scale,
    offset,
    lo,
    hi,
    is_value,
    length,
    kind,
    frame_id,
    ctr_parts,
    chk_parts,
    counter,
    out,
):  # pragma: no cover
    """The frame bytes of one message into ``out`` (uint8 row, zeroed first): every value signal
    from ``values`` (physical, finite; one entry per signal of the layout, integrity signals
    ignored), then the counter and CRC / checksum (:func:`lde.can.e2e.protect_row`)."""
    for k in range(out.shape[0]):
        out[k] = 0
    for k in range(pos.shape[0]):
        if not is_value[k]:
            continue
        raw = phys_to_raw(values[k], lo[k], hi[k], scale[k], offset[k], nbits[k], signed[k])
        put_bits(out, pos[k], nbits[k], little_endian[k], np.uint64(raw))
    protect_row(kind, frame_id, out, length, ctr_parts, chk_parts, counter)


@njit(cache=True, inline="always")
def encode_word(
    values,
    pos,
    nbits,
    little_endian,
    signed,
    scale,
    offset,
    lo,
    hi,
    is_value,
    length,
    kind,
    frame_id,
    ctr_parts,
    chk_parts,
    counter,
):  # pragma: no cover
    """:func:`encode_row` of a message of at most 8 bytes, as its little-endian 64-bit word."""
    row = np.zeros(8, np.uint8)
    encode_row(
        values, pos, nbits, little_endian, signed, scale, offset, lo, hi, is_value, length, kind,
        frame_id, ctr_parts, chk_parts, counter, row,
    )  # fmt: skip
    w = np.uint64(0)
    for k in range(8):
        w |= np.uint64(row[k]) << np.uint64(8 * k)
    return w


@njit(cache=True)
def _encode_rows(
    values,
    pos,
    nbits,
    little_endian,
    signed,
    scale,
    offset,
    lo,
    hi,
    is_value,
    length,
    kind,
    frame_id,
    ctr_parts,
    chk_parts,
    counter,
    modulus,
    invalid,
    has_counter,
    out,
):  # pragma: no cover
    c = counter
    for i in range(values.shape[0]):
        encode_row(
            values[i], pos, nbits, little_endian, signed, scale, offset, lo, hi, is_value, length,
            kind, frame_id, ctr_parts, chk_parts, c, out[i],
        )  # fmt: skip
        if has_counter:
            c = (c + 1) % modulus
            if c == invalid:
                c = (c + 1) % modulus
    return c


@njit(cache=True)
def _raw_rows(data, pos, nbits, little_endian, signed, out):  # pragma: no cover - compiled
    for i in range(data.shape[0]):
        out[i] = raw_value(data[i], pos, nbits, little_endian, signed)


# ------------------------------------------------------------------------------- signals


@dataclass(frozen=True)
class SignalCodec(SignalDef):
    """Bit position and scaling of one DBC signal (the profile's :class:`lde.can.profiles.SignalDef`,
    integer signals only) with the packer position the compiled codec uses."""

    @classmethod
    def of(cls, sig: SignalDef) -> SignalCodec:
        if sig.is_float:
            raise LdeError(f"signal {sig.name}: IEEE float signals are not supported")
        return cls(**{f.name: getattr(sig, f.name) for f in fields(SignalDef)})

    @classmethod
    def from_cantools(cls, sig: cantools.database.can.Signal) -> SignalCodec:
        return cls.of(SignalDef.from_cantools(sig))

    @property
    def pos(self) -> int:
        """The packer's position (:func:`lde.can.bitfield.field_pos`)."""
        return field_pos(self.start, self.length, self.little_endian)

    @property
    def mask(self) -> int:
        return (1 << self.length) - 1

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    @property
    def range(self) -> tuple[float, float]:
        """(lo, hi) of the DBC range; (inf, -inf) (no clipping) when it is not given or empty."""
        if self.minimum is None or self.maximum is None or not self.minimum < self.maximum:
            return math.inf, -math.inf
        return self.minimum, self.maximum

    # ---------------------------------------------------------------- decode
    def raw_batch(self, data: np.ndarray) -> np.ndarray:
        """Raw integer values (sign-extended) of frames ``data`` (uint8 [n, width]) -> int64 [n]."""
        d = np.ascontiguousarray(data, dtype=np.uint8)
        out = np.empty(d.shape[0], dtype=np.int64)
        _raw_rows(d, self.pos, self.length, self.little_endian, self.signed, out)
        return out

    def decode_batch(self, data: np.ndarray) -> np.ndarray:
        """Physical values (DBC units) of frames ``data`` -> float64 [n]."""
        raw = self.raw_batch(data)
        if not self.signed and self.length == 64:  # past 2**63: the unsigned value, not its int64
            return raw.view(np.uint64) * self.scale + self.offset
        return raw * self.scale + self.offset

    # ---------------------------------------------------------------- encode
    def to_raw(self, phys: float) -> int:
        """Physical -> raw, saturated at the DBC range and the bit range (module docstring)."""
        x = float(phys)
        if math.isnan(x):
            raise EncodeError(f"signal {self.name}: NaN cannot be encoded")
        lo, hi = self.range
        return int(phys_to_raw(x, lo, hi, self.scale, self.offset, self.length, self.signed))

    def to_raw_batch(self, phys: np.ndarray) -> np.ndarray:
        """:meth:`to_raw` of every element -> int64."""
        x = np.asarray(phys, dtype=np.float64)
        if np.isnan(x).any():
            raise EncodeError(f"signal {self.name}: NaN cannot be encoded")
        lo, hi = self.range
        return np.array(
            [phys_to_raw(v, lo, hi, self.scale, self.offset, self.length, self.signed) for v in x.ravel()],
            dtype=np.int64,
        ).reshape(x.shape)


# ------------------------------------------------------------------------------- messages


@dataclass(frozen=True, eq=False)
class MessageLayout:
    """One message as the arrays the compiled encoder and decoder read (one row per DBC signal)."""

    frame_id: int
    length: int
    scheme: IntegrityScheme
    pos: np.ndarray  # int64, the packer positions (lde.can.bitfield)
    nbits: np.ndarray  # int64
    little_endian: np.ndarray  # bool
    signed: np.ndarray  # bool
    scale: np.ndarray  # float64
    offset: np.ndarray  # float64
    lo: np.ndarray  # float64, DBC minimum (inf where there is no range)
    hi: np.ndarray  # float64, DBC maximum (-inf where there is no range)
    is_value: np.ndarray  # bool, False for the counter / CRC signals

    @classmethod
    def of(
        cls,
        frame_id: int,
        length: int,
        scheme: IntegrityScheme,
        codecs: list[SignalCodec],
        integrity: frozenset[str],
    ) -> MessageLayout:
        rng = [c.range for c in codecs]
        return cls(
            frame_id=int(frame_id),
            length=int(length),
            scheme=scheme,
            pos=np.array([c.pos for c in codecs], np.int64),
            nbits=np.array([c.length for c in codecs], np.int64),
            little_endian=np.array([c.little_endian for c in codecs], np.bool_),
            signed=np.array([c.signed for c in codecs], np.bool_),
            scale=np.array([c.scale for c in codecs], np.float64),
            offset=np.array([c.offset for c in codecs], np.float64),
            lo=np.array([r[0] for r in rng], np.float64),
            hi=np.array([r[1] for r in rng], np.float64),
            is_value=np.array([c.name not in integrity for c in codecs], np.bool_),
        )

    def kernel_args(self) -> tuple:
        """The encoder's layout arguments, in :func:`encode_row`'s order after ``values``."""
        s = self.scheme
        return (
            self.pos,
            self.nbits,
            self.little_endian,
            self.signed,
            self.scale,
            self.offset,
            self.lo,
            self.hi,
            self.is_value,
            self.length,
            s.kind_code,
            self.frame_id,
            s.counter_parts,
            s.checksum_parts,
        )

    def encode(self, values: np.ndarray, counter: int) -> bytes:
        """Frame bytes (``length``) of one row of physical values (one per signal, finite)."""
        out = np.zeros(data_width(self.length), np.uint8)
        encode_row(np.ascontiguousarray(values, np.float64), *self.kernel_args(), int(counter), out)  # type: ignore[call-arg]
        return out[: self.length].tobytes()


class MessageCodec:
    """Signal codecs of one message of a profile, split into value signals and integrity signals."""

    def __init__(self, profile: Profile, name: str) -> None:
        spec = profile.spec(name)  # ConfigError if unknown
        self.name = name
        self.frame_id = spec.frame_id
        self.length = spec.length
        self.scheme: IntegrityScheme = spec.scheme
        self.signals: dict[str, SignalCodec] = {s.name: SignalCodec.of(s) for s in profile.signals[name]}
        integrity_fields = set(self.scheme.counter_fields) | set(self.scheme.checksum_fields)
        self.integrity: frozenset[str] = frozenset(
            n for n, s in self.signals.items() if (s.start, s.length, s.little_endian) in integrity_fields
        )
        self.values: tuple[str, ...] = tuple(n for n in self.signals if n not in self.integrity)
        self.order: tuple[str, ...] = tuple(self.signals)  # the layout's row order
        self.index: dict[str, int] = {n: k for k, n in enumerate(self.order)}
        self.layout = MessageLayout.of(
            self.frame_id, self.length, self.scheme, list(self.signals.values()), self.integrity
        )

    def _check_names(self, names) -> None:
        bad = [n for n in names if n in self.integrity]
        if bad:
            raise EncodeError(f"{self.name}: {bad} are filled by the encoder (counter/CRC), do not pass them")
        unknown = [n for n in names if n not in self.signals]
        if unknown:
            raise EncodeError(f"{self.name}: unknown signals {unknown}; known: {list(self.values)}")

    def value_row(self, values: Mapping[str, float]) -> np.ndarray:
        """Physical values (a signal not given: 0) as the layout's row; NaN raises."""
        self._check_names(values)
        row = np.zeros(len(self.order), np.float64)
        for n, v in values.items():
            x = float(v)
            if math.isnan(x):
                raise EncodeError(f"signal {n}: NaN cannot be encoded")
            row[self.index[n]] = x
        return row

    def decode(self, data: bytes | bytearray) -> dict[str, float]:
        """All signals of one frame in DBC physical units (integrity signals as raw numbers)."""
        raw = bytes(data)[: data_width(self.length)]
        row = np.frombuffer(raw.ljust(data_width(self.length), b"\x00"), dtype=np.uint8).reshape(1, -1)
        return {n: float(s.decode_batch(row)[0]) for n, s in self.signals.items()}


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

    @property
    def frame_id(self) -> int:
        return self.codec.frame_id

    def encode(self, values: Mapping[str, float]) -> bytes:
        """Physical values (DBC units) -> frame bytes (message length), counter advanced by one."""
        c = self.codec
        data = c.layout.encode(c.value_row(values), self.counter)
        self.counter = c.scheme.next_counter(self.counter)
        return data

    def message(self, values: Mapping[str, float], t_ns: int, channel: str | None = None) -> can.Message:
        """Encoded python-can message with timestamp ``t_ns`` (float seconds)."""
        import can

        return can.Message(
            timestamp=ns_to_seconds(t_ns),
            arbitration_id=self.codec.frame_id,
            is_extended_id=False,
            data=self.encode(values),
            is_fd=self.codec.length > 8,
            channel=channel,
        )


def encode_batch(
    profile: Profile, name: str, columns: Mapping[str, np.ndarray], counter_start: int = 0
) -> np.ndarray:
    """Encoding of ``n`` frames of message ``name`` -> uint8 [n, width] (zero padded past its length;
    width 8, or the message's length for a CAN FD message).

    ``columns`` maps signal names to arrays of ``n`` physical values (scalars broadcast). Counters run
    ``counter_start, counter_start + 1, ...`` modulo the scheme's period (so the next batch continues at
    ``(counter_start + n) % modulus``); CRCs / checksums are computed per frame.
    """
    c = MessageCodec(profile, name)
    c._check_names(columns)
    n = 0
    for v in columns.values():
        n = max(n, np.size(v))
    width = data_width(c.length)
    if n == 0:
        return np.zeros((0, width), dtype=np.uint8)
    sch = c.scheme
    if not 0 <= counter_start < sch.modulus or counter_start == sch.invalid_counter:
        raise EncodeError(f"{name}: counter_start {counter_start} outside 0..{sch.modulus - 1}")
    values = np.zeros((n, len(c.order)), np.float64)
    for sname, col in columns.items():
        v = np.broadcast_to(np.asarray(col, dtype=np.float64), (n,))
        if np.isnan(v).any():
            raise EncodeError(f"signal {sname}: NaN cannot be encoded")
        values[:, c.index[sname]] = v
    out = np.zeros((n, width), np.uint8)
    _encode_rows(
        values,
        *c.layout.kernel_args(),
        int(counter_start),
        sch.modulus,
        sch.invalid_counter,
        sch.has_counter,
        out,
    )  # type: ignore[call-arg]
    return out


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
    spec = profile.spec(name)
    data = encode_batch(profile, name, cols, counter_start) if n else np.zeros((0, 8), dtype=np.uint8)
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
    an input that is the mean of several signals (four wheel speeds) gives each of them the value; one
    that is their sum (a coarse angle plus its fraction) gives each signal but the last the value
    rounded to its resolution and saturated at its range, the last what remains. Inputs of other
    messages raise :class:`EncodeError`. Use with :func:`encode_batch` / :class:`MessageEncoder` so
    unit conversions live only in the profile.
    """
    spec = profile.spec(message)
    sigs = {s.name: s for s in profile.signals[message]}
    out: dict[str, float | np.ndarray] = {}
    for name, value in si.items():
        if name not in spec.inputs:
            raise EncodeError(f"input {name!r} is not carried by {message} (it carries {list(spec.inputs)})")
        im = profile.inputs[name]
        v = im.to_dbc(value)
        if im.combine == "mean" or len(im.signals) == 1:
            for sig in im.signals:
                out[sig] = v
            continue
        rest = np.asarray(v, dtype=np.float64)
        for sig in im.signals[:-1]:
            sc = SignalCodec.of(sigs[sig])
            lo, hi = sc.range
            q = np.rint((rest - sc.offset) / sc.scale) * sc.scale + sc.offset
            if lo < hi:
                q = np.clip(q, lo, hi)
            out[sig] = q if q.ndim else float(q)
            rest = rest - q
        out[im.signals[-1]] = rest if rest.ndim else float(rest)
    return out
