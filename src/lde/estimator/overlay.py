"""Overlay torque: the feed-forward law (SPEC section 5) and its limiter state machine.

The law
-------
The whole column-level torque (driver plus boost) that holds the car straight against the
disturbance, requested from the MDPS as overlay torque so that the driver's share goes to zero.
Straight-line steady state of the 2-DOF model (paper eqs. 7-9, 12) with r = 0, beta_dot = r_dot = 0:

    alpha_f = delta_f - beta,  alpha_r = -beta                                    (9), r = 0
    0 = 2 Cf alpha_f + 2 Cr alpha_r + Fw                                          (7)
    0 = 2 lf Cf alpha_f - 2 lr Cr alpha_r + Mw                                    (8)
    => lr (7) + (8):  2 Cf alpha_f (lf + lr) = -(lr Fw + Mw)
    => 2 F_f = 2 Cf alpha_f = -(lr Fw + Mw) / L,            L = lf + lr
    T_align,ss = 2 K alpha_f = -K (lr Fw + Mw) / (Cf L)                           (12)
    T_ov = T_align,ss / N = -K (lr Fw + Mw) / (N Cf L)      [Nm at the column, left positive]

``T_align`` has the paper's sign (positive resists a left steer) and in steady state equals
``N (T_column + T_assist)``: the column torque that holds the wheel is ``T_align / N``. Sign check:
``Fw > 0`` pushes the car left, the car must be steered right (``alpha_f < 0``), the holding torque
is negative (right). The law is independent of speed and of the moment's reference point
(``lr Fw + Mw`` is the moment about the rear axle). It is *not* computed from the driver's torque:
the boost already multiplies that.

The limiter
-----------
A state machine (values as ``LDE_Overlay.State`` in ``dbc/lde.dbc``):

    OFF(0) --ok for rearm_delay (and past the override hold-off)--> RAMP_IN(1)
    RAMP_IN(1) --output reached the (clipped) demand--> ACTIVE(2)
    RAMP_IN/ACTIVE --any disengage condition--> RAMP_OUT(3) --output reached 0--> OFF(0)
    RAMP_OUT --ok again for rearm_delay (and past the hold-off)--> RAMP_IN
    any --input fault for fault_persist--> FAULT(4) --fault clear for fault_recover and output 0--> OFF

In every state the output moves toward its target by at most ``max_rate * dt`` per step and stays
within ``|T| <= max_torque``: ramp-in and ramp-out are rate limited, never a step. The target is the
clipped law in RAMP_IN/ACTIVE and 0 otherwise, so from any output a disengagement reaches zero within
``max_torque / max_rate`` seconds.

Disengage conditions (each ramps to zero):

* input fault: ``Status`` MDPS_FAULT, ESC_FAULT (stale or E2E-rejected inputs) or SHADOW_DEVIATION,
  or any non-finite input (Fw, Mw, speed, steering angle, column torque). Lasting ``fault_persist``
  it becomes the FAULT state;
* estimator not ready: VALID clear, NOT_CONVERGED or LOW_SPEED set;
* speed outside ``[min_speed, max_speed]`` (inclusive);
* steering-wheel angle ``|delta_sw| > max_steering_angle``;
* driver override: the driver's column torque outside what the disturbance explains by more than
  ``thr = driver_override_torque``: along the demand's direction ``s``, ``s T_column < -thr``
  (steering against the overlay) or ``s T_column > |T_demand| + thr`` (more than the whole holding
  torque); without a demand ``|T_column| > thr``. A driver who holds *with* the overlay (it is
  clipped at ``max_torque``; the driver holds the rest) is not overriding. Re-engaging waits
  ``hold_off`` after the last overriding step (and then ``rearm_delay`` of all conditions ok);
* ``enable`` false (the service's shutdown ramp-out, or the overlay switched off).

DEGRADED alone does not disengage (the estimate is usable); DEADLINE_MISS is the service's own bit.

Time is passed in (``t_ns``); ``dt`` is the difference to the previous call, clamped to
``[0, dt_max]`` so that a gap in the calls (or time going backwards) can never allow a larger step.
The per-step logic exists once, :func:`overlay_kernel` (numba), used by :class:`OverlayLimiter` in
the live loop and by :func:`run_batch_overlay` in replay (lockstep-tested).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from lde.errors import ConfigError
from lde.params import OverlayLimits, Vehicle
from lde.status import ESC_FAULT, FAULT_BITS, MDPS_FAULT, NOT_READY_BITS, VALID

__all__ = [
    "OverlayState",
    "OverlayTiming",
    "OverlayOutput",
    "OverlayLimiter",
    "feedforward_gain",
    "feedforward_torque",
    "limiter_params",
    "new_limiter_state",
    "overlay_kernel",
    "run_batch_overlay",
    "FAULT_BITS",
    "NOT_READY_BITS",
]


# state codes as plain ints for the compiled kernel (numba constants); OverlayState names them
ST_OFF, ST_RAMP_IN, ST_ACTIVE, ST_RAMP_OUT, ST_FAULT = 0, 1, 2, 3, 4


class OverlayState(enum.IntEnum):
    """``LDE_Overlay.State`` (dbc/lde.dbc VAL_ table)."""

    OFF = ST_OFF
    RAMP_IN = ST_RAMP_IN
    ACTIVE = ST_ACTIVE
    RAMP_OUT = ST_RAMP_OUT
    FAULT = ST_FAULT


_VALID_BIT = VALID


@dataclass(frozen=True)
class OverlayTiming:
    """Timing of the limiter state machine (not in the vehicle file yet; defaults documented here).

    Attributes:
        hold_off: after the last step with a driver override, wait this long before re-engaging [s].
        rearm_delay: all engage conditions must hold this long before (re-)engaging [s].
        fault_persist: an input fault lasting this long enters FAULT [s].
        fault_recover: FAULT is left after the input fault has been clear this long [s].
        dt_max: the largest time step the rate limit is applied with [s] (gaps are clamped).
    """

    hold_off: float = 1.0
    rearm_delay: float = 0.2
    fault_persist: float = 0.5
    fault_recover: float = 1.0
    dt_max: float = 0.05

    def __post_init__(self) -> None:
        for name in ("hold_off", "rearm_delay", "fault_persist", "fault_recover"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ConfigError(f"overlay timing {name} must be finite and >= 0, got {v!r}")
        if not (math.isfinite(self.dt_max) and self.dt_max > 0.0):
            raise ConfigError(f"overlay timing dt_max must be finite and > 0, got {self.dt_max!r}")


# --- the law ------------------------------------------------------------------------------------


def feedforward_gain(vehicle: Vehicle) -> float:
    """g = K / (N Cf L) [Nm at the column per (N m)], so that T_ov = -g (lr Fw + Mw)."""
    b, t = vehicle.body, vehicle.tires
    return t.align_rate / (vehicle.steering.ratio * t.cf * b.wheelbase)


def feedforward_torque(vehicle: Vehicle, fw: float | np.ndarray, mw: float | np.ndarray) -> Any:
    """The unlimited holding torque at the column [Nm, left positive] for Fw [N] and Mw [Nm].

    T_ov = -K (lr Fw + Mw) / (N Cf L)   (module docstring derivation)
    """
    return -feedforward_gain(vehicle) * (vehicle.body.lr * fw + mw)


# --- flat parameter vector and state arrays for the compiled kernel -----------------------------

LP_GAIN, LP_LR, LP_MAX_T, LP_MAX_RATE, LP_MIN_V, LP_MAX_V, LP_MAX_STEER, LP_OVERRIDE = range(8)
LP_HOLD_OFF_NS, LP_REARM_NS, LP_FAULT_PERSIST_NS, LP_FAULT_RECOVER_NS, LP_DT_MAX = range(8, 13)
LP_LAW_TAU = 13  # time constant of the law's input low-pass [s] (0: none)
LP_ALLOWED = 14  # ALLOWED_* below: whether the overlay may engage
#: LP_ALLOWED: never (a torque whose unit to Nm cannot be learned), always, once the estimator's learner
#: reports "learned" (a torque of unknown scale whose factor to the other, in Nm, is learned)
ALLOWED_NEVER, ALLOWED_ALWAYS, ALLOWED_ONCE_LEARNED = 0, 1, 2
N_LP = 15

# int64 state slots (times in ns; -1 = "not set")
LS_STATE = 0  # OverlayState
LS_LAST_T = 1  # t_ns of the previous call
LS_HAVE_T = 2  # 1 once a call has been made
LS_OK_SINCE = 3  # start of the current run of "all engage conditions ok", -1 if not ok
LS_OVERRIDE_UNTIL = 4  # no engaging before this time (driver override hold-off)
LS_FAULT_SINCE = 5  # start of the current input fault, -1 if none
LS_CLEAR_SINCE = 6  # start of the current fault-free run, -1 while faulted
N_LS = 7
# float64 state slots
LF_TORQUE = 0  # output torque of the previous step [Nm]
LF_DEMAND = 1  # law output of the previous step, before clipping [Nm] (diagnostics)
LF_MOMENT = 2  # low-passed law input lr Fw + Mw [Nm]; NaN until the first usable estimate
N_LF = 3


def _timing_from(limits: OverlayLimits, timing: OverlayTiming | None) -> OverlayTiming:
    if timing is not None:
        return timing
    # the vehicle file may carry these one day (params.OverlayLimits); fall back to the defaults
    d = OverlayTiming()
    return OverlayTiming(
        hold_off=float(getattr(limits, "hold_off", d.hold_off)),
        rearm_delay=float(getattr(limits, "rearm_delay", d.rearm_delay)),
        fault_persist=float(getattr(limits, "fault_persist", d.fault_persist)),
        fault_recover=float(getattr(limits, "fault_recover", d.fault_recover)),
        dt_max=d.dt_max,
    )


def limiter_params(
    vehicle: Vehicle, timing: OverlayTiming | None = None, allowed: int = ALLOWED_ALWAYS
) -> np.ndarray:
    """The kernel's float64 parameter vector (layout ``LP_*``) from a vehicle (SI); ``allowed``
    (``ALLOWED_*``): when the engine may enable the overlay (``LP_ALLOWED``)."""
    if not isinstance(vehicle, Vehicle):
        raise ConfigError(
            "the overlay needs the whole Vehicle (the law uses K, N, Cf, lf, lr; the limits come "
            f"from vehicle.overlay), got {type(vehicle).__name__}"
        )
    o = vehicle.overlay
    tm = _timing_from(o, timing)
    p = np.empty(N_LP, dtype=np.float64)
    p[LP_GAIN] = feedforward_gain(vehicle)
    p[LP_LR] = vehicle.body.lr
    p[LP_MAX_T] = o.max_torque
    p[LP_MAX_RATE] = o.max_rate
    p[LP_MIN_V] = o.min_speed
    p[LP_MAX_V] = o.max_speed
    p[LP_MAX_STEER] = o.max_steering_angle
    p[LP_OVERRIDE] = o.driver_override_torque
    p[LP_HOLD_OFF_NS] = round(tm.hold_off * 1e9)
    p[LP_REARM_NS] = round(tm.rearm_delay * 1e9)
    p[LP_FAULT_PERSIST_NS] = round(tm.fault_persist * 1e9)
    p[LP_FAULT_RECOVER_NS] = round(tm.fault_recover * 1e9)
    p[LP_DT_MAX] = tm.dt_max
    p[LP_LAW_TAU] = o.law_time
    p[LP_ALLOWED] = float(allowed)
    return p


def new_limiter_state() -> tuple[np.ndarray, np.ndarray]:
    """Fresh (int64 slots ``LS_*``, float64 slots ``LF_*``): OFF, zero torque, no history."""
    si = np.full(N_LS, -1, dtype=np.int64)
    si[LS_STATE] = ST_OFF
    si[LS_HAVE_T] = 0
    si[LS_LAST_T] = 0
    si[LS_OVERRIDE_UNTIL] = np.iinfo(np.int64).min
    sf = np.zeros(N_LF, dtype=np.float64)
    sf[LF_MOMENT] = np.nan
    return si, sf


# --- the one per-step function ------------------------------------------------------------------


@njit(cache=True, inline="always")
def overlay_kernel(p, si, sf, t_ns, fw, mw, status, speed, steer, col_tq, enable):  # pragma: no cover
    """One limiter step at ``t_ns`` [ns]; updates ``si``/``sf`` in place, returns the torque [Nm].

    Inputs: fw [N], mw [Nm], status (``LDE_Estimate.Status`` bits), speed [m/s], steer
    (steering-wheel angle) [rad], col_tq (driver column torque) [Nm], enable (bool).
    """
    # dt from the passed-in time, clamped to [0, dt_max]
    if si[LS_HAVE_T] == 0:
        dt = 0.0
        si[LS_HAVE_T] = 1
        si[LS_LAST_T] = t_ns
    elif t_ns > si[LS_LAST_T]:
        dt = min((t_ns - si[LS_LAST_T]) * 1e-9, p[LP_DT_MAX])
        si[LS_LAST_T] = t_ns
    else:
        dt = 0.0  # repeated or backwards time: no change allowed

    # T_ov = -K (lr Fw + Mw) / (N Cf L) = -g (lr Fw + Mw), on the low-passed moment lr Fw + Mw
    moment = p[LP_LR] * fw + mw
    finite = math.isfinite(moment) and math.isfinite(speed) and math.isfinite(steer) and math.isfinite(col_tq)
    input_fault = (not finite) or (status & FAULT_BITS) != 0
    not_ready = (status & _VALID_BIT) == 0 or (status & NOT_READY_BITS) != 0
    if math.isfinite(moment):
        # the law holds in steady state only; above ~1 Hz the overlay is carried by the steering's
        # friction and inertia, which the filter reads as disturbance with a loop gain of +1
        # (docs/design/overlay.md): backward Euler, exact restart on an unusable estimate
        m_f = sf[LF_MOMENT]
        if input_fault or not_ready or not math.isfinite(m_f) or p[LP_LAW_TAU] <= 0.0:
            m_f = moment
        else:
            m_f += dt / (p[LP_LAW_TAU] + dt) * (moment - m_f)
        sf[LF_MOMENT] = m_f
        demand = -p[LP_GAIN] * m_f
    else:
        demand = -p[LP_GAIN] * moment
    sf[LF_DEMAND] = demand
    # driver override: the driver's torque outside what the disturbance explains. In the demand's
    # direction the driver may hold anything from 0 up to the whole holding torque |demand| (the
    # overlay is clipped, the driver holds the rest), so the band is [-thr, |demand| + thr] along
    # that direction, [-thr, thr] without a demand.
    thr = p[LP_OVERRIDE]
    lo = -thr
    hi = thr
    if demand > 0.0:
        hi = demand + thr
    elif demand < 0.0:
        lo = demand - thr
    override = finite and (col_tq < lo or col_tq > hi)
    in_window = finite and speed >= p[LP_MIN_V] and speed <= p[LP_MAX_V] and abs(steer) <= p[LP_MAX_STEER]
    if override:
        si[LS_OVERRIDE_UNTIL] = t_ns + np.int64(p[LP_HOLD_OFF_NS])
    ok = enable and (not input_fault) and (not not_ready) and in_window and (not override)
    if not ok:
        si[LS_OK_SINCE] = -1
    elif si[LS_OK_SINCE] < 0:
        si[LS_OK_SINCE] = t_ns
    if input_fault:
        if si[LS_FAULT_SINCE] < 0:
            si[LS_FAULT_SINCE] = t_ns
        si[LS_CLEAR_SINCE] = -1
    else:
        si[LS_FAULT_SINCE] = -1
        if si[LS_CLEAR_SINCE] < 0:
            si[LS_CLEAR_SINCE] = t_ns

    state = si[LS_STATE]
    torque = sf[LF_TORQUE]
    go = False
    if state == ST_FAULT:  # ramp to zero; leave after fault_recover fault-free (and at zero)
        if (
            not input_fault
            and t_ns - si[LS_CLEAR_SINCE] >= np.int64(p[LP_FAULT_RECOVER_NS])
            and torque == 0.0
        ):
            state = ST_OFF
    elif input_fault and t_ns - si[LS_FAULT_SINCE] >= np.int64(p[LP_FAULT_PERSIST_NS]):
        state = ST_FAULT
    else:
        engaged = state in (ST_RAMP_IN, ST_ACTIVE)
        go = ok and (
            engaged or (t_ns >= si[LS_OVERRIDE_UNTIL] and t_ns - si[LS_OK_SINCE] >= np.int64(p[LP_REARM_NS]))
        )

    # target: the clipped law while engaged, else zero;  |T| <= max_torque
    target = 0.0
    if go:
        target = min(max(demand, -p[LP_MAX_T]), p[LP_MAX_T])
    # rate limit: |T_k - T_k-1| <= max_rate * dt
    lim = p[LP_MAX_RATE] * dt
    diff = target - torque
    if abs(diff) <= lim:
        torque = target
    elif diff > 0.0:
        torque = torque + lim
    else:
        torque = torque - lim
    torque = min(max(torque, -p[LP_MAX_T]), p[LP_MAX_T])

    if state != ST_FAULT:
        if go:
            if state != ST_ACTIVE:
                state = ST_ACTIVE if torque == target else ST_RAMP_IN
        else:
            state = ST_OFF if torque == 0.0 else ST_RAMP_OUT
    si[LS_STATE] = state
    sf[LF_TORQUE] = torque
    return torque


@njit(cache=True)
def _batch_kernel(
    p, si, sf, t_ns, fw, mw, status, speed, steer, col_tq, enable, out_t, out_state
):  # pragma: no cover
    for k in range(t_ns.shape[0]):
        out_t[k] = overlay_kernel(
            p, si, sf, t_ns[k], fw[k], mw[k], status[k], speed[k], steer[k], col_tq[k], enable[k]
        )
        out_state[k] = si[LS_STATE]


# --- live wrapper -------------------------------------------------------------------------------


@dataclass(frozen=True)
class OverlayOutput:
    """One limiter step's result.

    Attributes:
        torque: overlay torque request at the column [Nm], left positive (limited).
        active: ``LDE_Overlay.Active``: True in RAMP_IN and ACTIVE.
        state: the limiter state after this step.
        demand: the unlimited law output of this step [Nm] (diagnostics; NaN for bad inputs).
    """

    torque: float
    active: bool
    state: OverlayState
    demand: float


def _is_active(state: int) -> bool:
    return state == OverlayState.RAMP_IN or state == OverlayState.ACTIVE


class OverlayLimiter:
    """The overlay law + limiter for the live loop (the same kernel as :func:`run_batch_overlay`).

    Args:
        vehicle: the :class:`~lde.params.Vehicle` (law parameters and ``vehicle.overlay`` limits).
        timing: state-machine timing; default :class:`OverlayTiming`.
    """

    def __init__(self, vehicle: Vehicle, timing: OverlayTiming | None = None) -> None:
        self.params = limiter_params(vehicle, timing)
        self.limits = vehicle.overlay
        self.reset()

    def reset(self) -> None:
        """Back to OFF with zero torque and no history."""
        self._si, self._sf = new_limiter_state()

    @property
    def state(self) -> OverlayState:
        return OverlayState(int(self._si[LS_STATE]))

    @property
    def torque(self) -> float:
        """The last output [Nm]."""
        return float(self._sf[LF_TORQUE])

    def step_values(
        self,
        t_ns: int,
        fw: float,
        mw: float,
        status: int,
        speed: float,
        steering_angle: float,
        column_torque: float,
        enable: bool = True,
    ) -> OverlayOutput:
        """One step from plain values (SI; see :func:`overlay_kernel`)."""
        t = overlay_kernel(
            self.params,
            self._si,
            self._sf,
            np.int64(t_ns),
            float(fw),
            float(mw),
            np.int64(int(status) & 0xFF),
            float(speed),
            float(steering_angle),
            float(column_torque),
            bool(enable),
        )
        st = int(self._si[LS_STATE])
        return OverlayOutput(float(t), _is_active(st), OverlayState(st), float(self._sf[LF_DEMAND]))

    def step(self, t_ns: int, est: Any, inputs: Any, enable: bool = True) -> OverlayOutput:
        """One step from an estimator output (``.fw``, ``.mw``, ``.status``) and the sampled inputs
        (``.speed``, ``.steering_angle``, ``.column_torque``; ``.mdps_ok``/``.esc_ok`` false add
        MDPS_FAULT/ESC_FAULT: a stale or untrusted input ramps out even if the estimator held)."""
        status = int(est.status)
        if not getattr(inputs, "mdps_ok", True):
            status |= MDPS_FAULT
        if not getattr(inputs, "esc_ok", True):
            status |= ESC_FAULT
        return self.step_values(
            t_ns, est.fw, est.mw, status, inputs.speed, inputs.steering_angle, inputs.column_torque, enable
        )


# --- batch (replay) -----------------------------------------------------------------------------


def _col(name: str, a: Any, n: int, dtype: Any) -> np.ndarray:
    arr = np.ascontiguousarray(np.asarray(a), dtype=dtype)
    if arr.shape != (n,):
        raise ConfigError(f"run_batch_overlay: {name} has shape {arr.shape}, expected ({n},)")
    return arr


def run_batch_overlay(
    t_ns: Any,
    Fw: Any,
    Mw: Any,
    status: Any,
    speed: Any,
    steering_angle: Any,
    column_torque: Any,
    vehicle: Vehicle,
    enable: Any = None,
    timing: OverlayTiming | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The limiter over whole columns (replay), the same kernel as :class:`OverlayLimiter`.

    Args: equal-length 1-D arrays: t_ns [ns] (int64), Fw [N], Mw [Nm], status (Status bits),
    speed [m/s], steering_angle [rad, steering wheel], column_torque [Nm]; enable (bool, default
    all True); the vehicle.

    Returns:
        (T_overlay [Nm] float64, active bool, state uint8), one row per step.
    """
    t = np.ascontiguousarray(np.asarray(t_ns), dtype=np.int64)
    if t.ndim != 1:
        raise ConfigError(f"run_batch_overlay: t_ns must be 1-D, got shape {t.shape}")
    n = t.shape[0]
    en = np.ones(n, dtype=np.bool_) if enable is None else _col("enable", enable, n, np.bool_)
    p = limiter_params(vehicle, timing)
    si, sf = new_limiter_state()
    out_t = np.empty(n, dtype=np.float64)
    out_state = np.empty(n, dtype=np.int64)
    _batch_kernel(
        p,
        si,
        sf,
        t,
        _col("Fw", Fw, n, np.float64),
        _col("Mw", Mw, n, np.float64),
        _col("status", status, n, np.int64) & 0xFF,
        _col("speed", speed, n, np.float64),
        _col("steering_angle", steering_angle, n, np.float64),
        _col("column_torque", column_torque, n, np.float64),
        en,
        out_t,
        out_state,
    )
    state = out_state.astype(np.uint8)
    active = (state == OverlayState.RAMP_IN) | (state == OverlayState.ACTIVE)
    return out_t, active, state
