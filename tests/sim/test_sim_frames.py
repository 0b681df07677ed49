"""Frames on the bus: periods, counters, CRCs, decoded values vs truth, MDPS delay, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from lde.can.codec import MessageCodec
from lde.can.e2e import check_batch, p01_check, read_counter_batch
from lde.can.profiles import load_profile
from lde.errors import ConfigError
from lde.units import DEG, KMH, STEP_NS
from vcan_sim.run import Simulation, default_t0_ns, simulate

PERIODS = {
    "lde": {"MDPS_Sensors": 3_900_000, "ESC_Motion": 10_000_000},
    "hyundai": {"MDPS12": 10_000_000, "SAS11": 10_000_000, "ESP12": 20_000_000, "WHL_SPD11": 20_000_000},
}


def _decode(profile, name, frames):
    spec = profile.spec(name)
    sel = frames.select(frames.can_id == spec.frame_id)
    codec = MessageCodec(profile, name)
    cols = {s: np.array([codec.decode(bytes(d))[s] for d in sel.data]) for s in codec.signals}
    return sel, cols


@pytest.mark.parametrize("profile_name", ["lde", "hyundai"])
def test_periods_counters_and_crcs(sim_run, profile_name):
    res = sim_run("light_load", duration=3.0, profile=profile_name)
    prof = load_profile(profile_name)
    f = res.frames
    assert f.is_sorted() and np.all(f.is_rx)
    assert f.t_ns[0] == res.t0_ns == default_t0_ns(0)
    for name, period in PERIODS[profile_name].items():
        spec = prof.spec(name)
        sel = f.select(f.can_id == spec.frame_id)
        assert len(sel) == pytest.approx(3.0e9 / period, abs=1.5)
        assert np.all(np.diff(sel.t_ns) == period)
        assert np.all(sel.dlc == spec.length)
        assert np.all(check_batch(spec.scheme, spec.frame_id, sel.data, spec.length))
        ctr = read_counter_batch(spec.scheme, sel.data)
        assert np.all(ctr == np.arange(len(sel)) % spec.scheme.modulus)
        if profile_name == "lde":  # independent CRC check with autosar-e2e
            assert all(p01_check(spec.frame_id, bytes(d)) for d in sel.data[:20])
    assert len(f) == sum(round(3.0e9 / p + 0.5) for p in PERIODS[profile_name].values()) or len(f) > 0


def test_decoded_signals_match_truth_and_mdps_delay(sim_run):
    res = sim_run("heavy_load")
    prof = load_profile("lde")
    sel, cols = _decode(prof, "MDPS_Sensors", res.frames)
    tr, t_tr = res.truth, res.truth_t_ns
    assert np.array_equal(sel.t_ns, t_tr)  # the truth grid is the MDPS frame grid
    # torques are one MDPS period (3.9 ms) late (noise 5 mNm)
    np.testing.assert_allclose(cols["ColumnTorque"][1:], tr["T_column"][:-1], atol=0.03)
    np.testing.assert_allclose(cols["AssistTorque"][1:], tr["T_assist"][:-1], atol=0.03)
    # the MDPS senses its angle at the motor, below the torsion bar: N delta_f, not the wheel angle
    np.testing.assert_allclose(cols["SteeringAngle"] * DEG, tr["theta_p"], atol=0.15 * DEG)
    esc, ecols = _decode(prof, "ESC_Motion", res.frames)
    k = np.searchsorted(t_tr, esc.t_ns, side="right") - 1  # sample and hold of the 3.9 ms truth
    np.testing.assert_allclose(ecols["YawRate"] * DEG, tr["r"][k], atol=0.3 * DEG)
    np.testing.assert_allclose(ecols["VehicleSpeed"] * KMH, tr["vx"][k], atol=0.2)


def test_mdps_torques_delayed_by_3_9_ms_without_noise(vehicle, sim_params):
    import dataclasses

    quiet = dataclasses.replace(
        sim_params.sensors, column_torque_noise=0.0, assist_torque_noise=0.0, steering_angle_noise=0.0
    )
    sim = Simulation(
        "wind_step", vehicle, seed=0, duration=8.0, sim_params=dataclasses.replace(sim_params, sensors=quiet)
    )
    sim.run()
    res = sim.result()
    _, cols = _decode(load_profile("lde"), "MDPS_Sensors", res.frames)
    tr = res.truth
    lsb = 0.001
    assert np.abs(cols["ColumnTorque"][1:] - tr["T_column"][:-1]).max() <= 0.5 * lsb + 1e-9
    assert np.abs(cols["AssistTorque"][1:] - tr["T_assist"][:-1]).max() <= 0.5 * lsb + 1e-9
    assert np.abs(cols["ColumnTorque"][1:] - tr["T_column"][1:]).max() > 20 * lsb  # not the current value
    assert np.abs(cols["SteeringAngle"] * DEG - tr["theta_p"]).max() <= 0.05 * DEG + 1e-9  # angle: no delay


def test_angle_sensor_location(sim_run, sim_params, vehicle):
    """lde's MDPS angle is the pinion's (N delta_f); hyundai's SAS is the wheel's (twist included)."""
    lde_res = sim_run("heavy_load", duration=12.0)
    hy_res = sim_run("heavy_load", duration=12.0, profile="hyundai")
    tr = lde_res.truth
    twist = tr["delta_sw"] - tr["theta_p"]
    np.testing.assert_allclose(twist, tr["T_column"] / sim_params.steering.torsion_stiffness, atol=2e-4)
    np.testing.assert_allclose(tr["theta_p"], vehicle.steering.ratio * tr["delta_f"], rtol=1e-12)
    assert np.abs(twist).max() > 1.0 * DEG  # the holding torque twists the bar by more than a degree
    prof = load_profile("hyundai")
    sel, cols = _decode(prof, "SAS11", hy_res.frames)
    k = np.searchsorted(hy_res.truth_t_ns, sel.t_ns, side="right") - 1
    np.testing.assert_allclose(cols["SAS_Angle"] * DEG, hy_res.truth["delta_sw"][k], atol=0.15 * DEG)


def test_same_seed_same_bytes_other_seed_other_bytes():
    a = simulate("gusty_wind", seed=7, duration=5.0)
    b = simulate("gusty_wind", seed=7, duration=5.0)
    c = simulate("gusty_wind", seed=8, duration=5.0)
    assert np.array_equal(a.frames.t_ns, b.frames.t_ns) and np.array_equal(a.frames.data, b.frames.data)
    for k in a.truth:
        assert np.array_equal(a.truth[k], b.truth[k])
    assert c.t0_ns != a.t0_ns
    assert not np.array_equal(a.frames.data[100:], c.frames.data[100 : len(a.frames)])


@pytest.mark.parametrize("profile_name", ["lde", "hyundai"])
def test_stepping_equals_fast_path(profile_name):
    fast = simulate("wind_step", seed=3, duration=2.0, profile=profile_name)
    sim = Simulation("wind_step", seed=3, duration=2.0, profile=profile_name)
    steps = []
    while not sim.done:
        steps.append(sim.step())
    stepped = sim.result()
    assert np.array_equal(fast.frames.data, stepped.frames.data)
    assert np.array_equal(fast.frames.t_ns, stepped.frames.t_ns)
    assert sum(len(s) for s in steps) == len(fast.frames)
    assert all(len(s) == 0 or (s.t_ns.max() - s.t_ns.min()) < STEP_NS for s in steps)
    np.testing.assert_array_equal(fast.truth["Fw"], stepped.truth["Fw"])


def test_sensor_bias_and_noise_are_applied(vehicle, sim_params):
    import dataclasses

    sens = dataclasses.replace(sim_params.sensors, yaw_rate_bias=0.5 * DEG, yaw_rate_noise=0.0)
    sp = dataclasses.replace(sim_params, sensors=sens)
    sim = Simulation("straight", vehicle, seed=0, duration=2.0, sim_params=sp)
    sim.run()
    res = sim.result()
    _, cols = _decode(load_profile("lde"), "ESC_Motion", res.frames)
    assert np.mean(cols["YawRate"]) == pytest.approx(0.5, abs=0.02)


def test_mdps_angle_at_the_wheel_option(vehicle, sim_params):
    import dataclasses

    from lde.params import vehicle_from_dict

    sens = dataclasses.replace(sim_params.sensors, mdps_angle_at_motor=False, steering_angle_noise=0.0)
    sim = Simulation(
        "wind_step", vehicle, seed=0, duration=8.0, sim_params=dataclasses.replace(sim_params, sensors=sens)
    )
    sim.run()
    res = sim.result()
    _, cols = _decode(load_profile("lde"), "MDPS_Sensors", res.frames)
    assert np.abs(cols["SteeringAngle"] * DEG - res.truth["delta_sw"]).max() <= 0.05 * DEG + 1e-9
    # the TOML key
    from vcan_sim.config import sim_params_from_vehicle

    v = vehicle_from_dict({**_raw_vehicle(vehicle), "sim": {"sensors": {"mdps_angle_at_motor": False}}})
    assert sim_params_from_vehicle(v).sensors.mdps_angle_at_motor is False
    with pytest.raises(ConfigError, match="true or false"):
        sim_params_from_vehicle(
            vehicle_from_dict({**_raw_vehicle(vehicle), "sim": {"sensors": {"mdps_angle_at_motor": 1}}})
        )


def _raw_vehicle(v):
    b = v.body
    return {
        "name": "x",
        "vehicle": {
            "mass_kg": b.mass,
            "yaw_inertia_kgm2": b.yaw_inertia,
            "lf_m": b.lf,
            "lr_m": b.lr,
            "track_front_m": b.track_front,
            "track_rear_m": b.track_rear,
        },
        "steering": {"ratio": v.steering.ratio},
        "tires": {
            "cf_N_per_rad": v.tires.cf,
            "cr_N_per_rad": v.tires.cr,
            "align_rate_Nm_per_rad": v.tires.align_rate,
        },
    }


def test_hyundai_wheel_speeds_per_wheel():
    """WHL_SPD11 carries each wheel's speed: in a left turn the right (outer) wheels are faster."""
    from vcan_sim.scenarios import Scenario, Step

    turn = Scenario(
        "turn", "left turn", duration=6.0, speed_kmh=60.0, driver="angle", steer_deg=(Step(0.5, 0.5, 40.0),)
    )
    res = simulate(turn, seed=0, profile="hyundai")
    prof = load_profile("hyundai")
    sel, cols = _decode(prof, "WHL_SPD11", res.frames)
    late = slice(-50, None)
    assert (cols["WHL_SPD_FR"][late] - cols["WHL_SPD_FL"][late]).mean() > 0.5  # km/h
    assert (cols["WHL_SPD_RR"][late] - cols["WHL_SPD_RL"][late]).mean() > 0.5
    mean = (cols["WHL_SPD_FL"] + cols["WHL_SPD_FR"] + cols["WHL_SPD_RL"] + cols["WHL_SPD_RR"])[late] / 4 * KMH
    k = np.searchsorted(res.truth_t_ns, sel.t_ns[late], side="right") - 1
    np.testing.assert_allclose(mean, res.truth["vx"][k], atol=0.1)
