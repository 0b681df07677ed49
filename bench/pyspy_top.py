"""Top functions of a py-spy raw profile inside one function's calls (self time of the innermost
Python frame, as a share of the samples whose stack holds ``--inside``).

    py-spy record --rate 2000 --format raw -o F.txt -- python bench/bench_service_step.py --steps 4000
    python bench/pyspy_top.py F.txt [--inside step_once] [--top 15]
"""

from __future__ import annotations

import argparse
import collections
import re
import sys

_FRAME = re.compile(r"^(?P<fn>[^ ]+) \((?P<file>[^:)]+)(?::\d+)?\)$")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("raw")
    ap.add_argument("--inside", default="step_once")
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args(argv)
    own: collections.Counter[str] = collections.Counter()
    total = 0
    with open(args.raw) as fh:
        for line in fh:
            stack, _, n = line.rstrip("\n").rpartition(" ")
            frames = stack.split(";")
            names = []
            for f in frames:
                m = _FRAME.match(f.strip())
                names.append(f"{m['fn']} ({m['file'].rsplit('/', 1)[-1]})" if m else f.strip())
            if not any(nm.split(" ")[0].rsplit(".", 1)[-1] == args.inside for nm in names):
                continue
            total += int(n)
            own[names[-1]] += int(n)
    print(f"samples inside {args.inside}: {total}")
    for name, n in own.most_common(args.top):
        print(f"{100 * n / max(total, 1):6.1f} %  {n:6d}  {name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
