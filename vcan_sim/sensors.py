"""Sensors: what the MDPS and the ESC report about the plant, with noise, bias and delay.

Each estimator input (SI, ISO signs; names of :data:`lde.can.profiles.INPUT_NAMES`) is read from the
plant's output rows at the frame's sample (the last sub-step at or before the frame time)::

    column_torque  = T_column(k - d) + b + n      torsion-bar torque, delayed by the MDPS
    assist_torque  = T_assist(k - d) + b + n      total motor torque (boost + overlay), delayed
    steering_angle = th(k) + b + n                steering angle (steering-wheel scale, see below)
    steering_rate  = w(k) + n
    yaw_rate       = r(k) + b + n
    lat_accel      = a_y,meas(k) + b + n          body accelerometer (tire + aero force / m + g sin roll)
    speed          = vx(k) + n

Where the angle is sensed matters: the torsion bar twists by T_column / k_tb (about 1.5 deg at
3 Nm), so the steering-wheel angle differs from N delta_f. A column MDPS senses its angle at the
motor, below the torsion bar: messages in :data:`PINION_ANGLE_MESSAGES` (the ``lde`` profile's
MDPS_Sensors) carry the pinion angle th_p (= N delta_f) and rate (unless ``[sim.sensors]
mdps_angle_at_motor = false``); a steering-angle sensor at the top of the column (the ``hyundai``
profile's SAS11) carries the steering-wheel angle th_sw and rate, twist included (unless
``sas_angle_at_motor = true``: a car whose angle signal is the motor position). Both positions can
be modelled on both profiles (:func:`angle_below_torsion_bar`).

``d`` = round(mdps_delay / h) sub-steps (the paper's 3.9 ms computation delay), ``b`` the
configured bias, ``n`` white Gaussian noise (seeded, drawn once per frame for the whole run so that
stepping and the fast path give identical values). Quantisation is the DBC's scaling, applied when
the frame is encoded (:mod:`lde.can.codec`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .config import SensorParams
from .plant import O_AY, O_DSW, O_R, O_TAST, O_TCOL, O_THP, O_VX, O_WP, O_WSW

#: messages whose steering angle is sensed below the torsion bar (the MDPS motor's position)
PINION_ANGLE_MESSAGES = frozenset({"MDPS_Sensors"})
#: separate steering-angle sensor messages: at the steering wheel unless ``sas_angle_at_motor``
SAS_ANGLE_MESSAGES = frozenset({"SAS11"})


def angle_below_torsion_bar(sp: SensorParams, message: str) -> bool:
    """True if ``message`` carries the pinion angle and rate (below the torsion bar), False if the
    steering-wheel angle and rate (above it, the twist T_column / k_tb included)."""
    if message in PINION_ANGLE_MESSAGES:
        return sp.mdps_angle_at_motor
    if message in SAS_ANGLE_MESSAGES:
        return sp.sas_angle_at_motor
    return False


#: input -> (output column, delayed by the MDPS, noise attribute, bias attribute or None)
SENSOR_MAP: dict[str, tuple[int, bool, str, str | None]] = {
    "column_torque": (O_TCOL, True, "column_torque_noise", "column_torque_bias"),
    "assist_torque": (O_TAST, True, "assist_torque_noise", "assist_torque_bias"),
    "steering_angle": (O_DSW, False, "steering_angle_noise", "steering_angle_bias"),
    "steering_rate": (O_WSW, False, "steering_rate_noise", None),
    "yaw_rate": (O_R, False, "yaw_rate_noise", "yaw_rate_bias"),
    "lat_accel": (O_AY, False, "lat_accel_noise", "lat_accel_bias"),
    "speed": (O_VX, False, "speed_noise", None),
}


@dataclass(frozen=True)
class SensorNoise:
    """Pre-drawn noise of one message's inputs: input name -> array [n_frames] (SI)."""

    values: dict[str, np.ndarray]

    @classmethod
    def draw(cls, inputs: tuple[str, ...], n: int, sp: SensorParams, rng: np.random.Generator) -> SensorNoise:
        return cls({name: rng.standard_normal(n) * getattr(sp, SENSOR_MAP[name][2]) for name in inputs})


def measure(
    inputs: tuple[str, ...],
    rows: np.ndarray,
    rows_delayed: np.ndarray,
    noise: SensorNoise,
    sl: slice,
    sp: SensorParams,
    pinion_angle: bool = False,
) -> dict[str, np.ndarray]:
    """SI measurements of ``inputs`` for frames ``sl`` of a message.

    ``rows`` / ``rows_delayed``: plant output rows at the frames' samples and ``d`` sub-steps before;
    ``pinion_angle``: the angle and rate are sensed below the torsion bar (see the module doc).
    """
    out: dict[str, np.ndarray] = {}
    for name in inputs:
        col, delayed, _, bias_attr = SENSOR_MAP[name]
        if pinion_angle and col in _PINION:
            col = _PINION[col]
        src = rows_delayed if delayed else rows
        bias = getattr(sp, bias_attr) if bias_attr else 0.0
        out[name] = src[:, col] + bias + noise.values[name][sl]
    return out


_PINION = {O_DSW: O_THP, O_WSW: O_WP}


def delay_substeps(sp: SensorParams, h: float) -> int:
    """The MDPS computation delay in whole sub-steps."""
    return int(round(sp.mdps_delay / h))
