"""The zoo (vcan_sim/zoo): cars the estimator was not fitted to, their true values, their variety."""

from __future__ import annotations

import dataclasses

import pytest

from lde.params import load_vehicle, shipped_vehicles
from lde.units import DEG
from vcan_sim import zoo
from vcan_sim.config import SimParams, sim_params_from_vehicle
from vcan_sim.identify import static_stiffness

PLANTS = zoo.plant_names()


def _signature(vehicle):
    """Everything that makes a plant: body, ratio and the simulator's parameters."""
    sp = sim_params_from_vehicle(vehicle)
    return (vehicle.body, vehicle.steering.ratio, dataclasses.astuple(sp))


def test_at_least_eight_plants_each_with_a_one_line_description():
    assert len(PLANTS) >= 8
    for name in PLANTS:
        text = zoo.description(name)
        assert 20 < len(text) < 160 and "\n" not in text
        assert zoo.load_plant(name).name == name


def test_every_plant_differs_from_every_shipped_file_and_the_default_plant():
    shipped = {n: _signature(load_vehicle(n)) for n in shipped_vehicles()}
    ref = load_vehicle("reference")
    default_plant = (ref.body, ref.steering.ratio, dataclasses.astuple(SimParams()))
    sigs = {}
    for name in PLANTS:
        sig = _signature(zoo.load_plant(name))
        assert sig != default_plant, name
        for other, s in shipped.items():
            assert sig != s, (name, other)
        sigs[name] = sig
    assert len(set(map(repr, sigs.values()))) == len(PLANTS)  # no two plants alike


def test_the_zoo_covers_the_issue_11_variations():
    tv = zoo.read_true_values()
    assert set(tv) == set(PLANTS)
    ref_cf, ref_cr, ref_k = static_stiffness(load_vehicle("reference"))
    cf = [v.cf_static / ref_cf for v in tv.values()]
    assert min(cf) <= 0.75 + 0.01 and max(cf) >= 1.25 - 0.01  # tire stiffness +-25 %
    k = [v.k_static / ref_k for v in tv.values()]
    assert min(k) < 0.8 and max(k) > 1.2  # trail and aligning slope
    assert len({v.ratio for v in tv.values()}) >= 3  # steering ratio
    fr = [v.rack_friction_Nm for v in tv.values()]
    assert min(fr) <= 0.05 and max(fr) >= 0.8  # rack friction 0.05-0.8 Nm
    assert len({(v.mass, v.lf) for v in tv.values()}) >= 4  # mass / CG / yaw inertia
    assert any(v.payload_kg > 0 and v.cg_shift_m < -0.05 for v in tv.values())  # a payload variant
    assert any(v.steer_offset_deg != 0 and v.yaw_bias_deg_s != 0 for v in tv.values())
    for profile in ("lde", "hyundai"):  # the angle above and below the torsion bar on both profiles
        assert {getattr(v, f"angle_{profile}") for v in tv.values()} == {"pinion", "wheel"}


def test_independent_simulator_twin_has_its_tires():
    """Per-tire 70 / 58 kN/rad and an aligning slope of 7000 Nm/rad at the static loads, Table 2 body."""
    v = zoo.load_plant("indep_twin")
    cf, cr, k = static_stiffness(v)
    assert cf == pytest.approx(70_000, rel=0.005)
    assert cr == pytest.approx(58_000, rel=0.005)
    assert k == pytest.approx(7_000, rel=0.005)
    ref = load_vehicle("reference")
    assert v.body == ref.body and v.steering.ratio == ref.steering.ratio


def test_true_values_match_the_plants():
    """true_values.csv is what the plants are: static tangents and mass properties recomputed, the
    plant files' [tires] = the identified values, and one identification re-run (indep_twin)."""
    tv = zoo.read_true_values()
    for name in PLANTS:
        v = zoo.load_plant(name)
        t = tv[name]
        cf, cr, k = static_stiffness(v)
        assert (t.cf_static, t.cr_static, t.k_static) == pytest.approx((cf, cr, k), abs=1.0)
        assert (v.tires.cf, v.tires.cr, v.tires.align_rate) == pytest.approx((t.cf, t.cr, t.k), abs=1.0)
        sp = sim_params_from_vehicle(v)
        assert t.rack_friction_Nm == pytest.approx(sp.steering.rack_coulomb)
        assert t.steer_offset_deg == pytest.approx(sp.sensors.steering_angle_bias / DEG)
        assert t.description == zoo.description(name)
    again = zoo.identify_plant("indep_twin")
    t = tv["indep_twin"]
    assert (again.cf, again.cr, again.k) == pytest.approx((t.cf, t.cr, t.k), abs=1.0)


def test_payload_plant_truth_is_about_both_cgs():
    tv = zoo.read_true_values()["loaded_twin"]
    spec = zoo.load_plant("loaded_twin").body
    assert tv.mass == pytest.approx(spec.mass + tv.payload_kg)
    assert tv.lf > spec.lf + 0.1  # the load moves the CG back
    assert tv.cg_shift_m == pytest.approx(spec.lf - tv.lf, abs=1e-3)


def test_unknown_plant_is_a_clear_error():
    from lde.errors import ConfigError

    with pytest.raises(ConfigError, match="indep_twin"):
        zoo.plant_path("no_such_car")
