"""The command-line contract (SPEC section 4), run as a user runs it: ``python -m lde`` subprocesses.

``lde sim --list``; ``lde sim --scenario X --log --truth --mcap --duration --seed [--t0] [--profile]``;
``lde replay`` of candump, MCAP, ASC, BLF and ``--profile hyundai`` logs, with ``--vehicle`` (a
shipped name, a TOML file that extends the reference) and ``--backend fixed|float``. The CSV:
a header, one row per 3.9 ms step, ``t`` in the log's own time base (epoch seconds for these logs),
``Fw``, ``Mw``, ``T_overlay``; an ``lde replay --mcap`` recording replays to the same CSV.
Errors: exit status 2 and one ``lde: error:`` line. Short runs only (a few seconds of driving).
"""

from __future__ import annotations

import contextlib
import io
import subprocess
import sys
from decimal import Decimal
from pathlib import Path

import numpy as np
import pytest

STEP_US = 3900  # the grid period [us]
SEED = 3
T0_S = 1_700_000_000 + SEED  # lde sim's default clock start: 1.7e9 s + seed


def lde_all(*commands: tuple, ok: bool = True) -> list[subprocess.CompletedProcess]:
    """Run several ``lde`` commands at once (each a tuple of arguments); wait for all of them."""
    procs = [
        (
            cmd,
            subprocess.Popen(
                [sys.executable, "-m", "lde", *map(str, cmd)],
                stdout=subprocess.PIPE,
                stderr=subprocess.PIPE,
                text=True,
            ),
        )
        for cmd in commands
    ]
    done = []
    for cmd, p in procs:
        out, err = p.communicate(timeout=300)
        done.append(subprocess.CompletedProcess(cmd, p.returncode, out, err))
    if ok:
        for r in done:
            assert r.returncode == 0 and "Traceback" not in r.stderr, (r.args, r.stderr)
    return done


def lde(*args: str | Path, ok: bool = True) -> subprocess.CompletedProcess:
    return lde_all(args, ok=ok)[0]


def lde_here(*args: str | Path) -> subprocess.CompletedProcess:
    """The same command in this process (:func:`lde.cli.main`): no interpreter start-up."""
    from lde.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main([str(a) for a in args])
    return subprocess.CompletedProcess(args, rc, out.getvalue(), err.getvalue())


def read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    lines = path.read_text().splitlines()
    return lines[0].split(","), [r.split(",") for r in lines[1:]]


def t_us(rows: list[list[str]], col: int = 0) -> np.ndarray:
    """A time column as exact integer microseconds (the text, never through a float)."""
    return np.array([int(Decimal(r[col]) * 1_000_000) for r in rows], np.int64)


def column(header: list[str], rows: list[list[str]], name: str) -> np.ndarray:
    i = header.index(name)
    return np.array([float(r[i]) for r in rows])


def log_times_us(path: Path) -> np.ndarray:
    return np.array([int(Decimal(line[1 : line.index(")")]) * 1_000_000) for line in path.open()], np.int64)


@pytest.fixture(scope="module")
def sim(tmp_path_factory) -> tuple[Path, dict[str, subprocess.CompletedProcess]]:
    """``lde`` processes: 4 s of steady crosswind (ramping in over 2 s) -> a.log, a.csv (truth),
    a.mcap; and an error. In this process: ``--list``; 3 s on the hyundai profile with a shipped
    vehicle and an own start time -> h.log; another error."""
    d = tmp_path_factory.mktemp("cli")
    runs = lde_all(
        ("sim", "--scenario", "steady_wind", "--log", d / "a.log", "--truth", d / "a.csv",
         "--mcap", d / "a.mcap", "--duration", "4", "--seed", SEED),
        ("replay", d / "missing.log"),
        ok=False,
    )  # fmt: skip
    assert runs[0].returncode == 0, runs[0].stderr
    out = {"sim": runs[0], "err_replay": runs[1]}
    out["list"] = lde_here("sim", "--list")
    from lde.cli import main

    with pytest.raises(SystemExit) as version_exit, contextlib.redirect_stdout(io.StringIO()) as version:
        main(["--version"])
    assert version_exit.value.code == 0 and version.getvalue().startswith("lde ")
    out["hyundai"] = lde_here(
        "sim", "--scenario", "steady_wind", "--profile", "hyundai", "--vehicle", "est3", "--duration", "3",
        "--seed", "1", "--t0", "1234567890.25", "--log", d / "h.log",
    )  # fmt: skip
    out["err_sim"] = lde_here("sim", "--scenario", "no_such_scenario", "--log", d / "x.log")
    for n in ("sim", "hyundai", "list"):
        assert out[n].returncode == 0, out[n].stderr
    return d, out


