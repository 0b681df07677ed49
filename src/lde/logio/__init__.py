"""Log readers and writers: candump ``-L``, MCAP (raw CAN channels + JSON channels), python-can formats.

:func:`read_log` picks the format by suffix (``.mcap``; ``.log``/``.candump``/``.txt`` and unknown
suffixes sniffed for candump text or the MCAP magic; ASC, BLF, TRC, CSV, ... through python-can) and
returns a :class:`LogData` whose ``frames`` are stably sorted by time. A gzip-compressed log of any
of these formats (``x.log.gz``, ``x.asc.gz``, ``x.mcap.gz``, or gzip content under the plain suffix)
is read the same way: its format comes from the suffix before ``.gz`` and the decompressed content
(format name ``"<format>.gz"``); candump text is parsed from the decompressed bytes in memory, the
other formats from a decompressed temporary copy (so that every python-can reader and the MCAP reader
work, whatever the file name). A gzip stream cut short (a log still being written, a crash) keeps
what decompressed and counts a cut tail like an uncompressed one. Unreadable, corrupt, empty or
non-CAN files raise :class:`~lde.errors.LogFormatError` with a one-line message; skipped frames
(error, remote, malformed lines, a truncated last line) are counted in :class:`ReadStats`.
"""

from __future__ import annotations

import tempfile
import zlib
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..errors import LogFormatError
from ..frames import FrameBatch
from .candump import format_candump, looks_like_candump, parse_candump_bytes, write_candump
from .mcapfile import (
    CAN_SCHEMA_NAME,
    CAN_SCHEMA_TEXT,
    TOPIC_RX,
    TOPIC_TX,
    McapData,
    McapWriter,
    TopicInfo,
    can_payload,
    can_payloads,
    read_mcap,
)
from .pycan import pycan_suffixes, read_pycan

__all__ = [
    "LogData",
    "ReadStats",
    "read_log",
    "detect_format",
    "write_candump",
    "format_candump",
    "parse_candump_bytes",
    "McapWriter",
    "McapData",
    "TopicInfo",
    "read_mcap",
    "CAN_SCHEMA_NAME",
    "CAN_SCHEMA_TEXT",
    "can_payload",
    "can_payloads",
    "TOPIC_RX",
    "TOPIC_TX",
]

CANDUMP_SUFFIXES = {".log", ".candump", ".txt"}
MCAP_MAGIC = b"\x89MCAP0\r\n"
GZIP_MAGIC = b"\x1f\x8b"
GZ = ".gz"


@dataclass(frozen=True)
class ReadStats:
    """What a reader skipped. All counts are frames or lines.

    Attributes:
        frames: data frames returned.
        error_frames: error frames skipped.
        remote_frames: remote frames skipped.
        malformed_lines: candump lines that did not parse (first one: ``first_malformed_line``).
        truncated_last_line: 1 if the last line of a text log (or the last record of an MCAP file
            without summary: a recording cut by a crash) was cut off and skipped.
        bad_messages: MCAP CAN-channel messages of the wrong size/encoding (skipped).
    """

    frames: int
    error_frames: int = 0
    remote_frames: int = 0
    malformed_lines: int = 0
    truncated_last_line: int = 0
    first_malformed_line: int = 0
    bad_messages: int = 0

    @property
    def skipped(self) -> int:
        return (
            self.error_frames
            + self.remote_frames
            + self.malformed_lines
            + self.truncated_last_line
            + self.bad_messages
        )


