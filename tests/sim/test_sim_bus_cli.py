"""The bus pump, the closed loop on LDE_Overlay, and ``lde sim``."""

from __future__ import annotations

import threading
import time

import can
import numpy as np
import pytest

from lde.can.codec import MessageEncoder
from lde.can.e2e import E2EStatus
from lde.can.profiles import load_profile
from lde.cli import main
from lde.io import read_log, read_mcap
from lde.units import STEP_NS
from vcan_sim.closed_loop import OverlayReceiver
from vcan_sim.emitter import pump
from vcan_sim.run import Simulation, scenario_with, simulate
from vcan_sim.scenarios import SCENARIOS, Step


def _overlay_msg(enc: MessageEncoder, torque: float, t_ns: int, active: int = 1) -> can.Message:
    return enc.message({"OverlayTorque": torque, "Active": active, "State": 2}, t_ns)


def test_overlay_receiver_e2e_and_ramp_out():
    prof = load_profile("lde")
    rx = OverlayReceiver(prof, ramp_rate=5.0)
    enc = MessageEncoder(prof, "LDE_Overlay")
    t = 1_000_000_000
    for i in range(5):
        rx.on_message(_overlay_msg(enc, 1.5, t + i * STEP_NS), t + i * STEP_NS)
    t_now = t + 5 * STEP_NS
    assert rx.request(t_now) == pytest.approx(1.5, abs=0.01)
    # a corrupted CRC is rejected and counted, the value is not taken
    bad = bytearray(enc.encode({"OverlayTorque": -3.0, "Active": 1}))
    bad[0] ^= 0xFF
    st = rx.on_message(
        can.Message(arbitration_id=prof.spec("LDE_Overlay").frame_id, data=bad, is_extended_id=False), t_now
    )
    assert st == E2EStatus.WRONGCRC and rx.stats.rejected == 1
    # Active = 0 requests zero
    rx2 = OverlayReceiver(prof)
    enc2 = MessageEncoder(prof, "LDE_Overlay")
    for i in range(4):
        rx2.on_message(_overlay_msg(enc2, 2.0, t + i * STEP_NS, active=0), t + i * STEP_NS)
    assert rx2.request(t + 4 * STEP_NS) == 0.0
    # no frames: ramps to zero at 5 Nm/s, never steps
    t_late = t_now + 200_000_000
    r1 = rx.request(t_late)
    assert 0.0 < r1 < 1.5
    r2 = rx.request(t_late + 100_000_000)
    assert r2 == pytest.approx(max(0.0, r1 - 0.5), abs=1e-9)
    assert rx.request(t_late + 1_000_000_000) == 0.0
    # other ids are ignored
    assert rx.on_message(can.Message(arbitration_id=0x123, data=b"\0" * 8, is_extended_id=False), t) is None


def test_closed_loop_overlay_relieves_the_driver():
    """Applying the torque that holds the car straight takes the holding torque off the driver."""
    sc = scenario_with("steady_wind", wind_speed=(Step(3.0, 2.0, 6.0),))
    base = simulate(sc, seed=0, duration=20.0).truth
    last = slice(-1000, None)
    hold = base["T_column"][last].mean() + base["T_assist"][last].mean()  # column-level holding torque
    assert -5.0 < hold < -1.0  # within the MDPS overlay limit
    sim = Simulation(sc, seed=0, duration=20.0)
    while not sim.done:
        t = (sim.t_ns - sim.t0_ns) * 1e-9
        sim.step(hold * min(1.0, max(0.0, (t - 3.0) / 2.0)))
    tr = sim.result().truth
    assert tr["T_overlay"][last].mean() == pytest.approx(hold, rel=0.02)
    assert abs(tr["T_driver"][last].mean()) < 0.3 * abs(base["T_driver"][last].mean())
    assert abs(tr["T_column"][last].mean()) < 0.3 * abs(base["T_column"][last].mean())


def test_pump_on_virtual_bus_fast_and_closed_loop():
    chan = "vcan_sim_test_pump"
    prof = load_profile("lde")
    with (
        can.Bus(interface="virtual", channel=chan) as sim_bus,
        can.Bus(interface="virtual", channel=chan) as lde,
    ):
        sim = Simulation("straight", seed=1, duration=0.5)
        received: list[can.Message] = []
        stop = threading.Event()
        enc = MessageEncoder(prof, "LDE_Overlay")

        def service() -> None:  # a stand-in for lde: answers every MDPS frame with 1 Nm overlay
            while not stop.is_set():
                m = lde.recv(timeout=0.05)
                if m is None:
                    continue
                received.append(m)
                if m.arbitration_id == prof.spec("MDPS_Sensors").frame_id:
                    lde.send(_overlay_msg(enc, 1.0, int(m.timestamp * 1e9)))

        th = threading.Thread(target=service, daemon=True)
        th.start()
        rx = OverlayReceiver(prof)
        st = pump(sim, sim_bus, realtime=True, closed_loop=True, receiver=rx, keep_frames=True)
        deadline = time.monotonic() + 10.0  # let the stand-in drain its queue (slow, shared CI machines)
        while len(received) < st.sent and time.monotonic() < deadline:
            time.sleep(0.01)
        stop.set()
        th.join(2.0)
    fast = simulate("straight", seed=1, duration=0.5)
    assert st.sent == len(fast.frames) == len(received)
    assert st.send_errors == 0
    got = sorted(bytes(m.data) for m in received if m.arbitration_id == 0x2A8)
    assert rx.stats.used > 50  # the loop was closed
    assert sim.result().truth["T_overlay"][-1] == pytest.approx(1.0, abs=0.1)
    assert got  # ESC frames arrived too


