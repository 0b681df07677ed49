"""The real-time pump never waits for another process (it may run at a real-time priority on a CPU
it shares with the service it feeds): it sleeps until its next frame, uses the overlay frames that
have arrived, and, behind schedule, neither bursts nor holds the CPU (docs/overlay.md, UML notes)."""

from __future__ import annotations

import time

import can
import numpy as np

from lde.frames import FrameBatch
from lde.profiles import load_profile
from lde.units import STEP_NS
from vcan_sim.closed_loop import OverlayReceiver
from vcan_sim.emitter import MAX_BUSY_S, MAX_LAG_S, pump
from vcan_sim.run import Simulation


def test_closed_loop_without_a_service_keeps_real_time_on_the_last_request():
    """Nobody answers: every step after the first runs on the last overlay request (counted), and the
    pump keeps its schedule instead of waiting for a frame."""
    with can.Bus(interface="virtual", channel="lde-pacing-no-service") as bus:
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


class _SlowSim:
    """A stand-in simulation whose step costs ``cost_s`` of CPU, one frame per 3.9 ms step."""

    def __init__(self, n_steps: int, cost_s: float) -> None:
        self.t0_ns = 1_700_000_000 * 1_000_000_000
        self.k = 0
        self.n_steps = n_steps
        self.cost_s = cost_s

    @property
    def t_ns(self) -> int:
        return self.t0_ns + self.k * STEP_NS

    @property
    def done(self) -> bool:
        return self.k >= self.n_steps

    def step(self, overlay_request: float | None = None) -> FrameBatch:
        t_ns = self.t_ns
        end = time.thread_time() + self.cost_s
        while time.thread_time() < end:  # burn CPU, as a slow guest does
            pass
        self.k += 1
        return FrameBatch(
            t_ns=np.array([t_ns], np.int64),
            can_id=np.array([0x2A0], np.uint32),
            is_extended=np.zeros(1, bool),
            dlc=np.array([8], np.uint8),
            data=np.zeros((1, 8), np.uint8),
            is_rx=np.ones(1, bool),
        )


def test_a_simulator_slower_than_real_time_leaves_half_the_cpu():
    """Each step costs two periods of CPU: the pump falls behind, moves its schedule instead of
    bursting, and sleeps as long as it ran after each period of work, so it takes at most about half
    of the CPU (what a SCHED_FIFO simulator leaves to the service below it on one CPU)."""
    sim = _SlowSim(n_steps=60, cost_s=2 * STEP_NS * 1e-9)
    with can.Bus(interface="virtual", channel="lde-pacing-slow") as bus:
        cpu0, t0 = time.process_time(), time.monotonic()
        st = pump(sim, bus, realtime=True, closed_loop=False)
        cpu, wall = time.process_time() - cpu0, time.monotonic() - t0
    assert st.sent == 60
    assert st.slips > 0 and st.slipped_s > MAX_LAG_S
    assert st.max_late_s <= MAX_LAG_S
    assert st.yields > 0 and st.yield_s >= st.yields * MAX_BUSY_S
    # CPU over wall: at most 1/2 by construction (+ the sleeps' own overhead); 0.65 leaves room for
    # the pump's bookkeeping, a busy host only lowers it
    assert cpu / wall < 0.65, f"the pump took {100 * cpu / wall:.0f} % of a CPU while behind"
