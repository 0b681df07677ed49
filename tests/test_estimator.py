"""The lateral filter (lde.estimator.lateral) against an independently written linear model.

The model below is written from the equations (ISO 8855, per-tire stiffnesses, eq. 9 slips), not from
the filter's code, and discretised exactly (matrix exponential). Its measurements are the filter's
three: the yaw rate, the aligning torque N (T_col + T_ast) = 2K alpha_f (friction 0), and the
accelerometer's specific force (s (2 Cf alpha_f + 2 Cr alpha_r) + F_wind) / m, which excludes
gravity: a bank shows in it only through the tire forces. A wrong sign or a swapped term in any of
the filter's H rows, its Phi or its inputs biases the converged estimate of the wind, its moment or
the bank, which these tests compare with the truth.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.linalg import expm

from lde.estimator import lateral as E
from lde.estimator.outputs import N_OUT, O_BANK, O_BETA, O_FW, O_FW_WIND, O_MW, O_MW_WIND, O_T_ALIGN, O_YAW
from lde.params import load_vehicle
from lde.status import VALID
from lde.units import DEG, STEP_NS, STEP_S, G

VX = 100.0 / 3.6


def _truth_model(m, iz, lf, lr, cf, cr, vx):
    """Continuous x' = A x + B delta + Bd [F_wind + F_bank, M_wind]; x = [beta, r]."""
    a = np.array(
        [
            [-2 * (cf + cr) / (m * vx), -1 - 2 * (lf * cf - lr * cr) / (m * vx**2)],
            [-2 * (lf * cf - lr * cr) / iz, -2 * (lf**2 * cf + lr**2 * cr) / (iz * vx)],
        ]
    )
    b = np.array([2 * cf / (m * vx), 2 * lf * cf / iz])
    bd = np.array([[1 / (m * vx), 0.0], [0.0, 1 / iz]])
    return a, b, bd


def _discrete(a, bmat, dt):
    n, k = a.shape[0], bmat.shape[1]
    big = np.zeros((n + k, n + k))
    big[:n, :n], big[:n, n:] = a, bmat
    e = expm(big * dt)
    return e[:n, :n], e[:n, n:]


def _run(f_wind, m_wind, bank_rad, steer, seconds=40.0, seed=0, accel_scale=1.0, filter_scale=None):
    """Simulate the truth and run the filter's kernel on its measurements; returns the outputs of
    every step (n, N_OUT) and the status."""
    veh = load_vehicle("reference")
    b, t = veh.body, veh.tires
    m, iz, lf, lr = b.mass, b.yaw_inertia, b.lf, b.lr
    n_ratio = veh.steering.ratio
    cf, cr, k = t.cf, t.cr, t.align_rate
    p = E.params_vector(veh)
    p[E.P_TFRIC] = 0.0
    p[E.P_S] = accel_scale if filter_scale is None else filter_scale
    a, bvec, bd = _truth_model(m, iz, lf, lr, cf, cr, VX)
    ad, bdd = _discrete(a, np.column_stack([bvec, bd]), STEP_S)
    rng = np.random.default_rng(seed)
    x = np.zeros(2)
    xs, P = np.zeros(E.NX), np.zeros((E.NX, E.NX))
    fs, ints = np.zeros(E.N_F), np.zeros(E.N_I, np.int64)
    E.reset_kernel(p, xs, P, fs, ints)
    h, ph, out = np.zeros(E.NX), np.zeros(E.NX), np.zeros(N_OUT)
    n = int(seconds / STEP_S)
    outs, stats = np.zeros((n, N_OUT)), np.zeros(n, np.int64)
    f_bank = m * G * math.sin(bank_rad)
    for i in range(n):
        ti = i * STEP_S
        delta = steer(ti) / n_ratio
        beta, r = x
        af = delta - beta - lf * r / VX
        ar = -beta + lr * r / VX
        t_align = 2 * k * af
        ay = (accel_scale * (2 * cf * af + 2 * cr * ar) + f_wind) / m  # specific force: no gravity
        yaw = r + rng.normal(0, 0.05 * DEG)
        tcol = t_align / n_ratio + rng.normal(0, 0.02)
        ay_meas = ay + rng.normal(0, 0.02)
        stats[i] = E.step_kernel(
            p, xs, P, fs, ints, h, ph, 10**9 + i * STEP_NS, VX, steer(ti), yaw, tcol, 0.0, ay_meas,
            True, True, True, True, True, out,
        )  # fmt: skip
        outs[i] = out
        u = np.array([delta, f_wind + f_bank, m_wind])
        x = ad @ x + bdd @ u
    return outs, stats, m


