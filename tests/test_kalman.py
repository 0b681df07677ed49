"""lde.estimator.kalman: the compiled filter against filterpy over long random sequences, and its
invariants."""

from __future__ import annotations

import numpy as np
import pytest

from lde import kalman_reference
from lde.estimator import kalman, model
from lde.params import load_vehicle
from lde.units import KMH


@pytest.fixture(scope="module")
def veh():
    return load_vehicle("reference")


def _x0_P0(veh):
    e = veh.estimator
    return np.zeros(4), np.diag([e.p0_beta, e.p0_yaw, e.p0_fw, e.p0_mw]) ** 2


def _sequence(veh, n: int, seed: int):
    """Speeds that change every step (random walk 30..180 km/h), steering, noisy measurements
    of a truth driven by the discrete model, and a few steps with the T_align row left out."""
    rng = np.random.default_rng(seed)
    vx = np.clip(100 * KMH + np.cumsum(rng.normal(0, 0.05, n)), 30 * KMH, 180 * KMH)
    delta = 0.01 * np.sin(np.arange(n) * 0.01) + rng.normal(0, 1e-3, n)
    x = np.array([0.0, 0.0, 800.0, -300.0])
    zs = np.empty((n, 2))
    truth = np.empty((n, 4))
    for k in range(n):
        truth[k] = x
        d = model.discrete_matrices(veh, vx[k])
        zs[k] = d.H @ x + d.D * delta[k] + rng.normal(0, np.sqrt(np.diag(d.R)))
        x = d.Phi @ x + d.E * delta[k] + rng.multivariate_normal(np.zeros(4), d.Qd)
    use = np.ones((n, 2), dtype=bool)
    use[rng.random(n) < 0.05, 1] = False
    return vx, delta, zs, use, truth


def test_compiled_filter_matches_filterpy_over_long_sequence(veh):
    n = 4000
    vx, delta, zs, use, truth = _sequence(veh, n, seed=1)
    x0, P0 = _x0_P0(veh)
    ours = kalman.KalmanFilter(x0, P0)
    ref = kalman_reference.FilterpyReference(x0, P0)
    worst_x = worst_p = 0.0
    for k in range(n):
        d = model.discrete_matrices(veh, vx[k])
        for f in (ours, ref):
            f.update(zs[k], d.H, d.D, delta[k], d.R, use[k])
        # compare the a-posteriori estimates (what the estimator outputs)
        xs = np.abs(ref.x) + np.array([1e-6, 1e-6, 1.0, 1.0])
        worst_x = max(worst_x, float(np.max(np.abs(ours.x - ref.x) / xs)))
        worst_p = max(worst_p, float(np.max(np.abs(ours.P - ref.P)) / np.max(np.abs(ref.P))))
        for f in (ours, ref):
            f.predict(d.Phi, d.E, delta[k], d.Qd)
    print("worst relative deviation x, P:", worst_x, worst_p)
    assert worst_x < 1e-9
    assert worst_p < 1e-9
    # and the filter did something: the (random-walk) disturbance is tracked
    assert ours.x[2] == pytest.approx(truth[-1, 2], abs=300.0)
    assert ours.x[3] == pytest.approx(truth[-1, 3], abs=300.0)


def test_pure_functions_class_and_inplace_agree(veh):
    vx, delta, zs, use, truth = _sequence(veh, 300, seed=2)
    x0, P0 = _x0_P0(veh)
    cls = kalman.KalmanFilter(x0, P0)
    x, P = x0.copy(), P0.copy()
    xi, Pi, tmp = x0.copy(), P0.copy(), np.empty((4, 4))
    ws = np.empty((kalman.UPDATE_WS, 4, 4))
    for k in range(300):
        d = model.discrete_matrices(veh, vx[k])
        cls.update(zs[k], d.H, d.D, delta[k], d.R, use[k])
        x, P, _ = kalman.kf_update(x, P, zs[k], d.H, d.D, delta[k], d.R, use[k])
        kalman.update_inplace(xi, Pi, zs[k], d.H, d.D * delta[k], d.R, use[k], ws)
        cls.predict(d.Phi, d.E, delta[k], d.Qd)
        x, P = kalman.kf_predict(x, P, d.Phi, d.E, delta[k], d.Qd)
        kalman.predict_inplace(xi, Pi, d.Phi, d.E * delta[k], d.Qd, tmp)
    np.testing.assert_array_equal(cls.x, x)
    np.testing.assert_array_equal(cls.P, P)
    np.testing.assert_array_equal(xi, x)
    np.testing.assert_array_equal(Pi, P)


