"""vcan_sim's road and drive additions: curvature (road coordinates), slalom weave, driver style,
the car's own payload ([sim.payload]) and where the hyundai SAS senses its angle."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from lde.can.codec import MessageCodec
from lde.can.profiles import load_profile
from lde.errors import ConfigError
from lde.params import vehicle_from_dict
from lde.units import DEG
from vcan_sim.config import sim_params_from_vehicle
from vcan_sim.run import Simulation, scenario_with, simulate
from vcan_sim.scenarios import (
    CURVE_RADIUS_M,
    ROUGH_DRIVER,
    SCENARIOS,
    DriverStyle,
    Step,
    Weave,
    weave_profile,
)


def decode_message(profile, name, signal, frames):
    """(t_ns, values) of one signal of message ``name`` in ``frames``."""
    spec = profile.spec(name)
    sel = frames.select(frames.can_id == spec.frame_id)
    codec = MessageCodec(profile, name)
    return sel.t_ns, np.array([codec.decode(bytes(d))[signal] for d in sel.data])


NEW_SCENARIOS = (
    "slalom",
    "curve_800m",
    "speed_ramp",
    "rough_driver",
    "steady_crosswind_10min",
    "banked_road_10min",
    "prior_drive",
)


def test_new_scenarios_are_registered_and_old_names_still_work():
    for name in NEW_SCENARIOS:
        assert name in SCENARIOS and SCENARIOS[name].description
    for name in ("heavy_load", "light_load", "lane_change", "payload_full", "bus_faults", "speed_sweep"):
        assert name in SCENARIOS
    assert SCENARIOS["steady_crosswind_10min"].duration == SCENARIOS["banked_road_10min"].duration == 600.0
    free = {n for n, sc in SCENARIOS.items() if sc.disturbance_free}
    assert free == {"lane_change", "straight", "overlay_step", "prior_drive"}
    ramp = SCENARIOS["speed_ramp"]
    assert ramp.speed_kmh == 80.0 and max(s.value for s in ramp.speed_steps) == 130.0


def test_left_curve_yaws_left_at_v_over_r_and_the_driver_keeps_the_lane(sim_run):
    """800 m left curve at 100 km/h: yaw rate +vx/R (a wrong curvature sign turns right), the
    steering wheel held left, the car within 0.5 m of the lane, the superelevation's bank force left."""
    res = sim_run("curve_800m", seed=0)
    tr = res.truth
    t = tr["t"] - tr["t"][0]
    inside = (t > 12.0) & (t < 14.0)  # in the curve, before the wind
    r_expected = tr["vx"][inside] / CURVE_RADIUS_M
    assert np.mean(tr["r"][inside]) == pytest.approx(np.mean(r_expected), rel=0.03)
    assert np.mean(tr["delta_sw"][inside]) > 1.0 * DEG
    assert np.abs(tr["y"]).max() < 0.5
    f_bank = res.body.mass * 9.80665 * np.sin(2.0 * DEG)
    assert np.mean(tr["F_bank"][inside]) == pytest.approx(f_bank, rel=0.02)
    straight = t < 5.0
    assert np.abs(tr["r"][straight]).max() < 0.2 * DEG


def test_weave_profile_and_slalom():
    t = np.arange(0.0, 40.0, 0.01)
    w = Weave(t_start=4.0, amplitude=1.2, period=5.0, cycles=6)
    y = weave_profile(t, w)
    assert y[t < 4.0].max() == 0.0 and y[t > 34.0].max() == 0.0
    assert y.max() == pytest.approx(1.2, rel=1e-3) and y.min() == pytest.approx(-1.2, rel=1e-3)
    assert np.abs(np.diff(y)).max() < 0.02  # smooth: no jump at the ends
    tr = simulate("slalom", seed=0, duration=30.0).truth
    tt = tr["t"] - tr["t"][0]
    # the car follows the weave: it crosses the lane centre about twice per period
    yy = tr["y"][(tt > 8.0) & (tt < 28.0)]
    crossings = np.count_nonzero(np.diff(np.sign(yy)) != 0)
    assert 6 <= crossings <= 10
    assert np.abs(yy).max() > 0.6


