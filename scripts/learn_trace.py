"""The learner's course over a cold first drive against the plant's true values (diagnosis only).

Every second of the drive (cold, spec sheet): the learned K, trail K/Cf, Cf, Cr (relative error
against ``vcan_sim/zoo/true_values.csv``, read for this comparison only), the regressions'
posterior relative std of s/K (R3), L/t (R1) and 2 Cr (R2), the sample counts and the state.

    PYTHONPATH=src:scripts:. python scripts/learn_trace.py --plants indep_twin --profiles lde
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from first_drive_study import simulated
from light_diagnosis import engine_for, grid_arrays, run_grid, true_values
from tune_zoo import make_hook, map_runs

from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.paper import N_OUT

MARKS = (30, 60, 90, 120, 180, 300, 600)


def trace(plant: str, profile: str, seed: int, hook: str, scenario: str = "first_drive") -> list[dict[str, float]]:
    frames, truth = simulated(plant, scenario, profile, seed)
    eng = engine_for(plant, profile, None)
    h = make_hook(hook)
    info = eng.est.info
    if h is not None:
        h(info["p"], info["lp"])
        info["learner"][:] = Ln.init_state(info["p"], info["lp"], friction_prior=0.3)
    g, inp, fresh = grid_arrays(frames, profile)
    tv = true_values(plant)
    p, ls = info["p"], info["learner"]
    out = np.zeros((len(g), N_OUT))
    rows = []
    chunk = 256
    t0 = g.t_ns[0]
    for a in range(0, len(g), chunk):
        b = min(len(g), a + chunk)
        run_grid(eng.est.params, eng.est.state, g.t_ns[a:b], inp[a:b], fresh[a:b], g.mdps_ok[a:b], g.esc_ok[a:b], out[a:b])
        trail = p[E.P_K] / p[E.P_CF]
        rows.append(
            {
                "t": (g.t_ns[b - 1] - t0) * 1e-9,
                "eK": p[E.P_K] / tv.k - 1.0,
                "et": trail / (tv.k / tv.cf) - 1.0,
                "eCf": p[E.P_CF] / tv.cf - 1.0,
                "eCr": p[E.P_CR] / tv.cr - 1.0,
                "sK": math.sqrt(max(ls[Ln.LS_P3 + Ln.N3 + 1], 0.0)) / abs(ls[Ln.LS_T3 + 1]),
                "st": math.sqrt(max(ls[Ln.LS_P1], 0.0)) / abs(ls[Ln.LS_T1]),
                "sCr": math.sqrt(max(ls[Ln.LS_P2], 0.0)) / abs(ls[Ln.LS_T2]),
                "n": ls[Ln.LS_N],
                "n3": ls[Ln.LS_N + 1],
                "n1": ls[Ln.LS_N + 2],
                "state": ls[Ln.LS_STATE],
                "ctb": math.degrees(p[E.P_CTB]),
                "tf": p[E.P_TFRIC],
            }
        )
    return rows


def one(args: tuple) -> list[dict[str, Any]]:
    plant, profile, seed, hook = args
    rows = trace(plant, profile, seed, hook)
    return [{"plant": plant, "profile": profile, "seed": seed, "rows": rows}]


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="indep_twin,tires_minus25,suv_slow,angle_above_tb")
    ap.add_argument("--profiles", default="lde,hyundai")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--hook", default="")
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    tasks = [(pl, pr, int(s), a.hook) for s in a.seeds.split(",") for pl in a.plants.split(",") for pr in a.profiles.split(",")]
    for res in map_runs(one, tasks, a.jobs):
        rows = res["rows"]
        learned = next((r["t"] for r in rows if r["state"] == 2), math.nan)
        print(f"== {res['plant']} {res['profile']} s{res['seed']}: learned at {learned:.0f} s")
        print("   t    eK%   et%  eCf%  eCr% | sK%  st%  sCr% |   n3    n1 st  ctb   tf")
        for r in rows:
            if any(abs(r["t"] - m) < 0.5 for m in MARKS):
                print(f"  {r['t']:4.0f} {100 * r['eK']:5.1f} {100 * r['et']:5.1f} {100 * r['eCf']:5.1f} {100 * r['eCr']:5.1f} | "
                      f"{100 * r['sK']:4.1f} {100 * r['st']:4.1f} {100 * r['sCr']:4.1f} | {r['n3']:5.0f} {r['n1']:5.0f} "
                      f"{r['state']:.0f} {r['ctb']:4.2f} {r['tf']:4.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
