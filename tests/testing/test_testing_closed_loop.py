"""lde.testing in closed loop: the simulator, the lde service and the user's code on one bench."""

from __future__ import annotations

import can
import numpy as np
import pytest

from lde.can.codec import MessageCodec, MessageEncoder
from lde.can.e2e import p01_check
from lde.can.profiles import load_profile
from lde.demo import run_closed_loop
from lde.params import load_vehicle
from lde.replay.replay import replay_log
from lde.testing import STEP_S, Bench, Rank, assert_e2e_valid, assert_periodic
from lde.units import STEP_NS
from vcan_sim.run import default_t0_ns, simulate


def test_bench_closed_loop_equals_the_demo_lockstep() -> None:
    """The bench's scheduler (frames released at their times) and ``lde demo``'s lockstep loop (a
    period's frames sent at its start) give the same service outputs, step for step."""
    demo = run_closed_loop("wind_step", seed=3, duration=8.0, backend="float")
    with Bench(start_ns=default_t0_ns(3)) as bench:
        bench.simulator("wind_step", seed=3, duration=8.0)
        svc = bench.service(backend="float")
        bench.run()
    assert len(svc.results) == demo.steps == 2052
    np.testing.assert_array_equal(svc.series("t_ns"), demo.series["t_ns"])
    np.testing.assert_array_equal(svc.series("status"), demo.series["status"])
    np.testing.assert_array_equal(svc.series("fw"), demo.series["fw_hat"])
    np.testing.assert_array_equal(svc.series("mw"), demo.series["mw_hat"])
    np.testing.assert_array_equal(svc.series("t_overlay"), demo.series["t_overlay"])
    assert np.abs(svc.series("t_overlay")).max() > 1.0  # the loop was closed


def _frames(bench: Bench) -> list[tuple[int, int, bytes]]:
    out = []
    for i in (0x2A0, 0x2A8, 0x3D0, 0x3D1, 0x3D2):
        fl = bench.frames(i)
        out += [(int(t), i, bytes(d)) for t, d in zip(fl.t_ns, fl.data, strict=True)]
    return sorted(out)


def test_same_seed_same_frames_and_open_loop_equals_the_fast_path() -> None:
    runs = []
    for seed in (4, 4, 5):
        with Bench() as bench:
            bench.simulator("gusty_wind", seed=seed, duration=3.0, overlay=None)
            bench.run()
            runs.append((_frames(bench), bench.t0_ns))
    assert runs[0] == runs[1]
    assert runs[0][0] != runs[2][0]
    fast = simulate("gusty_wind", seed=4, duration=3.0, t0_ns=runs[0][1]).frames
    expect = sorted((int(fast.t_ns[k]), int(fast.can_id[k]), bytes(fast.data[k])) for k in range(len(fast)))
    assert runs[0][0] == expect


class ConstantOverlay:
    """A user's controller: requests ``torque`` Nm from 1 s on through LDE_Overlay (E2E by lde.can.codec)."""

    def __init__(self, bus: can.BusABC, torque: float) -> None:
        self.bus = bus
        self.torque = torque
        self.enc = MessageEncoder(load_profile("lde"), "LDE_Overlay")
        self.t0: int | None = None

    def step(self, t_ns: int) -> None:
        self.t0 = t_ns if self.t0 is None else self.t0
        on = t_ns - self.t0 >= 1_000_000_000
        vals = {"OverlayTorque": self.torque if on else 0.0, "Active": int(on)}
        self.bus.send(self.enc.message(vals, t_ns))


def test_the_users_controller_replaces_lde_overlay() -> None:
    with Bench() as bench:
        sim = bench.simulator("straight", seed=1, duration=3.0)
        svc = bench.service(backend="float", drop=["LDE_Overlay"])
        ctrl = ConstantOverlay(bench.bus("controller"), 1.5)
        bench.every(STEP_S, ctrl.step)
        bench.run()
        overlay = bench.frames("LDE_Overlay")
        assert svc.bus.dropped == len(svc.results) > 700  # lde's overlay never reached the bus
        assert len(overlay) == len(svc.results)  # only the controller's
        assert_e2e_valid(overlay)
        assert_periodic(overlay)
        st = sim.overlay_stats
        assert st is not None and st.rejected == 0
        assert st.received == len(overlay) - 1  # the last one was sent after the plant's last period
        assert st.used >= st.received - 2  # all but the frames before the MDPS's receiver trusts them
        truth = sim.truth()
        assert np.abs(truth.window(0.0, 1.0)["T_overlay"]).max() == 0.0
        assert truth.window(2.0)["T_overlay"].mean() == pytest.approx(1.5, abs=0.02)


