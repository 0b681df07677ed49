"""The lateral disturbance filter with the lateral acceleration: crosswind apart from road bank.

State ``x = [beta, r, F_wind, M_wind, F_bank]`` [rad, rad/s, N, Nm, N]; ISO 8855 signs (left
positive); ``F_bank = m g sin(phi_bank)`` (``phi_bank > 0``: the road's left side is lower, gravity
pulls the car left). Outputs: the totals of the paper, ``Fw = F_wind + F_bank`` [N] and
``Mw = M_wind`` [Nm] (a bank acts through the CG: no moment, SPEC erratum 5), the wind alone
(``F_wind``, ``M_wind``) and the bank angle ``phi_bank = asin(F_bank / (m g))``.

Model (per tire, linear; eq. 9 slips ``alpha_f = delta_f - beta - lf r/vx``, ``alpha_r = -beta + lr r/vx``)::

    m vx (beta_dot + r) = 2 Cf alpha_f + 2 Cr alpha_r + F_wind + F_bank            (7)
    Iz r_dot            = 2 lf Cf alpha_f - 2 lr Cr alpha_r + M_wind                 (8)
    F_wind, M_wind, F_bank: random walks (densities q_wind, q_wind_moment, q_bank)

Measurements, each used only on a step at which its CAN signal brought a new sample (a held value
is not new information; ``fresh`` flags from the receiver's sample ages)::

    r_meas - b_r                          = r                                                    (yaw rate)
    N (k_c T_col + k_a T_ast) - N T_fric z - T_0 = 2K alpha_f                                   (eqs. 11-12)
    a_y,meas                              = (s (2 Cf alpha_f + 2 Cr alpha_r) + F_wind) / m (accelerometer)

``k_c``, ``k_a`` are 1 when both torques are in Nm; a torque of unknown scale (raw counts) has its
factor learned relative to the other (:mod:`lde.estimator.learner`, ``L_TSCALE``); with both unknown
K, the friction and the twist are in the column signal's unit, and Fw, Mw stay in N and Nm (the
torque enters only through ``T / 2K``).

The accelerometer measures specific force: the tire and aerodynamic forces, never gravity. A bank,
whose gravity component the tires balance, shows in a_y only through the tire forces; a gust shows
at once: that is what tells wind from bank. ``s = 1 + g k_roll`` is the roll tilt of the body-fixed
sensor (the body rolls with the tire force; the wind acts near the CG's height and rolls it little).

Inputs after the learned corrections (:mod:`lde.estimator.learner` writes them into the parameter vector)::

    delta_f = (delta_sw - c_tb T_col - d_sw) / N        torsion twist (angle above the bar), offset
    z       = tanh(pinion_rate / w)                      the friction's sign; the pinion rate is the
                                                         derivative of (delta_sw - c_tb T_col) from a
                                                         10 Hz state-variable filter (the CAN rate
                                                         signals are too coarse or unsigned)

While the rack sticks (``|z| < 1``) the friction torque is anywhere in ``+-T_fric``: the aligning
torque's measurement variance is widened by ``(N T_fric (1 - z^2))^2``.

Discretisation as the paper's filter (SPEC erratum 8): ``Phi = I + A dt``, ``E = B dt``,
``Qd = W dt``; the update is sequential over the scalar measurements (R diagonal): no matrix
inverse. Every entry of Phi, E and H is a polynomial of degree <= 2 in 1/vx whose coefficients
depend on (Cf, Cr, K, s) only: between two pushes of the learner the filter is a linear KF.

Status (:mod:`lde.status`) as the paper's step: ESC_FAULT / MDPS_FAULT (+ DEGRADED) for an unusable
group, LOW_SPEED below ``min_speed``, NOT_CONVERGED for ``converge_time`` after a (re)start; held
(no update, no propagation) without ESC or below the minimum speed; P re-initialised on a restart.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from lde.estimator.outputs import O_BANK, O_BETA, O_FW, O_FW_WIND, O_MW, O_MW_WIND, O_T_ALIGN, O_YAW
from lde.params import Vehicle
from lde.status import DEGRADED, ESC_FAULT, LOW_SPEED, MDPS_FAULT, NOT_CONVERGED, VALID
from lde.units import DEG, STEP_S, G

NX = 5
IX_BETA, IX_R, IX_FA, IX_MA, IX_FB = range(5)

# --- the parameter vector (flat float64; the learner writes the learned slots) ------------------
(P_M, P_IZ, P_LF, P_LR, P_N, P_DT, P_G,
 P_CF, P_CR, P_K, P_S,                                   # learned tire / sensor model
 P_TFRIC, P_FW, P_CTB, P_DSW, P_BR, P_T0,                # learned corrections (P_FW: the sign's width)
 P_QB, P_QR, P_QFA, P_QMA, P_QFB, P_RR, P_RT, P_RA,      # noise densities / variances
 P_P0B, P_P0R, P_P0FA, P_P0MA, P_P0FB,
 P_VMIN, P_CONV,
 P_XCP, P_WCP,
 P_QLO, P_QD0, P_QTAU, P_QHI,
 P_KC, P_KA) = range(40)  # fmt: skip
N_P = 40

# --- aux state slots ---------------------------------------------------------------------------
# float: last valid delta_f, last T_align_hat, last friction sign, the 10 Hz rate filter (y, y')
F_DELTA, F_TALIGN, F_ZFRIC, F_SVF_Y, F_SVF_YD, F_SVF_INIT, F_ZR, F_ZT, F_ZA, F_QG = range(10)
N_F = 10
# int: held (1 after a reset / while held), convergence start t_ns (-1: not running), steps
I_HELD, I_CONV_START, I_STEPS = range(3)
N_I = 3
_NO_START = -1

#: the friction sign's width on the derived pinion rate [rad/s] (derived: the 2 deg/s LSB of
#: the lde profile's SteeringRate is too coarse for it; the hyundai one carries no sign)
FRICTION_RATE_WIDTH = 4.0 * DEG
#: natural frequency and damping of the state-variable filter deriving the pinion rate
SVF_W, SVF_Z = 2.0 * math.pi * 10.0, 0.8


def params_vector(
    vehicle: Vehicle, dt: float = STEP_S, *, angle_above_torsion_bar: bool = False
) -> np.ndarray:
    """The filter's parameter vector for ``vehicle`` (its tires and corrections are the starting
    values that the learner refines)."""
    b, t, e, c, lg = vehicle.body, vehicle.tires, vehicle.estimator, vehicle.corrections, vehicle.learning
    p = np.zeros(N_P)
    p[P_M], p[P_IZ], p[P_LF], p[P_LR] = b.mass, b.yaw_inertia, b.lf, b.lr
    p[P_N], p[P_DT], p[P_G] = vehicle.steering.ratio, dt, G
    p[P_CF], p[P_CR], p[P_K], p[P_S] = t.cf, t.cr, t.align_rate, lg.accel_scale
    p[P_TFRIC] = c.friction
    p[P_FW] = FRICTION_RATE_WIDTH
    ctb = c.torsion_compliance
    if ctb == 0.0 and angle_above_torsion_bar:
        ctb = lg.torsion_above_bar
    p[P_CTB], p[P_DSW], p[P_BR], p[P_T0] = ctb, c.steer_offset, c.yaw_bias, c.align_offset
    p[P_QB], p[P_QR] = e.q_beta, e.q_yaw
    p[P_QFA], p[P_QMA], p[P_QFB] = e.q_wind, e.q_wind_moment, e.q_bank
    p[P_RR], p[P_RT], p[P_RA] = e.r_yaw, e.r_align, e.r_lat_accel
    p[P_P0B], p[P_P0R], p[P_P0FA], p[P_P0MA], p[P_P0FB] = e.p0_beta, e.p0_yaw, e.p0_fw, e.p0_mw, e.p0_bank
    p[P_VMIN], p[P_CONV] = e.min_speed, e.converge_time
    p[P_XCP], p[P_WCP] = e.wind_cp, e.wind_cp_weight
    p[P_QLO], p[P_QD0], p[P_QTAU], p[P_QHI] = 1.0, 1.0, 0.15, 1.0
    # the torque signals' scales to the reference unit (1: both in Nm; a profile that declares a
    # torque's scale unknown has it learned: lde.estimator.learner, L_TSCALE)
    p[P_KC], p[P_KA] = 1.0, 1.0
    return p


class FilterState(NamedTuple):
    """The filter's state besides its parameter vector (what :func:`step_kernel` changes)."""

    x: np.ndarray  # (NX,) [beta rad, r rad/s, F_wind N, M_wind Nm, F_bank N], the a-priori estimate
    P: np.ndarray  # (NX, NX) its covariance (SI units squared)
    fs: np.ndarray  # (N_F,) float aux slots (F_*)
    ints: np.ndarray  # (N_I,) int64 aux slots (I_*)
    h: np.ndarray  # (NX,) scratch: a measurement row
    ph: np.ndarray  # (NX,) scratch: P h