def test_driver_style_default_is_the_file_driver_and_rough_is_rougher():
    plain = simulate("straight", seed=0, duration=10.0)
    same = simulate(scenario_with("straight", driver_style=DriverStyle()), seed=0, duration=10.0)
    assert np.array_equal(plain.frames.data, same.frames.data)
    rough = simulate(scenario_with("straight", driver_style=ROUGH_DRIVER), seed=0, duration=10.0)
    rate = {k: np.std(np.diff(r.truth["delta_sw"])) for k, r in (("plain", plain), ("rough", rough))}
    assert rate["rough"] > 5.0 * rate["plain"]
    assert SCENARIOS["rough_driver"].driver_style == ROUGH_DRIVER


def test_straight_road_is_bit_identical_with_zero_curvature():
    """A zero-curvature step leaves every byte as it was (the road-coordinate terms vanish exactly)."""
    a = simulate("wind_step", seed=2, duration=6.0)
    b = simulate(scenario_with("wind_step", curvature=(Step(1.0, 1.0, 0.0),)), seed=2, duration=6.0)
    assert np.array_equal(a.frames.data, b.frames.data)


def _raw(vehicle, sim):
    b = vehicle.body
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
        "steering": {"ratio": vehicle.steering.ratio},
        "tires": {"cf_N_per_rad": 62000.0, "cr_N_per_rad": 56000.0, "align_rate_Nm_per_rad": 7200.0},
        "sim": sim,
    }


def test_car_payload_loads_the_car_and_moves_mw_ref(vehicle):
    v = vehicle_from_dict(_raw(vehicle, {"payload": {"trunk": 150.0, "front_passenger": 80.0}}))
    sp = sim_params_from_vehicle(v)
    assert sp.payload == (("trunk", 150.0), ("front_passenger", 80.0))
    res = simulate("wind_step", v, seed=0, duration=10.0)
    assert res.body.mass == pytest.approx(vehicle.body.mass + 230.0)
    assert res.body.lf > vehicle.body.lf  # the trunk load moves the CG back
    tr = res.truth
    # Mw_ref (about the unloaded CG, which lies ahead of the loaded one) = Mw + dx Fw with dx < 0
    assert res.body.dx_ref < 0.0
    np.testing.assert_allclose(tr["Mw_ref"], tr["Mw"] + res.body.dx_ref * tr["Fw"], atol=1e-6)
    # a scenario payload comes on top of the car's own
    full = simulate("payload_trunk", v, seed=0, duration=2.0)
    assert full.body.mass == pytest.approx(vehicle.body.mass + 380.0)
    with pytest.raises(ConfigError, match="unknown seat"):
        sim_params_from_vehicle(vehicle_from_dict(_raw(vehicle, {"payload": {"glovebox": 3.0}})))
    with pytest.raises(ConfigError, match=r"\(0, 2000\]"):
        sim_params_from_vehicle(vehicle_from_dict(_raw(vehicle, {"payload": {"trunk": -5.0}})))


@pytest.mark.parametrize("at_motor", [False, True])
def test_hyundai_sas_angle_above_or_below_the_torsion_bar(vehicle, sim_params, at_motor):
    """SAS11 reads the steering wheel (twist T_col / k_tb included) unless sas_angle_at_motor: then
    the pinion angle. The crosswind makes the driver hold ~2 Nm, a ~1 deg twist."""
    sens = dataclasses.replace(
        sim_params.sensors, sas_angle_at_motor=at_motor, steering_angle_noise=0.0, steering_rate_noise=0.0
    )
    sim = Simulation(
        "wind_step",
        vehicle,
        profile="hyundai",
        seed=0,
        duration=12.0,
        sim_params=dataclasses.replace(sim_params, sensors=sens),
    )
    sim.run()
    res = sim.result()
    t_ns, angle = decode_message(load_profile("hyundai"), "SAS11", "SAS_Angle", res.frames)
    truth_t = res.truth_t_ns
    want = res.truth["theta_p" if at_motor else "delta_sw"]
    other = res.truth["delta_sw" if at_motor else "theta_p"]
    idx = np.searchsorted(truth_t, t_ns, side="right") - 1
    ok = idx >= 0
    err = angle[ok] * DEG - want[idx[ok]]
    assert np.abs(err).max() < 0.1 * DEG  # 0.1 deg resolution of SAS_Angle (and sample timing)
    twist = np.abs(res.truth["delta_sw"] - res.truth["theta_p"]).max()
    assert twist > 0.5 * DEG  # the two positions really differ here
    assert np.abs(angle[ok] * DEG - other[idx[ok]]).max() > 0.4 * DEG
    # the TOML key
    v = vehicle_from_dict(_raw(vehicle, {"sensors": {"sas_angle_at_motor": True}}))
    assert sim_params_from_vehicle(v).sensors.sas_angle_at_motor is True
