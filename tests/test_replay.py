"""lde.replay.replay and `lde replay`: the acceptance test on the linear-model sample log, CSV contract,
MCAP recordings that replay to the same estimates, CLI behaviour."""

from __future__ import annotations

import csv
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lde.can.profiles import load_profile
from lde.cli import main
from lde.io import read_log, read_mcap
from lde.params import load_vehicle
from lde.replay.replay import CSV_COLUMNS, csv_columns, replay, replay_log, write_csv, write_recording

DATA = Path(__file__).parent / "data"
SAMPLE = DATA / "sample_linear.log"
SAMPLE_MCAP = DATA / "sample_linear.mcap"
TRUTH = DATA / "sample_linear_truth.csv"
#: the sample's plant parameters (the estimator runs on them; robust to changes of the reference vehicle)
SAMPLE_VEHICLE = DATA / "sample_linear_vehicle.toml"
ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def profile():
    return load_profile("lde")


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle(SAMPLE_VEHICLE)


@pytest.fixture(scope="module")
def sample_replay(profile, vehicle):
    return replay_log(SAMPLE, profile, vehicle, "float")


def _backend_or_skip(name: str) -> str:
    from lde.errors import ConfigError
    from lde.replay.replay import resolve_backend

    try:
        resolve_backend(name)
    except ConfigError as exc:
        pytest.skip(str(exc))
    return name


def read_truth() -> dict[str, np.ndarray]:
    with TRUTH.open() as fh:
        rows = list(csv.DictReader(fh))
    t_ns = np.array([int(r["t"].replace(".", "")) * 1000 for r in rows], np.int64)  # 6 decimals exact
    return {"t_ns": t_ns, **{k: np.array([float(r[k]) for r in rows]) for k in ("Fw", "Mw")}}


@pytest.mark.parametrize("backend", ["float", "fixed"])
def test_acceptance_linear_log_converges_to_truth(backend, profile, vehicle):
    """THE acceptance test: after settling, the replayed estimate is within 5% of the true Fw, Mw."""
    _log, res = replay_log(SAMPLE, profile, vehicle, _backend_or_skip(backend))
    assert res.backend == backend
    truth = read_truth()
    j = np.searchsorted(truth["t_ns"], res.t_ns, side="right") - 1
    fw_true, mw_true = truth["Fw"][j], truth["Mw"][j]
    t_rel = (res.t_ns - truth["t_ns"][0]) * 1e-9
    settled = (t_rel >= 10.0) & (t_rel < 20.0)  # disturbance from 5 s, 5 s to settle
    assert np.all(fw_true[settled] == 800.0) and np.all(mw_true[settled] == -300.0)
    assert np.all(res.status[settled] & 1)  # VALID
    fw_mean, mw_mean = res.fw[settled].mean(), res.mw[settled].mean()
    assert abs(fw_mean - 800.0) <= 0.05 * 800.0, fw_mean
    assert abs(mw_mean + 300.0) <= 0.05 * 300.0, mw_mean
    # every 1 s window of the settled part, not only the mean of all of it
    for a in np.arange(10.0, 20.0, 1.0):
        w = (t_rel >= a) & (t_rel < a + 1.0)
        assert abs(res.fw[w].mean() - 800.0) <= 0.05 * 800.0, (a, res.fw[w].mean())
        assert abs(res.mw[w].mean() + 300.0) <= 0.10 * 300.0, (a, res.mw[w].mean())
    # before the disturbance the estimate stays near zero (after the filter's own start-up)
    quiet = (t_rel >= 2.0) & (t_rel < 5.0)
    assert abs(res.fw[quiet].mean()) < 0.05 * 800.0
    assert abs(res.mw[quiet].mean()) < 0.1 * 300.0


