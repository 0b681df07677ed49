"""``lde inspect`` end to end: a simulated drive whose signs are ISO 8855 by construction, and the
exit codes a script relies on."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from lde.io import write_candump

from helpers.cli import run_lde as run

#: the checks a drive with curves decides (e: the hyundai speed is the wheels' mean)
DECIDED = ("lat_accel", "yaw_vs_steering", "wheel_speeds", "column_torque", "assist_torque")


@pytest.fixture(scope="module")
def slalom(tmp_path_factory) -> Path:
    """30 s of the simulator's slalom at 90 km/h on the hyundai bus (per-wheel speeds included)."""
    from vcan_sim.run import simulate

    res = simulate("slalom", profile="hyundai", duration=30.0)
    log = tmp_path_factory.mktemp("inspect") / "slalom.log"
    write_candump(log, res.frames)
    return log


def test_a_simulated_drive_passes_every_check_and_finds_its_profile(slalom):
    rc, out, _ = run("inspect", str(slalom), "--json")
    assert rc == 0
    rep = json.loads(out)
    assert rep["profile"] == "hyundai" and rep["profile_origin"] == "shipped"
    assert rep["matches"][0]["profile"] == "hyundai" and rep["matches"][0]["fits"]
    outcome = {c["key"]: c["outcome"] for c in rep["checks"]}
    assert all(outcome[k] == "pass" for k in DECIDED), outcome
    assert outcome["speed"] == "not applicable"
    assert all(s["ok"] for s in rep["signs"].values()), rep["signs"]
    stats = {s["name"]: s for s in rep["inputs"]["stats"]}
    assert stats["speed"]["minimum"] > 20.0 and stats["yaw_rate"]["unit"] == "rad/s"
    assert all(g["counter_jumps"] == 0 for g in rep["inputs"]["integrity"])


def test_the_text_report_names_ids_messages_and_outcomes(slalom):
    rc, out, _ = run("inspect", str(slalom), "--profile", "hyundai")
    assert rc == 0
    assert "0x251" in out and "MDPS12" in out and "fits" in out
    assert "a. lateral acceleration against speed x yaw rate: PASS" in out
    assert "steering-angle offset" in out and "understeer gradient" in out


def test_a_log_without_the_profiles_messages_exits_3(slalom):
    rc, out, err = run("inspect", str(slalom), "--profile", "lde")
    assert rc == 3
    assert "MDPS_Sensors (0x2A0, 8 B) missing" in out
    assert "none of the input messages of profile lde" in err


def test_a_missing_log_is_a_user_error(tmp_path):
    rc, _, err = run("inspect", str(tmp_path / "nope.log"))
    assert rc == 2 and err.startswith("lde: error:") and "nope.log" in err
