#!/usr/bin/env python3
"""The first ``lde replay`` after an install, measured: each run on an empty ``NUMBA_CACHE_DIR``.

Compares source trees (each run with ``PYTHONPATH=TREE/src:TREE``), alternating them within each
round so that they share the machine's load::

    python scripts/cold_first_run.py --trees /work/main,. --backends fixed,float --rounds 3

Per run: wall seconds to the CSV (the command's exit), CPU seconds of the command and every process
it waited for, the 1-minute load average
before it, and whether the CSV equals the first tree's. Then medians and ranges per tree and backend.
``--second``: each run is followed by a second one on the cache it filled (what the user's next
command gets: it must be warm). ``--demo SEC``: ``lde demo --duration SEC`` instead of the replay
(its summary compared instead of the CSV). ``notice``: when the first line on stderr came.
"""

from __future__ import annotations

import argparse
import filecmp
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _timed(argv: list[str], env: dict[str, str], stdout: Path) -> tuple[float, float]:
    """Run ``argv`` (its stdout to ``stdout``): its wall seconds and when its first stderr line came."""
    t0 = time.perf_counter()
    with stdout.open("wb") as out:
        proc = subprocess.Popen(argv, env=env, stdin=subprocess.DEVNULL, stdout=out, stderr=subprocess.PIPE)
        assert proc.stderr is not None
        first = proc.stderr.readline()
        t_first = time.perf_counter() - t0 if first else float("nan")
        rest = proc.stderr.read()
        if proc.wait() != 0:
            sys.exit(f"{' '.join(argv)}: exit {proc.returncode}: {(first + rest).decode()[-2000:]}")
    return time.perf_counter() - t0, t_first


def _run(
    tree: Path, backend: str, log: Path, csv: Path, second: bool = False, demo_s: float | None = None
) -> tuple[float, ...]:
    """(wall, CPU, load, notice) of a run on an empty cache, then (wall, CPU) of a second one on the
    cache it filled when ``second``."""
    cache = Path(tempfile.mkdtemp(prefix="lde-cold-nb-"))
    # PYTHONSAFEPATH: `python -m` would import firmware_model from the working directory, not TREE
    env = dict(
        os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=f"{tree / 'src'}:{tree}", PYTHONSAFEPATH="1"
    )
    argv = [sys.executable, "-m", "lde", "replay", str(log), "--csv", str(csv), "--backend", backend]
    if demo_s is not None:
        argv = [sys.executable, "-m", "lde", "demo", "--no-mcap", "--no-plot", "--duration", str(demo_s)]
        argv += ["--backend", backend]
    load = os.getloadavg()[0]
    out: list[float] = []
    notice = float("nan")
    for k in range(2 if second else 1):
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        wall, t_first = _timed(argv, env, csv.with_suffix(".stdout") if k == 0 else Path(os.devnull))
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out += [wall, (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)]
        notice = t_first if k == 0 else notice
    shutil.rmtree(cache, ignore_errors=True)
    return out[0], out[1], load, notice, *out[2:]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trees", default="/work/main,.", help="comma-separated source trees")
    ap.add_argument("--backends", default="fixed,float")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--log", type=Path, default=Path("tests/data/sample_linear.log"))
    ap.add_argument("--second", action="store_true", help="also time a second run on the filled cache")
    ap.add_argument("--demo", type=float, metavar="SEC", help="lde demo --duration SEC instead of the replay")
    a = ap.parse_args()
    trees = [Path(t).resolve() for t in a.trees.split(",")]
    backends = a.backends.split(",")
    out = Path(tempfile.mkdtemp(prefix="lde-cold-csv-"))
    res: dict[tuple[int, str], list[tuple[float, ...]]] = {}
    for r in range(a.rounds):
        for b in backends:
            for i, tree in enumerate(trees):
                csv = out / f"{i}-{b}-{r}.csv"
                got = _run(tree, b, a.log.resolve(), csv, a.second, a.demo)
                wall, cpu, load, notice = got[:4]
                kind, ref = "CSV", out / f"0-{b}-{r}.csv"
                if a.demo is not None:  # the demo's summary
                    kind, csv, ref = "summary", csv.with_suffix(".stdout"), ref.with_suffix(".stdout")
                same = (
                    ""
                    if i == 0
                    else (f" same {kind}" if filecmp.cmp(csv, ref, False) else f" {kind} DIFFERS")
                )
                print(
                    f"round {r + 1} {b:5s} {tree}: {wall:5.1f} s wall, {cpu:5.1f} s CPU, notice after "
                    f"{notice:.2f} s, load {load:.2f}{same}"
                    + (f"; second run {got[4]:5.1f} s wall, {got[5]:5.1f} s CPU" if a.second else ""),
                    flush=True,
                )
                res.setdefault((i, b), []).append(got)
    print("\nmedian (range) over the rounds:")
    for b in backends:
        for i, tree in enumerate(trees):
            w, c, ld, nt, *sec = zip(*res[(i, b)], strict=True)
            print(
                f"  {b:5s} {tree}: wall {statistics.median(w):.1f} s ({min(w):.1f}-{max(w):.1f}), "
                f"CPU {statistics.median(c):.1f} s ({min(c):.1f}-{max(c):.1f}), "
                f"notice {statistics.median(nt):.2f} s ({min(nt):.2f}-{max(nt):.2f}), "
                f"load {min(ld):.1f}-{max(ld):.1f}"
                + (
                    f"; second run CPU {statistics.median(sec[1]):.1f} s "
                    f"({min(sec[1]):.1f}-{max(sec[1]):.1f})"
                    if sec
                    else ""
                )
            )
    shutil.rmtree(out, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