def test_receiver_diag_counts_frames_per_step(profile, vehicle):
    """frames_used sums to the frames used up to the last step; a corrupted frame is counted once."""
    log = read_log(SAMPLE)
    frames = log.frames
    bad = frames.data.copy()
    k = int(np.flatnonzero(frames.can_id == 0x2A0)[500])
    bad[k, 0] ^= 0xFF  # wrong CRC
    corrupted = type(frames)(frames.t_ns, frames.can_id, frames.is_extended, frames.dlc, bad, frames.is_rx)
    res = replay(corrupted, profile, vehicle, "float")
    d = res.diag
    assert d["frames_used"].sum() == res.frames.used - int(np.count_nonzero(frames.t_ns > res.t_ns[-1]))
    j = np.searchsorted(res.t_ns, frames.t_ns[k])
    assert d["e2e_rejects"][j - 1] == 0 and d["e2e_rejects"][j] == 1 and d["e2e_rejects"][-1] == 1
    assert res.frames.rejected_by_cause()["wrong_crc"] == 1


def test_sample_log_frames_are_all_used(sample_replay):
    log, res = sample_replay
    assert log.stats.skipped == 0
    assert res.frames.rejected == 0
    assert res.frames.ignored == 0
    # the E2E receiver needs a few frames to trust each message; everything else is used
    assert res.frames.used >= res.frames.total - 6


def test_mcap_copy_replays_like_candump(sample_replay, profile, vehicle):
    _log, res = sample_replay
    _log2, res2 = replay_log(SAMPLE_MCAP, profile, vehicle, "float")
    assert not res2.recorded_steps  # a plain log (no /can/tx, no /lde/estimate): grid from frames
    np.testing.assert_array_equal(res.t_ns, res2.t_ns)
    np.testing.assert_array_equal(res.fw, res2.fw)
    np.testing.assert_array_equal(res.mw, res2.mw)


def test_recording_replays_to_the_same_estimates(sample_replay, profile, vehicle, tmp_path: Path):
    log, res = sample_replay
    out = tmp_path / "rec.mcap"
    write_recording(out, log.frames, res, profile)
    rec_log, res2 = replay_log(out, profile, vehicle, "float")
    assert res2.recorded_steps
    assert rec_log.mcap is not None and {"/can/tx", "/lde/estimate", "/lde/inputs"} <= set(
        rec_log.mcap.topics
    )
    assert res2.frames.tx == 3 * len(res)  # LDE_Estimate, LDE_Overlay, LDE_Disturbance per step
    np.testing.assert_array_equal(res.t_ns, res2.t_ns)
    np.testing.assert_array_equal(res.fw, res2.fw)
    np.testing.assert_array_equal(res.mw, res2.mw)
    np.testing.assert_array_equal(res.status, res2.status)
    # the recorded estimates are the replayed ones (to the printed precision)
    est = read_mcap(out, json_topics=["/lde/estimate"]).json["/lde/estimate"]
    np.testing.assert_array_equal(est["t_ns"], res.t_ns)
    np.testing.assert_array_equal(est["Fw"], res.fw)  # the JSON floats are exact (round trip)


def test_recorded_step_times_are_used(sample_replay, profile, vehicle, tmp_path: Path):
    """Steps of a recording are its recorded ones even when they are not the frame-anchored grid."""
    log, res = sample_replay
    shifted = replay(log.frames, profile, vehicle, "float", step_times_ns=res.t_ns[::2] + 1_000_000)
    out = tmp_path / "shifted.mcap"
    write_recording(out, log.frames, shifted, profile)
    _, again = replay_log(out, profile, vehicle, "float")
    np.testing.assert_array_equal(again.t_ns, shifted.t_ns)
    np.testing.assert_array_equal(again.fw, shifted.fw)
    _, grid = replay_log(out, profile, vehicle, "float", use_recorded_steps=False)
    np.testing.assert_array_equal(grid.t_ns, res.t_ns)


