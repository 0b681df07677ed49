"""candump ``-L`` text logs (SocketCAN can-utils) <-> :class:`~lde.can.frames.FrameBatch`.

Line format (one frame per line)::

    (1700000000.123456) vcan0 2A0#0011223344556677        classic CAN, 11-bit id (3 hex digits)
    (1700000000.123456) vcan0 12345678#00112233           29-bit id (8 hex digits)
    (1700000000.123456) vcan0 2A0##1001122...              CAN FD: '##', one flags nibble, data
    (1700000000.123456) vcan0 2A0#R                        remote frame ('#R' or '#R<len>')
    (1700000000.123456) vcan0 20000080#0000000000000000    error frame (CAN_ERR_FLAG 0x20000000 in the id)
    (1700000000.123456) vcan0 2A0#0011 T                   python-can's optional direction (R rx, T tx)
    (1700000000.123456) 2A0#0011223344556677              no interface column (some other tools)

The interface column is each frame's channel (:attr:`lde.can.frames.FrameBatch.channels`; a line
without it: ``""``); CAN FD frames keep all their data bytes (up to 64).

Timestamps are parsed from their text to integer nanoseconds exactly (seconds and up to 9 fraction
digits; more digits are truncated), never through a float. The parser is a numba kernel over the raw
bytes so that a million-line log reads in well under a second. Remote and error frames carry no
payload for lde and are skipped with a count; a line that does not parse is counted as malformed.
candump ends every line with a newline, so a last line *without* one is a log cut while being written:
it is skipped and counted as truncated even if what is left of it parses (its payload may be cut).
Classic frames may carry python-can's ``_<dlc>`` suffix (len8_dlc), which is ignored.
"""

from __future__ import annotations

import io
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from lde.can.frames import CLASSIC_DATA, MAX_DATA, FrameBatch, data_width
from lde.errors import LogFormatError

__all__ = [
    "CandumpParse",
    "CandumpBlocks",
    "BAD_LINES_KEPT",
    "parse_candump_bytes",
    "looks_like_candump",
    "write_candump",
    "format_candump",
    "format_candump_bytes",
    "candump_decimals",
]

# per-line status codes of the kernel
ST_FRAME = 0
ST_ERROR = 1
ST_REMOTE = 2
ST_MALFORMED = 3
ST_BLANK = 4

CAN_ERR_FLAG = 0x20000000
CAN_EFF_MASK = 0x1FFFFFFF

# counts of the kernel: lines, error frames, remote frames, malformed lines, interface names known,
# then the 1-based line numbers of the first BAD_LINES_KEPT malformed lines (0: none) from C_FIRST_BAD on
C_LINES, C_ERROR, C_REMOTE, C_MALFORMED, C_NAMES, C_FIRST_BAD = range(6)
#: malformed lines whose numbers are kept (a warning names the first few, not thousands)
BAD_LINES_KEPT = 3
N_COUNTS = C_FIRST_BAD + BAD_LINES_KEPT
#: interface names a log may hold, and their longest (Linux: 15 characters)
MAX_NAMES = 256
NAME_BYTES = 32

#: hex digit value of every byte, -1 for the others
_HEX = np.full(256, -1, np.int64)
for _i, _c in enumerate(b"0123456789abcdef"):
    _HEX[_c] = _i
for _i, _c in enumerate(b"ABCDEF"):
    _HEX[_c] = 10 + _i

#: bytes read per block of a text log; a block is parsed at once (its frames are one piece)
BLOCK_BYTES = 2 << 20
#: the shortest line that holds a frame, ``(0) a 0#\n``: bounds the frames of a block
_MIN_LINE = 9


@numba.njit(cache=True, inline="always")
def _sp(c):  # pragma: no cover - compiled
    return c == 32 or c == 9 or c == 13


