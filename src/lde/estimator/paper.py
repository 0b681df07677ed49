"""THE estimator step: one numba-compiled function used by the live loop and by batch replay.

Per step k (time ``t_ns`` passed in, never read here), with inputs in SI:

0. Input corrections. The vehicle file's ``[corrections]`` (steering friction, torsion twist,
   offsets, bias: :mod:`lde.estimator.conditioning`) are removed from the raw inputs by the compiled
   :func:`lde.estimator.conditioning.condition_kernel`, in :meth:`Estimator.step` and :func:`run_batch`
   alike; none by default (the paper's estimator).
1. Validity. The ESC group (speed, yaw rate) is usable when ``esc_ok`` and the yaw rate is
   finite; the MDPS group (steering angle, column and assist torque) when ``mdps_ok`` and all
   three are finite. An unusable ESC group sets ESC_FAULT; an unusable MDPS group MDPS_FAULT and
   DEGRADED.
2. Hold. Without ESC the model cannot be scheduled (ESC carries the speed); below ``min_speed``
   (or with a non-finite speed: LOW_SPEED) the model is not used. Either way the state x and P
   are held, nothing is updated or propagated, and the outputs repeat the held estimate.
   When the filter resumes after a hold, x is kept and P is re-initialised to P0 (the held
   estimate is a good start but of unknown age), and the convergence timer restarts.
3. Update with z_k = [r, T_align], T_align = N (T_column + T_assist) (paper eq. 11; SPEC sign),
   at the model scheduled on vx_k; with an MDPS fault only the yaw-rate row is used.
4. Output the a-posteriori estimate: Fw, Mw, beta, r and T_align_hat = 2K alpha_f
   = H2 x + D2 delta_f (paper sign).
5. Propagate with delta_f,k = delta_sw,k / N at vx_k (SPEC erratum 4: the a-posteriori estimate
   is propagated). With an MDPS fault the last valid delta_f is used.

Status (IntFlag :class:`Status`, bits as in docs/ARCHITECTURE.md): NOT_CONVERGED until
``converge_time`` has passed since the filter (re)started with both measurements, i.e. after
:meth:`Estimator.reset`, after a hold, and after an MDPS fault (so it is also set while held);
VALID when none of MDPS_FAULT,
ESC_FAULT, LOW_SPEED, NOT_CONVERGED is set. SHADOW_DEVIATION and DEADLINE_MISS belong to the
service and are never set here.

The same jitted :func:`step_kernel` runs per call in :meth:`Estimator.step` and in the jitted
loop of :func:`run_batch`; they give bit-identical outputs (tested). The fixed-point backend
(``firmware_model``) offers the same ``run_batch`` signature and :class:`BatchResult`.

Cost (``bench/bench_step.py``, 2-core shared VM): an hour of steps (923,077) in about 0.5 s of
CPU time, about 4.5 us per live ``Estimator.step`` call. About half of the batch time is numba's
reference counting of the array arguments of the small kernels (a build without it measured
0.25 s); the arithmetic itself is ~280 ns per step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from lde.errors import LdeError
from lde.estimator.conditioning import condition_arrays, condition_kernel, corrections_vector, is_active
from lde.estimator.kalman import UPDATE_WS, predict_inplace, update_inplace
from lde.estimator.model import (
    P_CONV_TIME,
    P_MIN_SPEED,
    P_N,
    P_P0_BETA,
    P_P0_FW,
    P_P0_MW,
    P_P0_YAW,
    P_R_ALIGN,
    P_R_YAW,
    discrete_into,
    params_vector,
)
from lde.estimator.outputs import N_OUT, O_BETA, O_FW, O_MW, O_T_ALIGN, O_YAW
from lde.params import Vehicle
from lde.status import DEGRADED, ESC_FAULT, LOW_SPEED, MDPS_FAULT, NOT_CONVERGED, VALID, Status
from lde.units import STEP_S

_VALID, _DEGRADED, _MDPS_FAULT, _ESC_FAULT = VALID, DEGRADED, MDPS_FAULT, ESC_FAULT
_LOW_SPEED, _NOT_CONVERGED = LOW_SPEED, NOT_CONVERGED

# --- auxiliary state slots (besides x and P) ----------------------------------------------------
# float slots
F_DELTA_F = 0  #: last valid road-wheel angle delta_f [rad]
F_T_ALIGN = 1  #: last output T_align_hat [Nm]
N_FSTATE = 2
# int64 slots
I_STEPS = 0  #: steps since reset [-]
I_HELD = 1  #: 1 while the filter is held (and right after reset), else 0
I_CONV_START = 2  #: t_ns at which the filter (re)started with both measurements; -1: not running
I_UPDATES = 3  #: steps with a measurement update since reset [-]
N_ISTATE = 4
_NO_START = -1

# --- scratch workspace of the step (no allocation per step) -------------------------------------


def new_workspace() -> tuple[np.ndarray, ...]:
    """Scratch arrays for :func:`step_kernel`, a tuple (no allocation and no array views per step):
    Phi (4, 4), E (4,), Qd (4, 4), H (2, 4), D (2,), z (2,), Du (2,), R (2, 2), tmp (4, 4),
    the update's scratch (UPDATE_WS, 4, 4), use (2,) bool."""
    return (
        np.zeros((4, 4)),
        np.zeros(4),
        np.zeros((4, 4)),
        np.zeros((2, 4)),
        np.zeros(2),
        np.zeros(2),
        np.zeros(2),
        np.zeros((2, 2)),
        np.zeros((4, 4)),
        np.zeros((UPDATE_WS, 4, 4)),
        np.ones(2, dtype=np.bool_),
    )


