"""The lateral filter's model (:mod:`lde.estimator.lateral`) as polynomials in ``w = 1/vx``, normalised.

Every speed-dependent entry of the lateral filter's ``Phi = I + A dt``, ``E = B dt`` and of its
aligning-torque and accelerometer rows ``H``, ``D`` is ``c0 + c1 w + c2 w^2`` whose coefficients
depend on the parameter vector ``p`` only (masses, geometry, dt, and the learned Cf, Cr, K, s).
In the normalised units of the fixed-point model (``X_i = x_i / 2**e_i``, measurement ``m`` scaled
by ``2**e_m``) an entry is scaled by ``2**(e_j - e_i)`` (Phi), ``2**(e_j - e_m)`` (H), and ``E``, ``D``
are per rad of the corrected steering-wheel angle ``delta_sw - c_tb T_col - d_sw`` (the road-wheel
angle ``delta_f`` times N)::

    beta+ = (1 - dt 2(Cf+Cr)/(m vx)) beta + (-dt - dt 2(lf Cf - lr Cr)/(m vx^2)) r
            + dt/(m vx) (F_wind + F_bank) + dt 2 Cf/(m vx) delta_f                       (7)
    r+    = -dt 2(lf Cf - lr Cr)/Iz beta + (1 - dt 2(lf^2 Cf + lr^2 Cr)/(Iz vx)) r
            + dt/Iz M_wind + dt 2 lf Cf/Iz delta_f                                       (8)
    T_align = 2K (delta_f - beta - lf r/vx)                                              (12)
    a_y     = (s (2 Cf alpha_f + 2 Cr alpha_r) + F_wind)/m
            = -2 s (Cf+Cr)/m beta - 2 s (lf Cf - lr Cr)/(m vx) r + F_wind/m + 2 s Cf/m delta_f

The same function serves the generator (format ranges over the parameter box, the Riccati scales),
the slow task that quantises a coefficient set whenever the learner pushes parameters
(:func:`firmware_model.lateral.coef_set_kernel`) and the tests, which check it against the float
step (:func:`lde.estimator.lateral.step_kernel`) itself. F_wind and F_bank share one scale (the model's
output Fw is their sum), so one coefficient ``phi02`` serves both columns of (7).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from lde.estimator import lateral as E

#: the coefficients, in this order (``K_*`` slots). phiIJ: Phi_n[I, J]; e0, e1: E_n per rad of
#: corrected steering-wheel angle; ht*: the aligning-torque row (beta, r), dt: its D; ha*: the
#: accelerometer row (beta, r, F_wind), da: its D.
COEF_NAMES = (
    "phi00",
    "phi01",
    "phi02",
    "phi10",
    "phi11",
    "phi13",
    "e0",
    "e1",
    "ht0",
    "ht1",
    "dt",
    "ha0",
    "ha1",
    "ha2",
    "da",
)
(K_F00, K_F01, K_F02, K_F10, K_F11, K_F13, K_E0, K_E1, K_HT0, K_HT1, K_DT, K_HA0, K_HA1, K_HA2, K_DA) = range(
    15
)
N_K = 15
#: the result format group of each coefficient: a row of products accumulates in one format
GROUP_NAMES = ("phi", "e", "h", "d")
G_PHI, G_E, G_H, G_D = range(4)
COEF_GROUP = (G_PHI,) * 6 + (G_E,) * 2 + (G_H, G_H, G_D, G_H, G_H, G_H, G_D)

# normalisation exponents (``ex`` slots): the five states, then the two scaled measurements
X_B, X_R, X_FA, X_MA, X_FB, X_T, X_A = range(7)
N_EX = 7


@njit(cache=True)
def coef_polys(p, ex, c):  # pragma: no cover - compiled
    """Fill ``c`` (N_K, 3) with (c0, c1, c2) of every coefficient for the parameters ``p``
    (:mod:`lde.estimator.lateral` ``P_*`` slots) in the units scaled by ``2**ex`` (``X_*`` slots)."""
    m, iz, lf, lr, n, dt = p[E.P_M], p[E.P_IZ], p[E.P_LF], p[E.P_LR], p[E.P_N], p[E.P_DT]
    cf, cr, k, s = p[E.P_CF], p[E.P_CR], p[E.P_K], p[E.P_S]
    sb, sr = 2.0 ** ex[X_B], 2.0 ** ex[X_R]
    sfa, sma = 2.0 ** ex[X_FA], 2.0 ** ex[X_MA]
    st, sa = 2.0 ** ex[X_T], 2.0 ** ex[X_A]
    for i in range(N_K):
        for j in range(3):
            c[i, j] = 0.0
    cyl = lf * cf - lr * cr  # the tires' yaw coupling [Nm/rad]
    # (7): beta row
    c[K_F00, 0] = 1.0
    c[K_F00, 1] = -dt * 2.0 * (cf + cr) / m
    c[K_F01, 0] = -dt * sr / sb
    c[K_F01, 2] = -dt * 2.0 * cyl / m * sr / sb
    c[K_F02, 1] = dt / m * sfa / sb
    # (8): r row
    c[K_F10, 0] = -dt * 2.0 * cyl / iz * sb / sr
    c[K_F11, 0] = 1.0
    c[K_F11, 1] = -dt * 2.0 * (lf * lf * cf + lr * lr * cr) / iz
    c[K_F13, 0] = dt / iz * sma / sr
    c[K_E0, 1] = dt * 2.0 * cf / (m * n) / sb
    c[K_E1, 0] = dt * 2.0 * lf * cf / (iz * n) / sr
    # (12): aligning torque
    c[K_HT0, 0] = -2.0 * k * sb / st
    c[K_HT1, 1] = -2.0 * k * lf * sr / st
    c[K_DT, 0] = 2.0 * k / (n * st)
    # accelerometer
    c[K_HA0, 0] = -2.0 * s * (cf + cr) / m * sb / sa
    c[K_HA1, 1] = -2.0 * s * cyl / m * sr / sa
    c[K_HA2, 0] = sfa / (m * sa)
    c[K_DA, 0] = 2.0 * s * cf / (m * n * sa)


def polys(p: np.ndarray, ex) -> np.ndarray:
    """(N_K, 3) polynomial coefficients (a new array)."""
    c = np.zeros((N_K, 3))
    coef_polys(np.asarray(p, np.float64), np.asarray(ex, np.int64), c)
    return c


def evaluate(c: np.ndarray, w: float | np.ndarray) -> np.ndarray:
    """Every coefficient at ``w = 1/vx`` (float): shape (N_K,) or (N_K, len(w))."""
    w = np.asarray(w, np.float64)
    return c[:, 0:1] + c[:, 1:2] * w.reshape(1, -1) + c[:, 2:3] * w.reshape(1, -1) ** 2
