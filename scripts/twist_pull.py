"""Why R3 learns the torsion twist too small (docs/design/filters.md, "What it cannot learn").

Diagnosis only, not the evaluation: simulates a plant's prior drive (seed 500, as ``tune_zoo.py
--warm``) with the full truth and fits, by least squares over the learner's speed and linear-range
gates, the static form of R3's compliance model

    alpha_f = T_x / (2 K) + b T_col / N + (friction, ...) + c

The truth's twist sits in the angle, not in alpha_f, so b = 0 if the model held; what b takes is the
part of alpha_f(T) that the model lacks and that the column torque (concave in T through the boost
curve) can imitate. ``T_x`` is the measured ``N (T_col + T_ast)`` or the true aligning torque, with
the rack's friction, damping and inertia (``N (T_c z + c_p w_p + J_p w_p')``) added one by one.

    PYTHONPATH=src:. python scripts/twist_pull.py --plants tires_minus25,indep_twin --profile hyundai
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

import numpy as np


def prior_truth(plant: str, profile: str) -> dict[str, np.ndarray]:
    from lde.analysis.study.execute import simulate_run
    from lde.analysis.study.spec import SPEC_SHEET, RunSpec

    spec = RunSpec(
        scenario="prior_drive", est_vehicle=SPEC_SHEET, sim_vehicle=f"zoo:{plant}", seed=500, profile=profile
    )
    sim = simulate_run(spec, "prior_drive", 500)
    return {k: np.asarray(v) for k, v in sim.truth.items()}


def fits(tr: dict[str, np.ndarray], n: float, w_eps: float) -> list[tuple[str, float, float]]:
    """(regressors, K [Nm/rad], twist coefficient b [deg/Nm]) per model."""
    t, tcol, tal, af = tr["t"], tr["T_column"], tr["T_align"], tr["alpha_f"]
    T = n * (tcol + tr["T_assist"])
    wp = np.gradient(tr["theta_p"], t)
    wpd = np.gradient(wp, t)
    z = np.tanh(wp / w_eps)
    sel = (tr["vx"] > 50.0 / 3.6) & (np.abs(tr["ay"]) < 4.0)
    one = np.ones_like(T)
    models = {
        "T": [T / 2, tcol / n],
        "T, friction": [T / 2, tcol / n, n * z / 2],
        "T, friction, damping": [T / 2, tcol / n, n * z / 2, n * wp / 2],
        "T, friction, damping, inertia": [T / 2, tcol / n, n * z / 2, n * wp / 2, n * wpd / 2],
        "T_align (truth)": [tal / 2, tcol / n],
        "T_align, its rate (tire lag)": [tal / 2, tcol / n, np.gradient(tal, t) / 2],
    }
    out = []
    for name, cols in models.items():
        x = np.column_stack([*cols, one])[sel]
        c, *_ = np.linalg.lstsq(x, af[sel], rcond=None)
        out.append((name, 1.0 / c[0], math.degrees(c[1])))
    return out


def main(argv: Sequence[str] | None = None) -> None:
    from lde.analysis.study.execute import load_sim_vehicle, sim_params_from_vehicle

    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="tires_minus25,indep_twin")
    ap.add_argument("--profile", default="hyundai")
    a = ap.parse_args(argv)
    for plant in a.plants.split(","):
        veh = load_sim_vehicle(f"zoo:{plant}")
        st = sim_params_from_vehicle(veh).steering
        n = veh.steering.ratio
        tr = prior_truth(plant, a.profile)
        print(
            f"{plant} ({a.profile}): N {n:g}, rack J {st.rack_inertia:g} kg m^2, damping "
            f"{st.rack_damping:g} Nm s/rad, Coulomb {st.rack_coulomb:g} Nm"
        )
        for name, k, b in fits(tr, n, st.coulomb_smoothing):
            print(f"  alpha_f ~ {name:32s} K {k:6.0f} Nm/rad, twist coefficient {b:+.3f} deg/Nm")


if __name__ == "__main__":
    main()
