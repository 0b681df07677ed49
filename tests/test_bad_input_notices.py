"""Notices about bad input say where it is: the line numbers of the first few bad lines of a text
log (candump, ASC, CSV), the byte offsets of bad records of a binary log (MCAP, BLF); a cut MCAP is
a cut record with its bytes, not a "line"; a missing file in a batch is said once, naming its path
once; the progress bar's carriage returns never land in a file."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import can
import pytest

from lde.cli import main
from lde.errors import LogFormatError
from lde.io import (
    CAN_SCHEMA_NAME,
    CAN_SCHEMA_TEXT,
    TOPIC_RX,
    McapWriter,
    can_payload,
    read_log,
)

DATA = Path(__file__).parent / "data"
SAMPLE = DATA / "sample_linear.log"
SAMPLE_VEHICLE = DATA / "sample_linear_vehicle.toml"
OPTS = ["--vehicle", str(SAMPLE_VEHICLE), "--backend", "float"]
OP_CHUNK = 0x06  # the MCAP chunk record's opcode


def _not_read(err: str) -> str:
    """The summary's "not read: ..." part."""
    line = next(ln for ln in err.splitlines() if "not read:" in ln)
    return line.split("not read: ", 1)[1]


def test_malformed_candump_lines_are_named_by_line_number(tmp_path, capsys):
    lines = SAMPLE.read_text().splitlines(keepends=True)
    bad_at = [12, 57, 58, 400]  # 1-based line numbers in the written file
    out = list(lines)
    for k in bad_at:
        out.insert(k - 1, "(1700000000.1) vcan0 2A0#0G\n")  # a non-hex digit
    log = tmp_path / "bad.log"
    log.write_text("".join(out))
    assert main(["replay", str(log), *OPTS]) == 0
    assert _not_read(capsys.readouterr().err) == "4 malformed lines (first at lines 12, 57, 58)"
    # three or fewer: every one is named
    log.write_text("".join(out[:100]) + "".join(lines[100:]))
    assert main(["replay", str(log), *OPTS]) == 0
    assert _not_read(capsys.readouterr().err) == "3 malformed lines (at lines 12, 57, 58)"


def test_a_cut_candump_line_is_named_with_its_line_number(tmp_path, capsys):
    text = SAMPLE.read_bytes()
    log = tmp_path / "cut.log"
    log.write_bytes(text[:-5])  # inside the last line
    n_lines = text.count(b"\n")
    assert main(["replay", str(log), *OPTS]) == 0
    start = text[:-5].rfind(b"\n") + 1
    assert _not_read(capsys.readouterr().err) == (
        f"the cut last line (line {n_lines}, from byte {start}, no newline)"
    )


def test_a_cut_mcap_is_a_cut_record_with_its_bytes_not_a_line(tmp_path, capsys):
    """A recording cut inside its last chunk (a crash): the complete chunks replay; the summary
    names the cut record by its bytes."""
    frames = read_log(SAMPLE).frames
    src = tmp_path / "whole.mcap"
    with McapWriter(src, chunk_size=1 << 14) as w:  # many chunks
        w.write_frames(frames)
    raw = src.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) // 2])
    assert main(["replay", str(cut), *OPTS]) == 0
    err = capsys.readouterr().err
    part = _not_read(err)
    assert "line" not in part and "truncated" not in part, part
    start, end = (int(x) for x in part.split("(bytes ")[1].split(",")[0].split("-"))
    assert part == f"the cut last record (bytes {start}-{end}, cut short)"
    assert end == len(raw) // 2 and start < end and raw[start] == OP_CHUNK  # a chunk starts there
    assert f"at byte {start} of {end}" in err  # the warning agrees


def _mcap_with_bad_messages(path: Path, frames, bad_every: int) -> list[int]:
    """An MCAP log whose every ``bad_every``-th CAN message has the wrong size (written with the
    mcap library, small chunks); returns the indexes of the bad messages."""
    from mcap.writer import Writer

    bad = []
    with path.open("wb") as fh:
        w = Writer(fh, chunk_size=4096)
        w.start()
        sid = w.register_schema(CAN_SCHEMA_NAME, "ros2msg", CAN_SCHEMA_TEXT.encode())
        cid = w.register_channel(TOPIC_RX, "cdr", sid)
        for i in range(len(frames)):
            t = int(frames.t_ns[i])
            data = bytes(frames.data[i])
            payload = can_payload(int(frames.can_id[i]), False, True, int(frames.dlc[i]), data)
            if i % bad_every == bad_every - 1:
                payload = payload[:11]  # cut: the wrong size
                bad.append(i)
            w.add_message(cid, log_time=t, data=payload, publish_time=t)
        w.finish()
    return bad