def new_filter_state(p: np.ndarray) -> FilterState:
    """A reset filter state for the parameter vector ``p`` (held until the first usable step)."""
    f = FilterState(
        np.zeros(NX), np.zeros((NX, NX)), np.zeros(N_F), np.zeros(N_I, np.int64), np.zeros(NX), np.zeros(NX)
    )
    reset_kernel(p, f.x, f.P, f.fs, f.ints)
    return f


# --- compiled kernels --------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _p0(p, P):  # pragma: no cover - compiled
    for i in range(NX):
        for j in range(NX):
            P[i, j] = 0.0
    P[0, 0] = p[P_P0B] ** 2
    P[1, 1] = p[P_P0R] ** 2
    P[2, 2] = p[P_P0FA] ** 2
    P[3, 3] = p[P_P0MA] ** 2
    P[4, 4] = p[P_P0FB] ** 2


@njit(cache=True)
def reset_kernel(p, x, P, fs, ints):  # pragma: no cover - compiled
    """x = 0, P = P0, held (the first usable step starts the filter)."""
    for i in range(NX):
        x[i] = 0.0
    _p0(p, P)
    for i in range(N_F):
        fs[i] = 0.0
    ints[I_HELD] = 1
    ints[I_CONV_START] = _NO_START
    ints[I_STEPS] = 0


