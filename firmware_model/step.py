"""The integer-only estimator step: the pure-Python reference model of the MDPS firmware.

No floats and no numpy in :func:`step_raw`: Python ints with the int32/int64 semantics of
:mod:`firmware_model.qformat` (every stored value saturated to int32, every sum of products in a
saturating int64 accumulator, right shifts rounded HALF_UP). Floats appear only at the boundary
(:func:`quantise_inputs` and :meth:`FixedEstimator.step`'s output conversion).

Algorithm: the same time-varying Kalman filter as :mod:`lde.estimator.paper` (a covariance update in fixed
point, chosen over steady-state scheduled gains: see ``docs/firmware.md`` for the measurements),
in normalised units (``X_i = x_i / sigma_i`` and ``Pn_ij = P_ij / (sigma_i sigma_j)``, both Q15.16;
:mod:`firmware_model.gen_tables`). Per step, mirroring :func:`lde.estimator.paper.step_kernel`:

1. Validity: the ESC group is usable when ``esc_ok`` and the yaw rate is inside its format; the
   MDPS group when ``mdps_ok`` and steering angle and torques are inside theirs (an input outside
   its format is saturated, counted, and its group treated as faulty: no wrap-around, clear status).
2. Hold below ``min_speed`` or without ESC (x and P held; P re-initialised to P0 on resume).
3. Schedule: ``w = 1/vx`` by one rounded integer division, ``w2 = w^2``; every coefficient of the
   normalised Phi, E, H, D is ``c0 + c1 w + c2 w2`` (generated constants).
4. Update with the yaw rate, then (MDPS valid) with ``T_align = N (T_column + T_assist)``: two
   sequential scalar updates, equal to the float filter's joint update because R is diagonal,
   and needing one division each instead of a 2x2 inverse:

       ph = Pn h^T;  s = h ph + Rn;  Kg = ph / s
       X  = X + Kg (z - h X - d delta)
       Pn = Pn - Kg ph^T          (upper triangle, mirrored; diagonal floored at 0, counted)

5. Output the a-posteriori estimate and ``T_align_hat = h X + d delta``.
6. Predict with the a-posteriori estimate (Phi_n is sparse: rows Fw, Mw are identity):

       X  = Phi_n X + e delta
       Pn = Phi_n Pn Phi_n^T + Qdn

Status bits are those of :class:`lde.estimator.paper.Status`, set as the float step sets them; in addition a
saturation inside the step (speed above the model maximum, any arithmetic saturation) sets
DEGRADED (and so clears VALID). Input faults are counted per input and reported by their group's
fault bit, as in the float step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from lde.estimator.conditioning import condition_kernel, corrections_vector, without_corrections
from lde.estimator.paper import EstimatorInputs, EstimatorOutput, Status
from lde.params import Vehicle

from .qformat import INT32_MAX, INT32_MIN, add_sat64, div_round, shift_round
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

_VALID, _DEGRADED, _MDPS_FAULT, _ESC_FAULT, _LOW_SPEED, _NOT_CONVERGED = 1, 2, 4, 8, 16, 32

# --- saturation counter slots ---------------------------------------------------------------
SAT_NAMES = (
    "in_speed",  # speed input outside Q7.24 (or not finite)
    "in_steer",  # steering-wheel angle input outside Q4.27 (or not finite)
    "in_yaw",  # yaw-rate input outside its format (or not finite)
    "in_torque",  # a torque input outside Q8.23, or their sum outside int32 (or not finite)
    "speed_clamp",  # speed above the model's maximum (model runs at the maximum)
    "coef",  # a scheduled coefficient
    "x_beta",
    "x_r",
    "x_fw",
    "x_mw",  # a state
    "cov",  # a covariance element (or the Phi P product)
    "innov",  # an innovation or a measurement
    "gain",  # a Kalman gain
    "acc64",  # an int64 accumulator
    "p_floor",  # a covariance diagonal below 0 floored to 0
    "s_nonpos",  # innovation variance <= 0: update skipped
    "t_align",  # the T_align_hat output
)
(
    S_IN_SPEED,
    S_IN_STEER,
    S_IN_YAW,
    S_IN_TORQUE,
    S_SPEED_CLAMP,
    S_COEF,
    S_X0,
    S_X1,
    S_X2,
    S_X3,
    S_COV,
    S_INNOV,
    S_GAIN,
    S_ACC64,
    S_P_FLOOR,
    S_S_NONPOS,
    S_T_ALIGN,
) = range(len(SAT_NAMES))
N_SAT = len(SAT_NAMES)

# --- input flags from the boundary (bit mask) -------------------------------------------------
IN_SPEED_NAN = 1  #: speed not finite: treated as below min speed (LOW_SPEED), like the float step
IN_SPEED_SAT = 2  #: speed outside its format (saturated)
IN_STEER_BAD = 4  #: steering angle not finite or saturated
IN_YAW_BAD = 8  #: yaw rate not finite or saturated
IN_TORQUE_BAD = 16  #: a torque not finite or saturated

_NO_START = -1


@dataclass
class FixedState:
    """The whole integer state (what the ECU keeps in RAM between steps).

    Attributes:
        x: normalised a-priori estimate [beta, r, Fw, Mw] for the next step, Q15.16 each.
        P: normalised covariance, row-major 16 ints, Q15.16.
        delta: last valid steering-wheel angle, Q(f_steer) rad.
        t_align: last output T_align_hat, normalised Q15.16.
        steps, held, conv_start (t_ns or -1), updates: as in :class:`lde.estimator.paper.EstimatorState`.
        sat: saturation events per ``SAT_NAMES`` slot since reset.
    """

    x: list[int] = field(default_factory=lambda: [0, 0, 0, 0])
    P: list[int] = field(default_factory=lambda: [0] * 16)
    delta: int = 0
    t_align: int = 0
    steps: int = 0
    held: int = 1
    conv_start: int = _NO_START
    updates: int = 0
    sat: list[int] = field(default_factory=lambda: [0] * N_SAT)

    @classmethod
    def initial(cls, tb: FixedTables) -> FixedState:
        st = cls()
        reset(tb, st)
        return st

    def copy(self) -> FixedState:
        return FixedState(
            list(self.x),
            list(self.P),
            self.delta,
            self.t_align,
            self.steps,
            self.held,
            self.conv_start,
            self.updates,
            list(self.sat),
        )


def reset(tb: FixedTables, st: FixedState) -> None:
    """x = 0, P = P0, held; counters cleared."""
    st.x = [0, 0, 0, 0]
    _set_p0(tb, st.P)
    st.delta = 0
    st.t_align = 0
    st.steps = 0
    st.held = 1
    st.conv_start = _NO_START
    st.updates = 0
    st.sat = [0] * N_SAT


def _set_p0(tb: FixedTables, P: list[int]) -> None:
    for k in range(16):
        P[k] = 0
    for i in range(4):
        P[5 * i] = tb.p0_n[i]


# --- saturating helpers (count into st.sat) ---------------------------------------------------


def _sat32(st: FixedState, v: int, slot: int) -> int:
    if v > INT32_MAX:
        st.sat[slot] += 1
        return INT32_MAX
    if v < INT32_MIN:
        st.sat[slot] += 1
        return INT32_MIN
    return v


def _mac(st: FixedState, acc: int, a: int, b: int) -> int:
    """acc + a*b in a saturating int64 accumulator (a, b int32: the product always fits)."""
    r, hit = add_sat64(acc, a * b)
    if hit:
        st.sat[S_ACC64] += 1
    return r


def _add64(st: FixedState, a: int, b: int) -> int:
    r, hit = add_sat64(a, b)
    if hit:
        st.sat[S_ACC64] += 1
    return r


# --- the step -------------------------------------------------------------------------------


def schedule(tb: FixedTables, st: FixedState, v: int) -> list[int]:
    """The normalised coefficients at speed ``v`` (Q f_speed, >= v_min_raw): C_* slots."""
    w = div_round(1 << (tb.f_speed + tb.f_w), v)  # w = 1/vx, Q f_w
    w2 = shift_round(w * w, tb.f_w)  # w^2, Q f_w
    wp = (1, w, w2)
    c = [0] * N_COEF
    for k in range(N_COEF):
        acc = 0
        for j in range(3):
            raw, sh = tb.coef_terms[k][j]
            if raw != 0:
                acc = _add64(st, acc, shift_round(raw * wp[j], sh))
        c[k] = _sat32(st, acc, S_COEF)
    return c


def _scalar_update(
    tb: FixedTables, st: FixedState, h0: int, h1: int, unit_row: bool, z: int, dterm: int, r: int
) -> None:
    """Scalar measurement update (module docstring, step 4). ``unit_row``: h = [0, 1, 0, 0]
    (the yaw rate; no multiplication), else h = [h0, h1, 0, 0] in Q f_h."""
    P, X = st.P, st.x
    fh, fg = tb.f_h, tb.f_gain
    ph = [0, 0, 0, 0]
    if unit_row:
        # ph = Pn h^T = column r of Pn;  s = Pn_rr + Rn;  h X = X_r
        for i in range(4):
            ph[i] = P[4 * i + 1]
        s = _add64(st, ph[1], r)
        hx = X[1]
    else:
        for i in range(4):
            acc = _mac(st, _mac(st, 0, P[4 * i], h0), P[4 * i + 1], h1)
            ph[i] = _sat32(st, shift_round(acc, fh), S_COV)
        acc = _mac(st, _mac(st, 0, h0, ph[0]), h1, ph[1])
        s = _add64(st, shift_round(acc, fh), r)
        hx = shift_round(_mac(st, _mac(st, 0, h0, X[0]), h1, X[1]), fh)
    if s <= 0:
        st.sat[S_S_NONPOS] += 1
        return
    innov = _sat32(st, z - hx - dterm, S_INNOV)
    g = [_sat32(st, div_round(ph[i] << fg, s), S_GAIN) for i in range(4)]
    # X = X + Kg innov
    for i in range(4):
        X[i] = _sat32(st, X[i] + shift_round(g[i] * innov, fg), S_X0 + i)
    # Pn = Pn - Kg ph^T (upper triangle, mirrored)
    for i in range(4):
        for j in range(i, 4):
            v = _sat32(st, P[4 * i + j] - shift_round(g[i] * ph[j], fg), S_COV)
            P[4 * i + j] = v
            P[4 * j + i] = v
        if P[5 * i] < 0:
            P[5 * i] = 0
            st.sat[S_P_FLOOR] += 1


def _predict(tb: FixedTables, st: FixedState, c: list[int], delta: int) -> None:
    """X = Phi_n X + e delta;  Pn = Phi_n Pn Phi_n^T + Qdn (Phi_n rows 2, 3 are identity)."""
    X, P = st.x, st.P
    fp = tb.f_phi
    sh_e = tb.f_e + tb.f_steer - tb.f_state
    # Phi_n rows 0 and 1 as (column, coefficient) pairs
    rows = (
        ((0, c[C_PHI00]), (1, c[C_PHI01]), (2, c[C_PHI02])),
        ((0, c[C_PHI10]), (1, c[C_PHI11]), (3, c[C_PHI13])),
    )
    e = (c[C_E0], c[C_E1])
    # X = Phi_n X + e delta
    x_new = list(X)
    for i in range(2):
        acc = 0
        for k, a in rows[i]:
            acc = _mac(st, acc, a, X[k])
        x_new[i] = _sat32(st, shift_round(acc, fp) + shift_round(e[i] * delta, sh_e), S_X0 + i)
    st.x = x_new
    # T = Phi_n Pn
    T = list(P)
    for i in range(2):
        for j in range(4):
            acc = 0
            for k, a in rows[i]:
                acc = _mac(st, acc, a, P[4 * k + j])
            T[4 * i + j] = _sat32(st, shift_round(acc, fp), S_COV)
    # Pn = T Phi_n^T + Qdn, upper triangle mirrored
    for i in range(4):
        for j in range(i, 4):
            if j < 2:
                acc = 0
                for k, a in rows[j]:
                    acc = _mac(st, acc, T[4 * i + k], a)
                v = shift_round(acc, fp)
            else:
                v = T[4 * i + j]
            if i == j:
                v += tb.qd_n[i]
            v = _sat32(st, v, S_COV)
            P[4 * i + j] = v
            P[4 * j + i] = v


def step_raw(
    tb: FixedTables,
    st: FixedState,
    t_ns: int,
    v: int,
    steer: int,
    yaw: int,
    tcol: int,
    tas: int,
    in_flags: int,
    mdps_ok: bool,
    esc_ok: bool,
) -> tuple[int, int, int, int, int, int]:
    """One integer step. Inputs are raw (:func:`quantise_inputs`); returns
    (status, X_beta, X_r, X_Fw, X_Mw, T_align_hat) with the estimates normalised Q15.16."""
    st.steps += 1
    status = 0
    # input faults are counted here and reported by their group's fault bit (ESC_FAULT,
    # MDPS_FAULT, LOW_SPEED), exactly like the float step; DEGRADED below is for saturations
    # inside the step (speed clamp, arithmetic)
    if in_flags & (IN_SPEED_NAN | IN_SPEED_SAT):
        st.sat[S_IN_SPEED] += 1
    if in_flags & IN_STEER_BAD:
        st.sat[S_IN_STEER] += 1
    if in_flags & IN_YAW_BAD:
        st.sat[S_IN_YAW] += 1
    if in_flags & IN_TORQUE_BAD:
        st.sat[S_IN_TORQUE] += 1
    sat_before = sum(st.sat)
    esc_valid = esc_ok and not (in_flags & IN_YAW_BAD)
    mdps_valid = mdps_ok and not (in_flags & (IN_STEER_BAD | IN_TORQUE_BAD))
    if not esc_valid:
        status |= _ESC_FAULT
    if not mdps_valid:
        status |= _MDPS_FAULT | _DEGRADED
    speed_ok = not (in_flags & IN_SPEED_NAN) and v >= tb.v_min_raw
    if esc_valid and not speed_ok:
        status |= _LOW_SPEED

    if not (esc_valid and speed_ok):
        # hold: no update, no propagation; repeat the held estimate
        st.held = 1
        st.conv_start = _NO_START
        x = st.x
        if sum(st.sat) != sat_before:
            status |= _DEGRADED
        return status | _NOT_CONVERGED, x[0], x[1], x[2], x[3], st.t_align

    if st.held == 1:
        _set_p0(tb, st.P)
        st.held = 0

    delta = steer if mdps_valid else st.delta
    if v > tb.v_max_raw:
        st.sat[S_SPEED_CLAMP] += 1
        v = tb.v_max_raw
    c = schedule(tb, st, v)

    # update with the yaw rate (normalised by sigma_r: the input's raw value is already Z_r)
    _scalar_update(tb, st, 0, 0, True, yaw, 0, tb.r_n[0])
    # d delta, the feedthrough of the aligning-torque row (Q f_state, normalised)
    dterm = shift_round(c[C_D1] * delta, tb.f_d + tb.f_steer - tb.f_state)
    if mdps_valid:
        # T_align = N (T_column + T_assist), normalised by sigma_T
        n_raw, n_frac = tb.n_over_st
        tsum = _sat32(st, tcol + tas, S_IN_TORQUE)
        z_t = _sat32(st, shift_round(n_raw * tsum, n_frac + tb.f_torque - tb.f_state), S_INNOV)
        _scalar_update(tb, st, c[C_H10], c[C_H11], False, z_t, dterm, tb.r_n[1])
    st.updates += 1

    # T_align_hat = h X + d delta (a posteriori)
    X = st.x
    hx = shift_round(_mac(st, _mac(st, 0, c[C_H10], X[0]), c[C_H11], X[1]), tb.f_h)
    st.t_align = _sat32(st, hx + dterm, S_T_ALIGN)
    out = (X[0], X[1], X[2], X[3], st.t_align)
    if mdps_valid:
        st.delta = steer

    _predict(tb, st, c, delta)

    if not mdps_valid:
        st.conv_start = _NO_START
    elif st.conv_start == _NO_START:
        st.conv_start = t_ns
    if st.conv_start == _NO_START or t_ns - st.conv_start < tb.converge_ns:
        status |= _NOT_CONVERGED
    if sum(st.sat) != sat_before:
        status |= _DEGRADED
    if status == 0:
        status = _VALID
    return (status, *out)


# --- boundary: SI floats <-> raw ints ---------------------------------------------------------


def _q(value: float, n_frac: int) -> tuple[int, bool]:
    """Nearest int32 raw of ``value`` in Q.n_frac (ties away from zero); (raw, bad?) where bad
    means not finite or saturated. The same arithmetic as :func:`firmware_model.fast.quantise`."""
    if not math.isfinite(value):
        return 0, True
    a = abs(value) * math.ldexp(1.0, n_frac)
    if a >= 2147483647.5:
        return (INT32_MAX, True) if value > 0 else (INT32_MIN, True)
    r = int(math.floor(a + 0.5))
    if value < 0:
        r = -r
    return r, False


def quantise_inputs(
    tb: FixedTables,
    speed: float,
    steering_angle: float,
    yaw_rate: float,
    column_torque: float,
    assist_torque: float,
) -> tuple[int, int, int, int, int, int]:
    """(v, steer, yaw, tcol, tas, in_flags): the SI inputs as raw ints, with ``IN_*`` flags."""
    flags = 0
    if math.isfinite(speed):
        v, bad = _q(speed, tb.f_speed)
        if bad:
            flags |= IN_SPEED_SAT
    else:
        v = 0
        flags |= IN_SPEED_NAN
    steer, bad = _q(steering_angle, tb.f_steer)
    flags |= IN_STEER_BAD if bad else 0
    yaw, bad = _q(yaw_rate, tb.yaw_input_frac())
    flags |= IN_YAW_BAD if bad else 0
    tcol, bad1 = _q(column_torque, tb.f_torque)
    tas, bad2 = _q(assist_torque, tb.f_torque)
    flags |= IN_TORQUE_BAD if (bad1 or bad2) else 0
    return v, steer, yaw, tcol, tas, flags


class ReferenceEstimator:
    """The pure-Python reference model with the :class:`lde.estimator.paper.Estimator` interface (slow;
    for tests and golden vectors. The service uses :class:`firmware_model.fast.FixedEstimator`)."""

    def __init__(self, vehicle: Vehicle, tables: FixedTables | None = None) -> None:
        self.vehicle = vehicle
        self._c = corrections_vector(vehicle)  # input corrections: float, before the quantisation
        self.tables = tables or tables_for(without_corrections(vehicle))
        self.state = FixedState.initial(self.tables)

    def reset(self) -> None:
        reset(self.tables, self.state)

    def step_ints(self, t_ns: int, inputs: EstimatorInputs) -> tuple[int, ...]:
        """The raw result tuple of :func:`step_raw` for SI ``inputs``."""
        tb = self.tables
        angle, yaw_rate, col = inputs.steering_angle, inputs.yaw_rate, inputs.column_torque
        if not self.vehicle.corrections.is_identity:
            angle, yaw_rate, col = condition_kernel(
                self._c,
                float(angle),
                float(getattr(inputs, "steering_rate", math.nan)),
                float(yaw_rate),
                float(col),
            )
        v, steer, yaw, tcol, tas, flags = quantise_inputs(
            tb, inputs.speed, angle, yaw_rate, col, inputs.assist_torque
        )
        return step_raw(
            tb,
            self.state,
            int(t_ns),
            v,
            steer,
            yaw,
            tcol,
            tas,
            flags,
            bool(inputs.mdps_ok),
            bool(inputs.esc_ok),
        )

    def step(self, t_ns: int, inputs: EstimatorInputs) -> EstimatorOutput:
        s, xb, xr, xf, xm, ta = self.step_ints(t_ns, inputs)
        tb = self.tables
        return EstimatorOutput(
            int(t_ns),
            xf * tb.state_lsb(2),
            xm * tb.state_lsb(3),
            ta * tb.t_align_lsb(),
            xb * tb.state_lsb(0),
            xr * tb.state_lsb(1),
            Status(s),
        )