def test_csv_contract(sample_replay, tmp_path: Path):
    log, res = sample_replay
    out = tmp_path / "o.csv"
    write_csv(out, res)
    with out.open() as fh:
        rows = list(csv.reader(fh))
    header, body = rows[0], rows[1:]
    assert header[:4] == ["t", "Fw", "Mw", "T_overlay"]
    assert header[: len(CSV_COLUMNS)] == [c for c, _, _ in CSV_COLUMNS]  # the estimate columns first
    assert header == [c for c, _, _ in csv_columns()]
    assert len(body) == len(res)
    # t: seconds in the log's own time base, printed exactly (microseconds)
    first = int(log.frames.t_ns[0])
    for i in (0, 1, len(res) // 2, len(res) - 1):
        s, frac = body[i][0].split(".")
        assert len(frac) == 6
        assert int(s) * 10**9 + int(frac) * 1000 == res.t_ns[i]
    assert abs(float(body[0][0]) - first * 1e-9) < 0.05
    np.testing.assert_allclose([float(r[1]) for r in body], res.fw, atol=5e-4)
    np.testing.assert_allclose([float(r[2]) for r in body], res.mw, atol=5e-4)
    assert [int(r[5]) for r in body] == res.status.tolist()
    cols = res.columns()
    assert cols["Fw"] is res.fw and cols["T_overlay"] is res.t_overlay and len(cols["t_ns"]) == len(res)


def test_csv_writer_thread_writes_the_same_bytes_in_order(sample_replay, tmp_path: Path):
    """The CSV writer's thread (the engine's core stays free) writes what the inline writer does,
    block after block in order, and a write error surfaces as one OutputError (an OSError naming
    the file: lde replay keeps what was written, issue 13)."""
    from lde.errors import OutputError
    from lde.replay.replay import CsvWriter

    _, res = sample_replay
    block = res.block
    cuts = np.linspace(0, len(block), 7).astype(int)
    fields = vars(block)
    parts = [
        type(block)(**{k: v[a:b] for k, v in fields.items()})
        for a, b in zip(cuts[:-1], cuts[1:], strict=True)
    ]
    outs = {}
    for background in (True, False):
        out = tmp_path / f"bg{background}.csv"
        w = CsvWriter(out, background=background)
        for p in parts:
            w.write(p)
        w.close()
        outs[background] = out.read_bytes()
    assert outs[True] == outs[False]
    assert outs[True].count(b"\n") == len(block) + 1

    if not Path("/dev/full").exists():
        return
    w = CsvWriter("/dev/full")  # every write fails (ENOSPC): in the writer's thread
    w.write(block)
    with pytest.raises(OutputError, match="cannot write"):
        w.close()


def test_cli_end_to_end(tmp_path: Path, capsys):
    out = tmp_path / "o.csv"
    rec = tmp_path / "o.mcap"
    rc = main(
        ["replay", str(SAMPLE), "--vehicle", str(SAMPLE_VEHICLE), "--backend", "float"]
        + ["--csv", str(out), "--mcap", str(rec)]
    )
    assert rc == 0
    err = capsys.readouterr().err
    assert "steps" in err and "frames used" in err
    with out.open() as fh:
        rows = list(csv.reader(fh))
    assert rows[0][:4] == ["t", "Fw", "Mw", "T_overlay"]
    n_steps = len(rows) - 1
    assert f"{n_steps} steps" in err
    t = np.array([float(r[0]) for r in rows[1:]])
    assert t[0] > 1.7e9 and np.allclose(np.diff(t), 0.0039, atol=2e-6)
    # the recording replays to the identical CSV
    out2 = tmp_path / "o2.csv"
    args = [
        "replay",
        str(rec),
        "--vehicle",
        str(SAMPLE_VEHICLE),
        "--backend",
        "float",
        "--csv",
        str(out2),
        "-q",
    ]
    assert main(args) == 0
    assert out2.read_bytes() == out.read_bytes()


def test_cli_several_logs_write_a_directory(tmp_path: Path):
    outdir = tmp_path / "csv"
    assert (
        main(["replay", str(SAMPLE), str(SAMPLE_MCAP), "--backend", "float", "--csv", str(outdir), "-q"]) == 0
    )
    files = sorted(p.name for p in outdir.iterdir())
    assert files == ["sample_linear_log.csv", "sample_linear_mcap.csv"]
    # the MCAP copy holds the same frames: the same estimates
    assert (outdir / files[0]).read_bytes() == (outdir / files[1]).read_bytes()


def test_cli_errors_are_one_line(tmp_path: Path):
    bad = tmp_path / "bad.log"
    bad.write_text("not a log\n")
    for args in (
        ["replay", str(bad)],
        ["replay", str(tmp_path / "missing.mcap")],
        ["replay", str(SAMPLE), "--profile", "nope"],
        ["replay", str(SAMPLE), "--vehicle", str(tmp_path / "missing.toml")],
    ):
        proc = subprocess.run(
            [sys.executable, "-m", "lde", *args], capture_output=True, text=True, cwd=tmp_path, timeout=120
        )
        assert proc.returncode == 2, (args, proc.stderr)
        lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("lde: error:")]
        assert len(lines) == 1, proc.stderr
        assert "Traceback" not in proc.stderr


