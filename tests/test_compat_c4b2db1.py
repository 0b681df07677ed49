"""Compatible with lde before profile files: the shipped profiles, now read from files, give the
CSVs the commit before them (c4b2db1) gave on the simulator's logs, and a recording that commit wrote
still loads and replays to the estimates it holds (``tests/data/c4b2db1/README.md`` says how each file
was made)."""

from __future__ import annotations

import csv
import gzip
import io
from pathlib import Path

import numpy as np
import pytest

from lde.cli import main
from lde.io import read_mcap
from lde.io.recording import ESTIMATE_TOPIC
from lde.params import load_vehicle
from lde.replay.replay import replay_log

DATA = Path(__file__).resolve().parent / "data" / "c4b2db1"


def _columns(text: str) -> dict[str, list[str]]:
    rows = list(csv.reader(io.StringIO(text)))
    return {name: [r[k] for r in rows[1:]] for k, name in enumerate(rows[0])}


@pytest.mark.parametrize("profile", ["lde", "hyundai"])
def test_shipped_profiles_give_the_csv_of_the_commit_before_profile_files(tmp_path, profile):
    out = tmp_path / "now.csv"
    log = DATA / f"{profile}.log.gz"
    assert main(["replay", str(log), "--profile", profile, "--csv", str(out), "-q"]) == 0
    base = _columns(gzip.decompress((DATA / f"{profile}.csv.gz").read_bytes()).decode())
    now = _columns(out.read_text())
    shared = [c for c in base if c in now]
    assert {"t", "Fw", "Mw", "T_overlay", "status"} <= set(shared)
    assert len(now["t"]) == len(base["t"]) > 700
    for c in shared:
        assert now[c] == base[c], c
    assert any(float(v) != 0.0 for v in now["Fw"])  # an estimate, not only zeros


def test_a_recording_of_the_commit_before_loads_and_replays_to_its_own_estimates():
    path = DATA / "recording_lde.mcap"
    rec = read_mcap(path, json_topics=[ESTIMATE_TOPIC]).json[ESTIMATE_TOPIC]
    log, res = replay_log(path, None, load_vehicle("reference"), "fixed")
    assert res.profile is not None and res.profile.name == "lde" and res.profile_origin == "recording"
    assert res.recorded_steps
    np.testing.assert_array_equal(res.t_ns, rec["t_ns"])
    np.testing.assert_array_equal(res.block.status, rec["status"])
    for mine, theirs in (("Fw", "Fw"), ("Mw", "Mw"), ("T_overlay", "T_overlay")):
        np.testing.assert_array_equal(res.columns()[mine], rec[theirs])
    assert log.frames.channels == ("",) and log.frames.width == 8
