"""lde.estimator.model: each SPEC section 2 erratum has a test here that fails if it is reintroduced.

The expected values are worked out in the tests by hand from eqs. (7)-(9) and (12), not with
the functions under test.
"""

from __future__ import annotations

import numpy as np
import pytest

from lde.errors import ConfigError
from lde.estimator import model
from lde.params import load_vehicle, shipped_vehicles
from lde.units import KMH, STEP_S

SPEEDS_KMH = [30.0, 60.0, 100.0, 160.0, 180.0]


@pytest.fixture(scope="module")
def veh():
    return load_vehicle("reference")


def _discrete_fixed_point(d: model.DiscreteModel, delta_f: float, fw: float, mw: float):
    """[beta, r] with x = Phi x + E delta_f and Fw, Mw held: (I - Phi_11) y = Phi_12 w + E_1 delta_f."""
    phi11, phi12 = d.Phi[:2, :2], d.Phi[:2, 2:]
    return np.linalg.solve(np.eye(2) - phi11, phi12 @ np.array([fw, mw]) + d.E[:2] * delta_f)


def _hand_steady_state(veh, vx: float, delta_f: float, fw: float, mw: float):
    """Eqs. (7)-(9) with beta_dot = r_dot = 0, solved by hand.

    (7) m vx r = 2Ff + 2Fr + Fw,  (8) 0 = 2 lf Ff - 2 lr Fr + Mw.  With S = m vx r - Fw:
    2Ff = (lr S - Mw)/L,  2Fr = (lf S + Mw)/L.  (9): alpha_f - alpha_r = delta_f - L r / vx, so
    delta_f - L r/vx = (lr S - Mw)/(2 L Cf) - (lf S + Mw)/(2 L Cr), linear in r.
    Then beta = lr r / vx - alpha_r, and T_align = 2K alpha_f = 2K Ff / Cf.
    """
    m, lf, lr = veh.body.mass, veh.body.lf, veh.body.lr
    cf, cr, k = veh.tires.cf, veh.tires.cr, veh.tires.align_rate
    L = lf + lr
    # delta_f - L r/vx = a (m vx r - Fw) - b Mw
    # with a = lr/(2 L Cf) - lf/(2 L Cr),  b = 1/(2 L Cf) + 1/(2 L Cr)
    a = lr / (2 * L * cf) - lf / (2 * L * cr)
    b = 1 / (2 * L * cf) + 1 / (2 * L * cr)
    r = (delta_f + a * fw + b * mw) / (L / vx + a * m * vx)
    s = m * vx * r - fw
    ff = (lr * s - mw) / (2 * L)
    fr = (lf * s + mw) / (2 * L)
    alpha_r = fr / cr
    beta = lr * r / vx - alpha_r
    return beta, r, 2 * k * ff / cf


@pytest.mark.parametrize("kmh", SPEEDS_KMH)
def test_discrete_yaw_rate_gain_is_textbook_bicycle_gain(veh, kmh):
    """Catches a wrong sign of A[1,0] or a wrong A[1,1] (erratum 2) and a wrong B."""
    vx = kmh * KMH
    d = model.discrete_matrices(veh, vx)
    _, r = _discrete_fixed_point(d, 1.0, 0.0, 0.0)
    m, lf, lr = veh.body.mass, veh.body.lf, veh.body.lr
    caf, car = 2 * veh.tires.cf, 2 * veh.tires.cr  # axle stiffnesses
    L = lf + lr
    kus = m * (lr * car - lf * caf) / (L * caf * car)
    expected = vx / (L + kus * vx**2)
    assert r == pytest.approx(expected, rel=1e-9)
    assert model.yaw_rate_gain(veh, vx) == pytest.approx(expected, rel=1e-12)


@pytest.mark.parametrize("kmh", SPEEDS_KMH)
@pytest.mark.parametrize(
    "delta_f, fw, mw", [(0.0, 800.0, 0.0), (0.0, 0.0, -300.0), (0.01, 800.0, -300.0), (-0.02, -1500.0, 700.0)]
)
def test_steady_state_under_disturbance_matches_hand_solution(veh, kmh, delta_f, fw, mw):
    """Fixed point of the discrete model under constant Fw/Mw vs eqs. (7)-(9) solved by hand.

    Catches erratum 2 (A[1,0], A[1,1]) and a wrong input column of Fw or Mw; the T_align check with
    r != 0 catches l_r instead of l_f in H2 (erratum 1/3) and a wrong D2.
    """
    vx = kmh * KMH
    d = model.discrete_matrices(veh, vx)
    beta, r = _discrete_fixed_point(d, delta_f, fw, mw)
    beta_h, r_h, t_align_h = _hand_steady_state(veh, vx, delta_f, fw, mw)
    scale = max(abs(r_h), 1e-6)
    assert r == pytest.approx(r_h, rel=1e-9, abs=1e-12 * scale)
    assert beta == pytest.approx(beta_h, rel=1e-9, abs=1e-15)
    z = d.H @ np.array([beta, r, fw, mw]) + d.D * delta_f
    assert z[0] == pytest.approx(r, rel=1e-12)
    assert z[1] == pytest.approx(t_align_h, rel=1e-8, abs=1e-9)
    ss = model.steady_state(veh, vx, delta_f, fw, mw)
    assert (ss.beta, ss.yaw_rate, ss.t_align) == pytest.approx((beta_h, r_h, t_align_h), rel=1e-9, abs=1e-12)


