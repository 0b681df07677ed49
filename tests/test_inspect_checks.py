"""The physics checks of ``lde inspect`` on synthetic drives with known signs and scales.

A steady-state bicycle-model drive (speed around 20 m/s, the steering wheel weaving with periods
of 6-17 s, the yaw rate lagging it by a first-order 0.15 s) gives every input with ISO 8855 signs;
a test flips or rescales one and asserts which checks fail and which profile line they name.
"""

from __future__ import annotations

import numpy as np
import pytest

from lde.analysis.inspect.checks import (
    WHEELS,
    Geometry,
    Outcome,
    attribute_signs,
    run_checks,
    with_fixes,
)
from lde.analysis.inspect.resample import Series, common_grid
from lde.units import DEG, KMH

GEO = Geometry(wheelbase=2.7, steering_ratio=15.0, track=1.6, min_speed=30 * KMH)
K_US = 0.002  # s^2/m^2: 3.0 deg/g on a 2.7 m wheelbase
INPUTS = ("yaw_rate", "lat_accel", "steering_angle", "column_torque", "assist_torque")


def drive(
    seconds: float = 120.0,
    speed: float = 20.0,
    steer_deg: float = 20.0,
    seed: int = 0,
    wheels: bool = True,
    k_us: float = K_US,
    rate: bool = False,
) -> dict[str, Series]:
    """Inputs of a drive in SI with ISO signs, each at 100 Hz with its sensor's noise."""
    rng = np.random.default_rng(seed)
    dt = 0.01
    t = np.arange(0.0, seconds, dt)
    t_ns = 1_700_000_000_000_000_000 + np.rint(t * 1e9).astype(np.int64)
    v = speed + 2.0 * np.sin(2 * np.pi * t / 50.0)
    delta = steer_deg * DEG * (0.6 * np.sin(2 * np.pi * t / 17.0) + 0.4 * np.sin(2 * np.pi * t / 6.3 + 1.0))
    r_ss = v * delta / (GEO.steering_ratio * GEO.wheelbase * (1.0 + k_us * v**2))
    r = np.empty_like(r_ss)  # first-order yaw response, 0.15 s
    r[0] = r_ss[0]
    for i in range(1, t.size):
        r[i] = r[i - 1] + dt / 0.15 * (r_ss[i - 1] - r[i - 1])
    ay = 1.06 * v * r + 0.05  # roll tilt, a small bank
    torque = 2.0 * v * r + 0.3 * rng.standard_normal(t.size)  # held toward the turn
    out = {
        "speed": v + 0.02 * rng.standard_normal(t.size),
        "yaw_rate": r + 0.1 * DEG * rng.standard_normal(t.size),
        "lat_accel": ay + 0.05 * rng.standard_normal(t.size),
        "steering_angle": delta + 0.1 * DEG * rng.standard_normal(t.size),
        "column_torque": torque,
        "assist_torque": 3.0 * torque,
    }
    if rate:  # the angle sensor's own rate, in steps of 1 deg/s
        out["steering_rate"] = (
            np.round((np.gradient(delta, dt) + 0.5 * DEG * rng.standard_normal(t.size)) / DEG) * DEG
        )
    if wheels:  # right wheels on the outer circle of a left turn
        half = r * GEO.track / 2.0
        for w in WHEELS:
            side = 1.0 if w.endswith("r") else -1.0
            out[w] = v + side * half + 0.01 * rng.standard_normal(t.size)
    return {k: Series(t_ns, x, 30_000_000) for k, x in out.items()}


def check(
    series: dict[str, Series],
    geo: Geometry = GEO,
    signs: dict[str, float] | None = None,
    rate_signed: bool = True,
):
    """Run the checks with their sign attribution; (checks by key, findings)."""
    checks = run_checks(common_grid(series), geo, speed_is_wheels=False, rate_signed=rate_signed)
    found = attribute_signs(checks)
    fixed = with_fixes(checks, found, signs or {})
    return {c.key: c for c in fixed}, found


