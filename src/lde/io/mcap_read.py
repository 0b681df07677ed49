"""Reading MCAP files: the CAN frames chunk by chunk in time order, JSON channels as columns.

:class:`McapLog` opens a file and learns its layout without reading its messages:

1. the summary with the ``mcap`` library (``SeekingReader.get_summary``: schemas, channels,
   statistics, chunk indexes, metadata indexes); the metadata records with its ``iter_metadata``;
2. a file without chunk indexes (lde's compact layout, see :mod:`lde.io.mcap_write`) or without
   summary (a recording cut by a crash or a kill) is walked record header by record header: its
   schemas, channels and metadata are parsed with the ``mcap`` library's record types, its chunks
   and the message indexes after them are noted (offsets, time ranges, channels). The walk stops
   at the data end, the footer, or a record cut short (``truncated``: the cut tail is lost and
   reported). It is hand-walked because the library's ``StreamReader`` copies every chunk and
   turns every message index entry into a Python tuple (``bench/bench_mcap.py`` measures both);
3. files with messages outside chunks, or channels declared only inside chunks and no summary, are
   read with the library's per-message reader (``force_library=True`` selects it always).

:meth:`McapLog.iter_frames` then yields the frames of the CAN channels (schema
``lde_msgs/msg/CanFrame``) in time order, in pieces of at most ``chunk_frames``: chunks are taken
in the order of their start times; each is decompressed (zstd / lz4 / none, CRC checked) and a
numba kernel walks its records into frame columns; a frame is released once no chunk still to be
read can start before it. The order is exactly a stable sort by log time of all frames in file
order, and memory holds only the chunks whose time ranges overlap. Chunks known (from their
message indexes) to hold only channels nobody asked for are not decompressed: a replay leaves
lde's own ``/can/tx`` and the JSON channels compressed.

:meth:`McapLog.times` gives a channel's log times (from message indexes when every chunk of it
has one, else by walking its chunks), :meth:`McapLog.json` a JSON channel's columns
(:func:`lde.io.mcap_json.json_columns`). :func:`read_mcap` reads a whole file into a
:class:`McapData`.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import os
import struct
import zlib
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import lz4.frame as lz4frame
import numba
import numpy as np
import zstandard

from lde.can.frames import CLASSIC_DATA, MAX_DATA, FrameBatch, data_width
from lde.errors import LogFormatError
from lde.io.mcap_cdr import (
    CAN_FD_SCHEMA_NAME,
    CAN_PAYLOAD_SIZE,
    CAN_SCHEMA_NAME,
    CDR_HEADER,
    TOPIC_FD_RX,
    TOPIC_FD_TX,
    TOPIC_RX,
    TOPIC_TX,
    frames_of_fd_payloads,
    frames_of_payloads,
)
from lde.io.mcap_json import json_columns
from lde.io.mcap_write import (
    MAGIC,
    MSG_OVERHEAD,
    OP_CHANNEL,
    OP_CHUNK,
    OP_DATA_END,
    OP_FOOTER,
    OP_HEADER,
    OP_MESSAGE,
    OP_MESSAGE_INDEX,
    OP_METADATA,
    OP_SCHEMA,
)
from lde.io.stream import CHUNK_FRAMES, split, view

__all__ = ["McapLog", "McapData", "TopicInfo", "read_mcap", "can_counts"]

# what the walk kernel does with a channel's messages
W_COUNT, W_FRAME, W_TABLE, W_FD = 0, 1, 2, 3
_NO_CHANNEL = -1
#: chunks with bad CAN messages whose offsets are kept (a warning names the first few)
BAD_CHUNKS_KEPT = 3


@dataclass(frozen=True)
class TopicInfo:
    """One channel of an MCAP file: topic, encodings, schema name and message count."""

    topic: str
    channel_id: int
    message_encoding: str
    schema_name: str
    schema_encoding: str
    count: int
    #: a CAN channel of frames lde sent (``direction = tx``, or lde's ``/can/tx``)
    is_tx: bool = False

    @property
    def is_can(self) -> bool:
        return self.schema_name in (CAN_SCHEMA_NAME, CAN_FD_SCHEMA_NAME)


def can_counts(topics: dict[str, TopicInfo]) -> tuple[int, int]:
    """(received, sent) CAN frames over every CAN channel of a file."""
    rx = sum(t.count for t in topics.values() if t.is_can and not t.is_tx)
    tx = sum(t.count for t in topics.values() if t.is_can and t.is_tx)
    return rx, tx


# ----------------------------------------------------------------------------- the walk kernel
@numba.njit(cache=True, inline="always")
def _get(buf, o, nbytes):  # pragma: no cover - compiled
    v = np.uint64(0)
    for j in range(nbytes):
        v |= np.uint64(buf[o + j]) << np.uint64(8 * j)
    return v


@numba.njit(cache=True, nogil=True)
def _walk_chunk(buf, want, counts, t, cid, ext, dlc, data, rx, chan, busmap, o_chan, o_t, o_off, o_len):
    """One pass over the records of one decompressed chunk (runs without the GIL).

    Messages of channels with ``want[ch] == W_FRAME`` (classic CAN) or ``W_FD`` (CAN FD: as wide as
    ``data``) fill the frame columns (``chan``: the channel's bus, ``busmap[ch]``), ``W_TABLE`` the
    (channel, log time, offset, length) table, ``W_COUNT`` are only counted (``counts[ch]``, every
    message). ``want[ch] == -1``: a channel nobody declared. Returns (frames, table rows, bad CAN
    messages, status): status < 0 = a corrupt record stream (-4: an undeclared channel); a CAN
    message of the wrong size or byte order is counted as bad and skipped.
    """  # pragma: no cover
    n = buf.shape[0]
    i = 0
    k = 0
    m = 0
    bad = 0
    while i < n:
        if i + 9 > n:
            return k, m, bad, -1
        length = _get(buf, i + 1, 8)
        if length > np.uint64(n - i - 9):
            return k, m, bad, -2
        if buf[i] == OP_MESSAGE:
            if length < 22:
                return k, m, bad, -3
            ch = int(_get(buf, i + 9, 2))
            w = want[ch]
            if w < 0:
                return k, m, bad, -4
            counts[ch] += 1
            p = i + 31
            plen = int(length) - 22
            if w == W_FRAME:
                if plen != 19 or buf[p] != 0 or buf[p + 1] != 1:
                    bad += 1
                else:
                    t[k] = np.int64(_get(buf, i + 15, 8))
                    cid[k] = np.uint32(_get(buf, p + 4, 4))
                    ext[k] = buf[p + 8] != 0
                    rx[k] = buf[p + 9] != 0
                    dlc[k] = buf[p + 10]
                    chan[k] = busmap[ch]
                    for j in range(8):
                        data[k, j] = buf[p + 11 + j]
                    for j in range(8, data.shape[1]):
                        data[k, j] = 0
                    k += 1
            elif w == W_FD:
                n_data = int(_get(buf, p + 12, 4)) if plen >= 16 else -1
                if (
                    plen < 16
                    or buf[p] != 0
                    or buf[p + 1] != 1
                    or n_data > buf[p + 10]
                    or n_data > data.shape[1]
                    or plen != 16 + n_data
                ):
                    bad += 1
                else:
                    t[k] = np.int64(_get(buf, i + 15, 8))
                    cid[k] = np.uint32(_get(buf, p + 4, 4))
                    ext[k] = buf[p + 8] != 0
                    rx[k] = buf[p + 9] != 0
                    dlc[k] = buf[p + 10]
                    chan[k] = busmap[ch]
                    for j in range(n_data):
                        data[k, j] = buf[p + 16 + j]
                    for j in range(n_data, data.shape[1]):
                        data[k, j] = 0
                    k += 1
            elif w == W_TABLE:
                o_chan[m] = ch
                o_t[m] = np.int64(_get(buf, i + 15, 8))
                o_off[m] = p
                o_len[m] = plen
                m += 1
        i += 9 + int(length)
    return k, m, bad, 0


def _bus_of(topic: str, meta: dict[str, str]) -> str:
    """The bus of a CAN channel: its metadata's ``bus``; lde's topics of the unnamed bus: ``""``;
    any other topic: the topic itself (an MCAP file of another tool, one bus per topic)."""
    if "bus" in meta:
        return meta["bus"]
    if topic in (TOPIC_RX, TOPIC_TX, TOPIC_FD_RX, TOPIC_FD_TX):
        return ""
    return topic


# ----------------------------------------------------------------------------- file layout
@dataclass
class _Chunk:
    """A chunk record: where it is, its time range, and (when message indexes follow it) which
    channels it holds and where their index records are."""

    offset: int
    start: int
    end: int
    index: dict[int, int] = field(default_factory=dict)  # channel -> message index record offset

    @property
    def channels(self) -> set[int] | None:
        return set(self.index) if self.index else None


@dataclass
class _Layout:
    library: str
    ended: bool  # the data end or the footer was reached
    schemas: dict[int, Any]
    channels: dict[int, Any]
    chunks: list[_Chunk]
    metadata_offsets: list[int]
    truncated: bool
    counts: dict[int, int] | None  # per channel, from the statistics
    walked: bool = True  # found by walking the records (else from the summary)
    end_offset: int = 0  # where the walk stopped: the end of the last complete record [bytes]


def _walk_top_level(raw) -> _Layout | None:
    """Schemas, channels, metadata and chunks (with the message indexes that follow them) of a
    file without chunk indexes, by walking its top-level records (the module doc, step 2).

    Returns None when the file has messages outside chunks or no channel outside chunks (the
    ``mcap`` library reads those).

    Raises:
        LogFormatError: the file is cut before or inside its first chunk (nothing to recover).
    """
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Header, Schema

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    chunks: list[_Chunk] = []
    meta: list[int] = []
    library = ""
    ended = False
    pos = len(MAGIC)
    n = len(raw)
    truncated = False
    cut_op = -1  # opcode of the record the file ends in (-1: unknown)
    while True:
        if pos + 9 > n:
            truncated = pos < n
            cut_op = raw[pos] if pos < n else -1
            break
        op = raw[pos]
        (length,) = struct.unpack_from("<Q", raw, pos + 1)
        if pos + 9 + length > n:
            truncated = True
            cut_op = op
            break
        if op in (OP_SCHEMA, OP_CHANNEL, OP_HEADER):
            body = ReadDataStream(io.BytesIO(bytes(raw[pos + 9 : pos + 9 + length])))
            if op == OP_HEADER:
                library = Header.read(body).library
            elif op == OP_SCHEMA:
                rec = Schema.read(body)
                schemas[rec.id] = rec
            else:
                rec = Channel.read(body)
                channels[rec.id] = rec
        elif op == OP_CHUNK:
            t0, t1 = struct.unpack_from("<QQ", raw, pos + 9)
            chunks.append(_Chunk(pos, int(t0), int(t1)))
        elif op == OP_MESSAGE_INDEX and chunks and length >= 6:
            (ch,) = struct.unpack_from("<H", raw, pos + 9)
            chunks[-1].index[int(ch)] = pos
        elif op == OP_METADATA:
            meta.append(pos)
        elif op == OP_MESSAGE:
            return None
        elif op in (OP_DATA_END, OP_FOOTER):
            ended = True
            break
        pos += 9 + int(length)
    if truncated and not chunks:
        where = "inside its first chunk" if cut_op == OP_CHUNK else f"at byte {n}, before its first chunk"
        raise LogFormatError(f"truncated MCAP file: cut {where}; no complete chunk of frames")
    if not channels:
        return None
    return _Layout(library, ended, schemas, channels, chunks, meta, truncated, None, end_offset=pos)


def _layout_of_summary(summary, library: str) -> _Layout:
    chunks = [
        _Chunk(
            int(ci.chunk_start_offset),
            int(ci.message_start_time),
            int(ci.message_end_time),
            {int(c): int(o) for c, o in ci.message_index_offsets.items()},
        )
        for ci in summary.chunk_indexes
    ]
    stats = summary.statistics
    counts = dict(stats.channel_message_counts) if stats is not None else None
    return _Layout(
        library, True, dict(summary.schemas), dict(summary.channels), chunks, [], False, counts, walked=False
    )


def _chunk_header(raw, o: int) -> tuple[str, int, int, int, int]:
    """(compression, uncompressed size, crc, records start, records length) of the chunk at ``o``."""
    if o + 49 > len(raw) or raw[o] != OP_CHUNK:
        what = f"opcode {raw[o]:#x}" if o < len(raw) else "the end of the file"
        raise LogFormatError(f"chunk index points at {what}, not a chunk, at offset {o}")
    _t0, _t1, usize, ucrc = struct.unpack_from("<QQQI", raw, o + 9)
    (clen,) = struct.unpack_from("<I", raw, o + 37)
    comp = bytes(raw[o + 41 : o + 41 + clen]).decode()
    (dlen,) = struct.unpack_from("<Q", raw, o + 41 + clen)
    start = o + 49 + clen
    if start + dlen > len(raw):
        raise LogFormatError(f"chunk at offset {o} runs past the end of the file (truncated?)")
    return comp, usize, ucrc, start, dlen


def _index_entries(raw, o: int) -> np.ndarray | None:
    """(log_time, offset) pairs (uint64 [n, 2]) of the message index record at ``o``; None if it
    is not one."""
    if o + 15 > len(raw) or raw[o] != OP_MESSAGE_INDEX:
        return None
    (n_bytes,) = struct.unpack_from("<I", raw, o + 11)
    if o + 15 + n_bytes > len(raw) or n_bytes % 16:
        return None
    return np.frombuffer(raw, "<u8", count=n_bytes // 8, offset=o + 15).reshape(-1, 2)


_ZSTD = zstandard.ZstdDecompressor()


def _self_checked(compression: str, raw, start: int) -> bool:
    """True if the chunk's compressed frame carries its own checksum of the content, which the
    decompressor verifies (zstd and lz4 frames written by lde do): the chunk's CRC-32 (~0.7 ms per
    MB) is then not computed again."""
    try:
        if compression == "zstd":
            return bool(zstandard.get_frame_parameters(raw[start : start + 18]).has_checksum)
        if compression == "lz4":
            return bool(lz4frame.get_frame_info(raw[start : start + 19])["content_checksum"])
    except Exception:  # noqa: BLE001 - a damaged frame header: the decompressor will say so
        return False
    return False


def _decompress(compression: str, data, size: int) -> bytes:
    if compression == "":
        return bytes(data)
    if compression == "zstd":
        return _ZSTD.decompress(data, max_output_size=size)
    if compression == "lz4":
        return lz4frame.decompress(data)
    raise LogFormatError(f"unsupported MCAP chunk compression {compression!r}")


@dataclass
class _Walked:
    """One chunk walked: its frames (record order) and its table rows (W_TABLE channels)."""

    frames: FrameBatch
    o_chan: np.ndarray
    o_t: np.ndarray
    o_off: np.ndarray
    o_len: np.ndarray
    buf: np.ndarray
    bad: int


# ----------------------------------------------------------------------------- the open file
class McapLog:
    """An MCAP file opened for reading (the module doc). Use as a context manager or :meth:`close`.

    Attributes:
        path: the file.
        topics: topic -> :class:`TopicInfo` (``count`` from the statistics; for a file without
            them, counted while reading: final once :meth:`iter_frames` is exhausted).
        metadata: name -> key/value strings of the metadata records (``lde``: profile, ...).
        truncated: the file has no summary and ends inside a record: read up to its last complete
            chunk.
        complete: the file has its data end or footer (it was closed cleanly).
        size, end_offset: the file's size and where its complete records end [bytes] (a file
            without summary: what was recovered; else the size).
        lanes: written by lde (header library ``lde ...``): every chunk holds one channel's
            messages, and a JSON channel's chunks are followed by their message indexes.
        fast_path: False when the ``mcap`` library's per-message reader is used.
        bad_can_messages: CAN-channel messages of the wrong size or encoding, skipped so far.
        bad_chunks: byte offsets of the first :data:`BAD_CHUNKS_KEPT` chunks that held them.
        chunks_read, chunks_skipped: chunks decompressed / left compressed so far.

    Raises:
        LogFormatError: missing, empty, not MCAP, or cut before its first complete chunk.
    """

    def __init__(self, path: str | Path, *, validate_crcs: bool = True, force_library: bool = False) -> None:
        p = Path(path)
        self.path = p
        self.validate_crcs = validate_crcs
        try:
            self._fh = p.open("rb")
        except OSError as exc:
            raise LogFormatError(f"{p}: cannot read: {exc}") from exc
        try:
            self._open(force_library)
        except LogFormatError as exc:
            self.close()
            raise LogFormatError(f"{p}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - the mcap library raises many types on corrupt input
            self.close()
            raise LogFormatError(f"{p}: corrupt MCAP file ({type(exc).__name__}: {exc})") from exc

    def _open(self, force_library: bool) -> None:
        # the library only for MCAP files (a candump replay does not import it)
        from mcap.reader import SeekingReader

        fh = self._fh
        size = os.fstat(fh.fileno()).st_size
        if size == 0:
            raise LogFormatError("empty file")
        # memory-mapped: chunks that are not needed are never read from disk
        self._raw: Any = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        raw = self._raw
        if raw[: len(MAGIC)] != MAGIC:
            raise LogFormatError("not an MCAP file (no MCAP magic)")
        self.truncated = False
        self.bad_can_messages = 0
        self.bad_chunks: list[int] = []
        self.chunks_read = 0
        self.chunks_skipped = 0
        self._library: _LibraryData | None = None
        summary = None
        if not force_library:
            try:
                summary = SeekingReader(fh).get_summary()
            except Exception:  # noqa: BLE001 - a damaged or missing summary: walk the records
                summary = None
        layout: _Layout | None = None
        if summary is not None and summary.chunk_indexes:
            layout = _layout_of_summary(summary, _header_library(fh))
        elif not force_library:
            layout = _walk_top_level(raw)
            if layout is not None and summary is not None:
                layout.counts = _stats_counts(summary)
        self.lanes = False
        self.complete = summary is not None
        self.size = size
        self.end_offset = size
        if layout is None:
            fh.seek(0)
            self._library = _read_library(fh)
            self.fast_path = False
            schemas, channels = self._library.schemas, self._library.channels
            counts: dict[int, int] | None = self._library.counts
            self._chunks: list[_Chunk] = []
        else:
            self.fast_path = True
            self.truncated = layout.truncated
            self.complete = self.complete or layout.ended
            if layout.walked:
                self.end_offset = layout.end_offset
            self.lanes = layout.library.startswith("lde ")
            schemas, channels, counts = layout.schemas, layout.channels, layout.counts
            self._chunks = sorted(layout.chunks, key=lambda c: c.offset)
        self._rank = {c.offset: r for r, c in enumerate(self._chunks)}
        self._schemas, self._channels = schemas, channels
        self._counted = counts is not None
        self._counts = np.zeros(65536, np.int64)
        if counts:
            for ch, k in counts.items():
                self._counts[ch] = k
        self._declared = np.full(65536, _NO_CHANNEL, np.int8)
        self._can: set[int] = set()
        self._fd: set[int] = set()
        self._tx: set[int] = set()
        #: the buses of the CAN channels (:attr:`lde.can.frames.FrameBatch.channels` of the frames)
        self.buses: tuple[str, ...] = ()
        self._busmap = np.zeros(65536, np.uint16)
        buses: dict[str, int] = {}
        self.topics: dict[str, TopicInfo] = {}
        for cid in sorted(channels):
            ch = channels[cid]
            sch = schemas.get(ch.schema_id)
            sname = sch.name if sch else ""
            if sname in (CAN_SCHEMA_NAME, CAN_FD_SCHEMA_NAME):
                self._can.add(cid)
                if sname == CAN_FD_SCHEMA_NAME:
                    self._fd.add(cid)
                meta = dict(getattr(ch, "metadata", None) or {})
                if meta.get("direction") == "tx" or ch.topic == TOPIC_TX:
                    self._tx.add(cid)
                self._busmap[cid] = buses.setdefault(_bus_of(ch.topic, meta), len(buses))
            self._declared[cid] = W_COUNT
            self.topics[ch.topic] = TopicInfo(
                ch.topic, cid, ch.message_encoding, sname, sch.encoding if sch else "", 0, cid in self._tx
            )
        self.buses = tuple(buses) or ("",)
        self.metadata = self._read_metadata(summary, layout)
        self._update_counts()

    # ------------------------------------------------------------------ metadata
    def _read_metadata(self, summary, layout: _Layout | None) -> dict[str, dict[str, str]]:
        """Through the summary's metadata indexes with the ``mcap`` library; else the metadata
        records the walk found, parsed with its record type. A damaged record is left out."""
        from mcap.data_stream import ReadDataStream
        from mcap.reader import SeekingReader
        from mcap.records import Metadata

        out: dict[str, dict[str, str]] = {}
        if self._library is not None:
            return self._library.metadata
        if summary is not None and summary.metadata_indexes:
            try:
                for rec in SeekingReader(self._fh).iter_metadata():
                    out.setdefault(rec.name, {}).update(rec.metadata)
                return out
            except Exception:  # noqa: BLE001 - a damaged index: walk the records instead
                out = {}
        offsets = layout.metadata_offsets if layout is not None else []
        if layout is not None and not layout.walked:  # a summary without metadata indexes
            walked = _walk_top_level(self._raw)
            offsets = walked.metadata_offsets if walked is not None else []
        raw = self._raw
        for o in offsets:
            (length,) = struct.unpack_from("<Q", raw, o + 1)
            try:
                rec = Metadata.read(ReadDataStream(io.BytesIO(bytes(raw[o + 9 : o + 9 + length]))))
            except Exception:  # noqa: BLE001 - a damaged record is left out, never fatal
                continue
            out.setdefault(rec.name, {}).update(rec.metadata)
        return out

    # ------------------------------------------------------------------ counts
    def _update_counts(self) -> None:
        for topic, ti in list(self.topics.items()):
            self.topics[topic] = TopicInfo(**{**ti.__dict__, "count": int(self._counts[ti.channel_id])})

    def channel_id(self, topic: str) -> int:
        return self.topics[topic].channel_id

    @property
    def can_topics(self) -> list[str]:
        return [t for t, ti in self.topics.items() if ti.channel_id in self._can]

    # ------------------------------------------------------------------ chunks
    def _walk(self, c: _Chunk, want: np.ndarray, count: bool) -> _Walked:
        raw = self._raw
        comp, usize, ucrc, st, dlen = _chunk_header(raw, c.offset)
        # read with pread, not through the map: pages read through it would stay in this process's
        # resident set, which would then grow with the file (a 10-hour log: +200 MB)
        comp_data = os.pread(self._fh.fileno(), dlen, st)
        if len(comp_data) != dlen:
            raise LogFormatError(f"chunk at offset {c.offset} runs past the end of the file (truncated?)")
        out = _decompress(comp, comp_data, usize)
        if len(out) != usize:
            raise LogFormatError(
                f"chunk at offset {c.offset}: {len(out)} bytes after decompression, expected {usize}"
            )
        if self.validate_crcs and ucrc and not _self_checked(comp, comp_data, 0) and zlib.crc32(out) != ucrc:
            raise LogFormatError(f"chunk at offset {c.offset}: CRC mismatch")
        buf = np.frombuffer(out, np.uint8)
        cap = usize // MSG_OVERHEAD + 1  # at most one message per 31 bytes of records
        fd = bool(self._fd) and (c.channels is None or bool(c.channels & self._fd))
        t = np.empty(cap, np.int64)
        cid = np.empty(cap, np.uint32)
        ext = np.empty(cap, np.bool_)
        dlc = np.empty(cap, np.uint8)
        data = np.empty((cap, MAX_DATA if fd else CLASSIC_DATA), np.uint8)
        rx = np.empty(cap, np.bool_)
        chan = np.empty(cap, np.uint16)
        o_chan = np.empty(cap, np.uint16)
        o_t = np.empty(cap, np.int64)
        o_off = np.empty(cap, np.int64)
        o_len = np.empty(cap, np.int64)
        counts = self._counts if count else np.zeros(65536, np.int64)
        k, m, bad, status = _walk_chunk(
            buf, want, counts, t, cid, ext, dlc, data, rx, chan, self._busmap, o_chan, o_t, o_off, o_len
        )
        if status == -4:
            raise LogFormatError(f"chunk at offset {c.offset}: a message of an undeclared channel")
        if status < 0:
            raise LogFormatError(f"chunk at offset {c.offset}: corrupt record")
        self.chunks_read += 1
        width = data_width(int(dlc[:k].max())) if fd and k else CLASSIC_DATA
        frames = FrameBatch(
            t_ns=t[:k].copy(),
            can_id=cid[:k].copy(),
            is_extended=ext[:k].copy(),
            dlc=dlc[:k].copy(),
            data=data[:k, :width].copy(),
            is_rx=rx[:k].copy(),
            channel=chan[:k].copy(),
            channels=self.buses,
        )
        return _Walked(
            frames, o_chan[:m].copy(), o_t[:m].copy(), o_off[:m].copy(), o_len[:m].copy(), buf, bad
        )

    def _want(self, frames: set[int], table: set[int]) -> np.ndarray:
        want = self._declared.copy()
        for ch in frames:
            want[ch] = W_FD if ch in self._fd else W_FRAME
        for ch in table:
            want[ch] = W_TABLE
        return want

    def _guard(self, what: str, fn, *args):  # noqa: ANN001, ANN202
        try:
            return fn(*args)
        except LogFormatError as exc:
            raise LogFormatError(f"{self.path}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - decompressors raise their own types on corrupt data
            raise LogFormatError(f"{self.path}: corrupt MCAP {what} ({type(exc).__name__}: {exc})") from exc

    def iter_frames(self, *, tx: bool = True, chunk_frames: int = CHUNK_FRAMES) -> Iterator[FrameBatch]:
        """The frames of every CAN channel (without ``/can/tx`` unless ``tx``) in time order (the
        module doc), in pieces of at most ``chunk_frames`` frames.

        Raises:
            LogFormatError: a corrupt chunk (CRC, size, record stream).
        """
        wanted = {ch for ch in self._can if tx or ch not in self._tx}
        if self._library is not None:
            lib = self._library
            sel = np.isin(lib.frame_channel, np.array(sorted(wanted), np.int64))
            f = lib.frames.select(sel)
            ch = self._busmap[lib.frame_channel[sel]]
            f = FrameBatch(f.t_ns, f.can_id, f.is_extended, f.dlc, f.data, f.is_rx, ch, self.buses)
            yield from split(f, chunk_frames)
            return
        chunks = []
        for c in self._chunks:
            chans = c.channels
            if chans is not None and not (chans & wanted):
                self.chunks_skipped += 1
                if not self._counted:
                    for ch, o in c.index.items():
                        e = _index_entries(self._raw, o)
                        self._counts[ch] += 0 if e is None else e.shape[0]
                continue
            chunks.append(c)
        # read in the order of start times; a frame is final once no chunk left can start before it
        chunks.sort(key=lambda c: (c.start, c.offset))
        starts = [c.start for c in chunks]
        want = self._want(wanted, set())
        pool = _Pool()
        out = _Batcher(chunk_frames)
        for j, c in enumerate(chunks):
            w = self._guard("chunk", self._walk, c, want, not self._counted)
            self.bad_can_messages += w.bad
            if w.bad and len(self.bad_chunks) < BAD_CHUNKS_KEPT:
                self.bad_chunks.append(c.offset)
            pool.add(w.frames, self._rank[c.offset])
            del w  # the decompressed chunk is not held while the pieces are used
            bound = starts[j + 1] if j + 1 < len(chunks) else None
            yield from out.push(pool.release(bound))
        yield from out.push(pool.release(None))
        yield from out.finish()
        self._update_counts()

    # ------------------------------------------------------------------ other channels
    def times(self, topic: str) -> np.ndarray:
        """The log times of a channel's messages, sorted (stable in file order) [ns, int64]: from
        the message indexes where a chunk has them, else by walking the chunk."""
        ch = self.channel_id(topic)
        if self._library is not None:
            return self._library.times(ch)
        parts: list[np.ndarray] = []
        want = self._want(set(), {ch})
        for c in self._chunks:  # file order, then a stable sort: the order of a full read
            e = _index_entries(self._raw, c.index[ch]) if ch in c.index else None
            if e is not None:
                parts.append(e[:, 0].astype(np.int64))
            elif self._may_hold(c, ch):
                w = self._guard("chunk", self._walk, c, want, False)
                parts.append(w.o_t[w.o_chan == ch])
        ts = np.concatenate(parts) if parts else np.zeros(0, np.int64)
        return np.sort(ts, kind="stable")

    def json(self, topic: str) -> dict[str, np.ndarray]:
        """The columns of a JSON channel (:func:`lde.io.mcap_json.json_columns`).

        Raises:
            LogFormatError: no such topic, not JSON, or a message that is not a JSON object.
        """
        ti = self.topics.get(topic)
        if ti is None:
            raise LogFormatError(f"{self.path}: no topic {topic!r} in this MCAP file")
        if ti.message_encoding != "json":
            raise LogFormatError(f"{self.path}: topic {topic!r} is {ti.message_encoding!r}, not json")
        ch = ti.channel_id
        pays: list[bytes | memoryview]
        if self._library is not None:
            t, lib_pays = self._library.payloads(ch)
            pays = list(lib_pays)
        else:
            ts: list[np.ndarray] = []
            pays = []
            want = self._want(set(), {ch})
            for c in self._chunks:
                if not self._may_hold(c, ch):
                    continue
                w = self._guard("chunk", self._walk, c, want, False)
                sel = np.flatnonzero(w.o_chan == ch)
                mv = memoryview(w.buf)
                ts.append(w.o_t[sel])
                pays += [
                    mv[o : o + n] for o, n in zip(w.o_off[sel].tolist(), w.o_len[sel].tolist(), strict=True)
                ]
            t = np.concatenate(ts) if ts else np.zeros(0, np.int64)
        order = np.argsort(t, kind="stable")
        try:
            return json_columns(topic, t[order], [pays[i] for i in order.tolist()])
        except LogFormatError as exc:
            raise LogFormatError(f"{self.path}: {exc}") from exc

    def _may_hold(self, c: _Chunk, ch: int) -> bool:
        """Whether chunk ``c`` may hold messages of channel ``ch``: its message indexes say; a
        chunk without them may hold anything, except in a file written by lde (:attr:`lanes`),
        where every JSON chunk is followed by its index (only the last chunk of a cut file can
        have lost it)."""
        if c.index:
            return ch in c.index
        if self.lanes and ch not in self._can:
            return self.truncated and c is self._chunks[-1]
        return True

    # ------------------------------------------------------------------ end
    def close(self) -> None:
        raw = getattr(self, "_raw", None)
        if raw is not None:
            with contextlib.suppress(BufferError):  # a view still alive: the GC unmaps it
                raw.close()
            self._raw = None
        self._fh.close()

    def __enter__(self) -> McapLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _header_library(fh: IO[bytes]) -> str:
    from mcap.reader import SeekingReader

    try:
        return str(SeekingReader(fh).get_header().library)
    except Exception:  # noqa: BLE001 - a damaged header: not lde's layout
        return ""


def _stats_counts(summary) -> dict[int, int] | None:
    stats = getattr(summary, "statistics", None)
    return dict(stats.channel_message_counts) if stats is not None else None


class _Pool:
    """Frames of the chunks read so far that may still have earlier frames to come, ordered by
    (log time, chunk rank in the file, record order)."""

    def __init__(self) -> None:
        self._f = FrameBatch.empty()
        self._key = np.zeros(0, np.int64)  # rank << 32 | record index

    def add(self, f: FrameBatch, rank: int) -> None:
        key = (np.int64(rank) << np.int64(32)) + np.arange(len(f), dtype=np.int64)
        if len(self._f) == 0 and f.is_sorted():
            self._f, self._key = f, key
            return
        if (
            len(self._f)
            and f.is_sorted()
            and len(f)
            and (self._f.t_ns[-1] < f.t_ns[0] or (self._f.t_ns[-1] == f.t_ns[0] and self._key[-1] < key[0]))
        ):
            self._f = FrameBatch.concat([self._f, f], sort=False)
            self._key = np.concatenate([self._key, key])
            return
        allf = FrameBatch.concat([self._f, f], sort=False)
        allk = np.concatenate([self._key, key])
        order = np.lexsort((allk, allf.t_ns))
        self._f, self._key = allf.take(order), allk[order]

    def release(self, bound: int | None) -> FrameBatch:
        """The frames before ``bound`` (all of them for None)."""
        n = len(self._f) if bound is None else int(np.searchsorted(self._f.t_ns, bound, side="left"))
        out = view(self._f, 0, n)
        self._f, self._key = view(self._f, n, len(self._f)), self._key[n:]
        return out


class _Batcher:
    """Joins small pieces into pieces of ``n`` frames (the engine runs best on large ones)."""

    def __init__(self, n: int) -> None:
        self.n = n
        self._parts: list[FrameBatch] = []
        self._k = 0

    def push(self, f: FrameBatch) -> Iterator[FrameBatch]:
        if len(f) == 0:
            return
        self._parts.append(f)
        self._k += len(f)
        if self._k >= self.n:
            allf = FrameBatch.concat(self._parts, sort=False) if len(self._parts) > 1 else self._parts[0]
            full = (len(allf) // self.n) * self.n
            yield from split(view(allf, 0, full), self.n)
            rest = view(allf, full, len(allf))
            self._parts = [rest] if len(rest) else []
            self._k = len(rest)

    def finish(self) -> Iterator[FrameBatch]:
        if self._parts:
            yield FrameBatch.concat(self._parts, sort=False) if len(self._parts) > 1 else self._parts[0]
        self._parts, self._k = [], 0


# ----------------------------------------------------------------------------- the library path
@dataclass
class _LibraryData:
    """Everything of a file read with the ``mcap`` library's per-message reader."""

    schemas: dict[int, Any]
    channels: dict[int, Any]
    counts: dict[int, int]
    frames: FrameBatch
    frame_channel: np.ndarray
    other_chan: np.ndarray
    other_t: np.ndarray
    other: list[bytes]
    metadata: dict[str, dict[str, str]]

    def times(self, ch: int) -> np.ndarray:
        return np.sort(self.other_t[self.other_chan == ch], kind="stable")

    def payloads(self, ch: int) -> tuple[np.ndarray, list[bytes]]:
        idx = np.flatnonzero(self.other_chan == ch)
        return self.other_t[idx], [self.other[i] for i in idx.tolist()]


