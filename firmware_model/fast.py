"""The compiled integer twin of :mod:`firmware_model.step` (numba on int64 arrays) and the
fixed-point backend API: :func:`run_batch` and :class:`FixedEstimator`.

Every function here repeats, line for line, the reference in :mod:`firmware_model.step` and
:mod:`firmware_model.qformat` with int64 arrays instead of Python ints; the arithmetic is written
so that no intermediate exceeds int64 (so numba's wrapping int64 and Python's unbounded ints give
the same integers). ``tests/test_firmware_lockstep.py`` runs both on the same inputs and requires
bit-identical states, outputs and saturation counters at every step.

Layouts (int64 arrays):

- ``tv`` constants, ``T_*`` slots (:func:`tables_vector`); ``coef`` (N_COEF, 3, 2): (raw, shift).
- state: ``x`` (4,), ``P`` (16,) row-major, ``aux`` (``A_*`` slots), ``sat`` (N_SAT,).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass, replace

import numpy as np
from numba import njit

from lde.estimator.conditioning import (
    condition_arrays,
    condition_kernel,
    corrections_vector,
    is_active,
    without_corrections,
)
from lde.estimator.model import params_vector
from lde.estimator.paper import (
    BatchResult,
    Estimator,
    EstimatorInputs,
    EstimatorOutput,
    EstimatorState,
    Status,
    StepInputError,
    as_bool,
    as_f64,
)
from lde.estimator.paper import run_batch as float_run_batch
from lde.params import Vehicle
from lde.units import STEP_S

from .shadow import ShadowChecker, ShadowReport, shadow_check
from .step import (
    IN_SPEED_NAN,
    IN_SPEED_SAT,
    IN_STEER_BAD,
    IN_TORQUE_BAD,
    IN_YAW_BAD,
    N_SAT,
    S_ACC64,
    S_COEF,
    S_COV,
    S_GAIN,
    S_IN_SPEED,
    S_IN_STEER,
    S_IN_TORQUE,
    S_IN_YAW,
    S_INNOV,
    S_P_FLOOR,
    S_S_NONPOS,
    S_SPEED_CLAMP,
    S_T_ALIGN,
    S_X0,
    SAT_NAMES,
)
from .tables import (
    C_D1,
    C_E0,
    C_E1,
    C_H10,
    C_H11,
    C_PHI00,
    C_PHI01,
    C_PHI02,
    C_PHI10,
    C_PHI11,
    C_PHI13,
    N_COEF,
    FixedTables,
    tables_for,
)

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1

# --- constants vector layout ------------------------------------------------------------------
(
    T_F_STATE,
    T_F_COV,
    T_F_SPEED,
    T_F_STEER,
    T_F_TORQUE,
    T_F_W,
    T_F_GAIN,
    T_F_PHI,
    T_F_E,
    T_F_H,
    T_F_D,
    T_V_MIN,
    T_V_MAX,
    T_N_RAW,
    T_N_FRAC,
    T_R0,
    T_R1,
    T_QD0,
    T_P00,
    T_CONV_NS,
    T_F_YAW,
) = (0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 21, 25, 26)
N_T = 27

# --- aux state slots --------------------------------------------------------------------------
A_DELTA, A_T_ALIGN, A_STEPS, A_HELD, A_CONV_START, A_UPDATES = range(6)
N_AUX = 6
_NO_START = -1

_VALID, _DEGRADED, _MDPS_FAULT, _ESC_FAULT, _LOW_SPEED, _NOT_CONVERGED = 1, 2, 4, 8, 16, 32

# output slots of the batch kernel: normalised raw X_beta, X_r, X_Fw, X_Mw, T_align_hat
O_XB, O_XR, O_XF, O_XM, O_TA = range(5)
N_OUT = 5


def tables_vector(tb: FixedTables) -> np.ndarray:
    """The scalar constants of ``tb`` as an int64 vector (``T_*`` layout)."""
    tv = np.zeros(N_T, dtype=np.int64)
    tv[T_F_STATE], tv[T_F_COV], tv[T_F_SPEED], tv[T_F_STEER] = tb.f_state, tb.f_cov, tb.f_speed, tb.f_steer
    tv[T_F_TORQUE], tv[T_F_W], tv[T_F_GAIN] = tb.f_torque, tb.f_w, tb.f_gain
    tv[T_F_PHI], tv[T_F_E], tv[T_F_H], tv[T_F_D] = tb.f_phi, tb.f_e, tb.f_h, tb.f_d
    tv[T_V_MIN], tv[T_V_MAX] = tb.v_min_raw, tb.v_max_raw
    tv[T_N_RAW], tv[T_N_FRAC] = tb.n_over_st
    tv[T_R0], tv[T_R1] = tb.r_n
    tv[T_QD0 : T_QD0 + 4] = tb.qd_n
    tv[T_P00 : T_P00 + 4] = tb.p0_n
    tv[T_CONV_NS] = tb.converge_ns
    tv[T_F_YAW] = tb.yaw_input_frac()
    return tv


# --- arithmetic (the twins of qformat / step helpers) -----------------------------------------


@njit(cache=True)
def shift_round(value, s):  # pragma: no cover - compiled
    if s > 0:
        return (value >> s) + ((value >> (s - 1)) & 1)
    return value << (-s)


@njit(cache=True)
def div_round(num, den):  # pragma: no cover - compiled
    a = -num if num < 0 else num
    q = a // den
    r = a - q * den
    if r >= den - r:
        q += 1
    return -q if num < 0 else q


@njit(cache=True)
def sat32(sat, v, slot):  # pragma: no cover - compiled
    if v > INT32_MAX:
        sat[slot] += 1
        return INT32_MAX
    if v < INT32_MIN:
        sat[slot] += 1
        return INT32_MIN
    return v


@njit(cache=True)
def add64(sat, a, b):  # pragma: no cover - compiled
    if b > 0 and a > INT64_MAX - b:
        sat[S_ACC64] += 1
        return INT64_MAX
    if b < 0 and a < INT64_MIN - b:
        sat[S_ACC64] += 1
        return INT64_MIN
    return a + b


@njit(cache=True)
def mac(sat, acc, a, b):  # pragma: no cover - compiled
    return add64(sat, acc, a * b)


# --- the step ---------------------------------------------------------------------------------


@njit(cache=True)
def reset_kernel(tv, x, P, aux, sat):  # pragma: no cover - compiled
    for i in range(4):
        x[i] = 0
    _set_p0(tv, P)
    aux[A_DELTA] = 0
    aux[A_T_ALIGN] = 0
    aux[A_STEPS] = 0
    aux[A_HELD] = 1
    aux[A_CONV_START] = _NO_START
    aux[A_UPDATES] = 0
    for k in range(sat.shape[0]):
        sat[k] = 0


@njit(cache=True)
def _set_p0(tv, P):  # pragma: no cover - compiled
    for k in range(16):
        P[k] = 0
    for i in range(4):
        P[5 * i] = tv[T_P00 + i]


@njit(cache=True)
def schedule(tv, coef, sat, v, c):  # pragma: no cover - compiled
    w = div_round(np.int64(1) << (tv[T_F_SPEED] + tv[T_F_W]), v)
    w2 = shift_round(w * w, tv[T_F_W])
    for k in range(N_COEF):
        acc = np.int64(0)
        for j in range(3):
            raw = coef[k, j, 0]
            if raw != 0:
                wp = np.int64(1) if j == 0 else (w if j == 1 else w2)
                acc = add64(sat, acc, shift_round(raw * wp, coef[k, j, 1]))
        c[k] = sat32(sat, acc, S_COEF)


@njit(cache=True)
def _scalar_update(tv, x, P, sat, h0, h1, unit_row, z, dterm, r, ph, g):  # pragma: no cover - compiled
    fh = tv[T_F_H]
    fg = tv[T_F_GAIN]
    if unit_row:
        for i in range(4):
            ph[i] = P[4 * i + 1]
        s = add64(sat, ph[1], r)
        hx = x[1]
    else:
        for i in range(4):
            acc = mac(sat, mac(sat, np.int64(0), P[4 * i], h0), P[4 * i + 1], h1)
            ph[i] = sat32(sat, shift_round(acc, fh), S_COV)
        acc = mac(sat, mac(sat, np.int64(0), h0, ph[0]), h1, ph[1])
        s = add64(sat, shift_round(acc, fh), r)
        hx = shift_round(mac(sat, mac(sat, np.int64(0), h0, x[0]), h1, x[1]), fh)
    if s <= 0:
        sat[S_S_NONPOS] += 1
        return
    innov = sat32(sat, z - hx - dterm, S_INNOV)
    for i in range(4):
        g[i] = sat32(sat, div_round(ph[i] << fg, s), S_GAIN)
    for i in range(4):
        x[i] = sat32(sat, x[i] + shift_round(g[i] * innov, fg), S_X0 + i)
    for i in range(4):
        for j in range(i, 4):
            v = sat32(sat, P[4 * i + j] - shift_round(g[i] * ph[j], fg), S_COV)
            P[4 * i + j] = v
            P[4 * j + i] = v
        if P[5 * i] < 0:
            P[5 * i] = 0
            sat[S_P_FLOOR] += 1


@njit(cache=True)
def _predict(tv, x, P, sat, c, delta, T, rk, ra):  # pragma: no cover - compiled
    fp = tv[T_F_PHI]
    sh_e = tv[T_F_E] + tv[T_F_STEER] - tv[T_F_STATE]
    # Phi_n rows 0 and 1 as (column, coefficient) pairs
    rk[0, 0], rk[0, 1], rk[0, 2] = 0, 1, 2
    rk[1, 0], rk[1, 1], rk[1, 2] = 0, 1, 3
    ra[0, 0], ra[0, 1], ra[0, 2] = c[C_PHI00], c[C_PHI01], c[C_PHI02]
    ra[1, 0], ra[1, 1], ra[1, 2] = c[C_PHI10], c[C_PHI11], c[C_PHI13]
    x0, x1, x2, x3 = x[0], x[1], x[2], x[3]
    for i in range(2):
        acc = np.int64(0)
        for m in range(3):
            k = rk[i, m]
            xk = x0 if k == 0 else (x1 if k == 1 else (x2 if k == 2 else x3))
            acc = mac(sat, acc, ra[i, m], xk)
        e = c[C_E0] if i == 0 else c[C_E1]
        x[i] = sat32(sat, shift_round(acc, fp) + shift_round(e * delta, sh_e), S_X0 + i)
    for k in range(16):
        T[k] = P[k]
    for i in range(2):
        for j in range(4):
            acc = np.int64(0)
            for m in range(3):
                acc = mac(sat, acc, ra[i, m], P[4 * rk[i, m] + j])
            T[4 * i + j] = sat32(sat, shift_round(acc, fp), S_COV)
    for i in range(4):
        for j in range(i, 4):
            if j < 2:
                acc = np.int64(0)
                for m in range(3):
                    acc = mac(sat, acc, T[4 * i + rk[j, m]], ra[j, m])
                v = shift_round(acc, fp)
            else:
                v = T[4 * i + j]
            if i == j:
                v += tv[T_QD0 + i]
            v = sat32(sat, v, S_COV)
            P[4 * i + j] = v
            P[4 * j + i] = v


@njit(cache=True)
def step_kernel(
    tv, coef, x, P, aux, sat, ws, t_ns, v, steer, yaw, tcol, tas, in_flags, mdps_ok, esc_ok, out
):  # pragma: no cover - compiled
    """The twin of :func:`firmware_model.step.step_raw`; fills ``out`` (O_* slots), returns status.
    ``ws`` is an int64 scratch (4, 16)."""
    aux[A_STEPS] += 1
    status = 0
    if in_flags & (IN_SPEED_NAN | IN_SPEED_SAT):
        sat[S_IN_SPEED] += 1
    if in_flags & IN_STEER_BAD:
        sat[S_IN_STEER] += 1
    if in_flags & IN_YAW_BAD:
        sat[S_IN_YAW] += 1
    if in_flags & IN_TORQUE_BAD:
        sat[S_IN_TORQUE] += 1
    sat_before = np.int64(0)
    for k in range(sat.shape[0]):
        sat_before += sat[k]
    esc_valid = esc_ok and (in_flags & IN_YAW_BAD) == 0
    mdps_valid = mdps_ok and (in_flags & (IN_STEER_BAD | IN_TORQUE_BAD)) == 0
    if not esc_valid:
        status |= _ESC_FAULT
    if not mdps_valid:
        status |= _MDPS_FAULT | _DEGRADED
    speed_ok = (in_flags & IN_SPEED_NAN) == 0 and v >= tv[T_V_MIN]
    if esc_valid and not speed_ok:
        status |= _LOW_SPEED

    if not (esc_valid and speed_ok):
        aux[A_HELD] = 1
        aux[A_CONV_START] = _NO_START
        for i in range(4):
            out[i] = x[i]
        out[O_TA] = aux[A_T_ALIGN]
        sat_after = np.int64(0)
        for k in range(sat.shape[0]):
            sat_after += sat[k]
        if sat_after != sat_before:
            status |= _DEGRADED
        return status | _NOT_CONVERGED

    if aux[A_HELD] == 1:
        _set_p0(tv, P)
        aux[A_HELD] = 0

    delta = steer if mdps_valid else aux[A_DELTA]
    if v > tv[T_V_MAX]:
        sat[S_SPEED_CLAMP] += 1
        v = tv[T_V_MAX]
    c = ws[0]
    schedule(tv, coef, sat, v, c)

    ph, g = ws[1, 0:4], ws[1, 4:8]
    _scalar_update(tv, x, P, sat, np.int64(0), np.int64(0), True, yaw, np.int64(0), tv[T_R0], ph, g)
    dterm = shift_round(c[C_D1] * delta, tv[T_F_D] + tv[T_F_STEER] - tv[T_F_STATE])
    if mdps_valid:
        tsum = sat32(sat, tcol + tas, S_IN_TORQUE)
        z_t = sat32(
            sat, shift_round(tv[T_N_RAW] * tsum, tv[T_N_FRAC] + tv[T_F_TORQUE] - tv[T_F_STATE]), S_INNOV
        )
        _scalar_update(tv, x, P, sat, c[C_H10], c[C_H11], False, z_t, dterm, tv[T_R1], ph, g)
    aux[A_UPDATES] += 1

    hx = shift_round(mac(sat, mac(sat, np.int64(0), c[C_H10], x[0]), c[C_H11], x[1]), tv[T_F_H])
    aux[A_T_ALIGN] = sat32(sat, hx + dterm, S_T_ALIGN)
    for i in range(4):
        out[i] = x[i]
    out[O_TA] = aux[A_T_ALIGN]
    if mdps_valid:
        aux[A_DELTA] = steer

    rk = ws[2, 0:8].reshape((2, 4))
    ra = ws[2, 8:16].reshape((2, 4))
    _predict(tv, x, P, sat, c, delta, ws[3], rk, ra)

    if not mdps_valid:
        aux[A_CONV_START] = _NO_START
    elif aux[A_CONV_START] == _NO_START:
        aux[A_CONV_START] = t_ns
    if aux[A_CONV_START] == _NO_START or t_ns - aux[A_CONV_START] < tv[T_CONV_NS]:
        status |= _NOT_CONVERGED
    sat_after = np.int64(0)
    for k in range(sat.shape[0]):
        sat_after += sat[k]
    if sat_after != sat_before:
        status |= _DEGRADED
    if status == 0:
        status = _VALID
    return status


# --- boundary -------------------------------------------------------------------------------


@njit(cache=True)
def quantise(value, scale):  # pragma: no cover - compiled
    """(raw, bad) of ``value`` in a Q format with ``scale = 2**n_frac`` (twin of step._q)."""
    if not np.isfinite(value):
        return np.int64(0), True
    a = abs(value) * scale
    if a >= 2147483647.5:
        return (np.int64(INT32_MAX), True) if value > 0 else (np.int64(INT32_MIN), True)
    r = np.int64(np.floor(a + 0.5))
    if value < 0:
        r = -r
    return r, False


@njit(cache=True)
def quantise_kernel(tv, speed, steer, yaw, tcol, tas):  # pragma: no cover - compiled
    """The twin of :func:`firmware_model.step.quantise_inputs`: (v, steer, yaw, tcol, tas, flags)."""
    flags = 0
    if np.isfinite(speed):
        v, bad = quantise(speed, 2.0 ** tv[T_F_SPEED])
        if bad:
            flags |= IN_SPEED_SAT
    else:
        v = np.int64(0)
        flags |= IN_SPEED_NAN
    s, bad = quantise(steer, 2.0 ** tv[T_F_STEER])
    if bad:
        flags |= IN_STEER_BAD
    y, bad = quantise(yaw, 2.0 ** tv[T_F_YAW])
    if bad:
        flags |= IN_YAW_BAD
    c, bad1 = quantise(tcol, 2.0 ** tv[T_F_TORQUE])
    a, bad2 = quantise(tas, 2.0 ** tv[T_F_TORQUE])
    if bad1 or bad2:
        flags |= IN_TORQUE_BAD
    return v, s, y, c, a, flags


@njit(cache=True)
def step_si_kernel(
    tv,
    coef,
    x,
    P,
    aux,
    sat,
    ws,
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
    """Quantise SI inputs and step (one compiled call per live step); returns the status."""
    v, s, y, c, a, flags = quantise_kernel(tv, speed, steering_angle, yaw_rate, column_torque, assist_torque)
    return step_kernel(tv, coef, x, P, aux, sat, ws, t_ns, v, s, y, c, a, flags, mdps_ok, esc_ok, out)


@njit(cache=True, nogil=True)  # nogil: the float shadow runs beside it in a second thread
def batch_kernel(
    tv,
    coef,
    x,
    P,
    aux,
    sat,
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
    """Quantise and step every row; ``outs`` (n, N_OUT) int64 raw, ``status`` (n,) uint8."""
    ws = np.zeros((4, 16), dtype=np.int64)
    out = np.zeros(N_OUT, dtype=np.int64)
    for k in range(t_ns.shape[0]):
        v, s, y, c, a, flags = quantise_kernel(
            tv, speed[k], steering_angle[k], yaw_rate[k], column_torque[k], assist_torque[k]
        )
        st = step_kernel(
            tv, coef, x, P, aux, sat, ws, t_ns[k], v, s, y, c, a, flags, mdps_ok[k], esc_ok[k], out
        )
        for j in range(N_OUT):
            outs[k, j] = out[j]
        status[k] = st


# --- Python API -------------------------------------------------------------------------------


@dataclass
class FastState:
    """The integer state as int64 arrays (``x`` (4,), ``P`` (16,), ``aux`` (N_AUX,), ``sat`` (N_SAT,)),
    plus the float shadow filter's state and the shadow-check counters (batch runs with shadow).

    Attributes:
        shadow_state: the float filter's :class:`lde.estimator.paper.EstimatorState` (created on first use).
        shadow_count: steps whose deviation exceeded the bound, over all batches since creation.
        shadow_max_dfw, shadow_max_dmw: largest |dFw| [N] and |dMw| [Nm] seen.
        last_report: the :class:`firmware_model.shadow.ShadowReport` of the last batch.
    """

    x: np.ndarray
    P: np.ndarray
    aux: np.ndarray
    sat: np.ndarray
    shadow_state: EstimatorState | None = None
    shadow_count: int = 0
    shadow_max_dfw: float = 0.0
    shadow_max_dmw: float = 0.0
    last_report: ShadowReport | None = None

    @classmethod
    def initial(cls, tv: np.ndarray) -> FastState:
        st = cls(
            np.zeros(4, np.int64),
            np.zeros(16, np.int64),
            np.zeros(N_AUX, np.int64),
            np.zeros(N_SAT, np.int64),
        )
        reset_kernel(tv, st.x, st.P, st.aux, st.sat)
        return st

    def saturations(self) -> dict[str, int]:
        """Saturation events per variable since reset."""
        return {n: int(c) for n, c in zip(SAT_NAMES, self.sat, strict=True)}


def _dt_ns(dt: float) -> int:
    return int(round(dt * 1e9))


def _to_si(tb: FixedTables, outs: np.ndarray) -> tuple[np.ndarray, ...]:
    """Raw normalised outputs -> SI float arrays (beta, r, Fw, Mw, T_align): exact power-of-2 scalings."""
    return (
        outs[:, O_XB] * tb.state_lsb(0),
        outs[:, O_XR] * tb.state_lsb(1),
        outs[:, O_XF] * tb.state_lsb(2),
        outs[:, O_XM] * tb.state_lsb(3),
        outs[:, O_TA] * tb.t_align_lsb(),
    )


def _conditioned(vehicle: Vehicle, t_ns, steering_angle, steering_rate, yaw_rate, column_torque):
    """The inputs after the vehicle's corrections (shape errors as in :func:`run_batch_raw`)."""
    if not is_active(vehicle):
        return steering_angle, yaw_rate, column_torque
    n = np.shape(t_ns)[0] if np.ndim(t_ns) == 1 else -1
    return condition_arrays(
        vehicle,
        as_f64("steering_angle", steering_angle, n),
        None if steering_rate is None else as_f64("steering_rate", steering_rate, n),
        as_f64("yaw_rate", yaw_rate, n),
        as_f64("column_torque", column_torque, n),
    )