@njit(cache=True, inline="always")
def _scalar_update(x, P, h, d, z, r, ph):  # pragma: no cover - compiled
    """x += k (z - h x - d),  P -= k (P h)^T,  k = P h / (h P h + r). Returns the normalised
    innovation (z - h x - d) / sqrt(h P h + r)."""
    innov = z - d
    for i in range(NX):
        innov -= h[i] * x[i]
    s = r
    for i in range(NX):
        acc = 0.0
        for j in range(NX):
            acc += P[i, j] * h[j]
        ph[i] = acc
        s += h[i] * acc
    inv_s = 1.0 / s
    for i in range(NX):
        x[i] += ph[i] * inv_s * innov
    for i in range(NX):
        for j in range(i, NX):
            v = P[i, j] - ph[i] * ph[j] * inv_s
            P[i, j] = v
            P[j, i] = v
    return innov * math.sqrt(inv_s)


@njit(cache=True, inline="always")
def friction_sign(p, fs, pinion_angle):  # pragma: no cover - compiled
    """z = tanh(pinion_rate / w), the pinion rate from a 10 Hz state-variable filter of the pinion
    angle (semi-implicit Euler at the step period)."""
    if fs[F_SVF_INIT] == 0.0:
        fs[F_SVF_Y] = pinion_angle
        fs[F_SVF_YD] = 0.0
        fs[F_SVF_INIT] = 1.0
    dt = p[P_DT]
    ydd = SVF_W * SVF_W * (pinion_angle - fs[F_SVF_Y]) - 2.0 * SVF_Z * SVF_W * fs[F_SVF_YD]
    fs[F_SVF_YD] += dt * ydd
    fs[F_SVF_Y] += dt * fs[F_SVF_YD]
    return math.tanh(fs[F_SVF_YD] / p[P_FW])


