"""Input conditioning: what the paper's model neglects, removed from the inputs before the step.

The paper's measurement ``T_align = N (T_column + T_assist)`` (eq. 11) and its road-wheel angle
``delta_f = delta_sw / N`` assume an ideal steering and ideal sensors. Real ones add terms that the
filter can only explain as a disturbance (docs/design/studies.md, "What the paper neglects"):

- Coulomb friction of rack and column ``T_fric`` (0.3-1 Nm at the column): the driver and the
  motor push it along with the aligning torque, so ``N (T_column + T_assist)`` over-reads
  ``T_align`` by ``N T_fric`` while the wheel turns left and under-reads it while it turns right.
  0.35 Nm at the column is ~5 Nm at the kingpins, ~50-100 N of Fw;
- the torsion-bar twist when the angle sensor sits above the torsion bar (profile ``hyundai``'s
  SAS): the sensor reads ``N delta_f + c_tb T_column``;
- a steering-angle offset, a yaw-rate bias and a torque offset: each a steady residual.

Per step, with the vehicle file's ``[corrections]`` (:class:`lde.params.InputCorrections`; SI):

    T_column' = T_column - T_fric tanh(delta_sw_dot / w) - T_0 / N
    delta_sw' = delta_sw - c_tb T_column - d_sw
    r'        = r - b_r

``delta_sw_dot`` is the MDPS's steering-wheel rate (left positive); where it is not finite the
friction term is zero. The friction sign needs the direction of the rate: a profile whose rate is a
magnitude (``hyundai``'s ``SAS_Speed``) cannot use a friction correction
(:func:`check_profile`). All zero is the paper's estimator and passes the inputs through unchanged.

Both backends condition their inputs with the same compiled :func:`condition_kernel`, live per step
and in replay over arrays (:func:`condition_arrays` loops over the same scalar kernel, so live and
replay stay bit-identical). ``lde calibrate`` identifies the values from a drive without disturbance.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numba import njit

from lde.errors import ConfigError
from lde.params import InputCorrections, Vehicle

C_FRICTION, C_WIDTH, C_TORSION, C_STEER_OFFSET, C_YAW_BIAS, C_TORQUE_OFFSET, C_ACTIVE = range(7)
N_C = 7


def corrections_vector(vehicle: Vehicle) -> np.ndarray:
    """The vehicle's corrections as the float64 vector the kernels read (``C_*`` slots)."""
    c: InputCorrections = vehicle.corrections
    v = np.zeros(N_C)
    v[C_FRICTION] = c.friction
    v[C_WIDTH] = c.friction_rate_width
    v[C_TORSION] = c.torsion_compliance
    v[C_STEER_OFFSET] = c.steer_offset
    v[C_YAW_BIAS] = c.yaw_bias
    v[C_TORQUE_OFFSET] = c.align_offset / vehicle.steering.ratio
    v[C_ACTIVE] = 0.0 if c.is_identity else 1.0
    return v


def is_active(vehicle: Vehicle) -> bool:
    """The vehicle file asks for any correction."""
    return not vehicle.corrections.is_identity


def check_profile(vehicle: Vehicle, rate_signed: bool, profile_name: str = "") -> None:
    """ConfigError when the friction correction is asked for but the profile's steering rate is a
    magnitude (its sign is what the correction needs)."""
    if vehicle.corrections.friction != 0.0 and not rate_signed:
        raise ConfigError(
            f"vehicle {vehicle.name!r} sets [corrections] steering_friction_Nm = "
            f"{vehicle.corrections.friction:g}, but profile {profile_name or '?'!r} carries the steering "
            "rate as a magnitude: the friction's sign "
            "cannot be known. Set steering_friction_Nm = 0 for this profile."
        )


@njit(cache=True, inline="always")
def condition_kernel(c, steering_angle, steering_rate, yaw_rate, column_torque):  # pragma: no cover
    """(steering_angle', yaw_rate', column_torque') after the corrections (module docstring)."""
    if c[C_ACTIVE] == 0.0:
        return steering_angle, yaw_rate, column_torque
    col = column_torque - c[C_TORQUE_OFFSET]
    if c[C_FRICTION] != 0.0 and np.isfinite(steering_rate):
        col -= c[C_FRICTION] * np.tanh(steering_rate / c[C_WIDTH])
    angle = steering_angle - c[C_TORSION] * column_torque - c[C_STEER_OFFSET]
    return angle, yaw_rate - c[C_YAW_BIAS], col


@njit(cache=True, nogil=True)
def _condition_loop(c, angle, rate, yaw, col, angle_out, yaw_out, col_out):  # pragma: no cover - compiled
    for k in range(angle.shape[0]):
        angle_out[k], yaw_out[k], col_out[k] = condition_kernel(c, angle[k], rate[k], yaw[k], col[k])


def condition_arrays(
    vehicle: Vehicle,
    steering_angle: np.ndarray,
    steering_rate: np.ndarray | None,
    yaw_rate: np.ndarray,
    column_torque: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(steering_angle', yaw_rate', column_torque') for arrays of step inputs (SI; the same length,
    which the callers check: :func:`lde.estimator.paper.run_batch`, the fixed backend, the grid).

    ``steering_rate`` None means "not available": the friction term is then zero, which is an error
    when the vehicle asks for it (ConfigError). Identity corrections return the inputs themselves.
    """
    if not is_active(vehicle):
        return steering_angle, yaw_rate, column_torque
    angle = np.ascontiguousarray(steering_angle, dtype=np.float64)
    n = angle.shape[0]
    if steering_rate is None:
        if vehicle.corrections.friction != 0.0:
            raise ConfigError(
                f"vehicle {vehicle.name!r} corrects steering friction, which needs the steering rate"
            )
        rate = np.full(n, np.nan)
    else:
        rate = np.ascontiguousarray(steering_rate, dtype=np.float64)
    yaw = np.ascontiguousarray(yaw_rate, dtype=np.float64)
    col = np.ascontiguousarray(column_torque, dtype=np.float64)
    out = (np.empty(n), np.empty(n), np.empty(n))
    _condition_loop(corrections_vector(vehicle), angle, rate, yaw, col, *out)
    return out


def without_corrections(vehicle: Vehicle) -> Vehicle:
    """The vehicle with identity corrections: for a filter that receives already conditioned inputs
    (the fixed backend's float shadow)."""
    if not is_active(vehicle):
        return vehicle
    return replace(vehicle, corrections=InputCorrections())
