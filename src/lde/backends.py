"""The estimator backends, chosen through one explicit registry that fails loudly.

=========  ======================================================================================
``float``  :mod:`lde.step`: the float Kalman step (the reference).
``fixed``  :mod:`firmware_model`: the integer (fixed-point) step of an MDPS ECU without FPU, with
           the float step as a shadow at every step: a deviation beyond 5 N / 2 Nm sets
           ``SHADOW_DEVIATION`` and is counted.
=========  ======================================================================================

A backend is a compiled step with the :mod:`lde.pipeline` signature plus how to build its
parameters and state for a vehicle. :func:`get_backend` raises :class:`lde.errors.ConfigError` for a
name that is not registered; asking for ``fixed`` never yields ``float``. Each backend gets its own
compiled entry point (``run``): :func:`lde.pipeline.run_loop` specialised on its step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from firmware_model.fast import N_AUX, quantise_kernel, tables_vector
from firmware_model.fast import N_OUT as N_FIXED_OUT
from firmware_model.fast import reset_kernel as fixed_reset_kernel
from firmware_model.fast import run_batch as fixed_run_batch
from firmware_model.fast import step_kernel as fixed_step_kernel
from firmware_model.shadow import FW_BOUND_N, MW_BOUND_NM
from firmware_model.step import N_SAT
from firmware_model.tables import tables_for

from .conditioning import without_corrections
from .errors import ConfigError
from .model import params_vector
from .params import Vehicle
from .pipeline import make_loop
from .status import SHADOW_DEVIATION
from .step import N_OUT, O_BETA, O_FW, O_MW, O_T_ALIGN, O_YAW, EstimatorState, new_workspace
from .step import run_batch as float_run_batch
from .step import step_kernel as float_step_kernel
from .units import STEP_S

__all__ = ["Backend", "BackendState", "BACKENDS", "get_backend", "backend_names"]


@dataclass
class BackendState:
    """A backend's compiled parameters and mutable state (tuples of arrays), plus named views for
    Python (``info``: e.g. the shadow counters)."""

    params: tuple
    state: tuple
    info: dict[str, Any]
    shadow: str | None = None  # a backend whose estimates this one compares with (precomputable)

    def with_shadow(self, pre: np.ndarray) -> None:
        """Use ``pre`` (n, 2: Fw, Mw of the shadow backend per step of the next call) instead of
        computing the shadow inline; an empty array: compute it inline."""
        self.state = (*self.state[:-2], pre, np.zeros(1, np.int64))


@dataclass(frozen=True)
class Backend:
    """One registered backend: its name, what it is, how to make its state, and its compiled loop."""

    name: str
    description: str
    make: Callable[[Vehicle, float], BackendState]
    run: Any  # the compiled loop of lde.pipeline, specialised on this backend's step
    run_batch: Callable[..., Any]  # the step over arrays of inputs on a grid (lde.step.run_batch API)


# ------------------------------------------------------------------------------------ float


@njit(cache=True, inline="always")
def float_step(
    bp,
    bs,
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    lat_accel,
    steering_rate,
    mdps_ok,
    esc_ok,
    out,
):  # pragma: no cover
    """:func:`lde.step.step_kernel` with the pipeline's signature."""
    x, P, fs, ints, wk = bs
    return float_step_kernel(
        bp[0],
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
    )


def _make_float(vehicle: Vehicle, dt: float) -> BackendState:
    p = params_vector(without_corrections(vehicle), dt)
    st = EstimatorState.initial(p)
    return BackendState((p,), (st.x, st.P, st.fs, st.ints, new_workspace()), {"state": st})


#: :func:`lde.pipeline._run_loop` with the float step
run_float = make_loop(float_step, "run_float")


# ------------------------------------------------------------------------------------ fixed

# float counters of the shadow check: [deviating steps, max |dFw| N, max |dMw| Nm]
SH_COUNT, SH_MAX_DFW, SH_MAX_DMW = 0, 1, 2


