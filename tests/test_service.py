"""The live service on python-can's virtual bus, stepped by a simulated clock (no timing assertions).

A feeder (:class:`lde.testing.InputFeeder`) sends MDPS_Sensors every 3.9 ms and ESC_Motion every
10 ms (profile ``lde``, counters and CRCs by lde.can.codec) with explicit timestamps; the service, on an
lde test bench (the ``lde_bench`` fixture: a fresh virtual channel, the simulated clock), steps in
lockstep, driven by hand.
"""

from __future__ import annotations

import itertools
import json
import math

import can
import numpy as np
import pytest

from lde.can.codec import MessageCodec, si_to_dbc
from lde.can.e2e import p01_check
from lde.can.profiles import Profile, load_profile
from lde.clock import SimulatedClock
from lde.params import load_vehicle
from lde.service.diagnostics import DEADLINE_MISS_NS
from lde.service.service import STATUS_DEADLINE_MISS, Service
from lde.testing import Bench, InputFeeder
from lde.testing.bench import DEFAULT_START_NS
from lde.units import DEG, KMH, STEP_NS

T0 = DEFAULT_START_NS  # ns, the bench's start: 1_700_000_000 s
_channels = itertools.count()  # plain virtual buses of the tests that build their own service


def feeder(
    bus: can.BusABC,
    profile: Profile,
    first_ns: int = T0,
    mdps_offset_ns: int = 300_000,
    esc_offset_ns: int = 2_000_000,
) -> InputFeeder:
    """MDPS_Sensors every 3.9 ms from ``mdps_offset_ns`` before ``first_ns``, ESC_Motion every 10 ms
    from ``esc_offset_ns`` before it: 100 km/h, the driver holding 0.8 Nm against a disturbance
    from the right."""
    return InputFeeder(
        bus,
        profile,
        {"MDPS_Sensors": first_ns - mdps_offset_ns, "ESC_Motion": first_ns - esc_offset_ns},
        speed=100 * KMH,
        column_torque=0.8,
        assist_torque=1.2,
        steering_angle=0.5 * DEG,
    )


@pytest.fixture()
def rig(lde_bench: Bench):
    feed_bus = lde_bench.bus("feeder", preserve_timestamps=True)
    svc = lde_bench.service(backend="float").service  # stepped by hand here, not by the bench
    return svc, feeder(feed_bus, svc.profile), feed_bus, lde_bench.clock


def _outputs(bus: can.BusABC) -> list[can.Message]:
    out = []
    while (m := bus.recv(0.0)) is not None:
        out.append(m)
    return out


def _lockstep(svc: Service, feeder: InputFeeder, clock, n: int, k0: int = 0) -> list:
    res = []
    for k in range(k0, k0 + n):
        t_k = T0 + k * STEP_NS
        feeder.send_until(t_k)
        clock.sleep_until(t_k)
        res.append(svc.step_once(t_k))
    return res


def test_every_step_sends_estimate_overlay_diag_with_valid_e2e(rig) -> None:
    svc, feeder, feed_bus, clock = rig
    _lockstep(svc, feeder, clock, 60)
    msgs = _outputs(feed_bus)
    profile = svc.profile
    for name in ("LDE_Estimate", "LDE_Overlay", "LDE_Disturbance", "LDE_Diag"):
        fid = profile.output_id(name)
        frames = [m for m in msgs if m.arbitration_id == fid]
        assert len(frames) == 60, name
        assert all(p01_check(fid, bytes(m.data)) for m in frames), name
        counters = [m.data[1] & 0x0F for m in frames]
        assert all((b - a) % 15 == 1 for a, b in itertools.pairwise(counters)), name
        assert 15 not in counters


def test_estimate_becomes_valid_and_matches_frames(rig) -> None:
    svc, feeder, feed_bus, clock = rig
    res = _lockstep(svc, feeder, clock, 600)  # 2.3 s: past the convergence time
    last = res[-1]
    assert last.status & 1, f"status {last.status:#x} not VALID"
    assert math.isfinite(last.fw) and math.isfinite(last.mw)
    est = [m for m in _outputs(feed_bus) if m.arbitration_id == svc.profile.output_id("LDE_Estimate")]
    dec = MessageCodec(svc.profile, "LDE_Estimate").decode(bytes(est[-1].data))
    assert dec["LatForce"] == pytest.approx(last.fw, abs=0.5)
    assert dec["YawMoment"] == pytest.approx(last.mw, abs=0.5)
    assert int(dec["Status"]) == last.status


