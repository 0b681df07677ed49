"""Injected bus faults: what the E2E receiver sees, on both paths, and the --fault option."""

from __future__ import annotations

import numpy as np
import pytest

from lde.can.e2e import check_batch, read_counter_batch
from lde.can.profiles import load_profile
from lde.cli import main
from lde.errors import ConfigError
from vcan_sim.faults import Fault, FaultKind, hit_mask, parse_fault
from vcan_sim.run import Simulation, scenario_with, simulate
from vcan_sim.scenarios import Step

MDPS_PERIOD = 3_900_000


def _mdps(res):
    prof = load_profile("lde")
    spec = prof.spec("MDPS_Sensors")
    sel = res.frames.select(res.frames.can_id == spec.frame_id)
    return sel, spec


def test_each_fault_kind_on_the_frames():
    base = scenario_with("straight", wind_speed=(Step(1.0, 1.0, 5.0),), duration=6.0)
    faults = (
        Fault(FaultKind.DROP, "mdps", 1.0, 0.39, every=2),  # 100 frames in the window, 50 dropped
        Fault(FaultKind.CORRUPT, "MDPS_Sensors", 2.0, 0.0195),  # 5 frames
        Fault(FaultKind.REPEAT, "mdps", 3.0, 0.0117),  # 3 frames
        Fault(FaultKind.SILENCE, "esc", 4.0, 0.1),  # 10 ESC frames
    )
    clean = simulate(base, seed=1)
    res = simulate(scenario_with(base, faults=faults), seed=1)
    sel, spec = _mdps(res)
    sel0, _ = _mdps(clean)
    assert len(sel0) - len(sel) == 50
    ok = check_batch(spec.scheme, spec.frame_id, sel.data, spec.length)
    assert (~ok).sum() == 5
    bad_t = (sel.t_ns[~ok] - res.t0_ns) * 1e-9
    assert np.all((bad_t >= 2.0) & (bad_t < 2.0195))
    ctr = read_counter_batch(spec.scheme, sel.data)
    t_rel = sel.t_ns - res.t0_ns
    rep = (t_rel >= 3_000_000_000) & (t_rel < 3_011_700_000)
    assert rep.sum() == 3
    first = np.flatnonzero(rep)[0]
    assert np.all(ctr[rep] == ctr[first - 1])  # the frame before the window, sent again
    assert np.all(sel.data[rep] == sel.data[first - 1])
    esc = res.frames.select(res.frames.can_id == load_profile("lde").spec("ESC_Motion").frame_id)
    esc0 = clean.frames.select(clean.frames.can_id == load_profile("lde").spec("ESC_Motion").frame_id)
    assert len(esc0) - len(esc) == 10
    # the plant does not know about the bus
    np.testing.assert_array_equal(res.truth["Fw"], clean.truth["Fw"])


def test_faults_identical_on_step_path():
    fast = simulate("bus_faults", seed=2, duration=16.0)
    sim = Simulation("bus_faults", seed=2, duration=16.0)
    while not sim.done:
        sim.step()
    assert np.array_equal(sim.frames().data, fast.frames.data)
    assert np.array_equal(sim.frames().t_ns, fast.frames.t_ns)


def test_hit_mask_every():
    t = np.arange(0, 1_000_000_000, 10_000_000, dtype=np.int64)
    m = hit_mask(Fault(FaultKind.DROP, "esc", 0.1, 0.1, every=3), t)
    assert m.sum() == 3 and list(np.flatnonzero(m)) == [12, 15, 18]


def test_parse_fault_and_cli(tmp_path):
    f = parse_fault("drop:mdps:5:2:4")
    assert f == Fault(FaultKind.DROP, "mdps", 5.0, 2.0, 4)
    for bad in ("drop:mdps:5", "explode:mdps:1:1", "drop:mdps:x:1", "drop:mdps:1:0"):
        with pytest.raises(ConfigError):
            parse_fault(bad)
    log = tmp_path / "f.log"
    assert (
        main(
            [
                "sim",
                "--scenario",
                "straight",
                "--duration",
                "2",
                "--fault",
                "silence:mdps:1:0.5",
                "--log",
                str(log),
            ]
        )
        == 0
    )
    assert (
        main(
            [
                "sim",
                "--scenario",
                "straight",
                "--duration",
                "2",
                "--fault",
                "drop:nowhere:1:1",
                "--log",
                str(log),
            ]
        )
        == 2
    )
