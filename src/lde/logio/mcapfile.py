"""MCAP recordings of raw CAN frames plus JSON channels, with a numpy/numba bulk path.

Layout (documented for users in ``docs/mcap.md``):

* ``/can/rx`` — frames lde received, ``/can/tx`` — frames lde sent. Message encoding ``cdr``,
  schema ``lde_msgs/msg/CanFrame`` (encoding ``ros2msg``, text in :data:`CAN_SCHEMA_TEXT`),
  ``log_time`` = ``publish_time`` = the frame's timestamp in ns (the log's own time base). Every CAN
  message has the same size: a 4-byte CDR encapsulation header (``00 01 00 00``, little endian) and
  15 bytes of fields::

      offset  field            type
      0       id               uint32   arbitration id (11 or 29 bit)
      4       is_extended      bool
      5       is_rx            bool     False for frames lde sent
      6       dlc              uint8    data length in bytes (0..64; > 8 = CAN FD)
      7       data             uint8[8] first 8 data bytes, zero padded

* any number of JSON channels (message encoding ``json``, schema encoding ``jsonschema``): one flat
  object of numbers per message (estimates, diagnostics, simulator truth), registered with
  :meth:`McapWriter.add_json_channel`.

Writing: :class:`McapWriter` buffers messages, sorts them by ``log_time`` and writes zstd-compressed
chunks (records built by a numba kernel), message indexes, chunk indexes, metadata indexes, statistics
and the summary, readable by the ``mcap`` library and by Foxglove. The CAN channels and each JSON
channel go to separate chunks (time ranges of chunks of different channels overlap, which MCAP
allows), so that reading the CAN frames decompresses no JSON.

Reading: :func:`read_mcap` reads the summary with the ``mcap`` library, then every chunk record
directly: it decompresses the chunk (zstd / lz4 / none) and a numba kernel walks the records, filling
the :class:`~lde.frames.FrameBatch` columns of the CAN channels and the (channel, log_time, offset,
length) table of the others. A file without chunk indexes is read with the ``mcap`` library's own
(per-message, slower) reader.
"""

from __future__ import annotations

import io
import json
import math
import mmap
import os
import struct
import zlib
from collections.abc import Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numba
import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.reader import SeekingReader, make_reader
from mcap.records import Channel, Schema

from .. import __version__ as lde_version
from ..errors import LogFormatError
from ..frames import FrameBatch

try:
    import zstandard
except ImportError:  # pragma: no cover - zstandard is a dependency of mcap's zstd support
    zstandard = None  # type: ignore[assignment]
try:
    import lz4.frame as lz4frame
except ImportError:  # pragma: no cover
    lz4frame = None

__all__ = [
    "CAN_SCHEMA_NAME",
    "CAN_SCHEMA_TEXT",
    "CAN_PAYLOAD_SIZE",
    "TOPIC_RX",
    "TOPIC_TX",
    "McapWriter",
    "McapData",
    "TopicInfo",
    "read_mcap",
    "can_payloads",
    "can_payload",
    "CDR_HEADER",
]

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS = 0x06, 0x07, 0x08, 0x0B
OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 0x0C, 0x0D, 0x0E, 0x0F

TOPIC_RX = "/can/rx"
TOPIC_TX = "/can/tx"
CAN_SCHEMA_NAME = "lde_msgs/msg/CanFrame"
CAN_SCHEMA_TEXT = """\
# One raw CAN frame as lde received (/can/rx) or sent (/can/tx) it.
# Fixed size (15 bytes of CDR after the 4-byte encapsulation header) so that logs decode in bulk.
uint32 id          # arbitration id (11 or 29 bit)
bool is_extended   # 29-bit identifier
bool is_rx         # false for frames lde itself sent
uint8 dlc          # data length in bytes (0..64; above 8 only the first 8 bytes are kept)
uint8[8] data      # first 8 data bytes, zero padded
"""
CDR_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian
CAN_PAYLOAD_SIZE = 4 + 15
_MSG_OVERHEAD = 1 + 8 + 2 + 4 + 8 + 8  # opcode, record length, channel, sequence, log_time, publish_time


# ----------------------------------------------------------------------------- numba kernels
@numba.njit(cache=True, inline="always")
def _put(out, o, value, nbytes):
    v = np.uint64(value)
    for j in range(nbytes):
        out[o + j] = np.uint8((v >> np.uint64(8 * j)) & np.uint64(0xFF))


@numba.njit(cache=True, inline="always")
def _get(buf, o, nbytes):
    v = np.uint64(0)
    for j in range(nbytes):
        v |= np.uint64(buf[o + j]) << np.uint64(8 * j)
    return v


@numba.njit(cache=True)
def _build_records(order, chan, seq, t, pay, pay_off, pay_len, out, rec_off):
    """Message records of the messages ``order`` (in that order) into ``out`` at ``rec_off``."""
    for k in range(order.shape[0]):
        i = order[k]
        o = rec_off[k]
        n = pay_len[i]
        out[o] = OP_MESSAGE
        _put(out, o + 1, 22 + n, 8)
        _put(out, o + 9, chan[i], 2)
        _put(out, o + 11, seq[i], 4)
        _put(out, o + 15, t[i], 8)
        _put(out, o + 23, t[i], 8)
        p = pay_off[i]
        if n > 32:  # long (JSON) payloads: block copy; short (CAN) ones: the plain loop is faster
            out[o + 31 : o + 31 + n] = pay[p : p + n]
        else:
            for j in range(n):
                out[o + 31 + j] = pay[p + j]


