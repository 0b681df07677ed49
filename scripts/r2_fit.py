"""Where R2's rear stiffness comes from on a prior drive (docs/design/filters.md, "The learner").

Diagnosis only, not the evaluation: simulates a plant's prior drive (seed 500, as ``tune_zoo.py
--warm``) with the full truth, passes the signals through the learner's state-variable filter (3 Hz,
zeta 0.8) and fits, by least squares over the learner's gates (speed, linear range, lateral-force
excitation; the disturbance-quiet gate holds on this disturbance-free drive), R2's regression

    (lf T_x / t - Iz r_dot) / lr = 2 Cr (T_x / (2 K) - D) + theta_1 D_dot / vx + c2,
    D = delta_f - L r / vx

with the plant's true K and t = K / Cf (``vcan_sim/zoo/true_values.csv``) and its true road-wheel
angle, so that what remains is R2's own model error. ``T_x`` is the measured ``N (T_col + T_ast)``
or the truth's aligning torque; ``--learned`` adds rows with K and Cf as the learner ended, and
one row per K takes y from the lateral balance ``(lf m a_y - Iz r_dot) / L`` instead. A first-order
tire lag with relaxation length sigma gives ``theta_1 = +2 Cr sigma`` (a lag of the rear slip behind
D): printed as ``sigma = theta_1 / theta_0``. Samples: every 4th step after the first second, as the
learner's; the force gate on the truth's kinematic a_y (the learner's on the accelerometer).

    PYTHONPATH=src:. python scripts/r2_fit.py --plants indep_twin,suv_slow,tires_minus25,angle_above_tb \
        --learned indep_twin=6619:65809,suv_slow=7852:61536,tires_minus25=5396:42159,angle_above_tb=5528:48687
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence

import numpy as np
from twist_pull import prior_truth


def svf(u: np.ndarray, dt: float, w: float = 2 * math.pi * 3.0, zeta: float = 0.8) -> np.ndarray:
    """The learner's state-variable filter (semi-implicit Euler): rows value, rate, acceleration."""
    out = np.empty((3, len(u)))
    y, yd = u[0], 0.0
    for i, x in enumerate(u):
        ydd = w * w * (x - y) - 2.0 * zeta * w * yd
        yd += dt * ydd
        y += dt * yd
        out[:, i] = (y, yd, ydd)
    return out


def band_ms(u: np.ndarray, dt: float) -> np.ndarray:
    """The learner's excitation measure: mean square (2 s) of u's 0.05 s minus 3 s low-pass."""
    f1 = f2 = u[0]
    ms = 0.0
    out = np.empty(len(u))
    for i, x in enumerate(u):
        f1 += dt / 0.05 * (x - f1)
        f2 += dt / 3.0 * (x - f2)
        ms += dt / 2.0 * ((f1 - f2) ** 2 - ms)
        out[i] = ms
    return out


def fit(
    tr: dict[str, np.ndarray],
    tv,
    t_x: str,
    n: float,
    relax: bool,
    gate_rate: bool,
    k: float,
    cf: float,
    y_from: str = "T",
) -> tuple:
    """(Cr [N/rad], sigma [m], rms residual [N], samples) of R2's regression with aligning slope
    ``k`` [Nm/rad] and front stiffness ``cf`` [N/rad] (the trail k / cf)."""
    t = tr["t"]
    dt = float(np.median(np.diff(t)))
    iz, lf, lr, m = tv.yaw_inertia, tv.lf, tv.lr, tv.mass
    big_l = lf + lr
    trail = k / cf
    tx = n * (tr["T_column"] + tr["T_assist"]) if t_x == "measured" else tr["T_align"]
    r, df, vx, ay = (svf(tr[c], dt) for c in ("r", "delta_f", "vx", "ay"))
    T = svf(tx, dt)
    v = vx[0]
    d = df[0] - big_l * r[0] / v
    d_dot = df[1] - big_l * r[1] / v
    # y_from "ay": the lateral balance instead of the front force, (lf m a_y - Iz r_dot) / L
    front = (lf * T[0] / trail - iz * r[1]) / lr
    y = (lf * m * ay[0] - iz * r[1]) / big_l if y_from == "ay" else front
    cols = [T[0] / (2 * k) - d]
    if relax:
        cols.append(d_dot / v)
    cols.append(np.ones_like(d))
    x = np.column_stack(cols)
    exc_f = band_ms(m * tr["ay"], dt)
    sel = (v > 50 / 3.6) & (np.abs(ay[0]) < 4.0) & (exc_f > 150.0**2) & (t - t[0] > 1.0)
    if gate_rate:
        rate_ms = np.zeros_like(v)
        acc = 0.0
        for i, a in enumerate(df[1]):
            acc += dt / 1.0 * (a * a - acc)
            rate_ms[i] = acc
        sel &= rate_ms > (0.5 * math.pi / 180) ** 2
    sel &= np.arange(len(sel)) % 4 == 0
    c, *_ = np.linalg.lstsq(x[sel], y[sel], rcond=None)
    res = y[sel] - x[sel] @ c
    sigma = c[1] / c[0] if relax else 0.0
    return 0.5 * c[0], sigma, float(np.sqrt(np.mean(res**2))), int(sel.sum())


def main(argv: Sequence[str] | None = None) -> None:
    from vcan_sim.zoo import read_true_values

    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="indep_twin,suv_slow,tires_minus25,angle_above_tb")
    ap.add_argument("--profile", default="lde")
    ap.add_argument("--learned", default="", help="PLANT=K:CF,...: also fit with these (as learned)")
    a = ap.parse_args(argv)
    learned = {}
    for item in filter(None, a.learned.split(",")):
        name, kc = item.split("=")
        learned[name] = tuple(float(v) for v in kc.split(":"))
    tvs = read_true_values()
    for plant in a.plants.split(","):
        tv = tvs[plant]
        tr = prior_truth(plant, a.profile)
        print(f"{plant} ({a.profile}): true Cr {tv.cr:.0f} N/rad (bicycle equivalent)")
        kcs = [("true", tv.k, tv.cf)]
        if plant in learned:
            kcs.append(("learned", *learned[plant]))
        for kname, k, cf in kcs:
            for t_x in ("T_align", "measured"):
                for relax in (False, True):
                    for gate_rate in (False, True):
                        cr, sig, rms, ns = fit(tr, tv, t_x, tv.ratio, relax, gate_rate, k, cf)
                        print(
                            f"  K, Cf {kname:7s} T {t_x:8s} relax {relax!s:5s} rate gate {gate_rate!s:5s}: "
                            f"Cr {cr:7.0f} ({100 * (cr / tv.cr - 1):+5.1f} %), sigma {sig:+.2f} m, "
                            f"rms {rms:5.0f} N, n {ns}"
                        )
            for relax in (False, True):
                cr, sig, rms, ns = fit(tr, tv, "measured", tv.ratio, relax, False, k, cf, "ay")
                print(
                    f"  K, Cf {kname:7s} T measured relax {relax!s:5s}, y from m a_y: "
                    f"Cr {cr:7.0f} ({100 * (cr / tv.cr - 1):+5.1f} %), sigma {sig:+.2f} m, "
                    f"rms {rms:5.0f} N, n {ns}"
                )


if __name__ == "__main__":
    main()
