"""``--learned FILE`` live (``lde run``): read at the start, written every 60 s of step time from a
writer thread and once more at the end; the live service learns exactly what a replay of its
recording learns (one data path)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from lde.can.frames import FrameBatch
from lde.errors import ConfigError
from lde.estimator.learned import LearnedKeeper, LearnedSnapshot
from lde.params import load_vehicle
from lde.replay.replay import read_inputs, replay, replay_log
from lde.status import Status
from lde.testing import Bench
from lde.units import STEP_NS, STEP_S


def _wait_for(path: Path, timeout_s: float = 30.0) -> dict:
    """The file's JSON once the writer thread has put it there."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if path.exists():
            return json.loads(path.read_text())
        time.sleep(0.05)
    raise AssertionError(f"{path} was not written within {timeout_s} s")


def test_live_writes_every_60_s_and_at_the_end_and_equals_replay(tmp_path, lde_bench: Bench) -> None:
    learned, rec = tmp_path / "car.learned", tmp_path / "run.mcap"
    lde_bench.simulator("prior_drive")
    svc = lde_bench.service(backend="float", learned=learned, record=rec)
    lde_bench.run(59.0)
    time.sleep(0.2)
    assert not learned.exists()  # nothing due before 60 s of step time
    lde_bench.run(2.0)
    periodic = _wait_for(learned)
    assert periodic["drives"] == 1 and 0 < periodic["seconds"] <= 61.0
    lde_bench.run(10.0)
    svc.close()
    final = json.loads(learned.read_text())
    assert final["drives"] == 1 and final["seconds"] > periodic["seconds"]
    assert final["seconds"] == pytest.approx(svc.service.valid_steps * STEP_NS * 1e-9)
    assert final["learner"] != periodic["learner"]  # the learner moved on after the periodic write

    # the recording replayed with a fresh learned file learns the same, bit for bit
    again = tmp_path / "replayed.learned"
    replay_log(rec, None, load_vehicle("reference"), backend="float", learned=again)
    got = json.loads(again.read_text())
    assert got["params"] == final["params"]
    assert got["learner"] == final["learner"]
    assert got["seconds"] == final["seconds"]


def test_live_starts_from_the_file_and_counts_the_drive(tmp_path, lde_bench: Bench) -> None:
    learned = tmp_path / "car.learned"
    lde_bench.simulator("lane_change", duration=8.0)
    first = lde_bench.service(backend="float", learned=learned)
    lde_bench.run()
    first.close()
    doc = json.loads(learned.read_text())
    assert doc["drives"] == 1
    doc["params"]["cf_N_per_rad"] = 61234.0  # a value the vehicle file does not have
    learned.write_text(json.dumps(doc))

    rec = tmp_path / "warm.mcap"
    with Bench() as bench:
        bench.simulator("lane_change", duration=4.0)
        svc = bench.service(backend="float", learned=learned, record=rec)
        from lde.estimator import lateral as E

        assert svc.service.engine.est.state.p[E.P_CF] == 61234.0
        assert svc.service.engine.learned_from is not None
        bench.run()
        svc.close()
    again = json.loads(learned.read_text())
    assert again["drives"] == 2
    assert again["seconds"] > doc["seconds"]

    # the recording keeps the learned start: replayed without --learned it gives the live estimates
    vehicle = load_vehicle("reference")
    _, res = replay_log(rec, None, vehicle, backend="float")
    np.testing.assert_array_equal(res.fw, svc.series("fw"))
    np.testing.assert_array_equal(res.mw, svc.series("mw"))
    # ... which a replay from the vehicle file does not (the check above can fail)
    li = read_inputs(rec, None)
    assert li.learned_start is not None and json.loads(li.learned_start)["params"]["cf_N_per_rad"] == 61234.0
    with li.stream as stream:  # the log's frames, piece by piece in time order
        frames = FrameBatch.concat(list(stream), sort=False)
    cold = replay(frames, li.profile, vehicle, "float", step_times_ns=li.step_times_ns)
    assert not np.array_equal(cold.fw, res.fw)


def test_learned_needs_a_learning_backend_and_the_same_car(tmp_path, lde_bench: Bench) -> None:
    learned = tmp_path / "car.learned"
    with pytest.raises(ConfigError, match="does not learn"):
        lde_bench.service(backend="paper", learned=learned)
    lde_bench.simulator("straight", duration=2.0)
    svc = lde_bench.service(backend="float", learned=learned)
    lde_bench.run()
    svc.close()
    with pytest.raises(ConfigError, match="learned for another vehicle"):
        lde_bench.service(backend="float", learned=learned, vehicle="est2")


def _snap(seconds: float) -> LearnedSnapshot:
    from lde.estimator import lateral as E
    from lde.estimator import learner as Ln

    p = E.params_vector(load_vehicle("reference"))
    return LearnedSnapshot("reference", "lde", p, np.zeros(Ln.N_LS), 1, seconds)


