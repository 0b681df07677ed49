"""lde.estimator.paper: the shared estimator step (live per-call and batch), its status logic, and the
filter's accuracy on data simulated from the linear model with an exact (expm) discretisation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.linalg import expm

from lde.errors import LdeError
from lde.estimator import model
from lde.estimator import paper as step
from lde.estimator.paper import Status
from lde.params import load_vehicle
from lde.units import DEG, KMH, STEP_NS, STEP_S

T0_NS = 1_700_000_000_000_000_000  # an epoch-like log time base
KEYS = ("speed", "steering_angle", "yaw_rate", "column_torque", "assist_torque", "mdps_ok", "esc_ok")


@pytest.fixture(scope="module")
def veh():
    return load_vehicle("reference")


def _physics_A_B(veh, vx: float):
    """Continuous A, B written from the forces of eqs. (7)-(9) (not from lde.estimator.model): columns of the
    linear map x -> x_dot taken one unit vector at a time."""
    m, iz, lf, lr = veh.body.mass, veh.body.yaw_inertia, veh.body.lf, veh.body.lr
    cf, cr = veh.tires.cf, veh.tires.cr

    def f(x, delta):
        beta, r, fw, mw = x
        ff = cf * (delta - beta - lf * r / vx)
        fr = cr * (-beta + lr * r / vx)
        beta_dot = (2 * ff + 2 * fr + fw) / (m * vx) - r
        r_dot = (2 * lf * ff - 2 * lr * fr + mw) / iz
        return np.array([beta_dot, r_dot, 0.0, 0.0])

    A = np.column_stack([f(e, 0.0) for e in np.eye(4)])
    return A, f(np.zeros(4), 1.0)


def simulate(veh, n, fw, mw, speed_kmh, seed, steer_amp_deg=20.0):
    """Truth from the linear model, zero-order-hold exact discretisation (expm), with sensor noise of
    the tuning's R. Returns the estimator inputs (SI arrays) and the truth states."""
    rng = np.random.default_rng(seed)
    k_align, N = veh.tires.align_rate, veh.steering.ratio
    t = np.arange(n)
    speed = np.broadcast_to(np.asarray(speed_kmh, dtype=float) * KMH, (n,)).copy()
    # driver-like steering: slow sines (steering-wheel angle)
    sw = (
        steer_amp_deg
        * DEG
        * (np.sin(2 * np.pi * 0.2 * t * STEP_S) + 0.3 * np.sin(2 * np.pi * 0.9 * t * STEP_S))
    )
    x = np.array([0.0, 0.0, fw, mw])
    truth = np.empty((n, 4))
    yaw = np.empty(n)
    t_align = np.empty(n)
    cache = {}
    for k in range(n):
        vx = speed[k]
        if vx not in cache:
            A, B = _physics_A_B(veh, vx)
            M = np.zeros((5, 5))
            M[:4, :4], M[:4, 4] = A, B
            Md = expm(M * STEP_S)
            cache[vx] = (Md[:4, :4], Md[:4, 4])
        Ad, Bd = cache[vx]
        delta = sw[k] / N
        truth[k] = x
        yaw[k] = x[1]
        # eq. (12) with lf:  T_align = 2K (delta_f - beta - lf r / vx)
        t_align[k] = 2 * k_align * (delta - x[0] - veh.body.lf * x[1] / vx)
        x = Ad @ x + Bd * delta
    yaw_meas = yaw + rng.normal(0, np.sqrt(veh.estimator.r_yaw), n)
    ta_meas = t_align + rng.normal(0, np.sqrt(veh.estimator.r_align), n)
    # eq. (11): T_align = N (T_column + T_assist); split it 30 % driver / 70 % assist
    column = 0.3 * ta_meas / N
    assist = 0.7 * ta_meas / N
    inputs = dict(
        t_ns=T0_NS + np.arange(n, dtype=np.int64) * STEP_NS,
        speed=speed,
        steering_angle=sw,
        yaw_rate=yaw_meas,
        column_torque=column,
        assist_torque=assist,
        mdps_ok=np.ones(n, dtype=bool),
        esc_ok=np.ones(n, dtype=bool),
    )
    return inputs, truth


def _run(veh, inputs):
    return step.run_batch(vehicle=veh, **inputs)