@pytest.fixture(scope="module")
def replayed(sim) -> Path:
    """An ``lde`` process replays four copies of the drive (candump, MCAP, ASC, BLF) -> csv/ and
    mcap/ (default backend). In this process: the candump log with ``--backend float`` and with a
    vehicle file; the hyundai log with ``--profile hyundai`` and (wrongly) with the default one."""
    import can

    from lde.io import read_log

    d, _ = sim
    msgs = read_log(d / "a.log").frames.to_messages(channel=0)
    for suffix, writer in ((".asc", can.ASCWriter), (".blf", can.BLFWriter)):
        w = writer(str(d / f"p{suffix}"))
        for m in msgs:
            w.on_message_received(m)
        w.stop()
    lde(
        "replay",
        d / "a.log",
        d / "a.mcap",
        d / "p.asc",
        d / "p.blf",
        "--csv",
        d / "csv",
        "--mcap",
        d / "mcap",
        "-q",
    )
    (d / "heavy.toml").write_text('extends = "reference"\nname = "heavy"\n\n[vehicle]\nmass_kg = 1900.0\n')
    runs = [
        lde_here("replay", d / "a.log", "--backend", "float", "--csv", d / "float.csv", "-q"),
        lde_here("replay", d / "a.log", "--vehicle", d / "heavy.toml", "--csv", d / "heavy.csv", "-q"),
        lde_here("replay", d / "h.log", "--profile", "hyundai", "--csv", d / "h.csv", "-q"),
        lde_here("replay", d / "h.log", "--csv", d / "wrong.csv"),
    ]
    for r in runs[:-1]:
        assert r.returncode == 0, r.stderr
    assert runs[-1].returncode == 3, runs[-1].stderr  # replayed, but nothing usable: an honest exit
    (d / "wrong.err").write_text(runs[-1].stderr)
    return d


def test_sim_list_names_every_scenario(sim):
    from vcan_sim.scenarios import SCENARIOS

    out = sim[1]["list"].stdout.splitlines()
    assert [line.split()[0] for line in out] == list(SCENARIOS)
    assert all(len(line.split()) > 2 for line in out)  # a description follows each name


