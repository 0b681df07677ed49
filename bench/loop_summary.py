"""A markdown table of ``bench/bench_loop.py --out FILE`` runs: per label, the median over its runs
and the range (min-max) of each figure, with the 1-minute load average at the start of each run.

    python bench/loop_summary.py bench/results/results_loop_2026-11-23-lean.jsonl
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
from collections import defaultdict

COLS = [
    ("step cost p50 / p99", ("step_cost_p50_us", "step_cost_p99_us")),
    ("step time p50 / p99", ("step_time_p50_us", "step_time_p99_us")),
    ("period error p50 / p99 / max", ("period_error_p50_us", "period_error_p99_us", "period_error_max_us")),
    ("latency p50 / p99 / max", ("latency_p50_us", "latency_p99_us", "latency_max_us")),
    ("deadline misses (skipped)", ("deadline_misses", "skipped")),
    ("outputs per grid point", ("outputs_per_grid_point",)),
]


def _fmt(vals: list[float], pct: bool = False) -> str:
    med = statistics.median(vals)
    if pct:
        return f"{med:.2%}" if len(vals) == 1 else f"{med:.2%} ({min(vals):.2%}-{max(vals):.2%})"
    f = (lambda v: f"{v:.0f}") if all(abs(v) >= 10 or v == int(v) for v in vals) else (lambda v: f"{v:.1f}")
    return f(med) if len(vals) == 1 else f"{f(med)} ({f(min(vals))}-{f(max(vals))})"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("jsonl", nargs="+")
    args = ap.parse_args(argv)
    runs: dict[str, list[dict]] = defaultdict(list)
    for path in args.jsonl:
        with open(path) as fh:
            for line in fh:
                if line.strip():
                    d = json.loads(line)
                    runs[d.get("label", "")].append(d)
    head = ["run", "n", "load avg (1 min, at start)"] + [c for c, _ in COLS]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for label, rs in runs.items():
        cells = [label, str(len(rs)), ", ".join(f"{r['load_avg'][0]:.1f}" for r in rs)]
        for _, keys in COLS:
            parts = [_fmt([float(r[k]) for r in rs], pct=k == "outputs_per_grid_point") for k in keys]
            if keys == ("deadline_misses", "skipped"):
                cells.append(f"{parts[0]} ({parts[1]})")
            else:
                cells.append(" / ".join(parts))
        print("| " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
