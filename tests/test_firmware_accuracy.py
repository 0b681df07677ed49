"""The check of issue 5: the fixed-point estimate stays within 5 N (Fw) and 2 Nm (Mw) of the
float filter (lde.estimator.paper) at every step, with the same status bits, and the shadow check that
flags and counts deviations (Status bit 6)."""

from __future__ import annotations

import numpy as np
import pytest

from firmware_model.fast import FastState, FixedEstimator, run_batch, run_batch_with_shadow, tables_vector
from firmware_model.shadow import (
    FW_BOUND_N,
    MW_BOUND_NM,
    SHADOW_DEVIATION,
    ShadowChecker,
    shadow_check,
)
from firmware_model.synthetic import make_drive
from firmware_model.tables import tables_for
from lde.estimator.paper import BatchResult, Estimator, Status
from lde.estimator.paper import run_batch as float_run_batch
from lde.params import load_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("reference")


@pytest.mark.parametrize("kind", ["sweep", "gusts", "steer", "faults"])
def test_fixed_within_bound_of_float_at_every_step(vehicle, kind):
    d = make_drive(vehicle, kind, duration_s=20.0, seed=11)
    state = FastState.initial(tables_vector(tables_for(vehicle)))
    fx = run_batch(*d.inputs(), vehicle, state=state)
    fl = float_run_batch(*d.inputs(), vehicle)
    dfw = np.abs(fx.fw - fl.fw)
    dmw = np.abs(fx.mw - fl.mw)
    assert dfw.max() <= FW_BOUND_N, f"max |dFw| {dfw.max():.3f} N at step {dfw.argmax()}"
    assert dmw.max() <= MW_BOUND_NM, f"max |dMw| {dmw.max():.3f} Nm at step {dmw.argmax()}"
    np.testing.assert_array_equal(fx.status, fl.status)
    # the other outputs too (T_align within 0.1 Nm, beta, r tight)
    assert np.max(np.abs(fx.t_align - fl.t_align)) < 0.1
    assert np.max(np.abs(fx.yaw_rate - fl.yaw_rate)) < 1e-4
    # nothing saturated inside the supported ranges
    assert sum(state.saturations().values()) == 0, state.saturations()
    # and the synthetic drive really exercised the filter: the estimate follows the truth
    valid = (fl.status & Status.VALID) > 0
    assert valid.sum() > 0.5 * len(d)


def test_shadow_check_flags_and_counts(vehicle):
    d = make_drive(vehicle, "gusts", duration_s=4.0, seed=2)
    fx, rep = run_batch_with_shadow(*d.inputs(), vehicle)
    assert rep.count == 0 and not rep.deviation.any()
    assert rep.max_dfw <= FW_BOUND_N and rep.max_dmw <= MW_BOUND_NM
    assert not (fx.status & SHADOW_DEVIATION).any()
    # a deviating fixed result: bit 6 set exactly on the deviating steps, counted
    bad = BatchResult(fx.t_ns, fx.fw.copy(), fx.mw.copy(), fx.t_align, fx.beta, fx.yaw_rate, fx.status)
    bad.fw[10:15] += 5.5
    bad.mw[100] -= 2.01
    fl = float_run_batch(*d.inputs(), vehicle)
    rep2 = shadow_check(bad, fl)
    assert rep2.count == 6
    assert set(np.flatnonzero(rep2.deviation)) == {10, 11, 12, 13, 14, 100}
    assert np.all((rep2.status[rep2.deviation] & SHADOW_DEVIATION) > 0)
    assert np.all((rep2.status[~rep2.deviation] & SHADOW_DEVIATION) == 0)
    # the other bits are kept
    np.testing.assert_array_equal(rep2.status & ~np.uint8(SHADOW_DEVIATION), fx.status)


def test_shadow_check_rejects_different_grids(vehicle):
    d = make_drive(vehicle, "sweep", duration_s=0.5, seed=2)
    a = run_batch(*d.inputs(), vehicle)
    b = float_run_batch(*(x[1:] for x in d.inputs()), vehicle)
    with pytest.raises(ValueError):
        shadow_check(a, b)


def test_live_shadow_checker(vehicle):
    from lde.estimator.paper import EstimatorInputs

    d = make_drive(vehicle, "steer", duration_s=2.0, seed=4)
    fx, fl, chk = FixedEstimator(vehicle), Estimator(vehicle), ShadowChecker()
    for k in range(len(d)):
        u = EstimatorInputs(
            d.speed[k],
            d.steering_angle[k],
            d.yaw_rate[k],
            d.column_torque[k],
            d.assist_torque[k],
            bool(d.mdps_ok[k]),
            bool(d.esc_ok[k]),
        )
        a, b = fx.step(int(d.t_ns[k]), u), fl.step(int(d.t_ns[k]), u)
        s = chk.check(a, b)
        assert not (s & Status.SHADOW_DEVIATION)
        assert s == b.status
    assert chk.steps == len(d) and chk.count == 0
    assert 0.0 <= chk.max_dfw <= FW_BOUND_N
    out = fx.step(int(d.t_ns[-1]) + 3_900_000, u)
    from dataclasses import replace

    assert chk.check(replace(out, mw=out.mw + 3.0), out) & Status.SHADOW_DEVIATION
    assert chk.count == 1


def test_step_and_run_batch_can_be_mixed_with_the_shadow(vehicle):
    from lde.estimator.paper import EstimatorInputs

    d = make_drive(vehicle, "gusts", duration_s=3.0, seed=8)
    whole = run_batch(*d.inputs(), vehicle)
    est = FixedEstimator(vehicle)
    k = len(d) // 2
    first = est.run_batch(*(x[:k] for x in d.inputs()))
    rest = []
    for i in range(k, len(d)):
        u = EstimatorInputs(
            d.speed[i],
            d.steering_angle[i],
            d.yaw_rate[i],
            d.column_torque[i],
            d.assist_torque[i],
            bool(d.mdps_ok[i]),
            bool(d.esc_ok[i]),
        )
        rest.append(est.step(int(d.t_ns[i]), u))
    np.testing.assert_array_equal(np.concatenate([first.fw, [o.fw for o in rest]]), whole.fw)
    np.testing.assert_array_equal(np.concatenate([first.status, [int(o.status) for o in rest]]), whole.status)
    assert est.shadow is not None and est.shadow.count == 0
    est.reset()
    again = est.run_batch(*d.inputs())
    np.testing.assert_array_equal(again.fw, whole.fw)
    np.testing.assert_array_equal(again.status, whole.status)


@pytest.mark.parametrize("name", ["est1", "est2", "est3", "est4", "est5"])
def test_other_shipped_vehicles_within_bound(name):
    """The Table 1 candidate sets: constants generated in memory, same bound, no saturation."""
    v = load_vehicle(name)
    d = make_drive(v, "gusts", duration_s=6.0, seed=6)
    state = FastState.initial(tables_vector(tables_for(v)))
    fx = run_batch(*d.inputs(), v, state=state)
    fl = float_run_batch(*d.inputs(), v)
    assert np.abs(fx.fw - fl.fw).max() <= FW_BOUND_N
    assert np.abs(fx.mw - fl.mw).max() <= MW_BOUND_NM
    assert state.shadow_count == 0
    assert sum(state.saturations().values()) == 0