def _steer_weave(t):
    return 2.0 * DEG * math.sin(2 * math.pi * 0.3 * t)


def _settled(outs, stats, seconds=10.0):
    tail = outs[-int(seconds / STEP_S) :]
    assert np.all(stats[-int(seconds / STEP_S) :] & VALID)
    return tail.mean(axis=0)


@pytest.mark.parametrize(("fw", "mw"), [(400.0, 120.0), (-300.0, -60.0), (250.0, -80.0)])
def test_wind_converges_to_the_truth_with_its_sign(fw, mw):
    outs, stats, _ = _run(fw, mw, 0.0, _steer_weave)
    est = _settled(outs, stats)
    assert est[O_FW_WIND] == pytest.approx(fw, abs=0.05 * abs(fw) + 10)
    assert est[O_MW_WIND] == pytest.approx(mw, abs=0.05 * abs(mw) + 5)
    assert abs(est[O_BANK]) < 0.05 * DEG  # a wind is not a bank
    assert est[O_FW] == pytest.approx(est[O_FW_WIND] + (est[O_FW] - est[O_FW_WIND]))
    assert est[O_MW] == pytest.approx(est[O_MW_WIND])


@pytest.mark.parametrize("bank_deg", [2.0, -1.5])
def test_bank_is_told_from_wind_by_the_accelerometer(bank_deg):
    """A bank (left side lower: gravity pulls left, +) shows as F_bank and the bank angle, not as wind;
    the total Fw carries it (as the paper's Fw does), with no moment (it acts through the CG)."""
    outs, stats, m = _run(0.0, 0.0, bank_deg * DEG, _steer_weave)
    est = _settled(outs, stats)
    assert math.degrees(est[O_BANK]) == pytest.approx(bank_deg, abs=0.1)
    f_bank = m * G * math.sin(bank_deg * DEG)
    assert est[O_FW] == pytest.approx(f_bank, rel=0.05)
    assert abs(est[O_FW_WIND]) < 0.05 * abs(f_bank)
    assert abs(est[O_MW]) < 20.0


def test_wind_and_bank_together_on_a_straight_road():
    """Without steering the split still holds: the accelerometer reads the wind at once."""
    outs, stats, m = _run(300.0, 90.0, 1.0 * DEG, lambda t: 0.0)
    est = _settled(outs, stats)
    assert est[O_FW_WIND] == pytest.approx(300.0, abs=20.0)
    assert est[O_MW_WIND] == pytest.approx(90.0, abs=10.0)
    assert math.degrees(est[O_BANK]) == pytest.approx(1.0, abs=0.1)


def test_states_and_aligning_torque_follow_the_model():
    outs, stats, _ = _run(0.0, 0.0, 0.0, _steer_weave, seconds=20.0)
    veh = load_vehicle("reference")
    # the steady sine response: compare beta, r, T_align with the truth model's over the last seconds
    tail = outs[-int(5.0 / STEP_S) :]
    a, bvec, _ = _truth_model(
        veh.body.mass, veh.body.yaw_inertia, veh.body.lf, veh.body.lr, veh.tires.cf, veh.tires.cr, VX
    )
    w = 2 * math.pi * 0.3
    resp = np.linalg.solve(1j * w * np.eye(2) - a, bvec) * (2.0 * DEG / veh.steering.ratio)
    assert np.max(np.abs(tail[:, O_YAW])) == pytest.approx(abs(resp[1]), rel=0.05)
    assert np.max(np.abs(tail[:, O_BETA])) == pytest.approx(abs(resp[0]), rel=0.1)
    assert np.all(np.isfinite(tail[:, O_T_ALIGN]))


def test_accelerometer_roll_scale_is_used():
    """The filter's s (accel_scale) must match the sensor's: with s = 1.06 in both the wind is right;
    the same data through s = 1.0 is biased (so the scale's place in H matters)."""
    outs, stats, _ = _run(300.0, 0.0, 0.0, _steer_weave, accel_scale=1.06)
    right = _settled(outs, stats)[O_FW_WIND]
    assert right == pytest.approx(300.0, abs=25.0)
    outs, stats, _ = _run(300.0, 0.0, 0.0, _steer_weave, accel_scale=1.06, filter_scale=1.0)
    wrong = _settled(outs, stats)
    # the tire forces' 6 % go into the wind while steering: the error is visible in its swing
    assert np.std(outs[-2560:, O_FW_WIND]) > 2 * np.std(
        _run(300.0, 0.0, 0.0, _steer_weave, accel_scale=1.06)[0][-2560:, O_FW_WIND]
    )
    assert np.isfinite(wrong[O_FW_WIND])
