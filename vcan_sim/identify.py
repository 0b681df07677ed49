"""Linear-equivalent tire parameters identified from the simulator (the paper's Fig. 12 question).

The estimator's bicycle model uses per-tire linear tires ``F_f = C_f alpha_f``, ``F_r = C_r alpha_r``
and ``T_align = 2 K alpha_f`` (eqs. 9, 12). From a simulated run (ground truth) they are fitted by
least squares through the origin over the run's samples, in two senses:

* tire level (the paper's Fig. 12): each axle's lateral force per tire against its slip angle::

      C_f,tire = sum(F_front/2 * a_f) / sum(a_f^2),   C_r,tire = sum(F_rear/2 * a_r) / sum(a_r^2)

* bicycle equivalent (what eqs. 7-8 need): the plant's tire forces also carry aligning moments
  (the force acts a pneumatic trail behind the axle) and load-transfer effects, so the axle forces
  that reproduce BOTH the plant's total tire side force sum(Fy) and its tire yaw moment Mz_tires
  about the actual CG are::

      2 F_f,eq = (lr sum(Fy) + Mz_tires) / L,    2 F_r,eq = (lf sum(Fy) - Mz_tires) / L
      C_f = sum(F_f,eq a_f) / sum(a_f^2),        C_r = sum(F_r,eq a_r) / sum(a_r^2)

* aligning torque: ``K = sum(T_align/2 * a_f) / sum(a_f^2)`` (steering axis, paper sign).

``a_f``, ``a_r`` are the mean slip angles of the axle's tires; each fit reports
``r2`` = 1 - residual / total sum of squares. Samples with speed below
``min_speed`` are left out. :func:`static_stiffness` gives the small-slip tangent of the Magic
Formula at the static wheel loads instead (no load transfer, no nonlinearity), for comparison.
The steady-state linear bicycle model (:func:`bicycle_steady_state`) is what the validation tests
compare the nonlinear plant with.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

from lde.params import Vehicle, load_vehicle

from .config import SimParams, sim_params_from_vehicle
from .payload import combined, loaded_body, payload_by_name
from .run import simulate
from .tires import aligning_slope, force_slope


@dataclass(frozen=True)
class LinearEquivalent:
    """Per-tire linear-equivalent parameters: cf, cr bicycle equivalents [N/rad] (for eqs. 7-9),
    cf_tire, cr_tire tire level [N/rad], k [Nm/rad]; r2_* fit qualities [-]; n samples used;
    max_alpha_f [rad] the largest front slip seen (the fit's range)."""

    cf: float
    cr: float
    k: float
    cf_tire: float
    cr_tire: float
    r2_cf: float
    r2_cr: float
    r2_k: float
    n: int
    max_alpha_f: float


def _fit(y: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    sxx = float(np.dot(x, x))
    if sxx <= 0.0:
        return float("nan"), float("nan")
    c = float(np.dot(x, y)) / sxx
    res = y - c * x
    tot = float(np.dot(y - y.mean(), y - y.mean()))
    return c, (1.0 - float(np.dot(res, res)) / tot) if tot > 0 else float("nan")


def identify(
    truth: Mapping[str, np.ndarray], lf: float, lr: float, min_speed: float = 50.0 / 3.6
) -> LinearEquivalent:
    """Fit C_f, C_r, K (per tire) to a run's truth columns; ``lf``, ``lr`` of the actual (loaded) CG."""
    m = np.asarray(truth["vx"]) >= min_speed
    af = np.asarray(truth["alpha_f"])[m]
    ar = np.asarray(truth["alpha_r"])[m]
    fyf = np.asarray(truth["Fy_front"])[m]
    fyr = np.asarray(truth["Fy_rear"])[m]
    mzt = np.asarray(truth["Mz_tires"])[m]
    L = lf + lr
    cf, r2f = _fit((lr * (fyf + fyr) + mzt) / (2.0 * L), af)
    cr, r2r = _fit((lf * (fyf + fyr) - mzt) / (2.0 * L), ar)
    cf_t, _ = _fit(fyf / 2.0, af)
    cr_t, _ = _fit(fyr / 2.0, ar)
    k, r2k = _fit(np.asarray(truth["T_align"])[m] / 2.0, af)
    return LinearEquivalent(
        cf,
        cr,
        k,
        cf_t,
        cr_t,
        r2f,
        r2r,
        r2k,
        int(m.sum()),
        float(np.abs(af).max()) if af.size else float("nan"),
    )


def static_stiffness(
    vehicle: Vehicle | None = None, sp: SimParams | None = None, payload: str = "none"
) -> tuple[float, float, float]:
    """(C_f, C_r, K) per tire [N/rad, N/rad, Nm/rad]: Magic Formula tangents at the static wheel loads
    (mean of left and right) of the car with its own load (``[sim.payload]``) and ``payload``."""
    v = vehicle or load_vehicle()
    sp = sp or sim_params_from_vehicle(v)
    body = loaded_body(v, sp, combined(sp, payload_by_name(payload)))
    f1, f2, f3, f4 = body.wheel_loads
    cf = 0.5 * (force_slope(f1, sp.tire) + force_slope(f2, sp.tire))
    cr = 0.5 * (force_slope(f3, sp.tire) + force_slope(f4, sp.tire))
    k = 0.5 * (aligning_slope(f1, sp.tire) + aligning_slope(f2, sp.tire))
    return cf, cr, k


def bicycle_steady_state(
    m: float, lf: float, lr: float, cf: float, cr: float, vx: float, delta_f: float
) -> tuple[float, float]:
    """Steady (beta [rad], r [rad/s]) of the linear bicycle model, eqs. (7)-(9), per-tire C_f, C_r.

    0 = -2(Cf+Cr)/(m vx) beta + (-1 - 2(lf Cf - lr Cr)/(m vx^2)) r + 2 Cf/(m vx) delta_f
    0 = -2(lf Cf - lr Cr)/Iz beta - 2(lf^2 Cf + lr^2 Cr)/(Iz vx) r + 2 lf Cf/Iz delta_f   (Iz cancels)
    """
    a = np.array(
        [
            [-2 * (cf + cr) / (m * vx), -1.0 - 2 * (lf * cf - lr * cr) / (m * vx * vx)],
            [-2 * (lf * cf - lr * cr), -2 * (lf * lf * cf + lr * lr * cr) / vx],
        ]
    )
    b = np.array([2 * cf / (m * vx), 2 * lf * cf])
    beta, r = np.linalg.solve(a, -b * delta_f)
    return float(beta), float(r)


def identify_scenarios(
    names: Iterable[str],
    seeds: Iterable[int] = (0,),
    vehicle: Vehicle | str | None = None,
    duration: float | None = None,
) -> dict[str, LinearEquivalent]:
    """:func:`identify` over runs of several scenarios (truth of all seeds pooled per scenario)."""

    out: dict[str, LinearEquivalent] = {}
    for name in names:
        runs = [simulate(name, vehicle=vehicle, seed=s, duration=duration) for s in seeds]
        pooled = {k: np.concatenate([r.truth[k] for r in runs]) for k in _FIT_COLUMNS}
        out[name] = identify(pooled, runs[0].body.lf, runs[0].body.lr)
    return out


_FIT_COLUMNS = ("vx", "alpha_f", "alpha_r", "Fy_front", "Fy_rear", "Mz_tires", "T_align")
