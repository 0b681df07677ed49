"""One data path: the live service and replay give the same rows for the same frames.

The live service runs on python-can's virtual bus with a simulated clock and records; the same
frames then go through ``lde replay`` twice: from the recording (recorded step times, enable input
and deadline bits), and as a bare candump log with explicit step times. The CSV columns and the
status must be identical at every step, including the first steps, whose inputs are not finite yet
(no frame received), a stretch where the ESC frames stop (stale inputs), corrupted frames, a late
step (DEADLINE_MISS) and the shutdown ramp-out.
"""

from __future__ import annotations

import csv
import itertools
from pathlib import Path

import can
import numpy as np
import pytest

from lde.can.codec import MessageEncoder, si_to_dbc
from lde.can.frames import FrameBatch
from lde.can.profiles import Profile, load_profile
from lde.clock import SimulatedClock
from lde.engine.grid import locked_step_times
from lde.io.recording import Recorder, read_recording
from lde.params import load_vehicle
from lde.replay.replay import csv_columns, replay, replay_log, write_csv
from lde.service.diagnostics import DEADLINE_MISS_NS
from lde.service.service import Service
from lde.status import DEADLINE_MISS, ESC_FAULT, MDPS_FAULT, NOT_CONVERGED, VALID
from lde.testing import Bench, InputFeeder
from lde.testing.bench import DEFAULT_START_NS
from lde.units import DEG, KMH, STEP_NS

T0 = DEFAULT_START_NS  # the bench's start
_channels = itertools.count()  # the MDPS-grid test's own virtual buses


def _feeder(bus: can.BusABC, profile: Profile) -> InputFeeder:
    """MDPS every 3.9 ms (300 us before the grid), ESC every 10 ms, with a disturbance ramp, from
    step 20 and 22 on; ESC silent in [2.0 s, 2.3 s); every 997th MDPS frame has a corrupted CRC."""

    def s(t: int) -> float:
        return (t - T0) * 1e-9

    sent = {"MDPS_Sensors": 0}

    def corrupt(message: str, t: int, msg: can.Message) -> None:
        if message == "MDPS_Sensors":
            sent[message] += 1
            if sent[message] % 997 == 0:
                msg.data[0] ^= 0x5A

    return InputFeeder(
        bus,
        profile,
        {"MDPS_Sensors": T0 + 20 * STEP_NS - 300_000, "ESC_Motion": T0 + 22 * STEP_NS},  # steps 0-19: nothing
        silent=lambda message, t: message == "ESC_Motion" and 2.0 <= s(t) < 2.3,
        tamper=corrupt,
        column_torque=lambda t: 0.6 + 0.3 * np.sin(s(t)),
        assist_torque=lambda t: 1.0 + 0.5 * np.sin(s(t)),
        steering_angle=lambda t: (0.4 + 0.2 * np.sin(2 * s(t))) * DEG,
        steering_rate=lambda t: 0.4 * np.cos(2 * s(t)) * DEG,
        yaw_rate=lambda t: 0.002 * np.sin(s(t)),
        lat_accel=0.1,
        speed=100 * KMH,
    )


def _csv(path: Path) -> dict[str, list[str]]:
    with path.open() as fh:
        rows = list(csv.reader(fh))
    head = rows[0]
    return {h: [r[i] for r in rows[1:]] for i, h in enumerate(head)}


