"""Steering system with MDPS: column and rack, paper eq. (10), boost curve, overlay-torque input.

Two inertias joined by the torsion bar (the MDPS torque sensor), everything referred to the
steering column (angles are steering-wheel angles, the road-wheel angle is delta_f = th_p / N)::

    T_col = k_tb (th_sw - th_p) + c_tb (w_sw - w_p)                  column (torsion bar) torque
    T_ast = boost(T_col, vx) + T_ov                                   total motor torque (MDPS)
    J_sw w_sw' = T_drv - T_col - c_sw w_sw                            steering wheel + upper column
    J_p  w_p'  = T_col + T_ast - T_align / N - c_p w_p - T_c tanh(w_p / w_eps)
                                                                      lower column + motor + rack

The second line is eq. (10) divided by N, with J = N^2 J_p at the road wheels and
T_friction = N (c_p w_p + T_c tanh(w_p/w_eps)). With friction and accelerations zero it gives
eq. (11): T_align = N (T_col + T_ast). Signs: ISO (left positive) for angles and the column,
assist, driver and overlay torques; T_align in the paper's sign (positive resists a left steer).

Boost curve: an odd-symmetric piecewise-linear map of the column torque, scaled by a
piecewise-linear function of speed (less assist at speed)::

    boost(T, v) = sign(T) interp(|T|; boost_torque, boost_assist) * interp(v; boost_speed, boost_scale)

The overlay torque requested over the bus is clamped to +-overlay_max and applied through a
first-order lag (the motor's current loop), ``T_ov' = (T_req - T_ov) / tau``.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .config import SteeringSystemParams


@numba.njit(cache=True)
def boost(t_col: float, vx: float, bt: np.ndarray, ba: np.ndarray, bv: np.ndarray, bs: np.ndarray) -> float:
    """Boost assist torque [Nm] for column torque ``t_col`` [Nm] at speed ``vx`` [m/s]."""
    mag = np.interp(abs(t_col), bt, ba) * np.interp(vx, bv, bs)
    return mag if t_col >= 0.0 else -mag


@numba.njit(cache=True)
def coulomb(w: float, tc: float, w_eps: float) -> float:
    """Smoothed Coulomb friction torque tc tanh(w / w_eps) [Nm] (opposes the motion when subtracted)."""
    return tc * math.tanh(w / w_eps)


def boost_tables(s: SteeringSystemParams) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(torque, assist, speed, scale) breakpoint arrays for :func:`boost`."""
    return (
        np.asarray(s.boost_torque, np.float64),
        np.asarray(s.boost_assist, np.float64),
        np.asarray(s.boost_speed, np.float64),
        np.asarray(s.boost_scale, np.float64),
    )


def boost_gain(s: SteeringSystemParams, t_col: float, vx: float, dt: float = 1e-4) -> float:
    """Local boost gain d boost / d T_col [-] (for analysis and docs)."""
    tabs = boost_tables(s)
    return (boost(t_col + dt, vx, *tabs) - boost(t_col - dt, vx, *tabs)) / (2 * dt)
