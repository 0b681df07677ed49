"""How R3 splits the steering compliance between K and the torsion twist (docs/estimator.md, "K and
the twist: what splits them").

Diagnosis only, not the evaluation: runs the engine (backend ``lateral``) on a zoo plant's cached
prior drive (seed 500, as ``tune_zoo.py --warm``) with learner constants set per run, and reports
from R3's state at the end of the drive: the learned K and twist against the plant's truth
(``vcan_sim/zoo/true_values.csv``, read here for the diagnosis only), their posterior standard
deviations, the posterior correlation of the two coefficients (``s/K``, ``s c_tb``), and the
correlation of their regressors (``-vx T_true'/2``, ``-vx T_col'/N``) over the samples R3 took, from
the information those samples added (``P_end^-1 - P_0^-1``; the random walks of the other slots make
it approximate). The compliance that the two share, per unit of the aligning torque at the drive's
typical ``T_col / T``, is printed as well: collinear regressors fix that sum, the prior the split.

    PYTHONPATH=src:. python scripts/twist_split.py --plants angle_above_tb --hooks ";L_SIG_CTB=0.1*DEG"
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from tune_zoo import PRIOR_SEED_OFFSET, make_hook, run_engine, simulated, spec_vehicle

TRUE_CSV = Path(__file__).resolve().parents[1] / "vcan_sim" / "zoo" / "true_values.csv"


def truth(plant: str, profile: str) -> tuple[float, float]:
    """(K [Nm/rad], twist in this profile's angle [deg/Nm]) of a plant (diagnosis only)."""
    with TRUE_CSV.open() as fh:
        row = next(r for r in csv.DictReader(fh) if r["plant"] == plant)
    above = row[f"angle_{profile}"] == "wheel"
    return float(row["k"]), float(row["torsion_deg_per_Nm"]) if above else 0.0


def split(plant: str, profile: str, hook_spec: str, seed: int) -> dict[str, float]:
    from lde.estimator import lateral as E
    from lde.estimator import learner as Ln

    frames, _ = simulated(plant, "prior_drive", profile, seed + PRIOR_SEED_OFFSET)
    vehicle = spec_vehicle(plant)
    hook = make_hook(hook_spec)
    _, info = run_engine(frames, profile, vehicle, None, None, hook)
    p, ls = info["p"], info["learner"]
    n3 = Ln.N3
    th = ls[Ln.LS_T3 : Ln.LS_T3 + n3]
    P = ls[Ln.LS_P3 : Ln.LS_P3 + n3 * n3].reshape(n3, n3)
    # the prior R3 started from: the same init_state on the starting parameters
    from lde.can.profiles import load_profile
    from lde.engine.engine import Engine

    eng0 = Engine(load_profile(profile), vehicle, "float", encode_outputs=False)
    if hook is not None:
        hook(eng0.est.state.p, eng0.est.params.lp)
    fr = vehicle.corrections.friction or vehicle.learning.friction_prior
    ls0 = Ln.init_state(eng0.est.state.p, eng0.est.params.lp, friction_prior=fr)
    P0 = ls0[Ln.LS_P3 : Ln.LS_P3 + n3 * n3].reshape(n3, n3)
    info_m = np.linalg.inv(P) - np.linalg.inv(P0)
    i11, i44, i14 = info_m[1, 1], info_m[4, 4], info_m[1, 4]
    reg_corr = i14 / math.sqrt(i11 * i44) if i11 > 0 and i44 > 0 else math.nan
    post_corr = P[1, 4] / math.sqrt(P[1, 1] * P[4, 4])
    s = th[0]
    k_r3 = s / th[1]
    ctb_r3 = math.degrees(th[4] / s)
    k_true, ctb_true = truth(plant, profile)
    return {
        "K": p[E.P_K],
        "K_r3": k_r3,
        "K_err": 100.0 * (p[E.P_K] / k_true - 1.0),
        "sd_invK": 100.0 * math.sqrt(P[1, 1]) / th[1],
        "ctb": math.degrees(p[E.P_CTB]),
        "ctb_r3": ctb_r3,
        "ctb_true": ctb_true,
        "sd_ctb": math.degrees(math.sqrt(P[4, 4]) / s),
        "sd_ctb0": math.degrees(math.sqrt(P0[4, 4]) / s),
        "post_corr": post_corr,
        "reg_corr": reg_corr,
        "n3": ls[Ln.LS_N + 1],
        "Cf": p[E.P_CF],
        "Cr": p[E.P_CR],
    }


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="indep_twin,tires_minus25,suv_slow,angle_above_tb")
    ap.add_argument("--profiles", default="hyundai")
    ap.add_argument("--hooks", default="", help="';'-separated tune_zoo --hook specs; '' = shipped")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args(argv)
    print(
        "plant/profile | hook | K (R3) err % | sd(1/K) % | twist (R3) / true deg/Nm | sd twist (prior) | "
        "corr post / regressors | R3 samples"
    )
    for hook_spec in a.hooks.split(";"):
        for plant in a.plants.split(","):
            for profile in a.profiles.split(","):
                r = split(plant, profile, hook_spec, a.seed)
                print(
                    f"{plant}/{profile} | {hook_spec or 'shipped'} | {r['K']:.0f} ({r['K_r3']:.0f}) "
                    f"{r['K_err']:+.1f} | {r['sd_invK']:.1f} | {r['ctb']:.2f} ({r['ctb_r3']:.2f}) / "
                    f"{r['ctb_true']:.2f} | {r['sd_ctb']:.2f} ({r['sd_ctb0']:.2f}) | "
                    f"{r['post_corr']:+.3f} / {r['reg_corr']:+.3f} | {r['n3']:.0f}"
                )


if __name__ == "__main__":
    main()
