"""Benchmark of the batch replay: one hour of traffic, read / decode / grid / filter / overlay / CSV.

Measured, not invented. Synthetic lde-profile traffic for ``--hours`` (default 1 h: MDPS_Sensors
every 3.9 ms with 0..100 us jitter, ESC_Motion every 10 ms, about 1.28 M frames) at ~100 km/h with
small steering and noise is encoded with the vectorised :func:`lde.codec.encode_batch` (E2E counters
and CRCs) and written as

* ``log``: an MCAP log of the input frames only, and
* ``recording``: an lde recording like the live service writes: the input frames, three sent
  frames per step (LDE_Estimate, LDE_Overlay, LDE_Diag: ~2.8 M more frames) and the
  ``/lde/estimate``, ``/lde/inputs``, ``/lde/diag`` JSON channels (replayed on the recorded step
  times);
* optionally (``--candump``) the candump ``-L`` text of the input frames.

Then each stage runs ``--repeat`` times after one warm-up (numba compilation / cache load) and the
medians (min, max) are printed in ms:

    read     lde.logio.read_log (MCAP fast path without lde's own /can/tx frames / candump parser)
    decode   lde.signals.decode_batch (E2E receiver) of the received frames
    grid     lde.grid.build_grid (3.9 ms sample-and-hold)
    filter   the backend's run_batch (float: lde.step)
    overlay  lde.overlay.run_batch_overlay
    csv      lde.replay.write_csv (one row per step)
    total    lde.replay.replay_log + write_csv, end to end

    python bench/bench_replay.py                    # 1 h, 5 repeats, MCAP log and recording
    python bench/bench_replay.py --hours 0.25 --repeat 3 --candump --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from lde.codec import encode_batch, si_to_dbc
from lde.frames import FrameBatch
from lde.grid import build_grid
from lde.logio import McapWriter, read_log, write_candump
from lde.params import load_vehicle
from lde.profiles import load_profile
from lde.replay import (
    estimate,
    recorded_step_times,
    replay,
    replay_log,
    resolve_backend,
    write_csv,
    write_recording,
)
from lde.signals import decode_batch
from lde.units import DEG, KMH, STEP_NS

T0 = 1_700_000_000_000_000_000  # ns


def make_traffic(profile, seconds: float, seed: int) -> FrameBatch:
    """Input frames of the lde profile: smooth signals + noise, encoded in bulk."""
    rng = np.random.default_rng(seed)
    parts = []
    for k, (name, period) in enumerate((("MDPS_Sensors", STEP_NS), ("ESC_Motion", 10_000_000))):
        spec = profile.spec(name)
        n = int(seconds * 1e9 / period)
        t_nom = np.arange(n, dtype=np.int64) * period + k * 2_000_000
        ts = t_nom * 1e-9
        steer = 1.5 * DEG * np.sin(2 * np.pi * 0.3 * ts)
        si_all = {
            "steering_angle": steer + rng.normal(0, 0.05 * DEG, n),
            "steering_rate": 1.5 * DEG * 2 * np.pi * 0.3 * np.cos(2 * np.pi * 0.3 * ts),
            "column_torque": 0.4 * np.sin(2 * np.pi * 0.3 * ts) + rng.normal(0, 0.01, n),
            "assist_torque": 1.2 * np.sin(2 * np.pi * 0.3 * ts) + rng.normal(0, 0.02, n),
            "yaw_rate": 0.01 * np.sin(2 * np.pi * 0.3 * ts - 0.2) + rng.normal(0, 0.03 * DEG, n),
            "lat_accel": 0.3 * np.sin(2 * np.pi * 0.3 * ts - 0.2) + rng.normal(0, 0.05, n),
            "speed": np.full(n, 100 * KMH) + rng.normal(0, 0.05 * KMH, n),
        }
        si = {i: si_all[i] for i in spec.inputs}
        data = encode_batch(profile, name, si_to_dbc(profile, name, si))
        parts.append(
            FrameBatch(
                t_ns=T0 + t_nom + rng.integers(0, 101, n) * 1000,
                can_id=np.full(n, spec.frame_id),
                is_extended=np.zeros(n, bool),
                dlc=np.full(n, spec.length),
                data=data,
                is_rx=np.ones(n, bool),
            )
        )
    return FrameBatch.concat(parts)


def write_live_like_recording(path: Path, frames: FrameBatch, profile, vehicle) -> int:
    """A recording as the live service writes it: 3 sent frames per step + JSON channels."""
    res = replay(frames, profile, vehicle, "float")
    n = len(res)
    spec = profile.spec("LDE_Diag")
    # LDE_Diag per step (the live service sends it; replay has no timing to put in it)
    diag = FrameBatch(
        t_ns=res.t_ns,
        can_id=np.full(n, spec.frame_id),
        is_extended=np.zeros(n, bool),
        dlc=np.full(n, spec.length),
        data=encode_batch(profile, "LDE_Diag", {"StepTime": np.full(n, 50.0)}),
        is_rx=np.zeros(n, bool),
    )
    write_recording(path, frames, res, profile, extra_frames=diag)  # + LDE_Estimate, LDE_Overlay, JSON
    return n * 3


def timed(fn, repeat: int):
    out = fn()  # warm-up: numba compile or cache load
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return times, out


def fmt(name: str, times: list[float]) -> dict:
    med = statistics.median(times)
    d = {"stage": name, "median_ms": 1e3 * med, "min_ms": 1e3 * min(times), "max_ms": 1e3 * max(times)}
    print(f"  {name:<8} {d['median_ms']:9.1f} ms   (min {d['min_ms']:.1f}, max {d['max_ms']:.1f})")
    return d


def bench_file(label: str, path: Path, profile, vehicle, backend: str, repeat: int, tmpdir: Path) -> dict:
    _name, run_batch, _ = resolve_backend(backend)
    size = path.stat().st_size
    times_read, log = timed(lambda: read_log(path, skip_tx=True), repeat)
    steps = recorded_step_times(log)
    rx = log.frames.select(log.frames.is_rx) if not log.frames.is_rx.all() else log.frames
    print(
        f"{label}: {path.name} {size / 1e6:.1f} MB, {len(log.frames)} frames ({len(rx)} received), "
        f"{'recorded step times' if steps is not None else 'grid from frames'}"
    )
    rows = [fmt("read", times_read)]
    times, decoded = timed(lambda: decode_batch(profile, rx), repeat)
    rows.append(fmt("decode", times))
    times, grid = timed(lambda: build_grid(decoded, profile, step_times_ns=steps), repeat)
    rows.append(fmt("grid", times))
    times, est = timed(lambda: estimate(grid, vehicle, run_batch), repeat)
    rows.append(fmt("filter", times))
    from lde.overlay import run_batch_overlay

    times, _ = timed(
        lambda: run_batch_overlay(
            grid.t_ns,
            est.fw,
            est.mw,
            est.status,
            grid.speed,
            grid.steering_angle,
            grid.column_torque,
            vehicle,
        ),
        repeat,
    )
    rows.append(fmt("overlay", times))
    _log, res = replay_log(path, profile, vehicle, backend)
    csv_path = tmpdir / f"{label}.csv"
    times, _ = timed(lambda: write_csv(csv_path, res), repeat)
    rows.append(fmt("csv", times))

    def total():
        _l, r = replay_log(path, profile, vehicle, backend)
        write_csv(csv_path, r)
        return r

    times, res = timed(total, repeat)
    rows.append(fmt("total", times))
    print(
        f"  -> {len(res)} steps, {res.duration_s:.0f} s of traffic, "
        f"CSV {csv_path.stat().st_size / 1e6:.0f} MB"
    )
    return {"label": label, "file_bytes": size, "frames": len(log.frames), "steps": len(res), "stages": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--backend", default="float", choices=("float", "fixed", "paper", "paper-fixed"))
    ap.add_argument("--candump", action="store_true", help="also time a candump -L copy")
    ap.add_argument("--json", type=Path, default=None, help="write the numbers as JSON")
    ap.add_argument("--keep", type=Path, default=None, help="directory to keep the generated files in")
    args = ap.parse_args()
    profile = load_profile("lde")
    vehicle = load_vehicle("reference")
    print(
        f"python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} cpus; "
        f"{args.hours:g} h of traffic, backend {args.backend}, {args.repeat} repeats (medians)"
    )
    with tempfile.TemporaryDirectory() as td:
        tmp = args.keep or Path(td)
        tmp.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        frames = make_traffic(profile, args.hours * 3600, args.seed)
        t1 = time.perf_counter()
        log_path = tmp / "hour.mcap"
        with McapWriter(log_path) as w:
            w.write_frames(frames)
        t2 = time.perf_counter()
        print(f"generate {len(frames)} frames: {t1 - t0:.2f} s (encode_batch); write MCAP: {t2 - t1:.2f} s")
        rec_path = tmp / "hour_recording.mcap"
        t3 = time.perf_counter()
        n_tx = write_live_like_recording(rec_path, frames, profile, vehicle)
        print(f"write recording (+{n_tx} sent frames, JSON channels): {time.perf_counter() - t3:.2f} s")
        results = [
            bench_file("log", log_path, profile, vehicle, args.backend, args.repeat, tmp),
            bench_file("recording", rec_path, profile, vehicle, args.backend, args.repeat, tmp),
        ]
        if args.candump:
            cd_path = tmp / "hour.log"
            t4 = time.perf_counter()
            write_candump(cd_path, frames)
            print(f"write candump: {time.perf_counter() - t4:.2f} s")
            results.append(bench_file("candump", cd_path, profile, vehicle, args.backend, args.repeat, tmp))
    if args.json:
        args.json.write_text(json.dumps({"hours": args.hours, "results": results}, indent=2))


if __name__ == "__main__":
    main()