@numba.njit(cache=True, nogil=True)
def _walk_chunk(buf, kind, cmap, k0, m0, t, cid, ext, dlc, data, rx, o_chan, o_t, o_off, o_len, counts):
    """One pass over the records of one decompressed chunk (runs without the GIL).

    CAN-channel messages (``kind[channel] == 1``) fill the frame columns from row ``k0``, other
    messages the (channel, log_time, offset, length) table from row ``m0``; ``counts[cmap[ch]]``
    counts messages per channel. Returns (k_end, m_end, n_bad_can, status): status < 0 = corrupt
    record stream; a CAN message of the wrong size or byte order is counted as bad and skipped.
    """
    n = buf.shape[0]
    i = 0
    k = k0
    m = m0
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
            if cmap[ch] < 0:
                return k, m, bad, -4
            counts[cmap[ch]] += 1
            lt = np.int64(_get(buf, i + 15, 8))
            p = i + 31
            plen = int(length) - 22
            if kind[ch] == 1:
                if plen != 19 or buf[p] != 0 or buf[p + 1] != 1:
                    bad += 1
                else:
                    t[k] = lt
                    cid[k] = np.uint32(_get(buf, p + 4, 4))
                    ext[k] = buf[p + 8] != 0
                    rx[k] = buf[p + 9] != 0
                    dlc[k] = buf[p + 10]
                    for j in range(8):
                        data[k, j] = buf[p + 11 + j]
                    k += 1
            else:
                o_chan[m] = ch
                o_t[m] = lt
                o_off[m] = p
                o_len[m] = plen
                m += 1
        i += 9 + int(length)
    return k, m, bad, 0


