"""Pacejka Magic Formula tire: lateral force and aligning moment, load dependent, pure side slip.

Equations (see :class:`vcan_sim.config.TireCoeffs` for the coefficients), dfz = (Fz - Fz0)/Fz0::

    Fy = D sin(C atan(B a - E (B a - atan(B a))))                  lateral force [N], ISO: +a -> +Fy
    D  = pDy1 (1 + pDy2 dfz) Fz,   C = pCy1,   E = pEy1 + pEy2 dfz
    Ky = pKy1 Fz0 sin(2 atan(Fz / (pKy2 Fz0)))                      cornering stiffness [N/rad]
    B  = Ky / (C D)
    t  = Dt cos(Ct atan(Bt a - Et (Bt a - atan(Bt a)))) cos(a)     pneumatic trail [m]
    Dt = t0 (1 + qDz2 dfz),  Bt = qBz1 + qBz2 dfz
    Mz = -t Fy                                                      aligning moment, ISO [Nm]
    T_axis = (t + t_m) Fy                                           torque on the steering axis,
                                                                    paper sign (resists the steer)

``a`` is the slip angle [rad] in the ISO sense used by the paper's eq. (9): positive slip gives a
positive (leftward) force. The pneumatic trail falls with |a| (the aligning moment peaks and
collapses before the force saturates) and grows with load; Fz <= 0 (wheel lift) gives no force.

The numba kernels take the coefficients as a flat float64 vector (``pack_tire``) so that the
plant's integrator can call them without Python objects.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .config import TireCoeffs

# indices into the packed coefficient vector
T_FZ0, T_PCY1, T_PDY1, T_PDY2, T_PEY1, T_PEY2, T_PKY1, T_PKY2 = range(8)
T_T0, T_QDZ2, T_QBZ1, T_QBZ2, T_CT, T_ET, T_TM = range(8, 15)
N_TIRE = 15


def pack_tire(c: TireCoeffs) -> np.ndarray:
    """The coefficient vector used by the kernels (order of the T_* indices)."""
    return np.array(
        [
            c.fz0,
            c.pCy1,
            c.pDy1,
            c.pDy2,
            c.pEy1,
            c.pEy2,
            c.pKy1,
            c.pKy2,
            c.t0,
            c.qDz2,
            c.qBz1,
            c.qBz2,
            c.Ct,
            c.Et,
            c.mech_trail,
        ],
        dtype=np.float64,
    )


@numba.njit(cache=True)
def cornering_stiffness(fz: float, tc: np.ndarray) -> float:
    """Ky = pKy1 Fz0 sin(2 atan(Fz / (pKy2 Fz0))) [N/rad]; 0 for Fz <= 0."""
    if fz <= 0.0:
        return 0.0
    fz0 = tc[T_FZ0]
    return tc[T_PKY1] * fz0 * math.sin(2.0 * math.atan(fz / (tc[T_PKY2] * fz0)))


@numba.njit(cache=True)
def lateral_force(alpha: float, fz: float, tc: np.ndarray) -> float:
    """Magic Formula Fy(alpha, Fz) [N] (ISO: positive slip angle -> positive force)."""
    if fz <= 0.0:
        return 0.0
    fz0 = tc[T_FZ0]
    dfz = (fz - fz0) / fz0
    c = tc[T_PCY1]
    d = tc[T_PDY1] * (1.0 + tc[T_PDY2] * dfz) * fz
    e = tc[T_PEY1] + tc[T_PEY2] * dfz
    if e > 1.0:
        e = 1.0
    b = cornering_stiffness(fz, tc) / (c * d)
    ba = b * alpha
    return d * math.sin(c * math.atan(ba - e * (ba - math.atan(ba))))


@numba.njit(cache=True)
def pneumatic_trail(alpha: float, fz: float, tc: np.ndarray) -> float:
    """Pneumatic trail t(alpha, Fz) [m]; may turn slightly negative far beyond the force peak."""
    if fz <= 0.0:
        return 0.0
    fz0 = tc[T_FZ0]
    dfz = (fz - fz0) / fz0
    dt = tc[T_T0] * (1.0 + tc[T_QDZ2] * dfz)
    bt = tc[T_QBZ1] + tc[T_QBZ2] * dfz
    et = tc[T_ET]
    ba = bt * alpha
    return dt * math.cos(tc[T_CT] * math.atan(ba - et * (ba - math.atan(ba)))) * math.cos(alpha)


@numba.njit(cache=True)
def tire_forces(alpha: float, fz: float, tc: np.ndarray) -> tuple[float, float, float]:
    """(Fy [N], Mz [Nm] ISO at the contact patch, T_axis [Nm] on the steering axis, paper sign)."""
    fy = lateral_force(alpha, fz, tc)
    tp = pneumatic_trail(alpha, fz, tc)
    return fy, -tp * fy, (tp + tc[T_TM]) * fy


# ----------------------------------------------------------------------------- analysis helpers


def aligning_slope(fz: float, coeffs: TireCoeffs, d_alpha: float = 1e-5) -> float:
    """Per-tire slope of the steering-axis aligning torque at zero slip, d T_axis / d alpha [Nm/rad]."""
    tc = pack_tire(coeffs)
    return (tire_forces(d_alpha, fz, tc)[2] - tire_forces(-d_alpha, fz, tc)[2]) / (2.0 * d_alpha)


def force_slope(fz: float, coeffs: TireCoeffs, d_alpha: float = 1e-5) -> float:
    """Per-tire cornering stiffness at zero slip, d Fy / d alpha [N/rad] (numerical)."""
    tc = pack_tire(coeffs)
    return (lateral_force(d_alpha, fz, tc) - lateral_force(-d_alpha, fz, tc)) / (2.0 * d_alpha)
