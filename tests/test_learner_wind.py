"""lde.estimator.learner in a crosswind slalom on a zoo plant (issue 11, docs/estimator.md "The wind's
onset").

A crosswind that starts while the car weaves steps R1's intercept (``c1 = lr F_wind/s + M_wind``) by
about 2 kNm within a second and then varies with the heading in every weave; an intercept that is a
slow random walk cannot follow, and the regression fits the rest into the trail (Cf). The learner's
intercept process noise grows with the change the filter's wind estimate shows (``L_WIND_Q``), so the
tires learned on a prior drive stay where they were. The plant is vcan_sim's (aero forces that depend
on the heading and the body's sideslip), not a linear truth: there the onset alone leaves the tires
within 1 %, with or without it.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest

from lde.analysis.study.execute import load_sim_vehicle, simulate_run
from lde.analysis.study.spec import SPEC_SHEET, RunSpec
from lde.analysis.study.specsheet import spec_sheet_vehicle
from lde.can.profiles import load_profile
from lde.engine.engine import Engine
from lde.estimator import lateral as E
from lde.estimator import learner as Ln

PLANT = "zoo:indep_twin"


def _frames(scenario: str, seed: int):
    spec = RunSpec(scenario=scenario, est_vehicle=SPEC_SHEET, sim_vehicle=PLANT, seed=seed, profile="lde")
    return simulate_run(spec, scenario, seed).frames.sort()


def _run(vehicle, frames, learned_in, learned_out, wind_q, low_tier=True):
    eng = Engine(load_profile("lde"), vehicle, "float", encode_outputs=False)
    lp, p = eng.est.params.lp, eng.est.state.p
    if not low_tier:  # the steering gate without its low-rate tier (L_EXC_SW2), as before issue 11's fix
        lp[Ln.L_EXC_SW2] = -1.0
    if learned_in is not None:
        eng.load_learned(learned_in)
    lp[Ln.L_WIND_Q] = wind_q
    p_start = p.copy()
    eng.feed(frames, final=True)
    if learned_out is not None:
        eng.save_learned(learned_out, 1.0)
    return p_start, p.copy()


@pytest.fixture(scope="module")
def warm():
    """The spec-sheet vehicle and the state learned on a prior drive (default constants)."""
    tmp = Path(tempfile.mkdtemp(prefix="lde-wind-"))
    vehicle = spec_sheet_vehicle(load_sim_vehicle(PLANT), str(tmp))
    learned = tmp / "learned.json"
    prior = _frames("prior_drive", 500)
    _run(vehicle, prior, None, learned, Ln.default_lp()[Ln.L_WIND_Q])
    # the same prior drive without the steering gate's low-rate tier: the car ends it 'learning'
    # (521 samples), not 'learned' (1929 with the tier at 500 N), so the slalom's wind can still move
    # its tires
    learning = tmp / "learning.json"
    _run(vehicle, prior, None, learning, Ln.default_lp()[Ln.L_WIND_Q], low_tier=False)
    return vehicle, learned, learning, _frames("slalom", 0)


def test_the_slalom_in_a_crosswind_keeps_the_learned_tires(warm):
    """Default: Cf, Cr, K move less than 3 % during the 40 s slalom (10 m/s crosswind from 12 s);
    without the intercept noise (``L_WIND_Q`` 0, the learner before) Cf falls by more than 6 %
    (-11 % measured). The counterfactual needs a car still 'learning' after its prior drive: with the
    steering gate's low-rate tier the prior drive makes it 'learned' (1000x slower), and without the
    intercept noise Cf then falls by a few % only (2.6 % with the tier at 500 N); so both are checked
    on the prior learned without the tier (-0.7 % and -11 %), the first also on the default prior."""
    vehicle, learned, learning, frames = warm
    for state in (learned, learning):
        p0, p = _run(vehicle, frames, state, None, Ln.default_lp()[Ln.L_WIND_Q])
        for slot in (E.P_CF, E.P_CR, E.P_K):
            assert p[slot] == pytest.approx(p0[slot], rel=0.03), slot
    p0, p = _run(vehicle, frames, learning, None, 0.0, low_tier=False)
    assert p[E.P_CF] < 0.94 * p0[E.P_CF]
