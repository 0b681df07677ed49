"""Simulator speed, measured: ``python -m vcan_sim.bench [--repeat N]``.

Reports the median wall time of :func:`vcan_sim.run.simulate` (plant + sensors + frame encoding, no
file output) for a few scenarios, per run and per simulated minute, after one warm-up run (numba
compilation and cache loading excluded), plus the time to write the candump log, truth CSV and MCAP.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from .output import write_outputs
from .run import simulate

SCENARIOS = ("straight", "heavy_load", "gusty_wind", "payload_full")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    simulate("straight", duration=1.0)  # warm-up
    print(f"{'scenario':<14} {'sim s':>6} {'frames':>7} {'median s':>9} {'s per sim min':>14}")
    for name in SCENARIOS:
        times = []
        for seed in range(args.repeat):
            t = time.perf_counter()
            res = simulate(name, seed=seed)
            times.append(time.perf_counter() - t)
        dur = (res.truth_t_ns[-1] - res.t0_ns) * 1e-9
        med = statistics.median(times)
        print(f"{name:<14} {dur:6.1f} {len(res.frames):7d} {med:9.3f} {med / dur * 60:14.3f}")
    res = simulate("gusty_wind", seed=0)
    with tempfile.TemporaryDirectory() as d:
        for kind in ("log", "truth", "mcap"):
            times = []
            path = Path(d) / f"out.{kind}"
            for _ in range(args.repeat):
                t = time.perf_counter()
                write_outputs(
                    res,
                    log=path if kind == "log" else None,
                    truth=path if kind == "truth" else None,
                    mcap=path if kind == "mcap" else None,
                )
                times.append(time.perf_counter() - t)
            print(f"write {kind:<6} (gusty_wind, 60 s): median {statistics.median(times):.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