@pytest.mark.parametrize("backend", ["float", "fixed"])
def test_live_and_replay_give_identical_rows(tmp_path: Path, backend: str, lde_bench: Bench) -> None:
    profile, vehicle = lde_bench.profile, load_vehicle("reference")
    tap = lde_bench.bus("tap")  # every frame on the bus, in bus order
    rec_path = tmp_path / "live.mcap"
    clock = lde_bench.clock
    feeder = _feeder(lde_bench.bus("feeder", preserve_timestamps=True), profile)
    on_bench = lde_bench.service(backend=backend, vehicle=vehicle, record=rec_path)
    svc = on_bench.service  # stepped by hand: one late step
    live = []
    for k in range(1800):
        t_k = T0 + k * STEP_NS
        feeder.send_until(t_k)
        clock.sleep_until(t_k)
        late = k == 700  # one step starts late: DEADLINE_MISS, recorded and replayed
        live.append(svc.step_once(t_k, t_start=t_k + DEADLINE_MISS_NS + 1 if late else t_k))
    svc.request_stop()  # ramp-out: the limiter's enable input goes to 0
    for k in range(1800, 2100):
        t_k = T0 + k * STEP_NS
        feeder.send_until(t_k)
        clock.sleep_until(t_k)
        live.append(svc.step_once(t_k))
    on_bench.close()  # the recording is complete
    frames = []
    while (m := tap.recv(0.0)) is not None:
        if m.arbitration_id in (0x2A0, 0x2A8):
            frames.append(m)

    status = np.array([r.status for r in live])
    # the test covers what it says it does
    assert np.all(status[:20] & (MDPS_FAULT | ESC_FAULT))  # no input yet: NaN inputs
    assert np.any(status & VALID)
    assert np.any(status[400:] & ESC_FAULT)  # the ESC frames stop for 0.3 s
    assert status[700] & DEADLINE_MISS and np.count_nonzero(status & DEADLINE_MISS) == 1
    assert np.any(status & NOT_CONVERGED) and abs(live[1799].t_overlay) > 0 and live[-1].t_overlay == 0.0

    # 1. the recording, replayed on its recorded step times
    live_csv = tmp_path / "live.csv"
    _, res = replay_log(rec_path, None, vehicle, backend)
    write_csv(live_csv, res)
    np.testing.assert_array_equal(res.t_ns, [r.t_ns for r in live])
    np.testing.assert_array_equal(res.status, status)
    np.testing.assert_array_equal(res.fw, [r.fw for r in live])
    np.testing.assert_array_equal(res.mw, [r.mw for r in live])
    np.testing.assert_array_equal(res.t_overlay, [r.t_overlay for r in live])
    np.testing.assert_array_equal(res.overlay_state, [r.overlay_state for r in live])
    rec_data = read_recording(rec_path)
    np.testing.assert_array_equal(rec_data.estimate["Fw"], res.fw)  # exact floats in the recording

    # 2. the bare frames (no recording): the same rows with the live step times, enable and bits
    fb = FrameBatch.from_messages(frames)
    enable = np.array([r.overlay_enable for r in live])
    res2 = replay(
        fb,
        profile,
        vehicle,
        backend,
        step_times_ns=res.t_ns,
        overlay_enable=enable,
        extra_status=(status & DEADLINE_MISS).astype(np.uint8),
    )
    bare_csv = tmp_path / "bare.csv"
    write_csv(bare_csv, res2)
    a, b = _csv(live_csv), _csv(bare_csv)
    assert list(a) == [c for c, _, _ in csv_columns()]
    for col in a:
        assert a[col] == b[col], col


def _feed_jittered(bus: can.BusABC, profile, t_to: int, state: dict) -> list[int]:
    """Like :func:`_feed`, on the MDPS-locked grid's terms: the MDPS frames jitter by up to +-0.8 ms
    around their 3.9 ms schedule, and a few are lost (one in 211 in the first 3.5 s, two in a row once).
    Returns the receive times of the MDPS frames sent."""
    sent = []
    while min(state["next_m"], state["next_e"]) <= t_to:
        if state["next_m"] <= state["next_e"]:
            n = state["n_m"]
            state["n_m"] += 1
            t = state["next_m"] + ((n * 7919) % 1601 - 800) * 1000
            state["next_m"] += STEP_NS
            if (n % 211 == 5 and n < 900) or n == 301:
                continue
            s = (t - T0) * 1e-9
            vals = si_to_dbc(
                profile,
                "MDPS_Sensors",
                {
                    "column_torque": 0.6 + 0.3 * np.sin(s),
                    "assist_torque": 1.0 + 0.5 * np.sin(s),
                    "steering_angle": (0.4 + 0.2 * np.sin(2 * s)) * DEG,
                    "steering_rate": 0.4 * np.cos(2 * s) * DEG,
                },
            )
            msg = state["mdps"].message(vals, t)
            if n % 997 == 200:
                msg.data[0] ^= 0x5A  # a corrupted frame still marks the sender's period
            bus.send(msg)
            sent.append(t)
        else:
            t = state["next_e"]
            s = (t - T0) * 1e-9
            if not (2.0 <= s < 2.3):
                vals = si_to_dbc(
                    profile,
                    "ESC_Motion",
                    {"yaw_rate": 0.002 * np.sin(s), "lat_accel": 0.1, "speed": 100 * KMH},
                )
                bus.send(state["esc"].message(vals, t))
            state["next_e"] += 10_000_000
    return sent


