"""`lde replay`'s outputs explain themselves: the CSV decodes its status bits into 0/1 columns
(the estimate columns keep their names and order), `--help` and docs/guide/csv.md list every column, the
summary names every file it wrote, and a replay without --csv / --mcap says that nothing was
written and how to write it."""

from __future__ import annotations

import csv
import re
from pathlib import Path

import numpy as np
import pytest

from lde.cli import main
from lde.replay.columns import CSV_COLUMNS, SMOOTHED, STATUS_COLUMNS, csv_columns
from lde.status import STATUS_BITS, Status

DATA = Path(__file__).parent / "data"
SAMPLE = DATA / "sample_linear.log"
SAMPLE_VEHICLE = DATA / "sample_linear_vehicle.toml"
ROOT = Path(__file__).resolve().parents[1]
BASE = ["replay", str(SAMPLE), "--vehicle", str(SAMPLE_VEHICLE), "--backend", "float"]


def _read(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


@pytest.fixture(scope="module")
def replayed(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("outputs") / "o.csv"
    assert main([*BASE, "--csv", str(out), "-q"]) == 0
    return out


def test_the_estimate_columns_keep_their_names_and_order_and_the_status_comes_decoded(replayed):
    header, body = _read(replayed)
    names = [c for c, _, _ in CSV_COLUMNS]
    assert header[:4] == ["t", "Fw", "Mw", "T_overlay"]
    assert header[: len(names)] == names
    decoded = [c for c, _, _ in STATUS_COLUMNS]
    assert decoded == [*STATUS_BITS, "overlay_active"]
    assert header[len(names) :] == decoded  # appended after every existing column
    cols = {name: np.array([int(r[header.index(name)]) for r in body]) for name in ["status", *decoded]}
    for i, flag in enumerate(Status):
        np.testing.assert_array_equal(cols[str(flag.name).lower()], (cols["status"] >> i) & 1, flag.name)
    state = np.array([int(r[header.index("overlay_state")]) for r in body])
    np.testing.assert_array_equal(cols["overlay_active"], np.isin(state, (1, 2)).astype(int))
    # the sample drive has both: steps before convergence and valid steps with the overlay on
    assert cols["valid"].any() and (cols["valid"] == 0).any() and cols["not_converged"].any()
    assert cols["overlay_active"].any()
    for name in decoded:
        assert set(np.unique(cols[name])) <= {0, 1}, name


def test_smoothed_columns_stay_where_they_were_and_the_status_follows_them(tmp_path):
    out = tmp_path / "s.csv"
    assert main([*BASE, "--csv", str(out), "--smooth", "-q"]) == 0
    header, _ = _read(out)
    assert header == [c for c, _, _ in CSV_COLUMNS + SMOOTHED + STATUS_COLUMNS]
    assert header == [c for c, _, _ in csv_columns(smooth=True)]


def test_help_and_docs_list_every_column_with_its_unit(capsys):
    with pytest.raises(SystemExit):
        main(["replay", "--help"])
    text = capsys.readouterr().out
    doc = (ROOT / "docs" / "guide" / "csv.md").read_text()
    assert "ISO 8855" in text and "ISO 8855" in doc
    for name, _, meaning in csv_columns(smooth=True):
        unit = meaning.split(",")[0]
        assert re.search(rf"^\s+{re.escape(name)}\s+{re.escape(unit)}", text, re.M), name
        assert re.search(rf"^\| `{re.escape(name)}` \|", doc, re.M), f"{name} missing in docs/guide/csv.md"
    for flag in Status:  # the doc gives each decoded column its bit
        assert re.search(rf"^\| `{str(flag.name).lower()}` \| {flag.bit_length() - 1} \|", doc, re.M)


def test_a_replay_without_outputs_says_nothing_was_written_and_how(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(BASE) == 0
    err = capsys.readouterr().err
    assert "steps" in err and "frames used" in err  # the summary
    assert "nothing written" in err and "--csv" in err and "--mcap" in err
    assert " wrote " not in err
    assert list(tmp_path.iterdir()) == []
    # with --learned only, the learned state is written and named; the estimates are not
    learned = tmp_path / "l.toml"
    assert main([*BASE, "--learned", str(learned)]) == 0
    err = capsys.readouterr().err
    assert learned.exists() and f"wrote learned state {learned}" in err
    assert "the estimates were not written" in err and "nothing written" not in err
    # -q: nothing at all
    assert main([*BASE, "-q"]) == 0
    assert capsys.readouterr().err == ""


def test_the_summary_names_every_file_written(tmp_path, capsys):
    c, m, learned = tmp_path / "o.csv", tmp_path / "o.mcap", tmp_path / "l.toml"
    args = [*BASE, "--csv", str(c), "--mcap", str(m), "--learned", str(learned), "--smooth"]
    assert main(args) == 0
    err = capsys.readouterr().err
    line = next(ln for ln in err.splitlines() if ln.startswith("  wrote "))
    assert line == (
        f"  wrote CSV (with the *_smooth columns) {c}, MCAP (with /lde/smooth) {m}, learned state {learned}"
    )
    assert c.exists() and m.exists() and learned.exists()
    assert "nothing written" not in err


def test_several_logs_name_their_files_and_the_directory(tmp_path, capsys):
    mcap = DATA / "sample_linear.mcap"
    out = tmp_path / "csv"
    assert main(["replay", str(SAMPLE), str(mcap), "--backend", "float", "--csv", str(out)]) == 0
    err = capsys.readouterr().err
    for name in ("sample_linear_log.csv", "sample_linear_mcap.csv"):
        assert f"  wrote CSV {out / name}" in err
        assert (out / name).exists()
    assert f"lde replay: wrote 2 CSV files in {out}" in err
