"""Synthetic drives for testing and benchmarking the firmware model without the simulator.

The plant is the estimator's own linear 2-DOF model (:func:`lde.estimator.model.continuous_matrices`)
integrated with 4 Euler sub-steps per grid step, plus seeded Gaussian sensor noise: speed sweeps
within 30-180 km/h, steps and gusts of Fw up to 6000 N and Mw up to 6000 Nm, steering within
15 deg at the wheel. This tests the arithmetic, not the model's realism (that is vcan_sim's job).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lde.estimator.model import continuous_matrices
from lde.params import Vehicle
from lde.units import DEG, KMH, STEP_NS


@dataclass(frozen=True)
class Drive:
    """Inputs on the step grid (SI) and the true disturbance."""

    name: str
    t_ns: np.ndarray
    speed: np.ndarray
    steering_angle: np.ndarray
    yaw_rate: np.ndarray
    column_torque: np.ndarray
    assist_torque: np.ndarray
    mdps_ok: np.ndarray
    esc_ok: np.ndarray
    fw_true: np.ndarray
    mw_true: np.ndarray

    def inputs(self) -> tuple[np.ndarray, ...]:
        """The positional inputs of ``run_batch`` (without the vehicle)."""
        return (
            self.t_ns,
            self.speed,
            self.steering_angle,
            self.yaw_rate,
            self.column_torque,
            self.assist_torque,
            self.mdps_ok,
            self.esc_ok,
        )

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


def _smooth_step(t: np.ndarray, t0: float, rise: float) -> np.ndarray:
    return np.clip((t - t0) / rise, 0.0, 1.0)


def make_drive(
    vehicle: Vehicle,
    kind: str,
    duration_s: float = 20.0,
    seed: int = 0,
    t0_ns: int = 1_700_000_000_000_000_000,
) -> Drive:
    """A synthetic drive. ``kind``: ``sweep`` (speed 30->180->60 km/h, slalom-free steering,
    Fw/Mw steps), ``gusts`` (gusts of +-6000 N / +-6000 Nm at 100 km/h), ``steer`` (sinusoidal
    steering up to 15 deg at the wheel at 60-120 km/h with a bank force), ``faults`` (like
    ``sweep`` with MDPS/ESC dropouts and a dip below 30 km/h)."""
    rng = np.random.default_rng(seed)
    n = int(round(duration_s * 1e9 / STEP_NS))
    t = np.arange(n) * (STEP_NS * 1e-9)
    dt = STEP_NS * 1e-9
    N = vehicle.steering.ratio
    if kind in ("sweep", "faults"):
        speed = np.interp(t, [0, 0.4 * duration_s, 0.8 * duration_s, duration_s], [30, 180, 60, 60]) * KMH
        fw = 3000.0 * _smooth_step(t, 0.2 * duration_s, 0.2) - 5000.0 * _smooth_step(t, 0.5 * duration_s, 0.5)
        mw = -2500.0 * _smooth_step(t, 0.3 * duration_s, 0.1)
        mw = mw + 4000.0 * _smooth_step(t, 0.7 * duration_s, 1.0)
        delta_sw = 2.0 * DEG * np.sin(2 * np.pi * 0.2 * t)
        if kind == "faults":
            speed = np.where((t > 0.85 * duration_s) & (t < 0.9 * duration_s), 20 * KMH, speed)
    elif kind == "gusts":
        speed = np.full(n, 100 * KMH)
        fw = np.zeros(n)
        mw = np.zeros(n)
        for k, t0 in enumerate(np.arange(1.0, duration_s - 1.0, 2.0)):
            sgn = 1.0 if k % 2 == 0 else -1.0
            fw += sgn * 6000.0 * (_smooth_step(t, t0, 0.05) - _smooth_step(t, t0 + 1.0, 0.05))
            mw += -sgn * 6000.0 * (_smooth_step(t, t0 + 0.3, 0.05) - _smooth_step(t, t0 + 1.3, 0.05))
        delta_sw = 1.0 * DEG * np.sin(2 * np.pi * 0.5 * t)
    elif kind == "steer":
        speed = (90 + 30 * np.sin(2 * np.pi * t / duration_s)) * KMH
        fw = np.full(n, 1466 * 9.81 * 0.05)
        mw = 200.0 * np.sin(2 * np.pi * 0.3 * t)
        delta_sw = 15.0 * DEG * np.sin(2 * np.pi * 0.4 * t)
    else:
        raise ValueError(f"unknown drive kind {kind!r}")
    # integrate the linear plant
    x = np.zeros(2)
    r_true = np.empty(n)
    t_align = np.empty(n)
    sub = 4
    for k in range(n):
        c = continuous_matrices(vehicle, float(speed[k]))
        df = delta_sw[k] / N
        r_true[k] = x[1]
        t_align[k] = c.H[1, :2] @ x + c.D[1] * df
        for _ in range(sub):
            xd = (
                c.A[:2, :2] @ x
                + c.B[:2] * df
                + np.array([fw[k] / (vehicle.body.mass * speed[k]), mw[k] / vehicle.body.yaw_inertia])
            )
            x = x + xd * (dt / sub)
    yaw = r_true + rng.normal(0.0, 0.05 * DEG, n)
    total = t_align / N + rng.normal(0.0, 2.0 / N, n)  # column-level torque (driver + assist)
    assist = 0.7 * total
    column = total - assist
    mdps_ok = np.ones(n, dtype=bool)
    esc_ok = np.ones(n, dtype=bool)
    if kind == "faults":
        mdps_ok[(t > 0.35 * duration_s) & (t < 0.37 * duration_s)] = False
        esc_ok[(t > 0.6 * duration_s) & (t < 0.61 * duration_s)] = False
    steer_meas = np.round((delta_sw + rng.normal(0, 0.02 * DEG, n)) / (0.1 * DEG)) * (0.1 * DEG)
    t_ns = t0_ns + np.arange(n, dtype=np.int64) * STEP_NS
    return Drive(kind, t_ns, speed, steer_meas, yaw, column, assist, mdps_ok, esc_ok, fw, mw)
