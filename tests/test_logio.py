"""lde.io: candump -L, MCAP (fast path vs the mcap library), python-can formats, bad files."""

from __future__ import annotations

import io
import struct
from pathlib import Path

import can
import numpy as np
import pytest
from mcap_util import chunk_spans

from lde.can.frames import FrameBatch
from lde.errors import LogFormatError
from lde.io import (
    CAN_SCHEMA_NAME,
    McapWriter,
    detect_format,
    format_candump,
    parse_candump_bytes,
    read_log,
    read_mcap,
    write_candump,
)
from lde.io.mcap_can import McapCanReader, McapCanWriter

T0 = 1_700_000_000_000_000_000  # ns


def random_frames(n: int, seed: int = 0, us_exact: bool = True, classic: bool = False) -> FrameBatch:
    rng = np.random.default_rng(seed)
    t = T0 + np.sort(rng.integers(0, 60 * 10**9, n))
    if us_exact:
        t = t // 1000 * 1000
    ext = rng.random(n) < 0.2
    cid = np.where(ext, rng.integers(0, 1 << 29, n), rng.integers(0, 0x800, n))
    dlc = rng.integers(0, 9, n)
    if not classic:
        dlc[rng.random(n) < 0.05] = 8  # classic only: FD beyond 8 bytes is lossy by design
    data = rng.integers(0, 256, (n, 8)).astype(np.uint8)
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0
    return FrameBatch(t_ns=t, can_id=cid, is_extended=ext, dlc=dlc, data=data, is_rx=rng.random(n) < 0.7)


def assert_frames_equal(
    a: FrameBatch, b: FrameBatch, fields=("t_ns", "can_id", "is_extended", "dlc", "data", "is_rx")
):
    assert len(a) == len(b)
    for name in fields:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


# ----------------------------------------------------------------------------- candump
def test_candump_line_kinds_and_exact_timestamps():
    text = (
        b"(1700000000.123456) vcan0 2A0#0011223344556677\n"
        b"(1700000000.999999999) can1 12345678#0011 T\n"
        b"(1700000001.2) vcan0 2A8##1001122334455667788990011\n"
        b"(1700000001.300000) vcan0 2A0#R\n"
        b"(1700000001.300001) vcan0 2A0#R8\n"
        b"(1700000001.400000) vcan0 20000080#0000000000000000\n"
        b"\n"
        b"this is not a frame\n"
        b"(1700000001.500000) vcan0 3D1#01_9\n"
    )
    p = parse_candump_bytes(text)
    f = p.frames
    # parsed from the text: no float rounding even at 1 ns resolution
    assert f.t_ns.tolist() == [
        1700000000123456000,
        1700000000999999999,
        1700000001200000000,
        1700000001500000000,
    ]
    assert f.can_id.tolist() == [0x2A0, 0x12345678, 0x2A8, 0x3D1]
    assert f.is_extended.tolist() == [False, True, False, False]
    assert f.dlc.tolist() == [8, 2, 12, 1]
    assert f.is_rx.tolist() == [True, False, True, True]
    assert f.width == 12  # the longest frame's bytes (CAN FD)
    assert f.data[0].tolist() == [0x00, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0, 0, 0, 0]
    assert f.data[2].tolist() == [0x00, 0x11, 0x22, 0x33, 0x44, 0x55, 0x66, 0x77, 0x88, 0x99, 0x00, 0x11]
    assert f.data[3].tolist() == [1] + [0] * 11
    assert f.channels == ("vcan0", "can1") and f.channel_names().tolist() == [
        "vcan0",
        "can1",
        "vcan0",
        "vcan0",
    ]
    assert (p.error_frames, p.remote_frames, p.malformed_lines, p.truncated_last_line) == (1, 2, 1, 0)
    assert p.first_malformed_line == 8


def test_candump_truncated_last_line_is_counted_not_fatal(tmp_path: Path):
    frames = random_frames(50, classic=True)
    path = tmp_path / "cut.log"
    write_candump(path, frames)
    raw = path.read_bytes()
    path.write_bytes(raw[:-9])  # cut inside the last line (and its newline)
    data = read_log(path)
    assert data.format == "candump"
    assert data.stats.truncated_last_line == 1
    assert data.stats.malformed_lines == 0
    assert_frames_equal(data.frames, frames[:-1])