def _read_library(fh: IO[bytes]) -> _LibraryData:
    """The reference path: the ``mcap`` library's reader, one Python object per message."""
    from mcap.reader import make_reader

    reader = make_reader(fh)
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    counts: dict[int, int] = {}
    t: list[int] = []
    fch: list[int] = []
    payload = bytearray()
    fd_t: list[int] = []
    fd_ch: list[int] = []
    fd_pays: list[bytes] = []
    o_chan: list[int] = []
    o_t: list[int] = []
    other: list[bytes] = []
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        counts[channel.id] = counts.get(channel.id, 0) + 1
        if channel.id not in channels:
            channels[channel.id] = channel
            if schema is not None:
                schemas[schema.id] = schema
        if schema is not None and schema.name == CAN_SCHEMA_NAME:
            d = message.data
            if len(d) != CAN_PAYLOAD_SIZE or d[:2] != CDR_HEADER[:2]:
                continue
            t.append(message.log_time)
            fch.append(channel.id)
            payload += d
        elif schema is not None and schema.name == CAN_FD_SCHEMA_NAME:
            fd_t.append(message.log_time)
            fd_ch.append(channel.id)
            fd_pays.append(bytes(message.data))
        else:
            o_chan.append(channel.id)
            o_t.append(message.log_time)
            other.append(bytes(message.data))
    metadata: dict[str, dict[str, str]] = {}
    summary = None
    try:
        fh.seek(0)
        summary = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - no usable summary
        summary = None
    if summary is not None:
        for cid, ch in summary.channels.items():
            channels.setdefault(cid, ch)
        for sid, sch in summary.schemas.items():
            schemas.setdefault(sid, sch)
    fh.seek(0)
    try:
        for rec in make_reader(fh).iter_metadata():
            metadata.setdefault(rec.name, {}).update(rec.metadata)
    except Exception:  # noqa: BLE001 - metadata is optional
        pass
    frames = frames_of_payloads(np.array(t, np.int64), bytes(payload))
    chans = np.array(fch, np.int64)
    if fd_pays:
        fd_frames, kept = frames_of_fd_payloads(np.array(fd_t, np.int64), fd_pays)
        frames = FrameBatch.concat([frames, fd_frames], sort=False)
        chans = np.concatenate([chans, np.array(fd_ch, np.int64)[kept]])
    order = np.argsort(frames.t_ns, kind="stable")
    return _LibraryData(
        schemas,
        channels,
        counts,
        frames.take(order),
        chans[order],
        np.array(o_chan, np.int64),
        np.array(o_t, np.int64),
        other,
        metadata,
    )


