"""Benchmark of the CAN layer: batch decode, step grid, batch encode and the live receiver.

Measured, not invented: synthetic lde-profile traffic (MDPS_Sensors every 3.9 ms with jitter,
ESC_Motion every 10 ms; one hour = about 1.28 M input frames) is encoded with lde.can.codec, then
:func:`lde.engine.receiver.decode_batch` and :func:`lde.engine.grid.build_grid` run ``--repeat`` times after
one
warm-up (numba compilation / cache load). Prints medians (and min/max) in milliseconds, the
throughput, and the live :class:`lde.engine.receiver.Receiver` cost per fed frame and per sample.

    python bench/bench_decode.py                      # one hour of traffic, 7 repeats
    python bench/bench_decode.py --hours 0.25 --repeat 5 --profile hyundai --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from lde.can.codec import encode_frames, si_to_dbc
from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.engine.grid import build_grid
from lde.engine.receiver import Receiver, decode_batch

T0 = 1_700_000_000_000_000_000  # ns


def make_traffic(profile, seconds: float, seed: int) -> FrameBatch:
    """Periodic traffic of every input message of ``profile`` with 0..200 us jitter, random SI values."""
    rng = np.random.default_rng(seed)
    parts = []
    for k, spec in enumerate(profile.messages.values()):
        n = int(seconds * 1e9 / spec.period_ns)
        t = T0 + k * 1_000_000 + np.arange(n, dtype=np.int64) * spec.period_ns + rng.integers(0, 200_000, n)
        si = {}
        for name in spec.inputs:
            si[name] = rng.uniform(5.0, 40.0, n) if name == "speed" else rng.uniform(0.0, 0.5, n)
        parts.append(encode_frames(profile, spec.name, t, si_to_dbc(profile, spec.name, si)))
    return FrameBatch.concat(parts)


def timed(fn, repeat: int) -> tuple[list[float], object]:
    out = fn()  # warm-up
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return times, out


def summary(name: str, times: list[float], n: int | None = None) -> dict:
    med = statistics.median(times)
    d = {"name": name, "median_ms": 1e3 * med, "min_ms": 1e3 * min(times), "max_ms": 1e3 * max(times)}
    if n:
        d["frames_per_s"] = n / med
    rate = f", {d['frames_per_s'] / 1e6:.1f} M frames/s" if n else ""
    print(f"{name:28s} median {d['median_ms']:9.2f} ms  (min {d['min_ms']:.2f}, max {d['max_ms']:.2f}){rate}")
    return d


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--hours", type=float, default=1.0, help="hours of traffic (default 1)")
    ap.add_argument("--repeat", type=int, default=7, help="timed repetitions after one warm-up")
    ap.add_argument("--profile", default="lde")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--live-frames", type=int, default=20000, help="frames fed to the live receiver")
    ap.add_argument("--json", help="write the results here")
    args = ap.parse_args()

    p = load_profile(args.profile)
    seconds = args.hours * 3600.0
    t0 = time.perf_counter()
    fb = make_traffic(p, seconds, args.seed)
    print(
        f"profile {p.name}: {len(fb)} frames ({args.hours:g} h) generated in {time.perf_counter() - t0:.2f} s"
    )
    machine = f"{platform.machine()} {platform.processor() or ''}".strip()
    print(f"machine: {machine}, cpus={os.cpu_count()}, python {platform.python_version()}")

    results = []
    t_dec, d = timed(lambda: decode_batch(p, fb), args.repeat)
    results.append(summary("decode_batch", t_dec, len(fb)))
    t_grid, g = timed(lambda: build_grid(d, p), args.repeat)
    results.append(summary("build_grid", t_grid))
    t_both = [a + b for a, b in zip(t_dec, t_grid, strict=True)]
    results.append(summary("decode + grid", t_both, len(fb)))
    print(f"  grid steps {len(g)}, mdps_ok {g.mdps_ok.mean():.4f}, esc_ok {g.esc_ok.mean():.4f}")

    first = next(iter(p.messages.values()))
    cols = {s: np.zeros(len(fb)) for s in p.inputs[first.inputs[0]].signals}
    from lde.can.codec import encode_batch

    t_enc, _ = timed(lambda: encode_batch(p, first.name, cols), args.repeat)
    results.append(summary(f"encode_batch {first.name}", t_enc, len(fb)))

    # live receiver: per-frame feed and per-step sample cost
    n_live = min(args.live_frames, len(fb))
    sub = fb[:n_live]
    rows = [
        (int(sub.t_ns[i]), int(sub.can_id[i]), sub.data[i].tobytes(), int(sub.dlc[i])) for i in range(n_live)
    ]
    feed_times, sample_times = [], []
    for _ in range(3):
        r = Receiver(p)
        t0 = time.perf_counter()
        for row in rows:
            r.feed(*row)
        feed_times.append((time.perf_counter() - t0) / n_live)
        ts = np.linspace(rows[0][0], rows[-1][0], 2000).astype(np.int64)
        t0 = time.perf_counter()
        for t in ts:
            r.sample(int(t))
        sample_times.append((time.perf_counter() - t0) / ts.size)
    f_us = 1e6 * statistics.median(feed_times)
    s_us = 1e6 * statistics.median(sample_times)
    print(f"{'Receiver.feed':28s} median {f_us:9.2f} us/frame")
    print(f"{'Receiver.sample':28s} median {s_us:9.2f} us/step")
    results.append({"name": "Receiver.feed", "median_us_per_frame": f_us})
    results.append({"name": "Receiver.sample", "median_us_per_step": s_us})

    if args.json:
        with open(args.json, "w") as f:
            json.dump(
                {"profile": p.name, "frames": len(fb), "hours": args.hours, "results": results}, f, indent=2
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