@njit(cache=True, inline="always")
def _outputs(p, x, fs, out):  # pragma: no cover - compiled
    out[O_FW] = x[IX_FA] + x[IX_FB]
    out[O_MW] = x[IX_MA]
    out[O_FW_WIND] = x[IX_FA]
    out[O_MW_WIND] = x[IX_MA]
    sb = x[IX_FB] / (p[P_M] * p[P_G])
    out[O_BANK] = math.asin(min(1.0, max(-1.0, sb)))
    out[O_BETA] = x[IX_BETA]
    out[O_YAW] = x[IX_R]
    out[O_T_ALIGN] = fs[F_TALIGN]


@njit(cache=True, inline="always")
def blend_wind_moment(m_wind, f_wind, x_cp, w):  # pragma: no cover - compiled
    """``(1 - w) m_wind + w x_cp f_wind`` [Nm]: the wind moment [Nm] blended with the moment of the
    wind force [N] at the centre of pressure ``x_cp`` [m] ahead of the CG, weight ``w`` in 0..1
    (scalars, or arrays: the smoother's)."""
    return (1.0 - w) * m_wind + w * x_cp * f_wind


@njit(cache=True)
def wind_moment_output(p, out):  # pragma: no cover - compiled
    """The reported wind moment [Nm]: the filter's ``M_wind`` blended with the centre-of-pressure
    prior ``x_cp F_wind``, ``Mw = (1 - w) M_wind + w x_cp F_wind`` (``x_cp`` [m] ahead of the CG,
    ``w`` in 0..1; docs/design/filters.md, "The reported wind moment"). Both backends apply it
    to ``out`` after the learner, which reads the filter's own ``M_wind`` (``O_MW_WIND`` before this).

    Why a blend: in steady driving the filter's five states are fixed by two equilibria and three
    measurements, so its ``M_wind`` is whatever closes the yaw balance with the assumed tires; with
    tires known to +-25 % that is a yaw-moment error of the order of 0.3-0.7 m x the tire force, the
    same order as, and independent of, the spread of a car's aerodynamic centre of pressure. Both
    errors scale with the disturbance, so the minimum-variance combination has a constant weight.
    Off (``w = 0``) in the shipped defaults: a car whose tires are known and whose centre of pressure
    is not near ``x_cp`` loses by it (the acceptance drive's wind has its centre 0.375 m behind the CG)."""
    w = p[P_WCP]
    if w > 0.0:
        mw = blend_wind_moment(out[O_MW_WIND], out[O_FW_WIND], p[P_XCP], w)
        out[O_MW] = mw
        out[O_MW_WIND] = mw


@njit(cache=True)
def overlay_gain(p):  # pragma: no cover - compiled
    """The overlay law's gain ``K / (N Cf L)`` [Nm at the column per N m] from the current (learned)
    parameters (the holding torque is ``2 K alpha_f / N``; lde.estimator.overlay)."""
    return p[P_K] / (p[P_N] * p[P_CF] * (p[P_LF] + p[P_LR]))


