"""Compile every numba kernel ahead of time (``lde warmup``): the first real run then starts warm.

Each part runs a tiny workload through its kernels, so numba compiles them and writes its on-disk
cache; parts can run in parallel processes (one core each):

===========  ======================================================================================
a backend    the data path with that backend (one part per registered backend,
             :data:`lde.engine.backends.BACKENDS`); the default backend's part also builds a live
             service (``lde run``, ``lde demo``: the MDPS-locked grid, the step's compiled hand-off
             :mod:`lde.service.handoff`)
``logio``    candump parser and writer, MCAP writer and reader, CSV / JSON row formatting
``sim``      the vehicle simulator (``lde demo``, ``lde sim``) and the batch decoder and grid
``smooth``   ``lde replay --smooth``: the traced float lateral step and the RTS backward pass
===========  ======================================================================================
"""

from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import can
import numpy as np

from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.clock import SimulatedClock
from lde.engine.backends import BACKENDS, DEFAULT_BACKEND
from lde.engine.engine import Engine
from lde.engine.grid import build_grid
from lde.engine.receiver import decode_batch
from lde.io import McapWriter, open_log, read_mcap, write_candump
from lde.io.textfmt import EXACT, Column, format_rows, time_column
from lde.params import load_vehicle
from lde.replay.replay import CsvWriter, RecordingWriter, run_replay
from lde.replay.smoother import smooth_run
from lde.service.service import Service
from vcan_sim.run import simulate

__all__ = ["PARTS", "warm_up"]

PARTS = (*BACKENDS, "logio", "sim", "smooth")


def _frames() -> FrameBatch:
    """Half a second of simulated traffic (lde profile)."""
    return simulate("straight", seed=0, duration=0.5).frames


def _engine(backend: str) -> None:
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    frames = _frames()
    for explicit in (False, True):
        e = Engine(profile, vehicle, backend, explicit=explicit)
        steps = frames.t_ns[::3] if explicit else None
        e.feed(frames, step_times=steps, final=True)


def _service() -> None:
    """A service on a virtual bus: building it loads (or compiles) every kernel its step calls."""
    bus = can.Bus(interface="virtual", channel="lde-warmup")
    try:
        Service(
            bus, "lde", "reference", SimulatedClock(0), backend=DEFAULT_BACKEND, input_filters=False
        ).close()
    finally:
        bus.shutdown()


def _logio() -> None:
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    frames = _frames()
    with tempfile.TemporaryDirectory(prefix="lde-warmup-") as tmp:
        d = Path(tmp)
        write_candump(d / "x.log", frames)
        with open_log(d / "x.log") as s:
            list(s)
        csv = CsvWriter(d / "x.csv")
        rec = RecordingWriter(d / "x.mcap", profile)
        run_replay(frames, profile, vehicle, "float", sinks=(csv, rec))
        csv.close()
        rec.close()
        with McapWriter(d / "y.mcap") as w:
            w.write_frames(frames)
        read_mcap(d / "x.mcap", json_topics="all")
        n = 4
        cols = [time_column("t", np.arange(n) * 1000), Column("x", np.linspace(0, 1, n), EXACT)]
        format_rows(cols, ["", ","], "\n")


def _sim() -> None:
    profile = load_profile("lde")
    frames = _frames()
    build_grid(decode_batch(profile, frames), profile)


def _smooth() -> None:
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    with smooth_run([_frames()], profile, vehicle) as track:
        track.read_all()


def _backend(name: str) -> Callable[[], None]:
    def part() -> None:
        _engine(name)
        if name == DEFAULT_BACKEND:
            _service()

    return part


_RUN: dict[str, Callable[[], None]] = {
    **{name: _backend(name) for name in BACKENDS},
    "logio": _logio,
    "sim": _sim,
    "smooth": _smooth,
}


def run_part(part: str) -> tuple[str, float]:
    """Compile (or load) one part's kernels; (part, seconds)."""
    t0 = time.perf_counter()
    _RUN[part]()
    return part, time.perf_counter() - t0


def warm_up(parts: Iterable[str] = PARTS, jobs: int = 1) -> Iterable[tuple[str, float]]:
    """Run the parts (in ``jobs`` processes), yielding (part, seconds) as each ends."""
    todo = list(parts)
    unknown = [p for p in todo if p not in _RUN]
    if unknown:
        raise ValueError(f"unknown warm-up part(s) {', '.join(unknown)}: choose from {', '.join(PARTS)}")
    if jobs <= 1:
        for p in todo:
            yield run_part(p)
        return
    with ProcessPoolExecutor(max_workers=jobs, mp_context=get_context("spawn")) as pool:
        yield from pool.map(run_part, todo)