def flipped(series: dict[str, Series], *names: str, factor: float = -1.0) -> dict[str, Series]:
    out = dict(series)
    for n in names:
        s = out[n]
        out[n] = Series(s.t_ns, factor * s.values, s.timeout_ns)
    return out


@pytest.fixture(scope="module")
def good():
    return drive()


def test_a_drive_with_iso_signs_passes_every_check(good):
    checks, found = check(good)
    for key in ("lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque", "speed"):
        assert checks[key].outcome is Outcome.PASS, checks[key].why
        assert checks[key].fix == ()
    assert all(found[n].ok for n in INPUTS), found
    assert "wheel" in found["yaw_rate"].basis
    b = checks["yaw_vs_steering"].numbers
    assert (
        b["understeer_lo_deg_per_g"] <= K_US * GEO.wheelbase * 9.80665 / DEG <= b["understeer_hi_deg_per_g"]
    )
    assert b["steering_offset_lo_deg"] <= 0.0 <= b["steering_offset_hi_deg"]


@pytest.mark.parametrize("name", ["lat_accel", "steering_angle", "column_torque", "assist_torque"])
def test_a_flipped_input_fails_its_check_and_names_its_sign(good, name):
    checks, found = check(flipped(good, name), signs={name: 1.0})
    failed = [c for c in checks.values() if c.outcome is Outcome.FAIL]
    assert [c.relates[0] for c in failed] == [name], [c.why for c in failed]
    assert failed[0].fix == (f"[inputs.{name}] sign = -1",)
    assert found[name].ok is False and found["yaw_rate"].ok is True


def test_a_flipped_yaw_rate_is_named_once_by_every_check_it_fails(good):
    checks, found = check(flipped(good, "yaw_rate"), signs={"yaw_rate": -1.0})
    failed = {k for k, c in checks.items() if c.outcome is Outcome.FAIL}
    assert failed == {"lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque"}
    assert all(checks[k].fix == ("[inputs.yaw_rate] sign = 1",) for k in failed)
    assert found["yaw_rate"].ok is False
    assert all(found[n].ok for n in INPUTS if n != "yaw_rate")


def test_without_wheel_speeds_the_majority_blames_the_yaw_rate(good):
    no_wheels = {k: s for k, s in good.items() if k not in WHEELS}
    checks, found = check(flipped(no_wheels, "yaw_rate"))
    assert checks["wheel_speeds"].outcome is Outcome.NOT_APPLICABLE
    assert found["yaw_rate"].ok is False and "majority" in found["yaw_rate"].basis
    assert checks["lat_accel"].fix == ("[inputs.yaw_rate] sign = -1",)


def test_mirrored_drive_without_wheels_cannot_tell_which_side_is_left(good):
    """Every lateral signal negated is a physical drive: without wheel speeds all checks pass."""
    no_wheels = {k: s for k, s in good.items() if k not in WHEELS}
    checks, _ = check(flipped(no_wheels, *INPUTS))
    assert all(c.outcome in (Outcome.PASS, Outcome.NOT_APPLICABLE) for c in checks.values())
    with_wheels, found = check(flipped(good, *INPUTS))
    assert with_wheels["wheel_speeds"].outcome is Outcome.FAIL
    assert all(found[n].ok is False for n in INPUTS)


def test_a_straight_drive_is_not_enough_excitation_never_a_pass():
    checks, found = check(drive(steer_deg=0.0))
    for key in ("lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque"):
        assert checks[key].outcome is Outcome.NOT_ENOUGH_EXCITATION, checks[key].why
    assert found == {}


def test_a_flat_zero_input_is_not_enough_excitation(good):
    zero = dict(good)
    s = zero["steering_angle"]
    zero["steering_angle"] = Series(s.t_ns, np.zeros_like(s.values), s.timeout_ns)
    checks, _ = check(zero)
    assert checks["yaw_vs_steering"].outcome is Outcome.NOT_ENOUGH_EXCITATION
    assert "barely moves" in checks["yaw_vs_steering"].why


