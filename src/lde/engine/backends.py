"""The estimator backends, chosen through one explicit registry that fails loudly.

===============  ==================================================================================
``fixed``        :mod:`firmware_model.lateral` + :mod:`lde.estimator.learner`: the lateral filter in integers
                 (an MDPS ECU without FPU), its float step (:mod:`lde.estimator.lateral`) with the same
                 parameters as a shadow at every step (a deviation beyond 5 N / 2 Nm sets
                 ``SHADOW_DEVIATION`` and is counted), the learner as a float slow task whose pushes
                 re-quantise the integer coefficient set. The default.
``float``        :mod:`lde.estimator.lateral` + :mod:`lde.estimator.learner`: the lateral filter with the
lateral
                 acceleration (wind apart from bank) and online learning, float.
``paper-fixed``  :mod:`firmware_model`: the paper's step (states beta, r, Fw, Mw) in integers, with
                 the ``paper`` step as its shadow at every step (the same bound and bit).
``paper``        :mod:`lde.estimator.paper`: the paper's float Kalman step, with the vehicle file's input
                 corrections (:mod:`lde.estimator.conditioning`).
===============  ==================================================================================

``lateral`` is an alias of ``float`` (the lateral filter's name before it became the default pair;
:data:`ALIASES`). Until the lateral filter had its fixed-point model, ``fixed`` / ``float`` named
today's ``paper-fixed`` / ``paper``.

A backend is a compiled step with the :mod:`lde.engine.loop` signature::

    step(bp, bs, t_ns, inputs, fresh, mdps_ok, esc_ok, out) -> status

``inputs``: the sampled inputs in SI (:data:`lde.can.profiles.INPUT_NAMES` order, raw: each backend
applies its own corrections); ``fresh``: bit i set when input i brought a new sample at this step;
``out``: the ``lde.estimator.paper.O_*`` slots. :func:`get_backend` raises :class:`lde.errors.ConfigError`
for a
name that is not registered; asking for ``fixed`` never yields ``float``. Each backend gets its own
compiled copy of the loop (``run``).

The shadow check (:func:`shadow_compare`) is one kernel for both fixed-point backends. ``paper-fixed``
may take its shadow's estimates precomputed by a ``paper`` engine on the other core
(:meth:`lde.engine.engine.Engine.feed`: its parameters never change). ``fixed`` computes its shadow inline:
the shadow runs on the parameters the fixed step's own learner pushed, which exist only once the
fixed step has run, so a float engine cannot run ahead of it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from firmware_model import lateral as FX
from firmware_model.fast import N_AUX, quantise_kernel, tables_vector
from firmware_model.fast import N_OUT as N_FIXED_OUT
from firmware_model.fast import reset_kernel as fixed_reset_kernel
from firmware_model.fast import run_batch as fixed_run_batch
from firmware_model.fast import step_kernel as fixed_step_kernel
from firmware_model.shadow import FW_BOUND_N, MW_BOUND_NM
from firmware_model.step import N_SAT
from firmware_model.tables import lateral_tables_for, tables_for
from lde.engine.loop import make_loop
from lde.engine.receiver import (
    I_ASSIST_TORQUE,
    I_COLUMN_TORQUE,
    I_LAT_ACCEL,
    I_SPEED,
    I_STEERING_ANGLE,
    I_STEERING_RATE,
    I_YAW_RATE,
)
from lde.errors import ConfigError
from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.conditioning import condition_kernel, corrections_vector, is_active, without_corrections
from lde.estimator.model import params_vector
from lde.estimator.paper import (
    LEARN_NONE,
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
    EstimatorState,
    new_workspace,
)
from lde.estimator.paper import run_batch as float_run_batch
from lde.estimator.paper import step_kernel as float_step_kernel
from lde.params import Vehicle
from lde.status import SHADOW_DEVIATION, VALID
from lde.units import STEP_S

__all__ = [
    "Backend",
    "BackendState",
    "ALIASES",
    "BACKENDS",
    "DEFAULT_BACKEND",
    "get_backend",
    "backend_names",
    "make_backend_state",
]


@dataclass
class BackendState:
    """A backend's compiled parameters and mutable state (tuples of arrays), plus named views for
    Python (``info``: e.g. the shadow counters, the learner's state)."""

    params: tuple
    state: tuple
    info: dict[str, Any] = field(default_factory=dict)
    shadow: str | None = None  # a backend whose estimates this one compares with (precomputable)

    def params_changed(self) -> None:
        """The parameter vector ``info["p"]`` was changed from outside (a learned-state file was
        loaded): a backend that derives constants from it re-derives them (``info["refresh"]``)."""
        refresh = self.info.get("refresh")
        if refresh is not None:
            refresh()

    def with_shadow(self, pre: np.ndarray) -> None:
        """Use ``pre`` (n, 2: Fw, Mw of the shadow backend per step of the next call) instead of
        computing the shadow inline; an empty array: compute it inline."""
        self.state = (*self.state[:-2], pre, np.zeros(1, np.int64))


@dataclass(frozen=True)
class Backend:
    """One registered backend: its name, what it is, how to make its state, its compiled loop."""

    name: str
    description: str
    make: Callable[[Vehicle, float, bool], BackendState]  # (vehicle, dt, angle_above_torsion_bar)
    run: Any  # the compiled loop of lde.engine.loop, specialised on this backend's step
    run_batch: Callable[..., Any] | None = (
        None  # the step over arrays on a grid (lde.estimator.paper.run_batch API)
    )
    learns: bool = False


# -------------------------------------------------------------------- the paper's step, float


@njit(cache=True, inline="always")
def _conditioned(cvec, corrects, inp):  # pragma: no cover - compiled
    """(steering_angle, yaw_rate, column_torque) after the vehicle file's corrections."""
    angle, yaw, col = inp[I_STEERING_ANGLE], inp[I_YAW_RATE], inp[I_COLUMN_TORQUE]
    if corrects:
        angle, yaw, col = condition_kernel(cvec, angle, inp[I_STEERING_RATE], yaw, col)
    return angle, yaw, col


@njit(cache=True, inline="always")
def _no_lateral(out):  # pragma: no cover - compiled
    out[O_FW_WIND] = np.nan
    out[O_MW_WIND] = np.nan
    out[O_BANK] = np.nan
    out[O_LEARN] = LEARN_NONE
    out[O_GAIN] = np.nan


@njit(cache=True)
def paper_step(bp, bs, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """:func:`lde.estimator.paper.step_kernel` after the vehicle file's corrections."""
    p, cvec, corrects = bp
    x, P, fs, ints, wk = bs
    angle, yaw, col = _conditioned(cvec, corrects, inp)
    status = float_step_kernel(
        p, x, P, fs, ints, wk, t_ns, inp[I_SPEED], angle, yaw, col, inp[I_ASSIST_TORQUE], mdps_ok, esc_ok, out
    )
    _no_lateral(out)
    return status


def _make_paper(vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool) -> BackendState:
    p = params_vector(without_corrections(vehicle), dt)
    st = EstimatorState.initial(p)
    bp = (p, corrections_vector(vehicle), is_active(vehicle))
    return BackendState(bp, (st.x, st.P, st.fs, st.ints, new_workspace()), {"state": st})


#: the paper's float step in the loop
run_paper = make_loop(paper_step, "run_paper")

# -------------------------------------------------------------------- the paper's step, fixed

# float counters of the shadow check: [deviating steps, max |dFw| N, max |dMw| Nm]
SH_COUNT, SH_MAX_DFW, SH_MAX_DMW = 0, 1, 2


@njit(cache=True, inline="always")
def shadow_compare(bound, shadow, fw, mw, ffw, fmw, status):  # pragma: no cover - compiled
    """The shadow check of a fixed-point step: its (fw, mw) against the float step's (ffw, fmw).
    Beyond ``bound`` (|dFw| [N], |dMw| [Nm]; a non-finite difference too) the step gets
    SHADOW_DEVIATION and is counted in ``shadow`` (``SH_*``: count, largest |dFw|, largest |dMw|)."""
    dfw = abs(fw - ffw)
    dmw = abs(mw - fmw)
    if not (dfw <= bound[0] and dmw <= bound[1]):
        status |= SHADOW_DEVIATION
        shadow[SH_COUNT] += 1.0
    if dfw > shadow[SH_MAX_DFW]:
        shadow[SH_MAX_DFW] = dfw
    if dmw > shadow[SH_MAX_DMW]:
        shadow[SH_MAX_DMW] = dmw
    return status


@njit(cache=True)
def paper_fixed_step(bp, bs, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """Quantise the (corrected) SI inputs, run the integer step, convert its estimate to SI (exact
    power-of-two scalings), and compare it with the float step's estimate (the shadow check):
    computed here, or, in a batch, taken from ``pre`` where a float engine computed it on the same
    inputs in a second thread (:meth:`lde.engine.engine.Engine.feed`; the same kernel, so the same
    numbers)."""
    tv, coef, lsb, fp, bound, cvec, corrects = bp
    x, P, aux, sat, ws, iout, fx, fP, ffs, fints, fwk, fout, shadow, pre, pre_i = bs
    angle, yaw, col = _conditioned(cvec, corrects, inp)
    speed, assist = inp[I_SPEED], inp[I_ASSIST_TORQUE]
    v, s, y, c, a, flags = quantise_kernel(tv, speed, angle, yaw, col, assist)
    status = fixed_step_kernel(
        tv, coef, x, P, aux, sat, ws, t_ns, v, s, y, c, a, flags, mdps_ok, esc_ok, iout
    )
    out[O_BETA] = iout[0] * lsb[0]
    out[O_YAW] = iout[1] * lsb[1]
    out[O_FW] = iout[2] * lsb[2]
    out[O_MW] = iout[3] * lsb[3]
    out[O_T_ALIGN] = iout[4] * lsb[4]
    _no_lateral(out)
    j = pre_i[0]
    if j < pre.shape[0]:  # precomputed by the shadow engine
        ffw, fmw = pre[j, 0], pre[j, 1]
        pre_i[0] = j + 1
    else:
        float_step_kernel(
            fp, fx, fP, ffs, fints, fwk, t_ns, speed, angle, yaw, col, assist, mdps_ok, esc_ok, fout
        )
        ffw, fmw = fout[O_FW], fout[O_MW]
    return shadow_compare(bound, shadow, out[O_FW], out[O_MW], ffw, fmw, status)


def _make_paper_fixed(vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool) -> BackendState:
    v = without_corrections(vehicle)  # the inputs are corrected before the quantisation
    tb = tables_for(v, int(round(dt * 1e9)))
    tv = tables_vector(tb)
    x, P = np.zeros(4, np.int64), np.zeros(16, np.int64)
    aux = np.zeros(N_AUX, np.int64)
    sat = np.zeros(N_SAT, np.int64)
    fixed_reset_kernel(tv, x, P, aux, sat)
    lsb = np.array([tb.state_lsb(0), tb.state_lsb(1), tb.state_lsb(2), tb.state_lsb(3), tb.t_align_lsb()])
    fp = params_vector(v, dt)
    fst = EstimatorState.initial(fp)
    shadow = np.zeros(3)
    params = (
        tv,
        tb.coef_array(),
        lsb,
        fp,
        np.array([FW_BOUND_N, MW_BOUND_NM]),
        corrections_vector(vehicle),
        is_active(vehicle),
    )
    state = (
        x, P, aux, sat, np.zeros((4, 16), np.int64), np.zeros(N_FIXED_OUT, np.int64),
        fst.x, fst.P, fst.fs, fst.ints, new_workspace(), np.empty(N_OUT), shadow,
        np.zeros((0, 2)),  # pre: shadow estimates of this call's steps (batch), or none
        np.zeros(1, np.int64),  # pre_i: the next row of pre
    )  # fmt: skip
    info = {"tables": tb, "sat": sat, "shadow": shadow, "shadow_state": fst}
    return BackendState(params, state, info, shadow="paper")


#: the paper's fixed-point step and its float shadow in the loop
run_paper_fixed = make_loop(paper_fixed_step, "run_paper_fixed")

# -------------------------------------------------------------------- the lateral filter, float

FRESH_R = 1 << I_YAW_RATE
FRESH_T = (1 << I_COLUMN_TORQUE) | (1 << I_ASSIST_TORQUE)
FRESH_A = 1 << I_LAT_ACCEL


@njit(cache=True)
def lateral_step(bp, bs, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """:func:`lde.estimator.lateral.step_kernel` and :func:`lde.estimator.learner.learner_step` after it (the
    learner
    writes its pushes into the filter's parameter vector ``p``)."""
    lp = bp[0]
    p, x, P, fs, ints, h, ph, ls, lws = bs
    status = E.step_kernel(
        p,
        x,
        P,
        fs,
        ints,
        h,
        ph,
        t_ns,
        inp[I_SPEED],
        inp[I_STEERING_ANGLE],
        inp[I_YAW_RATE],
        inp[I_COLUMN_TORQUE],
        inp[I_ASSIST_TORQUE],
        inp[I_LAT_ACCEL],
        (fresh & FRESH_R) != 0,
        (fresh & FRESH_T) == FRESH_T,
        (fresh & FRESH_A) != 0,
        mdps_ok,
        esc_ok,
        out,
    )
    Ln.learner_step(
        lp,
        ls,
        lws,
        p,
        out,
        inp[I_SPEED],
        inp[I_STEERING_ANGLE],
        inp[I_YAW_RATE],
        inp[I_COLUMN_TORQUE],
        inp[I_ASSIST_TORQUE],
        inp[I_LAT_ACCEL],
        fs[E.F_ZFRIC],
        mdps_ok and esc_ok and (status & VALID) != 0,
    )
    E.wind_moment_output(p, out)
    out[O_LEARN] = ls[Ln.LS_STATE]
    # the overlay law with the learned trail K/Cf (the holding torque is 2 K alpha_f / N)
    out[O_GAIN] = p[E.P_K] / (p[E.P_N] * p[E.P_CF] * (p[E.P_LF] + p[E.P_LR]))
    return status


def _make_lateral(vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool) -> BackendState:
    p = E.params_vector(vehicle, dt, angle_above_torsion_bar=angle_above_torsion_bar)
    lp = Ln.learner_params(vehicle, angle_above_torsion_bar)
    ls = Ln.init_state(p, lp, friction_prior=vehicle.corrections.friction or vehicle.learning.friction_prior)
    x, P = np.zeros(E.NX), np.zeros((E.NX, E.NX))
    fs, ints = np.zeros(E.N_F), np.zeros(E.N_I, np.int64)
    E.reset_kernel(p, x, P, fs, ints)
    state = (p, x, P, fs, ints, np.zeros(E.NX), np.zeros(E.NX), ls, np.zeros((2, Ln.N3)))
    return BackendState((lp,), state, {"p": p, "learner": ls, "lp": lp})


#: the lateral filter and the learner in the loop
run_lateral = make_loop(lateral_step, "run_lateral")

# -------------------------------------------------------------------- the lateral filter, fixed


@njit(cache=True)
def lateral_fixed_step(bp, bs, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """Quantise the SI inputs, run the integer lateral step (:func:`firmware_model.lateral.step_kernel`)
    on the current coefficient set, convert its estimate to SI (exact power-of-two scalings); run the
    float step (:func:`lde.estimator.lateral.step_kernel`) on the same inputs and the same parameter vector
    as its shadow and compare (:func:`shadow_compare`); then the learner on the fixed estimate. When
    the learner pushes (every 128 steps) the slow task re-quantises the coefficient set
    (:func:`firmware_model.lateral.coef_set_kernel`): from the next step both filters run on the new
    parameters."""
    lp, tv, ft, lsb, bound = bp
    p, cs, x, P, aux, sat, ws, iout, fx, fP, ffs, fints, fh, fph, fout, shadow, ls, lws = bs
    speed, angle, yaw = inp[I_SPEED], inp[I_STEERING_ANGLE], inp[I_YAW_RATE]
    tcol, tast, ay = inp[I_COLUMN_TORQUE], inp[I_ASSIST_TORQUE], inp[I_LAT_ACCEL]
    fresh_r = (fresh & FRESH_R) != 0
    fresh_t = (fresh & FRESH_T) == FRESH_T
    fresh_a = (fresh & FRESH_A) != 0
    v, s, y, c, a, q, flags = FX.quantise_kernel(tv, speed, angle, yaw, tcol, tast, ay)
    status = FX.step_kernel(
        tv, ft, cs, x, P, aux, sat, ws, t_ns, v, s, y, c, a, q, flags, fresh_r, fresh_t, fresh_a,
        mdps_ok, esc_ok, iout,
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
        p, fx, fP, ffs, fints, fh, fph, t_ns, speed, angle, yaw, tcol, tast, ay, fresh_r, fresh_t, fresh_a,
        mdps_ok, esc_ok, fout,
    )  # fmt: skip
    status = shadow_compare(bound, shadow, out[O_FW], out[O_MW], fout[O_FW], fout[O_MW], status)
    pushed = Ln.learner_step(
        lp, ls, lws, p, out, speed, angle, yaw, tcol, tast, ay, iout[FX.IO_Z] * lsb[6],
        mdps_ok and esc_ok and (status & VALID) != 0,
    )  # fmt: skip
    if pushed:
        FX.coef_set_kernel(p, tv, cs)
    # the centre-of-pressure blend of the reported moment, after the shadow check and the learner (both
    # see the filter's own M_wind); in float at the boundary as the overlay law (not in the integer step)
    E.wind_moment_output(p, out)
    out[O_LEARN] = ls[Ln.LS_STATE]
    # the overlay law's gain from the current (learned) parameters, as the float backend (the overlay
    # law runs in float after the estimator in this model, for every backend)
    out[O_GAIN] = p[E.P_K] / (p[E.P_N] * p[E.P_CF] * (p[E.P_LF] + p[E.P_LR]))
    return status


def _make_lateral_fixed(vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool) -> BackendState:
    p = E.params_vector(vehicle, dt, angle_above_torsion_bar=angle_above_torsion_bar)
    lp = Ln.learner_params(vehicle, angle_above_torsion_bar)
    ls = Ln.init_state(p, lp, friction_prior=vehicle.corrections.friction or vehicle.learning.friction_prior)
    lt = lateral_tables_for(vehicle, int(round(dt * 1e9)))
    tv, ft = FX.tables_vectors(lt)
    cs = np.zeros(FX.N_CS, np.int64)
    FX.coef_set_kernel(p, tv, cs)
    x, P = np.zeros(5, np.int64), np.zeros(25, np.int64)
    aux, sat = np.zeros(FX.N_AUX, np.int64), np.zeros(FX.N_SAT, np.int64)
    FX.reset_kernel(cs, x, P, aux, sat)
    fx, fP = np.zeros(E.NX), np.zeros((E.NX, E.NX))
    ffs, fints = np.zeros(E.N_F), np.zeros(E.N_I, np.int64)
    E.reset_kernel(p, fx, fP, ffs, fints)
    lsb = np.array([lt.state_lsb(i) for i in range(5)] + [lt.t_align_lsb(), 2.0 ** -lt.formats["z"]])
    shadow = np.zeros(3)
    params = (lp, tv, ft, lsb, np.array([FW_BOUND_N, MW_BOUND_NM]))
    state = (
        p, cs, x, P, aux, sat, np.zeros((4, 16), np.int64), np.zeros(FX.N_IO, np.int64),
        fx, fP, ffs, fints, np.zeros(E.NX), np.zeros(E.NX), np.empty(N_OUT), shadow,
        ls, np.zeros((2, Ln.N3)),
    )  # fmt: skip

    def refresh() -> None:
        FX.coef_set_kernel(p, tv, cs)

    info = {
        "p": p,
        "learner": ls,
        "lp": lp,
        "tables": lt,
        "coef_set": cs,
        "sat": sat,
        "shadow": shadow,
        "refresh": refresh,
        "shadow_state": (fx, fP, ffs, fints),
        "state": (x, P, aux),
    }
    return BackendState(params, state, info)


#: the lateral filter in fixed point, its float shadow and the learner in the loop
run_lateral_fixed = make_loop(lateral_fixed_step, "run_lateral_fixed")

# -------------------------------------------------------------------- registry

#: the backend of ``lde run`` / ``lde replay`` / ``lde demo`` without ``--backend``
DEFAULT_BACKEND = "fixed"

BACKENDS: dict[str, Backend] = {
    "fixed": Backend(
        "fixed",
        "the lateral filter in fixed point (firmware model) with its float shadow check and the learner",
        _make_lateral_fixed,
        run_lateral_fixed,
        None,
        learns=True,
    ),
    "float": Backend(
        "float",
        "the lateral filter with the lateral acceleration (wind apart from bank) and online learning",
        _make_lateral,
        run_lateral,
        None,
        learns=True,
    ),
    "paper-fixed": Backend(
        "paper-fixed",
        "the paper's step in fixed point (firmware model) with the float shadow check",
        _make_paper_fixed,
        run_paper_fixed,
        fixed_run_batch,
    ),
    "paper": Backend("paper", "the paper's float Kalman step", _make_paper, run_paper, float_run_batch),
}


#: other names of registered backends (accepted by :func:`get_backend` and the CLI)
ALIASES: dict[str, str] = {"lateral": "float"}


def backend_names() -> tuple[str, ...]:
    return tuple(BACKENDS)


def get_backend(name: str) -> Backend:
    """The backend registered under ``name`` (or an alias of it); ConfigError otherwise (no
    fallback)."""
    try:
        return BACKENDS[ALIASES.get(name, name)]
    except KeyError:
        raise ConfigError(f"unknown backend {name!r}: choose one of {', '.join(BACKENDS)}") from None


def make_backend_state(
    name: str, vehicle: Vehicle, dt: float = STEP_S, angle_above_torsion_bar: bool = False
) -> BackendState:
    """:func:`get_backend` and its state for ``vehicle``."""
    return get_backend(name).make(vehicle, dt, angle_above_torsion_bar)