def test_bad_mcap_messages_are_located_by_their_chunks_byte_offsets(tmp_path, capsys):
    frames = read_log(SAMPLE).frames
    log = tmp_path / "bad.mcap"
    bad = _mcap_with_bad_messages(log, frames, bad_every=500)
    s = read_log(log).stats
    assert s.bad_messages == len(bad) > 3
    assert len(s.bad_messages_at) == 3 and list(s.bad_messages_at) == sorted(s.bad_messages_at)
    raw = log.read_bytes()
    assert all(raw[o] == OP_CHUNK for o in s.bad_messages_at)
    assert main(["replay", str(log), *OPTS]) == 0
    offsets = ", ".join(str(o) for o in s.bad_messages_at)
    assert _not_read(capsys.readouterr().err) == (
        f"{len(bad)} CAN messages of the wrong size or encoding (first in the chunks at bytes {offsets})"
    )


def _pycan_copy(path: Path, n: int = 300) -> None:
    frames = read_log(SAMPLE).frames
    with can.Logger(str(path)) as w:
        for i in range(n):
            d = bytes(frames.data[i][: int(frames.dlc[i])])
            t = float(frames.t_ns[i]) / 1e9
            w.on_message_received(can.Message(timestamp=t, arbitration_id=int(frames.can_id[i]), data=d))


@pytest.mark.parametrize(
    ("suffix", "line", "bad"),
    [
        ("asc", 20, " 0.050000 1  2A0             Rx   d 8 ZZ 00 60 FF EF FF 07 00\n"),
        ("csv", 30, "garbage\n"),
    ],
)
def test_a_corrupt_python_can_text_log_names_the_line(tmp_path, capsys, suffix, line, bad):
    good = tmp_path / f"good.{suffix}"
    _pycan_copy(good)
    lines = good.read_text().splitlines(keepends=True)
    lines[line - 1] = bad
    log = tmp_path / f"bad.{suffix}"
    log.write_text("".join(lines))
    with pytest.raises(LogFormatError, match=rf"corrupt \.{suffix} log at line {line} "):
        read_log(log)
    assert main(["replay", str(log), *OPTS]) == 2
    assert f"at line {line} " in capsys.readouterr().err
    assert len(read_log(good).frames) == 300  # the reader itself reads the intact file


def test_a_corrupt_blf_names_the_byte_offset(tmp_path):
    good = tmp_path / "good.blf"
    _pycan_copy(good)
    raw = bytearray(good.read_bytes())
    raw[300:310] = b"x" * 10  # inside the compressed container after the header
    log = tmp_path / "bad.blf"
    log.write_bytes(bytes(raw))
    with pytest.raises(LogFormatError, match=r"corrupt \.blf log before byte (\d+) ") as exc:
        read_log(log)
    at = int(str(exc.value).split("before byte ")[1].split()[0])
    assert 310 <= at <= len(raw)


def test_a_missing_file_in_a_batch_is_said_once_with_its_path_once(tmp_path, capsys):
    missing = tmp_path / "x.log"
    rc = main(["replay", str(SAMPLE), str(missing), *OPTS, "--csv", str(tmp_path / "out")])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.count(f"{missing}: no such file") == 1, err
    assert f"{missing}: {missing}" not in err
    assert f"lde: error: {missing}: no such file" in err


def test_no_progress_bar_when_stderr_is_a_file(tmp_path):
    """Several logs (the bar's case) with stderr to a file: the summaries have no carriage return."""
    err_file = tmp_path / "err.txt"
    with err_file.open("w") as fh:
        proc = subprocess.run(
            [sys.executable, "-m", "lde", "replay", str(SAMPLE), str(DATA / "sample_linear.mcap"), *OPTS]
            + ["--csv", str(tmp_path / "out")],
            stderr=fh,
            stdout=subprocess.DEVNULL,
            timeout=300,
        )
    err = err_file.read_bytes()
    assert proc.returncode == 0, err
    assert b"2 logs" in err and b"\r" not in err and b"%|" not in err


def test_the_first_bad_lines_survive_reading_in_blocks(tmp_path):
    """Line numbers count across the parser's blocks (a long log is parsed in pieces)."""
    from lde.io.candump import CandumpBlocks

    good = b"(1700000000.000000) vcan0 2A0#0011223344556677\n"
    text = bytearray()
    bad_at = [5, 3000, 3001]
    for k in range(1, 4000):
        text += b"(1700000000.1) vcan0 2A0#0G\n" if k in bad_at else good
    p = CandumpBlocks()
    step = 1000
    for a in range(0, len(text), step):
        p.feed(bytes(text[a : a + step]))
    p.end()
    assert p.malformed_at == tuple(bad_at)
