"""Log readers and writers: candump ``-L``, MCAP (raw CAN channels + JSON channels), python-can formats.

Two ways to read a log, both by format (:func:`detect_format`: ``.mcap``; ``.log``/``.candump``/
``.txt`` and unknown suffixes sniffed for candump text or the MCAP magic; ASC, BLF, TRC, CSV, ...
through python-can):

* :func:`open_log` streams it: a :class:`LogStream` yields its frames in time order in pieces of
  at most ``chunk_frames`` (candump text block by block, MCAP chunk by chunk, python-can formats in
  batches of messages), so memory does not grow with the log's length. Text and python-can logs
  are put in time order within a window (:class:`lde.io.stream.Reorder`): a frame more than
  ``reorder_window_ns`` behind a frame before it in the file is skipped and counted
  (``ReadStats.late_frames``). MCAP files are merged exactly by their chunks' time ranges.
* :func:`read_log` reads all of it into one :class:`LogData` whose ``frames`` are stably sorted by
  time (any disorder).

A gzip-compressed log of any of these formats (``x.log.gz``, ``x.asc.gz``, ``x.mcap.gz``, or gzip
content under the plain suffix) is read the same way: its format comes from the suffix before
``.gz`` and the decompressed content (format name ``"<format>.gz"``); candump text is decompressed
and parsed piece by piece, the other formats are read from a decompressed temporary copy (so that
every python-can reader and the MCAP reader work, whatever the file name). A gzip stream cut short
keeps what decompressed and counts a cut tail like an uncompressed one. Unreadable, corrupt, empty
or non-CAN files raise :class:`~lde.errors.LogFormatError` with a one-line message; skipped frames
(error, remote, malformed lines, a truncated last line, late frames) are counted in
:class:`ReadStats`.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from lde.can.frames import FrameBatch
from lde.errors import LogFormatError
from lde.io.candump import (
    BLOCK_BYTES,
    C_ERROR,
    C_FIRST_BAD,
    C_LINES,
    C_MALFORMED,
    C_REMOTE,
    CandumpBlocks,
    format_candump,
    looks_like_candump,
    parse_candump_bytes,
    write_candump,
)
from lde.io.ending import FileEnd, blf_end, text_end
from lde.io.gz import GZ, GZIP_MAGIC, gunzip_head, gunzip_pieces
from lde.io.mcap_cdr import CAN_SCHEMA_NAME, CAN_SCHEMA_TEXT, TOPIC_RX, TOPIC_TX, can_payload, can_payloads
from lde.io.mcap_read import (
    McapData,
    McapLog,
    TopicInfo,
    can_counts,
    check_can_channel,
    json_wanted,
    read_mcap,
)
from lde.io.mcap_write import McapWriter
from lde.io.pycan import PycanReader, pycan_suffixes
from lde.io.stream import CHUNK_FRAMES, REORDER_WINDOW_NS, Reorder, split

__all__ = [
    "FileEnd",
    "LogData",
    "LogStream",
    "ReadStats",
    "describe_skipped",
    "open_log",
    "read_log",
    "detect_format",
    "write_candump",
    "format_candump",
    "parse_candump_bytes",
    "McapWriter",
    "McapLog",
    "McapData",
    "TopicInfo",
    "read_mcap",
    "CAN_SCHEMA_NAME",
    "CAN_SCHEMA_TEXT",
    "can_payload",
    "can_payloads",
    "TOPIC_RX",
    "TOPIC_TX",
    "CHUNK_FRAMES",
    "REORDER_WINDOW_NS",
]

CANDUMP_SUFFIXES = {".log", ".candump", ".txt"}
#: python-can formats that are text, line by line (a cut last line is left out and reported)
PYCAN_TEXT = {"asc", "trc", "csv"}
MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass(frozen=True)
class ReadStats:
    """What a reader skipped. All counts are frames or lines.

    Attributes:
        frames: data frames returned.
        error_frames: error frames skipped.
        remote_frames: remote frames skipped.
        malformed_lines: candump lines that did not parse (first one: ``first_malformed_line``;
            the first few: ``malformed_at``, 1-based line numbers).
        truncated_last_line: 1 if the last line of a text log (or the last record of a binary
            log: an MCAP recording or a BLF file cut by a crash) was cut off and skipped; where it
            is comes from :attr:`LogStream.end`. The name is kept for the text logs it began with.
        bad_messages: MCAP CAN-channel messages of the wrong size/encoding (skipped); the byte
            offsets of the chunks holding the first few: ``bad_messages_at``.
        late_frames: frames more than the reorder window behind a frame before them in the file
            (a streamed text or python-can log; skipped: see :func:`open_log`).
    """

    frames: int
    error_frames: int = 0
    remote_frames: int = 0
    malformed_lines: int = 0
    truncated_last_line: int = 0
    first_malformed_line: int = 0
    bad_messages: int = 0
    late_frames: int = 0
    malformed_at: tuple[int, ...] = ()
    bad_messages_at: tuple[int, ...] = ()

    @property
    def skipped(self) -> int:
        return (
            self.error_frames
            + self.remote_frames
            + self.malformed_lines
            + self.truncated_last_line
            + self.bad_messages
            + self.late_frames
        )


@dataclass
class LogData:
    """A log read into columns (:func:`read_log`).

    Attributes:
        path: the file.
        format: ``"candump"``, ``"mcap"`` or the python-can suffix (``"asc"``, ``"blf"``, ...).
        frames: CAN frames, stably sorted by ``t_ns`` (the log's own time base).
        stats: skipped-frame counts.
        mcap: for MCAP files, the topics, the log times of the non-CAN channels and any JSON
            channels asked for; else None.
    """

    path: Path
    format: str
    frames: FrameBatch
    stats: ReadStats
    mcap: McapData | None = field(default=None)


def detect_format(path: str | Path) -> str:
    """``"mcap"``, ``"candump"`` or a python-can suffix such as ``"asc"``; by suffix, then content.
    A gzip-compressed log (``.gz`` or gzip content): the format of its content plus ``".gz"``
    (``"candump.gz"``, ``"asc.gz"``, ...), by the suffix before ``.gz``.

    Raises:
        LogFormatError: missing/unreadable/empty file, or a format nobody reads.
    """
    p = Path(path)
    try:
        with p.open("rb") as fh:
            head = fh.read(4096)
    except FileNotFoundError as exc:
        raise LogFormatError(f"{p}: no such file") from exc
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from exc
    if not head:
        raise LogFormatError(f"{p}: empty file")
    suffix = p.suffix.lower()
    if suffix == GZ or head.startswith(GZIP_MAGIC):
        inner = Path(p.stem).suffix.lower() if suffix == GZ else suffix
        return _classify(p, inner, gunzip_head(p, 4096), compressed=True) + GZ
    return _classify(p, suffix, head)


def _classify(p: Path, suffix: str, head: bytes, compressed: bool = False) -> str:
    """The format of a log from its (inner) suffix and the first bytes of its content."""
    what = "gzip-compressed " if compressed else ""
    if not head:
        raise LogFormatError(f"{p}: empty {what}file")
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if suffix == ".mcap":
        raise LogFormatError(f"{p}: not an MCAP file (no MCAP magic)")
    if suffix in CANDUMP_SUFFIXES:  # decided without python-can's reader list (its import: ~60 ms)
        if looks_like_candump(head):
            return "candump"
        raise LogFormatError(f"{p}: not a {what}candump -L log (first line does not parse)")
    pycan = pycan_suffixes() - {".mcap"}
    if suffix not in pycan and looks_like_candump(head):
        return "candump"
    if suffix in pycan:
        return suffix.lstrip(".")
    raise LogFormatError(
        f"{p}: unknown {what}log format (suffix {suffix or 'none'!r}; readable: .mcap, candump -L text, "
        f"{', '.join(sorted(pycan))}, each also gzip-compressed as <suffix>.gz)"
    )


# ----------------------------------------------------------------------------- streaming
class LogStream:
    """A log opened for reading in time order (:func:`open_log`). Iterate it once for its frames
    (pieces of at most ``chunk_frames``); :attr:`stats` is final once the iteration has ended.
    Use as a context manager or call :meth:`close`.

    Attributes:
        path, format: the file and its format (as :class:`LogData`).
        mcap: the open MCAP file (topics, metadata, :meth:`McapLog.times`, :meth:`McapLog.json`)
            for MCAP logs, else None.
        frames_read: frames yielded so far.
        last_t_ns: log time of the latest frame yielded so far [ns] (None: none yet).
    """

    def __init__(
        self,
        path: Path,
        fmt: str,
        pieces: Iterator[FrameBatch],
        stats: Callable[[], ReadStats],
        mcap: McapLog | None = None,
        cleanup: Callable[[], None] | None = None,
        skip_tx: bool = False,
        end: Callable[[], FileEnd | None] | None = None,
    ) -> None:
        self.path = path
        self.format = fmt
        self.mcap = mcap
        self.frames_read = 0
        self.last_t_ns: int | None = None
        self._end = end
        self._pieces = pieces
        self._stats = stats
        self._cleanup = cleanup
        self._skip_tx = skip_tx

    def __iter__(self) -> Iterator[FrameBatch]:
        for piece in self._pieces:
            if len(piece):
                self.frames_read += len(piece)
                t = int(piece.t_ns[-1])  # pieces are in time order
                self.last_t_ns = t if self.last_t_ns is None else max(self.last_t_ns, t)
                yield piece
        try:
            _require_frames(self.path, self.format, self.frames_read, self.stats, self.mcap, self.end)
        except LogFormatError as exc:
            e = self.end
            if e is None or not e.lossy:
                raise
            where = "cut short" if e.cut else "not closed by its writer"
            raise LogFormatError(
                f"{exc}; the file is {where} (complete records end at byte {e.offset} of {e.size})"
            ) from exc

    @property
    def stats(self) -> ReadStats:
        return self._stats()

    @property
    def end(self) -> FileEnd | None:
        """How the file ends (:class:`lde.io.ending.FileEnd`; final once the iteration has
        ended), None for a format that cannot tell."""
        return self._end() if self._end is not None else None

    def close(self) -> None:
        if self.mcap is not None:
            self.mcap.close()
        if self._cleanup is not None:
            self._cleanup()
            self._cleanup = None

    def __enter__(self) -> LogStream:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_log(
    path: str | Path,
    *,
    fmt: str | None = None,
    skip_tx: bool = False,
    chunk_frames: int = CHUNK_FRAMES,
    reorder_window_ns: int | None = REORDER_WINDOW_NS,
    validate_crcs: bool = True,
) -> LogStream:
    """Open a log for reading in time order (module doc); ``fmt`` as :func:`detect_format` names
    it. ``skip_tx``: MCAP chunks that hold only lde's own ``/can/tx`` frames stay compressed (a
    replay does not use them; they are still counted in ``topics``). ``reorder_window_ns`` None:
    a text or python-can log is sorted whole (its frames are held until the end).

    Raises:
        LogFormatError: unreadable, corrupt, empty or non-CAN file (here or while iterating: a
            corrupt chunk, a log without a single data frame).
    """
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt.endswith(GZ):
        return _open_gzip(p, fmt, skip_tx, chunk_frames, reorder_window_ns, validate_crcs)
    if fmt == "mcap":
        m = McapLog(p, validate_crcs=validate_crcs)
        try:
            check_can_channel(m)
            _require_rx(m, skip_tx)
        except LogFormatError:
            m.close()
            raise

        def mcap_stats() -> ReadStats:
            return ReadStats(
                frames=0,
                bad_messages=m.bad_can_messages,
                truncated_last_line=int(m.truncated),
                bad_messages_at=tuple(m.bad_chunks),
            )

        it = m.iter_frames(tx=not skip_tx, chunk_frames=chunk_frames)
        stream = LogStream(p, "mcap", it, mcap_stats, mcap=m, skip_tx=skip_tx, end=lambda: _mcap_end(m))
        stream._stats = lambda: _with_frames(mcap_stats(), stream.frames_read)
        return stream
    reorder = Reorder(reorder_window_ns)
    if fmt == "candump":
        parser = CandumpBlocks()
        pieces = _candump_file_pieces(p, parser)
        size = p.stat().st_size
        stream = LogStream(
            p,
            fmt,
            _ordered(pieces, reorder, chunk_frames),
            lambda: ReadStats(0),
            end=lambda: _candump_end(parser, size),
        )
        stream._stats = lambda: _candump_stats(parser, reorder, stream.frames_read)
        return stream
    end = _pycan_end(p, fmt)
    reader = PycanReader(
        p,
        limit=end.offset if end is not None and end.cut and fmt in PYCAN_TEXT else None,
        text=fmt in PYCAN_TEXT,
    )
    stream = LogStream(
        p, fmt, _ordered(iter(reader), reorder, chunk_frames), lambda: ReadStats(0), end=lambda: end
    )
    stream._stats = lambda: ReadStats(
        frames=stream.frames_read,
        error_frames=reader.error_frames,
        remote_frames=reader.remote_frames,
        truncated_last_line=int(end is not None and end.cut),
        late_frames=reorder.late,
    )
    return stream


def _mcap_end(m: McapLog) -> FileEnd:
    return FileEnd(m.complete, m.truncated, m.end_offset, m.size, what="record")


def _candump_end(parser: CandumpBlocks, size: int, compressed: bool = False) -> FileEnd:
    cut = bool(parser.truncated_last_line)
    lines = int(parser.counts[C_LINES]) - int(cut)
    return FileEnd(None, cut, size - parser.cut_bytes, size, lines, "line", compressed)


def _pycan_end(p: Path, fmt: str) -> FileEnd | None:
    """How a python-can log ends (ASC, TRC, CSV: its last line; BLF: its objects), else None."""
    try:
        if fmt in PYCAN_TEXT:
            return text_end(p, asc=fmt == "asc")
        if fmt == "blf":
            return blf_end(p)
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from exc
    return None


def _with_frames(s: ReadStats, n: int) -> ReadStats:
    return ReadStats(**{**s.__dict__, "frames": n})


def _candump_stats(parser: CandumpBlocks, reorder: Reorder, n: int) -> ReadStats:
    c = parser.counts
    return ReadStats(
        frames=n,
        error_frames=int(c[C_ERROR]),
        remote_frames=int(c[C_REMOTE]),
        malformed_lines=int(c[C_MALFORMED]),
        truncated_last_line=parser.truncated_last_line,
        first_malformed_line=int(c[C_FIRST_BAD]),
        late_frames=reorder.late,
        malformed_at=parser.malformed_at,
    )


def _candump_file_pieces(p: Path, parser: CandumpBlocks) -> Iterator[FrameBatch]:
    try:
        fh = p.open("rb")
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from exc
    with fh:
        try:
            yield from parser.read_file(fh)
        except OSError as exc:
            raise LogFormatError(f"{p}: cannot read: {exc}") from exc


class _GzState:
    """What a gzip stream gave: decompressed bytes, whether it was cut short."""

    def __init__(self) -> None:
        self.out_bytes = 0
        self.cut = False

    def end(self, parser: CandumpBlocks) -> FileEnd:
        e = _candump_end(parser, self.out_bytes, compressed=True)
        return FileEnd(not self.cut, e.cut or self.cut, e.offset, e.size, e.line, e.what, True)


def _candump_gz_pieces(
    p: Path, parser: CandumpBlocks, gz: _GzState, block_bytes: int = BLOCK_BYTES
) -> Iterator[FrameBatch]:
    buf: list[bytes] = []
    k = 0
    for piece, cut in gunzip_pieces(p):  # a cut stream ends inside a line: counted by the parser
        gz.out_bytes += len(piece)
        gz.cut = gz.cut or cut
        buf.append(piece)
        k += len(piece)
        if k >= block_bytes:
            yield parser.feed(b"".join(buf))
            buf, k = [], 0
    if buf:
        yield parser.feed(b"".join(buf))
    yield parser.end()


def _ordered(pieces: Iterable[FrameBatch], reorder: Reorder, n: int) -> Iterator[FrameBatch]:
    """Pieces in file order -> time order (within the window), at most ``n`` frames each."""
    for piece in pieces:
        yield from split(reorder.push(piece), n)
    yield from split(reorder.finish(), n)


def _require_rx(m: McapLog, skip_tx: bool) -> None:
    """LogFormatError (before anything is read) for an MCAP recording that holds only the frames
    lde itself sent, when the counts are known from the statistics and the replay skips them."""
    n_rx, n_tx = can_counts(m.topics)
    if skip_tx and n_tx > 0 and n_rx == 0:
        raise LogFormatError(
            f"{m.path}: only frames lde sent ({n_tx} on {TOPIC_TX}): no received input frames"
        )


def _require_frames(
    path: Path,
    fmt: str,
    n: int,
    stats: ReadStats,
    mcap: McapLog | McapData | None,
    end: FileEnd | None = None,
) -> None:
    """LogFormatError for a log without a single data frame (or, read with ``skip_tx``, an MCAP
    recording that holds only the frames lde itself sent)."""
    if n:
        return
    n_rx, n_tx = can_counts(mcap.topics) if mcap is not None else (0, 0)
    if n_tx > 0 and n_rx == 0:
        raise LogFormatError(f"{path}: only frames lde sent ({n_tx} on {TOPIC_TX}): no received input frames")
    raise LogFormatError(f"{path}: no CAN data frames in this {fmt} log ({_describe(stats, end)})")


def _open_gzip(
    p: Path, fmt: str, skip_tx: bool, chunk_frames: int, window: int | None, validate_crcs: bool
) -> LogStream:
    """A gzip-compressed log (``fmt`` = ``"<inner format>.gz"``): candump piece by piece, the
    others from a decompressed temporary copy named with the inner suffix (removed at close)."""
    inner = fmt[: -len(GZ)]
    if inner == "candump":
        parser = CandumpBlocks()
        reorder = Reorder(window)
        gz = _GzState()
        pieces = _candump_gz_pieces(p, parser, gz)
        stream = LogStream(
            p, fmt, _ordered(pieces, reorder, chunk_frames), lambda: ReadStats(0), end=lambda: gz.end(parser)
        )
        stream._stats = lambda: _candump_stats(parser, reorder, stream.frames_read)
        return stream
    tmp = tempfile.mkdtemp(prefix="lde-gz-")
    plain = Path(tmp) / f"log.{inner}"
    cut = False
    try:
        with plain.open("wb") as fh:
            for piece, c in gunzip_pieces(p):
                fh.write(piece)
                cut = cut or c
        inner_stream = open_log(
            plain,
            fmt=inner,
            skip_tx=skip_tx,
            chunk_frames=chunk_frames,
            reorder_window_ns=window,
            validate_crcs=validate_crcs,
        )
    except LogFormatError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        msg = str(exc).replace(str(plain), str(p))
        if cut:
            msg += " (the gzip stream is cut short)"
        raise LogFormatError(msg) from exc
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise LogFormatError(f"{p}: cannot decompress to {tmp}: {exc}") from exc

    def pieces_of() -> Iterator[FrameBatch]:
        try:
            yield from inner_stream._pieces
        except LogFormatError as exc:
            raise LogFormatError(str(exc).replace(str(plain), str(p))) from exc

    def stats() -> ReadStats:
        s = inner_stream.stats
        if cut and not s.truncated_last_line:
            s = ReadStats(**{**s.__dict__, "truncated_last_line": 1})
        return _with_frames(s, stream.frames_read)

    def cleanup() -> None:
        inner_stream.close()
        shutil.rmtree(tmp, ignore_errors=True)

    out_bytes = plain.stat().st_size

    def end() -> FileEnd:
        e = inner_stream.end
        if e is None:
            return FileEnd(not cut, cut, out_bytes, out_bytes, compressed=True)
        closed = e.closed if not cut else False
        return FileEnd(closed, e.cut or cut, e.offset, e.size, e.line, e.what, True)

    stream = LogStream(p, fmt, pieces_of(), stats, mcap=None, cleanup=cleanup, skip_tx=skip_tx, end=end)
    stream.mcap = inner_stream.mcap
    return stream


# ----------------------------------------------------------------------------- whole logs
def read_log(
    path: str | Path,
    *,
    fmt: str | None = None,
    json_topics: Iterable[str] | str | None = None,
    skip_tx: bool = False,
    json_optional: bool = False,
) -> LogData:
    """Read a whole log into a :class:`LogData` (format by :func:`detect_format` unless ``fmt``),
    its frames stably sorted by time whatever their order in the file.

    ``json_topics``, ``json_optional`` and ``skip_tx`` apply to MCAP files (see :func:`read_mcap`):
    with ``skip_tx`` the frames lde itself sent (``/can/tx``) are counted but need not be decoded.

    Raises:
        LogFormatError: unreadable, corrupt, empty or non-CAN file, or a file with no frames at all.
    """
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt in ("mcap", "mcap.gz"):
        with open_log(p, fmt=fmt, skip_tx=skip_tx) as s:
            m = s.mcap
            assert m is not None
            frames = FrameBatch.concat(list(s), sort=False)
            wanted = json_wanted(m, json_topics, json_optional)
            data = McapData(
                frames=frames,
                topics=dict(m.topics),
                times={t: m.times(t) for t in m.topics if t not in m.can_topics},
                json={t: m.json(t) for t in wanted},
                bad_can_messages=m.bad_can_messages,
                fast_path=m.fast_path,
                chunks_read=m.chunks_read,
                chunks_skipped=m.chunks_skipped,
                truncated=m.truncated,
                metadata=m.metadata,
            )
            return LogData(p, fmt, frames, s.stats, mcap=data)
    with open_log(p, fmt=fmt, reorder_window_ns=None) as s:
        frames = FrameBatch.concat(list(s), sort=False)
        return LogData(p, fmt, frames, s.stats)


def _describe(s: ReadStats, end: FileEnd | None = None) -> str:
    return ", ".join([f"{s.frames} frames", *describe_skipped(s, end)])


def _plural(n: int, word: str) -> str:
    return f"{n} {word}{'' if n == 1 else 's'}"


def _first_at(where: Sequence[int], n: int, prep: str, one: str, many: str) -> str:
    """`` (first at lines 12, 57, 58)``: where the first few of ``n`` bad records are (``one`` /
    ``many``: the words before one position / several)."""
    if not where:
        return ""
    first = "" if len(where) == n else "first "
    return f" ({first}{prep} {one if len(where) == 1 else many} {', '.join(str(w) for w in where)})"


def describe_skipped(s: ReadStats, end: FileEnd | None) -> list[str]:
    """What a reader skipped, in words, each with where it is in the file: the line numbers of
    malformed lines (text logs), the byte offsets of bad records (binary logs) and the cut last
    line or record (``end``: :attr:`LogStream.end`; None: not known). Empty when nothing was
    skipped."""
    out = []
    if s.error_frames:
        out.append(_plural(s.error_frames, "error frame"))
    if s.remote_frames:
        out.append(_plural(s.remote_frames, "remote frame"))
    if s.malformed_lines:
        at = s.malformed_at or ((s.first_malformed_line,) if s.first_malformed_line else ())
        where = _first_at(at, s.malformed_lines, "at", "line", "lines")
        out.append(_plural(s.malformed_lines, "malformed line") + where)
    if s.truncated_last_line:
        out.append(_cut_record(end))
    if s.bad_messages:
        out.append(
            _plural(s.bad_messages, "CAN message")
            + " of the wrong size or encoding"
            + _first_at(s.bad_messages_at, s.bad_messages, "in", "the chunk at byte", "the chunks at bytes")
        )
    if s.late_frames:
        out.append(_plural(s.late_frames, "late frame"))
    return out


def _cut_record(end: FileEnd | None) -> str:
    """The record a file ends inside of (skipped), and where."""
    if end is None or not end.cut:
        return "the cut last record"
    de = " decompressed" if end.compressed else ""
    if end.what == "line":
        return f"the cut last line (line {end.line + 1}, from byte {end.offset}{de}, no newline)"
    what = end.what or "record"
    return f"the cut last {what} (bytes {end.offset}-{end.size}{de}, cut short)"