class StepInputError(LdeError, ValueError):
    """Arrays given to :func:`run_batch` do not fit together (length, shape)."""


@dataclass
class EstimatorState:
    """The whole state of the estimator (mutable; :meth:`copy` for a snapshot).

    Attributes:
        x: [beta rad, r rad/s, Fw N, Mw Nm], the a-priori estimate for the next step.
        P: its 4x4 covariance (SI units squared).
        fs: float aux slots (``F_*``): last valid delta_f [rad], last T_align_hat [Nm].
        ints: int64 aux slots (``I_*``): steps, held flag, convergence start t_ns, updates.
    """

    x: np.ndarray
    P: np.ndarray
    fs: np.ndarray
    ints: np.ndarray

    @classmethod
    def initial(cls, params: np.ndarray) -> EstimatorState:
        """x = 0, P = diag(p0)^2, held (the first usable step starts the filter)."""
        st = cls(np.zeros(4), np.zeros((4, 4)), np.zeros(N_FSTATE), np.zeros(N_ISTATE, dtype=np.int64))
        reset_kernel(params, st.x, st.P, st.fs, st.ints)
        return st

    def copy(self) -> EstimatorState:
        return EstimatorState(self.x.copy(), self.P.copy(), self.fs.copy(), self.ints.copy())

    @property
    def steps(self) -> int:
        """Steps since reset."""
        return int(self.ints[I_STEPS])

    @property
    def held(self) -> bool:
        return bool(self.ints[I_HELD])


@dataclass(frozen=True)
class EstimatorInputs:
    """One step's inputs in SI (ISO 8855 signs; see docs/ARCHITECTURE.md)."""

    speed: float  # m/s
    steering_angle: float  # rad, steering wheel
    yaw_rate: float  # rad/s
    column_torque: float  # Nm
    assist_torque: float  # Nm, total motor torque referred to the column
    mdps_ok: bool = True  # MDPS_Sensors fresh and E2E trusted
    esc_ok: bool = True  # ESC_Motion fresh and E2E trusted
    steering_rate: float = math.nan  # rad/s, steering wheel (only the friction correction reads it)


@dataclass(frozen=True)
class EstimatorOutput:
    """One step's estimate (a-posteriori, SI). ``t_align`` has the paper's sign."""

    t_ns: int
    fw: float  # N, lateral disturbance force at the CG (left positive)
    mw: float  # Nm, disturbance yaw moment about the CG (left positive)
    t_align: float  # Nm at the steering axis, 2K alpha_f (positive resists a left steer)
    beta: float  # rad
    yaw_rate: float  # rad/s
    status: Status


