"""Backend ``float``: the lateral filter (:mod:`lde.estimator.lateral`) and the learner after it
(:mod:`lde.estimator.learner`), in float."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

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
from lde.estimator.outputs import O_GAIN, O_LEARN
from lde.params import Vehicle
from lde.status import VALID

NAME = "float"
DESCRIPTION = "the lateral filter with the lateral acceleration (wind apart from bank) and online learning"
LEARNS = True
SMOOTHABLE = True

#: the ``fresh`` bits of each measurement of the lateral filter: the yaw rate, both torques, the
#: lateral acceleration (one update per measurement whose CAN signal brought a new sample)
FRESH_R = 1 << I_YAW_RATE
FRESH_T = (1 << I_COLUMN_TORQUE) | (1 << I_ASSIST_TORQUE)
FRESH_A = 1 << I_LAT_ACCEL


class Params(NamedTuple):
    lp: np.ndarray  # (N_LP,) the learner's parameters (lde.estimator.learner L_*)


class State(NamedTuple):
    p: np.ndarray  # (N_P,) the filter's parameter vector (lde.estimator.lateral P_*, SI): the learner's
    filter: E.FilterState  # the lateral filter's state (estimate, covariance, aux slots, scratch)
    ls: np.ndarray  # (N_LS,) the learner's state (lde.estimator.learner LS_*)
    lws: np.ndarray  # (2, N3) the learner's workspace


def learner_arrays(
    vehicle: Vehicle, p: np.ndarray, angle_above_torsion_bar: bool, torque_scale: int = Ln.TS_KNOWN
) -> tuple[np.ndarray, ...]:
    """The learner's (parameters, state, workspace) for ``vehicle`` starting from the filter's ``p``
    (``torque_scale``: which torque's scale it learns, :func:`lde.estimator.learner.torque_scale_mode`)."""
    lp = Ln.learner_params(vehicle, angle_above_torsion_bar, torque_scale)
    prior = vehicle.corrections.friction or vehicle.learning.friction_prior
    return lp, Ln.init_state(p, lp, friction_prior=prior), np.zeros((2, Ln.N3))


def make(
    vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool, torque_scale: int = Ln.TS_KNOWN
) -> tuple[Params, State]:
    p = E.params_vector(vehicle, dt, angle_above_torsion_bar=angle_above_torsion_bar)
    lp, ls, lws = learner_arrays(vehicle, p, angle_above_torsion_bar, torque_scale)
    return Params(lp), State(p, E.new_filter_state(p), ls, lws)


@njit(cache=True)
def step(params, state, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """:func:`lde.estimator.lateral.step_kernel`, then :func:`lde.estimator.learner.learner_step` (which
    writes its pushes into the filter's parameter vector ``p``), then the reported wind moment and the
    overlay law's gain from the current parameters."""
    p, f, ls = state.p, state.filter, state.ls
    status = E.step_kernel(
        p, f.x, f.P, f.fs, f.ints, f.h, f.ph, t_ns,
        inp[I_SPEED], inp[I_STEERING_ANGLE], inp[I_YAW_RATE], inp[I_COLUMN_TORQUE], inp[I_ASSIST_TORQUE],
        inp[I_LAT_ACCEL], (fresh & FRESH_R) != 0, (fresh & FRESH_T) == FRESH_T, (fresh & FRESH_A) != 0,
        mdps_ok, esc_ok, out,
    )  # fmt: skip
    Ln.learner_step(
        params.lp, ls, state.lws, p, out,
        inp[I_SPEED], inp[I_STEERING_ANGLE], inp[I_YAW_RATE], inp[I_COLUMN_TORQUE], inp[I_ASSIST_TORQUE],
        inp[I_LAT_ACCEL], f.fs[E.F_ZFRIC], mdps_ok and esc_ok and (status & VALID) != 0,
    )  # fmt: skip
    E.wind_moment_output(p, out)
    out[O_LEARN] = ls[Ln.LS_STATE]
    out[O_GAIN] = E.overlay_gain(p)
    return status