# --- accuracy on the linear model -------------------------------------------------------------


@pytest.mark.parametrize("kmh", [60.0, 100.0, 160.0])
def test_converges_to_constant_disturbance_within_5_percent(veh, kmh):
    n = round(4.0 / STEP_S)
    inputs, _ = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=kmh, seed=11)
    res = _run(veh, inputs)
    last = slice(n - round(1.0 / STEP_S), n)
    assert np.mean(res.fw[last]) == pytest.approx(800.0, rel=0.05)
    assert np.mean(res.mw[last]) == pytest.approx(-300.0, rel=0.05)
    assert np.all(res.status[last] == Status.VALID)


def test_zero_disturbance_gives_about_zero(veh):
    n = round(4.0 / STEP_S)
    inputs, _ = simulate(veh, n, fw=0.0, mw=0.0, speed_kmh=100.0, seed=12)
    res = _run(veh, inputs)
    last = slice(n - round(1.0 / STEP_S), n)
    assert abs(np.mean(res.fw[last])) < 40.0  # 5 % of the 800 N case
    assert abs(np.mean(res.mw[last])) < 15.0  # 5 % of the 300 Nm case


def test_converges_while_speed_changes(veh):
    """The model is scheduled on speed: a ramp 60 -> 160 km/h still converges."""
    n = round(5.0 / STEP_S)
    speed = np.round(np.linspace(60.0, 160.0, n), 0)  # km/h, few distinct values for the expm cache
    inputs, _ = simulate(veh, n, fw=-1200.0, mw=500.0, speed_kmh=speed, seed=13)
    res = _run(veh, inputs)
    last = slice(n - round(1.0 / STEP_S), n)
    assert np.mean(res.fw[last]) == pytest.approx(-1200.0, rel=0.05)
    assert np.mean(res.mw[last]) == pytest.approx(500.0, rel=0.05)


def test_t_align_hat_tracks_measured_aligning_torque(veh):
    n = round(3.0 / STEP_S)
    inputs, truth = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=100.0, seed=14)
    res = _run(veh, inputs)
    vx = 100.0 * KMH
    ta_true = (
        2
        * veh.tires.align_rate
        * (inputs["steering_angle"] / veh.steering.ratio - truth[:, 0] - veh.body.lf * truth[:, 1] / vx)
    )
    last = slice(n // 2, n)
    assert np.sqrt(np.mean((res.t_align[last] - ta_true[last]) ** 2)) < 5.0  # Nm, R std is 10 Nm
    assert np.max(np.abs(ta_true)) > 50.0  # the test means something


def test_propagates_the_a_posteriori_estimate(veh):
    """SPEC erratum 4: after step k the state is Phi x_k+ + E delta_f,k (x_k+ = the output)."""
    n = 50
    inputs, _ = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=100.0, seed=15)
    est = step.Estimator(veh)
    d = model.discrete_matrices(veh, 100.0 * KMH)
    for k in range(n):
        out = est.step(
            int(inputs["t_ns"][k]),
            step.EstimatorInputs(
                *(
                    inputs[key][k]
                    for key in ("speed", "steering_angle", "yaw_rate", "column_torque", "assist_torque")
                )
            ),
        )
        x_post = np.array([out.beta, out.yaw_rate, out.fw, out.mw])
        delta_f = inputs["steering_angle"][k] / veh.steering.ratio
        np.testing.assert_allclose(est.state.x, d.Phi @ x_post + d.E * delta_f, rtol=1e-12, atol=1e-15)


# --- live step and batch are the same code -----------------------------------------------------