def test_an_ecu_model_applies_the_overlay_request() -> None:
    """The user's MDPS model (the simulator's ``overlay=`` callable) applies half of lde's request."""
    with Bench() as bench:
        mdps_bus = bench.bus("my_mdps")
        codec = MessageCodec(bench.profile, "LDE_Overlay")
        applied: list[float] = []
        state = {"request": 0.0}

        def my_mdps(t_ns: int) -> float:
            for msg in mdps_bus:
                if msg.arbitration_id == codec.frame_id and p01_check(codec.frame_id, bytes(msg.data)):
                    sig = codec.decode(bytes(msg.data))
                    state["request"] = sig["OverlayTorque"] if sig["Active"] else 0.0
            applied.append(0.5 * state["request"])
            return applied[-1]

        sim = bench.simulator("wind_step", seed=2, duration=9.0, overlay=my_mdps)
        svc = bench.service(backend="float")
        bench.run()
    assert sim.overlay_stats is None
    req = svc.series("t_overlay")
    assert len(applied) == sim.steps == len(req)
    # one period later, at the signal's 0.01 Nm resolution
    np.testing.assert_allclose(applied[1:], 0.5 * np.round(req[:-1], 2), rtol=0, atol=1e-12)
    truth = sim.truth().window(7.0)
    assert abs(truth["T_overlay"].mean()) > 0.5
    assert truth["T_overlay"].mean() == pytest.approx(0.5 * req[-500:].mean(), rel=0.05)


@pytest.mark.lde_sim(scenario="wind_step", seed=2, duration=9.0)
@pytest.mark.lde_service(backend="float")
def test_fixtures_close_the_loop_and_the_estimate_tracks_the_truth(lde_bench, lde_sim, lde_service) -> None:
    lde_bench.run()
    st = lde_sim.overlay_stats
    assert st is not None and st.rejected == 0 and st.used >= lde_sim.steps - 3  # closed loop
    truth = lde_sim.truth()
    t = lde_service.series("t_ns")
    fw = lde_service.series("fw")
    late = t >= lde_sim.t0_ns + 7_000_000_000  # the 12 m/s crosswind has been on for 2 s
    fw_true = np.interp(t[late], truth.t_ns, truth["Fw"])
    assert np.all(lde_service.series("status")[late] & 1)  # VALID
    assert abs(fw_true.mean()) > 500.0  # N
    assert np.sqrt(np.mean((fw[late] - fw_true) ** 2)) < 0.15 * abs(fw_true.mean())
    assert lde_sim.truth().at(int(t[-1]))["vx"] == pytest.approx(100 / 3.6, rel=0.02)


def test_user_code_and_handlers_run_the_same_every_time() -> None:
    def run() -> tuple[list, list]:
        with Bench() as bench:
            bench.simulator("gusty_wind", seed=7, duration=2.0)
            svc = bench.service(backend="fixed")
            ctrl = ConstantOverlay(bench.bus("late"), -0.4)
            bench.every(0.010, ctrl.step, phase_s=0.0013, rank=Rank.LATE)
            echo = bench.bus("echo")
            bench.on_frame(
                "LDE_Estimate",
                lambda f: echo.send(can.Message(arbitration_id=0x6E0, data=f.data, is_extended_id=False)),
                bus=echo,
            )
            bench.run()
            return _frames(bench) + [(0, 0, bytes(bench.frames(0x6E0).data.tobytes()))], [
                (r.t_ns, r.fw, r.mw, r.t_overlay, r.status) for r in svc.results
            ]

    assert run() == run()


def test_a_recorded_bench_run_replays_exactly(tmp_path) -> None:
    path = tmp_path / "bench.mcap"
    with Bench() as bench:
        bench.simulator("light_load", seed=1, duration=4.0)
        svc = bench.service(backend="float", record=path)
        bench.run()
    _, res = replay_log(path, load_profile("lde"), load_vehicle("reference"), backend="float")
    np.testing.assert_array_equal(res.t_ns, svc.series("t_ns"))
    np.testing.assert_array_equal(res.fw, svc.series("fw"))
    np.testing.assert_array_equal(res.t_overlay, svc.series("t_overlay"))
    assert np.diff(res.t_ns).max() == STEP_NS