# ----------------------------------------------------------------------------- whole files
@dataclass
class McapData:
    """A whole MCAP file read (:func:`read_mcap`).

    Attributes:
        frames: the CAN frames of every ``lde_msgs/msg/CanFrame`` channel, sorted by time.
        topics: topic -> :class:`TopicInfo` for every channel with messages or declared.
        times: topic -> int64 ``log_time`` array [ns] of every non-CAN channel.
        json: topic -> {field: array} for the JSON topics asked for: int64 for fields that are
            integers in every message (exact), else float64 (missing/null -> NaN); plus
            ``"log_time"`` and, unless a field has that name, ``"t_ns"`` (both the log times).
        bad_can_messages: CAN-channel messages of the wrong size or encoding (skipped).
        fast_path: True if the chunk-level numba reader was used (else the ``mcap`` library's).
        chunks_read, chunks_skipped: chunks decompressed / known from their message indexes only.
        truncated: the file has no summary and ends inside a record (a recording cut by a crash):
            everything up to the last complete chunk was read.
        metadata: name -> key/value strings of the file's metadata records (lde's writers store
            ``lde``: profile, vehicle, backend, source...); empty when there are none.
    """

    frames: FrameBatch
    topics: dict[str, TopicInfo] = field(default_factory=dict)
    times: dict[str, np.ndarray] = field(default_factory=dict)
    json: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    bad_can_messages: int = 0
    fast_path: bool = True
    chunks_read: int = 0
    chunks_skipped: int = 0
    truncated: bool = False
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)


