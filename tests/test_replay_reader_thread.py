"""``lde replay`` of an MCAP file reads its chunks in the reader thread (issue 12 item 5): a chunk
that fails to decompress there ends the replay with one ``lde: error:`` line, the thread stopped and
the CSV removed; through the API the pieces before it reach the engine and the error is the reader's."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest
from mcap_util import chunk_spans

from lde.can.frames import FrameBatch
from lde.cli import main
from lde.engine.engine import StepBlock
from lde.errors import LogFormatError
from lde.io import McapWriter, read_log
from lde.params import load_vehicle
from lde.replay.replay import read_inputs, run_replay

DATA = Path(__file__).parent / "data"


def _damaged_mcap(tmp_path: Path) -> tuple[Path, int]:
    """The 20 s sample log as an MCAP file of many small chunks, one chunk past the middle with its
    compressed bytes overwritten. Returns the file and the frames before the damaged chunk."""
    log = read_log(DATA / "sample_linear.log")
    src = tmp_path / "many.mcap"
    with McapWriter(src, chunk_size=64 << 10) as w:
        w.write_frames(log.frames)
    spans = chunk_spans(src)
    assert len(spans) >= 6, len(spans)
    bad = spans[len(spans) // 2 + 1]
    raw = bytearray(src.read_bytes())
    mid = bad.chunk_start_offset + bad.chunk_length // 2
    raw[mid : mid + 64] = bytes(range(64))
    out = tmp_path / "damaged.mcap"
    out.write_bytes(bytes(raw))
    before = int((log.frames.t_ns < bad.message_start_time).sum())
    return out, before


def _reader_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "lde-read"]


def test_a_chunk_that_fails_in_the_reader_thread_is_one_line_and_stops_the_thread(tmp_path, capsys):
    bad, _ = _damaged_mcap(tmp_path)
    csv = tmp_path / "out.csv"
    rc = main(["replay", "-q", str(bad), "--csv", str(csv)])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lde: error: "), err
    assert "damaged.mcap" in lines[0] and "chunk" in lines[0], err
    assert not csv.exists()  # outputs removed on failure
    assert _reader_threads() == []


def test_the_pieces_before_the_failing_chunk_reach_the_engine_then_its_error(tmp_path):
    bad, before = _damaged_mcap(tmp_path)
    li = read_inputs(bad, None, chunk_frames=997)
    fed = [0]

    def count(f: FrameBatch, _b: StepBlock) -> None:
        fed[0] += len(f)

    with li.stream as stream, pytest.raises(LogFormatError, match="damaged.mcap"):
        run_replay(stream, li.profile, load_vehicle("reference"), "float", sinks=(count,))
    assert 0 < fed[0] <= before
    assert _reader_threads() == []