def test_frames_after_step_time_wait_for_the_next_step(rig) -> None:
    """Step k uses exactly the frames received at or before t_k; later ones wait for step k+1."""
    svc, feeder, feed_bus, clock = rig
    _lockstep(svc, feeder, clock, 10)
    t_k = T0 + 10 * STEP_NS
    enc = feeder.encoders["MDPS_Sensors"]
    vals = si_to_dbc(svc.profile, "MDPS_Sensors", {"column_torque": 0.5})
    on_time = enc.message(vals, t_k)  # exactly at t_k: used
    late = enc.message(vals, t_k + 1_000)  # 1 us after t_k: must wait
    feed_bus.send(on_time)
    feed_bus.send(late)
    r1 = svc.step_once(t_k)
    assert r1.frames_used == 1
    assert svc.pending_times() == [t_k + 1_000]
    r2 = svc.step_once(t_k + STEP_NS)
    assert r2.frames_used == 1
    assert svc.pending_times() == []


def test_late_step_sets_deadline_miss(rig) -> None:
    svc, feeder, feed_bus, clock = rig
    _lockstep(svc, feeder, clock, 5)
    t_k = T0 + 5 * STEP_NS
    feeder.send_until(t_k)
    r = svc.step_once(t_k, t_start=t_k + DEADLINE_MISS_NS + 1)
    assert r.status & STATUS_DEADLINE_MISS
    assert r.timing is not None and r.timing.deadline_misses == 1
    ok = svc.step_once(t_k + STEP_NS, t_start=t_k + STEP_NS + DEADLINE_MISS_NS)  # exactly 1 ms: not a miss
    assert not ok.status & STATUS_DEADLINE_MISS
    diag = [m for m in _outputs(feed_bus) if m.arbitration_id == svc.profile.output_id("LDE_Diag")]
    d = MessageCodec(svc.profile, "LDE_Diag").decode(bytes(diag[-2].data))
    assert d["DeadlineMisses"] == 1
    assert d["PeriodError"] == pytest.approx((DEADLINE_MISS_NS + 1) / 1e3, abs=1)


def test_run_on_simulated_clock_keeps_the_grid(rig) -> None:
    svc, feeder, _, clock = rig
    seen: list[int] = []

    def on_step(res) -> None:
        seen.append(res.t_ns)
        feeder.send_until(res.t_ns + STEP_NS)  # frames for the next step

    summary = svc.run(max_steps=50, on_step=on_step)
    assert len(seen) == 50
    np.testing.assert_array_equal(np.diff(seen), STEP_NS)
    assert summary.steps == 50 and summary.deadline_misses == 0


def test_stop_ramps_the_overlay_out(rig) -> None:
    svc, feeder, _, clock = rig
    res = _lockstep(svc, feeder, clock, 1500)  # ~5.9 s: converged, overlay ramped in
    assert abs(res[-1].t_overlay) > 0.05, "the feeder's steady disturbance should ask for overlay"
    svc.request_stop()
    seen = []

    def on_step(r) -> None:
        seen.append(r.t_overlay)
        feeder.send_until(r.t_ns + STEP_NS)

    svc.run(on_step=on_step)
    assert seen[-1] == 0.0
    rate = np.abs(np.diff([res[-1].t_overlay, *seen])) / (STEP_NS * 1e-9)
    assert rate.max() <= svc.vehicle.overlay.max_rate * 1.01 + 0.01 / (STEP_NS * 1e-9)  # one LSB of slack
    assert len(seen) < 2 * abs(res[-1].t_overlay) / svc.vehicle.overlay.max_rate / (STEP_NS * 1e-9) + 10


def test_send_errors_are_counted_not_raised(rig) -> None:
    svc, feeder, _, clock = rig

    def broken_send(msg, timeout=None):
        raise can.CanOperationError("tx queue full")

    svc.bus.send = broken_send  # type: ignore[method-assign]
    _lockstep(svc, feeder, clock, 3)
    assert svc.send_errors == 12  # 3 steps x (LDE_Estimate, LDE_Overlay, LDE_Disturbance, LDE_Diag)