def test_keeper_period_and_failures(tmp_path) -> None:
    k = LearnedKeeper(tmp_path / "s.learned", 60 * 10**9)
    try:
        t0 = 1_700_000_000 * 10**9
        assert not k.due(t0)  # the first step starts the period
        assert not k.due(t0 + 59 * 10**9)
        assert k.due(t0 + 60 * 10**9)
        assert not k.due(t0 + 61 * 10**9)
        assert k.due(t0 + 250 * 10**9)  # a long gap: one write, the next period after it
        assert not k.due(t0 + 299 * 10**9) and k.due(t0 + 300 * 10**9)
        k.offer(_snap(1.0))
        assert _wait_for(tmp_path / "s.learned")["seconds"] == 1.0
    finally:
        k.close(_snap(2.0))
    assert json.loads((tmp_path / "s.learned").read_text())["seconds"] == 2.0

    bad = LearnedKeeper(tmp_path / "missing-dir" / "s.learned", 10**9)
    bad.offer(_snap(1.0))
    deadline = time.monotonic() + 30
    while bad.errors == 0 and time.monotonic() < deadline:  # a periodic failure: logged and counted
        time.sleep(0.01)
    assert bad.errors == 1
    with pytest.raises(ConfigError, match="cannot write"):  # the final one: the caller hears of it
        bad.close(_snap(2.0))


def test_overlay_law_uses_the_learned_tires(tmp_path) -> None:
    """The overlay's holding-torque gain K / (N Cf L) comes from the backend's current (learned)
    tires: a learned file with Cf doubled halves the gain, and in ACTIVE steady state the request
    follows -g (lr Fw + Mw) with that gain, not with the vehicle file's."""
    from lde.can.profiles import load_profile
    from lde.estimator import lateral as E
    from lde.estimator.outputs import O_GAIN
    from lde.estimator.overlay import OverlayState, feedforward_gain
    from vcan_sim.run import simulate

    vehicle = load_vehicle("reference")
    frames = simulate("light_load", seed=3, duration=12.0).frames  # below the torque limit
    profile = load_profile("lde")
    base = tmp_path / "base.learned"
    replay(frames, profile, vehicle, "float", learned=base)  # writes a file with the car's values
    doc = json.loads(base.read_text())
    cf0 = doc["params"]["cf_N_per_rad"]
    doc["params"]["cf_N_per_rad"] = 2.0 * cf0
    stiff = tmp_path / "stiff.learned"
    stiff.write_text(json.dumps(doc))

    cold = replay(frames, profile, vehicle, "float")
    warm = replay(frames, profile, vehicle, "float", learned=stiff)
    g_cold, g_warm = cold.block.est[:, O_GAIN], warm.block.est[:, O_GAIN]
    p = E.params_vector(vehicle)
    assert g_cold[0] == pytest.approx(p[E.P_K] / (p[E.P_N] * p[E.P_CF] * (p[E.P_LF] + p[E.P_LR])), rel=1e-12)
    assert g_cold[0] == pytest.approx(feedforward_gain(vehicle), rel=1e-9)  # both derivations agree
    k_ratio = doc["params"]["align_rate_Nm_per_rad"] / p[E.P_K]  # the file's K (not changed here)
    assert g_warm[0] == pytest.approx(g_cold[0] * k_ratio / 2.0, rel=1e-9)

    lr = vehicle.body.lr

    def law_input(res) -> np.ndarray:
        # the law's input low-pass (lde.estimator.overlay: backward Euler, tau = [overlay]
        # law_time_constant_s,
        # restarted while the estimate is not usable)
        tau, dt = vehicle.overlay.law_time, STEP_S
        moment = lr * res.fw + res.mw
        usable = (res.status & int(Status.VALID)) != 0
        m_f = np.empty_like(moment)
        for k in range(moment.size):
            if k == 0 or not usable[k]:
                m_f[k] = moment[k]
            else:
                m_f[k] = m_f[k - 1] + dt / (tau + dt) * (moment[k] - m_f[k - 1])
        return m_f

    for res, g in ((cold, g_cold), (warm, g_warm)):
        active = res.overlay_state == OverlayState.ACTIVE
        assert active.sum() > 500, "the scenario must bring the overlay into ACTIVE"
        demand = -g * law_input(res)
        lim = vehicle.overlay.max_torque
        inside = active & (np.abs(demand) < 0.9 * lim)
        err = np.abs(res.t_overlay[inside] - demand[inside])
        assert np.median(err) < 0.02, np.median(err)  # the rate limit lags by at most a step or two
    # ... and not with the vehicle file's gain (the check above can fail): with a doubled Cf the
    # filter explains the same measured aligning torque by a larger Fw, so the product -g (lr Fw + Mw)
    # stays near the holding torque only with the learned gain
    active = (warm.overlay_state == OverlayState.ACTIVE) & (np.abs(warm.t_overlay) < 0.9 * lim)
    wrong = -g_cold * law_input(warm)
    assert np.median(np.abs(warm.t_overlay[active] - wrong[active])) > 0.1