def json_wanted(m: McapLog, json_topics: Iterable[str] | str | None, optional: bool) -> list[str]:
    """The JSON topics of ``json_topics`` (``"all"``: every JSON channel) present in ``m``.

    Raises:
        LogFormatError: a topic asked for is missing (unless ``optional``) or not JSON.
    """
    if json_topics is None:
        return []
    if json_topics == "all":
        return [t for t, ti in m.topics.items() if ti.message_encoding == "json"]
    wanted = [json_topics] if isinstance(json_topics, str) else list(json_topics)
    out = []
    for topic in wanted:
        ti = m.topics.get(topic)
        if ti is None and optional:
            continue
        if ti is None:
            raise LogFormatError(f"{m.path}: no topic {topic!r} in this MCAP file")
        if ti.message_encoding != "json":
            raise LogFormatError(f"{m.path}: topic {topic!r} is {ti.message_encoding!r}, not json")
        out.append(topic)
    return out


def check_can_channel(m: McapLog) -> None:
    """LogFormatError when the file has no CAN channel."""
    if not m.can_topics:
        names = ", ".join(sorted(m.topics)) or "none"
        raise LogFormatError(
            f"{m.path}: no CAN channel (schema {CAN_SCHEMA_NAME}) in this MCAP file; topics: {names}"
        )


