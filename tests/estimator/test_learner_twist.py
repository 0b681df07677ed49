"""The torsion twist's bound inside the learner's R3 regression (docs/design/filters.md, "Bounds and rate").

A twist is >= 0, and ``push`` clamps the filter's value there. R3 must hold the same bound, or its
other coefficients (s/K: the aligning slope, the friction) stay fitted to a negative twist the filter
never applies: on the zoo's profile ``lde`` (the pinion angle) that made K and Cf 10-13 % low.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.params import load_vehicle
from lde.units import DEG, STEP_S

from helpers.linear_truth import rig_on_truth, sense, weave

VX = 100.0 / 3.6
I_TB = Ln.LS_T3 + 4  # R3's twist coefficient s c_tb


def _spd(n: int, rng: np.random.Generator) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return a @ a.T + 0.1 * np.eye(n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_projection_is_the_gaussian_conditioned_on_the_bound(seed):
    """Outside the bound, theta moves to the mean of N(theta, P) given theta_i = bound (numpy's
    conditional mean); P is unchanged; inside the bound nothing moves."""
    rng = np.random.default_rng(seed)
    n, i = Ln.N3, 4
    P = _spd(n, rng)
    theta = rng.normal(size=n)
    for lo, hi, bound in (
        (theta[i] + 0.5, theta[i] + 2.0, theta[i] + 0.5),
        (-5.0, theta[i] - 0.3, theta[i] - 0.3),
    ):
        ls = np.zeros(Ln.N_LS)
        ls[Ln.LS_T3 : Ln.LS_T3 + n] = theta
        ls[Ln.LS_P3 : Ln.LS_P3 + n * n] = P.ravel()
        Ln._project_bound(ls, Ln.LS_T3, Ln.LS_P3, n, i, lo, hi)
        expect = theta + P[:, i] / P[i, i] * (bound - theta[i])
        np.testing.assert_allclose(ls[Ln.LS_T3 : Ln.LS_T3 + n], expect, rtol=1e-12, atol=1e-12)
        assert ls[Ln.LS_T3 + i] == bound
        np.testing.assert_array_equal(ls[Ln.LS_P3 : Ln.LS_P3 + n * n], P.ravel())
    ls = np.zeros(Ln.N_LS)
    ls[Ln.LS_T3 : Ln.LS_T3 + n] = theta
    ls[Ln.LS_P3 : Ln.LS_P3 + n * n] = P.ravel()
    Ln._project_bound(ls, Ln.LS_T3, Ln.LS_P3, n, i, theta[i] - 1.0, theta[i] + 1.0)
    np.testing.assert_array_equal(ls[Ln.LS_T3 : Ln.LS_T3 + n], theta)


def _learn_pinion(sig_ctb_deg: float, lag_twist_deg: float, seconds: float = 60.0):
    """Filter + learner on the linear truth of test_learner (Cf, Cr, K 15 % above the prior), the
    angle read below the torsion bar (the pinion: no twist), but lagging the road wheels by
    ``lag_twist_deg`` x T_col [deg/Nm] (a negative twist: what R3 saw on the zoo's pinion angles).
    Returns p and the smallest R3 twist coefficient seen."""
    veh = load_vehicle("reference")
    b = veh.body
    n_ratio = veh.steering.ratio
    p = E.params_vector(veh)
    lp = Ln.default_lp(torsion=False)
    lp[Ln.L_SIG_CTB] = sig_ctb_deg * DEG
    rig = rig_on_truth(veh, p, lp, (1.15, 1.15, 1.15))
    ls = rig.ls
    x = np.zeros(2)
    rng = np.random.default_rng(0)
    lowest = math.inf
    for i in range(int(seconds / STEP_S)):
        ti = i * STEP_S
        delta = weave(ti) / n_ratio
        ay, yaw, tcol, tast = sense(x, delta, b, rig.truth, rig.s, n_ratio, rng)
        angle = weave(ti) + lag_twist_deg * DEG * tcol
        rig.step(i, angle, yaw, tcol, tast, ay)
        lowest = min(lowest, ls[I_TB])
        x = rig.ad @ x + rig.bd * delta
    return p, lowest


def test_r3_keeps_the_twist_at_or_above_zero_and_learns_k_as_if_it_were_known():
    """An angle that wants a negative twist: R3's twist never goes below 0, and the aligning slope K
    it gives is the one R3 learns when the twist is known to be 0 (prior std 0) within 1 %. Without
    the bound R3 fits the negative twist, push clamps it to 0 for the filter, and K comes out off."""
    p_bound, lowest = _learn_pinion(sig_ctb_deg=0.3, lag_twist_deg=-0.4)
    p_known, _ = _learn_pinion(sig_ctb_deg=0.0, lag_twist_deg=-0.4)
    assert lowest >= 0.0
    assert p_bound[E.P_CTB] < 0.01 * DEG
    assert p_bound[E.P_K] == pytest.approx(p_known[E.P_K], rel=0.01)
    assert p_bound[E.P_CF] == pytest.approx(p_known[E.P_CF], rel=0.01)