@pytest.mark.lde_bench(capture=False)
def test_cli_run_on_a_virtual_bus_records_and_stops(tmp_path, lde_bench: Bench) -> None:
    """``lde run`` in-process on a virtual bus fed from a thread; --duration ends it cleanly."""
    import threading
    import time

    from lde.cli import main
    from lde.io.recording import read_recording

    ch = lde_bench.channel  # a fresh channel; the bench checks that every bus on it was closed
    feed_bus = can.Bus(interface="virtual", channel=ch)  # stamps with time.time(), like a kernel
    profile = load_profile("lde")
    stop = threading.Event()

    def feed() -> None:
        fd = feeder(feed_bus, profile, first_ns=time.time_ns(), mdps_offset_ns=0, esc_offset_ns=0)
        while not stop.is_set():
            fd.send_until(time.time_ns())
            time.sleep(0.001)

    th = threading.Thread(target=feed, daemon=True)
    th.start()
    path = tmp_path / "run.mcap"
    try:
        rc = main(
            [
                "run",
                "--interface",
                "virtual",
                "--channel",
                ch,
                "--duration",
                "0.5",
                "--backend",
                "float",
                "--grid",
                "fixed",
                "--record",
                str(path),
            ]
        )
    finally:
        stop.set()
        th.join(2)
        feed_bus.shutdown()
    assert rc == 0
    rec = read_recording(path)
    assert rec.complete
    n = len(rec.step_times_ns)
    steps = rec.step_times_ns
    assert steps[-1] - steps[0] >= 0.5e9 - STEP_NS  # --duration (plus the ramp-out)
    # the fixed grid: every step on the 3.9 ms grid (the MDPS-locked grid, lde run's default, is checked
    # deterministically on a simulated clock in test_run_on_the_mdps_grid_...; the other lde run tests use it)
    np.testing.assert_array_equal(np.diff(steps) % STEP_NS, 0)
    assert len(rec.rx) > 100 and len(rec.tx) == 4 * n  # LDE_Estimate, _Overlay, _Disturbance, _Diag
    assert rec.metadata["backend"] == "float"


def test_sigterm_ends_lde_run_cleanly(tmp_path) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    from lde.errors import LogFormatError
    from lde.io.recording import read_recording

    path, learned = tmp_path / "term.mcap", tmp_path / "car.learned"
    cmd = [
        sys.executable,
        "-m",
        "lde",
        "run",
        "--interface",
        "virtual",
        "--channel",
        "term",
        "--backend",
        "float",
        "--record",
        str(path),
        "--learned",
        str(learned),
    ]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:  # until the service writes its first steps
            time.sleep(0.2)
            try:
                if len(read_recording(path).step_times_ns) > 10:
                    break
            except (FileNotFoundError, LogFormatError):  # the recorder's writer is still starting
                continue
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(30)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = proc.stderr.read().decode() if proc.stderr else ""
    assert rc == 3, err  # a silent bus: nothing usable, as lde replay
    assert "no input ever arrived on virtual:term with profile lde" in err
    rec = read_recording(path)
    assert rec.complete  # summary and footer written: the recorder was closed
    assert len(rec.step_times_ns) > 10
    # the learned state's last write (no input: nothing learned, no driving time, one drive)
    doc = json.loads(learned.read_text())
    assert doc["format"] == "lde-learned" and doc["drives"] == 1 and doc["seconds"] == 0.0


def test_bus_timestamps_in_another_time_base_are_restamped(rig) -> None:
    """An interface stamping with device uptime: frames are stamped on receipt, inputs still fresh."""
    svc, feeder, feed_bus, clock = rig
    enc_m, enc_e = feeder.encoders["MDPS_Sensors"], feeder.encoders["ESC_Motion"]
    vals_m = si_to_dbc(svc.profile, "MDPS_Sensors", {"column_torque": 0.5})
    vals_e = si_to_dbc(svc.profile, "ESC_Motion", {"speed": 100 * KMH})
    uptime0 = 12_345_000_000  # ns since the device booted
    for k in range(60):
        t_k = T0 + k * STEP_NS
        feed_bus.send(enc_m.message(vals_m, uptime0 + k * STEP_NS))
        if k % 3 == 0:
            feed_bus.send(enc_e.message(vals_e, uptime0 + k * STEP_NS))
        clock.sleep_until(t_k)
        r = svc.step_once(t_k)
    assert svc._restamp is True
    assert r.frames_used >= 1
    assert svc.receiver.sample(T0 + 59 * STEP_NS).mdps_ok


