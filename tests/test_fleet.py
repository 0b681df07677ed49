"""Fleets of logs: ``lde replay LOG... --jobs N`` on a local Dask cluster and ``--scheduler ADDR`` on a
``dask scheduler`` + ``dask worker`` started as separate processes (the stand-in for other machines):
the same CSV files as one replay after another, a summary table, a failed log reported while the
others go on."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from lde.cli import main
from lde.io import McapWriter, read_log, write_candump

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "data" / "sample_linear.log"


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> list[Path]:
    """Three logs: the sample as candump and MCAP, and its second half as candump."""
    d = tmp_path_factory.mktemp("fleet")
    frames = read_log(SAMPLE).frames
    a = d / "a.log"
    write_candump(a, frames)
    b = d / "b.mcap"
    with McapWriter(b) as w:
        w.write_frames(frames)
    c = d / "c.log"
    write_candump(c, frames[len(frames) // 2 :])
    return [a, b, c]


@pytest.fixture(scope="module")
def sequential(logs, tmp_path_factory) -> dict[str, bytes]:
    out = tmp_path_factory.mktemp("seq")
    assert main(["replay", *map(str, logs), "--backend", "float", "--csv", str(out), "-q"]) == 0
    return {p.name: p.read_bytes() for p in out.iterdir()}


def _csvs(d: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in d.iterdir()}


@pytest.mark.slow
def test_jobs_on_a_local_cluster_give_the_sequential_files(logs, sequential, tmp_path, capsys):
    out = tmp_path / "csv"
    rc = main(["replay", *map(str, logs), "--backend", "float", "--csv", str(out), "--jobs", "2"])
    err = capsys.readouterr().err
    assert rc == 0, err
    assert _csvs(out) == sequential and len(sequential) == 3
    # the summary table: one line per log and the total
    table = err[err.index("log ") :]
    for p in logs:
        assert p.name in table
    assert "3 logs" in table and "0 failed" in table


def test_a_bad_log_is_reported_and_the_others_are_replayed(logs, sequential, tmp_path, capsys):
    bad = tmp_path / "bad.log"
    bad.write_text("not a log\n")
    out = tmp_path / "csv"
    rc = main(["replay", str(logs[0]), str(bad), "--backend", "float", "--csv", str(out)])
    err = capsys.readouterr().err
    assert rc == 2
    assert (out / "a.csv").read_bytes() == sequential["a.csv"]
    assert not (out / "bad.csv").exists()  # nothing half-written
    assert "1 failed" in err and f"lde: error: {bad.resolve()}" in err and "Traceback" not in err


def _start(cmd: list[str], env: dict[str, str], log: Path) -> subprocess.Popen:
    return subprocess.Popen(cmd, env=env, stdout=log.open("w"), stderr=subprocess.STDOUT)


@pytest.mark.slow
def test_the_same_path_on_a_remote_scheduler(logs, sequential, tmp_path, capsys):
    """``dask scheduler`` and ``dask worker`` as separate processes on localhost."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT), env.get("PYTHONPATH", "")])
    sfile = tmp_path / "scheduler.json"
    dask = [sys.executable, "-m", "distributed.cli.dask_scheduler"]
    procs = [
        _start(
            [*dask, "--scheduler-file", str(sfile), "--port", "0", "--no-dashboard", "--host", "127.0.0.1"],
            env,
            tmp_path / "scheduler.txt",
        )
    ]
    try:
        deadline = time.monotonic() + 60
        while not sfile.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert sfile.exists(), (tmp_path / "scheduler.txt").read_text()
        addr = json.loads(sfile.read_text())["address"]
        worker = [sys.executable, "-m", "distributed.cli.dask_worker", addr, "--nthreads", "1"]
        procs.append(_start([*worker, "--no-dashboard"], env, tmp_path / "worker.txt"))
        out = tmp_path / "csv"
        rc = main(["replay", *map(str, logs), "--backend", "float", "--csv", str(out), "--scheduler", addr])
        err = capsys.readouterr().err
        assert rc == 0, err
        assert _csvs(out) == sequential
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_an_unreachable_scheduler_is_one_line(logs, tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "lde", "replay", str(logs[0]), "--scheduler", "tcp://127.0.0.1:9"],
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)])),
    )
    assert proc.returncode == 2, proc.stderr
    assert [ln for ln in proc.stderr.splitlines() if ln.startswith("lde: error:")], proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("opt", [["--jobs", "2"], ["--scheduler", "tcp://127.0.0.1:9"]])
def test_learned_with_jobs_or_scheduler_is_one_line(logs, tmp_path, opt):
    """--learned passes one file from log to log in order: parallel jobs cannot share it."""
    learned = tmp_path / "car.learned"
    out = tmp_path / "csv"
    proc = subprocess.run(
        [sys.executable, "-m", "lde", "replay", *map(str, logs), "--backend", "float"]
        + ["--learned", str(learned), "--csv", str(out), *opt],
        capture_output=True,
        text=True,
        timeout=120,
        env=dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT / "src"), str(ROOT)])),
    )
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("lde: error: --learned"), proc.stderr
    assert opt[0] in lines[0]
    assert not learned.exists() and not out.exists()  # nothing read, nothing written


def test_a_replay_without_its_helper_threads_writes_the_same_csv(logs, tmp_path):
    """A Dask worker replays with ``helper_threads=False`` (the log read and the CSV written in the
    replay's own thread): the same bytes as with the read-ahead and CSV threads."""
    from lde.replay.fleet import ReplayJob, replay_job

    out = {}
    for threads in (True, False):
        csv = tmp_path / f"{threads}.csv"
        rep = replay_job(ReplayJob(logs[1], csv=csv, backend="float", helper_threads=threads))
        assert not rep.error, rep.error
        out[threads] = csv.read_bytes()
    assert out[True] == out[False] and len(out[True]) > 1000


@pytest.mark.slow
def test_a_local_clusters_workers_keep_glibcs_trim_threshold():
    """The local cluster's workers run without dask's MALLOC_TRIM_THRESHOLD_=65536 (a replay frees
    MB-sized pieces all along; the trimming tripled its system time) and keep dask's other
    settings (one OpenMP thread)."""
    from distributed import Client

    from lde.replay.fleet_dask import _local_cluster

    cluster = _local_cluster(1)
    try:
        with Client(cluster) as client:
            env = client.run(
                lambda: (os.environ.get("MALLOC_TRIM_THRESHOLD_"), os.environ.get("OMP_NUM_THREADS"))
            )
    finally:
        cluster.close()
    ((trim, omp),) = env.values()
    assert trim is None
    assert omp == "1"