@njit(cache=True, inline="always")
def propagation_coefficients(m, iz, lf, lr, cf, cr, vx):  # pragma: no cover - compiled
    """The 2-DOF model's continuous-time coefficients at speed ``vx`` [m/s] (eqs. 7-8; per-axle
    stiffnesses ``2 cf``, ``2 cr`` [N/rad], mass ``m`` [kg], yaw inertia ``iz`` [kg m^2], CG to axles
    ``lf``, ``lr`` [m]): (a00, a01, a0f, a10, a11, a13, b0, b1) of
    ``d beta/dt = a00 beta + a01 r + a0f F + b0 delta``, ``d r/dt = a10 beta + a11 r + a13 M + b1 delta``.
    One definition for the causal step and the smoother's traced step (:mod:`lde.replay.smoother`)."""
    a00 = -2.0 * (cf + cr) / (m * vx)
    a01 = -1.0 - 2.0 * (lf * cf - lr * cr) / (m * vx * vx)
    a0f = 1.0 / (m * vx)
    a10 = -2.0 * (lf * cf - lr * cr) / iz
    a11 = -2.0 * (lf * lf * cf + lr * lr * cr) / (iz * vx)
    a13 = 1.0 / iz
    b0 = 2.0 * cf / (m * vx)
    b1 = 2.0 * lf * cf / iz
    return a00, a01, a0f, a10, a11, a13, b0, b1