# ----------------------------------------------------------------------------- record helpers
def _str(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _map_str(d: Mapping[str, str]) -> bytes:
    body = b"".join(_str(k) + _str(v) for k, v in d.items())
    return struct.pack("<I", len(body)) + body


def can_payload(can_id: int, is_extended: bool, is_rx: bool, dlc: int, data: bytes) -> bytes:
    """CDR payload (19 bytes) of one CAN frame on ``/can/rx``/``/can/tx`` (layout in the module doc).

    For writers that use the ``mcap`` library directly (the live recorder): register the schema
    ``CAN_SCHEMA_NAME`` / ``"ros2msg"`` / ``CAN_SCHEMA_TEXT`` and channels with encoding ``"cdr"``.
    """
    d = bytes(data[:8]).ljust(8, b"\x00")
    return CDR_HEADER + struct.pack("<I??B", int(can_id), bool(is_extended), bool(is_rx), int(dlc)) + d


def can_payloads(frames: FrameBatch) -> np.ndarray:
    """CDR payloads of ``frames`` as a ``uint8[n, 19]`` array (layout in the module doc)."""
    n = len(frames)
    p = np.zeros((n, CAN_PAYLOAD_SIZE), np.uint8)
    p[:, 1] = 1
    p[:, 4:8] = frames.can_id.astype("<u4").view(np.uint8).reshape(n, 4)
    p[:, 8] = frames.is_extended
    p[:, 9] = frames.is_rx
    p[:, 10] = frames.dlc
    p[:, 11:19] = frames.data
    return p


@dataclass
class _Block:
    chan: np.ndarray  # uint16
    seq: np.ndarray  # uint32
    t: np.ndarray  # int64
    pay: np.ndarray  # uint8 flat
    off: np.ndarray  # int64
    length: np.ndarray  # int64


class McapWriter:
    """Writes an lde MCAP recording (CAN channels ``/can/rx`` and ``/can/tx`` + JSON channels).

    Messages are buffered and written sorted by ``log_time`` when the buffer passes
    ``buffer_bytes`` (and at :meth:`close`), in chunks of about ``chunk_size`` uncompressed bytes.
    Within one flush the order is by time, so a live recorder (monotonic times) gives a file in time
    order; bulk writers may write the CAN frames and the JSON records in any order before closing.

    Args:
        path: output file.
        compression: ``"zstd"`` (default), ``"lz4"`` or ``""``.
        chunk_size: uncompressed bytes per chunk [B].
        buffer_bytes: flush threshold of the message buffer [B].
        metadata: key/value strings stored as an MCAP metadata record ``lde`` (indexed in the
            summary, see :meth:`add_metadata`).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        compression: str = "zstd",
        chunk_size: int = 4 << 20,
        buffer_bytes: int = 256 << 20,
        profile: str = "",
        metadata: Mapping[str, str] | None = None,
    ) -> None:
        if compression == "zstd" and zstandard is None:  # pragma: no cover
            raise LogFormatError("zstd compression needs the 'zstandard' package")
        if compression == "lz4" and lz4frame is None:  # pragma: no cover
            raise LogFormatError("lz4 compression needs the 'lz4' package")
        if compression not in ("zstd", "lz4", ""):
            raise ValueError(f"unknown MCAP compression {compression!r}")
        self.path = Path(path)
        try:
            self._f = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise LogFormatError(f"{path}: cannot write: {exc}") from exc
        self._compression = compression
        self._chunk_size = int(chunk_size)
        self._buffer_bytes = int(buffer_bytes)
        self._schemas: list[bytes] = []
        self._channels: list[bytes] = []
        self._topics: dict[int, str] = {}
        self._seq: dict[int, int] = {}
        self._counts: dict[int, int] = {}
        self._chunk_indexes: list[bytes] = []
        self._pending: list[_Block] = []
        self._pending_bytes = 0
        self._single: list[tuple[int, int, bytes]] = []  # (channel, t, payload) of one-at-a-time writes
        self._t_min: int | None = None
        self._t_max = 0
        self._n_chunks = 0
        self._closed = False
        self._crc = zlib.crc32(MAGIC)

        self._write(MAGIC, crc=False)
        self._write(_record(OP_HEADER, _str(profile) + _str(f"lde {lde_version}")))
        can_schema = self._add_schema(CAN_SCHEMA_NAME, "ros2msg", CAN_SCHEMA_TEXT.encode())
        self.rx_channel = self._add_channel(TOPIC_RX, "cdr", can_schema)
        self.tx_channel = self._add_channel(TOPIC_TX, "cdr", can_schema)
        self._json_keys: dict[int, tuple[str, ...]] = {}
        self._metadata_indexes: list[bytes] = []
        if metadata:
            self.add_metadata("lde", metadata)

    # ------------------------------------------------------------------ low level
    def _write(self, b: bytes, crc: bool = True) -> None:
        if crc:
            self._crc = zlib.crc32(b, self._crc)
        self._f.write(b)

    def _add_schema(self, name: str, encoding: str, data: bytes) -> int:
        sid = len(self._schemas) + 1
        rec = _record(OP_SCHEMA, struct.pack("<H", sid) + _str(name) + _str(encoding) + _str_bytes(data))
        self._schemas.append(rec)
        self._write(rec)
        return sid

    def _add_channel(
        self, topic: str, encoding: str, schema_id: int, meta: Mapping[str, str] | None = None
    ) -> int:
        if topic in self._topics.values():
            raise ValueError(f"MCAP channel {topic!r} registered twice")
        cid = len(self._channels) + 1
        body = struct.pack("<HH", cid, schema_id) + _str(topic) + _str(encoding) + _map_str(dict(meta or {}))
        rec = _record(OP_CHANNEL, body)
        self._channels.append(rec)
        self._topics[cid] = topic
        self._seq[cid] = 0
        self._counts[cid] = 0
        self._write(rec)
        return cid

    # ------------------------------------------------------------------ public API
    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Write a metadata record ``name`` (string keys and values) now, and its metadata index
        into the summary (so that ``mcap``'s ``iter_metadata()`` and Foxglove find it)."""
        rec = _record(OP_METADATA, _str(name) + _map_str({str(k): str(v) for k, v in data.items()}))
        offset = self._f.tell()
        self._write(rec)
        self._metadata_indexes.append(
            _record(OP_METADATA_INDEX, struct.pack("<QQ", offset, len(rec)) + _str(name))
        )

    def add_json_channel(
        self,
        topic: str,
        schema_props: Mapping[str, Mapping[str, Any]] | Iterable[str],
        title: str | None = None,
    ) -> int:
        """Register a JSON channel of flat objects; returns its channel id.

        ``schema_props`` maps each field name to its JSON-schema property (e.g.
        ``{"Fw": {"type": "number", "description": "N, left positive"}}``); a plain list of names
        makes them all numbers.
        """
        if not isinstance(schema_props, Mapping):
            schema_props = {k: {"type": "number"} for k in schema_props}
        schema = {
            "type": "object",
            "title": title or topic,
            "properties": {k: dict(v) for k, v in schema_props.items()},
        }
        sid = self._add_schema(
            title or topic.strip("/").replace("/", "_"), "jsonschema", json.dumps(schema).encode()
        )
        cid = self._add_channel(topic, "json", sid)
        self._json_keys[cid] = tuple(schema_props)
        return cid

    def write_frames(self, frames: FrameBatch) -> None:
        """Queue CAN frames: rx frames on ``/can/rx``, the others on ``/can/tx``."""
        n = len(frames)
        if n == 0:
            return
        pay = can_payloads(frames).reshape(-1)
        chan = np.where(frames.is_rx, self.rx_channel, self.tx_channel).astype(np.uint16)
        seq = np.empty(n, np.uint32)
        for c in (self.rx_channel, self.tx_channel):
            sel = chan == c
            k = int(np.count_nonzero(sel))
            seq[sel] = (np.arange(k, dtype=np.int64) + self._seq[c]) % (1 << 32)
            self._seq[c] += k
            self._counts[c] += k
        off = np.arange(n, dtype=np.int64) * CAN_PAYLOAD_SIZE
        self._queue(
            _Block(chan, seq, frames.t_ns.astype(np.int64), pay, off, np.full(n, CAN_PAYLOAD_SIZE, np.int64))
        )

    def write_frame(
        self, t_ns: int, can_id: int, is_extended: bool, dlc: int, data: bytes, is_rx: bool
    ) -> None:
        """Queue one CAN frame (the live recorder's path)."""
        pay = can_payload(can_id, is_extended, is_rx, dlc, data)
        self._queue_single(self.rx_channel if is_rx else self.tx_channel, int(t_ns), pay)

    def write_json(self, channel_id: int, t_ns: int, record: Mapping[str, Any]) -> None:
        """Queue one JSON message (a flat object of numbers) on a channel from :meth:`add_json_channel`."""
        if channel_id not in self._json_keys:
            raise ValueError(f"channel {channel_id} is not a JSON channel of this writer")
        self._queue_single(channel_id, int(t_ns), json.dumps(_plain(record), allow_nan=True).encode())

    def write_json_columns(
        self, channel_id: int, t_ns: np.ndarray, columns: Mapping[str, np.ndarray]
    ) -> None:
        """Queue one JSON message per row of ``columns`` (bulk form of :meth:`write_json`)."""
        if channel_id not in self._json_keys:
            raise ValueError(f"channel {channel_id} is not a JSON channel of this writer")
        t = np.asarray(t_ns, dtype=np.int64)
        n = t.size
        if n == 0:
            return
        texts = _json_rows(columns, n)
        pay = np.frombuffer("".join(texts).encode(), np.uint8)
        length = np.fromiter((len(s) for s in texts), np.int64, n)
        off = np.zeros(n, np.int64)
        np.cumsum(length[:-1], out=off[1:])
        seq = (np.arange(n, dtype=np.int64) + self._seq[channel_id]) % (1 << 32)
        self._seq[channel_id] += n
        self._counts[channel_id] += n
        self._queue(_Block(np.full(n, channel_id, np.uint16), seq.astype(np.uint32), t, pay, off, length))

    def write_json_payloads(
        self, channel_id: int, t_ns: np.ndarray, text: np.ndarray, offsets: np.ndarray
    ) -> None:
        """Queue pre-formatted JSON messages: message ``i`` is ``text[offsets[i]:offsets[i + 1]]``
        (the output of :func:`lde.logio.textfmt.format_rows`)."""
        if channel_id not in self._json_keys:
            raise ValueError(f"channel {channel_id} is not a JSON channel of this writer")
        t = np.asarray(t_ns, dtype=np.int64)
        n = t.size
        off = np.asarray(offsets, np.int64)
        if off.shape != (n + 1,):
            raise ValueError(f"offsets must have {n + 1} entries, got {off.shape}")
        if n == 0:
            return
        seq = (np.arange(n, dtype=np.int64) + self._seq[channel_id]) % (1 << 32)
        self._seq[channel_id] += n
        self._counts[channel_id] += n
        pay = np.frombuffer(text, np.uint8) if not isinstance(text, np.ndarray) else text
        self._queue(
            _Block(np.full(n, channel_id, np.uint16), seq.astype(np.uint32), t, pay, off[:-1], np.diff(off))
        )

    def flush(self) -> None:
        """Write every queued message (sorted by time) as chunks."""
        self._flush_single()
        if not self._pending:
            return
        blocks = self._pending
        self._pending = []
        self._pending_bytes = 0
        chan = np.concatenate([b.chan for b in blocks])
        seq = np.concatenate([b.seq for b in blocks])
        t = np.concatenate([b.t for b in blocks])
        length = np.concatenate([b.length for b in blocks])
        pays = [b.pay for b in blocks]
        base = np.cumsum([0] + [p.size for p in pays[:-1]])
        off = np.concatenate([b.off + base[i] for i, b in enumerate(blocks)])
        pay = np.concatenate(pays) if len(pays) > 1 else pays[0]
        # one chunk stream ("lane") per channel: a reader decompresses only the channels it wants
        # (replay: /can/rx), the others' log times and counts are in the message indexes
        for lane_id in np.unique(chan).tolist():
            idx = np.flatnonzero(chan == lane_id)
            order = idx[np.argsort(t[idx], kind="stable")]
            self._write_lane(order, chan, seq, t, pay, off, length)
        t_lo, t_hi = int(t.min()), int(t.max())
        self._t_min = t_lo if self._t_min is None else min(self._t_min, t_lo)
        self._t_max = max(self._t_max, t_hi)

    def sync(self, fsync: bool = False) -> None:
        """:meth:`flush`, then push the file's buffer to the OS (a killed process loses nothing
        written so far; ``fsync`` also survives a power loss, at a cost)."""
        self.flush()
        self._f.flush()
        if fsync:
            os.fsync(self._f.fileno())

    def _write_lane(self, order, chan, seq, t, pay, off, length) -> None:
        """Message records of ``order`` (time-sorted) as chunks of about ``chunk_size`` bytes."""
        rec_len = _MSG_OVERHEAD + length[order]
        rec_end = np.cumsum(rec_len)
        rec_off = rec_end - rec_len
        out = np.empty(int(rec_end[-1]), np.uint8)
        _build_records(order, chan, seq, t, pay, off, length, out, rec_off)
        # chunk boundaries: cut after the record that crosses each multiple of chunk_size
        cuts = np.searchsorted(
            rec_end, np.arange(self._chunk_size, int(rec_end[-1]), self._chunk_size), side="left"
        )
        bounds = np.unique(np.concatenate([[0], cuts + 1, [order.size]]))
        bounds = bounds[bounds <= order.size]
        for a, b in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
            if b > a:
                self._write_chunk(out, rec_off, rec_end, order, chan, t, a, b)

    def close(self) -> None:
        """Flush, then write the data end, the summary (schemas, channels, statistics, chunk
        indexes, metadata indexes, summary offsets), the footer and the closing magic."""
        if self._closed:
            return
        self.flush()
        self._write(_record(OP_DATA_END, struct.pack("<I", self._crc)))
        summary_start = self._f.tell()
        parts: list[bytes] = []
        offsets: list[bytes] = []
        pos = summary_start
        n_msgs = sum(self._counts.values())
        stats = struct.pack(
            "<QHIIIIQQ",
            n_msgs,
            len(self._schemas),
            len(self._channels),
            0,
            len(self._metadata_indexes),
            self._n_chunks,
            self._t_min or 0,
            self._t_max,
        )
        counts = b"".join(struct.pack("<HQ", c, k) for c, k in self._counts.items())
        stats += struct.pack("<I", len(counts)) + counts
        for op, recs in (
            (OP_SCHEMA, self._schemas),
            (OP_CHANNEL, self._channels),
            (OP_STATISTICS, [_record(OP_STATISTICS, stats)]),
            (OP_CHUNK_INDEX, self._chunk_indexes),
            (OP_METADATA_INDEX, self._metadata_indexes),
        ):
            group = b"".join(recs)
            if not group:
                continue
            offsets.append(_record(OP_SUMMARY_OFFSET, struct.pack("<BQQ", op, pos, len(group))))
            parts.append(group)
            pos += len(group)
        summary_offset_start = pos
        summary = b"".join(parts) + b"".join(offsets)
        footer_head = struct.pack("<BQQQ", OP_FOOTER, 20, summary_start, summary_offset_start)
        crc = zlib.crc32(footer_head, zlib.crc32(summary))
        self._f.write(summary)
        self._f.write(footer_head + struct.pack("<I", crc))
        self._f.write(MAGIC)
        self._f.close()
        self._closed = True

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _queue(self, block: _Block) -> None:
        self._pending.append(block)
        self._pending_bytes += int(block.pay.size) + _MSG_OVERHEAD * int(block.t.size)
        if self._pending_bytes > self._buffer_bytes:
            self.flush()

    def _queue_single(self, chan: int, t_ns: int, payload: bytes) -> None:
        self._single.append((chan, t_ns, payload))
        self._counts[chan] += 1
        if len(self._single) >= 65536:
            self._flush_single()

    def _flush_single(self) -> None:
        if not self._single:
            return
        items = self._single
        self._single = []
        n = len(items)
        chan = np.fromiter((c for c, _, _ in items), np.uint16, n)
        t = np.fromiter((t for _, t, _ in items), np.int64, n)
        length = np.fromiter((len(p) for _, _, p in items), np.int64, n)
        off = np.zeros(n, np.int64)
        np.cumsum(length[:-1], out=off[1:])
        pay = np.frombuffer(b"".join(p for _, _, p in items), np.uint8)
        seq = np.empty(n, np.uint32)
        for c in np.unique(chan).tolist():
            sel = chan == c
            k = int(np.count_nonzero(sel))
            seq[sel] = (np.arange(k, dtype=np.int64) + self._seq[c]) % (1 << 32)
            self._seq[c] += k
        block = _Block(chan, seq, t, pay, off, length)
        self._pending.append(block)
        self._pending_bytes += int(pay.size) + _MSG_OVERHEAD * n
        if self._pending_bytes > self._buffer_bytes:
            self.flush()

    def _write_chunk(self, out, rec_off, rec_end, order, chan, t, a: int, b: int) -> None:
        start = int(rec_off[a])
        raw = out[start : int(rec_end[b - 1])].tobytes()
        idx = order[a:b]
        ts = t[idx]
        t0, t1 = int(ts.min()), int(ts.max())
        if self._compression == "zstd":
            comp = zstandard.ZstdCompressor(level=1, write_checksum=True).compress(raw)
        elif self._compression == "lz4":
            comp = lz4frame.compress(raw)
        else:
            comp = raw
        body = struct.pack("<QQQI", t0, t1, len(raw), zlib.crc32(raw)) + _str(self._compression)
        chunk_rec = (
            struct.pack("<BQ", OP_CHUNK, len(body) + 8 + len(comp)) + body + struct.pack("<Q", len(comp))
        )
        chunk_start = self._f.tell()
        self._write(chunk_rec)
        self._write(comp)
        chunk_len = len(chunk_rec) + len(comp)
        # message indexes: per channel (log_time, offset of the record in the uncompressed chunk)
        ch = chan[idx]
        rel = (rec_off[a:b] - start).astype(np.uint64)
        mi_start = self._f.tell()
        mi_offsets: list[tuple[int, int]] = []
        pos = mi_start
        for c in np.unique(ch).tolist():
            sel = ch == c
            pairs = np.empty((int(np.count_nonzero(sel)), 2), "<u8")
            pairs[:, 0] = ts[sel]
            pairs[:, 1] = rel[sel]
            body_mi = struct.pack("<HI", c, pairs.nbytes) + pairs.tobytes()
            rec = _record(OP_MESSAGE_INDEX, body_mi)
            self._write(rec)
            mi_offsets.append((c, pos))
            pos += len(rec)
        offsets_blob = b"".join(struct.pack("<HQ", c, o) for c, o in mi_offsets)
        ci = (
            struct.pack("<QQQQ", t0, t1, chunk_start, chunk_len)
            + struct.pack("<I", len(offsets_blob))
            + offsets_blob
            + struct.pack("<Q", pos - mi_start)
            + _str(self._compression)
            + struct.pack("<QQ", len(comp), len(raw))
        )
        self._chunk_indexes.append(_record(OP_CHUNK_INDEX, ci))
        self._n_chunks += 1


def _str_bytes(b: bytes) -> bytes:
    return struct.pack("<I", len(b)) + b


def _plain(record: Mapping[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in record.items():
        if isinstance(v, (bool, np.bool_)):
            out[k] = bool(v)
        elif isinstance(v, (int, np.integer)):
            out[k] = int(v)
        else:
            f = float(v)
            out[k] = f if math.isfinite(f) else None
    return out


def _json_rows(columns: Mapping[str, np.ndarray], n: int) -> list[str]:
    """One compact JSON object per row (floats with repr precision; NaN/inf -> null)."""
    cols: list[list[str]] = []
    for name, col in columns.items():
        a = np.asarray(col)
        if a.shape != (n,):
            raise ValueError(f"JSON column {name!r} has shape {a.shape}, expected ({n},)")
        key = json.dumps(name)
        if a.dtype == np.bool_:
            vals = ["true" if x else "false" for x in a.tolist()]
        elif np.issubdtype(a.dtype, np.integer):
            vals = [str(x) for x in a.tolist()]
        else:
            vals = [repr(x) if math.isfinite(x) else "null" for x in a.astype(np.float64).tolist()]
        cols.append([f"{key}:{v}" for v in vals])
    return ["{" + ",".join(row) + "}" for row in zip(*cols, strict=True)] if cols else ["{}"] * n


# ----------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class TopicInfo:
    """One channel of an MCAP file: topic, encodings, schema name and message count."""

    topic: str
    channel_id: int
    message_encoding: str
    schema_name: str
    schema_encoding: str
    count: int


@dataclass
class McapData:
    """What :func:`read_mcap` returns.

    Attributes:
        frames: the CAN frames of every ``lde_msgs/msg/CanFrame`` channel, sorted by time.
        topics: topic -> :class:`TopicInfo` for every channel with messages or declared.
        times: topic -> int64 ``log_time`` array [ns] of every non-CAN channel (cheap, always there).
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


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    if compression == "":
        return data
    if compression == "zstd":
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
    if compression == "lz4":
        return lz4frame.decompress(data)
    raise LogFormatError(f"unsupported MCAP chunk compression {compression!r}")


def _summary(f: io.BufferedReader):

    return SeekingReader(f).get_summary()


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
    """Read an lde MCAP file (layout in the module doc).

    Args:
        json_topics: JSON topics to return as columns (``"all"`` for every JSON channel).
        json_optional: a topic of ``json_topics`` that the file does not have is left out of
            ``json`` instead of raising (for channels only some recordings have).
        require_can: raise :class:`LogFormatError` if the file has no CAN channel.
        force_library: use the ``mcap`` library's per-message reader (the reference path).
        validate_crcs: check each chunk's CRC-32 (a corrupt chunk then always raises).
        skip_tx: do not decompress chunks that hold only ``/can/tx`` (lde's own sent frames, which a
            replay does not use): ``frames`` then holds the received frames (and any tx frame that
            shares a chunk with them); ``topics["/can/tx"].count`` still counts them all.

    Raises:
        LogFormatError: not an MCAP file, corrupt, or (with ``require_can``) no CAN channel.
    """
    p = Path(path)
    try:
        fh = p.open("rb")
    except OSError as exc:
        raise LogFormatError(f"{p}: cannot read: {exc}") from exc
    with fh:
        size = os.fstat(fh.fileno()).st_size
        if size == 0:
            raise LogFormatError(f"{p}: empty file")
        # memory-mapped: chunks that are not needed are never read from disk
        raw = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        if raw[: len(MAGIC)] != MAGIC:
            raise LogFormatError(f"{p}: not an MCAP file (no MCAP magic)")
        try:
            summary = None if force_library else _summary(fh)
        except Exception:  # noqa: BLE001 - a damaged summary: the linear library reader decides
            summary = None
        try:
            if summary is not None and summary.chunk_indexes:
                data = _read_fast(raw, summary, validate_crcs, json_topics, skip_tx)
            elif not force_library and (scan := _scan_top_level(raw)) is not None:
                data = _read_fast(raw, scan, validate_crcs, json_topics, skip_tx)
                data.truncated = scan.truncated
            else:
                fh.seek(0)
                data = _read_library(fh)
        except LogFormatError as exc:
            raise LogFormatError(f"{p}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - the mcap library raises many types on corrupt input
            raise LogFormatError(f"{p}: corrupt MCAP file ({type(exc).__name__}: {exc})") from exc
        data.metadata = _read_metadata(raw, summary)
    if require_can and not any(ti.schema_name == CAN_SCHEMA_NAME for ti in data.topics.values()):
        names = ", ".join(sorted(data.topics)) or "none"
        raise LogFormatError(
            f"{p}: no CAN channel (schema {CAN_SCHEMA_NAME}) in this MCAP file; topics: {names}"
        )
    _fill_json(data, json_topics, json_optional)
    return data


def _parse_metadata(raw, o: int) -> tuple[str, dict[str, str]] | None:
    """(name, key/value map) of the metadata record at offset ``o``; None if there is none."""
    if o + 9 > len(raw) or raw[o] != OP_METADATA:
        return None
    (length,) = struct.unpack_from("<Q", raw, o + 1)
    end = o + 9 + length
    if end > len(raw):
        return None
    body = bytes(raw[o + 9 : end])

    def text(i: int) -> tuple[str, int]:
        (n,) = struct.unpack_from("<I", body, i)
        if i + 4 + n > len(body):
            raise ValueError("string past the record")
        return body[i + 4 : i + 4 + n].decode("utf-8"), i + 4 + n

    try:
        name, i = text(0)
        (map_len,) = struct.unpack_from("<I", body, i)
        i += 4
        stop = i + map_len
        out: dict[str, str] = {}
        while i < stop:
            k, i = text(i)
            v, i = text(i)
            out[k] = v
    except (struct.error, ValueError, UnicodeDecodeError):
        return None
    return name, out


def _read_metadata(raw, summary) -> dict[str, dict[str, str]]:
    """The metadata records of the file: through the summary's metadata indexes when it has them,
    else by walking the top-level records (a file without summary or index; stops at the data end,
    the footer or a record cut short). A damaged record is left out, never fatal."""
    offsets = [int(mi.offset) for mi in (getattr(summary, "metadata_indexes", None) or [])]
    if not offsets:
        pos, n = len(MAGIC), len(raw)
        while pos + 9 <= n:
            op = raw[pos]
            if op in (OP_DATA_END, OP_FOOTER):
                break
            (length,) = struct.unpack_from("<Q", raw, pos + 1)
            if op == OP_METADATA:
                offsets.append(pos)
            pos += 9 + int(length)
    out: dict[str, dict[str, str]] = {}
    for o in offsets:
        rec = _parse_metadata(raw, o)
        if rec is not None:
            out.setdefault(rec[0], {}).update(rec[1])
    return out


def _wanted_json_ids(
    summary_channels: Mapping[int, Any], json_topics: Iterable[str] | str | None
) -> set[int]:
    if json_topics is None:
        return set()
    if json_topics == "all":
        return {cid for cid, ch in summary_channels.items() if ch.message_encoding == "json"}
    wanted = {json_topics} if isinstance(json_topics, str) else set(json_topics)
    return {cid for cid, ch in summary_channels.items() if ch.topic in wanted}


def _index_times(
    raw, ci, kind: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray], dict[int, int]] | None:
    """From a chunk's message index records: (channels, log times) of its non-CAN messages and the
    message count per CAN channel; None if it has no (valid) message index."""
    if not ci.message_index_offsets:
        return None
    chans, times, can_counts = [], [], {}
    for ch, o in ci.message_index_offsets.items():
        if o + 15 > len(raw) or raw[o] != OP_MESSAGE_INDEX:
            return None
        (n_bytes,) = struct.unpack_from("<I", raw, o + 11)
        if o + 15 + n_bytes > len(raw) or n_bytes % 16:
            return None
        if kind[ch] == 1:
            can_counts[ch] = n_bytes // 16
            continue
        pairs = np.frombuffer(raw, "<u8", count=n_bytes // 8, offset=o + 15).reshape(-1, 2)
        times.append(pairs[:, 0].astype(np.int64))
        chans.append(np.full(pairs.shape[0], ch, np.uint16))
    return chans, times, can_counts


@dataclass
class _ChunkRef:
    chunk_start_offset: int
    message_index_offsets: dict[int, int] = field(default_factory=dict)


@dataclass
class _Scan:
    """A summary rebuilt by a linear scan (same attributes as ``mcap.summary.Summary`` uses here)."""

    schemas: dict[int, Any]
    channels: dict[int, Any]
    chunk_indexes: list[_ChunkRef]
    truncated: bool


def _scan_top_level(raw) -> _Scan | None:
    """Schemas, channels and chunks of a file without summary, by walking its top-level records.

    Stops at the data end record, at the end of the file, or at a record cut short (``truncated``).
    Returns None when the file has messages outside chunks or schema/channel records only inside
    chunks (the ``mcap`` library reads those).

    Raises:
        LogFormatError: the file is cut before or inside its first chunk (nothing to recover).
    """

    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    chunks: list[_ChunkRef] = []
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
        if op in (OP_SCHEMA, OP_CHANNEL):
            body = ReadDataStream(io.BytesIO(bytes(raw[pos + 9 : pos + 9 + length])))
            if op == OP_SCHEMA:
                rec = Schema.read(body)
                schemas[rec.id] = rec
            else:
                rec = Channel.read(body)
                channels[rec.id] = rec
        elif op == OP_CHUNK:
            chunks.append(_ChunkRef(pos))
        elif op == OP_MESSAGE:
            return None
        elif op in (OP_DATA_END, OP_FOOTER):
            break
        pos += 9 + int(length)
    if truncated and not chunks:
        where = "inside its first chunk" if cut_op == OP_CHUNK else f"at byte {n}, before its first chunk"
        raise LogFormatError(f"truncated MCAP file: cut {where}; no complete chunk of frames")
    if not channels or not chunks:
        return None
    return _Scan(schemas, channels, chunks, truncated)


def _chunk_header(raw, o: int) -> tuple[str, int, int, int, int]:
    """(compression, uncompressed size, crc, records start, records length) of the chunk at ``o``."""
    if raw[o] != OP_CHUNK:
        raise LogFormatError(f"chunk index points at opcode {raw[o]:#x}, not a chunk, at offset {o}")
    _t0, _t1, usize, ucrc = struct.unpack_from("<QQQI", raw, o + 9)
    (clen,) = struct.unpack_from("<I", raw, o + 37)
    comp = bytes(raw[o + 41 : o + 41 + clen]).decode()
    (dlen,) = struct.unpack_from("<Q", raw, o + 41 + clen)
    start = o + 49 + clen
    if start + dlen > len(raw):
        raise LogFormatError(f"chunk at offset {o} runs past the end of the file (truncated?)")
    return comp, usize, ucrc, start, dlen


def _read_fast(
    raw,
    summary,
    validate_crcs: bool,
    json_topics: Iterable[str] | str | None = None,
    skip_tx: bool = False,
) -> McapData:
    kind = np.zeros(65536, np.int8)
    cmap = np.full(65536, -1, np.int64)  # channel id -> compact index into the counts; -1 undeclared
    topics: dict[str, TopicInfo] = {}
    chan_ids = sorted(summary.channels)
    for idx, cid_ in enumerate(chan_ids):
        ch = summary.channels[cid_]
        sch = summary.schemas.get(ch.schema_id)
        sname = sch.name if sch else ""
        if sname == CAN_SCHEMA_NAME:
            kind[cid_] = 1
        cmap[cid_] = idx
        topics[ch.topic] = TopicInfo(
            ch.topic, cid_, ch.message_encoding, sname, sch.encoding if sch else "", 0
        )
    n_ch = max(len(chan_ids), 1)
    if chan_ids and max(chan_ids) >= 65536:  # pragma: no cover - channel ids are uint16
        raise LogFormatError("channel id out of range")

    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    # chunks holding only channels nobody asked for (JSON lanes) are not decompressed: their log
    # times and counts come from their message index records
    json_ids = _wanted_json_ids(summary.channels, json_topics)
    needed = {int(c) for c in np.flatnonzero(kind == 1)} | json_ids
    if skip_tx:
        needed -= {cid_ for cid_, ch in summary.channels.items() if ch.topic == TOPIC_TX}
    skip_chans: list[np.ndarray] = []
    skip_times: list[np.ndarray] = []
    skip_can = np.zeros(65536, np.int64)
    keep: list[Any] = []
    for ci in chunks:
        chans = set(ci.message_index_offsets)
        found = None if (not chans or chans & needed) else _index_times(raw, ci, kind)
        if found is None:
            keep.append(ci)
        else:
            skip_chans += found[0]
            skip_times += found[1]
            for ch, k in found[2].items():
                skip_can[ch] += k
    n_skipped = len(chunks) - len(keep)
    chunks = keep
    heads = [_chunk_header(raw, ci.chunk_start_offset) for ci in chunks]
    # rows per chunk: at most one message per 31 bytes of records; the arrays are allocated at that
    # bound (pages never touched cost nothing) and compacted afterwards
    bound = np.array([h[1] // _MSG_OVERHEAD + 1 for h in heads], np.int64)
    start = np.concatenate([[0], np.cumsum(bound)])
    total = int(start[-1])
    t = np.empty(total, np.int64)
    cid = np.empty(total, np.uint32)
    ext = np.empty(total, np.bool_)
    dlc = np.empty(total, np.uint8)
    data = np.empty((total, 8), np.uint8)
    rx = np.empty(total, np.bool_)
    o_chan = np.empty(total, np.uint16)
    o_t = np.empty(total, np.int64)
    o_off = np.empty(total, np.int64)
    o_len = np.empty(total, np.int64)
    counts = np.zeros((len(chunks), n_ch), np.int64)
    results: list[tuple[int, int, int, int]] = [(0, 0, 0, 0)] * len(chunks)
    bufs: dict[int, np.ndarray] = {}

    def work(i: int) -> None:
        comp, usize, ucrc, st, dlen = heads[i]
        off = chunks[i].chunk_start_offset
        out = _decompress(comp, raw[st : st + dlen], usize)
        if len(out) != usize:
            raise LogFormatError(
                f"chunk at offset {off}: {len(out)} bytes after decompression, expected {usize}"
            )
        if validate_crcs and ucrc and zlib.crc32(out) != ucrc:
            raise LogFormatError(f"chunk at offset {off}: CRC mismatch")
        buf = np.frombuffer(out, np.uint8)
        k0 = m0 = int(start[i])
        results[i] = _walk_chunk(
            buf, kind, cmap, k0, m0, t, cid, ext, dlc, data, rx, o_chan, o_t, o_off, o_len, counts[i]
        )
        if results[i][3] == -4:
            raise LogFormatError(f"chunk at offset {off}: a message of an undeclared channel")
        if results[i][3] < 0:
            raise LogFormatError(f"chunk at offset {off}: corrupt record")
        chans = set(chunks[i].message_index_offsets)
        if json_ids and (not chans or chans & json_ids):
            bufs[i] = buf

    if len(chunks) > 2:
        with ThreadPoolExecutor(max_workers=2) as pool:
            list(pool.map(work, range(len(chunks))))
    else:
        for i in range(len(chunks)):
            work(i)
    can_sl = [slice(int(start[i]), int(r[0])) for i, r in enumerate(results)]
    oth_sl = [slice(int(start[i]), int(r[1])) for i, r in enumerate(results)]

    def compact(a: np.ndarray, sl: list[slice]) -> np.ndarray:
        return np.concatenate([a[x] for x in sl]) if sl else a[:0]

    frames = FrameBatch(
        t_ns=compact(t, can_sl),
        can_id=compact(cid, can_sl),
        is_extended=compact(ext, can_sl),
        dlc=compact(dlc, can_sl),
        data=compact(data, can_sl),
        is_rx=compact(rx, can_sl),
    ).sort()
    o_chunk = np.concatenate(
        [np.full(r[1] - start[i], i, np.int32) for i, r in enumerate(results)] or [np.zeros(0, np.int32)]
    )
    o_chan, o_t = compact(o_chan, oth_sl), compact(o_t, oth_sl)
    o_off, o_len = compact(o_off, oth_sl), compact(o_len, oth_sl)
    ch_counts = np.zeros(65536, np.int64)
    ch_counts[chan_ids] = counts.sum(axis=0)[: len(chan_ids)]
    ch_counts += skip_can
    if skip_chans:
        sc = np.concatenate(skip_chans)
        ch_counts += np.bincount(sc, minlength=65536)
        o_chan = np.concatenate([o_chan, sc])
        o_t = np.concatenate([o_t, *skip_times])
        o_off = np.concatenate([o_off, np.full(sc.size, -1, np.int64)])  # payload not read
        o_len = np.concatenate([o_len, np.zeros(sc.size, np.int64)])
        o_chunk = np.concatenate([o_chunk, np.full(sc.size, -1, np.int32)])
    out = McapData(
        frames=frames,
        topics=topics,
        bad_can_messages=int(sum(r[2] for r in results)),
        fast_path=True,
        chunks_read=len(chunks),
        chunks_skipped=n_skipped,
    )
    out._other = (bufs, o_chunk, o_chan, o_t, o_off, o_len)  # type: ignore[attr-defined]
    _finish_topics(out, kind, ch_counts)
    return out


def _finish_topics(out: McapData, kind: np.ndarray, counts: np.ndarray) -> None:
    """Message counts per topic and the sorted log times of the non-CAN topics."""
    _bufs, _o_chunk, o_chan, o_t, _o_off, _o_len = out._other  # type: ignore[attr-defined]
    for topic, ti in list(out.topics.items()):
        out.topics[topic] = TopicInfo(**{**ti.__dict__, "count": int(counts[ti.channel_id])})
        if kind[ti.channel_id] != 1:
            ts = o_t[o_chan == ti.channel_id]
            out.times[topic] = ts[np.argsort(ts, kind="stable")]


def _read_library(fh: IO[bytes]) -> McapData:
    """The reference path: the ``mcap`` library's reader, one Python object per message."""

    reader = make_reader(fh)
    t: list[int] = []
    payload = bytearray()
    o_chan: list[int] = []
    o_t: list[int] = []
    o_off: list[int] = []
    o_len: list[int] = []
    other = bytearray()
    topics: dict[str, TopicInfo] = {}
    kind = np.zeros(65536, np.int8)
    bad = 0
    counts = np.zeros(65536, np.int64)
    for schema, channel, message in reader.iter_messages(log_time_order=True):
        counts[channel.id] += 1
        if channel.topic not in topics:
            sname = schema.name if schema else ""
            topics[channel.topic] = TopicInfo(
                channel.topic,
                channel.id,
                channel.message_encoding,
                sname,
                schema.encoding if schema else "",
                0,
            )
            kind[channel.id] = 1 if sname == CAN_SCHEMA_NAME else 0
        if kind[channel.id] == 1:
            d = message.data
            if len(d) != CAN_PAYLOAD_SIZE or d[:2] != CDR_HEADER[:2]:
                bad += 1
                continue
            t.append(message.log_time)
            payload += d
        else:
            o_chan.append(channel.id)
            o_t.append(message.log_time)
            o_off.append(len(other))
            o_len.append(len(message.data))
            other += message.data
    # channels declared without messages (summary), when there is one
    summary = reader.get_summary()
    if summary is not None:
        for cid, ch in summary.channels.items():
            if ch.topic not in topics:
                sch = summary.schemas.get(ch.schema_id)
                sname = sch.name if sch else ""
                kind[cid] = 1 if sname == CAN_SCHEMA_NAME else 0
                topics[ch.topic] = TopicInfo(
                    ch.topic, cid, ch.message_encoding, sname, sch.encoding if sch else "", 0
                )
    n = len(t)
    p = np.frombuffer(bytes(payload), np.uint8).reshape(n, CAN_PAYLOAD_SIZE)
    frames = FrameBatch(
        t_ns=np.array(t, np.int64),
        can_id=p[:, 4:8].copy().view("<u4").reshape(n),
        is_extended=p[:, 8] != 0,
        dlc=p[:, 10],
        data=p[:, 11:19],
        is_rx=p[:, 9] != 0,
    ).sort()
    out = McapData(frames=frames, topics=topics, bad_can_messages=bad, fast_path=False)
    out._other = (  # type: ignore[attr-defined]
        {0: np.frombuffer(bytes(other), np.uint8)},
        np.zeros(len(o_chan), np.int32),
        np.array(o_chan, np.uint16),
        np.array(o_t, np.int64),
        np.array(o_off, np.int64),
        np.array(o_len, np.int64),
    )
    _finish_topics(out, kind, counts)
    return out


def _fill_json(data: McapData, json_topics: Iterable[str] | str | None, optional: bool = False) -> None:
    bufs, o_chunk, o_chan, o_t, o_off, o_len = data._other  # type: ignore[attr-defined]
    del data._other  # type: ignore[attr-defined]
    if json_topics is None:
        return
    if json_topics == "all":
        wanted = [t for t, ti in data.topics.items() if ti.message_encoding == "json"]
    else:
        wanted = [json_topics] if isinstance(json_topics, str) else list(json_topics)
    for topic in wanted:
        ti = data.topics.get(topic)
        if ti is None and optional:
            continue
        if ti is None:
            raise LogFormatError(f"no topic {topic!r} in this MCAP file")
        if ti.message_encoding != "json":
            raise LogFormatError(f"topic {topic!r} is {ti.message_encoding!r}, not json")
        idx = np.flatnonzero(o_chan == ti.channel_id)
        idx = idx[np.argsort(o_t[idx], kind="stable")]
        if np.any(o_off[idx] < 0):  # pragma: no cover - asked-for channels are always decompressed
            raise LogFormatError(f"topic {topic!r}: payloads were not read")
        views = {c: memoryview(b) for c, b in bufs.items()}
        parts = [
            views[c][o : o + n]
            for c, o, n in zip(o_chunk[idx].tolist(), o_off[idx].tolist(), o_len[idx].tolist(), strict=True)
        ]
        text = b"[" + b",".join(parts) + b"]"
        try:
            rows = json.loads(text)
        except ValueError as exc:
            raise LogFormatError(f"topic {topic!r}: a message is not valid JSON ({exc})") from exc
        keys: dict[str, None] = {}
        for r in rows:
            if not isinstance(r, dict):
                raise LogFormatError(f"topic {topic!r}: a message is not a JSON object")
            for k in r:
                keys.setdefault(k, None)
        log_t = o_t[idx].copy()
        cols: dict[str, np.ndarray] = {}
        for k in keys:
            vals = [r.get(k) for r in rows]
            if all(type(v) is int for v in vals):
                cols[k] = np.array(vals, dtype=np.int64)  # exact (step times in ns)
            else:
                cols[k] = np.array([math.nan if v is None else v for v in vals], dtype=np.float64)
        cols.setdefault("t_ns", log_t)
        cols["log_time"] = log_t
        data.json[topic] = cols