def test_h2_uses_lf_in_front_slip_angle(veh):
    """Erratum 1/3 directly: dT_align/dr = -2K lf/vx, not lr."""
    vx = 25.0
    c = model.continuous_matrices(veh, vx)
    k, lf = veh.tires.align_rate, veh.body.lf
    assert c.H[1, 1] == pytest.approx(-2 * k * lf / vx)
    assert c.H[1, 0] == pytest.approx(-2 * k)
    assert c.D[1] == pytest.approx(2 * k)
    assert c.H[0].tolist() == [0.0, 1.0, 0.0, 0.0] and c.D[0] == 0.0


def test_euler_discretisation_and_qd_scaling(veh):
    """Phi = I + A dt, E = B dt, and Qd = W dt (erratum 8): the random-walk variance of Fw after
    1 s is q_fw * 1 s whatever the step; the paper's Gamma W Gamma^T would give q_fw * dt."""
    vx = 30.0
    c = model.continuous_matrices(veh, vx)
    for dt in (STEP_S, 0.01):
        d = model.discrete_matrices(veh, vx, dt)
        np.testing.assert_allclose(d.Phi, np.eye(4) + c.A * dt, rtol=1e-14, atol=1e-300)
        np.testing.assert_allclose(d.E, c.B * dt, rtol=1e-14)
        # density * time: a random walk of density q_fw gains q_fw * dt of variance per step
        assert d.Qd[2, 2] == pytest.approx(veh.estimator.q_fw * dt, rel=1e-12)
        assert d.Qd[3, 3] == pytest.approx(veh.estimator.q_mw * dt, rel=1e-12)
        assert d.Qd[0, 0] == pytest.approx(veh.estimator.q_beta * dt, rel=1e-12)
        np.testing.assert_array_equal(d.Qd, np.diag(np.diag(d.Qd)))


def test_straight_line_hold_matches_spec_section_5(veh):
    """r = 0 steady state: 2F_f = -(lr Fw + Mw)/L and T_align = 2K alpha_f; independent of speed."""
    fw, mw = 900.0, -250.0
    hold = model.straight_line_hold(veh, fw, mw)
    L = veh.body.lf + veh.body.lr
    t_ov = -veh.tires.align_rate * (veh.body.lr * fw + mw) / (veh.steering.ratio * veh.tires.cf * L)
    assert hold.t_align / veh.steering.ratio == pytest.approx(t_ov, rel=1e-12)
    for kmh in (40.0, 100.0, 170.0):
        ss = model.steady_state(veh, kmh * KMH, hold.delta_f, fw, mw)
        assert abs(ss.yaw_rate) < 1e-15
        assert ss.t_align == pytest.approx(hold.t_align, rel=1e-9)
        assert ss.beta == pytest.approx(hold.beta, rel=1e-9)


@pytest.mark.parametrize("kmh", np.arange(30.0, 181.0, 10.0).tolist())
def test_observability_rank_4(veh, kmh):
    assert model.observability_rank(veh, kmh * KMH) == 4


def test_observability_rank_detects_missing_measurement(veh):
    """The rank test can fail: yaw rate alone cannot separate Fw from Mw."""
    assert model.observability_rank(veh, 25.0, measurements=(model.IZ_YAW,)) < 4
    assert model.observability_rank(veh, 25.0, measurements=(model.IZ_ALIGN,)) < 4


@pytest.mark.parametrize("name", [n for n in shipped_vehicles() if n == "reference" or n.startswith("est")])
def test_shipped_wheelbases_agree(name):
    """Erratum 6: every parameter set of the paper (Table 1 candidates) keeps the 2.795 m wheelbase."""
    v = load_vehicle(name)
    assert v.body.lf + v.body.lr == pytest.approx(2.795, abs=1e-9)


def test_params_vector_layout(veh):
    p = model.params_vector(veh, dt=0.005)
    assert p.shape == (model.N_PARAMS,) and p.dtype == np.float64
    assert p[model.P_M] == veh.body.mass and p[model.P_LF] == veh.body.lf and p[model.P_LR] == veh.body.lr
    assert p[model.P_CF] == veh.tires.cf and p[model.P_K] == veh.tires.align_rate and p[model.P_DT] == 0.005
    assert p[model.P_R_ALIGN] == veh.estimator.r_align and p[model.P_MIN_SPEED] == veh.estimator.min_speed


@pytest.mark.parametrize("vx", [0.0, -3.0, float("nan")])
def test_bad_speed_is_a_clear_error(veh, vx):
    with pytest.raises(ConfigError):
        model.discrete_matrices(veh, vx)


def test_signs_left_steer_turns_left(veh):
    """ISO 8855: delta_f > 0 gives r > 0 and T_align > 0 (resists the left steer)."""
    ss = model.steady_state(veh, 25.0, 0.01)
    assert ss.yaw_rate > 0 and ss.t_align > 0
