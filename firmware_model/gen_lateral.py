"""Generator of the lateral fixed-point model's offline constants (the ``lateral`` section of
``tables_<vehicle>.json``, written by ``python -m firmware_model.gen_tables``).

What the firmware cannot compute at run time from the learned parameters is generated here: the
Q formats (normalisation exponents of the five states and two scaled measurements, the result format
of each coefficient group, the gain format) and the three small function tables (reciprocal seeds,
tanh, asin polynomial). The coefficient *values* are not here: they depend on the learned Cf, Cr, K,
s, and the slow task (:func:`firmware_model.lateral.coef_set_kernel`) quantises them from the
parameter vector whenever the learner pushes.

Normalisation (``docs/design/firmware.md``, "Normalised units and Q formats"): state i is stored as
``X_i = x_i / 2**e_i`` in Q15.16 with ``2**e_i`` the power of two nearest to its steady-state a-priori
standard deviation (discrete Riccati equation of the lateral filter at the vehicle's starting
parameters, the three measurements at their update rates, geometric mean over 30-180 km/h), raised
where P0 would not fit the covariance format with 2x headroom. F_wind and F_bank share one scale
(their sum is the output Fw). The aligning torque and the lateral acceleration are scaled by the
powers of two nearest to their noise standard deviations.

Coefficient formats: each group (Phi, E, H, D) gets the format that holds the largest coefficient
of the group, with 2x headroom, over the whole parameter box a learned-state file or the learner
can put into ``p`` (:data:`PARAM_BOX`, widened to the vehicle file's values) and over every speed
from the minimum to 128 m/s (the speed input's range). A coefficient set can then never saturate.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

import numpy as np

from lde.errors import ConfigError
from lde.estimator import lateral as E
from lde.estimator.learner import PLAUSIBLE
from lde.params import Vehicle
from lde.units import KMH, STEP_NS

from . import lat_coefs as LC
from .qformat import QFormat, frac_bits_for
from .riccati import steady_state_kf

# --- fixed choices (docs/design/firmware.md) --------------------------------------------------------
F_STATE = 16  #: normalised states, Q15.16
F_COV = 16  #: normalised covariance, Q15.16
F_SPEED = 24  #: speed input, Q7.24 m/s
F_STEER = 27  #: steering-wheel angle input and the pinion angle, Q4.27 rad
F_TORQUE = 23  #: column and assist torque inputs, Q8.23 Nm
F_RATE = 24  #: the pinion rate of the friction-sign filter, Q7.24 rad/s
F_Z = 30  #: the friction sign z = tanh(.) and the bank sine, Q1.30
F_U = 24  #: the tanh argument, Q7.24
F_CONST = 0  #: marker: a slow-task constant carries its own fractional bits

#: the reciprocal: seeds for the 2**RECIP_BITS mantissa intervals, two Newton steps
RECIP_BITS = 6
RECIP_FRAC = 30  #: mantissa and result format of the normalised reciprocal, Q1.30
#: tanh on [0, 2**TANH_U_EXP] in 2**(TANH_U_EXP + TANH_SEG_BITS) segments, linear interpolation
TANH_U_EXP = 3
TANH_SEG_BITS = 5
#: asin(x) for |x| <= 1/2 as x (1 + x^2 (a1 + x^2 (a2 + ...))) (Taylor), larger |x| by the half-angle
#: identity asin(x) = pi/2 - 2 asin(sqrt((1 - x)/2))
ASIN_TERMS = (1.0 / 6.0, 3.0 / 40.0, 5.0 / 112.0, 35.0 / 1152.0, 63.0 / 2816.0)

#: the speed input's largest value [m/s] (Q7.24): the coefficients' w range ends there
V_INPUT_MAX = 128.0
#: binary orders by which a state's scale may exceed its steady-state std (to fit P0)
MAX_SIGMA_RAISE = 3
#: update periods assumed for the Riccati scales [s]: yaw rate and lateral acceleration (ESC), the
#: aligning torque (MDPS); a scale only (a power of two), the zoo runs measure the real headroom
RICCATI_PERIODS = (0.010, 0.0039, 0.010)
RICCATI_KMH = tuple(range(30, 181, 10))

#: What ``p`` can hold for the learned tire and sensor values: the plausibility bounds of a
#: learned-state file (:data:`lde.estimator.learner.PLAUSIBLE`, checked by
#: :func:`lde.estimator.learned.load_learned`),
#: which contain the learner's push bounds (:func:`lde.estimator.learner.push`; tested). (low, high).
PARAM_BOX = PLAUSIBLE
_BOX_SLOTS = {"cf": E.P_CF, "cr": E.P_CR, "k": E.P_K, "s": E.P_S}


def _pow2_near(x: float) -> int:
    return int(round(math.log2(x)))


def physical_model(p: np.ndarray, vx: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(Phi 5x5, H 3x5, R 3) of the lateral filter at ``vx`` in SI (rows of H: yaw rate, aligning
    torque, lateral acceleration), from the same polynomials as the firmware."""
    c = LC.evaluate(LC.polys(p, np.zeros(LC.N_EX, np.int64)), 1.0 / vx)[:, 0]
    phi = np.eye(5)
    phi[0, 0], phi[0, 1], phi[0, 2], phi[0, 4] = c[LC.K_F00], c[LC.K_F01], c[LC.K_F02], c[LC.K_F02]
    phi[1, 0], phi[1, 1], phi[1, 3] = c[LC.K_F10], c[LC.K_F11], c[LC.K_F13]
    h = np.zeros((3, 5))
    h[0, 1] = 1.0
    h[1, 0], h[1, 1] = c[LC.K_HT0], c[LC.K_HT1]
    h[2, 0], h[2, 1], h[2, 2] = c[LC.K_HA0], c[LC.K_HA1], c[LC.K_HA2]
    r = np.array([p[E.P_RR], p[E.P_RT], p[E.P_RA]])
    return phi, h, r


