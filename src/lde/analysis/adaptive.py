"""Prototype estimator extensions (issue 6, items 3 and 5), measured in ``lde study`` / ``lde evaluate``.

The product step (:func:`lde.estimator.paper.run_batch`) implements the paper's filter. What the paper
neglects enters its measurements directly:

- Steering Coulomb friction (eq. 11 drops it): the column-level torque the MDPS sees is
  ``T_column + T_assist = T_align / N + T_fric sgn(delta_sw_dot) + J delta_sw_ddot``, so
  ``N (T_column + T_assist)`` over-reads the aligning torque by ``N T_fric`` while the wheel turns
  left and under-reads it while it turns right. 0.35 Nm at the column is ~5 Nm at the kingpins,
  a lateral force error of ~5 / trail ~ 100 N: a light-load scenario's whole signal.
- A steering-angle offset ``d_sw`` or a yaw-rate bias ``b_r`` produces a steady aligning-torque and
  yaw-rate residual that the filter can only explain as a disturbance.
- The steering-angle sensor sits above the torsion bar, which twists by ``c_tb T_column`` (about
  1.5 deg of steering wheel at a 3 Nm hold with a 2 Nm/deg bar): the road wheels are not at
  ``delta_sw / N``. A linear model absorbs that into a lower effective Cf and K, which is right only
  while the column torque stays proportional to the aligning torque (the boost curve is not).

The input corrections (friction, torsion twist, offsets, bias) are the product's
(:mod:`lde.estimator.conditioning`, the vehicle file's ``[corrections]``); the prototypes here apply them the
same way before their own filters.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from lde.analysis.calibrate import DriveData
from lde.can.frames import FrameBatch
from lde.can.profiles import Profile, load_profile
from lde.engine.grid import InputGrid, build_grid
from lde.engine.receiver import decode_batch
from lde.estimator.conditioning import condition_arrays, is_active
from lde.params import Vehicle
from lde.units import STEP_S


def grid_from_frames(frames: FrameBatch, profile: Profile | str = "lde") -> InputGrid:
    """CAN frames -> estimator inputs on the 3.9 ms grid (the replay pipeline's first stages;
    only received frames, ``is_rx``, are inputs)."""
    prof = profile if isinstance(profile, Profile) else load_profile(profile)
    return build_grid(decode_batch(prof, frames.select(frames.is_rx)), prof)


def drive_from_grid(grid: InputGrid) -> DriveData:
    """The grid as :class:`lde.analysis.calibrate.DriveData` (rows valid where both input groups are ok)."""
    return DriveData(
        t=grid.t_ns.astype(np.float64) * 1e-9,
        steering_angle=grid.steering_angle,
        steering_rate=grid.steering_rate,
        yaw_rate=grid.yaw_rate,
        lat_accel=grid.lat_accel,
        speed=grid.speed,
        column_torque=grid.column_torque,
        assist_torque=grid.assist_torque,
        valid=grid.mdps_ok & grid.esc_ok,
    )


def compensate(grid: InputGrid, vehicle: Vehicle) -> InputGrid:
    """A copy of ``grid`` with the vehicle's input corrections applied (:mod:`lde.estimator.conditioning`)."""
    if not is_active(vehicle):
        return grid
    angle, yaw, col = condition_arrays(
        vehicle, grid.steering_angle, grid.steering_rate, grid.yaw_rate, grid.column_torque
    )
    return replace(grid, steering_angle=angle, yaw_rate=yaw, column_torque=col)


# --- augmented filter: lateral acceleration as a third measurement ---------------------------------
#
# The accelerometer measures specific force: tire and aerodynamic forces, not gravity. A crosswind
# therefore shows in a_y at once, a bank does not (the tires balance it, a_y reads their force).
# Splitting the disturbance force into Fa (aerodynamic, sensed) and Fb (bank, not sensed):
#
#   x = [beta, r, Fa, Fb, Mw]
#   m vx (beta_dot + r) = 2 F_f + 2 F_r + Fa + Fb            Iz r_dot = 2 lf F_f - 2 lr F_r + Mw
#   z = [r, T_align, a_y]:  T_align = 2K alpha_f,   a_y = (s (2 F_f + 2 F_r) + Fa) / m
#
# with s the accelerometer's roll-tilt scale (the body rolls with the tire force; lde.analysis.calibrate).
# Output Fw = Fa + Fb. Euler discretisation and Qd = W dt as in lde.estimator.model.

#: a_y measurement standard deviation used by the augmented filter [m/s^2] (sensor noise plus model
#: error of the linear tires and the quasi-static roll)
AY_STD = 0.08
#: the sensed (aerodynamic) force may change this much faster than the vehicle file's q_fw: the
#: accelerometer observes it directly, so a faster random walk costs little noise (measured, seed 0,
#: step 7: factor 1 -> 3 takes heavy-load Fw 3.1 -> 2.3 %, payload_full 6.0 -> 5.5 %, light 3.6 -> 4.0 %)
Q_FA_FACTOR = 3.0