def test_replay_of_a_run_stopped_by_a_signal_reproduces_the_ramp_out(tmp_path, lde_bench: Bench) -> None:
    """The shutdown ramp-out is driven by the limiter's enable input, which no CAN frame carries: the
    recording's sparse ``/lde/events`` channel gives it back to the replay, step for step."""
    from lde.replay.replay import replay_log

    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    clock = lde_bench.clock
    path = tmp_path / "stopped.mcap"
    on_bench = lde_bench.service(backend="float", record=path)
    svc = on_bench.service
    fd = feeder(lde_bench.bus("feeder", preserve_timestamps=True), profile)
    live = _lockstep(svc, fd, clock, 1500)
    assert abs(live[-1].t_overlay) > 0.05
    svc.request_stop()

    def on_step(r) -> None:
        live.append(r)
        fd.send_until(r.t_ns + STEP_NS)

    svc.run(on_step=on_step)
    on_bench.close()  # the recording is complete
    assert live[-1].t_overlay == 0.0
    _, res = replay_log(path, profile, vehicle, backend="float")
    assert res.recorded_steps and len(res) == len(live)
    np.testing.assert_array_equal(res.t_ns, [r.t_ns for r in live])
    np.testing.assert_array_equal(res.fw, [r.fw for r in live])
    np.testing.assert_array_equal(res.t_overlay, [r.t_overlay for r in live])
    # without the events channel the replay would keep the overlay on: the check above can fail
    ramp = [r.t_overlay for r in live[1500:]]
    assert len(ramp) > 10 and abs(ramp[0]) > abs(ramp[-1])