def run_batch_raw(
    tb: FixedTables,
    state: FastState,
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    mdps_ok,
    esc_ok,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The compiled loop on checked arrays: (t_ns int64, outs int64 (n, 5) raw, status uint8)."""
    t = np.ascontiguousarray(t_ns, dtype=np.int64)
    if t.ndim != 1:
        raise StepInputError(f"t_ns must be 1-D, got shape {t.shape}")
    n = t.shape[0]

    outs = np.empty((n, N_OUT), dtype=np.int64)
    status = np.empty(n, dtype=np.uint8)
    batch_kernel(
        tables_vector(tb),
        tb.coef_array(),
        state.x,
        state.P,
        state.aux,
        state.sat,
        t,
        as_f64("speed", speed, n),
        as_f64("steering_angle", steering_angle, n),
        as_f64("yaw_rate", yaw_rate, n),
        as_f64("column_torque", column_torque, n),
        as_f64("assist_torque", assist_torque, n),
        as_bool("mdps_ok", mdps_ok, n),
        as_bool("esc_ok", esc_ok, n),
        outs,
        status,
    )
    return t, outs, status


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
    state: FastState | None = None,
    dt: float = STEP_S,
    shadow: bool = True,
    steering_rate: np.ndarray | None = None,
) -> BatchResult:
    """The fixed-point backend with the signature and result type of :func:`lde.estimator.paper.run_batch`.

    Inputs in SI on the step grid (see :func:`lde.estimator.paper.run_batch`); they are quantised at the
    boundary, stepped in integers and the raw estimates converted back to SI. ``state`` continues
    from (and advances) a :class:`FastState`; its ``sat`` counts saturations per variable.

    ``shadow`` (default): the float filter (:func:`lde.estimator.paper.run_batch`, its state kept in
    ``state.shadow_state``) runs beside it; steps where |dFw| > 5 N or |dMw| > 2 Nm get
    ``Status.SHADOW_DEVIATION`` and are counted in ``state.shadow_count``.

    The vehicle's input corrections (:mod:`lde.estimator.conditioning`, ``steering_rate`` for the friction
    term) are applied once, in float before the quantisation, and both filters see the same
    conditioned inputs.
    """
    steering_angle, yaw_rate, column_torque = _conditioned(
        vehicle, t_ns, steering_angle, steering_rate, yaw_rate, column_torque
    )
    vehicle = without_corrections(vehicle)
    tb = tables_for(vehicle, _dt_ns(dt))
    st = FastState.initial(tables_vector(tb)) if state is None else state
    shadow_thread = None
    if shadow:
        if st.shadow_state is None:
            st.shadow_state = EstimatorState.initial(params_vector(vehicle, dt))
        # Both compiled loops release the GIL: the float shadow runs on the other core while the
        # integer loop runs here, so the check costs memory, not (much) wall time. Its result is
        # the same as run sequentially (independent states, deterministic kernels).
        box: list[BatchResult] = []
        errs: list[BaseException] = []

        def _float() -> None:
            try:
                box.append(
                    float_run_batch(
                        t_ns,
                        speed,
                        steering_angle,
                        yaw_rate,
                        column_torque,
                        assist_torque,
                        mdps_ok,
                        esc_ok,
                        vehicle,
                        state=st.shadow_state,
                        dt=dt,
                    )
                )
            except BaseException as exc:  # noqa: BLE001 - re-raised in the calling thread below
                errs.append(exc)

        shadow_thread = threading.Thread(target=_float, name="lde-float-shadow")
        shadow_thread.start()
    try:
        t, outs, status = run_batch_raw(
            tb, st, t_ns, speed, steering_angle, yaw_rate, column_torque, assist_torque, mdps_ok, esc_ok
        )
    finally:
        if shadow_thread is not None:
            shadow_thread.join()
    beta, r, fw, mw, ta = _to_si(tb, outs)
    res = BatchResult(t_ns=t.copy(), fw=fw, mw=mw, t_align=ta, beta=beta, yaw_rate=r, status=status)
    if shadow:
        if errs:
            raise errs[0]
        flt = box[0]
        rep = shadow_check(res, flt)
        st.shadow_count += rep.count
        st.shadow_max_dfw = max(st.shadow_max_dfw, rep.max_dfw)
        st.shadow_max_dmw = max(st.shadow_max_dmw, rep.max_dmw)
        st.last_report = rep
        res.status = rep.status
    return res


class FixedEstimator:
    """The fixed-point estimator for the live loop, interface of :class:`lde.estimator.paper.Estimator`.

    With ``shadow`` (default) the float :class:`lde.estimator.paper.Estimator` steps beside it and
    :attr:`shadow` (a :class:`firmware_model.shadow.ShadowChecker`) flags each step whose deviation
    exceeds the bound with ``Status.SHADOW_DEVIATION`` and counts it.
    """

    def __init__(self, vehicle: Vehicle, dt: float = STEP_S, shadow: bool = True) -> None:
        self.vehicle = vehicle
        self.dt = float(dt)
        self._c = corrections_vector(vehicle)
        self._corrects = is_active(vehicle)
        vehicle = without_corrections(vehicle)  # both filters step on the conditioned inputs
        self.tables = tables_for(vehicle, _dt_ns(self.dt))
        self._tv = tables_vector(self.tables)
        self._coef = self.tables.coef_array()
        self._ws = np.zeros((4, 16), dtype=np.int64)
        self._out = np.zeros(N_OUT, dtype=np.int64)
        self.state = FastState.initial(self._tv)
        self._float = Estimator(vehicle, self.dt) if shadow else None
        self.shadow = ShadowChecker() if shadow else None
        if self._float is not None:
            # one float shadow state for step() and run_batch(): they can be mixed
            self.state.shadow_state = self._float.state

    def reset(self) -> None:
        """x = 0, P = P0, held until the next usable step; saturation and shadow counters cleared."""
        st = self.state
        reset_kernel(self._tv, st.x, st.P, st.aux, st.sat)
        st.shadow_count, st.shadow_max_dfw, st.shadow_max_dmw, st.last_report = 0, 0.0, 0.0, None
        if self._float is not None and self.shadow is not None:
            self._float.reset()  # resets st.shadow_state in place (the same object)
            self.shadow.reset()

    def step_ints(self, t_ns: int, inputs: EstimatorInputs) -> tuple[int, ...]:
        """(status, X_beta, X_r, X_Fw, X_Mw, T_align_hat) raw, as :func:`firmware_model.step.step_raw`
        (no shadow check: the integer step alone)."""
        return self._step_ints(t_ns, self._condition(inputs))

    def _condition(self, inputs: EstimatorInputs) -> EstimatorInputs:
        """The raw inputs (an EstimatorInputs or the receiver's InputSample) after the corrections."""
        if not self._corrects:
            return inputs
        angle, yaw, col = condition_kernel(
            self._c,
            float(inputs.steering_angle),
            float(getattr(inputs, "steering_rate", math.nan)),
            float(inputs.yaw_rate),
            float(inputs.column_torque),
        )
        return EstimatorInputs(
            float(inputs.speed),
            angle,
            yaw,
            col,
            float(inputs.assist_torque),
            bool(inputs.mdps_ok),
            bool(inputs.esc_ok),
        )

    def _step_ints(self, t_ns: int, inputs: EstimatorInputs) -> tuple[int, ...]:
        st = self.state
        status = step_si_kernel(
            self._tv,
            self._coef,
            st.x,
            st.P,
            st.aux,
            st.sat,
            self._ws,
            np.int64(t_ns),
            float(inputs.speed),
            float(inputs.steering_angle),
            float(inputs.yaw_rate),
            float(inputs.column_torque),
            float(inputs.assist_torque),
            bool(inputs.mdps_ok),
            bool(inputs.esc_ok),
            self._out,
        )
        o = self._out
        return (int(status), int(o[0]), int(o[1]), int(o[2]), int(o[3]), int(o[4]))

    def step(self, t_ns: int, inputs: EstimatorInputs) -> EstimatorOutput:
        """One step at ``t_ns`` [ns]; the a-posteriori estimate in SI and the status (with the
        shadow check's SHADOW_DEVIATION when enabled)."""
        inputs = self._condition(inputs)
        s, xb, xr, xf, xm, ta = self._step_ints(t_ns, inputs)
        tb = self.tables
        out = EstimatorOutput(
            int(t_ns),
            xf * tb.state_lsb(2),
            xm * tb.state_lsb(3),
            ta * tb.t_align_lsb(),
            xb * tb.state_lsb(0),
            xr * tb.state_lsb(1),
            Status(s),
        )
        if self._float is None or self.shadow is None:
            return out
        status = self.shadow.check(out, self._float.step(t_ns, inputs))
        return replace(out, status=status)

    def run_batch(
        self,
        t_ns,
        speed,
        steering_angle,
        yaw_rate,
        column_torque,
        assist_torque,
        mdps_ok,
        esc_ok,
        steering_rate=None,
    ) -> BatchResult:
        """:func:`run_batch` continuing from (and advancing) this estimator's state, the float
        shadow's included (``step`` and ``run_batch`` calls can be mixed)."""
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
            shadow=self._float is not None,
            steering_rate=steering_rate,
        )

    def saturations(self) -> dict[str, int]:
        return self.state.saturations()


def run_batch_with_shadow(
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    mdps_ok,
    esc_ok,
    vehicle: Vehicle,
    *,
    dt: float = STEP_S,
) -> tuple[BatchResult, ShadowReport]:
    """The fixed backend from a fresh state with the float filter as shadow: (fixed result with
    bit 6 set where it deviates, report)."""
    state = FastState.initial(tables_vector(tables_for(vehicle, int(round(dt * 1e9)))))
    fixed = run_batch(
        t_ns,
        speed,
        steering_angle,
        yaw_rate,
        column_torque,
        assist_torque,
        mdps_ok,
        esc_ok,
        vehicle,
        state=state,
        dt=dt,
        shadow=True,
    )
    assert state.last_report is not None
    return fixed, state.last_report