def test_covariance_stays_symmetric_positive_definite(veh):
    vx, delta, zs, use, truth = _sequence(veh, 2000, seed=3)
    x0, P0 = _x0_P0(veh)
    f = kalman.KalmanFilter(x0, P0)
    for k in range(2000):
        d = model.discrete_matrices(veh, vx[k])
        f.update(zs[k], d.H, d.D, delta[k], d.R, use[k])
        assert np.array_equal(f.P, f.P.T)
        f.predict(d.Phi, d.E, delta[k], d.Qd)
    assert np.all(np.linalg.eigvalsh(f.P) > 0)


def test_joseph_form_equals_simple_form_for_optimal_gain(veh):
    """With the optimal gain, (I-KH)P(I-KH)^T + KRK^T = (I-KH)P (to rounding)."""
    d = model.discrete_matrices(veh, 25.0)
    rng = np.random.default_rng(4)
    A = rng.normal(size=(4, 4))
    P = A @ A.T + np.diag([1e-4, 1e-4, 1e6, 1e6])
    x = rng.normal(size=4)
    z = np.array([0.01, 30.0])
    xn, Pn, nis = kalman.kf_update(x, P, z, d.H, d.D, 0.002, d.R, np.array([True, True]))
    S = d.H @ P @ d.H.T + d.R
    K = P @ d.H.T @ np.linalg.inv(S)
    y = z - d.H @ x - d.D * 0.002
    np.testing.assert_allclose(xn, x + K @ y, rtol=1e-9)
    np.testing.assert_allclose(Pn, (np.eye(4) - K @ d.H) @ P, rtol=1e-6, atol=1e-9 * np.max(np.abs(P)))
    assert nis == pytest.approx(float(y @ np.linalg.solve(S, y)), rel=1e-9)


def test_no_used_row_leaves_state_unchanged(veh):
    d = model.discrete_matrices(veh, 25.0)
    x0, P0 = _x0_P0(veh)
    x, P, nis = kalman.kf_update(x0, P0, np.array([1.0, 2.0]), d.H, d.D, 0.0, d.R, np.array([False, False]))
    np.testing.assert_array_equal(x, x0)
    np.testing.assert_array_equal(P, P0)
    assert nis == 0.0


def test_reset_is_explicit(veh):
    x0, P0 = _x0_P0(veh)
    f = kalman.KalmanFilter(x0, P0)
    d = model.discrete_matrices(veh, 25.0)
    f.update(np.array([0.05, 40.0]), d.H, d.D, 0.0, d.R)
    f.predict(d.Phi, d.E, 0.0, d.Qd)
    assert not np.array_equal(f.x, x0)
    f.reset()
    np.testing.assert_array_equal(f.x, x0)
    np.testing.assert_array_equal(f.P, P0)
    f.reset(x0=np.ones(4))
    np.testing.assert_array_equal(f.x, np.ones(4))
    with pytest.raises(ValueError):
        kalman.KalmanFilter(np.zeros(4), np.eye(3))


def test_steady_state_gain_matches_scipy_dare(veh):
    from scipy.linalg import solve_discrete_are

    d = model.discrete_matrices(veh, 100 * KMH)
    Kg, P_post = kalman.steady_state_gain(d.Phi, d.H, d.Qd, d.R)
    P_prior = solve_discrete_are(d.Phi.T, d.H.T, d.Qd, d.R)
    K_ref = P_prior @ d.H.T @ np.linalg.inv(d.H @ P_prior @ d.H.T + d.R)
    np.testing.assert_allclose(Kg, K_ref, rtol=1e-6, atol=1e-9 * np.max(np.abs(K_ref)))
    tau = kalman.closed_loop_time_constants(d.Phi, d.H, Kg, 0.0039)
    assert np.all(tau > 0) and tau[0] >= tau[-1]


def _spd(rng, m: int, cond: float, scale: float = 1e4) -> np.ndarray:
    """A random symmetric positive definite (m, m) matrix with condition number ``cond``, its rows
    and columns scaled over 1/scale..scale (as an innovation covariance mixing rad/s and Nm is)."""
    q, _ = np.linalg.qr(rng.normal(size=(m, m)))
    a = (q * np.logspace(0, -np.log10(cond), m)) @ q.T
    s = scale ** rng.uniform(-1, 1, m)
    return s[:, None] * (0.5 * (a + a.T)) * s[None, :]