@dataclass
class LogData:
    """A log read into columns.

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
        return _classify(p, inner, _gunzip_head(p, 4096), compressed=True) + GZ
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
    if suffix in CANDUMP_SUFFIXES or suffix not in _pycan_suffixes():
        if looks_like_candump(head):
            return "candump"
        if suffix in CANDUMP_SUFFIXES:
            raise LogFormatError(f"{p}: not a {what}candump -L log (first line does not parse)")
    if suffix in _pycan_suffixes():
        return suffix.lstrip(".")
    raise LogFormatError(
        f"{p}: unknown {what}log format (suffix {suffix or 'none'!r}; readable: .mcap, candump -L text, "
        f"{', '.join(sorted(_pycan_suffixes()))}, each also gzip-compressed as <suffix>.gz)"
    )


def _gunzip_chunks(p: Path, max_bytes: int | None = None) -> Iterable[tuple[bytes, bool]]:
    """Decompressed pieces of the gzip file ``p`` (every member of a multi-member file), each with
    a flag that is True on the last piece when the stream was cut short. Stops after ``max_bytes``.

    Raises:
        LogFormatError: unreadable file or data that is not gzip.
    """
    d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
    fed = False  # the current member's decompressor has had input
    out_n = 0
    try:
        with p.open("rb") as fh:
            while block := fh.read(1 << 20):
                while block:
                    try:
                        piece = d.decompress(block)
                    except zlib.error as exc:
                        raise LogFormatError(f"{p}: corrupt gzip data ({exc})") from exc
                    fed = True
                    out_n += len(piece)
                    yield piece, False
                    if max_bytes is not None and out_n >= max_bytes:
                        return
                    block = b""
                    if d.eof:  # the member ended: another one may follow
                        block = d.unused_data
                        if block and not block.startswith(GZIP_MAGIC[: len(block)]):
                            return  # trailing bytes after the last member: ignored, like gzip -d
                        d = zlib.decompressobj(wbits=16 + zlib.MAX_WBITS)
                        fed = False
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from exc
    yield d.flush(), fed and not d.eof


def _gunzip_head(p: Path, n: int) -> bytes:
    head = b"".join(piece for piece, _ in _gunzip_chunks(p, n))
    return head[:n]


def _gunzip(p: Path) -> tuple[bytes, bool]:
    """The decompressed content of ``p`` and whether the gzip stream was cut short."""
    pieces, cut = [], False
    for piece, c in _gunzip_chunks(p):
        pieces.append(piece)
        cut = cut or c
    return b"".join(pieces), cut


def _pycan_suffixes() -> set[str]:

    return pycan_suffixes() - {".mcap"}


def read_log(
    path: str | Path,
    *,
    fmt: str | None = None,
    json_topics: Iterable[str] | str | None = None,
    skip_tx: bool = False,
    json_optional: bool = False,
) -> LogData:
    """Read a CAN log into a :class:`LogData` (format by :func:`detect_format` unless ``fmt``).

    ``json_topics``, ``json_optional`` and ``skip_tx`` apply to MCAP files (see :func:`read_mcap`):
    with ``skip_tx`` the frames lde itself sent (``/can/tx``) are counted but need not be decoded.

    Raises:
        LogFormatError: unreadable, corrupt, empty or non-CAN file, or a file with no frames at all.
    """
    p = Path(path)
    fmt = fmt or detect_format(p)
    if fmt.endswith(GZ):
        return _read_gzip(p, fmt, json_topics=json_topics, skip_tx=skip_tx, json_optional=json_optional)
    if fmt == "mcap":
        data = read_mcap(p, json_topics=json_topics, skip_tx=skip_tx, json_optional=json_optional)
        stats = ReadStats(
            frames=len(data.frames),
            bad_messages=data.bad_can_messages,
            truncated_last_line=int(data.truncated),
        )
        out = LogData(p, "mcap", data.frames, stats, mcap=data)
    elif fmt == "candump":
        try:
            raw = p.read_bytes()
        except OSError as exc:
            raise LogFormatError(f"{p}: cannot read: {exc}") from exc
        out = _candump_data(p, raw)
    else:
        parsed_pc = read_pycan(p)
        stats = ReadStats(
            frames=len(parsed_pc.frames),
            error_frames=parsed_pc.error_frames,
            remote_frames=parsed_pc.remote_frames,
        )
        out = LogData(p, fmt, parsed_pc.frames.sort(), stats)
    _require_frames(out)
    return out


def _candump_data(p: Path, raw: bytes, fmt: str = "candump") -> LogData:
    parsed = parse_candump_bytes(raw)
    stats = ReadStats(
        frames=len(parsed.frames),
        error_frames=parsed.error_frames,
        remote_frames=parsed.remote_frames,
        malformed_lines=parsed.malformed_lines,
        truncated_last_line=parsed.truncated_last_line,
        first_malformed_line=parsed.first_malformed_line,
    )
    return LogData(p, fmt, parsed.frames.sort(), stats)


def _require_frames(out: LogData) -> None:
    """LogFormatError for a log without a single data frame (or, read with ``skip_tx``, an MCAP
    recording that holds only the frames lde itself sent)."""
    topics = out.mcap.topics if out.mcap is not None else {}
    n_tx = topics[TOPIC_TX].count if TOPIC_TX in topics else 0
    n_rx = topics[TOPIC_RX].count if TOPIC_RX in topics else 0
    if len(out.frames) == 0 and n_tx > 0 and n_rx == 0:
        raise LogFormatError(
            f"{out.path}: only frames lde sent ({n_tx} on {TOPIC_TX}): no received input frames"
        )
    if len(out.frames) == 0:
        raise LogFormatError(
            f"{out.path}: no CAN data frames in this {out.format} log ({_describe(out.stats)})"
        )


def _read_gzip(
    p: Path,
    fmt: str,
    *,
    json_topics: Iterable[str] | str | None,
    skip_tx: bool,
    json_optional: bool,
) -> LogData:
    """A gzip-compressed log (``fmt`` = ``"<inner format>.gz"``): candump in memory, the others
    from a decompressed temporary copy named with the inner suffix."""
    inner = fmt[: -len(GZ)]
    if inner == "candump":
        raw, _cut = _gunzip(p)  # a cut stream ends inside a line: counted by the parser
        out = _candump_data(p, raw, fmt)
        _require_frames(out)
        return out
    with tempfile.TemporaryDirectory(prefix="lde-gz-") as tmp:
        plain = Path(tmp) / f"log.{inner}"
        cut = False
        try:
            with plain.open("wb") as fh:
                for piece, c in _gunzip_chunks(p):
                    fh.write(piece)
                    cut = cut or c
        except OSError as exc:
            raise LogFormatError(f"{p}: cannot decompress to {tmp}: {exc}") from exc
        try:
            out = read_log(
                plain, fmt=inner, json_topics=json_topics, skip_tx=skip_tx, json_optional=json_optional
            )
        except LogFormatError as exc:
            msg = str(exc).replace(str(plain), str(p))
            if cut:
                msg += " (the gzip stream is cut short)"
            raise LogFormatError(msg) from exc
    out.path, out.format = p, fmt
    if cut and not out.stats.truncated_last_line:
        out.stats = replace(out.stats, truncated_last_line=1)
    return out


def _describe(s: ReadStats) -> str:
    parts = [f"{s.frames} frames"]
    for name in ("error_frames", "remote_frames", "malformed_lines", "truncated_last_line", "bad_messages"):
        v = getattr(s, name)
        if v:
            parts.append(f"{v} {name.replace('_', ' ')}")
    return ", ".join(parts)
