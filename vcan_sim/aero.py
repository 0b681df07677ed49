"""Crosswind aerodynamics, paper eqs. (1)-(2), with flat-plate-like coefficient curves.

Relative airflow: with the air's velocity ``w`` and the vehicle's velocity ``v`` (both in the body
frame, m/s), the airflow over the car is ``a = w - v`` (a_x is about -vx). Then::

    v_r     = |a|                                  relative air speed [m/s]
    beta_cw = atan2(a_y, -a_x)                     airflow side-slip angle [rad]; > 0 when the air
                                                   moves toward +y (wind from the right)
    F_y     = 1/2 rho Cy(beta_cw) v_r^2 A          eq. (1), lateral force, left positive [N]
    M_z,mid = Cn(beta_cw) rho/2 l A v_r^2          eq. (2), yaw moment about the mid-wheelbase
                                                   point, left positive [Nm]; l = wheelbase
    F_x     = -1/2 rho Cx(beta_cw) v_r^2 A         drag [N], acting through the CG line

Coefficient curves (A = frontal area is the reference area; documented in docs/design/simulator.md)::

    Cy(b) = cy1 sin b |cos b| + cy2 sin b |sin b|  slope cy1 per rad at small b, cy2 at 90 deg
    Cn(b) = cn1 sin b cos b                        peak at 45 deg, 0 at 90 deg (the flat plate's
                                                   centre of pressure moves to mid-length), reversed
                                                   for air from behind (b beyond 90 deg)
    Cx(b) = cx cos b |cos b|

These are the shapes a flat plate shows (normal force ~ sin b, centre of pressure travelling
from the leading edge to the centre as b goes to 90 deg), scaled to a sedan's side force
derivative (2-3 per rad on frontal area) and a centre of pressure ahead of the CG.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .config import AeroParams

A_AREA, A_RHO, A_CY1, A_CY2, A_CN1, A_CX = range(6)
N_AERO = 6


def pack_aero(a: AeroParams) -> np.ndarray:
    return np.array([a.frontal_area, a.air_density, a.cy1, a.cy2, a.cn1, a.cx], dtype=np.float64)


@numba.njit(cache=True)
def coeff_y(beta: float, ap: np.ndarray) -> float:
    """Cy(beta_cw) [-]."""
    s = math.sin(beta)
    return ap[A_CY1] * s * abs(math.cos(beta)) + ap[A_CY2] * s * abs(s)


@numba.njit(cache=True)
def coeff_n(beta: float, ap: np.ndarray) -> float:
    """Cn(beta_cw) [-], about the mid-wheelbase point."""
    return ap[A_CN1] * math.sin(beta) * math.cos(beta)


@numba.njit(cache=True)
def coeff_x(beta: float, ap: np.ndarray) -> float:
    """Cx(beta_cw) [-]."""
    c = math.cos(beta)
    return ap[A_CX] * c * abs(c)


@numba.njit(cache=True)
def airflow(vx: float, vy: float, wx_b: float, wy_b: float) -> tuple[float, float]:
    """(v_r [m/s], beta_cw [rad]) from the vehicle velocity and the air velocity, both in body axes."""
    ax = wx_b - vx
    ay = wy_b - vy
    return math.sqrt(ax * ax + ay * ay), math.atan2(ay, -ax)


@numba.njit(cache=True)
def crosswind(
    vx: float, vy: float, wx_b: float, wy_b: float, wheelbase: float, ap: np.ndarray
) -> tuple[float, float, float, float, float]:
    """(F_x [N], F_y [N], M_z about mid-wheelbase [Nm], v_r [m/s], beta_cw [rad]); eqs. (1)-(2)."""
    vr, beta = airflow(vx, vy, wx_b, wy_b)
    q = 0.5 * ap[A_RHO] * vr * vr * ap[A_AREA]
    return -q * coeff_x(beta, ap), q * coeff_y(beta, ap), q * wheelbase * coeff_n(beta, ap), vr, beta
