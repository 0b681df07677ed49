"""The issue's validation list: the nonlinear plant against physics and the linear model."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from lde.units import DEG, G
from vcan_sim.identify import bicycle_steady_state, identify, static_stiffness
from vcan_sim.run import simulate
from vcan_sim.scenarios import Scenario, Step


def _turn(speed_kmh: float, sw_deg: float) -> Scenario:
    return Scenario(
        "turn",
        "steady turn",
        duration=20.0,
        speed_kmh=speed_kmh,
        driver="angle",
        steer_deg=(Step(1.0, 1.0, sw_deg),),
    )


@pytest.mark.parametrize(("speed", "sw"), [(60.0, 10.0), (100.0, 5.0), (100.0, 10.0)])
def test_small_angle_steady_cornering_matches_linear_bicycle(vehicle, light, speed, sw):
    """Yaw rate and side slip in a steady small-angle turn vs eqs. (7)-(9) with the linear-equivalent
    stiffnesses identified from a DIFFERENT run (the light-load disturbance drive)."""
    eq = identify(light.truth, light.body.lf, light.body.lr)
    tr = simulate(_turn(speed, sw), seed=0).truth
    last = slice(-770, None)  # the last 3 s: the driver's hands add a little torque noise
    r_sim, beta_sim = tr["r"][last].mean(), tr["beta"][last].mean()
    assert abs(tr["ay"][last].mean()) < 2.0  # small angle: linear range
    assert tr["r"][last].std() < 0.01 * abs(r_sim)  # steady
    b = vehicle.body
    beta, r = bicycle_steady_state(
        b.mass, b.lf, b.lr, eq.cf, eq.cr, tr["vx"][last].mean(), tr["delta_f"][last].mean()
    )
    assert r_sim == pytest.approx(r, rel=0.02)
    assert beta_sim == pytest.approx(beta, rel=0.08, abs=2e-4)


def test_tire_level_stiffness_matches_magic_formula_tangent(light):
    """Fig. 12 check in the linear range: the fitted per-tire stiffness is the MF tangent at static load."""
    eq = identify(light.truth, light.body.lf, light.body.lr)
    cf, cr, k = static_stiffness()
    assert eq.cf_tire == pytest.approx(cf, rel=0.01)
    assert eq.cr_tire == pytest.approx(cr, rel=0.01)
    assert eq.k == pytest.approx(k, rel=0.01)


def test_heavy_and_light_linear_equivalents_close_and_k_in_paper_range(heavy, light):
    h = identify(heavy.truth, heavy.body.lf, heavy.body.lr)
    lo = identify(light.truth, light.body.lf, light.body.lr)
    assert h.cf == pytest.approx(lo.cf, rel=0.05) and h.cr == pytest.approx(lo.cr, rel=0.05)
    assert h.max_alpha_f > 3 * lo.max_alpha_f
    for e in (h, lo):
        assert 6750.0 <= e.k <= 7640.0
        assert min(e.r2_cf, e.r2_cr, e.r2_k) > 0.99


def test_crosswind_force_in_simulation_is_eq1(heavy, sim_params):
    tr = heavy.truth
    a = sim_params.aero
    m = tr["wind_speed"] > 5.0
    beta = tr["beta_cw"][m]
    cy = a.cy1 * np.sin(beta) * np.abs(np.cos(beta)) + a.cy2 * np.sin(beta) * np.abs(np.sin(beta))
    # relative airflow from the ground speed and the wind (crosswind toward +Y; heading ~ 0)
    vr2 = (tr["vx"][m] * np.cos(tr["psi"][m]) - tr["vy"][m] * np.sin(tr["psi"][m])) ** 2 + (
        tr["wind_speed"][m] - tr["vx"][m] * np.sin(tr["psi"][m]) - tr["vy"][m] * np.cos(tr["psi"][m])
    ) ** 2
    np.testing.assert_allclose(tr["Fy_wind"][m], 0.5 * a.air_density * cy * vr2 * a.frontal_area, rtol=1e-6)


def test_bank_force_is_mg_sin_bank(vehicle, sim_run):
    tr = sim_run("bank_transition").truth
    m = vehicle.body.mass
    expect = m * G * np.sin(tr["bank"]) * np.cos(tr["psi"])
    np.testing.assert_allclose(tr["F_bank"], expect, rtol=1e-9, atol=1e-9)
    assert np.abs(tr["bank"]).max() == pytest.approx(3.0 * DEG)
    assert np.abs(tr["F_bank"]).max() == pytest.approx(m * G * math.sin(3.0 * DEG), rel=1e-3)
    # no wind: the disturbance is the bank force alone, and it has no yaw moment about the CG
    assert np.abs(tr["Fw"] - tr["F_bank"]).max() < 20.0  # the car's own sideslip in still air: a few N
    assert np.abs(tr["Mw"]).max() < 5.0


def test_mw_about_reference_cg_for_a_payload(sim_run):
    res = sim_run("payload_full")
    tr = res.truth
    assert res.body.dx_ref < -0.1
    np.testing.assert_allclose(tr["Mw_ref"], tr["Mw"] + res.body.dx_ref * tr["Fw"], rtol=1e-12, atol=1e-9)
    assert np.abs(tr["Mw_ref"] - tr["Mw"]).max() > 100.0


def test_eq11_aligning_torque_balance_without_friction(vehicle, sim_params):
    """Steady state, Coulomb friction off: T_align = N (T_column + T_assist) (paper eq. 11)."""
    sp = dataclasses.replace(sim_params, steering=dataclasses.replace(sim_params.steering, rack_coulomb=0.0))
    sc = Scenario("hold", "steady wind", duration=15.0, wind_speed=(Step(1.0, 2.0, 10.0),))
    from vcan_sim.run import Simulation

    sim = Simulation(sc, vehicle, sim_params=sp, seed=1)
    sim.run()
    tr, _ = sim.truth()
    n = vehicle.steering.ratio
    last = slice(-300, None)
    lhs = tr["T_align"][last]
    rhs = n * (tr["T_column"][last] + tr["T_assist"][last])
    assert np.abs(lhs).mean() > 50.0  # a real load
    assert np.abs(lhs - rhs).mean() < 0.01 * np.abs(lhs).mean() + 1.0  # residual: rack damping x rate, noise


def test_straight_without_disturbance_stays_in_lane(sim_run):
    tr = sim_run("straight").truth
    assert np.abs(tr["y"]).max() < 0.25
    assert np.abs(tr["delta_sw"]).max() < 2.0 * DEG
    assert np.abs(tr["Fw"]).max() < 5.0


@pytest.mark.parametrize("name", ["heavy_load", "light_load", "lane_change"])
def test_driver_holds_the_lane_with_small_steering(name, sim_run):
    tr = sim_run(name).truth
    target = 0.0 if name != "lane_change" else None
    if target is not None:
        assert np.abs(tr["y"]).max() < 0.6
    else:
        assert tr["y"][np.searchsorted(tr["t"], tr["t"][0] + 13.0)] == pytest.approx(3.5, abs=0.3)
        assert abs(tr["y"][-1]) < 0.3
    assert np.abs(tr["delta_sw"]).max() < 15.0 * DEG  # paper: -15..15 deg for straight driving


def test_driver_reacts_to_overlay_torque(sim_run):
    """A 2 Nm overlay: the driver lets go of about that much torque instead of being steered away."""
    tr = sim_run("overlay_step").truth
    t = tr["t"] - tr["t"][0]
    on = (t > 10.0) & (t < 15.0)
    assert tr["T_overlay"][on].mean() == pytest.approx(2.0, abs=0.05)
    assert tr["T_driver"][on].mean() < -1.0  # counter-torque
    assert np.abs(tr["y"]).max() < 0.3


def test_payload_moves_the_linear_equivalents(sim_run, light):
    """Rear payload loads the rear tires: the identified rear stiffness rises, K stays in range."""
    lo = identify(light.truth, light.body.lf, light.body.lr)
    res = sim_run("payload_full")
    full = identify(res.truth, res.body.lf, res.body.lr)
    cf, cr, k = static_stiffness(payload="full")
    assert full.cr > 1.1 * lo.cr
    assert full.cr_tire == pytest.approx(cr, rel=0.02) and full.cf_tire == pytest.approx(cf, rel=0.02)
    assert 6750.0 <= full.k <= 7640.0