def augmented_estimate(
    grid: InputGrid,
    vehicle: Vehicle,
    accel_scale: float = 1.0,
    ay_std: float = AY_STD,
    q_fa_factor: float = Q_FA_FACTOR,
    curvature: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The 5-state filter above over the grid inputs after the vehicle's corrections:
    (t_ns, Fw [N], Mw [Nm], valid).

    ``curvature`` = (kappa_f, kappa_r, kappa_K) [1/rad^2] schedules the secant tire parameters on the
    estimated slip angles: ``C(alpha) = C (1 - kappa alpha^2)`` (the tires' force and aligning torque
    fall below linear at large slip; 0: linear tires).
    """

    g = compensate(grid, vehicle)
    b, t, e = vehicle.body, vehicle.tires, vehicle.estimator
    m, iz, lf, lr, cf0, cr0, k0, n_ratio = (
        b.mass, b.yaw_inertia, b.lf, b.lr, t.cf, t.cr, t.align_rate, vehicle.steering.ratio,
    )  # fmt: skip
    lf0, lr0 = lf, lr
    dt = STEP_S
    Qd = np.diag([e.q_beta, e.q_yaw, q_fa_factor * e.q_fw, e.q_fw, e.q_mw]) * dt
    R = np.diag([e.r_yaw, e.r_align, ay_std**2])
    P0 = np.diag([e.p0_beta, e.p0_yaw, e.p0_fw, e.p0_fw, e.p0_mw]) ** 2
    nst = len(g)
    fw_out = np.full(nst, np.nan)
    mw_out = np.full(nst, np.nan)
    valid = np.zeros(nst, dtype=bool)
    x = np.zeros(5)
    P = P0.copy()
    run_start = -1
    I5 = np.eye(5)
    for i in range(nst):
        vx = g.speed[i]
        ok = bool(g.mdps_ok[i] and g.esc_ok[i]) and np.isfinite(vx) and vx > e.min_speed
        ay = g.lat_accel[i]
        if not ok or not np.isfinite(ay):
            fw_out[i], mw_out[i] = x[2] + x[3], x[4]
            run_start = -1
            P = P0.copy()
            continue
        if run_start < 0:
            run_start = i
        d_f = g.steering_angle[i] / n_ratio
        # secant tire parameters at the a-priori slip angles (eq. 9)
        a_f = d_f - x[0] - lf0 * x[1] / vx
        a_r = -x[0] + lr0 * x[1] / vx
        cf = cf0 * max(0.5, 1.0 - curvature[0] * a_f * a_f)
        cr = cr0 * max(0.5, 1.0 - curvature[1] * a_r * a_r)
        k = k0 * max(0.5, 1.0 - curvature[2] * a_f * a_f)
        # measurement rows (alpha_f = d_f - beta - lf r/vx; tire force sum 2Ff + 2Fr)
        H = np.zeros((3, 5))
        H[0, 1] = 1.0
        H[1, 0] = -2.0 * k
        H[1, 1] = -2.0 * k * lf / vx
        H[2, 0] = -2.0 * accel_scale * (cf + cr) / m
        H[2, 1] = -2.0 * accel_scale * (lf * cf - lr * cr) / (m * vx)
        H[2, 2] = 1.0 / m
        D = np.array([0.0, 2.0 * k * d_f, 2.0 * accel_scale * cf * d_f / m])
        z = np.array([g.yaw_rate[i], n_ratio * (g.column_torque[i] + g.assist_torque[i]), ay])
        # update: K = P H' (H P H' + R)^-1 ; x += K (z - H x - D) ; Joseph form for P
        S = H @ P @ H.T + R
        Kg = np.linalg.solve(S, H @ P).T
        x = x + Kg @ (z - H @ x - D)
        A_ = I5 - Kg @ H
        P = A_ @ P @ A_.T + Kg @ R @ Kg.T
        fw_out[i], mw_out[i] = x[2] + x[3], x[4]
        valid[i] = (i - run_start) * dt >= e.converge_time
        # propagate: Phi = I + A dt
        A = np.zeros((5, 5))
        A[0, 0] = -2.0 * (cf + cr) / (m * vx)
        A[0, 1] = -1.0 - 2.0 * (lf * cf - lr * cr) / (m * vx * vx)
        A[0, 2] = A[0, 3] = 1.0 / (m * vx)
        A[1, 0] = -2.0 * (lf * cf - lr * cr) / iz
        A[1, 1] = -2.0 * (lf * lf * cf + lr * lr * cr) / (iz * vx)
        A[1, 4] = 1.0 / iz
        Bu = np.array([2.0 * cf / (m * vx), 2.0 * lf * cf / iz, 0.0, 0.0, 0.0]) * d_f
        Phi = I5 + A * dt
        x = Phi @ x + Bu * dt
        P = Phi @ P @ Phi.T + Qd
    return g.t_ns, fw_out, mw_out, valid