def test_sample_log_is_reproducible(tmp_path: Path):
    """The committed sample files are exactly what the script makes under its seed."""
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "make_sample_log.py"), "--out-dir", str(tmp_path)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "sample_linear.log").read_bytes() == SAMPLE.read_bytes()
    assert (tmp_path / "sample_linear_truth.csv").read_bytes() == TRUTH.read_bytes()
    assert (tmp_path / "sample_linear_vehicle.toml").read_bytes() == SAMPLE_VEHICLE.read_bytes()
    new = read_log(tmp_path / "sample_linear.mcap")
    old = read_log(SAMPLE_MCAP)
    np.testing.assert_array_equal(new.frames.data, old.frames.data)
    total = sum(p.stat().st_size for p in DATA.glob("sample_linear*"))
    assert total < 2_000_000


@pytest.mark.parametrize("suffix", [".blf", ".asc"])
def test_python_can_formats_replay_like_candump(sample_replay, profile, vehicle, tmp_path: Path, suffix: str):
    """The sample drive written by python-can's own writers replays to the same estimates."""
    import can

    log, res = sample_replay
    path = tmp_path / f"sample{suffix}"
    with can.Logger(str(path)) as writer:
        for msg in log.frames.to_messages(channel=0):
            writer.on_message_received(msg)
    other_log, other = replay_log(path, profile, vehicle, "float")
    assert other_log.format == suffix[1:]
    assert len(other) == len(res)
    np.testing.assert_array_equal(np.diff(other.t_ns), np.diff(res.t_ns))
    if suffix == ".blf":  # BLF keeps absolute time; ASC is relative to its start
        np.testing.assert_array_equal(other.t_ns, res.t_ns)
    np.testing.assert_allclose(other.fw, res.fw, rtol=0, atol=1e-6)
    np.testing.assert_allclose(other.mw, res.mw, rtol=0, atol=1e-6)


def _run_cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "lde", *args], capture_output=True, text=True, cwd=cwd, timeout=120
    )


def test_cli_never_overwrites_an_input_log(tmp_path: Path):
    """An output that is one of the LOGs (any spelling, a symlink) or another output: exit 2, one
    line, nothing written; a LOG given twice: the same."""
    log = tmp_path / "a.log"
    log.write_bytes(SAMPLE.read_bytes())
    (tmp_path / "b.log").write_bytes(SAMPLE.read_bytes())
    (tmp_path / "sub").mkdir()
    (tmp_path / "link.csv").symlink_to(log)
    before = log.read_bytes()
    cases = [
        ["replay", "a.log", "--csv", "a.log"],
        ["replay", "a.log", "--mcap", "a.log"],
        ["replay", "a.log", "--csv", "sub/../a.log"],
        ["replay", "a.log", "--csv", "link.csv"],
        ["replay", "a.log", "--csv", "o.x", "--mcap", "o.x"],
        ["replay", "a.log", "a.log", "--csv", "d"],
        ["replay", "a.log", "./sub/../a.log"],
        ["replay", "a.log", "--csv", "nodir/x.csv"],
        ["replay", "a.log", "b.log", "--csv", "nodir/d"],
    ]
    expect = ["input log"] * 4 + ["same file", "twice", "twice"] + ["no such directory nodir"] * 2
    for args, what in zip(cases, expect, strict=True):
        proc = _run_cli(args, tmp_path)
        assert proc.returncode == 2, (args, proc.stderr)
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("lde: error:"), (args, proc.stderr)
        assert what in lines[0], (args, proc.stderr)
        assert log.read_bytes() == before, args
        assert not (tmp_path / "o.x").exists() and not (tmp_path / "d").exists()
    # several LOGs into a directory that holds one of them under its output name
    csv_log = tmp_path / "a.csv"  # a python-can CSV log that would be <dir>/a.csv
    csv_log.write_text("x\n")
    proc = _run_cli(["replay", "a.csv", "b.log", "--csv", "."], tmp_path)
    assert proc.returncode == 2 and "input log" in proc.stderr, proc.stderr
    assert csv_log.read_text() == "x\n"