@pytest.mark.parametrize("us_exact", [True, False])
def test_candump_round_trip(tmp_path: Path, us_exact: bool):
    frames = random_frames(2000, seed=1, us_exact=us_exact, classic=True)
    path = tmp_path / "x.log"
    write_candump(path, frames)
    back = read_log(path)
    assert back.format == "candump"
    assert back.stats.skipped == 0
    assert_frames_equal(back.frames, frames)


def test_candump_readable_by_python_can(tmp_path: Path):
    frames = random_frames(100, seed=2, classic=True)
    path = tmp_path / "x.log"
    write_candump(path, frames)
    msgs = list(can.LogReader(str(path)))
    assert [m.arbitration_id for m in msgs] == frames.can_id.tolist()
    assert [bytes(m.data) for m in msgs] == [frames.data[i, : frames.dlc[i]].tobytes() for i in range(100)]


def test_candump_sniffed_without_suffix(tmp_path: Path):
    frames = random_frames(10, classic=True)
    path = tmp_path / "trace"
    write_candump(path, frames)
    assert detect_format(path) == "candump"


# ----------------------------------------------------------------------------- MCAP
def write_recording(
    path: Path,
    frames: FrameBatch,
    compression: str = "zstd",
    chunk_size: int = 64 << 10,
    indexed: bool = False,
) -> None:
    with McapWriter(path, compression=compression, chunk_size=chunk_size, indexed=indexed) as w:
        w.write_frames(frames)
        est = w.add_json_channel("/lde/estimate", {"Fw": {"type": "number"}, "Mw": {"type": "number"}})
        t = frames.t_ns[::7]
        w.write_json_columns(est, t, {"Fw": np.arange(t.size) * 0.5, "Mw": -np.arange(t.size, dtype=float)})
        w.write_json(est, int(frames.t_ns[3]) + 1, {"Fw": 1.25, "Mw": float("nan")})


@pytest.mark.parametrize("indexed", [False, True])
@pytest.mark.parametrize("compression", ["zstd", "lz4", ""])
def test_mcap_fast_path_equals_library_reader(tmp_path: Path, compression: str, indexed: bool):
    frames = random_frames(5000, seed=3)
    path = tmp_path / "x.mcap"
    write_recording(path, frames, compression, indexed=indexed)
    fast = read_mcap(path, json_topics="all", validate_crcs=True)
    lib = read_mcap(path, json_topics="all", force_library=True)
    assert fast.fast_path and not lib.fast_path
    assert_frames_equal(fast.frames, frames)
    assert_frames_equal(lib.frames, frames)
    assert fast.topics == lib.topics
    assert fast.topics["/can/rx"].count == int(frames.is_rx.sum())
    assert fast.topics["/can/tx"].count == int((~frames.is_rx).sum())
    assert fast.topics["/lde/estimate"].count == len(frames.t_ns[::7]) + 1
    for k in ("t_ns", "Fw", "Mw"):
        np.testing.assert_array_equal(fast.json["/lde/estimate"][k], lib.json["/lde/estimate"][k])
    np.testing.assert_array_equal(fast.times["/lde/estimate"], fast.json["/lde/estimate"]["t_ns"])
    # without JSON asked for, the JSON chunks are skipped: times and counts from the message indexes
    lean = read_mcap(path)
    assert lean.chunks_skipped > 0 and lean.chunks_read < fast.chunks_read
    assert lean.topics == fast.topics
    np.testing.assert_array_equal(lean.times["/lde/estimate"], fast.times["/lde/estimate"])
    assert_frames_equal(lean.frames, frames)
    # replay's read: only the received frames; the /can/tx chunks stay compressed when message
    # indexes say which they are (compact files: read, their frames left out)
    rx_only = read_mcap(path, skip_tx=True)
    assert rx_only.topics == fast.topics
    assert_frames_equal(rx_only.frames, frames[frames.is_rx])
    assert (rx_only.chunks_skipped > lean.chunks_skipped) == indexed
    assert np.isnan(fast.json["/lde/estimate"]["Mw"][1])  # the single write_json record, sorted in at t[3]+1


