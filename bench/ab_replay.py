"""`lde replay` from two source trees, taking turns: wall, CPU and peak RSS of each command.

    python bench/ab_replay.py /work/main /work/wt-x --log /tmp/lde-bench/hour.log \\
        --log /tmp/lde-bench/hour.mcap [--backend fixed --backend float] [--rounds 4]

Each tree runs as ``PYTHONPATH=TREE/src:TREE python -m lde replay LOG --backend B --csv OUT -q``,
after one warm-up run each (page cache, each tree's numba cache). Besides wall, CPU (user + sys) and
peak RSS it prints the main thread's CPU (the decode and filter path's one core; the reader and CSV
threads run beside it). Every round runs every command
once, so that a change in the machine's load falls on all of them alike; the load average before and
after is printed with the medians (min-max). The CSVs of the two trees are compared byte for byte.
"""

from __future__ import annotations

import argparse
import filecmp
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

_WRAP = (
    "import json, resource, subprocess, sys, time\n"
    "t = time.perf_counter(); r = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
    "w = time.perf_counter() - t; u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
    "print(json.dumps([r.returncode, w, u.ru_utime + u.ru_stime, u.ru_maxrss, r.stderr[-500:]]))\n"
)


#: ``python -m lde`` that also says, at exit, its main thread's CPU time: the one core of the decode
#: and filter path (imports, kernel loads, the engine), without the reader and CSV threads' CPU
_LDE = (
    "import atexit, runpy, sys, time\n"
    "atexit.register(lambda: sys.stderr.write(f'\\nab-main-thread-cpu {time.thread_time():.4f}\\n'))\n"
    "sys.argv = ['lde', *sys.argv[1:]]\n"
    "runpy.run_module('lde', run_name='__main__', alter_sys=True)\n"
)


def run(tree: Path, argv: list[str]) -> tuple[float, float, float, float]:
    """Wall, CPU (user + sys), peak RSS [MiB] and main-thread CPU of one command."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPATH"] = f"{tree}/src:{tree}"
    out = subprocess.run(
        [sys.executable, "-c", _WRAP, sys.executable, "-c", _LDE, *argv],
        capture_output=True,
        text=True,
        env=env,
        cwd=tree,
    )
    rc, wall, cpu, rss_kib, err = json.loads(out.stdout)
    if rc not in (0, 3):
        raise SystemExit(f"{tree}: lde {' '.join(argv)} failed ({rc}): {err}")
    main_cpu = float(err.rsplit("ab-main-thread-cpu ", 1)[1].split()[0])
    return wall, cpu, rss_kib / 1024, main_cpu


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("trees", nargs=2, type=Path)
    ap.add_argument("--log", action="append", type=Path, required=True)
    ap.add_argument("--backend", action="append", default=None)
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args(argv)
    backends = args.backend or ["fixed"]
    tmp = Path(tempfile.mkdtemp(prefix="lde-ab-"))
    cmds = []
    for log in args.log:
        for b in backends:
            for i, tree in enumerate(args.trees):
                csv = tmp / f"{log.name}.{b}.{i}.csv"
                cmds.append(
                    (
                        f"{tree.name:12s} {log.name} {b}",
                        tree,
                        csv,
                        ["replay", str(log.resolve()), "--backend", b, "--csv", str(csv), "-q"],
                    )
                )
    load0 = os.getloadavg()[0]
    for _, tree, _, a in cmds:
        run(tree, a)
    res: dict[str, list[tuple[float, float, float, float]]] = {label: [] for label, *_ in cmds}
    for _ in range(args.rounds):
        for label, tree, _, a in cmds:
            res[label].append(run(tree, a))
    print(f"load average {load0:.2f} before, {os.getloadavg()[0]:.2f} after; {args.rounds} rounds")
    for label, xs in res.items():
        w = [x[0] for x in xs]
        print(
            f"{label}  wall {statistics.median(w):.3f} ({min(w):.3f}-{max(w):.3f})  "
            f"cpu {statistics.median(x[1] for x in xs):.3f}  "
            f"main thread cpu {statistics.median(x[3] for x in xs):.3f}  "
            f"peak RSS {max(x[2] for x in xs):.0f} MiB"
        )
    for k in range(0, len(cmds), 2):
        same = filecmp.cmp(cmds[k][2], cmds[k + 1][2], shallow=False)
        print(f"CSV {cmds[k][2].name.rsplit('.', 2)[0]}: {'byte-identical' if same else 'DIFFERENT'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
