"""Where a whole ``lde replay`` command spends its time, by phase, from a py-spy raw profile.

    py-spy record --rate 500 --threads --format raw -o F.txt -- \\
        python -m lde replay HOUR.log --backend fixed --csv /tmp/x.csv -q
    python bench/pyspy_phases.py F.txt [--rate 500]

Each sample of the main thread goes to the first phase whose marker is on its stack (the engine's
compiled loop, numba's array registry with its BLAS check, the other kernel and registry loads,
imports, reading the log, the CSV hand-off); samples of the reader and CSV threads
are counted apart. Shares are of the main thread's samples: compare them between runs, not the
seconds of a loaded machine.
"""

from __future__ import annotations

import argparse
import collections
import sys

#: (phase, markers): the first phase with a marker on the stack takes the sample
PHASES: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("engine: the compiled data-path loop", ("run_arrays",)),
    # numba's array registry (its BLAS check imports scipy.linalg where scipy is installed)
    ("numba's array registry and its BLAS check", ("_check_blas", "arraymath.py")),
    ("numba: the other kernel and registry loads", ("load_overload", "compile (")),
    ("imports", ("_find_and_load",)),
    ("reading the log (in the main thread)", ("read_file", "iter_frames", "_walk", "_ordered")),
    ("CSV: columns and hand-off to its thread", ("CsvWriter",)),
)
THREADS = (("lde-read", "reader thread"), ("lde-csv", "CSV thread"))


def phases(path: str) -> collections.Counter[str]:
    out: collections.Counter[str] = collections.Counter()
    with open(path) as fh:
        for line in fh:
            stack, _, n = line.rstrip("\n").rpartition(" ")
            frames = stack.split(";")
            thread = next((name for tag, name in THREADS if tag in frames[0]), None)
            if thread is None:
                names = ";".join(frames[1:])
                thread = next((p for p, ms in PHASES if any(m in names for m in ms)), "other (main thread)")
            out[thread] += int(n)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw", nargs="+")
    ap.add_argument("--rate", type=float, default=500.0, help="py-spy's --rate [samples/s]")
    args = ap.parse_args(argv)
    for path in args.raw:
        c = phases(path)
        main_n = sum(v for k, v in c.items() if k not in {name for _, name in THREADS})
        print(f"{path}: main thread {main_n / args.rate:.2f} s sampled")
        for k, v in c.most_common():
            share = f"{100 * v / main_n:5.1f} %" if k not in {name for _, name in THREADS} else "  apart"
            print(f"  {v / args.rate:6.2f} s  {share}  {k}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
