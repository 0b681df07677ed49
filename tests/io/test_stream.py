"""The replay's reader thread (:class:`lde.io.stream.ReadAhead`): same pieces in the same order,
errors where they happened, bounded look-ahead, a clean stop; and the same rows as reading in line."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from lde.can.frames import FrameBatch
from lde.engine.engine import StepBlock
from lde.io.stream import ReadAhead
from lde.params import load_vehicle
from lde.replay.replay import read_inputs, run_replay

from helpers import TESTS

DATA = TESTS / "data"


class Source:
    """Items 0..n-1 from a generator that records how far it got and whether it was closed."""

    def __init__(self, n: int, fail_at: int | None = None) -> None:
        self.n = n
        self.fail_at = fail_at
        self.produced = 0
        self.closed = threading.Event()

    def __iter__(self) -> Iterator[int]:
        try:
            for i in range(self.n):
                if i == self.fail_at:
                    raise ValueError(f"bad piece {i}")
                self.produced += 1
                yield i
        finally:
            self.closed.set()


def test_items_arrive_in_order_and_the_producer_stays_within_its_depth():
    for depth in (1, 2):
        src = Source(50)
        got = []
        with ReadAhead(src, depth=depth) as ra:
            for x in ra:
                # the producer may have read at most `depth` pieces beyond the ones taken
                assert src.produced <= len(got) + 1 + depth
                got.append(x)
        assert got == list(range(50))
        assert src.closed.is_set()


def test_an_error_of_the_producer_reaches_the_consumer_after_the_pieces_before_it():
    src = Source(10, fail_at=4)
    got = []
    with pytest.raises(ValueError, match="bad piece 4"), ReadAhead(src) as ra:
        for x in ra:
            got.append(x)
    assert got == [0, 1, 2, 3]


def test_close_stops_the_producer_and_closes_its_iterator():
    src = Source(10_000)
    ra = ReadAhead(src)
    assert next(ra) == 0
    ra.close()
    assert src.closed.is_set()
    assert src.produced <= 3
    with pytest.raises(StopIteration):
        next(ra)


def _rows(read_ahead: bool, log: Path, chunk_frames: int) -> tuple[StepBlock, int]:
    vehicle = load_vehicle("reference")
    li = read_inputs(log, None, chunk_frames=chunk_frames)
    blocks: list[StepBlock] = []

    def keep(_f: FrameBatch, b: StepBlock) -> None:
        blocks.append(b)

    with li.stream as stream:
        s = run_replay(stream, li.profile, vehicle, "float", sinks=(keep,), read_ahead=read_ahead)
    return StepBlock.concat(blocks), s.frames.total


@pytest.mark.parametrize("name", ["sample_linear.log", "sample_linear.mcap"])
def test_replay_with_the_reader_thread_gives_the_same_rows(name: str):
    # small pieces: many hand-overs between the reader thread and the engine
    a, na = _rows(False, DATA / name, 997)
    b, nb = _rows(True, DATA / name, 997)
    assert na == nb > 0
    assert len(a) == len(b) > 0
    for col in ("t_ns", "status", "est", "t_overlay", "overlay_state", "inputs", "frames_used"):
        np.testing.assert_array_equal(getattr(a, col), getattr(b, col))
