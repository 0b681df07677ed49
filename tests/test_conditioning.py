"""Input corrections (lde.estimator.conditioning, the vehicle file's [corrections]): math, signs, live ==
replay on both backends, the profile check, and the effect on simulated faults."""

from __future__ import annotations

import numpy as np
import pytest

from lde.errors import ConfigError
from lde.estimator.conditioning import check_profile, condition_arrays, condition_kernel, corrections_vector
from lde.estimator.paper import Estimator, EstimatorInputs, run_batch
from lde.params import load_vehicle, vehicle_from_dict, with_corrections
from lde.units import DEG, STEP_NS


def _vehicle(**keys):
    return with_corrections(load_vehicle("reference"), keys)


def test_identity_corrections_pass_the_inputs_through_unchanged():
    v = load_vehicle("reference")
    assert v.corrections.is_identity
    a, r, c = np.ones(3), np.full(3, 0.1), np.full(3, 2.0)
    out = condition_arrays(v, a, None, r, c)
    assert out[0] is a and out[1] is r and out[2] is c
    assert condition_kernel(corrections_vector(v), 0.3, 1.0, 0.02, 1.5) == (0.3, 0.02, 1.5)


def test_each_correction_has_the_documented_sign_and_size():
    v = _vehicle(
        steering_friction_Nm=0.5,
        torsion_deg_per_Nm=0.5,
        steering_angle_offset_deg=1.0,
        yaw_rate_bias_deg_s=0.2,
        align_offset_Nm=3.0,
    )
    n_ratio = v.steering.ratio
    rate = np.array([-1.0, -0.001, 0.0, 0.001, 1.0, np.nan])  # rad/s, steering wheel
    ones = np.ones(rate.size)
    angle, yaw, col = condition_arrays(v, 0.1 * ones, rate, 0.01 * ones, 2.0 * ones)
    # turning left fast: friction adds to the measured torque, so it is subtracted (and vice versa)
    assert col[4] == pytest.approx(2.0 - 3.0 / n_ratio - 0.5 * np.tanh(1.0 / (2.0 * DEG)), abs=1e-12)
    assert col[0] == pytest.approx(2.0 - 3.0 / n_ratio + 0.5 * np.tanh(1.0 / (2.0 * DEG)), abs=1e-12)
    assert col[2] == pytest.approx(2.0 - 3.0 / n_ratio)  # no rate: no friction
    assert col[5] == pytest.approx(2.0 - 3.0 / n_ratio)  # unknown rate: no friction
    assert abs(col[3] - col[2]) < 0.5 * 0.03  # 0.06 deg/s is deep inside the smoothing width
    # the twist uses the measured column torque (2 Nm x 0.5 deg/Nm = 1 deg) plus the 1 deg offset
    assert angle == pytest.approx(0.1 - 2.0 * DEG)
    assert yaw == pytest.approx(0.01 - 0.2 * DEG)


def test_friction_needs_the_steering_rate():
    v = _vehicle(steering_friction_Nm=0.4)
    with pytest.raises(ConfigError, match="steering rate"):
        condition_arrays(v, np.zeros(3), None, np.zeros(3), np.zeros(3))
    with pytest.raises(ConfigError, match="magnitude"):
        check_profile(v, rate_signed=False, profile_name="hyundai")
    check_profile(_vehicle(torsion_deg_per_Nm=0.5), rate_signed=False)  # no friction: fine


@pytest.mark.parametrize(
    "key, value",
    [
        ("steering_friction_Nm", -0.1),
        ("steering_friction_Nm", 9.0),
        ("friction_rate_deg_s", 0.0),
        ("steering_angle_offset_deg", 45.0),
        ("yaw_rate_bias_deg_s", 10.0),
    ],
)
def test_implausible_corrections_are_clear_errors(key, value):
    with pytest.raises(ConfigError, match=key):
        _vehicle(**{key: value})


def test_corrections_table_in_a_vehicle_file():
    v = vehicle_from_dict(
        {
            "name": "x",
            "vehicle": {
                "mass_kg": 1500,
                "yaw_inertia_kgm2": 2500,
                "lf_m": 1.1,
                "lr_m": 1.7,
                "track_front_m": 1.6,
                "track_rear_m": 1.6,
            },
            "steering": {"ratio": 15.0},
            "tires": {"cf_N_per_rad": 6e4, "cr_N_per_rad": 6e4, "align_rate_Nm_per_rad": 7000},
            "corrections": {"steering_friction_Nm": 0.3, "yaw_rate_bias_deg_s": -0.1},
        }
    )
    assert v.corrections.friction == 0.3
    assert v.corrections.yaw_bias == pytest.approx(-0.1 * DEG)
    with pytest.raises(ConfigError, match="unknown key"):
        with_corrections(v, {"steering_fricton_Nm": 1.0})


