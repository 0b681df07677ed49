"""A standing car is a standing car: a log whose speed never reaches the model's minimum (the
real Hyundai Kona of tests/data/real, powered up and never moving) is reported as below the
minimum speed by ``lde replay`` (exit 3) and as not enough excitation by ``lde inspect``, never as
a wrong profile."""

from __future__ import annotations

import json

from helpers.cli import run_lde as run
from helpers.real_cars import KONA_LOG

KONA = KONA_LOG
#: the checks that need the car moving (e: the hyundai speed is the wheels' mean)
MOVING = ("lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque")


def test_a_standing_car_is_not_enough_excitation_below_the_minimum_speed():
    rc, out, _ = run("inspect", str(KONA), "--json")
    assert rc == 0
    rep = json.loads(out)
    assert rep["profile"] == "hyundai"
    for c in rep["checks"]:
        if c["key"] in MOVING:
            assert c["outcome"] == "not enough excitation"
            assert "below the minimum speed of 30 km/h for the whole log" in c["why"]
    assert rep["signs"] == {}


def test_replay_of_a_standing_car_says_so_and_exits_3(tmp_path):
    rc, _, err = run("replay", str(KONA), "--profile", "hyundai", "--csv", str(tmp_path / "k.csv"))
    assert rc == 3
    line = [s for s in err.splitlines() if "no valid estimate" in s]
    assert len(line) == 1, err
    assert "below the minimum speed of 30 km/h for the whole log" in line[0]
    assert "wrong --profile" not in line[0]
