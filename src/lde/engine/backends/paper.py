"""Backend ``paper``: the paper's float Kalman step (:mod:`lde.estimator.paper`; states beta, r, Fw,
Mw), after the vehicle file's input corrections (:mod:`lde.estimator.conditioning`): the float
reference of the seed (the study's Table 1 and Fig. 12 reproduction, the tests' oracle)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from lde.engine.receiver import (
    I_ASSIST_TORQUE,
    I_COLUMN_TORQUE,
    I_SPEED,
    I_STEERING_ANGLE,
    I_STEERING_RATE,
    I_YAW_RATE,
)
from lde.estimator import paper as K
from lde.estimator.conditioning import condition_kernel, corrections_vector, is_active, without_corrections
from lde.estimator.model import params_vector
from lde.estimator.outputs import LEARN_NONE, O_BANK, O_FW_WIND, O_GAIN, O_LEARN, O_MW_WIND
from lde.params import Vehicle

NAME = "paper"
DESCRIPTION = "the paper's float Kalman step"
LEARNS = False


class Params(NamedTuple):
    p: np.ndarray  # the model's parameter vector (lde.estimator.model P_*; SI)
    cvec: np.ndarray  # the vehicle file's input corrections (lde.estimator.conditioning)
    corrects: bool  # any correction to apply


class State(NamedTuple):
    x: np.ndarray  # (4,) [beta rad, r rad/s, Fw N, Mw Nm], the a-priori estimate for the next step
    P: np.ndarray  # (4, 4) its covariance (SI units squared)
    fs: np.ndarray  # (N_FSTATE,) float aux slots (lde.estimator.paper F_*)
    ints: np.ndarray  # (N_ISTATE,) int64 aux slots (lde.estimator.paper I_*)
    wk: tuple  # the step's scratch arrays (lde.estimator.paper.new_workspace)


def make(
    vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool, torque_scale: int = 0
) -> tuple[Params, State]:
    """The paper's filter learns nothing: ``torque_scale`` must be 0 (both torques in Nm; the engine
    refuses a profile with a torque of unknown scale for a backend that does not learn)."""
    p = params_vector(without_corrections(vehicle), dt)
    st = K.EstimatorState.initial(p)
    params = Params(p, corrections_vector(vehicle), is_active(vehicle))
    return params, State(st.x, st.P, st.fs, st.ints, K.new_workspace())


@njit(cache=True)
def step(params, state, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """:func:`lde.estimator.paper.step_kernel` after the vehicle file's corrections."""
    angle, yaw, col = inp[I_STEERING_ANGLE], inp[I_YAW_RATE], inp[I_COLUMN_TORQUE]
    if params.corrects:
        angle, yaw, col = condition_kernel(params.cvec, angle, inp[I_STEERING_RATE], yaw, col)
    status = K.step_kernel(
        params.p, state.x, state.P, state.fs, state.ints, state.wk, t_ns,
        inp[I_SPEED], angle, yaw, col, inp[I_ASSIST_TORQUE], mdps_ok, esc_ok, out,
    )  # fmt: skip
    out[O_FW_WIND] = np.nan
    out[O_MW_WIND] = np.nan
    out[O_BANK] = np.nan
    out[O_LEARN] = LEARN_NONE
    out[O_GAIN] = np.nan
    return status
