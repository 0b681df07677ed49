"""Many small constant arrays as one buffer: one compiled argument instead of dozens.

numba unboxes every array argument of a compiled call on its own (a Python object, its dtype, a
meminfo each): about 50 ns per array on a hot cache, and several cache misses per array when the
call runs once per 3.9 ms period on caches that other work has refilled (the live step). The
receiver's and the output encoder's tables (39 arrays that never change) therefore travel as one
uint8 buffer and a layout table (:func:`pack`); inside the compiled code the typed views come back
with :func:`i8_1` ... :func:`b1_1`, which cost a few instructions each.

``kinds`` name each array's dtype and number of dimensions (``"i8:1"``: int64, 1-d; ``"f8:1"``,
``"b1:1"``, ``"i8:2"``, ``"i8:3"``); the compiled unpacker that reads a buffer must ask for the same
kinds in the same order, so both sides take them from one tuple next to the unpacker.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["KINDS", "pack", "i8_1", "i8_2", "i8_3", "f8_1", "b1_1"]

#: the supported kinds and their dtypes
KINDS: dict[str, tuple[np.dtype, int]] = {
    "i8:1": (np.dtype(np.int64), 1),
    "i8:2": (np.dtype(np.int64), 2),
    "i8:3": (np.dtype(np.int64), 3),
    "f8:1": (np.dtype(np.float64), 1),
    "b1:1": (np.dtype(np.bool_), 1),
}
#: layout columns: byte offset, then up to three dimensions
_OFF, _D0, _D1, _D2 = range(4)
_ALIGN = 64


def pack(arrays: tuple[np.ndarray, ...], kinds: tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Copy ``arrays`` into one uint8 buffer (each 64-byte aligned); returns (buffer, layout), the
    layout int64 (n, 4): byte offset and dimensions. ValueError when an array is not of its kind."""
    if len(arrays) != len(kinds):
        raise ValueError(f"{len(arrays)} arrays for {len(kinds)} kinds")
    offs, size = [], _ALIGN  # room to align the first array
    for a, kind in zip(arrays, kinds, strict=True):
        dt, nd = KINDS[kind]
        if a.dtype != dt or a.ndim != nd:
            raise ValueError(f"array of {a.dtype} with {a.ndim} dimensions where {kind} is expected")
        offs.append(size)
        size = (size + a.nbytes + _ALIGN - 1) & ~(_ALIGN - 1)
    mem = np.zeros(size, np.uint8)
    base = (-mem.ctypes.data) % _ALIGN - _ALIGN
    lay = np.zeros((len(arrays), 4), np.int64)
    for k, (a, off) in enumerate(zip(arrays, offs, strict=True)):
        o = base + off
        mem[o : o + a.nbytes].view(a.dtype).reshape(a.shape)[...] = a
        lay[k, _OFF] = o
        lay[k, _D0 : _D0 + a.ndim] = a.shape
    return mem, lay


@njit(cache=True, inline="always")
def _bytes(mem, lay, k, itemsize):  # pragma: no cover - compiled
    n = lay[k, _D0] * max(lay[k, _D1], 1) * max(lay[k, _D2], 1)
    return mem[lay[k, _OFF] : lay[k, _OFF] + n * itemsize]


@njit(cache=True, inline="always")
def i8_1(mem, lay, k):  # pragma: no cover - compiled
    """Array ``k`` of a :func:`pack` buffer as int64, 1-d (a view)."""
    return _bytes(mem, lay, k, 8).view(np.int64)


@njit(cache=True, inline="always")
def i8_2(mem, lay, k):  # pragma: no cover - compiled
    """Array ``k`` as int64, 2-d (a view)."""
    return _bytes(mem, lay, k, 8).view(np.int64).reshape((lay[k, _D0], lay[k, _D1]))


@njit(cache=True, inline="always")
def i8_3(mem, lay, k):  # pragma: no cover - compiled
    """Array ``k`` as int64, 3-d (a view)."""
    return _bytes(mem, lay, k, 8).view(np.int64).reshape((lay[k, _D0], lay[k, _D1], lay[k, _D2]))


@njit(cache=True, inline="always")
def f8_1(mem, lay, k):  # pragma: no cover - compiled
    """Array ``k`` as float64, 1-d (a view)."""
    return _bytes(mem, lay, k, 8).view(np.float64)


@njit(cache=True, inline="always")
def b1_1(mem, lay, k):  # pragma: no cover - compiled
    """Array ``k`` as bool, 1-d (a view)."""
    return _bytes(mem, lay, k, 1).view(np.bool_)
