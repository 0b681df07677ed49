"""Closed loop with the real lde service (lockstep on python-can's virtual bus, simulated clock)."""

from __future__ import annotations

import can
import numpy as np
import pytest

from vcan_sim.closed_loop import OverlayReceiver, run_lockstep
from vcan_sim.run import Simulation


def _run(overlay: bool, duration: float = 9.0):
    service_mod = pytest.importorskip("lde.service.service")
    clock_mod = pytest.importorskip("lde.clock")
    ch = f"vcan_sim_lockstep_{overlay}"
    with (
        can.Bus(interface="virtual", channel=ch, preserve_timestamps=True) as sim_bus,
        can.Bus(interface="virtual", channel=ch, preserve_timestamps=True) as lde_bus,
    ):
        sim = Simulation("wind_step", seed=0, duration=duration)
        clock = clock_mod.SimulatedClock(sim.t0_ns)
        svc = service_mod.Service(
            lde_bus, "lde", None, clock, backend="float", overlay_enabled=overlay, log_period_s=0
        )

        def step(t_k: int) -> None:
            clock.sleep_until(t_k)
            svc.step_once(t_k)

        st = run_lockstep(sim, sim_bus, OverlayReceiver(sim.profile), step)
    return sim.result().truth, st


def test_service_overlay_relieves_the_driver_in_closed_loop():
    off, _ = _run(False)
    on, st = _run(True)
    assert st.overlay_frames >= st.steps - 2  # one LDE_Overlay per step came back and passed E2E
    t = off["t"] - off["t"][0]
    gust = t > 7.0  # the 12 m/s crosswind is on from 5 s
    assert np.abs(off["T_overlay"][gust]).max() == 0.0
    assert np.abs(on["T_overlay"][gust]).mean() > 1.0  # the request reached the motor
    # same sign as the holding torque (the driver steers right against wind from the right)
    assert np.sign(on["T_overlay"][gust].mean()) == np.sign(off["T_column"][gust].mean())
    assert np.abs(on["T_column"][gust]).mean() < 0.85 * np.abs(off["T_column"][gust]).mean()
