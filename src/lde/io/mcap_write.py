"""Writing lde's MCAP files: :class:`McapWriter` (CAN channels ``/can/rx``, ``/can/tx`` and JSON
channels), readable by the ``mcap`` library, Foxglove and python-can (through :mod:`lde.io.mcap_can`).

Messages are buffered, sorted by ``log_time`` and written as compressed chunks (zstd by default, as
Foxglove writes them; lz4 or none selectable) whose records a numba kernel builds. **Each channel
goes to its own chunks** ("lanes": chunk time ranges of different channels overlap, which MCAP
allows), so a reader decompresses only the channels it wants.

Two layouts (``indexed``):

* compact (default): no message index for the CAN channels and no chunk indexes in the summary.
  A message index costs 16 bytes per message outside the compressed chunks, more than a compressed
  CAN frame (~17 bytes): without them an hour of traffic takes ~37 % of its candump text instead of
  ~71 %. Readers read such a file front to back (the ``mcap`` library's readers do that by
  themselves; Foxglove loads it whole, up to 1 GB). JSON channels keep their message indexes
  after each chunk (lde's reader takes step times from them without decompressing the chunk).
* indexed: message indexes for every chunk and chunk indexes in the summary: random access (seeking
  in Foxglove, ``mcap``'s ``SeekingReader``), at 16 bytes per message.

Both end with the summary (schemas, channels, statistics with per-channel message counts,
metadata indexes, summary offsets) and the footer. Layout of the CAN messages: :mod:`lde.io.mcap_cdr`.
"""

from __future__ import annotations

import contextlib
import json
import os
import struct
import zlib
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lz4.frame as lz4frame
import numba
import numpy as np
import zstandard

from lde import __version__ as lde_version
from lde.can.frames import FrameBatch
from lde.errors import LogFormatError, OutputError
from lde.io.mcap_cdr import (
    CAN_FD_SCHEMA_NAME,
    CAN_FD_SCHEMA_TEXT,
    CAN_PAYLOAD_SIZE,
    CAN_SCHEMA_NAME,
    CAN_SCHEMA_TEXT,
    TOPIC_RX,
    TOPIC_TX,
    can_fd_payloads,
    can_payload,
    can_payloads,
    topic_of,
)
from lde.io.mcap_json import json_rows, object_schema, plain

__all__ = ["McapWriter", "COMPRESSIONS", "MAGIC"]

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
OP_CHUNK, OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_STATISTICS = 0x06, 0x07, 0x08, 0x0B
OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 0x0C, 0x0D, 0x0E, 0x0F
#: chunk compressions: zstd (default), lz4, none
COMPRESSIONS = ("zstd", "lz4", "")
#: bytes of a message record besides its payload: opcode, length, channel, sequence, log and publish time
MSG_OVERHEAD = 1 + 8 + 2 + 4 + 8 + 8
#: zstd level of the chunks: 1 compresses CAN records as well as 3-9 here (measured) at 2-4x the speed
ZSTD_LEVEL = 1


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


# ----------------------------------------------------------------------------- records
def _str(s: str) -> bytes:
    b = s.encode("utf-8")
    return struct.pack("<I", len(b)) + b