@njit(cache=True, inline="always")
def fixed_step(
    bp,
    bs,
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    lat_accel,
    steering_rate,
    mdps_ok,
    esc_ok,
    out,
):  # pragma: no cover
    """Quantise the SI inputs, run the integer step, convert its estimate to SI (exact power-of-two
    scalings), and compare it with the float step's estimate (the shadow check): computed here, or,
    in a batch, taken from ``pre`` where a float engine computed it on the same inputs in a second
    thread (:meth:`lde.engine.Engine.feed`; the same kernel, so the same numbers)."""
    tv, coef, lsb, fp, bound = bp
    x, P, aux, sat, ws, iout, fx, fP, ffs, fints, fwk, fout, shadow, pre, pre_i = bs
    v, s, y, c, a, flags = quantise_kernel(tv, speed, steering_angle, yaw_rate, column_torque, assist_torque)
    status = fixed_step_kernel(
        tv, coef, x, P, aux, sat, ws, t_ns, v, s, y, c, a, flags, mdps_ok, esc_ok, iout
    )
    out[O_BETA] = iout[0] * lsb[0]
    out[O_YAW] = iout[1] * lsb[1]
    out[O_FW] = iout[2] * lsb[2]
    out[O_MW] = iout[3] * lsb[3]
    out[O_T_ALIGN] = iout[4] * lsb[4]
    j = pre_i[0]
    if j < pre.shape[0]:  # precomputed by the shadow engine
        ffw, fmw = pre[j, 0], pre[j, 1]
        pre_i[0] = j + 1
    else:
        float_step_kernel(
            fp,
            fx,
            fP,
            ffs,
            fints,
            fwk,
            t_ns,
            speed,
            steering_angle,
            yaw_rate,
            column_torque,
            assist_torque,
            mdps_ok,
            esc_ok,
            fout,
        )
        ffw, fmw = fout[O_FW], fout[O_MW]
    dfw = abs(out[O_FW] - ffw)
    dmw = abs(out[O_MW] - fmw)
    if not (dfw <= bound[0] and dmw <= bound[1]):
        status |= SHADOW_DEVIATION
        shadow[SH_COUNT] += 1.0
    if dfw > shadow[SH_MAX_DFW]:
        shadow[SH_MAX_DFW] = dfw
    if dmw > shadow[SH_MAX_DMW]:
        shadow[SH_MAX_DMW] = dmw
    return status


def _make_fixed(vehicle: Vehicle, dt: float) -> BackendState:
    v = without_corrections(vehicle)  # the pipeline conditions the inputs before the step
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
    params = (tv, tb.coef_array(), lsb, fp, np.array([FW_BOUND_N, MW_BOUND_NM]))
    state = (
        x,
        P,
        aux,
        sat,
        np.zeros((4, 16), np.int64),
        np.zeros(N_FIXED_OUT, np.int64),
        fst.x,
        fst.P,
        fst.fs,
        fst.ints,
        new_workspace(),
        np.empty(N_OUT),
        shadow,
        np.zeros((0, 2)),  # pre: shadow estimates of this call's steps (batch), or none
        np.zeros(1, np.int64),  # pre_i: the next row of pre
    )
    return BackendState(
        params, state, {"tables": tb, "sat": sat, "shadow": shadow, "shadow_state": fst}, shadow="float"
    )


#: :func:`lde.pipeline._run_loop` with the fixed-point step and its float shadow
run_fixed = make_loop(fixed_step, "run_fixed")


# ------------------------------------------------------------------------------------ registry

BACKENDS: dict[str, Backend] = {
    "fixed": Backend(
        "fixed",
        "fixed-point firmware model with the float shadow check",
        _make_fixed,
        run_fixed,
        fixed_run_batch,
    ),
    "float": Backend("float", "float Kalman step (the reference)", _make_float, run_float, float_run_batch),
}


def backend_names() -> tuple[str, ...]:
    return tuple(BACKENDS)


def get_backend(name: str) -> Backend:
    """The backend registered under ``name``; ConfigError otherwise (no fallback)."""
    try:
        return BACKENDS[name]
    except KeyError:
        raise ConfigError(f"unknown backend {name!r}: choose one of {', '.join(BACKENDS)}") from None


def make_backend_state(name: str, vehicle: Vehicle, dt: float = STEP_S) -> BackendState:
    """:func:`get_backend` and its state for ``vehicle``."""
    return get_backend(name).make(vehicle, dt)
