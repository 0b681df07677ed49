"""``lde inspect`` on a real car: the RAV4's 60 s drive of tests/data/real with the shipped
toyota_rav4_2017 profile, and the same profile with one sign flipped in a copy.

The expectations are outcomes and signs, never a fitted number: the shipped profile's signs were
found by these checks, so every check the drive decides passes and every sign it decides agrees
with ISO 8855; a flipped sign is named with the key to change, and only that one.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from lde.can.profiles import dbc_dir

from helpers.cli import run_lde as run
from helpers.real_cars import RAV4_LOG

RAV4 = RAV4_LOG
PROFILE = "toyota_rav4_2017"
#: the checks a drive with gentle curves in both directions decides (the drive's lane-keeping holds
#: the wheel, so the driver's torque may stay undecided: it must not fail)
DECIDED = ("lat_accel", "yaw_vs_steering", "wheel_speeds", "assist_torque", "steering_rate")


def flipped_copy(folder: Path, name: str) -> Path:
    """A copy of the shipped RAV4 profile (and its DBC) with input ``name``'s sign negated."""
    src = dbc_dir() / f"{PROFILE}.toml"
    shutil.copy(dbc_dir() / f"{PROFILE}.dbc", folder / f"{PROFILE}.dbc")
    lines = src.read_text().splitlines()
    table = lines.index(f"[inputs.{name}]")
    k = next(i for i in range(table + 1, len(lines)) if lines[i].startswith("sign ="))
    sign = int(lines[k].split("=")[1].split("#")[0])
    lines[k] = f"sign = {-sign}"
    out = folder / f"flipped_{name}.toml"
    out.write_text("\n".join(lines) + "\n")
    return out


def test_the_shipped_profile_passes_every_check_the_drive_decides():
    rc, out, _ = run("inspect", str(RAV4), "--profile", PROFILE, "--json")
    assert rc == 0
    rep = json.loads(out)
    assert rep["profile"] == PROFILE and rep["channel"] == "can0"
    assert rep["matches"][0]["profile"] == PROFILE and rep["matches"][0]["fits"]
    outcome = {c["key"]: c["outcome"] for c in rep["checks"]}
    assert all(outcome[k] == "pass" for k in DECIDED), outcome
    assert outcome["column_torque"] in ("pass", "not enough excitation")
    assert outcome["speed"] == "not applicable"  # the speed is the wheels' mean
    assert "fail" not in outcome.values()
    # the yaw rate's sign from the wheels' names, every other from it
    assert rep["signs"]["yaw_rate"]["checks"] == ["wheel_speeds"]
    assert all(s["ok"] for s in rep["signs"].values()), rep["signs"]
    assert set(rep["signs"]) >= {"yaw_rate", "lat_accel", "steering_angle", "assist_torque", "steering_rate"}
    integrity = {g["message"]: g for g in rep["inputs"]["integrity"]}
    assert integrity["STEER_TORQUE_SENSOR"]["checksum_failures"] == 0
    stats = {s["name"]: s for s in rep["inputs"]["stats"]}
    assert stats["assist_torque"]["unit"] == stats["column_torque"]["unit"] == "counts"  # unknown scale
    assert sorted(rep["inputs"]["unknown_scale"]) == ["assist_torque", "column_torque"]


def test_the_text_report_says_which_check_lacks_excitation():
    rc, out, _ = run("inspect", str(RAV4), "--profile", PROFILE)
    assert rc == 0
    assert "a. lateral acceleration against speed x yaw rate: PASS" in out
    assert "FAIL" not in out and "change:" not in out
    undecided = [line for line in out.splitlines() if "NOT ENOUGH EXCITATION" in line]
    assert all("column torque" in line for line in undecided), undecided
    assert "counts" in out  # the torques of unknown scale in raw counts


@pytest.mark.parametrize("name", ["yaw_rate", "lat_accel", "steering_angle", "steering_rate"])
def test_a_flipped_sign_is_named_with_the_key_to_change(tmp_path, name):
    profile = flipped_copy(tmp_path, name)
    rc, out, _ = run("inspect", str(RAV4), "--profile", str(profile), "--json")
    assert rc == 0
    rep = json.loads(out)
    wrong = {n for n, s in rep["signs"].items() if s["ok"] is False}
    assert wrong == {name}, rep["signs"]
    now = rep["input_signs"][name]
    line = f"[inputs.{name}] sign = {-int(now)}"
    fixes = [f for c in rep["checks"] for f in c["fix"]]
    assert fixes and all(f == line for f in fixes), fixes
    _, text, _ = run("inspect", str(RAV4), "--profile", str(profile))
    assert f"change: {line}" in text and f"{name}: wrong: set {line}" in text