def test_sim_writes_candump_truth_and_mcap_in_one_time_base(sim):
    d = sim[0]
    first = (d / "a.log").open().readline().split()
    assert first[0] == f"({T0_S}.000000)" and first[1] == "vcan0" and "#" in first[2]
    header, rows = read_csv(d / "a.csv")
    assert header[:3] == ["t", "Fw", "Mw"]
    t = t_us(rows)
    assert t[0] == T0_S * 1_000_000 and np.all(np.diff(t) == STEP_US)
    assert t[-1] - t[0] >= 4_000_000 - STEP_US
    from lde.io import read_log

    mcap = read_log(d / "a.mcap").frames
    assert np.array_equal(mcap.t_ns // 1000, log_times_us(d / "a.log"))


def test_replay_csv_contract(replayed: Path):
    header, rows = read_csv(replayed / "csv" / "a_log.csv")
    assert header[:4] == ["t", "Fw", "Mw", "T_overlay"]
    assert all(len(r) == len(header) for r in rows)
    t = t_us(rows)
    frames_t = log_times_us(replayed / "a.log")
    # one row per step, 3.9 ms apart, from the first accepted MDPS frame to the last frame,
    # in the log's own epoch (not relative to its start)
    assert np.all(np.diff(t) == STEP_US)
    assert frames_t[0] <= t[0] <= frames_t[0] + 3 * STEP_US and t[0] in frames_t
    assert frames_t[-1] - STEP_US < t[-1] <= frames_t[-1]
    assert len(rows) == (t[-1] - t[0]) // STEP_US + 1
    # the estimate's steps are the simulator's truth times (same time base)
    truth_t = t_us(read_csv(replayed / "a.csv")[1])
    assert np.isin(t, truth_t).all()
    for name in ("Fw", "Mw", "T_overlay"):
        assert np.isfinite(column(header, rows, name)).all()
    fw = column(header, rows, "Fw")
    assert abs(fw[-1]) > 100.0  # the crosswind is seen (accuracy is tested elsewhere)


def test_replay_of_mcap_blf_and_asc_copies_gives_the_same_csv(replayed: Path):
    d = replayed / "csv"
    ref = (d / "a_log.csv").read_text()
    assert (d / "a_mcap.csv").read_text() == ref
    header, rows = read_csv(d / "a_log.csv")
    for name in ("p_asc", "p_blf"):
        h2, rows2 = read_csv(d / f"{name}.csv")
        assert h2 == header and [r[1:] for r in rows2] == [r[1:] for r in rows]
    # BLF keeps the absolute time; ASC's own time base is relative to its start of measurement
    assert t_us(read_csv(d / "p_blf.csv")[1]).tolist() == t_us(rows).tolist()
    t_asc = t_us(read_csv(d / "p_asc.csv")[1])
    assert np.array_equal(t_asc, t_us(rows) - log_times_us(replayed / "a.log")[0])


def test_replay_of_an_lde_recording_reproduces_the_csv(replayed: Path):
    rec = replayed / "mcap" / "a_log.mcap"
    lde("replay", rec, "--csv", replayed / "again.csv", "-q")
    assert (replayed / "again.csv").read_text() == (replayed / "csv" / "a_log.csv").read_text()


def test_backends_float_and_fixed_share_the_grid_and_agree(replayed: Path):
    hf, rf = read_csv(replayed / "float.csv")
    hx, rx = read_csv(replayed / "csv" / "a_log.csv")  # the default backend: fixed
    assert hf == hx and t_us(rf).tolist() == t_us(rx).tolist()
    fw_f, fw_x = column(hf, rf, "Fw"), column(hx, rx, "Fw")
    assert np.max(np.abs(fw_f - fw_x)) < 0.05 * np.max(np.abs(fw_f)) + 20.0


def test_vehicle_file_extending_the_reference(replayed: Path):
    ref = column(*read_csv(replayed / "csv" / "a_log.csv"), "Fw")
    header, rows = read_csv(replayed / "heavy.csv")
    heavy = column(header, rows, "Fw")
    assert len(heavy) == len(ref) and not np.array_equal(heavy, ref)


def test_hyundai_profile_sim_and_replay_with_own_start_time(replayed: Path):
    assert " 251#" in (replayed / "h.log").read_text()  # MDPS12 = 593
    header, rows = read_csv(replayed / "h.csv")
    t = t_us(rows)
    assert 1234567890_250000 <= t[0] < 1234567890_300000 and np.all(np.diff(t) == STEP_US)
    assert column(header, rows, "esc_ok")[-1] == 1 and column(header, rows, "mdps_ok")[-1] == 1
    # the same log under the default profile: no MDPS frame, a header-only CSV and a note
    err = (replayed / "wrong.err").read_text()
    assert "no estimator step" in err
    assert "no frame of MDPS_Sensors (0x2A0), ESC_Motion (0x2A8)" in err and "fit profile hyundai" in err
    assert (replayed / "wrong.csv").read_text().splitlines() == [",".join(header)]


def test_errors_exit_2_with_one_line(sim):
    for name in ("err_replay", "err_sim"):
        proc = sim[1][name]
        assert proc.returncode == 2 and "Traceback" not in proc.stderr
        assert proc.stderr.startswith("lde: error: ") and len(proc.stderr.strip().splitlines()) == 1