def _inverse(a: np.ndarray) -> np.ndarray:
    m = a.shape[0]
    ws = np.full((2, kalman.NX, kalman.NX), np.nan)
    ws[0, :m, :m] = a
    kalman.invert_small(ws, 0, 1, m)
    assert np.isnan(ws[1, m:, :]).all() and np.isnan(ws[1, :, m:]).all()  # stays in its block
    return ws[1, :m, :m].copy()


@pytest.mark.parametrize("m", [1, 2, 3, 4])
@pytest.mark.parametrize("cond", [1.0, 1e4, 1e8, 1e12])
def test_small_inverse_matches_numpy_on_spd_and_near_singular_matrices(m, cond):
    """The inverse without LAPACK against numpy's (LAPACK's LU) on SPD matrices up to near-singular
    ones: the two differ by no more than their rounding, c * cond * eps relative to the inverse
    (each side's error is of that order; near-singular the entries are ~1e12 and still agree)."""
    rng = np.random.default_rng(1000 * m + int(np.log10(cond)))
    eps = np.finfo(float).eps
    for _ in range(200):
        a = _spd(rng, m, cond)
        ref = np.linalg.inv(a)
        # relative to the inverse of the unscaled matrix: D^-1 (D A D)^-1 D^-1 entry by entry
        d = np.sqrt(np.diag(a))
        err = np.abs(_inverse(a) - ref) * d[:, None] * d[None, :]
        assert np.max(err) <= 20 * m * np.linalg.cond(a / d[:, None] / d[None, :]) * eps * np.max(
            np.abs(ref * d[:, None] * d[None, :])
        )


@pytest.mark.parametrize("m", [3, 4])
def test_small_inverse_pivots_on_matrices_that_need_it(m):
    """A zero or tiny leading entry (no SPD innovation covariance has one, a general S could): the
    row exchange keeps the result exact where elimination in order would divide by ~0."""
    rng = np.random.default_rng(m)
    for _ in range(200):
        a = rng.normal(size=(m, m))
        a[0, 0] = 0.0 if rng.random() < 0.5 else 1e-17
        a[1, 1] *= 1e-3
        ref = np.linalg.inv(a)
        np.testing.assert_allclose(
            _inverse(a), ref, rtol=0, atol=1e4 * np.linalg.cond(a) * 2.3e-16 * np.abs(ref).max()
        )


@pytest.mark.parametrize("rows", [(True, True, True), (True, True, True, True), (True, False, True, True)])
def test_update_with_three_and_four_rows_matches_the_textbook_form(rows):
    """update_inplace with 3-4 used rows (the Gauss-Jordan branch; the estimator step uses two)
    against y = z - Hx - Du, K = P H^T S^-1, Joseph form, NIS = y^T S^-1 y, in numpy."""
    m = len(rows)
    use = np.array(rows)
    rng = np.random.default_rng(m + int(use.sum()))
    for _ in range(50):
        x = rng.normal(size=4) * [0.01, 0.01, 500.0, 200.0]
        P = _spd(rng, 4, 1e3, scale=10.0)
        H = rng.normal(size=(m, 4))
        R = _spd(rng, m, 1e2, scale=10.0)
        z, du = rng.normal(size=m), rng.normal(size=m)
        xn, Pn = x.copy(), P.copy()
        nis = kalman.update_inplace(xn, Pn, z, H, du, R, use, np.empty((kalman.UPDATE_WS, 4, 4)))
        Hu, Ru = H[use], R[np.ix_(use, use)]
        y = (z - H @ x - du)[use]
        S = Hu @ P @ Hu.T + Ru
        K = P @ Hu.T @ np.linalg.inv(S)
        IKH = np.eye(4) - K @ Hu
        P_ref = IKH @ P @ IKH.T + K @ Ru @ K.T
        np.testing.assert_allclose(xn, x + K @ y, rtol=1e-8, atol=1e-8 * np.abs(x).max())
        np.testing.assert_allclose(Pn, 0.5 * (P_ref + P_ref.T), rtol=1e-6, atol=1e-8 * np.abs(P).max())
        assert nis == pytest.approx(float(y @ np.linalg.solve(S, y)), rel=1e-8)