@pytest.mark.parametrize("backend", ["float", "fixed"])
def test_live_on_the_mdps_grid_and_replay_give_identical_rows(tmp_path: Path, backend: str) -> None:
    """The live loop (:meth:`Service.run`, ``grid="mdps"``) steps at the MDPS frames' receive times;
    a replay of its recording, and of the bare frames on the step times that :mod:`lde.engine.grid`'s rule
    gives for them (:func:`lde.engine.grid.locked_step_times`), give the same rows."""
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    ch = f"lde-one-path-{next(_channels)}"
    feed_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    tap = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    rec_path = tmp_path / "live.mcap"
    clock = SimulatedClock(T0)
    state = {
        "mdps": MessageEncoder(profile, "MDPS_Sensors"),
        "esc": MessageEncoder(profile, "ESC_Motion"),
        "next_m": T0 + 20 * STEP_NS,  # the first periods have no input at all: steps at the windows' ends
        "next_e": T0 + 22 * STEP_NS,
        "n_m": 0,
    }
    sent: list[int] = []
    live = []

    def on_step(r) -> None:
        live.append(r)
        if len(live) == 700:  # this step overran: the next one starts 1.2 ms after its frame
            clock.advance(STEP_NS + 1_200_000)
        if len(live) == 1800:
            svc.request_stop()  # ramp-out: the limiter's enable input goes to 0
        sent.extend(_feed_jittered(feed_bus, profile, r.t_ns + 2 * STEP_NS, state))

    rec = Recorder(rec_path)
    try:
        svc = Service(
            svc_bus, profile, vehicle, clock, backend=backend, recorder=rec, log_period_s=0, grid="mdps"
        )
        sent.extend(_feed_jittered(feed_bus, profile, T0 + 2 * STEP_NS, state))
        svc.run(on_step=on_step, t0_ns=T0)
    finally:
        rec.close()
        feed_bus.shutdown()
        svc_bus.shutdown()
    frames = []
    while (m := tap.recv(0.0)) is not None:
        if m.arbitration_id in (0x2A0, 0x2A8):
            frames.append(m)
    tap.shutdown()

    t_live = np.array([r.t_ns for r in live])
    status = np.array([r.status for r in live])
    # the test covers what it says it does
    assert np.all(status[:19] & MDPS_FAULT) and np.all(
        t_live[:19] == T0 + STEP_NS // 2 + np.arange(19) * STEP_NS
    )
    on_frame = np.isin(t_live, sent)
    assert on_frame.sum() > 1700 and 3 < (~on_frame[20:]).sum() < 10  # lost frames: window-end steps
    assert np.any(status & VALID) and np.any(status[400:] & ESC_FAULT)
    assert status[700] & DEADLINE_MISS and np.count_nonzero(status & DEADLINE_MISS) == 1
    assert np.any(status & NOT_CONVERGED) and abs(live[1799].t_overlay) > 0 and live[-1].t_overlay == 0.0

    # the rule gives the live step times from the MDPS frames' receive times alone
    fb = FrameBatch.from_messages(frames)
    anchor_t = fb.t_ns[fb.can_id == 0x2A0]
    np.testing.assert_array_equal(locked_step_times(anchor_t, T0, int(t_live[-1])), t_live)

    # 1. the recording, replayed on its recorded step times
    live_csv = tmp_path / "live.csv"
    _, res = replay_log(rec_path, None, vehicle, backend)
    write_csv(live_csv, res)
    np.testing.assert_array_equal(res.t_ns, t_live)
    np.testing.assert_array_equal(res.status, status)
    np.testing.assert_array_equal(res.fw, [r.fw for r in live])
    np.testing.assert_array_equal(res.t_overlay, [r.t_overlay for r in live])

    # 2. the bare frames on the rule's step times
    res2 = replay(
        fb,
        profile,
        vehicle,
        backend,
        step_times_ns=locked_step_times(anchor_t, T0, int(t_live[-1])),
        overlay_enable=np.array([r.overlay_enable for r in live]),
        extra_status=(status & DEADLINE_MISS).astype(np.uint8),
    )
    bare_csv = tmp_path / "bare.csv"
    write_csv(bare_csv, res2)
    a, b = _csv(live_csv), _csv(bare_csv)
    for col in a:
        assert a[col] == b[col], col
