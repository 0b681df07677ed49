"""Payload mass properties (eqs. 17-18) and the [sim] table."""

from __future__ import annotations

import pytest

from lde.errors import ConfigError
from lde.params import vehicle_from_dict
from vcan_sim.config import sim_params_from_vehicle
from vcan_sim.payload import PAYLOADS, Payload, cg_from_wheel_loads, loaded_body, static_wheel_loads


def test_eq17_18_recover_the_mass_weighted_cg(vehicle, sim_params):
    b = vehicle.body
    for name, pl in PAYLOADS.items():
        body = loaded_body(vehicle, sim_params, pl)
        masses = [(b.mass, b.lf, 0.0)] + [
            (m, sim_params.seats[s].x_behind_front_axle, sim_params.seats[s].y_left) for s, m in pl.items
        ]
        mt = sum(m for m, _, _ in masses)
        assert body.mass == pytest.approx(mt), name
        assert body.lf == pytest.approx(sum(m * x for m, x, _ in masses) / mt), name
        assert body.y_cg == pytest.approx(sum(m * y for m, _, y in masses) / mt, abs=1e-12), name
        assert body.lf + body.lr == pytest.approx(b.wheelbase)
        assert body.yaw_inertia >= b.yaw_inertia


def test_cg_from_wheel_loads_roundtrip():
    fz = static_wheel_loads(1500.0, 1.2, 0.1, 2.8, 1.6)
    x, y = cg_from_wheel_loads(fz, 2.8, 1.6)
    assert (x, y) == pytest.approx((1.2, 0.1))


def test_full_load_is_in_papers_range(vehicle, sim_params):
    body = loaded_body(vehicle, sim_params, PAYLOADS["full"])
    assert 1800 <= body.mass <= 1950 and body.lf > vehicle.body.lf and body.dx_ref < 0


def test_bad_payload_and_sim_table(vehicle, sim_params):
    with pytest.raises(ConfigError):
        loaded_body(vehicle, sim_params, Payload((("glovebox", 10.0),)))
    with pytest.raises(ConfigError):
        loaded_body(vehicle, sim_params, Payload((("trunk", -5.0),)))
    raw = {
        "name": "x",
        "vehicle": {
            "mass_kg": 1466.0,
            "yaw_inertia_kgm2": 2744.0,
            "lf_m": 1.071,
            "lr_m": 1.724,
            "track_front_m": 1.587,
            "track_rear_m": 1.587,
        },
        "steering": {"ratio": 15.0},
        "tires": {"cf_N_per_rad": 6e4, "cr_N_per_rad": 6e4, "align_rate_Nm_per_rad": 7000.0},
    }
    assert sim_params_from_vehicle(vehicle_from_dict(raw)).tire == sim_params.tire  # defaults without [sim]
    with pytest.raises(ConfigError, match="cg_hieght_m"):
        sim_params_from_vehicle(vehicle_from_dict({**raw, "sim": {"cg_hieght_m": 0.5}}))
    with pytest.raises(ConfigError, match="aero"):
        sim_params_from_vehicle(vehicle_from_dict({**raw, "sim": {"aero": {"frontal_area_m2": "big"}}}))
    sp = sim_params_from_vehicle(
        vehicle_from_dict(
            {**raw, "sim": {"steering": {"torsion_stiffness_Nm_per_deg": 1.5}, "tire": {"pKy1": 15.0}}}
        )
    )
    assert sp.tire.pKy1 == 15.0 and sp.steering.torsion_stiffness == pytest.approx(1.5 * 57.29577951308232)


def test_diverging_plant_is_a_clear_error(vehicle, sim_params):
    import dataclasses

    from vcan_sim.run import Simulation, SimulationError

    bad = dataclasses.replace(
        sim_params, steering=dataclasses.replace(sim_params.steering, wheel_inertia=1e-6)
    )
    sim = Simulation("straight", vehicle, sim_params=bad, duration=1.0)
    with pytest.raises(SimulationError, match="diverged"):
        sim.run()