def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _map_str(d: Mapping[str, str]) -> bytes:
    body = b"".join(_str(k) + _str(v) for k, v in d.items())
    return struct.pack("<I", len(body)) + body


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
        profile: the MCAP header's profile string.
        metadata: key/value strings stored as an MCAP metadata record ``lde`` (indexed in the
            summary, see :meth:`add_metadata`).
        indexed: write message and chunk indexes (the module doc's indexed layout); default compact.
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
        indexed: bool = False,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise ValueError(f"unknown MCAP compression {compression!r}: one of zstd, lz4 or ''")
        self.indexed = bool(indexed)
        self._zstd = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_checksum=True)
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
        self._can_schema = self._add_schema(CAN_SCHEMA_NAME, "ros2msg", CAN_SCHEMA_TEXT.encode())
        self._fd_schema = 0  # registered with the first CAN FD frame
        self.rx_channel = self._add_channel(TOPIC_RX, "cdr", self._can_schema)
        self.tx_channel = self._add_channel(TOPIC_TX, "cdr", self._can_schema, {"direction": "tx"})
        #: (bus, is_rx, CAN FD) -> channel id; more are registered as frames of other buses come
        self._can_chan: dict[tuple[str, bool, bool], int] = {
            ("", True, False): self.rx_channel,
            ("", False, False): self.tx_channel,
        }
        self._can_channels = {self.rx_channel, self.tx_channel}
        self._json_keys: dict[int, tuple[str, ...]] = {}
        self._metadata_indexes: list[bytes] = []
        if metadata:
            self.add_metadata("lde", metadata)

    # ------------------------------------------------------------------ low level
    def _write(self, b: bytes, crc: bool = True) -> None:
        if crc:
            self._crc = zlib.crc32(b, self._crc)
        try:
            self._f.write(b)
        except OSError as exc:  # disk full, file size limit: the chunks before stay readable
            raise OutputError(f"{self.path}: cannot write: {exc}") from exc

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
        keys, schema = object_schema(topic, schema_props, title)
        sid = self._add_schema(title or topic.strip("/").replace("/", "_"), "jsonschema", schema)
        cid = self._add_channel(topic, "json", sid)
        self._json_keys[cid] = keys
        return cid

    def can_channel(self, bus: str, is_rx: bool, fd: bool) -> int:
        """The channel of a bus's received / sent, classic / CAN FD frames (registered when new:
        topics and metadata as :mod:`lde.io.mcap_cdr` says)."""
        key = (bus, bool(is_rx), bool(fd))
        cid = self._can_chan.get(key)
        if cid is None:
            if fd and not self._fd_schema:
                self._fd_schema = self._add_schema(CAN_FD_SCHEMA_NAME, "ros2msg", CAN_FD_SCHEMA_TEXT.encode())
            meta = {"bus": bus} if bus else {}
            if not is_rx:
                meta["direction"] = "tx"
            schema = self._fd_schema if fd else self._can_schema
            cid = self._can_chan[key] = self._add_channel(topic_of(bus, is_rx, fd), "cdr", schema, meta)
            self._can_channels.add(cid)
        return cid

    def write_frames(self, frames: FrameBatch) -> None:
        """Queue CAN frames: each on its bus's channel (module doc of :mod:`lde.io.mcap_cdr`): received
        frames on ``/can/rx``, the others on ``/can/tx``, CAN FD frames on ``/can/fd/...``."""
        n = len(frames)
        if n == 0:
            return
        fd = frames.dlc > 8
        # one group per (bus, direction, classic / FD)
        key = frames.channel.astype(np.int64) * 4 + frames.is_rx.astype(np.int64) * 2 + fd
        chan = np.zeros(n, np.uint16)
        for k in np.unique(key).tolist():
            cid = self.can_channel(frames.channels[k // 4], bool(k & 2), bool(k & 1))
            chan[key == k] = cid
        seq = np.empty(n, np.uint32)
        for c in np.unique(chan).tolist():
            sel = chan == c
            k = int(np.count_nonzero(sel))
            seq[sel] = (np.arange(k, dtype=np.int64) + self._seq[c]) % (1 << 32)
            self._seq[c] += k
            self._counts[c] += k
        t = frames.t_ns.astype(np.int64)
        classic = np.flatnonzero(~fd)
        if classic.size == n:
            pay = can_payloads(frames).reshape(-1)
            off = np.arange(n, dtype=np.int64) * CAN_PAYLOAD_SIZE
            self._queue(_Block(chan, seq, t, pay, off, np.full(n, CAN_PAYLOAD_SIZE, np.int64)))
            return
        if classic.size:
            c = frames.take(classic)
            pay = can_payloads(c).reshape(-1)
            off = np.arange(classic.size, dtype=np.int64) * CAN_PAYLOAD_SIZE
            lens = np.full(classic.size, CAN_PAYLOAD_SIZE, np.int64)
            self._queue(_Block(chan[classic], seq[classic], t[classic], pay, off, lens))
        wide = np.flatnonzero(fd)
        pay, off, lens = can_fd_payloads(frames.take(wide))
        self._queue(_Block(chan[wide], seq[wide], t[wide], pay, off, lens))

    def write_frame(
        self, t_ns: int, can_id: int, is_extended: bool, dlc: int, data: bytes, is_rx: bool, bus: str = ""
    ) -> None:
        """Queue one CAN frame (the live recorder's path); ``bus``: its bus's name (``""``: not named)."""
        fd = dlc > 8
        if fd:
            row = np.frombuffer(bytes(data), np.uint8).reshape(1, -1)
            one = FrameBatch(
                np.array([t_ns]),
                np.array([can_id]),
                np.array([is_extended]),
                np.array([dlc]),
                row,
                np.array([is_rx]),
            )
            pay = can_fd_payloads(one)[0].tobytes()
        else:
            pay = can_payload(can_id, is_extended, is_rx, dlc, data)
        self._queue_single(self.can_channel(bus, is_rx, fd), int(t_ns), pay)

    def write_json(self, channel_id: int, t_ns: int, record: Mapping[str, Any]) -> None:
        """Queue one JSON message (a flat object of numbers) on a channel from :meth:`add_json_channel`."""
        if channel_id not in self._json_keys:
            raise ValueError(f"channel {channel_id} is not a JSON channel of this writer")
        self._queue_single(channel_id, int(t_ns), json.dumps(plain(record), allow_nan=True).encode())

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
        texts = json_rows(columns, n)
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
        (the output of :func:`lde.io.textfmt.format_rows`)."""
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
        # (replay: /can/rx), the others' log times and counts are in the message indexes; the
        # received frames' lanes first (a file cut while writing keeps the inputs it can)
        lanes = sorted(np.unique(chan).tolist(), key=lambda c: (self._lane_rank(c), c))
        for lane_id in lanes:
            idx = np.flatnonzero(chan == lane_id)
            order = idx[np.argsort(t[idx], kind="stable")]
            self._write_lane(order, chan, seq, t, pay, off, length)
        t_lo, t_hi = int(t.min()), int(t.max())
        self._t_min = t_lo if self._t_min is None else min(self._t_min, t_lo)
        self._t_max = max(self._t_max, t_hi)

    def _lane_rank(self, cid: int) -> int:
        """0 for a channel of received CAN frames, 1 for sent ones, 2 for the others."""
        for (_bus, is_rx, _fd), c in self._can_chan.items():
            if c == cid:
                return 0 if is_rx else 1
        return 2

    def sync(self, fsync: bool = False) -> None:
        """:meth:`flush`, then push the file's buffer to the OS (a killed process loses nothing
        written so far; ``fsync`` also survives a power loss, at a cost)."""
        self.flush()
        try:
            self._f.flush()
            if fsync:
                os.fsync(self._f.fileno())
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write: {exc}") from exc

    def _write_lane(self, order, chan, seq, t, pay, off, length) -> None:
        """Message records of ``order`` (time-sorted) as chunks of about ``chunk_size`` bytes."""
        rec_len = MSG_OVERHEAD + length[order]
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
        self._write(summary, crc=False)
        self._write(footer_head + struct.pack("<I", crc), crc=False)
        self._write(MAGIC, crc=False)
        try:
            self._f.close()
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write: {exc}") from exc
        self._closed = True

    def abort(self, keep: bool = False) -> None:
        """Close without the summary and remove the file (a writer whose input failed); ``keep``:
        leave what was written (an output that could not be written further: it reads up to its
        last complete chunk)."""
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(OSError):
            self._f.close()
        if not keep:
            with contextlib.suppress(OSError):
                self.path.unlink()

    def __enter__(self) -> McapWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ internals
    def _queue(self, block: _Block) -> None:
        self._pending.append(block)
        self._pending_bytes += int(block.pay.size) + MSG_OVERHEAD * int(block.t.size)
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
        self._pending_bytes += int(pay.size) + MSG_OVERHEAD * n
        if self._pending_bytes > self._buffer_bytes:
            self.flush()

    def _write_chunk(self, out, rec_off, rec_end, order, chan, t, a: int, b: int) -> None:
        start = int(rec_off[a])
        raw = out[start : int(rec_end[b - 1])].tobytes()
        idx = order[a:b]
        ts = t[idx]
        t0, t1 = int(ts.min()), int(ts.max())
        if self._compression == "zstd":
            comp = self._zstd.compress(raw)
        elif self._compression == "lz4":
            comp = lz4frame.compress(raw, content_checksum=True)
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
        self._n_chunks += 1
        # message indexes: per channel (log_time, offset of the record in the uncompressed chunk);
        # compact files index only the JSON lanes (16 bytes per message, outside the compression)
        ch = chan[idx]
        lanes = np.unique(ch).tolist()
        if not self.indexed and any(c in self._can_channels for c in lanes):
            return
        rel = (rec_off[a:b] - start).astype(np.uint64)
        mi_start = self._f.tell()
        mi_offsets: list[tuple[int, int]] = []
        pos = mi_start
        for c in lanes:
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
        if self.indexed:
            self._chunk_indexes.append(_record(OP_CHUNK_INDEX, ci))


def _str_bytes(b: bytes) -> bytes:
    return struct.pack("<I", len(b)) + b