@dataclass
class BatchResult:
    """Outputs of :func:`run_batch`, one row per step (numpy arrays, SI)."""

    t_ns: np.ndarray  # int64
    fw: np.ndarray  # float64, N
    mw: np.ndarray  # float64, Nm
    t_align: np.ndarray  # float64, Nm (paper sign)
    beta: np.ndarray  # float64, rad
    yaw_rate: np.ndarray  # float64, rad/s
    status: np.ndarray  # uint8, Status bits

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


# --- compiled kernels ---------------------------------------------------------------------------


@njit(cache=True, inline="always")
def _set_p0(p, P):  # pragma: no cover - compiled
    for i in range(4):
        for j in range(4):
            P[i, j] = 0.0
    P[0, 0] = p[P_P0_BETA] * p[P_P0_BETA]
    P[1, 1] = p[P_P0_YAW] * p[P_P0_YAW]
    P[2, 2] = p[P_P0_FW] * p[P_P0_FW]
    P[3, 3] = p[P_P0_MW] * p[P_P0_MW]


@njit(cache=True)
def reset_kernel(p, x, P, fs, ints):  # pragma: no cover - compiled
    """x = 0, P = P0, held; counters cleared."""
    for i in range(4):
        x[i] = 0.0
    _set_p0(p, P)
    fs[F_DELTA_F] = 0.0
    fs[F_T_ALIGN] = 0.0
    ints[I_STEPS] = 0
    ints[I_HELD] = 1
    ints[I_CONV_START] = _NO_START
    ints[I_UPDATES] = 0


@njit(cache=True, inline="always")
def step_kernel(
    p,
    x,
    P,
    fs,
    ints,
    wk,
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    mdps_ok,
    esc_ok,
    out,
):  # pragma: no cover - compiled
    """One estimator step (see the module docstring). Mutates the state, fills ``out``
    (``O_*`` slots) and returns the status bits."""
    ints[I_STEPS] += 1
    status = 0
    esc_valid = esc_ok and np.isfinite(yaw_rate)
    mdps_valid = (
        mdps_ok and np.isfinite(steering_angle) and np.isfinite(column_torque) and np.isfinite(assist_torque)
    )
    if not esc_valid:
        status |= _ESC_FAULT
    if not mdps_valid:
        status |= _MDPS_FAULT | _DEGRADED
    speed_ok = np.isfinite(speed) and speed >= p[P_MIN_SPEED]
    if esc_valid and not speed_ok:
        status |= _LOW_SPEED

    if not (esc_valid and speed_ok):
        # hold: no update, no propagation; repeat the held estimate
        ints[I_HELD] = 1
        ints[I_CONV_START] = _NO_START
        out[O_FW] = x[2]
        out[O_MW] = x[3]
        out[O_T_ALIGN] = fs[F_T_ALIGN]
        out[O_BETA] = x[0]
        out[O_YAW] = x[1]
        return status | _NOT_CONVERGED

    if ints[I_HELD] == 1:
        # (re)start after reset or a hold: keep x, re-initialise P
        _set_p0(p, P)
        ints[I_HELD] = 0

    n_ratio = p[P_N]
    delta_f = steering_angle / n_ratio if mdps_valid else fs[F_DELTA_F]

    # the model at vx_k
    Phi, E, Qd, H, D, z, Du, R, tmp, uws, use = wk
    discrete_into(p, speed, Phi, E, Qd, H, D)

    # update with z_k = [r, T_align],  T_align = N (T_column + T_assist)   (eq. 11)
    z[0] = yaw_rate
    z[1] = n_ratio * (column_torque + assist_torque) if mdps_valid else 0.0
    R[0, 0] = p[P_R_YAW]
    R[0, 1] = 0.0
    R[1, 0] = 0.0
    R[1, 1] = p[P_R_ALIGN]
    use[0] = True
    use[1] = mdps_valid
    Du[0] = D[0] * delta_f
    Du[1] = D[1] * delta_f
    update_inplace(x, P, z, H, Du, R, use, uws)
    ints[I_UPDATES] += 1

    # output the a-posteriori estimate;  T_align_hat = 2K (delta_f - beta - lf r / vx) = H2 x + D2 delta_f
    t_align = Du[1]
    for j in range(4):
        t_align += H[1, j] * x[j]
    fs[F_T_ALIGN] = t_align
    out[O_FW] = x[2]
    out[O_MW] = x[3]
    out[O_T_ALIGN] = t_align
    out[O_BETA] = x[0]
    out[O_YAW] = x[1]
    if mdps_valid:
        fs[F_DELTA_F] = delta_f

    # propagate the a-posteriori estimate with delta_f,k at vx_k   (SPEC erratum 4)
    for i in range(4):
        E[i] *= delta_f
    predict_inplace(x, P, Phi, E, Qd, tmp)

    # convergence timer: runs while both measurements are used
    if not mdps_valid:
        ints[I_CONV_START] = _NO_START
    elif ints[I_CONV_START] == _NO_START:
        ints[I_CONV_START] = t_ns
    conv_ns = p[P_CONV_TIME] * 1e9
    if ints[I_CONV_START] == _NO_START or float(t_ns - ints[I_CONV_START]) < conv_ns:
        status |= _NOT_CONVERGED
    if status == 0:
        status = _VALID
    return status


