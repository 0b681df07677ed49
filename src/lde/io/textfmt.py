"""Fast fixed-point text rows (CSV lines, flat JSON objects) from numeric columns: a numba kernel.

``np.savetxt`` and per-row f-strings cost 2-5 us per row; an hour of replay has ~1M rows. Here one
numba loop (without the GIL, two threads on large inputs, each on half of the rows) prints every
value as an integer with the decimal point inserted::

    float column, d decimals:  r = round_half_away(|v| * 10**d);  "-" if v < 0 and r > 0;
                               digits of r with "." before the last d (at least one before it)
    int column:                the integer (d = 0)
    time column:               integer ns (or us) printed with 9 (or 6) decimals: exact seconds
    exact float column:        17 significant digits, correctly rounded (``decimals = EXACT``):
                               parses back to the same double (JSON recordings that a replay
                               compares bit for bit); ``%g``-like layout, trailing zeros dropped

Non-finite floats (and |v| * 10**d >= 9e18) print as ``nan_text`` (``nan`` in CSV, ``null`` in
JSON). :func:`time_column` prints integer ns timestamps exactly (``1700000000.123900``: 6 digits
when every value is a whole microsecond, else 9).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["Column", "format_rows", "time_column", "EXACT"]

_K_FLOAT, _K_INT, _K_EXACT = 0, 1, 2
#: ``Column.decimals`` value asking for the exact (round-trip) float format
EXACT = -1
_P17 = 10**17
_P16 = 10**16
_PARALLEL_ROWS = 100_000  # split into two threads above this many rows
_LUT = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()


@dataclass(frozen=True)
class Column:
    """One output column: ``values`` (float or int array) printed with ``decimals`` digits.

    ``prescaled``: ``values`` are integers already in units of ``10**-decimals`` (time columns).
    ``decimals`` :data:`EXACT`: floats in the exact round-trip format (module docstring).
    """

    name: str
    values: np.ndarray
    decimals: int = 0
    prescaled: bool = False


def time_column(name: str, t_ns: np.ndarray) -> Column:
    """Seconds from int ns, exactly: 6 decimals if all are whole microseconds, else 9."""
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size and np.all(t % 1000 == 0):
        return Column(name, t // 1000, 6, prescaled=True)
    return Column(name, t, 9, prescaled=True)


@numba.njit(cache=True, nogil=True)
def _mul_small(limbs, n, f):  # pragma: no cover - compiled
    """limbs (little-endian base 2**32 in uint64 slots, n used) *= f (f < 2**32); returns new n."""
    carry = np.uint64(0)
    for i in range(n):
        v = limbs[i] * np.uint64(f) + carry
        limbs[i] = v & np.uint64(0xFFFFFFFF)
        carry = v >> np.uint64(32)
    while carry:
        limbs[n] = carry & np.uint64(0xFFFFFFFF)
        carry = carry >> np.uint64(32)
        n += 1
    return n


@numba.njit(cache=True, nogil=True)
def _bit(limbs, n, i):  # pragma: no cover - compiled
    """Bit ``i`` of the limb number (0 beyond its ``n`` limbs)."""
    j = i // 32
    if j >= n:
        return np.uint64(0)
    return (limbs[j] >> np.uint64(i % 32)) & np.uint64(1)


@numba.njit(cache=True, nogil=True)
def _shift_round(limbs, n, s):  # pragma: no cover - compiled
    """round_half_even(limbs / 2**s) as int64 (the result must fit in 62 bits; s >= 1)."""
    w = s // 32
    b = s % 32
    # bits s.. live in limbs w, w+1, w+2 (the result has < 62 bits)
    q = limbs[w] >> np.uint64(b) if w < n else np.uint64(0)
    if w + 1 < n:
        q |= limbs[w + 1] << np.uint64(32 - b)
    if w + 2 < n and b > 0:
        q |= limbs[w + 2] << np.uint64(64 - b)
    half = _bit(limbs, n, s - 1)
    rest = False
    w = (s - 1) // 32
    for j in range(min(w, n)):
        if limbs[j]:
            rest = True
            break
    if not rest and w < n and (limbs[w] & ((np.uint64(1) << np.uint64((s - 1) % 32)) - np.uint64(1))):
        rest = True
    if half and (rest or (q & np.uint64(1))):
        q += np.uint64(1)
    return np.int64(q)


@numba.njit(cache=True, nogil=True)
def _digits17(a, limbs):  # pragma: no cover - compiled
    """(D, k) with a ~= D * 10**(k - 16), 10**16 <= D < 10**17, D correctly rounded, for finite
    a > 0 below 1e17 (exact integer arithmetic on the double's mantissa)."""
    f, e = math.frexp(a)
    m = np.int64(f * 9007199254740992.0)  # 2**53: the mantissa, exact
    e2 = e - 53
    k = min(int(math.floor(math.log10(a))), 16)  # a < 1e17: q = 16 - k >= 0
    for _ in range(3):  # log10 may be one off near a power of ten
        q = 16 - k  # a * 10**q has 17 digits
        # m * 5**q * 2**(e2 + q), q >= 0 for a < 1e17
        limbs[0] = np.uint64(m) & np.uint64(0xFFFFFFFF)
        limbs[1] = np.uint64(m) >> np.uint64(32)
        # int64, not literals: numba would compile _mul_small once more per literal it sees
        n = np.int64(2)
        r = q
        while r >= 13:  # 5**13 < 2**32
            n = _mul_small(limbs, n, np.int64(1220703125))
            r -= 13
        if r > 0:
            n = _mul_small(limbs, n, 5**r)
        s = e2 + q
        if s >= 0:
            d = np.int64(0)
            for b in range(n - 1, -1, -1):
                d = (d << 32) | np.int64(limbs[b])
            d = d << s
        else:
            d = _shift_round(limbs, n, -s)
        if d >= _P17:
            k += 1
        elif d < _P16:
            k -= 1
        else:
            return d, k
    return d, k


@numba.njit(cache=True, nogil=True)
def _format(fcols, icols, kinds, slot, decimals, sep, sep_off, end, nan_text, lut, out, row_off, r0, r1):
    """Rows r0..r1-1 into ``out`` from 0; row_off[i - r0] = start of row i. Returns bytes written."""
    m = kinds.shape[0]
    o = np.int64(0)  # not the literal 0: numba would compile _write_exact for it too
    digits = np.empty(24, np.uint8)
    limbs = np.zeros(40, np.uint64)
    p10 = np.empty(m, np.float64)
    for c in range(m):
        p10[c] = 10.0 ** decimals[c]
    for i in range(r0, r1):
        row_off[i - r0] = o
        for c in range(m):
            for j in range(sep_off[c], sep_off[c + 1]):
                out[o] = sep[j]
                o += 1
            d = decimals[c]
            neg = False
            if kinds[c] == _K_EXACT:
                o = _write_exact(fcols[slot[c], i], out, o, nan_text, lut, digits, limbs)
                continue
            if kinds[c] == _K_FLOAT:
                x = fcols[slot[c], i] * p10[c]
                if not (abs(x) < 9e18):  # NaN, inf, out of range
                    for j in range(nan_text.shape[0]):
                        out[o] = nan_text[j]
                        o += 1
                    continue
                neg = x < 0
                r = np.int64(math.floor(abs(x) + 0.5))
                if r == 0:
                    neg = False
            else:
                r = icols[slot[c], i]
                if r < 0:
                    neg = True
                    r = -r
            # digits of r, least significant first, two at a time
            k = 0
            while r >= 100:
                q = r // 100
                two = 2 * (r - q * 100)
                digits[k] = lut[two + 1]
                digits[k + 1] = lut[two]
                k += 2
                r = q
            if r >= 10:
                digits[k] = lut[2 * r + 1]
                digits[k + 1] = lut[2 * r]
                k += 2
            else:
                digits[k] = 48 + r
                k += 1
            while k <= d:  # at least one digit before the point
                digits[k] = 48
                k += 1
            if neg:
                out[o] = 45  # '-'
                o += 1
            for j in range(k - 1, -1, -1):
                out[o] = digits[j]
                o += 1
                if j == d and d > 0:
                    out[o] = 46  # '.'
                    o += 1
        for j in range(end.shape[0]):
            out[o] = end[j]
            o += 1
    row_off[r1 - r0] = o
    return o


@numba.njit(cache=True, nogil=True)
def _write_exact(x, out, o, nan_text, lut, digits, limbs):  # pragma: no cover - compiled
    """``x`` in the exact format at ``out[o:]``; returns the new offset."""
    if not math.isfinite(x):
        for j in range(nan_text.shape[0]):
            out[o] = nan_text[j]
            o += 1
        return o
    if x == 0.0:
        if math.copysign(1.0, x) < 0:
            out[o] = 45
            o += 1
        out[o] = 48
        return o + 1
    if x < 0:
        out[o] = 45  # '-'
        o += 1
    a = abs(x)
    if a >= 1e17:  # beyond the exact range: 17 digits in floating point (documented)
        k = int(math.floor(math.log10(a)))
        d = np.int64(round(a / 10.0 ** (k - 16)))
        if d >= _P17:
            d //= 10
            k += 1
    else:
        d, k = _digits17(a, limbs)
    # the 17 digits, most significant first, trailing zeros dropped
    for j in range(16, -1, -1):
        digits[j] = 48 + d % 10
        d //= 10
    nd = 17
    while nd > 1 and digits[nd - 1] == 48:
        nd -= 1
    if -5 <= k < 17:
        if k < 0:  # 0.000ddd
            out[o] = 48
            out[o + 1] = 46
            o += 2
            for _ in range(-k - 1):
                out[o] = 48
                o += 1
            for j in range(nd):
                out[o] = digits[j]
                o += 1
        else:
            for j in range(max(nd, k + 1)):
                if j == k + 1:
                    out[o] = 46  # '.'
                    o += 1
                out[o] = digits[j] if j < nd else 48
                o += 1
        return o
    out[o] = digits[0]
    o += 1
    if nd > 1:
        out[o] = 46
        o += 1
        for j in range(1, nd):
            out[o] = digits[j]
            o += 1
    out[o] = 101  # 'e'
    o += 1
    if k < 0:
        out[o] = 45
        k = -k
    else:
        out[o] = 43  # '+'
    o += 1
    if k >= 100:
        out[o] = 48 + k // 100
        o += 1
    out[o] = 48 + (k // 10) % 10
    out[o + 1] = 48 + k % 10
    return o + 2


def format_rows(
    columns: Sequence[Column], separators: Sequence[str], end: str, nan_text: str = "nan"
) -> tuple[np.ndarray, np.ndarray]:
    """Rows of text: for each row, ``separators[c] + value_c`` for every column, then ``end``.

    Returns the text as a uint8 array (write it with ``file.write``) and the row start offsets
    (int64 [n + 1]).
    """
    if len(separators) != len(columns):
        raise ValueError("one separator per column")
    n = int(np.asarray(columns[0].values).shape[0]) if columns else 0
    m = len(columns)
    kinds = np.zeros(m, np.int64)
    slot = np.zeros(m, np.int64)
    dec = np.zeros(m, np.int64)
    fl: list[np.ndarray] = []
    il: list[np.ndarray] = []
    for c, col in enumerate(columns):
        v = np.asarray(col.values)
        if v.shape != (n,):
            raise ValueError(f"column {col.name!r} has shape {v.shape}, expected ({n},)")
        dec[c] = max(col.decimals, 0)
        if col.decimals == EXACT and v.dtype.kind == "f":
            kinds[c] = _K_EXACT
            slot[c] = len(fl)
            fl.append(v.astype(np.float64))
        elif col.prescaled or v.dtype.kind in "iub":
            kinds[c] = _K_INT
            slot[c] = len(il)
            iv = v.astype(np.int64)
            il.append(iv if col.prescaled or col.decimals == 0 else iv * (10**col.decimals))
        else:
            kinds[c] = _K_FLOAT
            slot[c] = len(fl)
            fl.append(v.astype(np.float64))
    fcols = np.stack(fl) if fl else np.zeros((1, n))
    icols = np.stack(il) if il else np.zeros((1, n), np.int64)
    sep_b = [s.encode() for s in separators]
    sep = np.frombuffer(b"".join(sep_b) or b"\0", np.uint8)
    sep_off = np.zeros(m + 1, np.int64)
    np.cumsum([len(s) for s in sep_b], out=sep_off[1:])
    end_b = np.frombuffer(end.encode() or b"\0", np.uint8)[: len(end.encode())]
    nan_b = np.frombuffer(nan_text.encode(), np.uint8)
    width = (
        int(sep_off[-1]) + len(end_b) + m * max(26, len(nan_b))
    )  # 26: an exact float with sign and exponent
    parts = [(0, n)] if n < _PARALLEL_ROWS else [(0, n // 2), (n // 2, n)]
    outs = [np.empty(max((b - a) * width, 1), np.uint8) for a, b in parts]
    offs = [np.empty(b - a + 1, np.int64) for a, b in parts]

    def run(k: int) -> int:
        a, b = parts[k]
        return _format(
            fcols, icols, kinds, slot, dec, sep, sep_off, end_b, nan_b, _LUT, outs[k], offs[k], a, b
        )

    if len(parts) == 1:
        sizes = [run(0)]
    else:
        with ThreadPoolExecutor(max_workers=2) as pool:
            sizes = list(pool.map(run, range(len(parts))))
    if len(parts) == 1:
        return outs[0][: sizes[0]], offs[0]
    text = np.concatenate([o[:s] for o, s in zip(outs, sizes, strict=True)])
    row_off = np.concatenate([offs[0][:-1], offs[1] + sizes[0]])
    return text, row_off
