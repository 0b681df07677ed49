"""The alternative firmware algorithm, in float, for measurement: steady-state Kalman gains
scheduled on speed (the generated table over 30-180 km/h, linear interpolation, clamped at the
ends), no covariance at run time.

Per step, with the semantics of :func:`lde.estimator.paper.step_kernel` (hold below min speed / without ESC,
update then output then predict, last valid delta_f on an MDPS fault):

    Kg = interp(vx, table)                    (4x2; a-priori steady state of the DARE)
    x  = x + Kg (z - H x - D delta_f)         (yaw-rate column only on an MDPS fault: an
                                               approximation, the table holds the joint gain)
    x  = Phi x + E delta_f

Used by ``bench/bench_firmware.py`` and ``docs/firmware.md`` to state what this algorithm costs
against the time-varying float filter; it is not a backend.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from lde.estimator.model import discrete_into, params_vector
from lde.estimator.paper import BatchResult
from lde.params import Vehicle
from lde.units import KMH, STEP_S

from .tables import tables_for


@njit(cache=True)
def _ss_kernel(
    p, speeds, gains, min_speed, t_ns, speed, steer, yaw, tcol, tas, mdps_ok, esc_ok, outs
):  # pragma: no cover - compiled
    x = np.zeros(4)
    Phi = np.zeros((4, 4))
    E = np.zeros(4)
    Qd = np.zeros((4, 4))
    H = np.zeros((2, 4))
    D = np.zeros(2)
    delta_last = 0.0
    t_align_last = 0.0
    n_ratio = p[7]
    for k in range(t_ns.shape[0]):
        esc_valid = esc_ok[k] and np.isfinite(yaw[k])
        mdps_valid = mdps_ok[k] and np.isfinite(steer[k]) and np.isfinite(tcol[k]) and np.isfinite(tas[k])
        if not (esc_valid and np.isfinite(speed[k]) and speed[k] >= min_speed):
            outs[k, 0], outs[k, 1], outs[k, 2] = x[2], x[3], t_align_last
            continue
        vx = speed[k]
        delta = steer[k] / n_ratio if mdps_valid else delta_last
        discrete_into(p, vx, Phi, E, Qd, H, D)
        # interpolated gain
        vc = min(max(vx, speeds[0]), speeds[-1])
        j = 0
        while j < speeds.shape[0] - 2 and speeds[j + 1] < vc:
            j += 1
        a = (vc - speeds[j]) / (speeds[j + 1] - speeds[j])
        y0 = yaw[k] - x[1]
        y1 = 0.0
        if mdps_valid:
            y1 = n_ratio * (tcol[k] + tas[k]) - D[1] * delta
            for m in range(4):
                y1 -= H[1, m] * x[m]
        for i in range(4):
            k0 = (1 - a) * gains[j, i, 0] + a * gains[j + 1, i, 0]
            k1 = (1 - a) * gains[j, i, 1] + a * gains[j + 1, i, 1]
            x[i] += k0 * y0 + k1 * y1
        ta = D[1] * delta
        for m in range(4):
            ta += H[1, m] * x[m]
        t_align_last = ta
        outs[k, 0], outs[k, 1], outs[k, 2] = x[2], x[3], ta
        if mdps_valid:
            delta_last = delta
        xn = np.zeros(4)
        for i in range(4):
            s = E[i] * delta
            for m in range(4):
                s += Phi[i, m] * x[m]
            xn[i] = s
        x[:] = xn


def run_batch_steady_state(
    t_ns,
    speed,
    steering_angle,
    yaw_rate,
    column_torque,
    assist_torque,
    mdps_ok,
    esc_ok,
    vehicle: Vehicle,
    *,
    dt: float = STEP_S,
) -> BatchResult:
    """The steady-state-gain filter over a batch (float); ``status`` is all zeros (not computed)."""
    tb = tables_for(vehicle, int(round(dt * 1e9)))
    ss = tb.raw["ss_table"]
    speeds = np.asarray(ss["speeds_kmh"], dtype=np.float64) * KMH
    gains = np.asarray(ss["gain"], dtype=np.float64)
    p = params_vector(vehicle, dt)
    t = np.ascontiguousarray(t_ns, dtype=np.int64)
    n = t.shape[0]
    outs = np.zeros((n, 3))
    f = np.ascontiguousarray
    _ss_kernel(
        p,
        speeds,
        gains,
        vehicle.estimator.min_speed,
        t,
        f(speed, np.float64),
        f(steering_angle, np.float64),
        f(yaw_rate, np.float64),
        f(column_torque, np.float64),
        f(assist_torque, np.float64),
        f(mdps_ok, np.bool_),
        f(esc_ok, np.bool_),
        outs,
    )
    nan = np.full(n, np.nan)
    return BatchResult(
        t.copy(),
        outs[:, 0].copy(),
        outs[:, 1].copy(),
        outs[:, 2].copy(),
        nan,
        nan.copy(),
        np.zeros(n, dtype=np.uint8),
    )