def read_mcap(
    path: str | Path,
    json_topics: Iterable[str] | str | None = None,
    *,
    require_can: bool = True,
    force_library: bool = False,
    validate_crcs: bool = True,
    skip_tx: bool = False,
    json_optional: bool = False,
) -> McapData:
    """Read a whole MCAP file (the frames of all its CAN channels at once; see :class:`McapLog`).

    Args:
        json_topics: JSON topics to return as columns (``"all"`` for every JSON channel).
        json_optional: a topic of ``json_topics`` that the file does not have is left out of
            ``json`` instead of raising (for channels only some recordings have).
        require_can: raise :class:`LogFormatError` if the file has no CAN channel.
        force_library: use the ``mcap`` library's per-message reader (the reference path).
        validate_crcs: check each chunk's CRC-32 (zstd chunks: the zstd frame checksum).
        skip_tx: leave out ``/can/tx`` (lde's own sent frames, which a replay does not use); its
            chunks stay compressed when their message indexes say which they are.
            ``topics["/can/tx"].count`` still counts them all.

    Raises:
        LogFormatError: not an MCAP file, corrupt, or (with ``require_can``) no CAN channel.
    """
    with McapLog(path, validate_crcs=validate_crcs, force_library=force_library) as m:
        if require_can:
            check_can_channel(m)
        wanted = json_wanted(m, json_topics, json_optional)
        frames = FrameBatch.concat(list(m.iter_frames(tx=not skip_tx)), sort=False)
        times = {t: m.times(t) for t, ti in m.topics.items() if ti.channel_id not in m._can}
        js = {t: m.json(t) for t in wanted}
        return McapData(
            frames=frames,
            topics=dict(m.topics),
            times=times,
            json=js,
            bad_can_messages=m.bad_can_messages,
            fast_path=m.fast_path,
            chunks_read=m.chunks_read,
            chunks_skipped=m.chunks_skipped,
            truncated=m.truncated,
            metadata=m.metadata,
        )