def test_recording_replays_under_the_profile_it_names(tmp_path: Path, capsys):
    """A recording of a hyundai replay, replayed without --profile, uses hyundai (from its ``lde``
    metadata record) and gives the identical CSV; an explicit --profile wins, and a replay without
    a single VALID step says so on stderr (even with -q)."""
    d = tmp_path
    assert (
        main(
            ["sim", "--scenario", "steady_wind", "--profile", "hyundai", "--duration", "3"]
            + ["--log", str(d / "h.log")]
        )
        == 0
    )
    args = ["--backend", "float", "-q"]
    assert (
        main(
            ["replay", str(d / "h.log"), "--profile", "hyundai", "--csv", str(d / "h1.csv")]
            + ["--mcap", str(d / "h1.mcap"), *args]
        )
        == 0
    )
    assert read_mcap(d / "h1.mcap").metadata["lde"]["profile"] == "hyundai"
    capsys.readouterr()
    assert main(["replay", str(d / "h1.mcap"), "--csv", str(d / "h2.csv"), *args]) == 0
    assert capsys.readouterr().err == ""
    assert (d / "h2.csv").read_bytes() == (d / "h1.csv").read_bytes()
    assert main(["replay", str(d / "h1.mcap"), "--profile", "lde", "--csv", str(d / "h3.csv"), *args]) == 3
    err = capsys.readouterr().err
    assert "no valid estimate: no frame of MDPS_Sensors (0x2A0), ESC_Motion (0x2A8)" in err, err
    assert "(profile lde, given)" in err and "fit profile hyundai (4 of its 4" in err
    status = np.loadtxt(d / "h3.csv", delimiter=",", skiprows=1, usecols=5)
    assert status.size > 0 and not np.any(status.astype(int) & 1)


def test_recorded_profile_of_a_profile_file(tmp_path: Path, profile, sample_replay):
    """A profile from a user's file is recorded with its path; a recording naming a file that is not
    there, or a DBC (which older versions took as a profile), is a ConfigError asking for --profile;
    logs without metadata name none."""
    from lde.errors import ConfigError
    from lde.replay.replay import profile_metadata, recorded_profile

    (tmp_path / "lde.dbc").write_bytes(Path(profile.dbc_path).read_bytes())
    mine_file = tmp_path / "mine.toml"
    mine_file.write_bytes(profile.path.read_bytes())
    mine = load_profile(mine_file)
    log, res = sample_replay
    rec = tmp_path / "r.mcap"
    write_recording(rec, log.frames, res, mine, metadata=profile_metadata(mine))
    assert recorded_profile(read_log(rec)) == str(mine_file.resolve())
    assert recorded_profile(read_log(SAMPLE)) is None
    mine_file.unlink()
    with pytest.raises(ConfigError, match="give --profile"):
        recorded_profile(read_log(rec))
    old = tmp_path / "old.mcap"
    write_recording(old, log.frames, res, profile, metadata={"profile": "mine", "profile_dbc": "/x/mine.dbc"})
    with pytest.raises(ConfigError, match=r"DBC /x/mine\.dbc: write a profile file for it.*give --profile"):
        recorded_profile(read_log(old))


def test_cli_replays_a_gzip_compressed_log(tmp_path: Path):
    """``x.log.gz`` replays like ``x.log``; with several LOGs its output is named ``x_log_gz``."""
    import gzip

    gz = tmp_path / "sample_linear.log.gz"
    gz.write_bytes(gzip.compress(SAMPLE.read_bytes(), mtime=0))
    args = ["--backend", "float", "-q"]
    assert main(["replay", str(gz), "--csv", str(tmp_path / "z.csv"), *args]) == 0
    assert main(["replay", str(SAMPLE), "--csv", str(tmp_path / "p.csv"), *args]) == 0
    assert (tmp_path / "z.csv").read_bytes() == (tmp_path / "p.csv").read_bytes()
    assert main(["replay", str(SAMPLE), str(gz), "--csv", str(tmp_path / "d"), *args]) == 0
    assert sorted(p.name for p in (tmp_path / "d").iterdir()) == [
        "sample_linear_log.csv",
        "sample_linear_log_gz.csv",
    ]


