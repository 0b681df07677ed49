"""Recording: round trip, flat JSON channels, recovery of an unfinished file, SIGKILL loses < ~1 s."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from lde.can.frames import seconds_to_ns
from lde.errors import LogFormatError
from lde.io import read_mcap
from lde.io.recording import DIAG_TOPIC, ESTIMATE_TOPIC, INPUTS_TOPIC, Recorder, read_recording
from lde.units import STEP_NS

from helpers import TESTS
from helpers.recorded_steps import T0, record_steps


def test_round_trip_all_channels(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with Recorder(path, metadata={"profile": "lde", "backend": "float"}) as rec:
        results = record_steps(rec, 300)
    r = read_recording(path)
    assert r.complete
    assert r.metadata["profile"] == "lde"
    assert len(r.rx) == 300 and len(r.tx) == 300
    assert r.rx.is_rx.all() and not r.tx.is_rx.any()
    assert r.rx.t_ns[5] == seconds_to_ns((T0 + 5 * STEP_NS - 500_000) / 1e9)
    assert r.rx.data[7].tolist() == [7] * 8
    np.testing.assert_array_equal(r.step_times_ns, [x.t_ns for x in results])
    # floats survive JSON exactly (repr round trip): replay compares bit for bit
    np.testing.assert_array_equal(r.estimate["Fw"], [x.fw for x in results])
    np.testing.assert_array_equal(r.estimate["T_overlay"], [x.t_overlay for x in results])
    np.testing.assert_array_equal(r.estimate["status"], [x.status for x in results])
    np.testing.assert_array_equal(r.estimate["deadline_miss"], [(x.status >> 7) & 1 for x in results])
    assert r.inputs["speed"][0] == 27.0 and r.inputs["esc_ok"][0] == 0
    assert r.diag["step_time_us"][0] == 150.0


def test_file_is_readable_by_logio_and_flat_json(tmp_path: Path) -> None:
    """The same file through lde.io's reader: CAN frames and flat numeric JSON columns."""
    path = tmp_path / "run.mcap"
    with Recorder(path) as rec:
        record_steps(rec, 50)
    d = read_mcap(path, json_topics=[ESTIMATE_TOPIC, DIAG_TOPIC, INPUTS_TOPIC])
    assert len(d.frames) == 100
    for topic in (ESTIMATE_TOPIC, DIAG_TOPIC, INPUTS_TOPIC):
        cols = d.json[topic]
        assert len(cols["t_ns"]) == 50
        for name, col in cols.items():
            assert col.dtype.kind in "fi", (topic, name)


def test_recovers_file_without_footer(tmp_path: Path) -> None:
    """A copy taken while the recorder is open (as after a SIGKILL) has no footer and still reads."""
    path = tmp_path / "open.mcap"
    rec = Recorder(path, flush_interval_s=3600.0)  # the thread never flushes on its own here
    try:
        record_steps(rec, 200)
        rec._drain()  # what the writer thread does every flush interval
        record_steps(rec, 50, seed=2)  # queued, not yet written: lost in a crash
        copy = tmp_path / "crashed.mcap"
        shutil.copyfile(path, copy)
    finally:
        rec.close()
    r = read_recording(copy)
    assert not r.complete
    assert len(r.step_times_ns) == 200
    assert len(r.rx) == 200
    # and a file cut in the middle of a chunk: everything before that chunk survives
    raw = copy.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(raw[: len(raw) - 100])
    r2 = read_recording(cut)
    assert 0 < len(r2.step_times_ns) <= 200
    np.testing.assert_array_equal(r2.step_times_ns, r.step_times_ns[: len(r2.step_times_ns)])


def test_not_mcap_is_a_clear_error(tmp_path: Path) -> None:
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world, not mcap")
    with pytest.raises(LogFormatError):
        read_recording(p)


_CHILD = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    sys.path.insert(0, {tests!r})
    from helpers.recorded_steps import step_result, step_inputs, step_row
    from lde.io.recording import Recorder
    from lde.units import STEP_NS
    import dataclasses
    rec = Recorder({path!r})
    rng = np.random.default_rng(0)
    k = 0
    print("ready", flush=True)
    while True:
        res = dataclasses.replace(step_result(k, rng), t_ns=time.time_ns())
        rec.steps(*step_row(res, step_inputs(rng), 0))
        k += 1
        time.sleep(STEP_NS / 1e9)
    """
)


def _killed_recording(tmp_path: Path, name: str, group: bool):
    """A process recording steps, SIGKILLed after 2 s (``group``: with its writer process)."""
    path = tmp_path / name
    code = _CHILD.format(tests=str(TESTS), path=str(path))
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    proc = subprocess.Popen(
        [sys.executable, "-c", code], stdout=subprocess.PIPE, env=env, start_new_session=True
    )
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == b"ready"
        time.sleep(2.0)
        t_kill = time.time_ns()
        if group:
            os.killpg(proc.pid, signal.SIGKILL)
        else:
            proc.send_signal(signal.SIGKILL)
        proc.wait(10)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    return path, t_kill


def test_sigkill_of_the_service_loses_nothing_the_writer_closes_the_file(tmp_path: Path) -> None:
    path, t_kill = _killed_recording(tmp_path, "killed.mcap", group=False)
    deadline = time.monotonic() + 20.0
    while not (r := read_recording(path)).complete and time.monotonic() < deadline:
        time.sleep(0.1)  # the writer process outlives the service: it reads the pipes and closes
    # the writer process outlived the service: it wrote what the pipes held and closed the file
    assert r.complete
    lost_s = (t_kill - int(r.step_times_ns[-1])) / 1e9
    assert lost_s < 3 * STEP_NS / 1e9 + 0.05, f"the last {lost_s:.3f} s were lost"


def test_sigkill_of_service_and_writer_loses_at_most_about_half_a_second(tmp_path: Path) -> None:
    path, t_kill = _killed_recording(tmp_path, "killed_both.mcap", group=True)
    r = read_recording(path)
    assert not r.complete
    assert len(r.step_times_ns) > 0
    lost_s = (t_kill - int(r.step_times_ns[-1])) / 1e9
    assert lost_s < 1.0, f"the last {lost_s:.2f} s were lost"