@njit(cache=True, nogil=True)  # nogil: the fixed backend runs it as a shadow in a second thread
def batch_kernel(
    p,
    x,
    P,
    fs,
    ints,
    wk,
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    mdps_ok,
    esc_ok,
    outs,
    status,
):  # pragma: no cover - compiled
    """The jitted loop: :func:`step_kernel` for every row; ``outs`` (n, N_OUT), ``status`` (n,)."""
    out = np.empty(N_OUT)
    for k in range(t_ns.shape[0]):
        s = step_kernel(
            p,
            x,
            P,
            fs,
            ints,
            wk,
            t_ns[k],
            speed[k],
            steering_angle[k],
            yaw_rate[k],
            column_torque[k],
            assist_torque[k],
            mdps_ok[k],
            esc_ok[k],
            out,
        )
        for j in range(N_OUT):
            outs[k, j] = out[j]
        status[k] = s


# --- Python API -------------------------------------------------------------------------------


def as_f64(name: str, a: object, n: int) -> np.ndarray:
    """``a`` as a contiguous float64 array of shape (n,) (StepInputError otherwise)."""
    arr = np.ascontiguousarray(a, dtype=np.float64)
    if arr.shape != (n,):
        raise StepInputError(f"{name} must have shape ({n},) like t_ns, got {arr.shape}")
    return arr


def as_bool(name: str, a: object, n: int) -> np.ndarray:
    """``a`` as a contiguous bool array of shape (n,) (StepInputError otherwise)."""
    arr = np.ascontiguousarray(a, dtype=np.bool_)
    if arr.shape != (n,):
        raise StepInputError(f"{name} must have shape ({n},) like t_ns, got {arr.shape}")
    return arr


def run_batch(
    t_ns: np.ndarray,
    speed: np.ndarray,
    steering_angle: np.ndarray,
    yaw_rate: np.ndarray,
    column_torque: np.ndarray,
    assist_torque: np.ndarray,
    mdps_ok: np.ndarray,
    esc_ok: np.ndarray,
    vehicle: Vehicle,
    *,
    state: EstimatorState | None = None,
    dt: float = STEP_S,
    steering_rate: np.ndarray | None = None,
) -> BatchResult:
    """Run the estimator over arrays of inputs on the step grid (SI, one row per step).

    Args:
        t_ns: int64 step times [ns] in the log's time base.
        speed [m/s], steering_angle [rad, steering wheel], yaw_rate [rad/s], column_torque [Nm],
        assist_torque [Nm]: float arrays of the same length.
        mdps_ok, esc_ok: bool arrays, the input group is fresh and E2E trusted.
        vehicle: parameters and tuning.
        state: continue from this state (mutated in place); default: a fresh (reset) state.
        dt: model period [s], the grid period.
        steering_rate: steering-wheel rate [rad/s] per step, for the vehicle's friction correction
            (:mod:`lde.estimator.conditioning`; the other corrections do not need it).

    Returns:
        :class:`BatchResult` with the a-posteriori estimates and status bits per step.
    """
    t = np.ascontiguousarray(t_ns, dtype=np.int64)
    if t.ndim != 1:
        raise StepInputError(f"t_ns must be 1-D, got shape {t.shape}")
    n = t.shape[0]
    angle, yaw, col = condition_arrays(
        vehicle,
        as_f64("steering_angle", steering_angle, n),
        None if steering_rate is None else as_f64("steering_rate", steering_rate, n),
        as_f64("yaw_rate", yaw_rate, n),
        as_f64("column_torque", column_torque, n),
    )
    p = params_vector(vehicle, dt)
    st = EstimatorState.initial(p) if state is None else state
    outs = np.empty((n, N_OUT))
    status = np.empty(n, dtype=np.uint8)
    batch_kernel(
        p,
        st.x,
        st.P,
        st.fs,
        st.ints,
        new_workspace(),
        t,
        as_f64("speed", speed, n),
        angle,
        yaw,
        col,
        as_f64("assist_torque", assist_torque, n),
        as_bool("mdps_ok", mdps_ok, n),
        as_bool("esc_ok", esc_ok, n),
        outs,
        status,
    )
    return BatchResult(
        t_ns=t.copy(),
        fw=outs[:, O_FW].copy(),
        mw=outs[:, O_MW].copy(),
        t_align=outs[:, O_T_ALIGN].copy(),
        beta=outs[:, O_BETA].copy(),
        yaw_rate=outs[:, O_YAW].copy(),
        status=status,
    )