def test_frame_delivered_after_its_step_is_restamped_fed_next_step_and_counted(rig) -> None:
    """A frame stamped at or before the last step's time that only reaches the socket after that
    step (a real-time sender on one CPU) is used at the next step, and recorded with the first
    microsecond after the last step: the recording then says when it could be used, so a replay on
    the recorded step times feeds it at the same step as the live run did."""
    svc, feeder, feed_bus, clock = rig

    class Capture:  # the recorder's hot-path interface (lde.io.recording.Recorder.frame / .step)
        def __init__(self) -> None:
            self.rx_t_ns: list[int] = []

        def frame(self, t_ns: int, can_id: int, ext: bool, dlc: int, word: int, is_rx: bool) -> None:
            if is_rx:
                self.rx_t_ns.append(t_ns)

        def step(self, *args: object) -> None:
            pass

    _lockstep(svc, feeder, clock, 20)
    t_last = T0 + 19 * STEP_NS
    assert svc.late_rx == 0
    cap = Capture()
    svc.recorder = cap
    vals = si_to_dbc(
        svc.profile,
        "MDPS_Sensors",
        {"column_torque": 0.8, "assist_torque": 1.2, "steering_angle": 0.5 * DEG, "steering_rate": 0.0},
    )
    stamp_ns = t_last - 500_000  # stamped 0.5 ms before the last step, delivered only now
    feed_bus.send(feeder.encoders["MDPS_Sensors"].message(vals, stamp_ns))
    t_k = T0 + 20 * STEP_NS
    feeder.send_until(t_k)
    clock.sleep_until(t_k)
    res = svc.step_once(t_k)
    assert svc.late_rx == 1
    restamped = [t for t in cap.rx_t_ns if t == (t_last // 1000 + 1) * 1000]
    assert len(restamped) == 1, cap.rx_t_ns
    # every frame received in this step (the regular ones and the late one) was fed to this step
    assert res.frames_used == len(cap.rx_t_ns) >= 2


def test_run_on_the_mdps_grid_steps_at_each_mdps_frame_and_at_1p5_periods_without_one() -> None:
    """``grid="mdps"``: a step at every MDPS frame's receive time, with its outputs; a lost frame gives
    one step 1.5 periods after the previous one and the next frame locks on again."""
    ch = f"lde-test-service-{next(_channels)}"
    feed_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    tap = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    profile = load_profile("lde")
    clock = SimulatedClock(T0)
    svc = Service(
        svc_bus, profile, load_vehicle("reference"), clock, backend="float", log_period_s=0, grid="mdps"
    )
    fd = feeder(feed_bus, profile, mdps_offset_ns=-(STEP_NS + 700_000))  # first MDPS at T0 + P + 0.7 ms
    lost = {30, 31, 60}
    sent: list[int] = []
    n_mdps = [0]
    real_send = feed_bus.send

    def send(msg: can.Message, timeout: float | None = None) -> None:
        if msg.arbitration_id == 0x2A0:
            n_mdps[0] += 1
            if n_mdps[0] in lost:
                return
            sent.append(round(msg.timestamp * 1e6) * 1000)
        real_send(msg)

    feed_bus.send = send  # type: ignore[method-assign]
    seen: list[int] = []

    def on_step(res) -> None:
        seen.append(res.t_ns)
        fd.send_until(res.t_ns + 2 * STEP_NS)  # the next frames are on the bus before they are due

    fd.send_until(T0 + 2 * STEP_NS)
    try:
        summary = svc.run(max_steps=100, on_step=on_step, t0_ns=T0 + STEP_NS)
    finally:
        feed_bus.shutdown()
        svc_bus.shutdown()
    out = _outputs(tap)
    tap.shutdown()
    t = np.array(seen)
    assert summary.steps == 100 and summary.deadline_misses == 0
    assert t[0] == sent[0]  # the first MDPS frame locks on at once (its window was open)
    on_frames = np.isin(t, sent)
    assert np.count_nonzero(~on_frames) == len(lost)  # exactly one step per lost frame
    first = T0 + STEP_NS + 700_000
    lost_nominal = [first + (n - 1) * STEP_NS for n in sorted(lost)]  # where the lost frames were due
    np.testing.assert_array_equal(t[~on_frames], np.array(lost_nominal) + STEP_NS // 2)
    np.testing.assert_array_equal(t[on_frames], sent[: np.count_nonzero(on_frames)])
    for name in ("LDE_Estimate", "LDE_Overlay", "LDE_Disturbance", "LDE_Diag"):
        assert sum(m.arbitration_id == profile.output_id(name) for m in out) == 100, name
    lat = svc.stats.arrays()["latency"]
    assert np.all(lat[on_frames] == 0)  # simulated clock: the outputs leave at the frame's time


def test_input_filters_pass_only_the_input_messages() -> None:
    ch = f"lde-test-service-{next(_channels)}"
    feed_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    profile = load_profile("lde")
    svc = Service(
        svc_bus, profile, load_vehicle("reference"), SimulatedClock(T0), backend="float", log_period_s=0
    )
    try:
        for fid in (0x123, 0x3D0, 0x2A0, 0x2A8):
            feed_bus.send(
                can.Message(timestamp=T0 / 1e9, arbitration_id=fid, data=bytes(8), is_extended_id=False)
            )
        svc._drain()
        assert sorted(svc._pid[: svc._np].tolist()) == [0x2A0, 0x2A8]
        # python-can's virtual bus has no descriptor to tell a filtered frame from an empty queue: no
        # filters there, the service drops the other ids itself (lde.can.busio.receive_only)
        assert svc.filters.startswith("none") and svc.foreign == 2
    finally:
        feed_bus.shutdown()
        svc_bus.shutdown()


def test_run_states_the_defaults_a_vehicle_file_leaves_out(tmp_path, caplog) -> None:
    """A vehicle file without ``[estimator]``: lde run says which keys took lde's defaults, and the
    recording's metadata keeps the same list (issue 13 item 5)."""
    import re
    from importlib.resources import files

    from lde.cli import main
    from lde.io.recording import read_recording

    text = (files("lde") / "vehicles" / "reference.toml").read_text()
    cut = re.sub(r"(?ms)^\[estimator\].*?(?=^\[|\Z)", "", text)
    assert "[estimator]" not in cut and cut != text
    car = tmp_path / "no_tuning.toml"
    car.write_text(cut)
    path = tmp_path / "run.mcap"
    with caplog.at_level("INFO", logger="lde.service.service"):
        rc = main(
            ["run", "-i", "virtual", "-c", "lde-defaults", "--vehicle", str(car), "--duration", "0.2"]
            + ["--backend", "float", "--record", str(path)]
        )
    assert rc == 3  # no input on this bus
    note = [r.getMessage() for r in caplog.records if "defaults used for" in r.getMessage()]
    assert note and "[estimator]" in note[0], caplog.text
    assert "[estimator]" in read_recording(path).metadata["vehicle_defaults"]


def test_a_blind_service_says_which_input_is_missing_and_what_arrived(caplog) -> None:
    """Wrong profile: the bus carries the hyundai profile's messages, the service decodes lde's. The
    log names the missing message, its id, the bus and the profile, and the profile the traffic fits
    (issue 13 item 2; lde.can.watch)."""
    ch = f"lde-test-service-{next(_channels)}"
    feed_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    try:
        svc = Service(svc_bus, "lde", load_vehicle("reference"), SimulatedClock(T0), backend="float")
        hy = load_profile("hyundai")
        for k in range(150):  # 1.5 s of the hyundai profile's input messages, every 10 ms
            for spec in hy.messages.values():
                feed_bus.send(
                    can.Message(
                        timestamp=(T0 + k * 10_000_000) / 1e9,
                        arbitration_id=spec.frame_id,
                        is_extended_id=False,
                        data=bytes(spec.length),
                    )
                )
        with caplog.at_level("INFO", logger="lde.service.service"):
            svc.run(max_steps=300)  # 1.17 s of steps
        warns = [
            r.getMessage()
            for r in caplog.records
            if r.levelname == "WARNING" and "no input" in r.getMessage()
        ]
        assert warns, caplog.text
        assert "MDPS_Sensors (0x2A0) never received" in warns[0]
        assert ch in warns[0] and "profile lde" in warns[0]
        assert "fit profile hyundai (4 of its 4 input messages" in warns[0]
        assert svc.watch.warnings == len(warns) <= 2  # MDPS first, ESC_Motion when it joins; not every step
    finally:
        feed_bus.shutdown()
        svc_bus.shutdown()


def test_the_mdps_grid_skips_the_windows_it_fell_behind_by_and_counts_them() -> None:
    """No MDPS frame and a loop held up for 10.2 periods (a slow CPU, user-mode Linux): the locked
    grid skips the windows that ended before the last one (counted as skipped deadline misses), keeps
    its phase, and steps on time again, instead of running every missed window late one after the
    other."""
    ch = f"lde-test-service-{next(_channels)}"
    bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    clock = SimulatedClock(T0)
    svc = Service(
        bus,
        load_profile("lde"),
        load_vehicle("reference"),
        clock,
        backend="float",
        log_period_s=0,
        grid="mdps",
    )
    seen: list[tuple[int, int]] = []

    def on_step(res) -> None:
        seen.append((res.t_ns, res.timing.period_error_ns))
        if len(seen) == 20:
            clock.advance(10 * STEP_NS + STEP_NS // 5)  # the loop stood still for 10.2 periods

    try:
        summary = svc.run(max_steps=30, on_step=on_step, t0_ns=T0 + STEP_NS)
    finally:
        bus.shutdown()
    t = np.array([s[0] for s in seen])
    pe = np.array([s[1] for s in seen])
    assert np.all(np.diff(t[:20]) == STEP_NS) and np.all(pe[:20] <= 1)  # timeout steps: 1 period apart
    assert svc.stats.skipped == 9 and summary.deadline_misses == 9  # the late step: 0.78 ms late
    assert t[20] - t[19] == 10 * STEP_NS  # the phase is kept: whole periods skipped
    assert 0 < pe[20] < STEP_NS  # the one late step: the latest window that ended
    assert np.all(np.diff(t[20:]) == STEP_NS) and np.all(pe[21:] <= 1)  # on time again


class _CallRecorder:
    """A recorder without rings: the service calls it per frame and per step (the Python hand-off)."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, int, int, int, bool]] = []
        self.rows: list[tuple[float, float, tuple[int, ...]]] = []

    def frame(self, t_ns: int, can_id: int, ext: bool, dlc: int, word: int, is_rx: bool) -> None:
        self.frames.append((t_ns, can_id, dlc, word, is_rx))

    def step(self, block, row: int, timing: tuple[int, ...]) -> None:
        self.rows.append((float(block.est[row, 0]), float(block.t_overlay[row]), tuple(timing)))


def test_the_compiled_hand_off_sends_and_records_what_the_python_path_does(tmp_path) -> None:
    """The step's compiled hand-off (lde.service.handoff: timing, LDE_Diag, the recorder's rings) against a
    recorder called from Python, on the same inputs and start times: the same LDE_Diag frames (and
    their values those of lde.service.diagnostics.diag_values, saturations included), the same sent frames and
    step rows in the recording."""
    from lde.io.recording import Recorder, read_recording
    from lde.service.diagnostics import diag_signals

    runs = []
    for ringed in (True, False):
        ch = f"lde-test-handoff-{next(_channels)}"
        feed_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
        svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
        clock = SimulatedClock(T0)
        rec = Recorder(tmp_path / "ring.mcap") if ringed else _CallRecorder()
        profile, vehicle = load_profile("lde"), load_vehicle("reference")
        svc = Service(svc_bus, profile, vehicle, clock, backend="float", recorder=rec)
        assert (svc._ring is not None) == ringed
        fd = feeder(feed_bus, svc.profile)
        results = []
        # late starts: inside the range, past a deadline, past every LDE_Diag range (saturated)
        lateness = {40: 300_000, 41: DEADLINE_MISS_NS + 1, 42: 9_000_000, 43: 20_000_000}
        for k in range(120):
            t_k = T0 + k * STEP_NS
            fd.send_until(t_k)
            clock.sleep_until(t_k)
            late = lateness.get(k, 0)
            clock.sleep_until(t_k + late)
            results.append(svc.step_once(t_k, t_start=t_k + late))
        if ringed:
            rec.close()
        names = ("LDE_Estimate", "LDE_Overlay", "LDE_Disturbance", "LDE_Diag")
        ids = {svc.profile.output_id(n) for n in names}
        out = [m for m in _outputs(feed_bus) if m.arbitration_id in ids]
        feed_bus.shutdown()
        svc_bus.shutdown()
        runs.append((svc, rec, results, out))

    (svc, rec, results, out), (_, calls, results_py, out_py) = runs
    assert [bytes(m.data) for m in out] == [bytes(m.data) for m in out_py]
    diag_id = svc.profile.output_id("LDE_Diag")
    dc = MessageCodec(svc.profile, "LDE_Diag")
    diags = [dc.decode(bytes(m.data)) for m in out if m.arbitration_id == diag_id]
    assert len(diags) == len(results) == 120
    for r, d in zip(results, diags, strict=True):
        assert r.timing is not None
        want = diag_signals(r.timing, 0)
        assert {k: d[k] for k in want} == pytest.approx(want), r.t_ns
    assert diags[42]["PeriodError"] == 8191 and diags[43]["DeadlineMisses"] == 3
    assert [r.timing for r in results] == [r.timing for r in results_py]

    got = read_recording(tmp_path / "ring.mcap")
    tx = got.tx
    cols = zip(tx.t_ns, tx.can_id, tx.data, tx.dlc, strict=True)
    sent = [(int(t), int(i), bytes(d[:n])) for t, i, d, n in cols]
    sent_py = [(t, i, int(w).to_bytes(8, "little")[:n]) for t, i, n, w, is_rx in calls.frames if not is_rx]
    assert sent == sent_py
    assert [s[2] for s in sent] == [bytes(m.data) for m in out]
    # the received frames: handed to the ring by the compiled hand-off after the sends, the same
    rx = got.rx
    rcols = zip(rx.t_ns, rx.can_id, rx.data, rx.dlc, strict=True)
    received = [(int(t), int(i), bytes(d[:n])) for t, i, d, n in rcols]
    received_py = [(t, i, int(w).to_bytes(8, "little")[:n]) for t, i, n, w, is_rx in calls.frames if is_rx]
    assert received == received_py and len(received) > 120
    np.testing.assert_array_equal(got.estimate["Fw"], [row[0] for row in calls.rows])
    timing = np.array([row[2] for row in calls.rows])
    np.testing.assert_array_equal(got.diag["deadline_misses"], timing[:, 4])
    np.testing.assert_allclose(got.diag["period_error_us"], timing[:, 0] / 1e3)
    np.testing.assert_allclose(got.diag["step_time_us"], timing[:, 1] / 1e3)


def test_the_engine_call_built_once_follows_a_reset_of_the_engine(rig) -> None:
    """The live engine call's arguments are built once per pending-frame count (Engine.live_args);
    after Engine.reset (new state arrays) they are rebuilt, not run on the old state."""
    svc, feeder, _, clock = rig
    _lockstep(svc, feeder, clock, 5)
    assert svc._heads and all(svc.engine.live_args_valid(a) for a in svc._heads.values())
    svc.engine.reset()
    assert not any(svc.engine.live_args_valid(a) for a in svc._heads.values())
    _lockstep(svc, feeder, clock, 3, k0=5)
    assert svc.engine.steps == 3  # the reset engine ran them


class _SpinningClock(SimulatedClock):
    """A simulated clock that spins like MonotonicClock (``spin_ns``: the service's engine pre-warm
    runs) and puts the feeder's frames on the bus when the service waits past their time."""

    spin_ns = 200_000

    def __init__(self, start_ns: int, fd: InputFeeder) -> None:
        super().__init__(start_ns)
        self.fd = fd

    def recv_until(self, bus, t_ns: int, expect_ns: int | None = None):
        msg = bus.recv(0.0)
        if msg is None:
            self.fd.send_until(t_ns)
            msg = bus.recv(0.0)
            if msg is None:
                self.sleep_until(t_ns)
        return msg


@pytest.mark.parametrize("lost", [(), (9, 20, 21)])
def test_the_engine_prewarm_before_the_mdps_frame_changes_nothing(lost) -> None:
    """``Service(prewarm=True)`` (the default) makes the engine's empty call when the spin before an
    expected MDPS frame starts: the same step times, the same frames on the bus and the same engine
    state as without it, with and without lost MDPS frames."""
    runs = []
    for prewarm in (True, False):
        ch = f"lde-test-service-{next(_channels)}"
        feed_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
        svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
        tap = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
        profile = load_profile("lde")
        fd = feeder(feed_bus, profile, mdps_offset_ns=-(STEP_NS + 700_000))
        n_mdps = [0]
        real_send = feed_bus.send

        def send(msg: can.Message, timeout: float | None = None, real_send=real_send, n_mdps=n_mdps) -> None:
            if msg.arbitration_id == 0x2A0:
                n_mdps[0] += 1
                if n_mdps[0] in lost:
                    return
            real_send(msg)

        feed_bus.send = send  # type: ignore[method-assign]
        clock = _SpinningClock(T0, fd)
        svc = Service(
            svc_bus,
            profile,
            load_vehicle("reference"),
            clock,
            backend="fixed",
            log_period_s=0,
            grid="mdps",
            prewarm=prewarm,
        )
        seen: list = []
        try:
            svc.run(max_steps=40, on_step=seen.append, t0_ns=T0 + STEP_NS)
        finally:
            feed_bus.shutdown()
            svc_bus.shutdown()
        ours = {profile.output_id(n) for n in ("LDE_Estimate", "LDE_Overlay", "LDE_Disturbance", "LDE_Diag")}
        out = [(m.arbitration_id, bytes(m.data)) for m in _outputs(tap) if m.arbitration_id in ours]
        tap.shutdown()
        rows = [(r.t_ns, r.fw, r.mw, r.status, r.t_overlay, r.frames_used) for r in seen]
        st = svc.engine.est.state  # the filter's, its shadow's and the learner's state, the limiter's
        kept = [
            st.x,
            st.P,
            st.aux,
            *st.shadow[:4],
            st.ls,
            st.p,
            svc.engine.lsf,
            svc.engine.lsi,
        ]
        runs.append((rows, out, [np.copy(a) for a in kept], svc.prewarms))
    (rows_w, out_w, state_w, n_w), (rows, out, state, n) = runs
    assert n == 0 and n_w >= 30  # a pre-warm before (nearly) every expected frame
    assert len(rows) == 40 and rows_w == rows
    assert out_w == out and len(out) == 4 * 40
    for a, b in zip(state_w, state, strict=True):
        np.testing.assert_array_equal(a, b)
