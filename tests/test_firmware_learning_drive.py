"""fixed vs float where both learn: the zoo drive on which their Mw moved apart (issue 11,
docs/firmware_lateral.md "Fixed vs float while the learners learn").

On the zoo's suv_slow, heavy_load, spec sheet only (cold), the two backends' Mw differ by up to
0.070 Nm (0.136 Nm with ``L_WIND_Q`` before ``L_R2_UPQ``, 0.027 Nm before both). The integer step is
not the cause: its own shadow (the float step on the fixed learner's parameters) stays within
0.011 Nm. Each backend runs its own learner on its own filter's wind estimate, and ``L_WIND_Q`` makes
R1's and R2's gains depend on the square of that estimate's band-passed change (``L_R2_UPQ``: R2's
on the pushes' changes of K and the trail): the integer filter's F_wind (within 0.1 N of the float
one's) moves Cf, Cr, K by 1-2.5e-5 relative, and Mw, which closes the yaw balance over kN of tire
force, by 0.1 Nm. The tests pin that split: the integer step tight on the same parameters, the
learners on the same branches and within a relative 1e-4, the rest of the Mw difference set by
``L_WIND_Q`` and ``L_R2_UPQ``.
"""

from __future__ import annotations

import tempfile

import numpy as np
import pytest

from lde.analysis.study.execute import load_sim_vehicle, simulate_run
from lde.analysis.study.spec import SPEC_SHEET, RunSpec
from lde.analysis.study.specsheet import spec_sheet_vehicle
from lde.can.profiles import load_profile
from lde.engine.backends.fixed import SH_COUNT, SH_MAX_DFW, SH_MAX_DMW
from lde.engine.engine import Engine
from lde.estimator import lateral as E
from lde.estimator import learner as Ln

PLANT, SCENARIO = "zoo:suv_slow", "heavy_load"


@pytest.fixture(scope="module")
def drive():
    vehicle = spec_sheet_vehicle(load_sim_vehicle(PLANT), tempfile.mkdtemp(prefix="lde-fxlearn-"))
    spec = RunSpec(scenario=SCENARIO, est_vehicle=SPEC_SHEET, sim_vehicle=PLANT, seed=0, profile="lde")
    return vehicle, simulate_run(spec, SCENARIO, 0).frames.sort()


def _run(drive, backend, wind_q=None, r2_upq=None):
    vehicle, frames = drive
    eng = Engine(load_profile("lde"), vehicle, backend, encode_outputs=False)
    lp = eng.est.params.lp
    if wind_q is not None:
        lp[Ln.L_WIND_Q] = wind_q
    if r2_upq is not None:
        lp[Ln.L_R2_UPQ] = r2_upq
    block = eng.feed(frames, final=True)
    return block, eng.est


@pytest.fixture(scope="module")
def runs(drive):
    return {b: _run(drive, b) for b in ("fixed", "float")}


def test_the_drive_learns_in_a_varying_wind(runs):
    """What makes the drive the one that shows it: the learner learns (cold, 522 excited samples), in
    a wind of kN."""
    block, est = runs["float"]
    assert est.state.ls[Ln.LS_STATE] != Ln.ST_NOT
    assert est.state.ls[Ln.LS_N] > 300
    assert np.nanmax(np.abs(block.fw_wind)) > 2000.0


def test_the_integer_step_tracks_its_shadow_tightly(runs):
    """On the same parameters (the shadow) the integer step stays at its design agreement while the
    learner re-quantises the coefficient set every 0.5 s: 0.095 N / 0.011 Nm measured (26 reference
    scenarios: 0.030 N / 0.013 Nm), bound 0.2 N / 0.05 Nm (the product check is 5 N / 2 Nm)."""
    _, est = runs["fixed"]
    sh = est.state.shadow_counts
    assert sh[SH_COUNT] == 0
    assert sh[SH_MAX_DFW] <= 0.2
    assert sh[SH_MAX_DMW] <= 0.05


def test_the_learners_take_the_same_branches(runs):
    """The two learners see the same gates (the same excited-sample counts, the same learned state at
    every step) and their parameters differ by less than 1e-4 relative (2.5e-5 measured): a gate
    decided differently or a push at another step moves a tire by up to 2 % (the push rate limit)."""
    (bx, ix), (bf, jf) = runs["fixed"], runs["float"]
    lx, lf = ix.state.ls, jf.state.ls
    for slot in (Ln.LS_N, Ln.LS_N + 1, Ln.LS_N + 2, Ln.LS_STATE):
        assert lx[slot] == lf[slot], slot
    np.testing.assert_array_equal(bx.learn_state, bf.learn_state)
    for slot in (E.P_CF, E.P_CR, E.P_K, E.P_S):
        assert ix.state.p[slot] == pytest.approx(jf.state.p[slot], rel=1e-4), slot


def test_the_backends_mw_difference_is_set_by_the_wind_onset_noise(drive, runs):
    """Between the backends Mw differs by 0.070 Nm at most with the default ``L_WIND_Q`` and
    ``L_R2_UPQ`` (0.136 with ``L_WIND_Q`` alone; bound 0.5); with both off in both learners by 0.027
    Nm (bound 0.06), the size before them (each alone off: 0.070 and 0.136 Nm: R2's forgetting also
    scales its gain by the pushes' changes, which differ by 1e-5 between the backends). The difference
    above the shadow's is the learners' (module docstring)."""
    dmw = np.nanmax(np.abs(runs["fixed"][0].mw - runs["float"][0].mw))
    assert dmw <= 0.5
    off = [_run(drive, b, wind_q=0.0, r2_upq=0.0)[0] for b in ("fixed", "float")]
    dmw0 = np.nanmax(np.abs(off[0].mw - off[1].mw))
    assert dmw0 <= 0.06
