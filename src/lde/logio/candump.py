"""candump ``-L`` text logs (SocketCAN can-utils) <-> :class:`~lde.frames.FrameBatch`.

Line format (one frame per line)::

    (1700000000.123456) vcan0 2A0#0011223344556677        classic CAN, 11-bit id (3 hex digits)
    (1700000000.123456) vcan0 12345678#00112233           29-bit id (8 hex digits)
    (1700000000.123456) vcan0 2A0##1001122...              CAN FD: '##', one flags nibble, data
    (1700000000.123456) vcan0 2A0#R                        remote frame ('#R' or '#R<len>')
    (1700000000.123456) vcan0 20000080#0000000000000000    error frame (CAN_ERR_FLAG 0x20000000 in the id)
    (1700000000.123456) vcan0 2A0#0011 T                   python-can's optional direction (R rx, T tx)

Timestamps are parsed from their text to integer nanoseconds exactly (seconds and up to 9 fraction
digits; more digits are truncated), never through a float. The parser is a numba kernel over the raw
bytes so that a million-line log reads in well under a second. Remote and error frames carry no
payload for lde and are skipped with a count; a line that does not parse is counted as malformed.
candump ends every line with a newline, so a last line *without* one is a log cut while being written:
it is skipped and counted as truncated even if what is left of it parses (its payload may be cut).
Classic frames may carry python-can's ``_<dlc>`` suffix (len8_dlc), which is ignored.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from ..errors import LogFormatError
from ..frames import FrameBatch

__all__ = ["CandumpParse", "parse_candump_bytes", "looks_like_candump", "write_candump", "format_candump"]

# per-line status codes of the kernel
ST_FRAME = 0
ST_ERROR = 1
ST_REMOTE = 2
ST_MALFORMED = 3
ST_BLANK = 4

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF


@numba.njit(cache=True, inline="always")
def _hexval(c: int) -> int:
    if 48 <= c <= 57:
        return c - 48
    if 65 <= c <= 70:
        return c - 55
    if 97 <= c <= 102:
        return c - 87
    return -1


@numba.njit(cache=True, inline="always")
def _is_space(c: int) -> bool:
    return c == 32 or c == 9 or c == 13


@numba.njit(cache=True)
def _parse_line(buf, a, b, out_t, out_id, out_ext, out_dlc, out_data, out_rx, k):  # noqa: C901
    """Parse buf[a:b] (one line without its newline) into row k. Returns a status code."""
    i = a
    while i < b and _is_space(buf[i]):
        i += 1
    if i >= b:
        return ST_BLANK
    if buf[i] != 40:  # '('
        return ST_MALFORMED
    i += 1
    # seconds: up to 11 digits (int64 ns stays exact up to year 2262)
    sec = np.int64(0)
    nd = 0
    while i < b and 48 <= buf[i] <= 57:
        if nd >= 11:
            return ST_MALFORMED
        sec = sec * 10 + (buf[i] - 48)
        nd += 1
        i += 1
    if nd == 0:
        return ST_MALFORMED
    # int64 ns holds 9223372036.854775807 s at most: a larger time would wrap, so the line is bad
    if sec > 9_223_372_035:
        return ST_MALFORMED
    frac = np.int64(0)
    nf = 0
    if i < b and buf[i] == 46:  # '.'
        i += 1
        while i < b and 48 <= buf[i] <= 57:
            if nf < 9:
                frac = frac * 10 + (buf[i] - 48)
            nf += 1
            i += 1
    if i >= b or buf[i] != 41:  # ')'
        return ST_MALFORMED
    i += 1
    for _ in range(9 - min(nf, 9)):
        frac *= 10
    t = sec * 1_000_000_000 + frac
    # interface token
    if i >= b or not _is_space(buf[i]):
        return ST_MALFORMED
    while i < b and _is_space(buf[i]):
        i += 1
    n_if = 0
    while i < b and not _is_space(buf[i]):
        i += 1
        n_if += 1
    if n_if == 0:
        return ST_MALFORMED
    while i < b and _is_space(buf[i]):
        i += 1
    # id
    cid = np.int64(0)
    nh = 0
    while i < b and buf[i] != 35:  # '#'
        h = _hexval(buf[i])
        if h < 0 or nh >= 8:
            return ST_MALFORMED
        cid = cid * 16 + h
        nh += 1
        i += 1
    if nh == 0 or i >= b:
        return ST_MALFORMED
    i += 1  # past '#'
    ext = nh > 3
    if not ext and cid > 0x7FF:
        return ST_MALFORMED
    status = ST_FRAME
    if ext and (cid & CAN_ERR_FLAG) != 0:
        status = ST_ERROR
    fd = False
    if i < b and buf[i] == 35:  # '##': CAN FD, one flags nibble follows
        fd = True
        i += 1
        if i >= b or _hexval(buf[i]) < 0:
            return ST_MALFORMED
        i += 1
    n = 0
    if not fd and i < b and (buf[i] == 82 or buf[i] == 114):  # 'R' / 'r': remote frame
        i += 1
        while i < b and 48 <= buf[i] <= 57:
            i += 1
        if status == ST_FRAME:
            status = ST_REMOTE
    else:
        while i + 1 < b and _hexval(buf[i]) >= 0 and _hexval(buf[i + 1]) >= 0:
            if n < 8:
                out_data[k, n] = _hexval(buf[i]) * 16 + _hexval(buf[i + 1])
            n += 1
            i += 2
        if n > 64 or (not fd and n > 8):
            return ST_MALFORMED
        if i < b and _hexval(buf[i]) >= 0:  # odd number of hex digits
            return ST_MALFORMED
        if not fd and i < b and buf[i] == 95:  # '_<dlc>' (python-can len8_dlc)
            i += 1
            if i >= b or _hexval(buf[i]) < 0:
                return ST_MALFORMED
            i += 1
    # optional direction token and trailing blanks
    rx = True
    if i < b and not _is_space(buf[i]):
        return ST_MALFORMED
    while i < b and _is_space(buf[i]):
        i += 1
    if i < b:
        c = buf[i]
        if c == 84 or c == 116:  # 'T'
            rx = False
        elif c != 82 and c != 114:  # 'R'
            return ST_MALFORMED
        i += 1
        while i < b and _is_space(buf[i]):
            i += 1
        if i < b:
            return ST_MALFORMED
    out_t[k] = t
    out_id[k] = cid & CAN_EFF_MASK
    out_ext[k] = ext
    out_dlc[k] = n
    out_rx[k] = rx
    return status


@numba.njit(cache=True)
def _parse_all(buf, out_t, out_id, out_ext, out_dlc, out_data, out_rx, line_status):
    """Split buf at b'\\n' and parse every line; rows are packed (frames only). Returns n_frames."""
    n = buf.shape[0]
    a = 0
    line = 0
    k = 0
    while a < n:
        b = a
        while b < n and buf[b] != 10:
            b += 1
        st = _parse_line(buf, a, b, out_t, out_id, out_ext, out_dlc, out_data, out_rx, k)
        line_status[line] = st
        if st == ST_FRAME:
            k += 1
        else:
            for j in range(8):
                out_data[k, j] = 0
        line += 1
        a = b + 1
    return k


@dataclass(frozen=True)
class CandumpParse:
    """Result of parsing a candump ``-L`` text.

    Attributes:
        frames: the data frames (is_rx True unless the line carried python-can's ``T`` flag), in
            file order (not re-sorted).
        lines: number of lines (including blank ones).
        error_frames: error frames skipped.
        remote_frames: remote frames skipped.
        malformed_lines: lines that did not parse (excluding a truncated last line).
        truncated_last_line: 1 if the last line had no newline and did not parse, else 0.
        first_malformed_line: 1-based number of the first malformed line, 0 if none.
    """

    frames: FrameBatch
    lines: int
    error_frames: int
    remote_frames: int
    malformed_lines: int
    truncated_last_line: int
    first_malformed_line: int


def parse_candump_bytes(raw: bytes | bytearray | memoryview) -> CandumpParse:
    """Parse the bytes of a candump ``-L`` log (see the module doc). Never raises on bad lines."""
    buf = np.frombuffer(raw, dtype=np.uint8)
    n_lines = int(np.count_nonzero(buf == 10)) + 1
    t = np.empty(n_lines, np.int64)
    cid = np.empty(n_lines, np.uint32)
    ext = np.empty(n_lines, np.bool_)
    dlc = np.empty(n_lines, np.uint8)
    data = np.zeros((n_lines, 8), np.uint8)
    rx = np.empty(n_lines, np.bool_)
    status = np.full(n_lines, ST_BLANK, np.int8)
    k = _parse_all(buf, t, cid, ext, dlc, data, rx, status) if buf.size else 0
    ends_with_newline = buf.size == 0 or buf[-1] == 10
    # the kernel sees an empty last "line" after a final newline: it is blank
    truncated = 0
    bad = status == ST_MALFORMED
    if not ends_with_newline and status[n_lines - 1] != ST_BLANK:
        truncated = 1
        bad[n_lines - 1] = False
        if status[n_lines - 1] == ST_FRAME:
            k -= 1  # frames are packed in line order: the last line's frame is the last row
    bad_idx = np.flatnonzero(bad)
    frames = FrameBatch(
        t_ns=t[:k], can_id=cid[:k], is_extended=ext[:k], dlc=dlc[:k], data=data[:k], is_rx=rx[:k]
    )
    return CandumpParse(
        frames=frames,
        lines=n_lines - (1 if ends_with_newline else 0),
        error_frames=int(np.count_nonzero(status == ST_ERROR)),
        remote_frames=int(np.count_nonzero(status == ST_REMOTE)),
        malformed_lines=int(bad_idx.size),
        truncated_last_line=truncated,
        first_malformed_line=int(bad_idx[0]) + 1 if bad_idx.size else 0,
    )


def looks_like_candump(head: bytes) -> bool:
    """Content sniffing: does the first non-blank line of ``head`` parse as a candump ``-L`` line?"""
    for line in head.splitlines():
        if line.strip():
            p = parse_candump_bytes(line.rstrip(b"\r\n") + b"\n")
            return len(p.frames) + p.error_frames + p.remote_frames == 1
    return False


def _timestamps_text(t_ns: np.ndarray) -> list[str]:
    """``sec.frac`` with 6 fraction digits when every timestamp is a whole microsecond, else 9."""
    t = np.asarray(t_ns, dtype=np.int64)
    if t.size and np.any(t < 0):
        raise LogFormatError("candump logs cannot hold negative timestamps")
    sec = t // 1_000_000_000
    rem = t % 1_000_000_000
    if np.all(rem % 1000 == 0):
        us = rem // 1000
        return [f"{s}.{f:06d}" for s, f in zip(sec.tolist(), us.tolist(), strict=True)]
    return [f"{s}.{f:09d}" for s, f in zip(sec.tolist(), rem.tolist(), strict=True)]


def format_candump(frames: FrameBatch, channel: str = "vcan0") -> str:
    """The candump ``-L`` text of ``frames`` (rx frames plain; frames sent by lde get a `` T`` flag).

    Frames with ``dlc > 8`` are written as CAN FD (``##0``) holding only their stored first 8 bytes.
    """
    n = len(frames)
    if n == 0:
        return ""
    ts = _timestamps_text(frames.t_ns)
    hexdata = frames.data.tobytes().hex().upper()
    dlc = frames.dlc.astype(np.int64).tolist()
    ids = frames.can_id.tolist()
    ext = frames.is_extended.tolist()
    rx = frames.is_rx.tolist()
    out = []
    for i in range(n):
        d = dlc[i]
        idtxt = f"{ids[i]:08X}" if ext[i] else f"{ids[i]:03X}"
        sep = "##0" if d > 8 else "#"
        payload = hexdata[16 * i : 16 * i + 2 * min(d, 8)]
        out.append(f"({ts[i]}) {channel} {idtxt}{sep}{payload}{'' if rx[i] else ' T'}\n")
    return "".join(out)


def write_candump(path: str | Path, frames: FrameBatch, channel: str = "vcan0") -> None:
    """Write ``frames`` as a candump ``-L`` log (see :func:`format_candump`)."""
    try:
        Path(path).write_text(format_candump(frames, channel), encoding="ascii")
    except OSError as exc:
        raise LogFormatError(f"{path}: cannot write: {exc}") from exc
