"""lde.testing's bench: the one scheduler on the simulated clock, bench buses, capture and assertions."""

from __future__ import annotations

import can
import numpy as np
import pytest

import lde.testing
from lde.can.codec import MessageEncoder
from lde.can.frames import seconds_to_ns
from lde.errors import ConfigError
from lde.testing import (
    STEP_S,
    Bench,
    BenchTimeout,
    InputFeeder,
    LeakedBus,
    Rank,
    assert_e2e_valid,
    assert_in_range,
    assert_periodic,
)
from lde.testing.bench import DEFAULT_START_NS
from lde.units import KMH, STEP_NS

T0 = DEFAULT_START_NS
MS = 1_000_000


def test_public_names_are_exported() -> None:
    for name in lde.testing.__all__:
        assert getattr(lde.testing, name) is not None, name
    with pytest.raises(AttributeError):
        _ = lde.testing.NoSuchThing


def test_actions_at_one_instant_run_by_rank_then_creation(lde_bench: Bench) -> None:
    seen: list[tuple[int, str]] = []

    def log(tag: str):
        return lambda t: seen.append(((t - T0) // MS, tag))

    lde_bench.every(0.002, log("late"), rank=Rank.LATE)
    lde_bench.every(0.002, log("service"), rank=Rank.SERVICE)
    lde_bench.every(0.002, log("user-a"))
    lde_bench.every(0.004, log("user-b"), phase_s=0.001)
    lde_bench.every(0.002, log("source"), rank=Rank.SOURCE)
    lde_bench.run(0.005)  # [0, 5 ms): the instants 0, 1 (b), 2, 4; the clock ends at 5 ms
    assert seen == [
        *[(0, "source"), (0, "user-a"), (0, "service"), (0, "late")],
        (1, "user-b"),
        *[(2, "source"), (2, "user-a"), (2, "service"), (2, "late")],
        *[(4, "source"), (4, "user-a"), (4, "service"), (4, "late")],
    ]
    assert lde_bench.now_ns == T0 + 5 * MS and lde_bench.elapsed_s == pytest.approx(0.005)


def test_tasks_cannot_start_in_the_past_and_cancel_stops_them(lde_bench: Bench) -> None:
    lde_bench.run(0.010)
    with pytest.raises(ConfigError, match="before now"):
        lde_bench.scheduler.at(T0, lambda t: None)
    hits: list[int] = []
    task = lde_bench.every(0.004, hits.append)  # aligned to the bench's grid: 12, 16, 20 ms...
    lde_bench.run(0.009)
    task.cancel()
    lde_bench.run(0.010)
    assert [(t - T0) // MS for t in hits] == [12, 16]


def test_frames_carry_the_bench_time_unless_preserved(lde_bench: Bench) -> None:
    a = lde_bench.bus("a")
    keep = lde_bench.bus("keep", preserve_timestamps=True)
    b = lde_bench.bus("b")
    lde_bench.run(0.0125)
    a.send(can.Message(arbitration_id=0x123, data=b"\x01", is_extended_id=False, timestamp=5.0))
    keep.send(can.Message(arbitration_id=0x124, data=b"\x02", is_extended_id=False, timestamp=7.0))
    got = [b.recv(), b.recv()]
    assert [m.arbitration_id for m in got] == [0x123, 0x124]
    assert seconds_to_ns(got[0].timestamp) == T0 + 12_500_000  # stamped when sent, as a kernel would
    assert got[1].timestamp == 7.0
    assert a.recv() is not None  # a hears keep's frame (never its own)
    assert a.recv() is None


def test_recv_never_waits_and_iteration_stops(lde_bench: Bench) -> None:
    a, b = lde_bench.bus("a"), lde_bench.bus("b")
    assert b.recv(timeout=10.0) is None  # no frame can arrive while the bench stands still
    for k in range(3):
        a.send(can.Message(arbitration_id=0x100 + k, data=b"", is_extended_id=False))
    assert [m.arbitration_id for m in b] == [0x100, 0x101, 0x102]
    assert list(b) == []


def test_drop_and_filters(lde_bench: Bench) -> None:
    tx = lde_bench.bus("tx", drop=[0x200])
    rx = lde_bench.bus("rx", can_filters=[{"can_id": 0x300, "can_mask": 0x7FF}])
    for i in (0x200, 0x300, 0x301):
        tx.send(can.Message(arbitration_id=i, data=b"\x00", is_extended_id=False))
    assert tx.dropped == 1 and tx.sent == 2
    assert [m.arbitration_id for m in rx] == [0x300]
    assert [f.can_id for f in (lde_bench.frames(0x200), lde_bench.frames(0x301))] == [0x200, 0x301]
    assert (len(lde_bench.frames(0x200)), len(lde_bench.frames(0x301))) == (0, 1)


def test_send_periodic_runs_on_the_bench_clock(lde_bench: Bench) -> None:
    bus = lde_bench.bus("periodic")
    msgs = [can.Message(arbitration_id=0x400, data=bytes([k]), is_extended_id=False) for k in range(2)]
    task = bus.send_periodic(msgs, period=0.010, duration=0.055)
    lde_bench.run(0.100)
    frames = lde_bench.frames(0x400)
    assert_periodic(frames, 0.010)
    assert len(frames) == 6  # 0, 10, ..., 50 ms: the duration ends it
    assert [f.data for f in frames] == [b"\x00", b"\x01"] * 3
    task.stop()
    bus.shutdown()  # stops its tasks; the bench no longer delivers to it
    assert bus not in lde_bench.medium.buses


def test_on_frame_handlers_answer_at_the_same_instant(lde_bench: Bench) -> None:
    """An ECU model answering every MDPS frame: the answer carries the frame's own time."""
    lde_bench.feeder(speed=100 * KMH)
    ecu = lde_bench.bus("ecu")
    answered: list[int] = []

    def answer(frame) -> None:
        answered.append(frame.t_ns)
        ecu.send(can.Message(arbitration_id=0x5A0, data=bytes([len(answered) & 0xFF]), is_extended_id=False))

    assert lde_bench.on_frame("MDPS_Sensors", answer, bus=ecu) is ecu
    lde_bench.run(0.1)
    mdps, answers = lde_bench.frames("MDPS_Sensors"), lde_bench.frames(0x5A0)
    assert len(mdps) == len(answers) == 26
    np.testing.assert_array_equal(answers.t_ns, mdps.t_ns)
    np.testing.assert_array_equal(answered, mdps.t_ns)


def test_wait_for_runs_until_a_new_frame_and_times_out(lde_bench: Bench) -> None:
    lde_bench.feeder(start_s=0.0125, speed=100 * KMH)
    esc = lde_bench.wait_for("ESC_Motion", timeout_s=0.1)
    assert esc.t_ns == T0 + 12_500_000 and lde_bench.now_ns == esc.t_ns  # it stops at that instant
    assert esc["VehicleSpeed"] == pytest.approx(100.0, abs=0.1) and esc.e2e_ok
    nxt = lde_bench.wait_for("ESC_Motion", timeout_s=0.010)  # the next one, not the same again:
    assert nxt.t_ns == esc.t_ns + 10 * MS  # due exactly at the timeout, which counts
    slow = lde_bench.wait_for("ESC_Motion", timeout_s=1.0, where=lambda f: f.t_ns >= T0 + 100 * MS)
    assert slow.t_ns == T0 + 102_500_000
    before = lde_bench.now_ns
    with pytest.raises(BenchTimeout, match=r"LDE_Overlay frame .* 0.05 s .* MDPS_Sensors: \d+"):
        lde_bench.wait_for("LDE_Overlay", timeout_s=0.05)
    assert lde_bench.now_ns == before + 50 * MS
    with pytest.raises(ConfigError, match="has no message 'NoSuchMessage'"):
        lde_bench.wait_for("NoSuchMessage")


def test_feeder_on_the_bench_sends_what_it_sends_by_hand() -> None:
    """Scheduled by the bench, each frame goes out at its time; by hand (``send_until``), with its
    nominal time as timestamp: the same frames either way."""

    def speed(t: int) -> float:
        return 100 * KMH + (t - T0) * 1e-9

    with Bench() as auto, Bench() as manual:
        auto.feeder(column_torque=0.8, speed=speed)
        auto.run(0.5)
        fd = InputFeeder(
            manual.bus("by hand", preserve_timestamps=True), manual.profile, T0, column_torque=0.8
        )
        fd.set(speed=speed)
        for _ in range(50):
            manual.run(0.01)
            fd.send_until(manual.now_ns - 1)  # [0, 0.5 s), like auto.run(0.5)
        for name in ("MDPS_Sensors", "ESC_Motion"):
            a, m = auto.frames(name), manual.frames(name)
            assert len(a) == len(m) > 40
            np.testing.assert_array_equal(a.t_ns, m.t_ns)
            np.testing.assert_array_equal(a.data, m.data)


def test_a_bus_left_open_on_the_channel_is_reported_and_closed() -> None:
    bench = Bench()
    bench.bus("closed by the bench")
    mine = can.Bus(interface="virtual", channel=bench.channel)
    with pytest.raises(LeakedBus, match="1 bus"):
        bench.close()
    from can.interfaces import virtual

    mine.shutdown()
    assert bench.channel not in virtual.channels
    with Bench() as clean, can.Bus(interface="virtual", channel=clean.channel):
        pass  # closed before the bench: no leak


def _lde_frames(backend: str = "float", seconds: float = 0.5):
    bench = Bench()
    bench.feeder(column_torque=0.8, assist_torque=1.2, speed=100 * KMH)
    bench.service(backend=backend)
    bench.run(seconds)
    return bench


def test_assertions_pass_on_lde_outputs_and_fail_on_broken_frames() -> None:
    with _lde_frames() as bench:
        est = bench.frames("LDE_Estimate")
        assert len(est) == round(0.5 / STEP_S) + 1
        assert_periodic(est)
        assert_e2e_valid(est)
        assert_in_range(est, "LatForce", -6000, 6000)
        with pytest.raises(AssertionError, match=r"LDE_Estimate: 1 of \d+ intervals are not 10 ms"):
            assert_periodic(est[:2], 0.010)
        with pytest.raises(AssertionError, match="at least 200"):
            assert_periodic(est, min_frames=200)
        with pytest.raises(AssertionError, match="LatForce: .* outside"):
            assert_in_range(est, "LatForce", 1.0e6, 2.0e6)
        skipped = est._take(np.r_[0:10, 11 : len(est)])  # one frame lost
        with pytest.raises(AssertionError, match="1 counter breaks"):
            assert_e2e_valid(skipped)
        bad = est[:5]
        bad.data[2, 3] ^= 0x10  # one payload bit flipped: the CRC no longer matches
        bad = bad._take(np.arange(5))  # fresh verdicts
        with pytest.raises(AssertionError, match="1 of 5 frames fail the CRC"):
            assert_e2e_valid(bad)
        with pytest.raises(AssertionError, match="not a message of the profile"):
            assert_e2e_valid(bench.frames(0x7FF))


def test_frames_decode_by_name_and_give_columns() -> None:
    with _lde_frames() as bench:
        svc = bench.services[0]
        est = bench.frames("LDE_Estimate")
        np.testing.assert_array_equal(est.t_ns, svc.series("t_ns"))
        np.testing.assert_allclose(est.signal("LatForce"), np.round(svc.series("fw")), atol=0.51)
        last = est[-1]
        assert last.name == "LDE_Estimate" and last.can_id == 0x3D1
        assert int(last["Status"]) == svc.last.status
        with pytest.raises(KeyError, match="has no signal 'Nope'"):
            last["Nope"]
        with pytest.raises(ConfigError, match="has no signal"):
            est.signal("Nope")
        assert len(est.since(est.t_ns[-3])) == 3


def test_service_options_are_checked() -> None:
    with Bench() as bench:
        with pytest.raises(ConfigError, match="does not learn"):
            bench.service(backend="paper", learned="state.learned")
        with pytest.raises(ConfigError, match="not an lde output message"):
            bench.service(drop=["MDPS_Sensors"])
        with pytest.raises(ConfigError, match="add a simulator first"):
            bench.run()
        with pytest.raises(ConfigError, match="overlay='script'"):
            bench.simulator("straight", overlay="script")
    with pytest.raises(ConfigError, match="use one of virtual, socketcan"):
        Bench(interface="pcan")


def test_bench_encoders_match_the_codec(lde_bench: Bench) -> None:
    """A frame the user encodes with lde.can.codec decodes back through the capture."""
    bus = lde_bench.bus("user")
    enc = MessageEncoder(lde_bench.profile, "LDE_Overlay")
    for k in range(20):
        bus.send(enc.message({"OverlayTorque": 0.01 * k, "Active": 1}, 0))
        lde_bench.run(STEP_NS / 1e9)
    ov = lde_bench.frames("LDE_Overlay")
    assert_e2e_valid(ov)
    assert_periodic(ov)
    np.testing.assert_allclose(ov.signal("OverlayTorque"), 0.01 * np.arange(20), atol=1e-9)