@njit(cache=True)
def step_kernel(p, x, P, fs, ints, h, ph, t_ns, vx, angle, yaw, tcol, tast, ay,
                fresh_r, fresh_t, fresh_a, mdps_ok, esc_ok, out):  # fmt: skip  # pragma: no cover - compiled
    """One step (module docstring): update with the fresh measurements at vx, output the
    a-posteriori estimate, propagate it. Fills ``out`` (:mod:`lde.estimator.outputs`), returns the
    status."""
    ints[I_STEPS] += 1
    status = 0
    esc_valid = esc_ok and math.isfinite(yaw)
    mdps_valid = mdps_ok and math.isfinite(angle) and math.isfinite(tcol) and math.isfinite(tast)
    if not esc_valid:
        status |= ESC_FAULT
    if not mdps_valid:
        status |= MDPS_FAULT | DEGRADED
    speed_ok = math.isfinite(vx) and vx >= p[P_VMIN]
    if esc_valid and not speed_ok:
        status |= LOW_SPEED
    if not (esc_valid and speed_ok):
        ints[I_HELD] = 1
        ints[I_CONV_START] = _NO_START
        _outputs(p, x, fs, out)
        return status | NOT_CONVERGED
    if ints[I_HELD] == 1:
        _p0(p, P)  # (re)start after a reset or a hold: keep x, re-initialise P
        ints[I_HELD] = 0

    m, iz, lf, lr, n = p[P_M], p[P_IZ], p[P_LF], p[P_LR], p[P_N]
    dt = p[P_DT]
    # inputs after the learned corrections
    if mdps_valid:
        pinion = angle - p[P_CTB] * tcol  # the torsion twist removed
        fs[F_ZFRIC] = friction_sign(p, fs, pinion)
        fs[F_DELTA] = (pinion - p[P_DSW]) / n
    zf = fs[F_ZFRIC]
    delta = fs[F_DELTA]
    cf, cr, k, s = p[P_CF], p[P_CR], p[P_K], p[P_S]
    iv = 1.0 / vx

    # --- updates (sequential, scalar), each with a fresh sample only
    # the change detector of the adaptive process noise: each measurement's normalised innovation,
    # low-passed over P_QTAU (a disturbance that moves shows as a persistent innovation)
    ad = min(1.0, p[P_DT] / p[P_QTAU])
    if fresh_r:
        for i in range(NX):
            h[i] = 0.0
        h[IX_R] = 1.0
        nu = _scalar_update(x, P, h, 0.0, yaw - p[P_BR], p[P_RR], ph)
        fs[F_ZR] += ad * (nu - fs[F_ZR])
    if fresh_t and mdps_valid:
        # N (T_col + T_ast) - N T_fric z - T_0 = 2K alpha_f = 2K (delta - beta - lf r / vx)
        for i in range(NX):
            h[i] = 0.0
        h[IX_BETA] = -2.0 * k
        h[IX_R] = -2.0 * k * lf * iv
        z = n * (p[P_KC] * tcol + p[P_KA] * tast) - n * p[P_TFRIC] * zf - p[P_T0]
        fu = n * p[P_TFRIC] * (1.0 - zf * zf)  # sticking: the friction torque is anywhere in +-T_fric
        nu = _scalar_update(x, P, h, 2.0 * k * delta, z, p[P_RT] + fu * fu, ph)
        fs[F_ZT] += ad * (nu - fs[F_ZT])
    if fresh_a and math.isfinite(ay):
        # a_y = (s (2 Cf alpha_f + 2 Cr alpha_r) + F_wind) / m
        for i in range(NX):
            h[i] = 0.0
        h[IX_BETA] = -2.0 * s * (cf + cr) / m
        h[IX_R] = -2.0 * s * (lf * cf - lr * cr) * iv / m
        h[IX_FA] = 1.0 / m
        nu = _scalar_update(x, P, h, 2.0 * s * cf * delta / m, ay, p[P_RA], ph)
        fs[F_ZA] += ad * (nu - fs[F_ZA])

    fs[F_TALIGN] = 2.0 * k * (delta - x[IX_BETA] - lf * x[IX_R] * iv)
    _outputs(p, x, fs, out)

    # --- propagate the a-posteriori estimate: x = Phi x + E delta,  P = Phi P Phi' + W dt
    a00, a01, a0f, a10, a11, a13, b0, b1 = propagation_coefficients(m, iz, lf, lr, cf, cr, vx)
    # Phi rows 0, 1 (rows 2-4 are the identity): F_wind and F_bank both act through (7)
    f00, f01, f02, f04 = 1.0 + a00 * dt, a01 * dt, a0f * dt, a0f * dt
    f10, f11, f13 = a10 * dt, 1.0 + a11 * dt, a13 * dt
    x0 = f00 * x[0] + f01 * x[1] + f02 * x[2] + f04 * x[4] + b0 * dt * delta
    x1 = f10 * x[0] + f11 * x[1] + f13 * x[3] + b1 * dt * delta
    x[0] = x0
    x[1] = x1
    # P <- Phi P: rows 0 and 1 change
    for j in range(NX):
        t0 = f00 * P[0, j] + f01 * P[1, j] + f02 * P[2, j] + f04 * P[4, j]
        ph[j] = f10 * P[0, j] + f11 * P[1, j] + f13 * P[3, j]
        P[0, j] = t0
    for j in range(NX):
        P[1, j] = ph[j]
    # ... then (Phi P) Phi': columns 0 and 1 change
    for i in range(NX):
        c0 = P[i, 0] * f00 + P[i, 1] * f01 + P[i, 2] * f02 + P[i, 4] * f04
        c1 = P[i, 0] * f10 + P[i, 1] * f11 + P[i, 3] * f13
        P[i, 0] = c0
        P[i, 1] = c1
    P[0, 0] += p[P_QB] * dt
    P[1, 1] += p[P_QR] * dt
    # adaptive process noise of the disturbances: P_QLO x the densities while the innovations are
    # unbiased, up to the full densities as their low-passed square reaches P_QD0
    dstat = fs[F_ZR] * fs[F_ZR] + fs[F_ZT] * fs[F_ZT] + fs[F_ZA] * fs[F_ZA]
    g = min(p[P_QHI], p[P_QLO] + (1.0 - p[P_QLO]) * dstat / p[P_QD0])
    fs[F_QG] = g
    P[2, 2] += p[P_QFA] * g * dt
    P[3, 3] += p[P_QMA] * g * dt
    P[4, 4] += p[P_QFB] * g * dt

    # convergence timer: runs while both the MDPS and the ESC groups are used
    if not mdps_valid:
        ints[I_CONV_START] = _NO_START
    elif ints[I_CONV_START] == _NO_START:
        ints[I_CONV_START] = t_ns
    if ints[I_CONV_START] == _NO_START or float(t_ns - ints[I_CONV_START]) < p[P_CONV] * 1e9:
        status |= NOT_CONVERGED
    if status == 0:
        status = VALID
    return status
