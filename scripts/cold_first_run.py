#!/usr/bin/env python3
"""The first ``lde replay`` after an install, measured: each run on an empty ``NUMBA_CACHE_DIR``.

Compares source trees (each run with ``PYTHONPATH=TREE/src:TREE``), alternating them within each
round so that they share the machine's load::

    python scripts/cold_first_run.py --trees /work/main,. --backends fixed,float --rounds 3

Per run: wall seconds to the CSV (the command's exit), CPU seconds of the command and every process
it waited for (the compile helper of :mod:`lde.coldstart` included), the 1-minute load average
before it, and whether the CSV equals the first tree's. Then medians and ranges per tree and backend.
``--second``: each run is followed by a second one on the cache it filled (what the user's next
command gets: it must be warm).
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


def _run(tree: Path, backend: str, log: Path, csv: Path, second: bool = False) -> tuple[float, ...]:
    """(wall, CPU, load) of a run on an empty cache, then (wall, CPU) of a second one on the cache it
    filled when ``second``."""
    cache = Path(tempfile.mkdtemp(prefix="lde-cold-nb-"))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=f"{tree / 'src'}:{tree}")
    argv = [sys.executable, "-m", "lde", "replay", str(log), "--csv", str(csv), "-q", "--backend", backend]
    load = os.getloadavg()[0]
    out: list[float] = []
    for _ in range(2 if second else 1):
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run(argv, env=env, check=True, stdin=subprocess.DEVNULL)
        wall = time.perf_counter() - t0
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        out += [wall, (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)]
    shutil.rmtree(cache, ignore_errors=True)
    return out[0], out[1], load, *out[2:]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--trees", default="/work/main,.", help="comma-separated source trees")
    ap.add_argument("--backends", default="fixed,float")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--log", type=Path, default=Path("tests/data/sample_linear.log"))
    ap.add_argument("--second", action="store_true", help="also time a second run on the filled cache")
    a = ap.parse_args()
    trees = [Path(t).resolve() for t in a.trees.split(",")]
    backends = a.backends.split(",")
    out = Path(tempfile.mkdtemp(prefix="lde-cold-csv-"))
    res: dict[tuple[int, str], list[tuple[float, ...]]] = {}
    for r in range(a.rounds):
        for b in backends:
            for i, tree in enumerate(trees):
                csv = out / f"{i}-{b}-{r}.csv"
                got = _run(tree, b, a.log.resolve(), csv, a.second)
                wall, cpu, load = got[:3]
                same = (
                    ""
                    if i == 0
                    else (" same CSV" if filecmp.cmp(csv, out / f"0-{b}-{r}.csv", False) else " CSV DIFFERS")
                )
                print(
                    f"round {r + 1} {b:5s} {tree}: {wall:5.1f} s wall, {cpu:5.1f} s CPU, "
                    f"load {load:.2f}{same}"
                    + (f"; second run {got[3]:5.1f} s wall, {got[4]:5.1f} s CPU" if a.second else ""),
                    flush=True,
                )
                res.setdefault((i, b), []).append(got)
    print("\nmedian (range) over the rounds:")
    for b in backends:
        for i, tree in enumerate(trees):
            w, c, ld, *sec = zip(*res[(i, b)], strict=True)
            print(
                f"  {b:5s} {tree}: wall {statistics.median(w):.1f} s ({min(w):.1f}-{max(w):.1f}), "
                f"CPU {statistics.median(c):.1f} s ({min(c):.1f}-{max(c):.1f}), "
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
