"""Summarise ``scripts/tune_zoo.py --out`` files by plant set (docs/design/filters.md, "How the
constants were chosen").

Tuning plants and held-out plants apart, as issue 11's tuning rule needs: met (issue 11's targets),
mean NRMSE Fw / Mw over the disturbed runs, and the disturbance-free drives' worst RMS.

    PYTHONPATH=src:. python scripts/zoo_sets.py /tmp/base.json /tmp/variant.json
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence

import numpy as np
from tune_zoo import meets

TUNE = ("indep_twin", "tires_minus25", "suv_slow", "angle_above_tb")


def line(rows: list[dict]) -> str:
    ok = [r for r in rows if not r.get("lost")]
    dist = [r for r in ok if not r["undist"]]
    und = [r for r in ok if r["undist"]]
    met = sum(meets(r) for r in ok)
    mf = 100 * np.mean([r["fw"] for r in dist])
    mm = 100 * np.mean([r["mw"] for r in dist])
    w10 = sum(max(r["fw"], r["mw"]) <= 0.10 for r in dist)
    und_s = "-"
    if und:
        und_s = f"{max(r['fw'] for r in und):.0f} N / {max(r['mw'] for r in und):.0f} Nm"
    return (
        f"met {met}/{len(ok)}, <=10 % {w10}/{len(dist)}, Fw {mf:.2f} / Mw {mm:.2f} %, "
        f"undisturbed worst {und_s}"
    )


def main(argv: Sequence[str] | None = None) -> None:
    for path in argv if argv is not None else sys.argv[1:]:
        with open(path) as fh:
            rows = json.load(fh)
        tune = [r for r in rows if r["plant"] in TUNE]
        held = [r for r in rows if r["plant"] not in TUNE]
        print(f"{path}\n  tune:     {line(tune)}\n  held out: {line(held)}\n  all:      {line(rows)}")


if __name__ == "__main__":
    main()
