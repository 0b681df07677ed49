"""Accuracy of the RTS smoother beside the causal filter on the zoo (cars the estimator was not fitted
to): NRMSE after 2 s of Fw and Mw against the simulator's truth, causal vs smoothed, per plant x
profile x scenario, cold (only the spec-sheet vehicle file) with backend ``float``.

The drives are the zoo's (``scripts/tune_zoo.py``'s cache of ``lde.analysis.study`` simulations, seed 0);
each is replayed in process by :func:`lde.replay.replay.replay` with ``smooth=True`` (the same two passes
as ``lde replay --smooth``) and scored with :func:`lde.analysis.metrics.accuracy` (Mw about the vehicle
file's CG, as issue 11's targets; disturbance-free drives: the RMS of the estimate in N / Nm).

    PYTHONPATH=src:. python bench/smooth_zoo.py [--plants a,b] [--profiles lde,hyundai] [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from tune_zoo import simulated, spec_vehicle  # noqa: E402


def figures(t, fw, mw, valid, truth, scenario):
    from lde.analysis import metrics
    from lde.analysis.study.execute import scenario_kind

    tr = metrics.Truth(t=truth["t"], fw=truth["Fw"], mw=truth["Mw"], mw_ref=truth["Mw_ref"])
    acc = metrics.accuracy(t, fw, mw, tr, valid=valid, kind=scenario_kind(scenario))
    f, m = metrics.target_figures(acc)
    return float(f), float(m), acc.kind is metrics.Kind.UNDISTURBED


def main() -> int:
    from lde.analysis.study.zoo import ZOO_SCENARIOS, plants
    from lde.can.profiles import load_profile
    from lde.replay.replay import replay
    from lde.replay.smoother import S_FW, S_MW
    from lde.status import VALID

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--plants", default=",".join(plants()))
    ap.add_argument("--profiles", default="lde,hyundai")
    ap.add_argument("--scenarios", default=",".join(ZOO_SCENARIOS))
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    rows = []
    for plant in a.plants.split(","):
        vehicle = spec_vehicle(plant)
        for prof in a.profiles.split(","):
            profile = load_profile(prof)
            for sc in a.scenarios.split(","):
                frames, truth = simulated(plant, sc, prof, 0)
                if not bool(truth["ok"]):
                    continue
                res = replay(frames, profile, vehicle, "float", output_frames=False, smooth=True)
                assert res.smooth is not None
                t = res.t_ns * 1e-9
                valid = (res.status & int(VALID)) != 0
                fc, mc, undist = figures(t, res.fw, res.mw, valid, truth, sc)
                fs, ms, _ = figures(t, res.smooth[:, S_FW], res.smooth[:, S_MW], valid, truth, sc)
                rows.append(
                    {"plant": plant, "profile": prof, "scenario": sc, "undist": undist,
                     "fw_causal": fc, "mw_causal": mc, "fw_smooth": fs, "mw_smooth": ms}
                )  # fmt: skip
                print(
                    f"{plant:15s} {prof:8s} {sc:16s} "
                    + (
                        f"RMS Fw {fc:6.1f} -> {fs:6.1f} N, Mw {mc:6.1f} -> {ms:6.1f} Nm"
                        if undist
                        else f"NRMSE Fw {100 * fc:5.1f} -> {100 * fs:5.1f} %, "
                        f"Mw {100 * mc:5.1f} -> {100 * ms:5.1f} %"
                    ),
                    flush=True,
                )
    summarise(rows)
    if a.out:
        a.out.write_text(json.dumps(rows, indent=0))
    return 0


def summarise(rows: list[dict]) -> None:
    print("\nper scenario (median over plants x profiles; NRMSE % or RMS N / Nm for lane_change):")
    print(
        "| scenario | runs | Fw causal | Fw smoothed | Mw causal | Mw smoothed | smoothed better (Fw / Mw) |"
    )
    print("|---|---|---|---|---|---|---|")
    for sc in dict.fromkeys(r["scenario"] for r in rows):
        rs = [r for r in rows if r["scenario"] == sc]
        k = 1.0 if rs[0]["undist"] else 100.0
        med = {
            c: k * float(np.median([r[c] for r in rs]))
            for c in ("fw_causal", "fw_smooth", "mw_causal", "mw_smooth")
        }
        bf = sum(r["fw_smooth"] < r["fw_causal"] for r in rs)
        bm = sum(r["mw_smooth"] < r["mw_causal"] for r in rs)
        print(
            f"| {sc} | {len(rs)} | {med['fw_causal']:.1f} | {med['fw_smooth']:.1f} | {med['mw_causal']:.1f} "
            f"| {med['mw_smooth']:.1f} | {bf}/{len(rs)} / {bm}/{len(rs)} |"
        )


if __name__ == "__main__":
    raise SystemExit(main())
