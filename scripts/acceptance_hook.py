"""The acceptance drive of ``tests/replay/test_replay.py`` (a crosswind step on the linear sample plant)
replayed in process under learner/filter hooks (``scripts/tune_zoo.py``'s ``--hook`` syntax): the
settled Fw / Mw means (truth 800 N / -300 Nm, 10-20 s) and the range of their 1 s windows, what the
test bounds (Fw 5 %, Mw 10 % per window). A variant of the learner's constants must keep it.

    PYTHONPATH=src:. python scripts/acceptance_hook.py "" "L_EXC_SW=0.2*DEG" "L_EXC_SW=0.2*DEG,L_EXC_F=500"
"""

from __future__ import annotations

import csv
import sys
from collections.abc import Sequence
from pathlib import Path

from tune_zoo import make_hook, run_engine

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"


def main(argv: Sequence[str] | None = None) -> None:
    from lde.io import read_log
    from lde.params import load_vehicle

    frames = read_log(DATA / "sample_linear.log").frames
    vehicle = load_vehicle(DATA / "sample_linear_vehicle.toml")
    with (DATA / "sample_linear_truth.csv").open() as fh:
        first = next(csv.DictReader(fh))
    t0 = int(first["t"].replace(".", "")) * 1000
    for hook in (argv if argv is not None else sys.argv[1:]) or [""]:
        block, _ = run_engine(frames, "lde", vehicle, None, None, make_hook(hook))
        t = (block.t_ns - t0) * 1e-9
        settled = (t >= 10.0) & (t < 20.0)
        fw = [block.fw[(t >= a) & (t < a + 1.0)].mean() for a in range(10, 20)]
        mw = [block.mw[(t >= a) & (t < a + 1.0)].mean() for a in range(10, 20)]
        print(
            f"{hook or 'shipped'}: Fw {block.fw[settled].mean():.1f} N "
            f"(800; 1 s windows {min(fw):.0f}..{max(fw):.0f}), "
            f"Mw {block.mw[settled].mean():.1f} Nm (-300; 1 s windows {min(mw):.0f}..{max(mw):.0f})"
        )


if __name__ == "__main__":
    main()
