"""Backend ``fixed`` (the default): the firmware model, the lateral filter in integers
(:mod:`firmware_model.lateral`), checked against its float step at every step, with the learner.

Per step: quantise the SI inputs, run the integer step on the current coefficient set, convert its
estimate to SI (exact power-of-two scalings); run the float step (:func:`lde.estimator.lateral.step_kernel`)
on the same inputs and the same parameter vector as its shadow and compare (:func:`shadow_compare`);
then the learner on the fixed estimate. When the learner pushes (every 128 steps) the slow task
re-quantises the coefficient set (:func:`firmware_model.lateral.coef_set_kernel`): from the next step
both filters run on the new parameters.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from firmware_model import lateral as FX
from firmware_model.shadow import FW_BOUND_N, MW_BOUND_NM
from firmware_model.tables import lateral_tables_for
from lde.engine.backends.float import FRESH_A, FRESH_R, FRESH_T, learner_arrays
from lde.engine.receiver import (
    I_ASSIST_TORQUE,
    I_COLUMN_TORQUE,
    I_LAT_ACCEL,
    I_SPEED,
    I_STEERING_ANGLE,
    I_YAW_RATE,
)
from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.outputs import (
    N_OUT,
    O_BANK,
    O_BETA,
    O_FW,
    O_FW_WIND,
    O_GAIN,
    O_LEARN,
    O_MW,
    O_MW_WIND,
    O_T_ALIGN,
    O_YAW,
)
from lde.params import Vehicle
from lde.status import SHADOW_DEVIATION, VALID

NAME = "fixed"
DESCRIPTION = "the lateral filter in fixed point (firmware model) with its float shadow check and the learner"
LEARNS = True
SMOOTHABLE = True

# the shadow check's counters (float64): deviating steps, largest |dFw| [N], largest |dMw| [Nm]
SH_COUNT, SH_MAX_DFW, SH_MAX_DMW = 0, 1, 2
N_SH = 3


class Params(NamedTuple):
    lp: np.ndarray  # (N_LP,) the learner's parameters (lde.estimator.learner L_*)
    tv: np.ndarray  # (N_T,) int64 the generated constants (firmware_model.lateral T_*)
    ft: np.ndarray  # int64 the function tables (reciprocal seeds, tanh, asin)
    lsb: np.ndarray  # (7,) SI value of one raw unit: the 5 states, T_align [Nm], the friction sign z
    bound: np.ndarray  # (2,) the shadow check's bound: |dFw| [N], |dMw| [Nm]


class State(NamedTuple):
    p: np.ndarray  # (N_P,) the filter's parameter vector (lde.estimator.lateral P_*, SI): the learner's
    cs: np.ndarray  # (N_CS,) int64 the coefficient set quantised from p (the slow task)
    x: np.ndarray  # (5,) int64 the normalised state (Q15.16)
    P: np.ndarray  # (25,) int64 its normalised covariance, row-major (Q15.16)
    aux: np.ndarray  # (N_AUX,) int64 aux slots (firmware_model.lateral A_*)
    sat: np.ndarray  # (N_SAT,) int64 saturation counters (firmware_model.lateral SAT_NAMES)
    ws: np.ndarray  # (4, 16) int64 scratch
    iout: np.ndarray  # (N_IO,) int64 the step's raw outputs (firmware_model.lateral IO_*)
    shadow: E.FilterState  # the float step on the same parameters (the shadow)
    shadow_out: np.ndarray  # (N_OUT,) the shadow's output row
    shadow_counts: np.ndarray  # (N_SH,) the shadow check's counters (SH_*)
    ls: np.ndarray  # (N_LS,) the learner's state (lde.estimator.learner LS_*)
    lws: np.ndarray  # (2, N3) the learner's workspace


def make(
    vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool, torque_scale: int = Ln.TS_KNOWN
) -> tuple[Params, State]:
    p = E.params_vector(vehicle, dt, angle_above_torsion_bar=angle_above_torsion_bar)
    lp, ls, lws = learner_arrays(vehicle, p, angle_above_torsion_bar, torque_scale)
    lt = lateral_tables_for(vehicle, int(round(dt * 1e9)))
    tv, ft = FX.tables_vectors(lt)
    cs = np.zeros(FX.N_CS, np.int64)
    FX.coef_set_kernel(p, tv, cs)
    x, P = np.zeros(5, np.int64), np.zeros(25, np.int64)
    aux, sat = np.zeros(FX.N_AUX, np.int64), np.zeros(FX.N_SAT, np.int64)
    FX.reset_kernel(cs, x, P, aux, sat)
    lsb = np.array([lt.state_lsb(i) for i in range(5)] + [lt.t_align_lsb(), 2.0 ** -lt.formats["z"]])
    params = Params(lp, tv, ft, lsb, np.array([FW_BOUND_N, MW_BOUND_NM]))
    state = State(
        p, cs, x, P, aux, sat, np.zeros((4, 16), np.int64), np.zeros(FX.N_IO, np.int64),
        E.new_filter_state(p), np.empty(N_OUT), np.zeros(N_SH), ls, lws,
    )  # fmt: skip
    return params, state


def params_changed(params: Params, state: State) -> None:
    """``p`` was changed from outside (a learned-state file): the coefficient set is quantised again."""
    FX.coef_set_kernel(state.p, params.tv, state.cs)


@njit(cache=True)
def shadow_compare(bound, counts, fw, mw, ffw, fmw, status):  # pragma: no cover - compiled
    """The shadow check: the fixed step's (fw, mw) against the float step's (ffw, fmw). Beyond
    ``bound`` (|dFw| [N], |dMw| [Nm]; a non-finite difference too) the step gets SHADOW_DEVIATION and
    is counted in ``counts`` (``SH_*``: count, largest |dFw|, largest |dMw|)."""
    dfw = abs(fw - ffw)
    dmw = abs(mw - fmw)
    if not (dfw <= bound[0] and dmw <= bound[1]):
        status |= SHADOW_DEVIATION
        counts[SH_COUNT] += 1.0
    if dfw > counts[SH_MAX_DFW]:
        counts[SH_MAX_DFW] = dfw
    if dmw > counts[SH_MAX_DMW]:
        counts[SH_MAX_DMW] = dmw
    return status


@njit(cache=True)
def step(params, state, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """One step of the firmware model, its shadow check and the learner (module docstring)."""
    tv, lsb = params.tv, params.lsb
    p, iout, f, fout = state.p, state.iout, state.shadow, state.shadow_out
    speed, angle, yaw = inp[I_SPEED], inp[I_STEERING_ANGLE], inp[I_YAW_RATE]
    tcol, tast, ay = inp[I_COLUMN_TORQUE], inp[I_ASSIST_TORQUE], inp[I_LAT_ACCEL]
    fresh_r = (fresh & FRESH_R) != 0
    fresh_t = (fresh & FRESH_T) == FRESH_T
    fresh_a = (fresh & FRESH_A) != 0
    v, s, y, c, a, q, flags = FX.quantise_kernel(tv, speed, angle, yaw, tcol, tast, ay)
    status = FX.step_kernel(
        tv, params.ft, state.cs, state.x, state.P, state.aux, state.sat, state.ws, t_ns,
        v, s, y, c, a, q, flags, fresh_r, fresh_t, fresh_a, mdps_ok, esc_ok, iout,
    )  # fmt: skip
    out[O_BETA] = iout[FX.IO_XB] * lsb[0]
    out[O_YAW] = iout[FX.IO_XR] * lsb[1]
    out[O_FW] = iout[FX.IO_FW] * lsb[2]
    out[O_MW] = iout[FX.IO_XMA] * lsb[3]
    out[O_FW_WIND] = iout[FX.IO_XFA] * lsb[2]
    out[O_MW_WIND] = iout[FX.IO_XMA] * lsb[3]
    out[O_T_ALIGN] = iout[FX.IO_TA] * lsb[5]
    out[O_BANK] = iout[FX.IO_BANK] * lsb[6]
    E.step_kernel(
        p, f.x, f.P, f.fs, f.ints, f.h, f.ph, t_ns, speed, angle, yaw, tcol, tast, ay,
        fresh_r, fresh_t, fresh_a, mdps_ok, esc_ok, fout,
    )  # fmt: skip
    status = shadow_compare(
        params.bound, state.shadow_counts, out[O_FW], out[O_MW], fout[O_FW], fout[O_MW], status
    )
    pushed = Ln.learner_step(
        params.lp, state.ls, state.lws, p, out, speed, angle, yaw, tcol, tast, ay, iout[FX.IO_Z] * lsb[6],
        mdps_ok and esc_ok and (status & VALID) != 0,
    )  # fmt: skip
    if pushed:
        FX.coef_set_kernel(p, tv, state.cs)
    # the centre-of-pressure blend of the reported moment, after the shadow check and the learner (both
    # see the filter's own M_wind); in float at the boundary as the overlay law (not in the integer step)
    E.wind_moment_output(p, out)
    out[O_LEARN] = state.ls[Ln.LS_STATE]
    out[O_GAIN] = E.overlay_gain(p)
    return status
