"""Tire (Magic Formula Fy, Mz) and crosswind (eqs. 1-2) components."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lde.units import G
from vcan_sim.aero import coeff_n, coeff_y, crosswind, pack_aero
from vcan_sim.tires import aligning_slope, force_slope, lateral_force, pack_tire, pneumatic_trail, tire_forces


def _front_static_load(vehicle) -> float:
    b = vehicle.body
    return b.mass * G * b.lr / b.wheelbase / 2.0


def test_cornering_stiffness_in_215_60R16_range(vehicle, sim_params):
    c = force_slope(_front_static_load(vehicle), sim_params.tire)
    assert 55e3 <= c <= 75e3


def test_aligning_slope_in_paper_range(vehicle, sim_params):
    """Per-tire (pneumatic + mechanical trail) x Fy slope at nominal load: paper's 6750-7640 Nm/rad."""
    k = aligning_slope(_front_static_load(vehicle), sim_params.tire)
    assert 6750.0 <= k <= 7640.0


def test_signs_and_symmetry(sim_params):
    tc = pack_tire(sim_params.tire)
    for a in (0.01, 0.05, 0.2):
        fy, mz, tax = tire_forces(a, 4000.0, tc)
        assert fy > 0 and tax > 0 and mz < 0  # ISO Mz resists, paper-sign T_align positive
        fy2, mz2, tax2 = tire_forces(-a, 4000.0, tc)
        assert fy2 == pytest.approx(-fy) and tax2 == pytest.approx(-tax) and mz2 == pytest.approx(-mz)


def test_pneumatic_trail_falls_with_slip_and_rises_with_load(sim_params):
    tc = pack_tire(sim_params.tire)
    trails = [pneumatic_trail(math.radians(a), 4000.0, tc) for a in (0.0, 2.0, 4.0, 6.0, 8.0)]
    assert all(b < a for a, b in zip(trails, trails[1:], strict=False))
    assert pneumatic_trail(0.0, 5000.0, tc) > pneumatic_trail(0.0, 3000.0, tc)
    # aligning moment peaks before the force saturates
    alphas = np.radians(np.linspace(0.1, 15, 150))
    mz = np.array([-tire_forces(a, 4000.0, tc)[1] for a in alphas])
    fy = np.array([lateral_force(a, 4000.0, tc) for a in alphas])
    assert alphas[np.argmax(mz)] < alphas[np.argmax(fy)]


def test_load_dependence(sim_params):
    tc = pack_tire(sim_params.tire)
    # more load -> more force, but less than proportionally (load sensitivity)
    f3, f6 = lateral_force(0.05, 3000.0, tc), lateral_force(0.05, 6000.0, tc)
    assert f3 < f6 < 2.0 * f3
    assert lateral_force(0.05, 0.0, tc) == 0.0 and lateral_force(0.05, -10.0, tc) == 0.0
    # friction limit: |Fy| <= mu Fz
    assert abs(lateral_force(0.5, 4000.0, tc)) <= 1.05 * 4000.0


def test_crosswind_force_matches_eq1(sim_params):
    ap = pack_aero(sim_params.aero)
    a = sim_params.aero
    vx, w = 100 / 3.6, 15.0  # wind from the right: the air moves toward +y
    fx, fy, m_mid, vr, beta = crosswind(vx, 0.0, 0.0, w, 2.795, ap)
    assert vr == pytest.approx(math.hypot(vx, w))
    assert beta == pytest.approx(math.atan2(w, vx))
    cy = a.cy1 * math.sin(beta) * abs(math.cos(beta)) + a.cy2 * math.sin(beta) ** 2
    assert fy == pytest.approx(0.5 * a.air_density * cy * vr**2 * a.frontal_area)  # eq. (1)
    assert m_mid == pytest.approx(
        a.cn1 * math.sin(beta) * math.cos(beta) * a.air_density / 2 * 2.795 * a.frontal_area * vr**2
    )  # eq. (2)
    assert fy > 0 and m_mid > 0 and fx < 0


def test_coefficient_curves_flat_plate_like(sim_params):
    ap = pack_aero(sim_params.aero)
    b = np.radians(np.linspace(-60, 60, 121))
    cy = np.array([coeff_y(x, ap) for x in b])
    assert np.all(np.diff(cy) > 0)  # side force grows with the airflow angle up to 60 deg
    assert all(coeff_y(x, ap) > 0 for x in np.radians(np.linspace(1, 179, 50)))  # pushes with the air
    assert coeff_y(-0.3, ap) == pytest.approx(-coeff_y(0.3, ap))
    assert coeff_n(math.pi / 2, ap) == pytest.approx(0.0, abs=1e-12)
    assert coeff_n(math.pi / 4, ap) == pytest.approx(sim_params.aero.cn1 / 2)