@numba.njit(cache=True, inline="always")
def _name_index(buf, a, n, names, name_len, counts):  # pragma: no cover - compiled
    """Index of the interface name ``buf[a:a+n]`` in the names table (added when new); -1 when it
    is too long or the table is full."""
    if n > NAME_BYTES:
        return -1
    for j in range(counts[C_NAMES]):
        if name_len[j] != n:
            continue
        same = True
        for q in range(n):
            if names[j, q] != buf[a + q]:
                same = False
                break
        if same:
            return j
    j = counts[C_NAMES]
    if j >= MAX_NAMES:
        return -1
    for q in range(n):
        names[j, q] = buf[a + q]
    name_len[j] = n
    counts[C_NAMES] = j + 1
    return j


@numba.njit(cache=True, nogil=True)
def _parse_block(
    buf,
    hexv,
    t_out,
    id_out,
    ext_out,
    dlc_out,
    word_out,
    rx_out,
    chan_out,
    more,
    more_off,
    names,
    name_len,
    counts,
):  # pragma: no cover
    """Parse every line of ``buf`` (which ends with a newline) in one pass; frames are packed into
    the output rows (the first 8 data bytes as a little-endian word; the bytes past 8 of a CAN FD
    frame into ``more`` from ``more_off[k]``, -1 for none; the interface's index in ``names``), the
    other line kinds counted in ``counts`` (``C_*``; the malformed lines' numbers from
    ``C_FIRST_BAD`` on, counted from ``counts[C_LINES]``). Returns the frames written. The grammar
    is the module doc's; the kernel never reads past the block's last newline."""
    n = buf.shape[0]
    i = 0
    k = 0
    line = 0
    m = 0  # bytes of ``more`` used
    while i < n:
        line += 1
        st = ST_MALFORMED
        while _sp(buf[i]):
            i += 1
        c = buf[i]
        if c == 10:
            st = ST_BLANK
        elif c == 40:  # '('
            i += 1
            # seconds: up to 11 digits (int64 ns holds 9223372036.854775807 s at most)
            sec = np.int64(0)
            nd = 0
            while 48 <= buf[i] <= 57 and nd < 12:
                sec = sec * 10 + (buf[i] - 48)
                nd += 1
                i += 1
            ok = 0 < nd <= 11 and sec <= 9_223_372_035
            frac = np.int64(0)
            nf = 0
            if ok and buf[i] == 46:  # '.': up to 9 fraction digits kept, more truncated
                i += 1
                while 48 <= buf[i] <= 57:
                    if nf < 9:
                        frac = frac * 10 + (buf[i] - 48)
                    nf += 1
                    i += 1
            if ok and buf[i] == 41 and _sp(buf[i + 1]):  # ')' and a blank
                i += 1
                for _ in range(9 - min(nf, 9)):
                    frac *= 10
                t = sec * 1_000_000_000 + frac
                while _sp(buf[i]):
                    i += 1
                n_if = 0  # interface token
                tok = i
                tok_len = 0
                while buf[i] != 10 and not _sp(buf[i]):
                    if buf[i] == 35:  # '#': no interface column, this is the frame (other tools' -L)
                        i = tok
                        n_if = 1
                        tok_len = 0
                        break
                    i += 1
                    n_if += 1
                    tok_len += 1
                while _sp(buf[i]):
                    i += 1
                cid = np.int64(0)  # id: 3 (standard) or more (extended) hex digits, at most 8
                nh = 0
                while True:
                    h = hexv[buf[i]]
                    if h < 0 or nh >= 8:
                        break
                    cid = cid * 16 + h
                    nh += 1
                    i += 1
                ext = nh > 3
                if n_if > 0 and nh > 0 and buf[i] == 35 and (ext or cid <= 0x7FF):  # '#'
                    i += 1
                    status = ST_FRAME
                    if ext and (cid & CAN_ERR_FLAG) != 0:
                        status = ST_ERROR
                    fd = False
                    good = True
                    if buf[i] == 35:  # '##': CAN FD, one flags nibble follows
                        fd = True
                        i += 1
                        if hexv[buf[i]] < 0:
                            good = False
                        else:
                            i += 1
                    nb = 0
                    w = np.uint64(0)
                    m0 = m
                    if good:
                        if not fd and (buf[i] == 82 or buf[i] == 114):  # 'R' / 'r': remote frame
                            i += 1
                            while 48 <= buf[i] <= 57:
                                i += 1
                            if status == ST_FRAME:
                                status = ST_REMOTE
                        else:
                            while True:
                                h1 = hexv[buf[i]]
                                if h1 < 0:
                                    break
                                h2 = hexv[buf[i + 1]]
                                if h2 < 0:  # an odd number of hex digits
                                    good = False
                                    break
                                if nb < 8:
                                    w |= np.uint64(h1 * 16 + h2) << np.uint64(8 * nb)
                                elif nb < 64:
                                    more[m] = h1 * 16 + h2
                                    m += 1
                                nb += 1
                                i += 2
                            if nb > 64 or (not fd and nb > 8):
                                good = False
                            if good and not fd and buf[i] == 95:  # '_<dlc>' (python-can len8_dlc)
                                i += 1
                                if hexv[buf[i]] < 0:
                                    good = False
                                else:
                                    i += 1
                    rx = True
                    if good:  # optional direction token (R / T) and trailing blanks
                        c = buf[i]
                        if c != 10 and not _sp(c):
                            good = False
                        while _sp(buf[i]):
                            i += 1
                        c = buf[i]
                        if good and c != 10:
                            if c == 84 or c == 116:  # 'T'
                                rx = False
                            elif c != 82 and c != 114:
                                good = False
                            i += 1
                            while _sp(buf[i]):
                                i += 1
                            if buf[i] != 10:
                                good = False
                    ch = 0
                    if good and status == ST_FRAME:
                        ch = _name_index(buf, tok, tok_len, names, name_len, counts)
                        if ch < 0:
                            good = False
                    if good:
                        st = status
                        if status == ST_FRAME:
                            t_out[k] = t
                            id_out[k] = cid & CAN_EFF_MASK
                            ext_out[k] = ext
                            dlc_out[k] = nb
                            word_out[k] = w
                            rx_out[k] = rx
                            chan_out[k] = ch
                            more_off[k] = m0 if nb > 8 else -1
                            k += 1
                    if not good or status != ST_FRAME:
                        m = m0  # bytes of a line that is not kept
        while buf[i] != 10:  # the rest of the line
            i += 1
        i += 1
        if st == ST_ERROR:
            counts[C_ERROR] += 1
        elif st == ST_REMOTE:
            counts[C_REMOTE] += 1
        elif st == ST_MALFORMED:
            if counts[C_MALFORMED] < BAD_LINES_KEPT:
                counts[C_FIRST_BAD + counts[C_MALFORMED]] = counts[C_LINES] + line
            counts[C_MALFORMED] += 1
    counts[C_LINES] += line
    return k


