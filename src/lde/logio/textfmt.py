"""Fast fixed-point text rows (CSV lines, flat JSON objects) from numeric columns: a numba kernel.

``np.savetxt`` and per-row f-strings cost 2-5 us per row; an hour of replay has ~1M rows. Here every
column is first scaled to an integer in numpy, ``round(v * 10**decimals)``, then one numba loop
prints the integers with the decimal point inserted (``-12.345`` for -12345 with 3 decimals).
Non-finite values print as ``nan_text`` (``nan`` in CSV, ``null`` in JSON). Timestamps are printed
exactly from integer ns (``1700000000.123900``: 6 digits when every value is a whole microsecond,
else 9).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

__all__ = ["Column", "format_rows", "time_column"]


@dataclass(frozen=True)
class Column:
    """One output column: ``values`` (float or int array) printed with ``decimals`` digits.

    ``prescaled``: ``values`` are integers already in units of ``10**-decimals`` (time columns).
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


@numba.njit(cache=True)
def _format(ints, finite, decimals, sep, sep_off, end, nan_text, out, row_off):
    n, m = ints.shape
    o = 0
    digits = np.empty(24, np.uint8)
    for i in range(n):
        row_off[i] = o
        for c in range(m):
            for j in range(sep_off[c], sep_off[c + 1]):
                out[o] = sep[j]
                o += 1
            if not finite[i, c]:
                for j in range(nan_text.shape[0]):
                    out[o] = nan_text[j]
                    o += 1
                continue
            v = ints[i, c]
            neg = v < 0
            if neg:
                v = -v
            d = decimals[c]
            k = 0
            while v > 0 or k <= d:
                digits[k] = 48 + v % 10
                v //= 10
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
    row_off[n] = o
    return o


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
    ints = np.zeros((n, m), np.int64)  # row-major: the kernel reads one row at a time
    finite = np.ones((n, m), np.bool_)
    dec = np.zeros(m, np.int64)
    for c, col in enumerate(columns):
        v = np.asarray(col.values)
        if v.shape != (n,):
            raise ValueError(f"column {col.name!r} has shape {v.shape}, expected ({n},)")
        dec[c] = col.decimals
        if col.prescaled:
            ints[:, c] = v.astype(np.int64)
        elif v.dtype.kind in "iub":
            ints[:, c] = v.astype(np.int64) * (10**col.decimals)
        else:
            f = v.astype(np.float64)
            ok = np.isfinite(f) & (np.abs(f) * 10.0**col.decimals < 9e18)
            finite[:, c] = ok
            ints[:, c] = np.rint(np.where(ok, f, 0.0) * 10.0**col.decimals).astype(np.int64)
    sep_b = [s.encode() for s in separators]
    sep = np.frombuffer(b"".join(sep_b) or b"\0", np.uint8)
    sep_off = np.zeros(m + 1, np.int64)
    np.cumsum([len(s) for s in sep_b], out=sep_off[1:])
    end_b = np.frombuffer(end.encode() or b"", np.uint8)
    nan_b = np.frombuffer(nan_text.encode(), np.uint8)
    width = int(sep_off[-1]) + len(end_b) + m * max(22, len(nan_b))
    out = np.empty(max(n * width, 1), np.uint8)
    row_off = np.empty(n + 1, np.int64)
    size = _format(ints, finite, dec, sep, sep_off, end_b, nan_b, out, row_off)
    return out[:size], row_off