def test_a_standing_car_says_it_is_below_the_minimum_speed():
    checks, _ = check(drive(speed=3.0))
    for key in ("lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque"):
        assert checks[key].outcome is Outcome.NOT_ENOUGH_EXCITATION
        assert "below the minimum speed of 30 km/h for the whole log" in checks[key].why


def test_a_lateral_acceleration_in_g_fails_on_its_scale(good):
    checks, _ = check(flipped(good, "lat_accel", factor=1.0 / 9.80665))
    a = checks["lat_accel"]
    assert a.outcome is Outcome.FAIL and "wrong scale" in a.why
    assert any("[inputs.lat_accel] scale" in f for f in a.fix)


def test_an_implausible_understeer_names_the_steering_ratio(good):
    checks, _ = check(good, geo=Geometry(GEO.wheelbase, 40.0, GEO.track, GEO.min_speed))
    b = checks["yaw_vs_steering"]
    assert b.outcome is Outcome.FAIL and b.numbers["understeer_hi_deg_per_g"] < 0.0
    assert any("[steering] ratio" in f for f in b.fix)


def test_a_torque_that_does_not_follow_the_turn_is_not_enough_excitation(good):
    noise = dict(good)
    s = noise["column_torque"]
    noise["column_torque"] = Series(
        s.t_ns, np.random.default_rng(5).standard_normal(s.values.size), s.timeout_ns
    )
    checks, found = check(noise)
    assert checks["column_torque"].outcome is Outcome.NOT_ENOUGH_EXCITATION
    assert "column_torque" not in found


def test_the_speed_against_the_wheels_catches_a_wrong_unit(good):
    assert check(good)[0]["speed"].outcome is Outcome.PASS
    checks, _ = check(flipped(good, "speed", factor=3.6))  # km/h read as m/s
    assert checks["speed"].outcome is Outcome.FAIL and checks["speed"].fix == ("[inputs.speed] scale",)
    only = run_checks(common_grid(good), GEO, speed_is_wheels=True)
    assert next(c for c in only if c.key == "speed").outcome is Outcome.NOT_APPLICABLE


@pytest.fixture(scope="module")
def with_rate():
    return drive(rate=True)


def test_the_steering_rate_against_the_angles_derivative(with_rate):
    checks, found = check(with_rate)
    assert checks["steering_rate"].outcome is Outcome.PASS, checks["steering_rate"].why
    assert found["steering_rate"].ok is True
    checks, found = check(flipped(with_rate, "steering_rate"), signs={"steering_rate": 1.0})
    assert checks["steering_rate"].outcome is Outcome.FAIL
    assert checks["steering_rate"].fix == ("[inputs.steering_rate] sign = -1",)
    assert found["steering_rate"].ok is False and found["steering_angle"].ok is True


def test_a_flipped_angle_is_blamed_not_its_rate(with_rate):
    checks, found = check(flipped(with_rate, "steering_angle"), signs={"steering_angle": 1.0})
    assert {k for k, c in checks.items() if c.outcome is Outcome.FAIL} == {"yaw_vs_steering", "steering_rate"}
    assert checks["steering_rate"].fix == ("[inputs.steering_angle] sign = -1",)
    assert found["steering_angle"].ok is False and found["steering_rate"].ok is True


def test_a_rate_in_the_wrong_unit_fails_on_its_scale(with_rate):
    checks, _ = check(flipped(with_rate, "steering_rate", factor=1.0 / DEG))  # deg/s read as rad/s
    f = checks["steering_rate"]
    assert f.outcome is Outcome.FAIL and "wrong scale" in f.why
    assert any("[inputs.steering_rate] scale" in x for x in f.fix)


def test_a_rate_that_is_a_magnitude_is_not_checked(with_rate):
    checks, found = check(with_rate, rate_signed=False)
    assert checks["steering_rate"].outcome is Outcome.NOT_APPLICABLE and "steering_rate" not in found