def test_summary_of_a_log_with_two_time_bases(tmp_path: Path, capsys, sample_replay):
    """Two joined recordings (relative, then epoch timestamps): the summary gives the stepped time
    (steps x 3.9 ms) and 2 segments, not the ~1.7e9 s between the first and last step."""
    from lde.can.frames import FrameBatch
    from lde.io import write_candump
    from lde.units import STEP_NS

    log, _ = sample_replay
    f = log.frames
    t0 = int(f.t_ns[0])
    split = t0 + 8 * 10**9
    early = f.select(f.t_ns < split)
    early.t_ns = early.t_ns - t0 + 10**9
    path = tmp_path / "mixed.log"
    write_candump(path, FrameBatch.concat([early, f.select(f.t_ns >= split)]))
    _, res = replay_log(path, None, load_vehicle(SAMPLE_VEHICLE), "float")
    assert res.segments == 2 and res.duration_s == pytest.approx(len(res) * STEP_NS * 1e-9)
    assert main(["replay", str(path), "--backend", "float", "--vehicle", str(SAMPLE_VEHICLE)]) == 0
    err = capsys.readouterr().err
    assert f"{len(res)} steps = {len(res) * STEP_NS * 1e-9:.3f} s stepped in 2 segments" in err, err
    assert res.duration_s < 60.0


@pytest.mark.parametrize("command", ["replay", "demo"])
def test_cli_start_up_imports_only_the_named_subcommand(command: str):
    """``lde replay`` / ``lde demo`` build their parser without importing the service, the
    calibrator, the study or numba (heavy imports live in the subcommands' ``run``)."""
    code = (
        "import sys; from lde.cli import build_parser; "
        f"p = build_parser(['-v', '{command}', '--help']); "
        "print(' '.join(m for m in sys.modules if m.split('.')[0] in ('lde', 'numba', 'dask', 'cantools')))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    loaded = set(proc.stdout.split())
    assert f"lde.cli.{command}" in loaded
    heavy = {
        "lde.service.service",
        "lde.analysis.adaptive",
        "lde.analysis.calibrate",
        "lde.analysis.study",
        "lde.cli.run",
        "numba",
        "dask",
        "cantools",
    }
    assert not loaded & heavy, loaded & heavy
    # and the full help still lists every subcommand
    proc = subprocess.run(
        [sys.executable, "-m", "lde", "--help"], capture_output=True, text=True, timeout=120
    )
    from lde.cli import SUBCOMMANDS

    assert proc.returncode == 0 and all(f"    {name} " in proc.stdout for name in SUBCOMMANDS), proc.stdout


def test_several_logs_go_on_past_a_bad_one_and_exit_non_zero(tmp_path, capsys) -> None:
    """A log that cannot be read is reported and skipped, the others are replayed; exit 2 at the end.
    All readable but one without a VALID step: exit 3 (issue 13 item 4)."""
    from vcan_sim.output import write_outputs
    from vcan_sim.run import simulate

    good, hy = tmp_path / "good.log", tmp_path / "hy.log"
    write_outputs(simulate("straight", seed=1, duration=3.0), log=good)
    write_outputs(simulate("straight", seed=1, duration=3.0, profile="hyundai"), log=hy)
    bad = tmp_path / "bad.log"
    bad.write_text("not a log\n")
    out = tmp_path / "out"
    assert main(["replay", str(bad), str(good), "--csv", str(out), "--backend", "float"]) == 2
    err = capsys.readouterr().err
    assert "bad.log: not a candump" in err and "1 failed" in err
    assert (out / "good.csv").stat().st_size > 1000  # the good log after the bad one was replayed
    assert main(["replay", str(good), str(hy), "--csv", str(out), "--backend", "float"]) == 3
    assert main(["replay", str(good), "--csv", str(out / "g.csv"), "--backend", "float", "-q"]) == 0
