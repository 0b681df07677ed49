"""Drives for the firmware model's tests: the synthetic drives of :mod:`firmware_model.synthetic` with
the lde profile's update rates, and one that visits every format's limits. Each is the input tuple
``(t_ns, speed, steering_angle, yaw_rate, column_torque, assist_torque, a_y, fresh_r, fresh_t,
fresh_a, mdps_ok, esc_ok)`` in SI units, as ``firmware_model.lateral.run_drive`` takes it."""

from __future__ import annotations

import numpy as np

from firmware_model.synthetic import make_drive


def lateral_drive(vehicle, kind: str, seed: int = 0, duration_s: float = 12.0) -> tuple[np.ndarray, ...]:
    """A synthetic drive (firmware_model.synthetic) with a lateral acceleration (vx r + noise, the
    steady-state part of the specific force) and the ESC/MDPS update rates of the lde profile
    (yaw rate and a_y fresh every 10 ms, the torques every 3.9 ms)."""
    d = make_drive(vehicle, kind, duration_s=duration_s, seed=seed)
    rng = np.random.default_rng(seed + 100)
    n = len(d)
    ay = d.speed * d.yaw_rate + rng.normal(0.0, 0.05, n)
    k = np.arange(n)
    fresh_esc = (k * 39) // 100 != ((k - 1) * 39) // 100  # every ~10 ms
    fresh_t = np.ones(n, bool)
    return (
        d.t_ns, d.speed, d.steering_angle, d.yaw_rate, d.column_torque, d.assist_torque, ay,
        fresh_esc, fresh_t, fresh_esc, d.mdps_ok, d.esc_ok,
    )  # fmt: skip


def extreme_drive(vehicle, seed: int = 3) -> tuple[np.ndarray, ...]:
    """A drive that visits the formats' limits: huge and non-finite inputs, over-speed, faults,
    held steps, wild steering and accelerations (for the no-wrap check)."""
    base = lateral_drive(vehicle, "gusts", seed=seed, duration_s=4.0)
    t, speed, steer, yaw, tcol, tas, ay, fr, ftq, fa, mdps, esc = (np.array(a, copy=True) for a in base)
    rng = np.random.default_rng(seed)
    n = len(t)
    for a, scale in ((speed, 140.0), (steer, 20.0), (yaw, 20.0), (tcol, 300.0), (tas, 300.0), (ay, 4000.0)):
        idx = rng.choice(n, 40, replace=False)
        a[idx] = rng.uniform(-scale, scale, 40)
        a[rng.choice(n, 3, replace=False)] = np.nan
        a[rng.choice(n, 2, replace=False)] = np.inf
    seg = slice(n // 2, n // 2 + 200)  # a stretch of bang-bang steering and saturated torques
    steer[seg] = np.where(np.arange(200) % 40 < 20, 15.0, -15.0)
    tcol[seg] = 250.0
    ay[seg] = -1000.0
    speed[n // 3 : n // 3 + 50] = 5.0  # held, then a restart from P0
    mdps[n // 4 : n // 4 + 30] = False
    esc[2 * n // 3 : 2 * n // 3 + 30] = False
    return t, speed, steer, yaw, tcol, tas, ay, fr, ftq, fa, mdps, esc
