"""Lane-keeping driver that steers by column torque.

The driver looks ``T_p`` ahead, turns the lateral error there (plus a slow integral of it) into a
wanted steering-wheel angle, lags it (reaction and neuromuscular delay) and holds the wheel with
arm stiffness, damping and a slowly built-up holding torque::

    y_p    = Y + T_p (vx sin psi + vy cos psi)               predicted lateral position [m]
    e      = y_ref(t + T_p) - y_p                            preview error, left positive [m]
    a_w    = k_y e + k_i int(e)                               wanted lateral acceleration [m/s^2]
    th_raw = N (L + k_us vx^2) (a_w / vx^2 + kappa_p) - k_psi psi     wanted steering-wheel angle [rad]

(the driver's internal model of the car: the path curvature a_w / vx^2 + kappa_p needs the
road-wheel angle (L + k_us vx^2) times it, with the understeer gradient k_us [rad s^2/m] it has
learnt; kappa_p is the road's curvature at the preview point, which the driver steers into ahead
of the curve; 0 on a straight road).
    th_d'  = (th_raw - th_d) / tau                            lagged wanted angle
    T_drv  = k_a (th_d - th_sw) - d_a w_sw + I + n(t)         wheel torque [Nm], left positive
    I'     = k_ia (th_d - th_sw)                              holding torque build-up

``n(t)`` is a seeded Ornstein-Uhlenbeck torque noise (the human's variability, generated with the
scenario) and the gains are varied per seed by +-``gain_spread``. Because the driver tracks an
angle with torque, it reacts to a disturbance (the car drifts, the error grows) and to an overlay
torque (the angle moves, the arm lets go of the torque the overlay now supplies).

Modes: DRIVER_LANE (above), DRIVER_ANGLE (th_raw is a commanded steering-wheel angle from the
scenario: the validation runs), DRIVER_HANDS_OFF (T_drv = 0).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .config import DriverParams

DRIVER_LANE = 0
DRIVER_ANGLE = 1
DRIVER_HANDS_OFF = 2

DR_TP, DR_KY, DR_KI, DR_KPSI, DR_TAU, DR_KA, DR_DA, DR_KIA, DR_MODE, DR_GEO, DR_KUS = range(11)
N_DRIVER = 11


def pack_driver(
    d: DriverParams, mode: int, rng: np.random.Generator | None, wheelbase: float, ratio: float
) -> np.ndarray:
    """Driver vector, gains varied by +-gain_spread (uniform) when an rng is given (per seed)."""

    def vary(x: float) -> float:
        if rng is None or d.gain_spread <= 0.0:
            return x
        return x * (1.0 + rng.uniform(-d.gain_spread, d.gain_spread))

    return np.array(
        [
            d.preview_time,
            vary(d.lateral_gain),
            vary(d.integral_gain),
            d.heading_gain,
            vary(d.lag_time),
            vary(d.arm_stiffness),
            d.arm_damping,
            d.arm_integral,
            float(mode),
            ratio * wheelbase,
            ratio * d.understeer_gradient,
        ],
        dtype=np.float64,
    )


@numba.njit(cache=True)
def wanted_angle(
    y: float,
    psi: float,
    vx: float,
    vy: float,
    y_ref_preview: float,
    e_int: float,
    angle_cmd: float,
    kappa_preview: float,
    dp: np.ndarray,
) -> tuple[float, float]:
    """(th_raw [rad], e [m]): the wanted steering-wheel angle and the preview error
    (``kappa_preview``: the road's curvature at the preview point [1/m], left positive)."""
    if int(dp[DR_MODE]) == DRIVER_ANGLE:
        return angle_cmd, 0.0
    y_p = y + dp[DR_TP] * (vx * math.sin(psi) + vy * math.cos(psi))
    e = y_ref_preview - y_p
    v2 = max(vx, 5.0) ** 2
    a_w = dp[DR_KY] * e + dp[DR_KI] * e_int
    return (dp[DR_GEO] / v2 + dp[DR_KUS]) * (a_w + v2 * kappa_preview) - dp[DR_KPSI] * psi, e


@numba.njit(cache=True)
def arm_torque(th_d: float, th_sw: float, w_sw: float, hold: float, noise: float, dp: np.ndarray) -> float:
    """T_drv [Nm] = k_a (th_d - th_sw) - d_a w_sw + I + n."""
    if int(dp[DR_MODE]) == DRIVER_HANDS_OFF:
        return 0.0
    return dp[DR_KA] * (th_d - th_sw) - dp[DR_DA] * w_sw + hold + noise
