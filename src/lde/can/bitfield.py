"""The one bit-field packer: reading and writing the bit fields of a CAN frame's data bytes (classic
frames of up to 8 bytes and CAN FD frames of up to 64).

A field is given by its DBC layout (``start|length@1`` Intel, ``start|length@0`` Motorola, at most 64
bits) and stored as a *position* that makes both byte orders one loop over the bytes it covers:

* Intel (little-endian): bit ``k`` of the frame is bit ``k % 8`` of byte ``k // 8``; the field's
  position is its LSB, the DBC start bit: ``pos = start``. Its bytes run upwards from ``pos // 8``::

      raw = (sum of data[pos // 8 + j] << 8 j) >> (pos % 8)   masked to length bits

* Motorola (big-endian): the DBC start bit is the MSB; numbered MSB first (bit 7 of byte 0 is 0),
  the MSB sits at ``m = 8 (start // 8) + 7 - start % 8`` and the LSB at ``pos = m + length - 1``.
  Its bytes run downwards from ``pos // 8``::

      raw = (sum of data[pos // 8 - j] << 8 j) >> (7 - pos % 8)   masked to length bits

A field of 64 bits that does not start on a byte boundary covers 9 bytes: the ninth is shifted in
separately. Multi-part fields (an alive counter split into two 2-bit halves, hyundai WHL_SPD11) are an
int64 array of ``(pos, length, little_endian)`` rows, least significant part first; rows of length 0
are unused.

Everything here is compiled (numba) and used by the encoder and decoder kernels
(:mod:`lde.can.codec`), the integrity checks (:mod:`lde.can.e2e`) and the receiver
(:mod:`lde.engine.receiver`). :func:`field_pos` converts a DBC layout at the Python boundary.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "field_pos",
    "field_bytes",
    "get_bits",
    "put_bits",
    "get_parts",
    "put_parts",
    "parts_array",
]


def field_pos(start: int, length: int, little_endian: bool) -> int:
    """The packer's position of a DBC field (module doc): the start bit for Intel, the MSB-first
    index of the LSB for Motorola."""
    if little_endian:
        return int(start)
    return (int(start) // 8) * 8 + 7 - int(start) % 8 + int(length) - 1


def field_bytes(start: int, length: int, little_endian: bool) -> tuple[int, int]:
    """(first byte, last byte) a DBC field covers (to check it fits in a message's length)."""
    pos = field_pos(start, length, little_endian)
    if little_endian:
        return pos // 8, (pos + length - 1) // 8
    return (pos - length + 1) // 8, pos // 8


@njit(cache=True, inline="always")
def _mask(length):  # pragma: no cover - compiled
    if length >= 64:
        return np.uint64(0xFFFFFFFFFFFFFFFF)
    return (np.uint64(1) << np.uint64(length)) - np.uint64(1)


@njit(cache=True, inline="always")
def get_bits(data, pos, length, little_endian):  # pragma: no cover - compiled
    """Unsigned value (uint64) of the ``length``-bit field at ``pos`` (module doc) of the frame bytes
    ``data`` (uint8 row); the bytes it covers must lie within ``data``."""
    if length <= 0:
        return np.uint64(0)
    if little_endian:
        b = pos >> 3
        sh = pos & 7
        step = 1
    else:
        b = pos >> 3
        sh = 7 - (pos & 7)
        step = -1
    nb = (sh + length + 7) >> 3
    acc = np.uint64(0)
    for j in range(min(nb, 8)):
        acc |= np.uint64(data[b + step * j]) << np.uint64(8 * j)
    v = acc >> np.uint64(sh)
    if nb > 8:  # a 64-bit field off a byte boundary: the ninth byte
        v |= np.uint64(data[b + step * 8]) << np.uint64(64 - sh)
    return v & _mask(length)


@njit(cache=True, inline="always")
def put_bits(data, pos, length, little_endian, value):  # pragma: no cover - compiled
    """Write the low ``length`` bits of ``value`` into the field at ``pos`` of ``data`` (in place;
    the other bits are kept)."""
    if length <= 0:
        return
    v = np.uint64(value) & _mask(length)
    if little_endian:
        b = pos >> 3
        sh = pos & 7
        step = 1
    else:
        b = pos >> 3
        sh = 7 - (pos & 7)
        step = -1
    nb = (sh + length + 7) >> 3
    # the field's bits as they sit in the bytes b, b + step, ...: bit i of the field at bit sh + i
    for j in range(nb):
        lo = 8 * j - sh  # the field's bit at this byte's bit 0 (negative: the byte starts before it)
        if lo < 0:
            part = (v << np.uint64(-lo)) & np.uint64(0xFF)
            m = (_mask(length) << np.uint64(-lo)) & np.uint64(0xFF)
        else:
            part = (v >> np.uint64(lo)) & np.uint64(0xFF) if lo < 64 else np.uint64(0)
            m = (_mask(length) >> np.uint64(lo)) & np.uint64(0xFF) if lo < 64 else np.uint64(0)
        k = b + step * j
        data[k] = np.uint8((np.uint64(data[k]) & ~m & np.uint64(0xFF)) | part)


@njit(cache=True, inline="always")
def get_parts(data, parts):  # pragma: no cover - compiled
    """Value of a multi-part field: ``parts`` int64 [k, 3] of (pos, length, little_endian), LSB
    part first; rows with length 0 are unused."""
    out = np.uint64(0)
    at = 0
    for k in range(parts.shape[0]):
        n = parts[k, 1]
        if n > 0:
            out |= get_bits(data, parts[k, 0], n, parts[k, 2] != 0) << np.uint64(at)
            at += n
    return out


@njit(cache=True, inline="always")
def put_parts(data, parts, value):  # pragma: no cover - compiled
    """Write ``value`` into the multi-part field ``parts`` (see :func:`get_parts`) of ``data``."""
    v = np.uint64(value)
    for k in range(parts.shape[0]):
        n = parts[k, 1]
        if n > 0:
            put_bits(data, parts[k, 0], n, parts[k, 2] != 0, v)
            v = v >> np.uint64(n)


def parts_array(fields: tuple[tuple[int, int, bool], ...], rows: int = 2) -> np.ndarray:
    """DBC fields ``(start, length, little_endian)`` (LSB part first) as the int64 [rows, 3] parts
    array of :func:`get_parts` (unused rows 0)."""
    if len(fields) > rows:
        raise ValueError(f"at most {rows} parts per field, got {fields}")
    a = np.zeros((rows, 3), dtype=np.int64)
    for k, (start, length, le) in enumerate(fields):
        a[k] = (field_pos(start, length, le), length, int(bool(le)))
    return a
