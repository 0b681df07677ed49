"""The one bit-field packer: reading and writing bit fields of a CAN frame's 8 bytes.

A frame's 8 bytes are one little-endian 64-bit word ``w_le`` (bit ``k`` of the frame is bit
``k % 8`` of byte ``k // 8``), the layout of Intel (``@1``) DBC signals. Motorola (``@0``) signals are
contiguous in the big-endian word ``w_be = byteswap(w_le)``; their LSB position there is
``(7 - start // 8) * 8 + start % 8 - length + 1`` for a DBC start bit ``start`` (the MSB)::

    field value = (w >> shift) & (2**length - 1)
    w'          = (w & ~(mask << shift)) | ((value & mask) << shift)

Multi-part fields (an alive counter split into two 2-bit halves, hyundai WHL_SPD11) are an array
of ``(shift, length)`` rows, least significant part first.

Everything here is compiled (numba) and used by the decoder and encoder kernels
(:mod:`lde.can.codec`), the E2E counters and checksums (:mod:`lde.can.e2e`) and the receiver
(:mod:`lde.engine.receiver`); :func:`frame_word` / :func:`word_bytes` convert at the Python boundary.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "motorola_shift",
    "get_field",
    "put_field",
    "get_parts",
    "put_parts",
    "bytes_to_word",
    "word_to_bytes",
    "byteswap64",
    "frame_word",
    "word_bytes",
]

_MASK64 = (1 << 64) - 1


def motorola_shift(start: int, length: int) -> int:
    """LSB position in ``w_be`` of a Motorola signal with DBC start bit ``start`` (its MSB)."""
    return (7 - start // 8) * 8 + start % 8 - length + 1


@njit(cache=True, inline="always")
def byteswap64(w):  # pragma: no cover - compiled
    """The 64-bit word with its bytes reversed (``w_le`` <-> ``w_be``)."""
    w = np.uint64(w)
    out = np.uint64(0)
    for k in range(8):
        out = (out << np.uint64(8)) | ((w >> np.uint64(8 * k)) & np.uint64(0xFF))
    return out


@njit(cache=True, inline="always")
def get_field(w, shift, length):  # pragma: no cover - compiled
    """Unsigned value of the ``length``-bit field at ``shift`` of the uint64 word ``w``."""
    w = np.uint64(w)
    if length >= 64:
        return w >> np.uint64(shift)
    return (w >> np.uint64(shift)) & ((np.uint64(1) << np.uint64(length)) - np.uint64(1))


@njit(cache=True, inline="always")
def put_field(w, shift, length, value):  # pragma: no cover - compiled
    """``w`` with the field at ``shift`` set to the low ``length`` bits of ``value`` (uint64)."""
    w = np.uint64(w)
    mask = ((np.uint64(1) << np.uint64(length)) - np.uint64(1)) << np.uint64(shift)
    return (w & ~mask) | ((np.uint64(value) << np.uint64(shift)) & mask)


@njit(cache=True, inline="always")
def get_parts(w, parts):  # pragma: no cover - compiled
    """Value of a multi-part field: ``parts`` int64 [k, 2] of (shift, length), LSB part first;
    rows with length 0 are unused."""
    w = np.uint64(w)
    out = np.uint64(0)
    pos = 0
    for k in range(parts.shape[0]):
        n = parts[k, 1]
        if n > 0:
            out |= get_field(w, parts[k, 0], n) << np.uint64(pos)
            pos += n
    return out


@njit(cache=True, inline="always")
def put_parts(w, parts, value):  # pragma: no cover - compiled
    """``w`` with the multi-part field ``parts`` (see :func:`get_parts`) set to ``value``."""
    w = np.uint64(w)
    v = np.uint64(value)
    for k in range(parts.shape[0]):
        n = parts[k, 1]
        if n > 0:
            w = put_field(w, parts[k, 0], n, v)
            v = v >> np.uint64(n)
    return w


@njit(cache=True, inline="always")
def bytes_to_word(data, length):  # pragma: no cover - compiled
    """``w_le`` of the first ``min(length, 8)`` bytes of ``data`` (uint8 array); the rest is zero."""
    w = np.uint64(0)
    n = min(length, 8, data.shape[0])
    for k in range(n):
        w |= np.uint64(data[k]) << np.uint64(8 * k)
    return w


@njit(cache=True, inline="always")
def word_to_bytes(w, out):  # pragma: no cover - compiled
    """Write ``w_le`` into the 8 bytes of ``out`` (uint8 [8])."""
    w = np.uint64(w)
    for k in range(8):
        out[k] = np.uint8((w >> np.uint64(8 * k)) & np.uint64(0xFF))


def frame_word(data: bytes | bytearray, length: int | None = None) -> int:
    """``w_le`` of a frame's bytes as a Python int (bytes past ``length`` and past 8 count as 0)."""
    raw = bytes(data)[: 8 if length is None else min(8, int(length))]
    return int.from_bytes(raw.ljust(8, b"\x00"), "little")


def word_bytes(w: int, length: int = 8) -> bytes:
    """The first ``length`` bytes of ``w_le``."""
    return (int(w) & _MASK64).to_bytes(8, "little")[: int(length)]