def _faulty_sequence(veh, n, seed):
    inputs, _ = simulate(veh, n, fw=600.0, mw=200.0, speed_kmh=100.0, seed=seed)
    rng = np.random.default_rng(seed)
    inputs["speed"][n // 5 : n // 5 + 200] = 20.0 * KMH  # low speed
    inputs["mdps_ok"][2 * n // 5 : 2 * n // 5 + 30] = False
    inputs["esc_ok"][n // 2 + 100 : n // 2 + 120] = False
    inputs["mdps_ok"][rng.integers(0, n // 2, 5)] = False
    inputs["esc_ok"][rng.integers(0, n // 2, 5)] = False
    inputs["column_torque"][n // 2] = np.nan  # a non-finite value with mdps_ok set
    inputs["yaw_rate"][n // 2 + 7] = np.inf
    inputs["speed"][n // 2 + 11] = np.nan
    return inputs


def test_step_per_call_and_run_batch_are_bit_identical(veh):
    n = 3000
    inputs = _faulty_sequence(veh, n, seed=21)
    res = _run(veh, inputs)
    est = step.Estimator(veh)
    rows = []
    for k in range(n):
        o = est.step(int(inputs["t_ns"][k]), step.EstimatorInputs(*(inputs[key][k] for key in KEYS)))
        rows.append((o.fw, o.mw, o.t_align, o.beta, o.yaw_rate, int(o.status)))
    live = np.array(rows)
    for j, name in enumerate(("fw", "mw", "t_align", "beta", "yaw_rate")):
        np.testing.assert_array_equal(live[:, j], getattr(res, name), err_msg=name)
    np.testing.assert_array_equal(live[:, 5].astype(np.uint8), res.status)
    # the sequence exercised every status
    seen = np.bitwise_or.reduce(res.status)
    for bit in Status:
        if bit not in (Status.SHADOW_DEVIATION, Status.DEADLINE_MISS):
            assert seen & bit, bit


def test_run_batch_in_chunks_equals_one_run(veh):
    n = 2000
    inputs = _faulty_sequence(veh, n, seed=22)
    whole = _run(veh, inputs)
    est = step.Estimator(veh)
    parts = [est.run_batch(**{k: v[a : a + 700] for k, v in inputs.items()}) for a in range(0, n, 700)]
    np.testing.assert_array_equal(np.concatenate([p.fw for p in parts]), whole.fw)
    np.testing.assert_array_equal(np.concatenate([p.status for p in parts]), whole.status)


def test_reset_gives_a_fresh_estimator(veh):
    n = 600
    inputs, _ = simulate(veh, n, fw=600.0, mw=200.0, speed_kmh=100.0, seed=23)
    est = step.Estimator(veh)
    first = est.run_batch(**inputs)
    est.reset()
    again = est.run_batch(**inputs)
    np.testing.assert_array_equal(first.fw, again.fw)
    np.testing.assert_array_equal(first.status, again.status)


# --- status logic ----------------------------------------------------------------------------


def test_status_bits_are_the_architecture_contract():
    assert [int(s) for s in Status] == [1, 2, 4, 8, 16, 32, 64, 128]
    assert [s.name for s in Status] == [
        "VALID",
        "DEGRADED",
        "MDPS_FAULT",
        "ESC_FAULT",
        "LOW_SPEED",
        "NOT_CONVERGED",
        "SHADOW_DEVIATION",
        "DEADLINE_MISS",
    ]


def test_not_converged_for_converge_time_then_valid(veh):
    n = round(2.0 / STEP_S)
    inputs, _ = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=100.0, seed=31)
    res = _run(veh, inputs)
    t_s = (res.t_ns - res.t_ns[0]) * 1e-9
    conv = veh.estimator.converge_time
    assert np.all(res.status[t_s < conv - 1e-6] == Status.NOT_CONVERGED)
    assert np.all(res.status[t_s >= conv] == Status.VALID)


def test_low_speed_holds_state_and_restarts_convergence(veh):
    n = round(4.0 / STEP_S)
    inputs, _ = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=100.0, seed=32)
    a, b = round(2.0 / STEP_S), round(2.5 / STEP_S)
    inputs["speed"][a:b] = 29.0 * KMH
    res = _run(veh, inputs)
    held = res.status[a:b]
    assert np.all(held & Status.LOW_SPEED) and not np.any(held & Status.VALID)
    assert np.all(res.fw[a:b] == res.fw[a - 1]) and np.all(res.mw[a:b] == res.mw[a - 1])
    assert np.all(res.t_align[a:b] == res.t_align[a - 1])
    # resumes: NOT_CONVERGED for converge_time, then VALID again
    t_s = (res.t_ns - res.t_ns[b]) * 1e-9
    after = res.status[b:]
    assert np.all(after[t_s[b:] < veh.estimator.converge_time - 1e-6] == Status.NOT_CONVERGED)
    assert np.all(after[t_s[b:] >= veh.estimator.converge_time] == Status.VALID)
    assert np.mean(res.fw[-100:]) == pytest.approx(800.0, rel=0.05)


def test_esc_fault_holds_and_is_flagged(veh):
    n = round(2.5 / STEP_S)
    inputs, _ = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=100.0, seed=33)
    a = n - 50
    inputs["esc_ok"][a:] = False
    inputs["yaw_rate"][a:] = 12.0  # garbage that must not be used
    res = _run(veh, inputs)
    assert np.all(res.status[a:] & Status.ESC_FAULT)
    assert not np.any(res.status[a:] & (Status.VALID | Status.LOW_SPEED))
    assert np.all(res.fw[a:] == res.fw[a - 1])


def test_mdps_fault_uses_yaw_rate_only(veh):
    n = round(2.5 / STEP_S)
    inputs, _ = simulate(veh, n, fw=800.0, mw=-300.0, speed_kmh=100.0, seed=34)
    a = n - 50
    inputs["mdps_ok"][a:] = False
    inputs["column_torque"][a:] = 500.0  # garbage that must not be used
    res = _run(veh, inputs)
    st = res.status[a:]
    assert np.all(st & Status.MDPS_FAULT) and np.all(st & Status.DEGRADED)
    assert not np.any(st & Status.VALID)
    assert np.all(np.abs(res.fw[a:] - 800.0) < 200.0)  # garbage torque not used
    assert not np.all(res.fw[a:] == res.fw[a - 1])  # but the yaw-rate update still runs


def test_non_finite_inputs_with_ok_flags_count_as_faults(veh):
    est = step.Estimator(veh)
    good = dict(speed=27.0, steering_angle=0.0, yaw_rate=0.0, column_torque=0.0, assist_torque=0.0)
    o = est.step(0, step.EstimatorInputs(**{**good, "assist_torque": float("nan")}))
    assert o.status & Status.MDPS_FAULT
    o = est.step(STEP_NS, step.EstimatorInputs(**{**good, "yaw_rate": float("inf")}))
    assert o.status & Status.ESC_FAULT
    o = est.step(2 * STEP_NS, step.EstimatorInputs(**{**good, "speed": float("nan")}))
    assert o.status & Status.LOW_SPEED
    assert all(np.isfinite([o.fw, o.mw, o.t_align, o.beta, o.yaw_rate]))


def test_run_batch_rejects_mismatched_arrays(veh):
    inputs, _ = simulate(veh, 20, fw=0.0, mw=0.0, speed_kmh=100.0, seed=41)
    inputs["yaw_rate"] = inputs["yaw_rate"][:-1]
    with pytest.raises(LdeError, match="yaw_rate"):
        _run(veh, inputs)


# --- robustness over the DBC input ranges ------------------------------------------------------


def _col(lo, hi, n):
    return st.lists(st.one_of(st.floats(lo, hi), st.just(float("nan"))), min_size=n, max_size=n)


@settings(max_examples=40, deadline=None)
@given(
    speed=_col(0.0, 300 * KMH, 60),
    angle=_col(-800 * DEG, 800 * DEG, 60),
    yaw=_col(-100 * DEG, 100 * DEG, 60),
    col=_col(-20.0, 20.0, 60),
    ast=_col(-100.0, 100.0, 60),
    mdps=st.lists(st.booleans(), min_size=60, max_size=60),
    esc=st.lists(st.booleans(), min_size=60, max_size=60),
)
def test_any_inputs_in_dbc_ranges_give_finite_outputs_and_consistent_status(
    speed, angle, yaw, col, ast, mdps, esc
):
    veh = load_vehicle("reference")
    n = 60
    res = step.run_batch(
        T0_NS + np.arange(n, dtype=np.int64) * STEP_NS, speed, angle, yaw, col, ast, mdps, esc, veh
    )
    for name in ("fw", "mw", "t_align", "beta", "yaw_rate"):
        assert np.all(np.isfinite(getattr(res, name))), name
    faults = Status.MDPS_FAULT | Status.ESC_FAULT | Status.LOW_SPEED | Status.NOT_CONVERGED
    for s in res.status:
        assert bool(s & Status.VALID) == (not (s & faults))
        assert not s & (Status.SHADOW_DEVIATION | Status.DEADLINE_MISS)