class Estimator:
    """The float estimator for the live loop: ``step(t_ns, inputs)`` once per grid step.

    ``run_batch`` continues from the same state with the same compiled step.
    """

    def __init__(self, vehicle: Vehicle, dt: float = STEP_S) -> None:
        self.vehicle = vehicle
        self.dt = float(dt)
        self._p = params_vector(vehicle, self.dt)
        self._c = corrections_vector(vehicle)
        self._corrects = is_active(vehicle)
        self._out = np.empty(N_OUT)
        self._wk = new_workspace()
        self.state = EstimatorState.initial(self._p)

    def reset(self) -> None:
        """x = 0, P = P0, held until the next usable step; NOT_CONVERGED for converge_time after it."""
        st = self.state
        reset_kernel(self._p, st.x, st.P, st.fs, st.ints)

    def step(self, t_ns: int, inputs: EstimatorInputs) -> EstimatorOutput:
        """One step at time ``t_ns`` [ns]; returns the a-posteriori estimate and status.

        ``inputs`` is an :class:`EstimatorInputs` or the live receiver's
        :class:`lde.engine.receiver.InputSample` (raw inputs: the vehicle's corrections are applied here).
        """
        st, o = self.state, self._out
        angle, yaw, col = float(inputs.steering_angle), float(inputs.yaw_rate), float(inputs.column_torque)
        if self._corrects:
            rate = float(getattr(inputs, "steering_rate", math.nan))
            angle, yaw, col = condition_kernel(self._c, angle, rate, yaw, col)
        s = step_kernel(
            self._p,
            st.x,
            st.P,
            st.fs,
            st.ints,
            self._wk,
            np.int64(t_ns),
            float(inputs.speed),
            angle,
            yaw,
            col,
            float(inputs.assist_torque),
            bool(inputs.mdps_ok),
            bool(inputs.esc_ok),
            o,
        )
        return EstimatorOutput(
            int(t_ns),
            float(o[O_FW]),
            float(o[O_MW]),
            float(o[O_T_ALIGN]),
            float(o[O_BETA]),
            float(o[O_YAW]),
            Status(int(s)),
        )

    def run_batch(
        self,
        t_ns: np.ndarray,
        speed: np.ndarray,
        steering_angle: np.ndarray,
        yaw_rate: np.ndarray,
        column_torque: np.ndarray,
        assist_torque: np.ndarray,
        mdps_ok: np.ndarray,
        esc_ok: np.ndarray,
        steering_rate: np.ndarray | None = None,
    ) -> BatchResult:
        """:func:`run_batch` continuing from (and advancing) this estimator's state."""
        return run_batch(
            t_ns,
            speed,
            steering_angle,
            yaw_rate,
            column_torque,
            assist_torque,
            mdps_ok,
            esc_ok,
            self.vehicle,
            state=self.state,
            dt=self.dt,
            steering_rate=steering_rate,
        )