def test_cli_list(capsys):
    assert main(["sim", "--list"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == len(SCENARIOS)
    for line, name in zip(out, SCENARIOS, strict=True):
        assert line.split()[0] == name and len(line.split()) > 3


def test_cli_files_read_back(tmp_path):
    log, csv, mcap = tmp_path / "o.log", tmp_path / "o.csv", tmp_path / "o.mcap"
    rc = main(
        [
            "sim",
            "--scenario",
            "wind_step",
            "--duration",
            "3",
            "--seed",
            "5",
            "--log",
            str(log),
            "--truth",
            str(csv),
            "--mcap",
            str(mcap),
        ]
    )
    assert rc == 0
    ref = simulate("wind_step", seed=5, duration=3.0)
    data = read_log(log)
    assert np.array_equal(data.frames.t_ns, ref.frames.t_ns) and np.array_equal(
        data.frames.data, ref.frames.data
    )
    truth = np.genfromtxt(csv, delimiter=",", names=True)
    assert {"t", "Fw", "Mw", "Mw_ref", "T_overlay"} <= set(truth.dtype.names)
    # t is in the log's own time base: the first truth row is the first MDPS frame
    assert truth["t"][0] == pytest.approx(data.frames.t_ns[0] * 1e-9, abs=1e-6)
    np.testing.assert_allclose(truth["Fw"], ref.truth["Fw"])
    rec = read_mcap(mcap, json_topics="/truth")
    assert np.array_equal(rec.frames.data, ref.frames.data)
    jt = rec.json["/truth"]
    assert np.array_equal(jt["log_time"], ref.truth_t_ns)
    np.testing.assert_allclose(jt["Mw"], ref.truth["Mw"])


def test_cli_errors(capsys):
    assert main(["sim", "--scenario", "no_such", "--log", "x.log"]) == 2
    assert "unknown scenario" in capsys.readouterr().err
    assert main(["sim", "--scenario", "straight", "--duration", "-1", "--log", "x.log"]) == 2


@pytest.mark.parametrize("fmt", ["log", "mcap"])
def test_replay_reads_sim_logs(tmp_path, fmt):
    pytest.importorskip("lde.replay.replay")
    log, out = tmp_path / f"s.{fmt}", tmp_path / "r.csv"
    assert main(["sim", "--scenario", "light_load", "--duration", "4", f"--{fmt}", str(log)]) == 0
    assert main(["replay", str(log), "--csv", str(out), "--backend", "float", "-q"]) == 0
    rows = np.genfromtxt(out, delimiter=",", names=True)
    assert rows.size > 900 and np.all(np.isfinite(rows["Fw"]))
    assert rows["t"][0] == pytest.approx(1_700_000_000.0, abs=0.1)  # the log's own time base


@pytest.mark.parametrize("sig", ["SIGTERM", "SIGINT"])
def test_live_sim_stopped_by_a_signal_writes_its_files(tmp_path, sig):
    """``lde sim`` on a live bus (real-time pacing) ended by SIGTERM or SIGINT still writes its
    --log, --truth and --mcap: complete, readable, and holding what was simulated up to the signal."""
    import os
    import signal
    import subprocess
    import sys

    log, csv, mcap = tmp_path / "s.log", tmp_path / "s.csv", tmp_path / "s.mcap"
    cmd = [sys.executable, "-m", "lde", "sim", "--interface", "virtual", "--channel", f"simsig-{sig}"]
    cmd += [
        "--scenario",
        "straight",
        "--open-loop",
        "--log",
        str(log),
        "--truth",
        str(csv),
        "--mcap",
        str(mcap),
    ]
    proc = subprocess.Popen(
        cmd, stderr=subprocess.PIPE, text=True, env=dict(os.environ, PYTHONUNBUFFERED="1")
    )
    try:
        assert proc.stderr is not None
        first = proc.stderr.readline()  # printed once the bus is open and simulating starts
        assert "SIGINT/SIGTERM stop it" in first, first + proc.stderr.read()
        time.sleep(2.0)
        assert proc.poll() is None, proc.stderr.read()
        proc.send_signal(getattr(signal, sig))
        rc = proc.wait(60)
        err = proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 0, err
    assert f"stopped by {sig}" in err
    data = read_log(log)
    n = len(data.frames)
    assert n > 0
    span = (data.frames.t_ns[-1] - data.frames.t_ns[0]) * 1e-9
    assert span < SCENARIOS["straight"].duration  # stopped early: not the whole scenario
    rec = read_mcap(mcap, json_topics="/truth")
    assert np.array_equal(rec.frames.data, data.frames.data)  # the same frames in both files
    # one row when the signal came while the kernels still compiled (a cold cache): a 0-d array
    truth = np.atleast_1d(np.genfromtxt(csv, delimiter=",", names=True))
    assert len(truth) > 0 and truth["t"][-1] <= data.frames.t_ns[-1] * 1e-9 + 0.01
