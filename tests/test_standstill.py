"""A standing car is a standing car: a log whose speed never reaches the model's minimum (the
real Hyundai Kona of tests/data/real, powered up and never moving) is reported as below the
minimum speed by ``lde replay`` (exit 3) and as not enough excitation by ``lde inspect``, never as
a wrong profile."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

from lde.cli import main

KONA = Path(__file__).parent / "data" / "real" / "kona_ev_2019_standstill.log.gz"
#: the checks that need the car moving (e: the hyundai speed is the wheels' mean)
MOVING = ("lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque")


def run(*argv: str) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(argv))
    assert "Traceback" not in err.getvalue()
    return rc, out.getvalue(), err.getvalue()


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
