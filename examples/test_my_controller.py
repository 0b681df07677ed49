"""Testing your own code against lde: a crosswind hold-assist controller and its tests.

``HoldAssist`` stands for *your* code: an ECU function that reads lde's ``LDE_Estimate`` from the
car's CAN bus and asks the MDPS for an overlay torque (``LDE_Overlay``, with its AUTOSAR E2E counter
and CRC) that holds the car straight against the estimated crosswind - instead of lde's own overlay
law. Its tests put it in closed loop with lde's vehicle simulator and lde's estimator service,
through lde's pytest plugin (the ``lde_bench`` fixture, installed with lde): one CAN bus, one
simulated clock, 12 s of driving in a few seconds, the same frames on every run.

    python -m pytest examples/test_my_controller.py
    python -m pytest examples/test_my_controller.py --lde-interface socketcan --lde-channel vcan0
"""

from __future__ import annotations

import can
import numpy as np

from lde.can.codec import MessageCodec, MessageEncoder
from lde.can.e2e import p01_check
from lde.can.profiles import load_profile
from lde.testing import STEP_S, Bench, Rank, assert_e2e_valid, assert_in_range, assert_periodic

# --------------------------------------------------------------------------- the user's controller


class HoldAssist:
    """Overlay torque ``T = -(gain_fw Fw + gain_mw Mw)`` from lde's estimate, while it is VALID and
    fresh; limited to +-``limit`` Nm and ``rate`` Nm/s; ramps out when the estimate stops.

    Call :meth:`step` periodically with the time [ns]; it reads the frames that arrived since the
    last call from ``bus`` and sends one ``LDE_Overlay`` frame.
    """

    GAIN_FW = 4.0e-3  # Nm per N of lateral disturbance force
    GAIN_MW = 2.5e-3  # Nm per Nm of disturbance yaw moment
    STALE_NS = 3 * 3_900_000  # an estimate older than three lde steps is not used

    def __init__(self, bus: can.BusABC, limit: float = 3.0, rate: float = 4.0) -> None:
        profile = load_profile("lde")
        self.bus = bus
        self.limit = limit  # Nm
        self.rate = rate  # Nm/s
        self.estimate = MessageCodec(profile, "LDE_Estimate")
        self.overlay = MessageEncoder(profile, "LDE_Overlay")  # fills Counter and CRC
        self.torque = 0.0  # Nm, the request sent last
        self.target = 0.0
        self.t_estimate: int | None = None  # when the last good estimate arrived [ns]
        self.t_last: int | None = None

    def step(self, t_ns: int) -> None:
        for msg in self.bus:
            data = bytes(msg.data)
            if msg.arbitration_id != self.estimate.frame_id or not p01_check(msg.arbitration_id, data):
                continue
            est = self.estimate.decode(data)
            valid = int(est["Status"]) & 1
            self.target = (
                -(self.GAIN_FW * est["LatForce"] + self.GAIN_MW * est["YawMoment"]) if valid else 0.0
            )
            self.t_estimate = t_ns
        if self.t_estimate is None or t_ns - self.t_estimate > self.STALE_NS:
            self.target = 0.0
        dt = 0.0 if self.t_last is None else (t_ns - self.t_last) * 1e-9
        self.t_last = t_ns
        target = float(np.clip(self.target, -self.limit, self.limit))
        self.torque += float(np.clip(target - self.torque, -self.rate * dt, self.rate * dt))
        active = int(self.torque != 0.0)
        self.bus.send(
            self.overlay.message({"OverlayTorque": self.torque, "Active": active, "State": 2 * active}, t_ns)
        )


# --------------------------------------------------------------------------- its tests


def drive(bench: Bench, with_assist: bool):
    """12 s at 100 km/h under the paper's light lateral load (2 m/s crosswind from the right, road
    bank -1..1 deg); lde estimates, the assist steers. Returns the simulator's truth from 4 s on
    (lde's estimate is valid after about 1 s, the assist has ramped in) and the assist."""
    sim = bench.simulator("light_load", seed=1, duration=12.0)
    bench.service(backend="float", drop=["LDE_Overlay"])  # lde's estimate only: the overlay is ours
    assist = None
    if with_assist:
        assist = HoldAssist(bench.bus("hold_assist"))
        bench.every(STEP_S, assist.step, rank=Rank.LATE)  # right after lde's step, every 3.9 ms
    bench.run()
    return sim.truth().window(4.0), assist


def test_hold_assist_relieves_the_driver(lde_bench):
    with Bench() as baseline:
        without, _ = drive(baseline, with_assist=False)
    with_assist, _ = drive(lde_bench, with_assist=True)
    held_without = np.abs(without["T_driver"]).mean()
    held_with = np.abs(with_assist["T_driver"]).mean()
    assert held_without > 0.5  # Nm: the load is worth relieving
    assert held_with < 0.3 * held_without
    assert np.abs(with_assist["y"]).max() < np.abs(without["y"]).max()  # and the car drifts less


def test_hold_assist_sends_a_protected_request_every_step(lde_bench):
    drive(lde_bench, with_assist=True)
    overlay = lde_bench.frames("LDE_Overlay")
    assert len(overlay) == len(lde_bench.frames("LDE_Estimate"))  # one answer per estimate
    assert_periodic(overlay)  # every 3.9 ms, exactly: the clock is simulated
    assert_e2e_valid(overlay)  # CRC right, counter +1 per frame
    assert_in_range(overlay, "OverlayTorque", -3.0, 3.0)
    torque = overlay.signal("OverlayTorque")
    assert np.abs(np.diff(torque)).max() <= 4.0 * STEP_S + 0.01  # Nm per step: the rate limit (+1 LSB)


def test_hold_assist_ramps_out_when_the_estimate_stops(lde_bench):
    _, assist = drive(lde_bench, with_assist=True)
    assert abs(assist.torque) > 0.5  # Nm, holding against the load at the end of the drive
    lde_bench.services[0].task.cancel()  # lde goes silent
    lde_bench.wait_for("LDE_Overlay", timeout_s=1.0, where=lambda f: f["OverlayTorque"] == 0.0)
    ramp = lde_bench.frames("LDE_Overlay").since(lde_bench.now_ns - 1_000_000_000).signal("OverlayTorque")
    assert np.abs(np.diff(ramp)).max() <= 4.0 * STEP_S + 0.01  # no step, a ramp
