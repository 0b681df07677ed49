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
from types import SimpleNamespace

import can
import numpy as np
import pytest

from lde.can.frames import seconds_to_ns
from lde.can.profiles import INPUT_NAMES
from lde.engine.engine import StepBlock
from lde.errors import LogFormatError
from lde.io import read_mcap
from lde.io.recording import DIAG_TOPIC, ESTIMATE_TOPIC, INPUTS_TOPIC, Recorder, Timing, read_recording
from lde.service.diagnostics import StepTiming
from lde.service.service import StepResult
from lde.units import STEP_NS

T0 = 1_700_000_000_000_000_000  # ns, an epoch-like time base


def _result(k: int, rng: np.random.Generator) -> StepResult:
    return StepResult(
        t_ns=T0 + k * STEP_NS,
        fw=float(rng.normal(0, 500)),
        mw=float(rng.normal(0, 300)),
        t_align=float(rng.normal(0, 10)),
        t_overlay=float(rng.uniform(-3, 3)),
        overlay_state=int(k % 5),
        overlay_active=bool(k % 2),
        status=int(rng.integers(0, 256)),
        frames_used=int(k % 3),
        timing=StepTiming(int(rng.integers(-100, 2_000_000)), 150_000, 300_000, False, k // 10),
    )


def _inputs(rng: np.random.Generator) -> SimpleNamespace:
    return SimpleNamespace(
        column_torque=float(rng.normal()),
        assist_torque=float(rng.normal()),
        steering_angle=0.01,
        steering_rate=0.0,
        yaw_rate=0.001,
        lat_accel=0.1,
        speed=27.0,
        mdps_ok=True,
        esc_ok=False,
    )


def _row(res: StepResult, inputs: SimpleNamespace, e2e_rejects: int) -> tuple[StepBlock, Timing]:
    """One step as the service hands it to the recorder (a StepBlock row and its timing)."""
    b = StepBlock.empty(1)
    b.t_ns[0] = res.t_ns
    b.status[0] = res.status
    b.est[0] = [res.fw, res.mw, res.t_align, 0.001, 0.002, res.fw - 100.0, res.mw, 0.01, 1, 0.002]
    b.t_overlay[0] = res.t_overlay
    b.overlay_state[0] = res.overlay_state
    b.overlay_enable[0] = True
    b.inputs[0] = [getattr(inputs, n) for n in INPUT_NAMES]
    b.ages[0] = 0
    b.valid_mask[0] = 0
    b.ok[0] = (inputs.mdps_ok, inputs.esc_ok)
    b.frames_used[0] = res.frames_used
    b.e2e_rejects[0] = e2e_rejects
    tm = res.timing
    assert tm is not None
    values = (
        tm.period_error_ns,
        tm.step_time_ns,
        tm.latency_ns,
        int(tm.deadline_miss),
        tm.deadline_misses,
        0,
    )
    timing = Timing(*(np.array([v]) for v in values))
    return b, timing


def _record(rec: Recorder, n: int, seed: int = 1) -> list[StepResult]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        t = T0 + k * STEP_NS
        rx = can.Message(timestamp=(t - 500_000) / 1e9, arbitration_id=0x2A0, data=bytes([k % 256] * 8))
        tx = can.Message(timestamp=(t + 200_000) / 1e9, arbitration_id=0x3D1, data=bytes(range(8)))
        rec.rx(rx)
        res = _result(k, rng)
        rec.steps(*_row(res, _inputs(rng), e2e_rejects=k // 100))
        rec.tx(tx)
        out.append(res)
    return out


def test_round_trip_all_channels(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with Recorder(path, metadata={"profile": "lde", "backend": "float"}) as rec:
        results = _record(rec, 300)
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
        _record(rec, 50)
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
        _record(rec, 200)
        rec._drain()  # what the writer thread does every flush interval
        _record(rec, 50, seed=2)  # queued, not yet written: lost in a crash
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
    from test_recording import _result, _inputs, _row
    from lde.io.recording import Recorder
    from lde.units import STEP_NS
    import dataclasses
    rec = Recorder({path!r})
    rng = np.random.default_rng(0)
    k = 0
    print("ready", flush=True)
    while True:
        res = dataclasses.replace(_result(k, rng), t_ns=time.time_ns())
        rec.steps(*_row(res, _inputs(rng), 0))
        k += 1
        time.sleep(STEP_NS / 1e9)
    """
)


def _killed_recording(tmp_path: Path, name: str, group: bool):
    """A process recording steps, SIGKILLed after 2 s (``group``: with its writer process)."""
    path = tmp_path / name
    code = _CHILD.format(tests=str(Path(__file__).parent), path=str(path))
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
