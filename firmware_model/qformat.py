"""Fixed-point vocabulary: Q formats, overflow and rounding policies, saturating integer arithmetic.

Notation (as in fxpmath and the ARM CMSIS-DSP docs): a signed ``Qm.n`` number is stored in a
two's-complement word of ``n_word = 1 + m + n`` bits; ``n`` fractional bits, so the real value is
``raw * 2**-n`` and the representable range is ``[-2**m, 2**m - 2**-n]``. ``Q15.16`` is an int32
with 16 fractional bits. Here every *stored* variable is an int32 (``n_word = 32``) and every
accumulator an int64, as on a 32-bit MCU without FPU.

Policies used by the firmware model (one of each, named, never implicit):

- :class:`Overflow.SATURATE`: a result outside the word's range is clamped to the nearest end and
  the event is counted (:class:`SatCounters`); results never wrap around.
- :class:`Rounding.HALF_UP`: a right shift by ``s`` bits adds ``2**(s-1)`` first and then shifts
  arithmetically (floor), i.e. round to nearest with ties towards +inf. Divisions round to nearest
  with ties away from zero (:func:`div_round`), computed on magnitudes so that the result does not
  depend on a language's rule for negative division.

All functions here are pure integer code. Python's ``>>`` on negative ints is an arithmetic shift
(floor), like numba's int64 ``>>`` and like ``ASR`` on ARM; the compiled step
(:mod:`firmware_model.lateral`) has its own kernels of the same rules, run on Python ints by its tests.

Conversions between real values (float) and raw integers exist only for the boundary (the CAN
signals in SI and the tables generator): :meth:`QFormat.to_raw` / :meth:`QFormat.to_real`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1


class Overflow(Enum):
    """What happens to a result outside its word: SATURATE clamps (and counts); WRAP is not used."""

    SATURATE = "saturate"
    WRAP = "wrap"


class Rounding(Enum):
    """Rounding of right shifts: HALF_UP adds half an LSB then floors; FLOOR truncates towards -inf."""

    HALF_UP = "half_up"
    FLOOR = "floor"


@dataclass(frozen=True)
class QFormat:
    """A fixed-point format: ``n_word`` bits in total, ``n_frac`` fractional bits, signed or not.

    ``n_frac`` may be negative (LSB larger than 1) or larger than ``n_word`` (all fraction).
    """

    n_word: int
    n_frac: int
    signed: bool = True
    overflow: Overflow = Overflow.SATURATE
    rounding: Rounding = Rounding.HALF_UP

    @property
    def n_int(self) -> int:
        """Integer bits m of Qm.n (sign bit excluded)."""
        return self.n_word - self.n_frac - (1 if self.signed else 0)

    @property
    def raw_min(self) -> int:
        return -(2 ** (self.n_word - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return 2 ** (self.n_word - 1) - 1 if self.signed else 2**self.n_word - 1

    @property
    def lsb(self) -> float:
        """Resolution: the real value of one raw unit."""
        return math.ldexp(1.0, -self.n_frac)

    @property
    def real_min(self) -> float:
        return self.raw_min * self.lsb

    @property
    def real_max(self) -> float:
        return self.raw_max * self.lsb

    def __str__(self) -> str:
        return f"{'' if self.signed else 'U'}Q{self.n_int}.{self.n_frac}"

    def to_raw(self, value: float) -> tuple[int, bool]:
        """Nearest raw integer to ``value`` (ties away from zero), saturated; (raw, saturated?).

        NaN maps to 0 and counts as saturated (the caller flags the input as invalid).
        """
        if value != value:  # NaN
            return 0, True
        if math.isinf(value):
            return (self.raw_max, True) if value > 0 else (self.raw_min, True)
        scaled = math.ldexp(value, self.n_frac)
        raw = int(math.floor(abs(scaled) + 0.5))
        raw = raw if scaled >= 0 else -raw
        return saturate(raw, self.raw_min, self.raw_max)

    def to_real(self, raw: int) -> float:
        return math.ldexp(float(raw), -self.n_frac)

    def fits(self, value: float, headroom: float = 1.0) -> bool:
        """True if ``|value| * headroom`` is representable."""
        return abs(value) * headroom <= self.real_max


def q32(n_frac: int) -> QFormat:
    """A signed int32 format with ``n_frac`` fractional bits (``q32(16)`` is Q15.16)."""
    return QFormat(32, n_frac)


def frac_bits_for(max_abs: float, n_word: int = 32, headroom: float = 2.0) -> int:
    """The most fractional bits of a signed ``n_word`` format that holds ``max_abs * headroom``."""
    if max_abs <= 0.0:
        return n_word - 1
    m = math.floor(math.log2(max_abs * headroom)) + 1  # 2**m > value: m integer bits
    return n_word - 1 - m


# --- saturating integer arithmetic (the reference semantics) ----------------------------------


def saturate(value: int, lo: int = INT32_MIN, hi: int = INT32_MAX) -> tuple[int, bool]:
    """Clamp ``value`` to [lo, hi]; (result, saturated?)."""
    if value > hi:
        return hi, True
    if value < lo:
        return lo, True
    return value, False


def shift_round(value: int, s: int) -> int:
    """``value * 2**-s`` rounded HALF_UP for s > 0; a left shift for s <= 0 (exact).

    Written as ``(value >> s) + bit s-1 of value``, which equals ``(value + 2**(s-1)) >> s`` but
    cannot overflow an int64 (the numba twin computes in int64).
    """
    if s > 0:
        return (value >> s) + ((value >> (s - 1)) & 1)
    return value << (-s)


def add_sat64(acc: int, p: int) -> tuple[int, bool]:
    """acc + p in an int64 accumulator, saturating; (sum, saturated?). Both operands are int64."""
    if p > 0 and acc > INT64_MAX - p:
        return INT64_MAX, True
    if p < 0 and acc < INT64_MIN - p:
        return INT64_MIN, True
    return acc + p, False


def div_round(num: int, den: int) -> int:
    """num / den rounded to nearest, ties away from zero; den > 0. On magnitudes (portable: no
    dependence on a language's rule for negative division) and without overflow in int64."""
    a = -num if num < 0 else num
    q = a // den
    r = a - q * den
    if r >= den - r:
        q += 1
    return -q if num < 0 else q


# --- saturation counters ----------------------------------------------------------------------


@dataclass
class SatCounters:
    """Saturation events per named variable (a firmware would keep one uint16/uint32 per slot)."""

    names: tuple[str, ...]
    counts: list[int] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not self.counts:
            self.counts = [0] * len(self.names)

    def hit(self, slot: int) -> None:
        self.counts[slot] += 1

    def as_dict(self) -> dict[str, int]:
        return dict(zip(self.names, self.counts, strict=True))

    def total(self) -> int:
        return sum(self.counts)

    def reset(self) -> None:
        self.counts = [0] * len(self.names)

    @classmethod
    def from_counts(cls, names: Iterable[str], counts: Iterable[int]) -> SatCounters:
        return cls(tuple(names), [int(c) for c in counts])