def test_mcap_fast_path_matches_independent_library_iteration(tmp_path: Path):
    """The mcap library's own SeekingReader (CRCs checked) sees the same messages we decode."""
    from mcap.reader import make_reader

    frames = random_frames(3000, seed=4)
    path = tmp_path / "x.mcap"
    write_recording(path, frames)
    fast = read_mcap(path)
    ids, ts = [], []
    with path.open("rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        stats = reader.get_summary().statistics
        for schema, _channel, message in reader.iter_messages(topics=["/can/rx", "/can/tx"]):
            assert schema.name == CAN_SCHEMA_NAME
            assert len(message.data) == 19
            (cid,) = struct.unpack_from("<I", message.data, 4)
            ids.append(cid)
            ts.append(message.log_time)
    assert ts == fast.frames.t_ns.tolist()
    assert ids == fast.frames.can_id.tolist()
    assert stats.message_count == len(frames) + len(frames.t_ns[::7]) + 1


def test_mcap_without_chunks_uses_library_fallback(tmp_path: Path):
    from mcap.writer import Writer

    from lde.io import CAN_SCHEMA_TEXT, can_payload

    frames = random_frames(200, seed=5)
    path = tmp_path / "plain.mcap"
    with path.open("wb") as fh:
        w = Writer(fh, use_chunking=False)
        w.start()
        sid = w.register_schema(CAN_SCHEMA_NAME, "ros2msg", CAN_SCHEMA_TEXT.encode())
        rx = w.register_channel("/can/rx", "cdr", sid)
        tx = w.register_channel("/can/tx", "cdr", sid)
        for i in range(len(frames)):
            pay = can_payload(
                frames.can_id[i],
                frames.is_extended[i],
                frames.is_rx[i],
                frames.dlc[i],
                frames.data[i].tobytes(),
            )
            w.add_message(rx if frames.is_rx[i] else tx, int(frames.t_ns[i]), pay, int(frames.t_ns[i]))
        w.finish()
    data = read_mcap(path)
    assert not data.fast_path
    assert_frames_equal(data.frames, frames)


def test_mcap_cut_recording_is_recovered_up_to_its_last_chunk(tmp_path: Path):
    """A recording cut by a crash (no summary, last chunk incomplete) gives every complete chunk."""
    frames = random_frames(4000, seed=12)
    path = tmp_path / "live.mcap"
    w = McapWriter(path, chunk_size=4096)
    for a in range(0, 4000, 500):
        w.write_frames(frames[a : a + 500])
        w.sync()  # what the live recorder does every 0.25 s
    size = path.stat().st_size
    w.close()
    last = chunk_spans(path)[-1]
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(path.read_bytes()[: last.chunk_start_offset + last.chunk_length // 2])  # crash
    log = read_log(cut)
    assert log.mcap is not None and log.mcap.truncated and log.stats.truncated_last_line == 1
    n = len(log.frames)
    assert 4000 - 200 <= n < 4000  # one small chunk (of one channel) lost

    # what was recovered is exactly the original minus the frames of the lost chunk
    def rows(f: FrameBatch) -> set:
        return set(zip(f.t_ns.tolist(), f.can_id.tolist(), map(bytes, f.data), f.is_rx.tolist(), strict=True))

    got, full = rows(log.frames), rows(frames)
    assert got <= full and len(got) == n
    # a complete file without summary (footer cut away): everything
    whole = tmp_path / "nosummary.mcap"
    whole.write_bytes(path.read_bytes()[:size])
    assert_frames_equal(read_log(whole).frames, frames)


def test_mcap_streaming_writer_many_flushes(tmp_path: Path):
    frames = random_frames(3000, seed=6)
    path = tmp_path / "s.mcap"
    w = McapWriter(path, buffer_bytes=4096, chunk_size=2048)
    for i in range(len(frames)):
        w.write_frame(
            int(frames.t_ns[i]),
            int(frames.can_id[i]),
            bool(frames.is_extended[i]),
            int(frames.dlc[i]),
            frames.data[i].tobytes(),
            bool(frames.is_rx[i]),
        )
    w.close()
    assert_frames_equal(read_mcap(path).frames, frames)
    assert_frames_equal(read_mcap(path, force_library=True).frames, frames)


def test_python_can_mcap_plugins(tmp_path: Path):
    frames = random_frames(300, seed=7, classic=True)
    path = tmp_path / "pc.mcap"
    logger = can.Logger(str(path))
    assert isinstance(logger, McapCanWriter)
    for m in frames.to_messages():
        logger.on_message_received(m)
    logger.stop()
    reader = can.LogReader(str(path))
    assert isinstance(reader, McapCanReader)
    msgs = list(reader)
    assert [m.arbitration_id for m in msgs] == frames.can_id.tolist()
    assert [m.is_rx for m in msgs] == frames.is_rx.tolist()
    assert [bytes(m.data) for m in msgs] == [
        frames.data[i, : frames.dlc[i]].tobytes() for i in range(len(frames))
    ]
    assert_frames_equal(read_log(path).frames, frames)


# ----------------------------------------------------------------------------- python-can formats
@pytest.mark.parametrize("suffix", [".asc", ".blf"])
def test_python_can_formats_round_trip(tmp_path: Path, suffix: str):
    frames = random_frames(500, seed=8, classic=True)
    path = tmp_path / f"x{suffix}"
    with can.Logger(str(path)) as logger:
        for m in frames.to_messages(channel=0):
            logger.on_message_received(m)
    data = read_log(path)
    assert data.format == suffix[1:]
    assert_frames_equal(data.frames, frames, fields=("can_id", "is_extended", "dlc", "data"))
    # ASC keeps timestamps relative to its start; both keep the spacing to the microsecond
    dt = np.diff(data.frames.t_ns) - np.diff(frames.t_ns)
    assert np.max(np.abs(dt)) <= 1000


# ----------------------------------------------------------------------------- bad files
def _bad_files(tmp: Path) -> dict[str, Path]:
    good = tmp / "good.mcap"
    write_recording(good, random_frames(2000, seed=9))
    raw = good.read_bytes()
    c0 = chunk_spans(good)[1]
    g = c0.chunk_start_offset + c0.chunk_length // 2  # inside the compressed records of chunk 1
    files = {
        "empty.log": b"",
        "empty.mcap": b"",
        "text.mcap": b"hello world\n",
        "binary.log": bytes(range(256)) * 4,
        "not_candump.log": b"this is not a log\nat all\n",
        "cut.mcap": raw[:40],  # inside the header: nothing to recover
        "garbled_chunk.mcap": raw[:g] + bytes(64) + raw[g + 64 :],
        "bad.asc": b"date Mon Jan 1 00:00:00 2024\nbase hex timestamps absolute\n   garbage garbage\n",
        "bad.blf": b"LOGG" + bytes(100),
        "x.unknownsuffix": b"\x00\x01\x02",
    }
    out = {}
    for name, content in files.items():
        p = tmp / name
        p.write_bytes(content)
        out[name] = p
    # a valid MCAP without CAN channels
    from mcap.writer import Writer

    p = tmp / "json_only.mcap"
    with p.open("wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        ch = w.register_channel("/truth", "json", sid)
        w.add_message(ch, 1, b'{"a": 1}', 1)
        w.finish()
    out["json_only.mcap"] = p
    return out


def test_bad_files_raise_log_format_error(tmp_path: Path):
    for name, path in _bad_files(tmp_path).items():
        with pytest.raises(LogFormatError) as info:
            read_log(path)
        msg = str(info.value)
        assert str(path) in msg, name
        assert "\n" not in msg, name
    with pytest.raises(LogFormatError, match="no such file"):
        read_log(tmp_path / "missing.log")


def test_json_only_mcap_names_its_topics(tmp_path: Path):
    path = _bad_files(tmp_path)["json_only.mcap"]
    with pytest.raises(LogFormatError, match="no CAN channel.*/truth"):
        read_log(path)
    data = read_mcap(path, json_topics="all", require_can=False)
    assert data.json["/truth"]["a"].tolist() == [1.0]


def test_mcap_writer_payload_layout_is_fixed_size():
    from lde.io import can_payloads

    frames = random_frames(10, seed=10)
    p = can_payloads(frames)
    assert p.shape == (10, 19)
    assert (p[:, :4] == np.array([0, 1, 0, 0], np.uint8)).all()
    assert struct.unpack_from("<I", p[3].tobytes(), 4)[0] == frames.can_id[3]
    _ = io  # keep import list honest for linters


# ----------------------------------------------------------------------------- text formatter
def test_format_rows_matches_python_formatting():
    from lde.io.textfmt import Column, format_rows, time_column

    rng = np.random.default_rng(11)
    n = 500
    f = rng.normal(0, 1000, n)
    f[:5] = [0.0, -0.0004, 0.0005, 123456.7891, -1.5]
    f[7] = np.nan
    k = rng.integers(-300, 300, n)
    t = T0 + np.arange(n, dtype=np.int64) * 3_900_000 + 123_000
    text, off = format_rows(
        [time_column("t", t), Column("f", f, 3), Column("k", k, 0), Column("b", k > 0, 0)],
        ["", ",", ",", ","],
        "\n",
    )
    lines = text.tobytes().decode().splitlines()
    assert len(lines) == n and off[-1] == len(text) and off[1] == len(lines[0]) + 1
    for i, line in enumerate(lines):
        ts, fs, ks, bs = line.split(",")
        assert ts == f"{t[i] // 10**9}.{t[i] % 10**9 // 1000:06d}"
        if np.isnan(f[i]):
            assert fs == "nan"
        else:
            assert float(fs) == pytest.approx(f[i], abs=5e-4 + 1e-12)
            assert len(fs.split(".")[1]) == 3
        assert int(ks) == k[i] and int(bs) == int(k[i] > 0)
    # ns timestamps that are not whole microseconds print with 9 digits
    text9, _ = format_rows([time_column("t", np.array([T0 + 1]))], [""], "")
    assert text9.tobytes() == b"1700000000.000000001"


def test_can_schema_decodes_with_the_ros2_cdr_decoder(tmp_path: Path):
    """Foxglove-style decoding: the ros2msg schema + CDR payloads decode to the frames written."""
    pytest.importorskip(
        "mcap_ros2", reason="mcap-ros2-support (the reference ROS 2 CDR decoder) not installed"
    )
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    frames = random_frames(300, seed=13, classic=True)
    path = tmp_path / "ros.mcap"
    with McapWriter(path) as w:
        w.write_frames(frames)
    got = []
    with path.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _s, _c, message, ros in reader.iter_decoded_messages():
            got.append((message.log_time, ros.id, ros.is_extended, ros.is_rx, ros.dlc, bytes(ros.data)))
    got.sort(key=lambda g: g[0])
    assert [g[0] for g in got] == frames.t_ns.tolist()
    assert [g[1] for g in got] == frames.can_id.tolist()
    assert [g[2] for g in got] == frames.is_extended.tolist()
    assert [g[3] for g in got] == frames.is_rx.tolist()
    assert [g[4] for g in got] == frames.dlc.tolist()
    assert [g[5] for g in got] == [frames.data[i].tobytes() for i in range(len(frames))]


def test_mcap_metadata_is_read_with_and_without_summary(tmp_path: Path):
    """The ``lde`` metadata record (profile, ...) is read from a complete file and from one cut
    by a crash (no summary: found by walking the top-level records)."""
    frames = random_frames(2000, seed=21)
    path = tmp_path / "m.mcap"
    meta = {"profile": "hyundai", "vehicle": "reference", "note": "ä ünïcode"}
    with McapWriter(path, chunk_size=4096, metadata=meta) as w:
        w.write_frames(frames)
    assert read_mcap(path).metadata == {"lde": meta}
    raw = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) // 2])
    data = read_mcap(cut)
    assert data.truncated and data.metadata == {"lde": meta}
    plain = tmp_path / "plain.mcap"
    with McapWriter(plain) as w:
        w.write_frames(frames)
    assert read_mcap(plain).metadata == {}


# ----------------------------------------------------------------------------- gzip
def _gz(src: Path, dst: Path, members: int = 1) -> Path:
    import gzip

    raw = src.read_bytes()
    cut = [len(raw) * i // members for i in range(members + 1)]
    dst.write_bytes(
        b"".join(gzip.compress(raw[a:b], mtime=0) for a, b in zip(cut[:-1], cut[1:], strict=True))
    )
    return dst


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf", ".mcap"])
def test_gzip_compressed_logs_read_like_the_plain_ones(tmp_path: Path, suffix: str):
    """``x<suffix>.gz`` (also a multi-dot name, a multi-member gzip) gives the frames of
    ``x<suffix>``; format ``<format>.gz``."""
    frames = random_frames(3000, seed=31, classic=True)
    plain = tmp_path / f"x{suffix}"
    if suffix == ".log":
        write_candump(plain, frames)
    elif suffix == ".mcap":
        with McapWriter(plain, metadata={"profile": "lde"}) as w:
            w.write_frames(frames)
    else:
        with can.Logger(str(plain)) as logger:
            for m in frames.to_messages(channel=0):
                logger.on_message_received(m)
    ref = read_log(plain)
    for name, members in ((f"x{suffix}.gz", 1), (f"my.drive{suffix}.gz", 3)):
        gz = _gz(plain, tmp_path / name, members)
        data = read_log(gz)
        assert data.format == ref.format + ".gz" and data.path == gz
        assert_frames_equal(data.frames, ref.frames)
        assert data.stats == ref.stats
    if suffix == ".mcap":
        assert data.mcap is not None and data.mcap.metadata["lde"]["profile"] == "lde"


def test_gzip_candump_cut_short_and_bad_gzip(tmp_path: Path):
    frames = random_frames(2000, seed=32)
    plain = tmp_path / "x.log"
    write_candump(plain, frames)
    gz = _gz(plain, tmp_path / "x.log.gz").read_bytes()
    # gzip content under the plain suffix is still read
    (tmp_path / "y.log").write_bytes(gz)
    assert read_log(tmp_path / "y.log").format == "candump.gz"
    cut = tmp_path / "cut.log.gz"
    cut.write_bytes(gz[: len(gz) // 2])
    data = read_log(cut)
    n = len(data.frames)
    assert 0 < n < 2000 and data.stats.truncated_last_line + data.stats.malformed_lines <= 1
    assert_frames_equal(data.frames, frames[:n])
    for name, content in (("bad.log.gz", b"\x1f\x8bnot really gzip"), ("plain.asc.gz", b"hello\n")):
        (tmp_path / name).write_bytes(content)
        with pytest.raises(LogFormatError, match="gzip"):
            read_log(tmp_path / name)


def test_mcap_cut_inside_or_before_its_first_chunk_says_so(tmp_path: Path):
    frames = random_frames(3000, seed=33)
    path = tmp_path / "a.mcap"
    with McapWriter(path) as w:  # one chunk of frames
        w.write_frames(frames)
    first = chunk_spans(path)[0]
    raw = path.read_bytes()
    for name, end, where in (
        ("in.mcap", first.chunk_start_offset + first.chunk_length // 2, "inside its first chunk"),
        ("before.mcap", first.chunk_start_offset - 3, "before its first chunk"),
    ):
        cut = tmp_path / name
        cut.write_bytes(raw[:end])
        with pytest.raises(LogFormatError) as info:
            read_log(cut)
        msg = str(info.value)
        assert msg.startswith(f"{cut}: truncated MCAP file: cut ") and where in msg, msg
        assert "no complete chunk of frames" in msg and "\n" not in msg


def test_mcap_with_only_sent_frames_says_so(tmp_path: Path):
    """A recording that holds only lde's own /can/tx frames: that, not "0 frames"."""
    frames = random_frames(1500, seed=34)
    tx = frames.select(~frames.is_rx)
    path = tmp_path / "tx.mcap"
    with McapWriter(path) as w:
        w.write_frames(tx)
    with pytest.raises(
        LogFormatError, match=rf"only frames lde sent \({len(tx)} on /can/tx\): no received input"
    ):
        read_log(path, skip_tx=True)
    assert len(read_log(path).frames) == len(tx)  # read without skip_tx: the frames are there


def test_mcap_metadata_is_indexed_for_the_mcap_library(tmp_path: Path):
    """The ``lde`` metadata record (and one added later) is in the summary's metadata indexes:
    ``mcap``'s ``iter_metadata()`` finds them, and the statistics count them."""
    from mcap.reader import make_reader

    path = tmp_path / "m.mcap"
    meta = {"profile": "hyundai", "vehicle": "reference"}
    with McapWriter(path, chunk_size=4096, metadata=meta) as w:
        w.write_frames(random_frames(1000, seed=35))
        w.flush()
        w.add_metadata("run", {"note": "after a chunk"})
    with path.open("rb") as fh:
        reader = make_reader(fh)
        found = {m.name: m.metadata for m in reader.iter_metadata()}
        summary = reader.get_summary()
    assert found == {"lde": meta, "run": {"note": "after a chunk"}}
    assert summary.statistics.metadata_count == 2 and len(summary.metadata_indexes) == 2
    assert read_mcap(path).metadata == found


def test_candump_read_in_blocks_equals_one_parse(tmp_path: Path):
    """Blocks cut anywhere inside lines (and a line longer than a block) give the frames and counts
    of one parse of the whole text."""
    from lde.io.candump import CandumpBlocks

    frames = random_frames(3000, seed=51)
    text = format_candump(frames).encode()
    lines = text.splitlines(keepends=True)
    text = b"".join(lines[:1000]) + b"x" * 5000 + b"\n" + b"".join(lines[1000:]) + b"(17"  # cut last line
    whole = parse_candump_bytes(text)
    for block in (7, 64, 1000, 4096, 1 << 20):
        p = CandumpBlocks()
        with io.BytesIO(text) as fh:
            got = FrameBatch.concat(list(p.read_file(fh, block)), sort=False)
        assert_frames_equal(got, whole.frames)
        r = p.result(got)
        assert (r.lines, r.malformed_lines, r.first_malformed_line, r.truncated_last_line) == (
            whole.lines,
            whole.malformed_lines,
            whole.first_malformed_line,
            whole.truncated_last_line,
        )
