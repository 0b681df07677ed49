"""The estimator's 2-DOF bicycle model with disturbance states, scheduled on speed.

State ``x = [beta, r, Fw, Mw]``: side slip [rad], yaw rate [rad/s], lateral disturbance force at
the CG [N], disturbance yaw moment about the CG [Nm]. Input ``u = delta_f = delta_sw / N`` [rad,
road wheel]. Measurements ``z = [r, T_align]`` [rad/s, Nm at the steering axis]. ISO 8855 signs
(left positive); ``T_align`` keeps the paper's sign (positive resists a left steer).

Derivation (paper eqs. 7-9 and 12; SPEC section 2 errata resolved). Per tire, linear:

    alpha_f = delta_f - beta - lf r / vx            alpha_r = -beta + lr r / vx       (9)
    F_f = Cf alpha_f                                F_r = Cr alpha_r
    m vx (beta_dot + r) = 2 F_f + 2 F_r + Fw                                          (7)
    Iz r_dot            = 2 lf F_f - 2 lr F_r + Mw                                    (8)
    T_align             = 2 K alpha_f     (lf, not lr, in alpha_f: erratum 1)         (12)

Substituting (9) in (7)-(8) gives ``x_dot = A x + B delta_f + Bw w`` with

    A = [[-2(Cf+Cr)/(m vx),   -1 - 2(lf Cf - lr Cr)/(m vx^2),   1/(m vx),  0   ],
         [-2(lf Cf - lr Cr)/Iz, -2(lf^2 Cf + lr^2 Cr)/(Iz vx),   0,        1/Iz],     (erratum 2)
         [0, 0, 0, 0],
         [0, 0, 0, 0]]
    B = [2 Cf/(m vx), 2 lf Cf/Iz, 0, 0]
    Bw = I (4x4): white noise of density W = diag(q_beta, q_yaw, q_fw, q_mw) drives every state;
         Fw and Mw are random walks.

and ``z = H x + D delta_f + v``:

    H = [[0, 1, 0, 0], [-2K, -2K lf/vx, 0, 0]],   D = [0, 2K]                     (erratum 3)

Discretisation (paper eq. 15, Euler, period dt = the 3.9 ms grid period):

    Phi = I + A dt,    E = B dt,    Qd = Bw W Bw^T dt

SPEC erratum 8: the paper's ``Gamma W Gamma^T`` with ``Gamma = Bw dt`` scales the noise by dt^2;
here W is a *continuous* noise density and ``Qd = Bw W Bw^T dt`` is its discrete covariance (to
first order in dt). The Kalman gain of eq. (16) is not the aligning-torque rate K (erratum 9).

Flat parameter vector (for the numba-compiled code; built by :func:`params_vector`), float64:

    ====  ==========  ==============================================
    idx   name        meaning [unit]
    ====  ==========  ==============================================
    0     P_M         mass m [kg]
    1     P_IZ        yaw inertia Iz [kg m^2]
    2     P_LF        CG to front axle lf [m]
    3     P_LR        CG to rear axle lr [m]
    4     P_CF        front cornering stiffness per tire Cf [N/rad]
    5     P_CR        rear cornering stiffness per tire Cr [N/rad]
    6     P_K         aligning-torque rate per front tire K [Nm/rad]
    7     P_N         steering ratio N [-]
    8     P_DT        model period dt [s]
    9-12  P_Q_*       W = diag(q_beta, q_yaw, q_fw, q_mw) [rad^2/s, rad^2/s^3, N^2/s, Nm^2/s]
    13    P_R_YAW     yaw-rate measurement variance [(rad/s)^2]
    14    P_R_ALIGN   T_align measurement variance [Nm^2]
    15-18 P_P0_*      initial standard deviations of beta, r, Fw, Mw [rad, rad/s, N, Nm]
    19    P_MIN_SPEED below this speed the filter holds [m/s]
    20    P_CONV_TIME converge time after a (re)start [s]
    ====  ==========  ==============================================
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from lde.errors import ConfigError
from lde.params import EstimatorTuning, Vehicle
from lde.units import STEP_S

# --- state / measurement slots -------------------------------------------------------------
NX = 4  #: number of states
NZ = 2  #: number of measurements
IX_BETA, IX_YAW, IX_FW, IX_MW = 0, 1, 2, 3  #: state slots: beta [rad], r [rad/s], Fw [N], Mw [Nm]
IZ_YAW, IZ_ALIGN = 0, 1  #: measurement slots: r [rad/s], T_align [Nm]

# --- flat parameter vector layout (see module docstring) -----------------------------------
P_M, P_IZ, P_LF, P_LR, P_CF, P_CR, P_K, P_N, P_DT = 0, 1, 2, 3, 4, 5, 6, 7, 8
P_Q_BETA, P_Q_YAW, P_Q_FW, P_Q_MW = 9, 10, 11, 12
P_R_YAW, P_R_ALIGN = 13, 14
P_P0_BETA, P_P0_YAW, P_P0_FW, P_P0_MW = 15, 16, 17, 18
P_MIN_SPEED, P_CONV_TIME = 19, 20
N_PARAMS = 21


def params_vector(vehicle: Vehicle, dt: float = STEP_S) -> np.ndarray:
    """The flat float64 parameter vector (layout in the module docstring) of ``vehicle``."""
    b, t, e = vehicle.body, vehicle.tires, vehicle.estimator
    p = np.empty(N_PARAMS, dtype=np.float64)
    p[P_M], p[P_IZ], p[P_LF], p[P_LR] = b.mass, b.yaw_inertia, b.lf, b.lr
    p[P_CF], p[P_CR], p[P_K], p[P_N] = t.cf, t.cr, t.align_rate, vehicle.steering.ratio
    p[P_DT] = dt
    p[P_Q_BETA], p[P_Q_YAW], p[P_Q_FW], p[P_Q_MW] = e.q_beta, e.q_yaw, e.q_fw, e.q_mw
    p[P_R_YAW], p[P_R_ALIGN] = e.r_yaw, e.r_align
    p[P_P0_BETA], p[P_P0_YAW], p[P_P0_FW], p[P_P0_MW] = e.p0_beta, e.p0_yaw, e.p0_fw, e.p0_mw
    p[P_MIN_SPEED], p[P_CONV_TIME] = e.min_speed, e.converge_time
    return p


# --- numba kernels on the flat vector (the single implementation of the matrices) ----------


@njit(cache=True)
def continuous_into(p, vx, A, B, H, D):  # pragma: no cover - compiled
    """Fill A (4x4), B (4,), H (2x4), D (2,) for speed ``vx`` [m/s] > 0 (every entry written)."""
    m, iz, lf, lr = p[P_M], p[P_IZ], p[P_LF], p[P_LR]
    cf, cr, k = p[P_CF], p[P_CR], p[P_K]
    inv_v = 1.0 / vx
    inv_mv = inv_v / m  # 1/(m vx)
    inv_iz = 1.0 / iz
    for i in range(4):
        for j in range(4):
            A[i, j] = 0.0
    # beta_dot = -2(Cf+Cr)/(m vx) beta + (-1 - 2(lf Cf - lr Cr)/(m vx^2)) r + Fw/(m vx) + 2Cf/(m vx) delta_f
    A[0, 0] = -2.0 * (cf + cr) * inv_mv
    A[0, 1] = -1.0 - 2.0 * (lf * cf - lr * cr) * inv_mv * inv_v
    A[0, 2] = inv_mv
    # r_dot = -2(lf Cf - lr Cr)/Iz beta - 2(lf^2 Cf + lr^2 Cr)/(Iz vx) r + Mw/Iz + 2 lf Cf/Iz delta_f
    A[1, 0] = -2.0 * (lf * cf - lr * cr) * inv_iz
    A[1, 1] = -2.0 * (lf * lf * cf + lr * lr * cr) * inv_iz * inv_v
    A[1, 3] = inv_iz
    B[0] = 2.0 * cf * inv_mv
    B[1] = 2.0 * lf * cf * inv_iz
    B[2] = 0.0
    B[3] = 0.0
    # z1 = r ;  z2 = T_align = 2K (delta_f - beta - lf r/vx)
    for j in range(4):
        H[0, j] = 0.0
        H[1, j] = 0.0
    H[0, 1] = 1.0
    H[1, 0] = -2.0 * k
    H[1, 1] = -2.0 * k * lf * inv_v
    D[0] = 0.0
    D[1] = 2.0 * k


@njit(cache=True)
def discrete_into(p, vx, Phi, E, Qd, H, D):  # pragma: no cover - compiled
    """Fill the Euler-discrete Phi (4x4), E (4,), Qd (4x4), H (2x4), D (2,) for ``vx`` [m/s] > 0.

    Phi = I + A dt, E = B dt, Qd = Bw W Bw^T dt with Bw = I, W = diag(q_beta, q_yaw, q_fw, q_mw).
    """
    dt = p[P_DT]
    continuous_into(p, vx, Phi, E, H, D)
    for i in range(4):
        for j in range(4):
            Phi[i, j] *= dt
            Qd[i, j] = 0.0
        Phi[i, i] += 1.0
        E[i] *= dt
    Qd[0, 0] = p[P_Q_BETA] * dt
    Qd[1, 1] = p[P_Q_YAW] * dt
    Qd[2, 2] = p[P_Q_FW] * dt
    Qd[3, 3] = p[P_Q_MW] * dt


# --- Python API from a Vehicle ---------------------------------------------------------------


@dataclass(frozen=True)
class ContinuousModel:
    """x_dot = A x + B delta_f + Bw w,  z = H x + D delta_f + v (SI; see module docstring)."""

    A: np.ndarray  # (4, 4)
    B: np.ndarray  # (4,)   per rad of delta_f (road wheel)
    Bw: np.ndarray  # (4, 4) identity
    H: np.ndarray  # (2, 4)
    D: np.ndarray  # (2,)
    W: np.ndarray  # (4, 4) continuous process-noise density diag(q_beta, q_yaw, q_fw, q_mw)


@dataclass(frozen=True)
class DiscreteModel:
    """x+ = Phi x + E delta_f + w (cov Qd),  z = H x + D delta_f + v (cov R); period ``dt`` [s]."""

    Phi: np.ndarray  # (4, 4)
    E: np.ndarray  # (4,)
    Qd: np.ndarray  # (4, 4)
    H: np.ndarray  # (2, 4)
    D: np.ndarray  # (2,)
    R: np.ndarray  # (2, 2) diag(r_yaw, r_align)
    dt: float


def _check_speed(vx: float) -> float:
    vx = float(vx)
    if not np.isfinite(vx) or vx <= 0.0:
        raise ConfigError(f"the model needs a finite speed vx > 0 m/s, got {vx!r}")
    return vx


def process_noise_density(tuning: EstimatorTuning) -> np.ndarray:
    """W = diag(q_beta, q_yaw, q_fw, q_mw), the continuous process-noise density."""
    return np.diag([tuning.q_beta, tuning.q_yaw, tuning.q_fw, tuning.q_mw]).astype(np.float64)


def measurement_noise(tuning: EstimatorTuning) -> np.ndarray:
    """R = diag(r_yaw, r_align) [(rad/s)^2, Nm^2]."""
    return np.diag([tuning.r_yaw, tuning.r_align]).astype(np.float64)


def continuous_matrices(vehicle: Vehicle, vx: float) -> ContinuousModel:
    """A, B, Bw, H, D (and W) of the 2-DOF model at speed ``vx`` [m/s] > 0."""
    vx = _check_speed(vx)
    p = params_vector(vehicle)
    A, B = np.empty((4, 4)), np.empty(4)
    H, D = np.empty((2, 4)), np.empty(2)
    continuous_into(p, vx, A, B, H, D)
    return ContinuousModel(A, B, np.eye(4), H, D, process_noise_density(vehicle.estimator))


def discrete_matrices(vehicle: Vehicle, vx: float, dt: float = STEP_S) -> DiscreteModel:
    """Euler-discrete Phi, E, Qd (erratum 8: Qd = Bw W Bw^T dt), H, D, R at ``vx`` [m/s], ``dt`` [s]."""
    vx = _check_speed(vx)
    p = params_vector(vehicle, dt)
    Phi, E, Qd = np.empty((4, 4)), np.empty(4), np.empty((4, 4))
    H, D = np.empty((2, 4)), np.empty(2)
    discrete_into(p, vx, Phi, E, Qd, H, D)
    return DiscreteModel(Phi, E, Qd, H, D, measurement_noise(vehicle.estimator), float(dt))


# --- steady states -----------------------------------------------------------------------------


def understeer_gradient(vehicle: Vehicle) -> float:
    """Kus [rad/(m/s^2)] with axle stiffnesses 2Cf, 2Cr: Kus = m (lr/(2Cf) - lf/(2Cr)) / L."""
    b, t = vehicle.body, vehicle.tires
    return b.mass * (b.lr / (2.0 * t.cf) - b.lf / (2.0 * t.cr)) / b.wheelbase


def yaw_rate_gain(vehicle: Vehicle, vx: float) -> float:
    """Steady-state r/delta_f [1/s] of the undisturbed model: vx / (L + Kus vx^2)."""
    vx = _check_speed(vx)
    return vx / (vehicle.body.wheelbase + understeer_gradient(vehicle) * vx * vx)


@dataclass(frozen=True)
class SteadyState:
    """A steady state of the model (SI). ``t_align`` is 2K alpha_f (paper sign) at the steering axis."""

    beta: float  # rad
    yaw_rate: float  # rad/s
    delta_f: float  # rad, road wheel
    alpha_f: float  # rad
    alpha_r: float  # rad
    t_align: float  # Nm


def _outputs(vehicle: Vehicle, vx: float, beta: float, r: float, delta_f: float) -> SteadyState:
    b, t = vehicle.body, vehicle.tires
    alpha_f = delta_f - beta - b.lf * r / vx
    alpha_r = -beta + b.lr * r / vx
    return SteadyState(beta, r, delta_f, alpha_f, alpha_r, 2.0 * t.align_rate * alpha_f)


def steady_state(
    vehicle: Vehicle, vx: float, delta_f: float, fw: float = 0.0, mw: float = 0.0
) -> SteadyState:
    """Steady state (beta_dot = r_dot = 0) at road-wheel angle ``delta_f`` [rad] under constant
    ``fw`` [N], ``mw`` [Nm], speed ``vx`` [m/s]:

        A[:2, :2] [beta, r] = -(B[:2] delta_f + [Fw/(m vx), Mw/Iz])
    """
    vx = _check_speed(vx)
    c = continuous_matrices(vehicle, vx)
    rhs = -(c.B[:2] * delta_f + c.A[:2, 2] * fw + c.A[:2, 3] * mw)
    beta, r = np.linalg.solve(c.A[:2, :2], rhs)
    return _outputs(vehicle, vx, float(beta), float(r), float(delta_f))


def straight_line_hold(vehicle: Vehicle, fw: float, mw: float) -> SteadyState:
    """The steering that holds the car straight (r = 0) against constant ``fw`` [N], ``mw`` [Nm].

    From (7)-(8) with r = 0:  2F_f = -(lr Fw + Mw)/L,  2F_r = (Mw - lf Fw)/L;  alpha = F/C;
    beta = -alpha_r;  delta_f = alpha_f - alpha_r;  T_align = 2K alpha_f (SPEC section 5). Independent
    of speed; ``t_align / N`` is the column-level holding torque (driver plus assist).
    """
    b, t = vehicle.body, vehicle.tires
    L = b.wheelbase
    two_ff = -(b.lr * fw + mw) / L
    two_fr = (mw - b.lf * fw) / L
    alpha_f = two_ff / (2.0 * t.cf)
    alpha_r = two_fr / (2.0 * t.cr)
    return SteadyState(-alpha_r, 0.0, alpha_f - alpha_r, alpha_f, alpha_r, 2.0 * t.align_rate * alpha_f)


def observability_matrix(
    vehicle: Vehicle, vx: float, dt: float = STEP_S, measurements: tuple[int, ...] = (IZ_YAW, IZ_ALIGN)
) -> np.ndarray:
    """O = [H; H Phi; H Phi^2; H Phi^3] of the discrete model using the measurement rows
    ``measurements``, columns scaled to typical magnitudes (0.01 rad, 0.01 rad/s, 1000 N, 1000 Nm)
    and rows normalised so that a rank is meaningful."""
    d = discrete_matrices(vehicle, vx, dt)
    rows, M = [], d.H[list(measurements)].copy()
    for _ in range(NX):
        rows.append(M)
        M = M @ d.Phi
    O = np.vstack(rows) @ np.diag([0.01, 0.01, 1000.0, 1000.0])
    return O / np.linalg.norm(O, axis=1, keepdims=True)


def observability_rank(
    vehicle: Vehicle,
    vx: float,
    dt: float = STEP_S,
    measurements: tuple[int, ...] = (IZ_YAW, IZ_ALIGN),
    rtol: float = 1e-9,
) -> int:
    """Rank of the (scaled) observability matrix of (Phi, H): 4 means Fw and Mw are observable."""
    s = np.linalg.svd(observability_matrix(vehicle, vx, dt, measurements), compute_uv=False)
    return int(np.sum(s > rtol * s[0]))