class _Names:
    """The interface names of one log, in order of first appearance (the kernel adds to them)."""

    def __init__(self) -> None:
        self.table = np.zeros((MAX_NAMES, NAME_BYTES), np.uint8)
        self.length = np.zeros(MAX_NAMES, np.int64)
        self._names: tuple[str, ...] = ()

    def names(self, n: int) -> tuple[str, ...]:
        if len(self._names) != n:
            self._names = tuple(
                bytes(self.table[j, : self.length[j]]).decode("ascii", "replace") for j in range(n)
            )
        return self._names


def _parse_lines(buf: np.ndarray, counts: np.ndarray, names: _Names) -> FrameBatch:
    """The frames of ``buf`` (complete lines, ending with a newline), in file order."""
    cap = buf.shape[0] // _MIN_LINE + 1
    t = np.empty(cap, np.int64)
    cid = np.empty(cap, np.uint32)
    ext = np.empty(cap, np.bool_)
    dlc = np.empty(cap, np.uint8)
    words = np.empty(cap, np.uint64)
    rx = np.empty(cap, np.bool_)
    chan = np.empty(cap, np.uint16)
    more_off = np.empty(cap, np.int64)
    more = np.empty(buf.shape[0] // 2 + MAX_DATA, np.uint8)  # untouched pages cost nothing
    if buf.flags.writeable:  # one signature (read-only, as a bytes buffer gives it): one compilation
        buf = buf.view()
        buf.flags.writeable = False
    k = 0
    if buf.size:
        k = _parse_block(
            buf, _HEX, t, cid, ext, dlc, words, rx, chan, more, more_off, names.table, names.length, counts
        )
    # copies: the capacity's unused pages are released with the arrays
    data = words[:k].view(np.uint8).reshape(k, CLASSIC_DATA)
    lens = dlc[:k]
    fd = np.flatnonzero(more_off[:k] >= 0)
    if fd.size:  # CAN FD frames: the batch as wide as its longest frame
        width = data_width(int(lens.max()))
        wide = np.zeros((k, width), np.uint8)
        wide[:, :CLASSIC_DATA] = data
        for i in fd.tolist():
            n = int(lens[i]) - CLASSIC_DATA
            o = int(more_off[i])
            wide[i, CLASSIC_DATA : CLASSIC_DATA + n] = more[o : o + n]
        data = wide
    return FrameBatch(
        t_ns=t[:k].copy(),
        can_id=cid[:k].copy(),
        is_extended=ext[:k].copy(),
        dlc=lens.copy(),
        data=data.copy(),
        is_rx=rx[:k].copy(),
        channel=chan[:k].copy(),
        channels=names.names(int(counts[C_NAMES])) or ("",),
    )


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
        malformed_at: 1-based numbers of the first :data:`BAD_LINES_KEPT` malformed lines.
    """

    frames: FrameBatch
    lines: int
    error_frames: int
    remote_frames: int
    malformed_lines: int
    truncated_last_line: int
    first_malformed_line: int
    malformed_at: tuple[int, ...] = ()


class CandumpBlocks:
    """Parses candump ``-L`` text fed in pieces of any size (a file read block by block, a gzip
    stream): :meth:`feed` returns the frames of the complete lines so far (file order), :meth:`end`
    those of a last line without newline (none: such a line is a log cut while being written, it
    is counted as truncated, see the module doc). The counts accumulate in :attr:`counts` (``C_*``)
    and :attr:`truncated_last_line`."""

    def __init__(self) -> None:
        self.counts = np.zeros(N_COUNTS, np.int64)
        self.names = _Names()
        self.truncated_last_line = 0
        self.cut_bytes = 0  # bytes of the cut last line (not parsed)
        self._carry = b""

    def feed(self, piece: bytes | bytearray | memoryview) -> FrameBatch:
        data = piece if isinstance(piece, bytes) else bytes(piece)
        cut = data.rfind(b"\n")
        if cut < 0:
            self._carry += data
            return FrameBatch.empty()
        if self._carry:
            block = np.frombuffer(self._carry + data[: cut + 1], np.uint8)
        else:
            block = np.frombuffer(data, np.uint8, count=cut + 1)
        self._carry = data[cut + 1 :]
        return _parse_lines(block, self.counts, self.names)

    def read_file(self, fh: io.BufferedIOBase, block_bytes: int = BLOCK_BYTES) -> Iterator[FrameBatch]:
        """The frames of an open file, block by block: each block is read into one reused buffer
        behind the cut line of the block before (no copy of the text), then :meth:`end`."""
        buf = bytearray(block_bytes + 4096)
        carry = 0
        while True:
            if len(buf) - carry < block_bytes:  # a line longer than the spare room: grow
                buf.extend(bytes(block_bytes + carry - len(buf) + 4096))
            n = fh.readinto(memoryview(buf)[carry : carry + block_bytes])
            if not n:
                break
            end = carry + n
            cut = buf.rfind(b"\n", 0, end)
            if cut < 0:
                carry = end
                continue
            yield _parse_lines(np.frombuffer(buf, np.uint8, count=cut + 1), self.counts, self.names)
            rest = end - (cut + 1)
            buf[:rest] = buf[cut + 1 : end]
            carry = rest
        self._carry = bytes(buf[:carry])
        yield self.end()

    def end(self) -> FrameBatch:
        """The log ended: a last line without newline is counted as truncated unless it is blank
        (its frame, if it parses, is not used: its payload may be cut)."""
        rest, self._carry = self._carry, b""
        if rest:
            self.counts[C_LINES] += 1
            if rest.strip(b" \t\r"):
                self.truncated_last_line = 1
                self.cut_bytes = len(rest)
        return FrameBatch.empty()

    def result(self, frames: FrameBatch) -> CandumpParse:
        c = self.counts
        return CandumpParse(
            frames=frames,
            lines=int(c[C_LINES]),
            error_frames=int(c[C_ERROR]),
            remote_frames=int(c[C_REMOTE]),
            malformed_lines=int(c[C_MALFORMED]),
            truncated_last_line=self.truncated_last_line,
            first_malformed_line=int(c[C_FIRST_BAD]),
            malformed_at=self.malformed_at,
        )

    @property
    def malformed_at(self) -> tuple[int, ...]:
        """1-based numbers of the first :data:`BAD_LINES_KEPT` malformed lines so far."""
        kept = self.counts[C_FIRST_BAD : C_FIRST_BAD + min(BAD_LINES_KEPT, int(self.counts[C_MALFORMED]))]
        return tuple(int(x) for x in kept)


def parse_candump_bytes(raw: bytes | bytearray | memoryview) -> CandumpParse:
    """Parse the bytes of a candump ``-L`` log (see the module doc). Never raises on bad lines."""
    p = CandumpBlocks()
    frames = p.feed(raw)
    p.end()
    return p.result(frames)


def looks_like_candump(head: bytes) -> bool:
    """Content sniffing: does the first non-blank line of ``head`` parse as a candump ``-L`` line?"""
    for line in head.splitlines():
        if line.strip():
            p = parse_candump_bytes(line.rstrip(b"\r\n") + b"\n")
            return len(p.frames) + p.error_frames + p.remote_frames == 1
    return False


_HEX_UPPER = np.frombuffer(b"0123456789ABCDEF", np.uint8).copy()


@numba.njit(cache=True, nogil=True)
def _format_lines(t, ndec, names, name_len, chan, ids, ext, dlc, data, rx, hexd, out):  # pragma: no cover
    """The candump lines of the frames into ``out`` (module doc of :func:`format_candump`);
    returns the bytes written."""
    o = 0
    digits = np.empty(24, np.uint8)
    div = 1000 if ndec == 6 else 1
    for i in range(t.shape[0]):
        sec = t[i] // 1_000_000_000
        frac = (t[i] % 1_000_000_000) // div
        out[o] = 40  # '('
        o += 1
        k = 0
        while True:
            digits[k] = 48 + sec % 10
            sec //= 10
            k += 1
            if sec == 0:
                break
        for j in range(k - 1, -1, -1):
            out[o] = digits[j]
            o += 1
        out[o] = 46  # '.'
        o += 1
        for j in range(ndec - 1, -1, -1):
            out[o + j] = 48 + frac % 10
            frac //= 10
        o += ndec
        out[o] = 41  # ')'
        out[o + 1] = 32
        o += 2
        c = chan[i]
        for j in range(name_len[c]):
            out[o] = names[c, j]
            o += 1
        out[o] = 32
        o += 1
        nh = 8 if ext[i] else 3
        v = ids[i]
        for j in range(nh - 1, -1, -1):
            out[o + j] = hexd[v & 15]
            v >>= 4
        o += nh
        out[o] = 35  # '#'
        o += 1
        d = dlc[i]
        if d > 8:
            out[o] = 35
            out[o + 1] = 48  # '##0': CAN FD, flags 0
            o += 2
        for j in range(d):
            b = data[i, j]
            out[o] = hexd[b >> 4]
            out[o + 1] = hexd[b & 15]
            o += 2
        if not rx[i]:
            out[o] = 32
            out[o + 1] = 84  # ' T'
            o += 2
        out[o] = 10
        o += 1
    return o


def candump_decimals(frames: FrameBatch) -> int:
    """Fraction digits of the timestamps: 6 when every one is a whole microsecond, else 9."""
    return 6 if np.all(np.asarray(frames.t_ns, dtype=np.int64) % 1000 == 0) else 9


def format_candump_bytes(frames: FrameBatch, channel: str = "vcan0", decimals: int | None = None) -> bytes:
    """The candump ``-L`` text of ``frames`` as bytes (rx frames plain; frames sent by lde get a
    `` T`` flag). Each frame's interface is its channel name; ``channel`` names the frames whose
    channel is not named (``""``). Timestamps with ``decimals`` fraction digits (6 or 9; default
    :func:`candump_decimals`: 6 when every one is a whole microsecond, else 9). Frames with
    ``dlc > 8`` are written as CAN FD (``##0``, flags 0) with all their bytes.

    Raises:
        LogFormatError: a negative timestamp.
        ValueError: ``decimals`` not 6 or 9, or 6 for a timestamp that is not a whole microsecond,
            or a channel name that is not one candump token of at most 32 ASCII characters.
    """
    n = len(frames)
    if n == 0:
        return b""
    t = np.asarray(frames.t_ns, dtype=np.int64)
    if np.any(t < 0):
        raise LogFormatError("candump logs cannot hold negative timestamps")
    ndec = candump_decimals(frames) if decimals is None else decimals
    if ndec not in (6, 9) or (ndec == 6 and np.any(t % 1000 != 0)):
        raise ValueError(f"candump timestamps with {decimals} decimals: need 9, or 6 for whole microseconds")
    labels = [c or channel for c in frames.channels]
    table = np.zeros((len(labels), NAME_BYTES), np.uint8)
    lens = np.zeros(len(labels), np.int64)
    for j, name in enumerate(labels):
        raw = name.encode("ascii", "replace")
        if not raw or len(raw) > NAME_BYTES or any(b in b" \t\r\n#()" for b in raw):
            raise ValueError(f"channel name {name!r} cannot be a candump interface column")
        table[j, : len(raw)] = np.frombuffer(raw, np.uint8)
        lens[j] = len(raw)
    data = frames.data
    width = 2 + 20 + 1 + ndec + 2 + int(lens.max()) + 1 + 8 + 3 + 2 * data.shape[1] + 2 + 1
    out = np.empty(n * width, np.uint8)
    k = _format_lines(
        t,
        ndec,
        table,
        lens,
        frames.channel,
        frames.can_id.astype(np.int64),
        frames.is_extended,
        np.minimum(frames.dlc, data.shape[1]),
        data,
        frames.is_rx,
        _HEX_UPPER,
        out,
    )
    return out[:k].tobytes()


def format_candump(frames: FrameBatch, channel: str = "vcan0") -> str:
    """:func:`format_candump_bytes` as text."""
    return format_candump_bytes(frames, channel).decode("ascii")


def write_candump(path: str | Path, frames: FrameBatch, channel: str = "vcan0") -> None:
    """Write ``frames`` as a candump ``-L`` log (see :func:`format_candump_bytes`; ``channel`` names
    the frames whose channel is not named)."""
    try:
        Path(path).write_bytes(format_candump_bytes(frames, channel))
    except OSError as exc:
        raise LogFormatError(f"{path}: cannot write: {exc}") from exc