def steady_state_std(p: np.ndarray) -> np.ndarray:
    """A-priori steady-state standard deviations (len(RICCATI_KMH), 5) of the lateral filter with
    every measurement's variance scaled to one update per step (R dt_update / dt)."""
    dt = p[E.P_DT]
    qd = np.diag([p[E.P_QB], p[E.P_QR], p[E.P_QFA], p[E.P_QMA], p[E.P_QFB]]) * dt
    out = []
    for kmh in RICCATI_KMH:
        phi, h, r = physical_model(p, kmh * KMH)
        r_eff = np.diag(r * np.array(RICCATI_PERIODS) / dt)
        ss = steady_state_kf(phi, h, qd, r_eff)
        out.append(np.sqrt(np.diag(ss.P_prior)))
    return np.array(out)


def exponents(p: np.ndarray) -> list[int]:
    """The normalisation exponents (``lat_coefs.X_*`` order; module docstring)."""
    sd = steady_state_std(p)
    geo = np.exp(np.mean(np.log(sd), axis=0))
    forces = math.sqrt(geo[LC.X_FA] * geo[LC.X_FB])  # one scale for F_wind and F_bank
    scales = [geo[LC.X_B], geo[LC.X_R], forces, geo[LC.X_MA], forces]
    p0 = [p[E.P_P0B], p[E.P_P0R], p[E.P_P0FA], p[E.P_P0MA], p[E.P_P0FB]]
    q = [p[E.P_QB], p[E.P_QR], p[E.P_QFA], p[E.P_QMA], p[E.P_QFB]]
    q_cov = QFormat(32, F_COV)
    ex = []
    for i, s in enumerate(scales):
        e0 = e = _pow2_near(float(s))
        while e < e0 + MAX_SIGMA_RAISE and not q_cov.fits((p0[i] ** 2 + q[i] * p[E.P_DT]) / 4.0**e, 2.0):
            e += 1
        ex.append(e)
    ex[LC.X_FB] = ex[LC.X_FA] = max(ex[LC.X_FA], ex[LC.X_FB])
    ex.append(_pow2_near(math.sqrt(p[E.P_RT])))
    ex.append(_pow2_near(math.sqrt(p[E.P_RA])))
    return ex


def param_corners(p: np.ndarray) -> list[np.ndarray]:
    """Parameter vectors at every corner of :data:`PARAM_BOX` widened to ``p``'s own values."""
    ranges = []
    for name, (lo, hi) in PARAM_BOX.items():
        v = float(p[_BOX_SLOTS[name]])
        ranges.append((_BOX_SLOTS[name], (min(lo, v), max(hi, v))))
    out = []
    for corner in itertools.product(*(r for _, r in ranges)):
        q = p.copy()
        for (slot, _), value in zip(ranges, corner, strict=True):
            q[slot] = value
        out.append(q)
    return out


def group_max(p: np.ndarray, ex: list[int], w_max: float) -> list[float]:
    """The largest |coefficient| of each group over the parameter box and w in [1/128 m/s, w_max]."""
    w = np.linspace(1.0 / V_INPUT_MAX, w_max, 65)
    mx = [0.0] * len(LC.GROUP_NAMES)
    for q in param_corners(p):
        vals = np.abs(LC.evaluate(LC.polys(q, ex), w)).max(axis=1)
        for k, g in enumerate(LC.COEF_GROUP):
            mx[g] = max(mx[g], float(vals[k]))
    return mx


# --- function tables ---------------------------------------------------------------------------------


