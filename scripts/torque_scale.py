"""Torque signals of unknown scale on the simulator (docs/estimator.md, "Torques of unknown scale").

The cold first drive of a zoo plant with its torque inputs multiplied by factors the estimator is not
told (a profile whose torques are raw counts: ``--assist 2.7`` reads 2.7 counts per Nm of assist),
the learner in the matching ``L_TSCALE`` mode; against the same drive in Nm. Prints the learned
factor against the true one, when the learner reports "learned", and the per-minute NRMSE.

    PYTHONPATH=src:scripts:. python scripts/torque_scale.py --plants indep_twin --profiles lde
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

import numpy as np
from first_drive_study import _truth, simulated
from light_diagnosis import engine_for, grid_arrays, run_grid
from tune_zoo import map_runs

from lde.analysis import metrics
from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.paper import N_OUT, O_FW, O_LEARN, O_MW
from lde.status import VALID

CASES = {  # name: (column factor, assist factor, mode)
    "known": (1.0, 1.0, Ln.TS_KNOWN),
    "assist": (1.0, 2.7, Ln.TS_ASSIST),
    "column": (0.4, 1.0, Ln.TS_COLUMN),
    "both": (0.4, 2.7, Ln.TS_BOTH),
}


def one(args: tuple) -> list[dict]:
    plant, profile, seed, case = args
    fc, fa, mode = CASES[case]
    frames, truth = simulated(plant, "first_drive", profile, seed)
    eng = engine_for(plant, profile, None)
    info = eng.est.info
    info["lp"][Ln.L_TSCALE] = mode
    info["learner"][:] = Ln.init_state(info["p"], info["lp"], friction_prior=0.3)
    g, inp, fresh = grid_arrays(frames, profile)
    inp[:, 0] *= fc
    inp[:, 1] *= fa
    out = np.zeros((len(g), N_OUT))
    st = run_grid(eng.est.params, eng.est.state, g.t_ns, inp, fresh, g.mdps_ok, g.esc_ok, out)
    t = g.t_ns * 1e-9
    ld = metrics.long_drive(t, out[:, O_FW], out[:, O_MW], _truth(truth), valid=(st & int(VALID)) != 0,
                            learn_state=out[:, O_LEARN])  # fmt: skip
    p = info["p"]
    # the true factor of the learned torque to the reference: assist (column reference) or column
    true_k = {Ln.TS_KNOWN: 1.0, Ln.TS_ASSIST: fc / fa, Ln.TS_COLUMN: fa / fc, Ln.TS_BOTH: fc / fa}[mode]
    learned_k = p[E.P_KC] if mode == Ln.TS_COLUMN else p[E.P_KA]
    fs, ms = metrics.target_figures(ld.scored)
    return [{
        "plant": plant, "profile": profile, "seed": seed, "case": case, "k_true": true_k,
        "k": learned_k, "k_sd": Ln.scale_sd(info["learner"]), "K": p[E.P_K], "learned_s": ld.learned_s,
        "fw": fs, "mw": ms,
        "min_fw": [metrics.target_figures(w)[0] if w else math.nan for w in ld.windows],
        "min_mw": [metrics.target_figures(w)[1] if w else math.nan for w in ld.windows],
    }]  # fmt: skip


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="indep_twin,tires_minus25,suv_slow,angle_above_tb")
    ap.add_argument("--profiles", default="lde,hyundai")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    tasks = [(pl, pr, int(s), c) for s in a.seeds.split(",") for pl in a.plants.split(",")
             for pr in a.profiles.split(",") for c in a.cases.split(",")]  # fmt: skip
    for r in map_runs(one, tasks, a.jobs):
        f = " ".join(f"{100 * x:4.1f}" for x in r["min_fw"][1:])
        m = " ".join(f"{100 * x:4.1f}" for x in r["min_mw"][1:])
        print(f"{r['plant'][:12]:12s} {r['profile'][:3]} s{r['seed']} {r['case']:6s} factor {r['k']:.3f} "
              f"(true {r['k_true']:.3f}, sd {100 * r['k_sd']:.1f} %) K {r['K']:8.0f} learned {r['learned_s']:5.0f} s "
              f"min2+ {100 * r['fw']:4.1f}/{100 * r['mw']:4.1f} | Fw% {f} | Mw% {m}")  # fmt: skip


if __name__ == "__main__":
    main()
