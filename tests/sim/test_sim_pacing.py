"""The real-time pump never waits for another process (it may run at a real-time priority on a CPU
it shares with the service it feeds): it sleeps until its next frame, uses the overlay frames that
have arrived, and after a stall moves its schedule instead of sending a burst (docs/overlay.md,
"UML notes")."""

from __future__ import annotations

import time

import can
import numpy as np

from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.units import STEP_NS
from vcan_sim.closed_loop import OverlayReceiver
from vcan_sim.emitter import MAX_LAG_S, pump
from vcan_sim.run import Simulation


def test_closed_loop_without_a_service_keeps_real_time_on_the_last_request():
    """Nobody answers: every step after the first runs on the last overlay request (counted), and the
    pump keeps its schedule instead of waiting for a frame."""
    with can.Bus(interface="virtual", channel="lde-pacing-no-service") as bus:
        # compiled before the timed run: on a cold numba cache the first steps compile for seconds
        pump(Simulation("straight", seed=1, duration=0.02), bus, realtime=False, closed_loop=True)
        sim = Simulation("straight", seed=1, duration=0.5)
        rx = OverlayReceiver(load_profile("lde"))
        t0 = time.monotonic()
        st = pump(sim, bus, realtime=True, closed_loop=True, receiver=rx)
        wall = time.monotonic() - t0
    assert st.steps == sim.n_steps
    assert st.overlay_used == 0
    assert st.stale_overlay_steps == st.steps - 1
    assert st.sent > 0 and st.send_errors == 0
    # 0.5 s of traffic; a shared machine may add its own delays, a pump waiting for frames would not end
    assert 0.45 < wall < 5.0


class _StallingSim:
    """A stand-in simulation: one MDPS-like frame per 3.9 ms step; step ``stall_at`` stands still for
    ``stall_s`` (the guest stopped the process)."""

    def __init__(self, n_steps: int, stall_at: int, stall_s: float) -> None:
        self.t0_ns = 1_700_000_000 * 1_000_000_000
        self.k = 0
        self.n_steps = n_steps
        self.stall_at = stall_at
        self.stall_s = stall_s

    @property
    def t_ns(self) -> int:
        return self.t0_ns + self.k * STEP_NS

    @property
    def done(self) -> bool:
        return self.k >= self.n_steps

    def step(self, overlay_request: float | None = None) -> FrameBatch:
        t_ns = self.t_ns
        if self.k == self.stall_at:
            time.sleep(self.stall_s)
        self.k += 1
        return FrameBatch(
            t_ns=np.array([t_ns], np.int64),
            can_id=np.array([0x2A0], np.uint32),
            is_extended=np.zeros(1, bool),
            dlc=np.array([8], np.uint8),
            data=np.zeros((1, 8), np.uint8),
            is_rx=np.ones(1, bool),
        )


class _SendTimes(can.BusABC):
    """A bus that keeps the wall-clock time of every send."""

    def __init__(self) -> None:
        super().__init__(channel="send-times")
        self.sent: list[float] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append(time.monotonic())

    def _recv_internal(self, timeout: float | None):
        return None, False


def test_after_a_stall_the_schedule_moves_instead_of_a_burst():
    """A 100 ms stall: the frames after it keep their 3.9 ms spacing (the schedule slips by the
    stall, counted) instead of going out back to back to catch up."""
    sim = _StallingSim(n_steps=80, stall_at=20, stall_s=0.1)
    with _SendTimes() as bus:
        st = pump(sim, bus, realtime=True, closed_loop=False)
    assert st.sent == 80 and st.steps == 80
    # the stall slips the schedule once; a shared machine may add a slip of its own (> 11.7 ms late)
    assert st.slips >= 1
    assert 0.09 < st.slipped_s < 0.5
    assert st.max_late_s <= MAX_LAG_S
    after = np.asarray(bus.sent[21:])  # from the first frame after the stall
    # a burst would send the ~25 frames the stall held back within a few ms, so the 59 frames after it
    # would span about 34 periods; paced, they span 59 periods or more. A loaded machine that wakes the
    # pump late only stretches the span (its late frames then leave back to back), never shortens it.
    span = after[-1] - after[0]
    assert span >= 0.9 * (after.size - 1) * STEP_NS * 1e-9, np.round(np.diff(after) * 1e3, 2)
    assert st.wall_s > 80 * STEP_NS * 1e-9 + 0.09  # the traffic ended that much later


def test_spinning_pump_sends_no_frame_before_its_time_and_traces_every_send():
    """``spin_s``: sleep, then busy-wait to each frame's time. A frame never leaves before its
    scheduled time, and ``send_trace`` holds one (scheduled, before, after, id) row per frame sent,
    in order (no bound on lateness: the machine is shared)."""
    trace: list[tuple[int, int, int, int]] = []
    with can.Bus(interface="virtual", channel="lde-pacing-spin") as bus:
        sim = Simulation("straight", seed=1, duration=0.3)
        st = pump(sim, bus, realtime=True, closed_loop=False, spin_s=300e-6, send_trace=trace)
    t = np.array(trace, np.int64)
    assert t.shape == (st.sent, 4) and st.sent > 0
    assert np.all(t[:, 1] >= t[:, 0])  # never early
    assert np.all(t[:, 2] >= t[:, 1]) and np.all(np.diff(t[:, 0]) >= 0)
    assert set(t[:, 3].tolist()) == {m.frame_id for m in load_profile("lde").messages.values()}