def _random_inputs(n=3000, seed=5):
    rng = np.random.default_rng(seed)
    t = 1_700_000_000_000_000_000 + np.arange(n, dtype=np.int64) * STEP_NS
    speed = 25.0 + np.cumsum(rng.normal(0, 0.01, n))
    angle = 0.05 * np.sin(np.arange(n) * 0.01) + rng.normal(0, 0.002, n)
    rate = np.gradient(angle, STEP_NS * 1e-9)
    yaw = 0.02 * np.sin(np.arange(n) * 0.01 + 0.3) + rng.normal(0, 0.001, n)
    col = 1.0 + rng.normal(0, 0.3, n)
    ast = 2.0 + rng.normal(0, 0.3, n)
    mdps = rng.random(n) > 0.01
    esc = rng.random(n) > 0.01
    speed[500:600] = 5.0  # a low-speed hold in between
    return t, speed, angle, rate, yaw, col, ast, mdps, esc


def test_live_steps_equal_the_batch_with_corrections():
    v = _vehicle(
        steering_friction_Nm=0.4, steering_angle_offset_deg=0.5, yaw_rate_bias_deg_s=0.1, align_offset_Nm=2.0
    )
    t, speed, angle, rate, yaw, col, ast, mdps, esc = _random_inputs()
    live = Estimator(v)
    batch = run_batch(t, speed, angle, yaw, col, ast, mdps, esc, v, steering_rate=rate)
    fw = np.empty(t.size)
    mw = np.empty(t.size)
    st = np.empty(t.size, dtype=np.uint8)
    for k in range(t.size):
        o = live.step(
            int(t[k]),
            EstimatorInputs(
                speed[k], angle[k], yaw[k], col[k], ast[k], bool(mdps[k]), bool(esc[k]), steering_rate=rate[k]
            ),
        )
        fw[k], mw[k], st[k] = o.fw, o.mw, int(o.status)
    assert np.array_equal(fw, batch.fw)
    assert np.array_equal(mw, batch.mw)
    assert np.array_equal(st, batch.status)
    # and the corrections did change the result
    plain = run_batch(t, speed, angle, yaw, col, ast, mdps, esc, load_vehicle("reference"))
    assert np.max(np.abs(plain.fw - batch.fw)) > 10.0


def _lane_change(sim_options, est_options, seed=0):
    pytest.importorskip("vcan_sim")
    from lde.analysis.study import ClusterConfig, RunSpec, run_specs

    spec = RunSpec(
        scenario="lane_change", seed=seed, duration=20.0, sim_options=sim_options, est_options=est_options
    )
    (res,) = run_specs([spec], ClusterConfig(n_workers=0), progress=False)
    assert res.ok, res.error
    return res.accuracy


@pytest.mark.slow
def test_angle_offset_and_yaw_bias_corrections_remove_the_fake_disturbance():
    """A 1 deg steering offset and a 0.2 deg/s gyro bias look like disturbances; the corrections with
    the true values take the undisturbed lane change's estimate back to the fault-free level (a wrong
    sign would double the error)."""
    clean = _lane_change((), ())
    off = _lane_change((("steer_offset_deg", 1.0),), ())
    fixed = _lane_change((("steer_offset_deg", 1.0),), (("steering_angle_offset_deg", 1.0),))
    assert off.rms_fw > 3 * clean.rms_fw
    assert fixed.rms_fw == pytest.approx(clean.rms_fw, rel=0.05, abs=2.0)
    assert fixed.rms_mw == pytest.approx(clean.rms_mw, rel=0.05, abs=1.0)
    bias = _lane_change((("yaw_bias_deg_s", 0.2),), ())
    unbiased = _lane_change((("yaw_bias_deg_s", 0.2),), (("yaw_rate_bias_deg_s", 0.2),))
    assert bias.rms_mw > 3 * clean.rms_mw
    assert unbiased.rms_mw == pytest.approx(clean.rms_mw, rel=0.05, abs=1.0)


@pytest.mark.slow
def test_friction_correction_removes_most_of_the_friction_residual():
    """0.8 Nm of rack friction in the simulator: the undisturbed lane change's estimate follows the
    driver's corrections; the correction with the simulator's value removes most of it."""
    raw = _lane_change((("friction_Nm", 0.8),), ())
    corr = _lane_change((("friction_Nm", 0.8),), (("steering_friction_Nm", 0.8),))
    assert corr.rms_fw < 0.5 * raw.rms_fw
