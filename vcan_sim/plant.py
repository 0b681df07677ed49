"""The nonlinear plant: planar two-track vehicle with roll and load transfer, steering, driver.

States (``X_*``), SI, ISO 8855 (x forward, y left, z up), in road coordinates::

    X, Y, psi        distance along the road's reference line [m], lateral offset from it [m]
                     (left positive) and heading relative to the road's tangent [rad]
    vx, vy, r        body velocities [m/s] and yaw rate [rad/s]
    phi, phi'        body roll [rad] (positive: right side down) and its rate
    th_sw, w_sw      steering-wheel angle [rad] and rate (upper column)
    th_p, w_p        lower column / pinion angle [rad] and rate (road wheels: delta_f = th_p / N)
    T_ov             overlay torque the motor applies [Nm]
    a_t              lateral tire force / m, lagged by a few ms (for load transfer) [m/s^2]
    e_int, th_d, I   driver: integral of the preview error [m s], lagged wanted angle [rad],
                     holding torque [Nm]

Body equations (wheels i = FL, FR, RL, RR at (x_i, y_i) from the CG; front wheels steered by
delta_f; Fx_i, Fy_i in wheel axes, rotated into body axes for the front)::

    m (vx' - r vy) = sum Fx_b,i + F_aero,x + m g sin(bank) sin(psi)
    m (vy' + r vx) = sum Fy_b,i + F_aero,y + m g sin(bank) cos(psi)       (erratum 7's form)
    Iz r'          = sum (x_i Fy_b,i - y_i Fx_b,i) + sum Mz_i + M_aero,CG
    Ixx phi''      = m_s h_s a_t + m_s g h_s sin(phi) - k_phi phi - c_phi phi'

Vertical loads: static (from the loaded CG, eqs. 17-18 inverted) plus lateral transfer per axle,
right wheels gaining when the tires push left::

    dFz_f = (k_phi,f phi + c_phi,f phi') / t_f + (m lr / L) a_t h_ra / t_f     (rear alike)

Road coordinates (Frenet frame of the road's reference line, curvature kappa [1/m], left turns
positive; on a straight road, kappa = 0, they are world coordinates with the road along X)::

    X'   = (vx cos psi - vy sin psi) / (1 - kappa Y)
    Y'   = vx sin psi + vy cos psi
    psi' = r - kappa X'

Wind and bank are given in road axes (the wind's direction is relative to the road, so on a curve
it turns with the road; the bank tilts the road's lateral axis).

Slip angles (eq. 9 generalised per wheel) a_i = delta_i - atan2(vy + r x_i, vx - r y_i), lagged by
the tire's relaxation length sigma (a_eff' = vx / sigma (a_i - a_eff), four states); tires by
the Magic Formula (:mod:`vcan_sim.tires`); steering by :mod:`vcan_sim.steering`; driver by
:mod:`vcan_sim.driver`; crosswind by :mod:`vcan_sim.aero`. Bank: gravity along the road's lateral
axis, F_bank = m g sin(bank), through the CG (no yaw moment). Aero drag acts through the CG line.
Speed is held by a cruise controller at the front (driven) wheels. The wind force is taken to act
at CG height (so roll is driven by the tire forces alone).

Integration: classic RK4 at a fixed sub-step (default STEP_NS/4 = 0.975 ms); inputs are held
over a sub-step. One jitted kernel (``integrate``) serves the fast path and the closed loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from lde.params import Vehicle
from lde.units import G

from .aero import crosswind, pack_aero
from .config import SimParams
from .driver import (
    DR_KIA,
    DR_MODE,
    DR_TAU,
    DRIVER_HANDS_OFF,
    DRIVER_LANE,
    arm_torque,
    pack_driver,
    wanted_angle,
)
from .payload import LoadedBody, Payload, loaded_body
from .steering import boost, boost_tables, coulomb
from .tires import pack_tire, tire_forces

# ------------------------------------------------------------------ state layout
(
    X_X,
    X_Y,
    X_PSI,
    X_VX,
    X_VY,
    X_R,
    X_PHI,
    X_PHID,
    X_THSW,
    X_WSW,
    X_THP,
    X_WP,
    X_TOV,
    X_AT,
    X_EINT,
    X_THD,
    X_HOLD,
    X_A1,
    X_A2,
    X_A3,
    X_A4,
) = range(21)
N_STATE = 21

# ------------------------------------------------------------------ parameter vector
(
    P_M,
    P_IZ,
    P_LF,
    P_LR,
    P_YCG,
    P_TF,
    P_TR,
    P_H,
    P_HRA,
    P_KPF,
    P_KPR,
    P_CPF,
    P_CPR,
    P_IXX,
    P_MS,
    P_FRR,
    P_KV,
    P_TAUAT,
    P_N,
    P_JSW,
    P_JP,
    P_KTB,
    P_CTB,
    P_CSW,
    P_CP,
    P_TCOUL,
    P_WEPS,
    P_OVMAX,
    P_OVTAU,
    P_DXREF,
    P_SIGMA,
) = range(31)
N_PARAM = 31

# ------------------------------------------------------------------ per-sub-step inputs
# air velocity in world axes [m/s], bank [rad], lane centre at t + preview [m], driver noise torque
# [Nm], speed reference [m/s], scripted overlay request [Nm], commanded steering-wheel angle [rad],
# road curvature at the car and at the driver's preview point [1/m] (left turns positive)
D_WX, D_WY, D_BANK, D_YREFP, D_TNOISE, D_VREF, D_TOVREQ, D_SWCMD, D_KAPPA, D_KAPPAP = range(10)
N_DRIVE = 10

# ------------------------------------------------------------------ outputs (one row per sub-step)
(
    O_VX,
    O_VY,
    O_R,
    O_BETA,
    O_X,
    O_Y,
    O_PSI,
    O_AY,
    O_AYKIN,
    O_DSW,
    O_WSW,
    O_DF,
    O_TCOL,
    O_TAST,
    O_TOV,
    O_TALIGN,
    O_TDRV,
    O_FW,
    O_MW,
    O_MWREF,
    O_FYW,
    O_MZW,
    O_FBANK,
    O_WIND,
    O_BCW,
    O_VR,
    O_BANK,
    O_PHI,
    O_FZ1,
    O_FZ2,
    O_FZ3,
    O_FZ4,
    O_AF,
    O_AR,
    O_FYF,
    O_FYR,
    O_TBOOST,
    O_MZT,
    O_THP,
    O_WP,
    O_VW1,
    O_VW2,
    O_VW3,
    O_VW4,
) = range(44)
N_OUT = 44
OUTPUT_NAMES = (
    "vx",
    "vy",
    "r",
    "beta",
    "X",
    "y",
    "psi",
    "ay_meas",
    "ay",
    "delta_sw",
    "omega_sw",
    "delta_f",
    "T_column",
    "T_assist",
    "T_overlay",
    "T_align",
    "T_driver",
    "Fw",
    "Mw",
    "Mw_ref",
    "Fy_wind",
    "Mz_wind",
    "F_bank",
    "wind_speed",
    "beta_cw",
    "v_rel",
    "bank",
    "roll",
    "Fz_fl",
    "Fz_fr",
    "Fz_rl",
    "Fz_rr",
    "alpha_f",
    "alpha_r",
    "Fy_front",
    "Fy_rear",
    "T_boost",
    "Mz_tires",
    "theta_p",
    "omega_p",
    "v_wheel_fl",
    "v_wheel_fr",
    "v_wheel_rl",
    "v_wheel_rr",
)


@numba.njit(cache=True)
def derivatives(
    x: np.ndarray,
    p: np.ndarray,
    tc: np.ndarray,
    ap: np.ndarray,
    dp: np.ndarray,
    bt: np.ndarray,
    ba: np.ndarray,
    bv: np.ndarray,
    bs: np.ndarray,
    d: np.ndarray,
    ov_req: float,
    dx: np.ndarray,
    out: np.ndarray,
    want_out: bool,
) -> None:
    """dx = f(x, inputs); fills ``out`` (O_* layout) when ``want_out``."""
    m = p[P_M]
    lf = p[P_LF]
    lr = p[P_LR]
    L = lf + lr
    tf = p[P_TF]
    tr = p[P_TR]
    ycg = p[P_YCG]
    n_ratio = p[P_N]
    psi = x[X_PSI]
    vx = x[X_VX]
    vy = x[X_VY]
    r = x[X_R]
    phi = x[X_PHI]
    phid = x[X_PHID]
    cpsi = math.cos(psi)
    spsi = math.sin(psi)

    # --- disturbances: crosswind (eqs. 1-2) and bank (gravity, through the CG)
    wxb = d[D_WX] * cpsi + d[D_WY] * spsi
    wyb = -d[D_WX] * spsi + d[D_WY] * cpsi
    fax, fay, m_mid, vr, bcw = crosswind(vx, vy, wxb, wyb, L, ap)
    # moment about the CG: the mid-wheelbase point lies (lf - lr)/2 ahead of the CG
    m_aero = m_mid + 0.5 * (lf - lr) * fay
    sb = math.sin(d[D_BANK])
    fbx = m * G * sb * spsi
    fby = m * G * sb * cpsi
    w_norm = m * G * math.cos(d[D_BANK])

    # --- steering: torsion bar (torque sensor), road-wheel angle
    t_col = p[P_KTB] * (x[X_THSW] - x[X_THP]) + p[P_CTB] * (x[X_WSW] - x[X_WP])
    delta = x[X_THP] / n_ratio

    # --- vertical loads: static + lateral transfer
    fzf = w_norm * lr / L
    fzr = w_norm * lf / L
    left_share = (0.5 * tf + ycg) / tf
    left_share_r = (0.5 * tr + ycg) / tr
    a_t = x[X_AT]
    dfzf = (p[P_KPF] * phi + p[P_CPF] * phid) / tf + m * lr / L * a_t * p[P_HRA] / tf
    dfzr = (p[P_KPR] * phi + p[P_CPR] * phid) / tr + m * lf / L * a_t * p[P_HRA] / tr
    fz1 = fzf * left_share - dfzf
    fz2 = fzf * (1.0 - left_share) + dfzf
    fz3 = fzr * left_share_r - dfzr
    fz4 = fzr * (1.0 - left_share_r) + dfzr

    # --- wheel kinematics and slip angles (eq. 9 per wheel)
    yl = 0.5 * tf - ycg
    yr = -0.5 * tf - ycg
    yl_r = 0.5 * tr - ycg
    yr_r = -0.5 * tr - ycg
    a1 = delta - math.atan2(vy + r * lf, vx - r * yl)
    a2 = delta - math.atan2(vy + r * lf, vx - r * yr)
    a3 = -math.atan2(vy - r * lr, vx - r * yl_r)
    a4 = -math.atan2(vy - r * lr, vx - r * yr_r)
    # relaxation length: the slip that makes the force lags the kinematic slip,
    # a_eff' = (vx / sigma) (a - a_eff); sigma = 0 turns it off
    sigma = p[P_SIGMA]
    if sigma > 0.0:
        rate = max(vx, 1.0) / sigma
        dx[X_A1] = rate * (a1 - x[X_A1])
        dx[X_A2] = rate * (a2 - x[X_A2])
        dx[X_A3] = rate * (a3 - x[X_A3])
        dx[X_A4] = rate * (a4 - x[X_A4])
        a1 = x[X_A1]
        a2 = x[X_A2]
        a3 = x[X_A3]
        a4 = x[X_A4]
    else:
        dx[X_A1] = 0.0
        dx[X_A2] = 0.0
        dx[X_A3] = 0.0
        dx[X_A4] = 0.0
    fy1, mz1, tax1 = tire_forces(a1, fz1, tc)
    fy2, mz2, tax2 = tire_forces(a2, fz2, tc)
    fy3, mz3, _ = tire_forces(a3, fz3, tc)
    fy4, mz4, _ = tire_forces(a4, fz4, tc)

    # --- longitudinal: cruise control at the front wheels, rolling resistance everywhere
    frr = p[P_FRR]
    f_drive = m * p[P_KV] * (d[D_VREF] - vx) + frr * w_norm - fax - fbx
    fx1 = 0.5 * f_drive - frr * max(fz1, 0.0)
    fx2 = 0.5 * f_drive - frr * max(fz2, 0.0)
    fx3 = -frr * max(fz3, 0.0)
    fx4 = -frr * max(fz4, 0.0)
    cd = math.cos(delta)
    sd = math.sin(delta)
    fxb1 = fx1 * cd - fy1 * sd
    fyb1 = fx1 * sd + fy1 * cd
    fxb2 = fx2 * cd - fy2 * sd
    fyb2 = fx2 * sd + fy2 * cd
    sfx = fxb1 + fxb2 + fx3 + fx4
    sfy = fyb1 + fyb2 + fy3 + fy4
    mz_t = (
        lf * (fyb1 + fyb2)
        - lr * (fy3 + fy4)
        - yl * fxb1
        - yr * fxb2
        - yl_r * fx3
        - yr_r * fx4
        + mz1
        + mz2
        + mz3
        + mz4
    )

    # --- body (road coordinates: exactly the world's on a straight road, kappa = 0)
    kappa = d[D_KAPPA]
    sdot = (vx * cpsi - vy * spsi) / (1.0 - kappa * x[X_Y])
    dx[X_X] = sdot
    dx[X_Y] = vx * spsi + vy * cpsi
    dx[X_PSI] = r - kappa * sdot
    dx[X_VX] = r * vy + (sfx + fax + fbx) / m
    dx[X_VY] = -r * vx + (sfy + fay + fby) / m
    dx[X_R] = (mz_t + m_aero) / p[P_IZ]
    ms = p[P_MS]
    hs = p[P_H] - p[P_HRA]
    dx[X_PHI] = phid
    dx[X_PHID] = (
        ms * hs * a_t
        + ms * G * hs * math.sin(phi)
        - (p[P_KPF] + p[P_KPR]) * phi
        - (p[P_CPF] + p[P_CPR]) * phid
    ) / p[P_IXX]
    dx[X_AT] = (sfy / m - a_t) / p[P_TAUAT]

    # --- steering system (eq. 10 at the column) and MDPS
    t_align = tax1 + tax2
    t_boost = boost(t_col, vx, bt, ba, bv, bs)
    req = min(max(ov_req, -p[P_OVMAX]), p[P_OVMAX])
    dx[X_TOV] = (req - x[X_TOV]) / p[P_OVTAU]
    t_ast = t_boost + x[X_TOV]

    # --- driver
    th_raw, e = wanted_angle(x[X_Y], psi, vx, vy, d[D_YREFP], x[X_EINT], d[D_SWCMD], d[D_KAPPAP], dp)
    dx[X_EINT] = e
    dx[X_THD] = (th_raw - x[X_THD]) / dp[DR_TAU]
    t_drv = arm_torque(x[X_THD], x[X_THSW], x[X_WSW], x[X_HOLD], d[D_TNOISE], dp)
    dx[X_HOLD] = dp[DR_KIA] * (x[X_THD] - x[X_THSW]) if int(dp[DR_MODE]) != DRIVER_HANDS_OFF else 0.0

    dx[X_THSW] = x[X_WSW]
    dx[X_WSW] = (t_drv - t_col - p[P_CSW] * x[X_WSW]) / p[P_JSW]
    dx[X_THP] = x[X_WP]
    dx[X_WP] = (
        t_col + t_ast - t_align / n_ratio - p[P_CP] * x[X_WP] - coulomb(x[X_WP], p[P_TCOUL], p[P_WEPS])
    ) / p[P_JP]

    if want_out:
        fw = fay + fby
        out[O_VX] = vx
        out[O_VY] = vy
        out[O_R] = r
        out[O_BETA] = math.atan2(vy, vx)
        out[O_X] = x[X_X]
        out[O_Y] = x[X_Y]
        out[O_PSI] = psi
        # accelerometer on the rolled body: tire + aero specific force, plus g sin(roll)
        out[O_AY] = (sfy + fay) / m + G * math.sin(phi)
        out[O_AYKIN] = dx[X_VY] + r * vx
        out[O_DSW] = x[X_THSW]
        out[O_WSW] = x[X_WSW]
        out[O_DF] = delta
        out[O_TCOL] = t_col
        out[O_TAST] = t_ast
        out[O_TOV] = x[X_TOV]
        out[O_TALIGN] = t_align
        out[O_TDRV] = t_drv
        out[O_FW] = fw
        out[O_MW] = m_aero
        out[O_MWREF] = m_aero + p[P_DXREF] * fw
        out[O_FYW] = fay
        out[O_MZW] = m_aero
        out[O_FBANK] = fby
        out[O_WIND] = math.sqrt(d[D_WX] * d[D_WX] + d[D_WY] * d[D_WY])
        out[O_BCW] = bcw
        out[O_VR] = vr
        out[O_BANK] = d[D_BANK]
        out[O_PHI] = phi
        out[O_FZ1] = fz1
        out[O_FZ2] = fz2
        out[O_FZ3] = fz3
        out[O_FZ4] = fz4
        out[O_AF] = 0.5 * (a1 + a2)
        out[O_AR] = 0.5 * (a3 + a4)
        out[O_FYF] = fyb1 + fyb2
        out[O_FYR] = fy3 + fy4
        out[O_TBOOST] = t_boost
        out[O_MZT] = mz_t
        out[O_THP] = x[X_THP]
        out[O_WP] = x[X_WP]
        # wheel speeds over ground in each wheel's plane (what wheel-speed sensors see)
        out[O_VW1] = (vx - r * yl) * cd + (vy + r * lf) * sd
        out[O_VW2] = (vx - r * yr) * cd + (vy + r * lf) * sd
        out[O_VW3] = vx - r * yl_r
        out[O_VW4] = vx - r * yr_r


@numba.njit(cache=True)
def integrate(
    x: np.ndarray,
    p: np.ndarray,
    tc: np.ndarray,
    ap: np.ndarray,
    dp: np.ndarray,
    bt: np.ndarray,
    ba: np.ndarray,
    bv: np.ndarray,
    bs: np.ndarray,
    drive: np.ndarray,
    k0: int,
    k1: int,
    h: float,
    ov_req: float,
    use_ov_req: bool,
    out: np.ndarray,
    out_k0: int,
) -> None:
    """RK4 from sub-step k0 to k1 (exclusive) in place on ``x``.

    Row ``out[out_k0 + k - k0]`` receives the outputs at the state of sub-step k (before the
    step). ``drive[k]`` holds the inputs of sub-step k; the overlay request is ``ov_req`` when
    ``use_ov_req`` (closed loop), else the scenario's scripted request ``drive[k, D_TOVREQ]``.
    """
    n = x.shape[0]
    k1v = np.empty(n)
    k2v = np.empty(n)
    k3v = np.empty(n)
    k4v = np.empty(n)
    xt = np.empty(n)
    dummy = np.empty(out.shape[1])
    for k in range(k0, k1):
        d = drive[k]
        req = ov_req if use_ov_req else d[D_TOVREQ]
        # k1 = f(x)  (also the outputs of this sub-step)
        derivatives(x, p, tc, ap, dp, bt, ba, bv, bs, d, req, k1v, out[out_k0 + k - k0], True)
        for i in range(n):
            xt[i] = x[i] + 0.5 * h * k1v[i]
        derivatives(xt, p, tc, ap, dp, bt, ba, bv, bs, d, req, k2v, dummy, False)
        for i in range(n):
            xt[i] = x[i] + 0.5 * h * k2v[i]
        derivatives(xt, p, tc, ap, dp, bt, ba, bv, bs, d, req, k3v, dummy, False)
        for i in range(n):
            xt[i] = x[i] + h * k3v[i]
        derivatives(xt, p, tc, ap, dp, bt, ba, bv, bs, d, req, k4v, dummy, False)
        for i in range(n):
            x[i] += h / 6.0 * (k1v[i] + 2.0 * k2v[i] + 2.0 * k3v[i] + k4v[i])


# ------------------------------------------------------------------ assembling the vectors
@dataclass(frozen=True)
class PlantModel:
    """Packed numeric vectors of one simulated vehicle (built by :func:`build_plant`)."""

    p: np.ndarray
    tc: np.ndarray
    ap: np.ndarray
    dp: np.ndarray
    boost: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    body: LoadedBody
    ratio: float


def build_plant(
    vehicle: Vehicle,
    sp: SimParams,
    payload: Payload,
    driver_mode: int = DRIVER_LANE,
    rng: np.random.Generator | None = None,
) -> PlantModel:
    """Pack the vehicle (with payload), tire, aero, steering and driver data for the kernels."""
    body = loaded_body(vehicle, sp, payload)
    c, s = sp.chassis, sp.steering
    m0 = vehicle.body.mass
    p = np.zeros(N_PARAM)
    p[P_M] = body.mass
    p[P_IZ] = body.yaw_inertia
    p[P_LF] = body.lf
    p[P_LR] = body.lr
    p[P_YCG] = body.y_cg
    p[P_TF] = vehicle.body.track_front
    p[P_TR] = vehicle.body.track_rear
    p[P_H] = body.cg_height
    p[P_HRA] = c.roll_axis_height
    p[P_KPF] = c.roll_stiffness_front
    p[P_KPR] = c.roll_stiffness_rear
    p[P_CPF] = c.roll_damping_front
    p[P_CPR] = c.roll_damping_rear
    p[P_IXX] = c.roll_inertia * body.mass / m0
    p[P_MS] = c.sprung_fraction * m0 + (body.mass - m0)
    p[P_FRR] = c.rolling_resistance
    p[P_KV] = c.speed_gain
    p[P_TAUAT] = c.load_filter_time
    p[P_N] = vehicle.steering.ratio
    p[P_JSW] = s.wheel_inertia
    p[P_JP] = s.rack_inertia
    p[P_KTB] = s.torsion_stiffness
    p[P_CTB] = s.torsion_damping
    p[P_CSW] = s.column_damping
    p[P_CP] = s.rack_damping
    p[P_TCOUL] = s.rack_coulomb
    p[P_WEPS] = s.coulomb_smoothing
    p[P_OVMAX] = s.overlay_max
    p[P_OVTAU] = s.overlay_time
    p[P_DXREF] = body.dx_ref
    p[P_SIGMA] = sp.tire.relaxation_length
    return PlantModel(
        p=p,
        tc=pack_tire(sp.tire),
        ap=pack_aero(sp.aero),
        dp=pack_driver(sp.driver, driver_mode, rng, body.lf + body.lr, vehicle.steering.ratio),
        boost=boost_tables(s),
        body=body,
        ratio=vehicle.steering.ratio,
    )


def initial_state(speed: float) -> np.ndarray:
    """Straight driving at ``speed`` [m/s], everything else at rest."""
    x = np.zeros(N_STATE)
    x[X_VX] = speed
    return x


def run_span(
    model: PlantModel,
    x: np.ndarray,
    drive: np.ndarray,
    k0: int,
    k1: int,
    h: float,
    out: np.ndarray,
    out_k0: int = 0,
    ov_req: float | None = None,
) -> None:
    """Integrate sub-steps k0..k1-1 (see :func:`integrate`); ``ov_req`` overrides the scripted overlay."""
    integrate(
        x,
        model.p,
        model.tc,
        model.ap,
        model.dp,
        *model.boost,
        drive,
        k0,
        k1,
        h,
        0.0 if ov_req is None else float(ov_req),
        ov_req is not None,
        out,
        out_k0,
    )