def recip_seeds() -> list[int]:
    """Q1.30 seeds of 1/a for a in [1, 2) by 2**RECIP_BITS intervals: the reciprocal of the interval's
    midpoint (relative error <= 2**-(RECIP_BITS+1) before the Newton steps)."""
    n = 1 << RECIP_BITS
    return [int(round(2.0**RECIP_FRAC / (1.0 + (i + 0.5) / n))) for i in range(n)]


def tanh_table() -> list[int]:
    """tanh at 2**(TANH_U_EXP + TANH_SEG_BITS) + 1 points on [0, 2**TANH_U_EXP], Q1.30."""
    n = 1 << (TANH_U_EXP + TANH_SEG_BITS)
    return [int(round(math.tanh(i * 2.0**-TANH_SEG_BITS) * 2.0**F_Z)) for i in range(n + 1)]


def asin_coefs() -> list[int]:
    """The asin polynomial's coefficients in Q1.30."""
    return [int(round(a * 2.0**F_Z)) for a in ASIN_TERMS]


def fixed_choices() -> dict[str, Any]:
    """This generator's fixed choices (part of the tables' input hash)."""
    return {
        "formats": [F_STATE, F_COV, F_SPEED, F_STEER, F_TORQUE, F_RATE, F_Z, F_U],
        "recip": [RECIP_BITS, RECIP_FRAC],
        "tanh": [TANH_U_EXP, TANH_SEG_BITS],
        "asin": list(ASIN_TERMS),
        "box": {k: list(v) for k, v in PARAM_BOX.items()},
        "riccati": [list(RICCATI_PERIODS), list(RICCATI_KMH), MAX_SIGMA_RAISE, V_INPUT_MAX],
        "coefs": list(LC.COEF_NAMES),
    }


def generate(vehicle: Vehicle, dt_ns: int = STEP_NS) -> dict[str, Any]:
    """The ``lateral`` section of the tables (JSON-ready)."""
    p = E.params_vector(vehicle, dt_ns * 1e-9)
    ex = exponents(p)
    q_speed = QFormat(32, F_SPEED)
    v_min_raw, _ = q_speed.to_raw(p[E.P_VMIN])
    w_max = 1.0 / (v_min_raw * q_speed.lsb)
    f_w = frac_bits_for(w_max, headroom=1.0)
    gmax = group_max(p, ex, w_max)
    groups = {name: frac_bits_for(mx, headroom=2.0) for name, mx in zip(LC.GROUP_NAMES, gmax, strict=True)}
    # the gain: |K_i| <= sqrt(Pn_ii / Rn) for a scalar update; the largest Pn_ii is P0 (+ Qd)
    q_cov = QFormat(32, F_COV)
    dt = p[E.P_DT]
    p0 = [p[E.P_P0B], p[E.P_P0R], p[E.P_P0FA], p[E.P_P0MA], p[E.P_P0FB]]
    q = [p[E.P_QB], p[E.P_QR], p[E.P_QFA], p[E.P_QMA], p[E.P_QFB]]
    p0n = [(p0[i] ** 2 + q[i] * dt) / 4.0 ** ex[i] for i in range(5)]
    for i, v in enumerate(p0n):
        if not q_cov.fits(v, 2.0):
            raise ConfigError(
                f"{vehicle.name}: initial std of lateral state {i} ({p0[i]:.3g}) is too large against its "
                f"steady-state scale for the fixed-point covariance ({q_cov}, 2x headroom)"
            )
    rn = [p[E.P_RR] / 4.0 ** ex[LC.X_R], p[E.P_RT] / 4.0 ** ex[LC.X_T], p[E.P_RA] / 4.0 ** ex[LC.X_A]]
    k_bound = math.sqrt(max(p0n) * 1.1 / min(rn))
    f_gain = frac_bits_for(k_bound, headroom=2.0)
    names = ("beta", "r", "F_wind", "M_wind", "F_bank")
    units = ("rad", "rad/s", "N", "Nm", "N")
    return {
        "formats": {
            "state": F_STATE,
            "cov": F_COV,
            "speed": F_SPEED,
            "steer": F_STEER,
            "torque": F_TORQUE,
            "rate": F_RATE,
            "z": F_Z,
            "u": F_U,
            "w": f_w,
            "gain": f_gain,
            "coef_groups": groups,
        },
        "sigma_exp": {"state": ex[:5], "t_align": ex[LC.X_T], "lat_accel": ex[LC.X_A]},
        "state_formats": [
            {"state": names[i], "unit": units[i], "q": str(QFormat(32, F_STATE - ex[i]))} for i in range(5)
        ],
        "v_min_raw": v_min_raw,
        "recip": {"bits": RECIP_BITS, "frac": RECIP_FRAC, "seeds": recip_seeds()},
        "tanh": {"u_exp": TANH_U_EXP, "seg_bits": TANH_SEG_BITS, "table": tanh_table()},
        "asin": {"coefs": asin_coefs(), "half_pi": int(round(math.pi / 2.0 * 2.0**F_Z))},
    }
