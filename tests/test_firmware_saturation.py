"""Saturation at the extremes and inputs outside the supported ranges: clear status, counted
saturations, never a wrap-around, never an exception."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_model.fast import O_XF, O_XM, FastState, FixedEstimator, run_batch_raw, tables_vector
from firmware_model.step import SAT_NAMES
from firmware_model.tables import tables_for
from lde.estimator.paper import EstimatorInputs, Status
from lde.estimator.paper import run_batch as float_run_batch
from lde.params import load_vehicle
from lde.units import KMH, STEP_NS

INT32 = 2**31


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("reference")


def _run(vehicle, n, speed, steer, yaw, tcol, tas, mdps=True, esc=True):
    tb = tables_for(vehicle)
    st_ = FastState.initial(tables_vector(tb))
    cols = [np.full(n, c, dtype=np.float64) for c in (speed, steer, yaw, tcol, tas)]
    t = np.arange(n, dtype=np.int64) * STEP_NS
    _, outs, status = run_batch_raw(tb, st_, t, *cols, np.full(n, mdps), np.full(n, esc))
    return outs, status, dict(zip(SAT_NAMES, st_.sat.tolist(), strict=True))


# input -> (status bits that must be set on every step, saturation counter that must count)
OUT_OF_RANGE = {
    "steer_nan": (dict(steer=float("nan")), Status.MDPS_FAULT | Status.DEGRADED, "in_steer"),
    "steer_huge": (dict(steer=100.0), Status.MDPS_FAULT | Status.DEGRADED, "in_steer"),
    "torque_inf": (dict(tcol=float("inf")), Status.MDPS_FAULT | Status.DEGRADED, "in_torque"),
    "torque_huge": (dict(tas=-1e4), Status.MDPS_FAULT | Status.DEGRADED, "in_torque"),
    "yaw_nan": (dict(yaw=float("nan")), Status.ESC_FAULT | Status.NOT_CONVERGED, "in_yaw"),
    "yaw_huge": (dict(yaw=50.0), Status.ESC_FAULT | Status.NOT_CONVERGED, "in_yaw"),
    "speed_nan": (dict(speed=float("nan")), Status.LOW_SPEED | Status.NOT_CONVERGED, "in_speed"),
    "speed_negative": (dict(speed=-5.0), Status.LOW_SPEED | Status.NOT_CONVERGED, None),
    "speed_over_model": (dict(speed=300 * KMH), Status.DEGRADED, "speed_clamp"),
    "speed_over_format": (dict(speed=1e6), Status.DEGRADED, "in_speed"),
}


@pytest.mark.parametrize("case", sorted(OUT_OF_RANGE))
def test_inputs_outside_the_supported_ranges_give_a_clear_status(vehicle, case):
    over, bits, counter = OUT_OF_RANGE[case]
    u = dict(speed=100 * KMH, steer=0.01, yaw=0.01, tcol=0.5, tas=1.0) | over
    n = 50
    outs, status, sat = _run(vehicle, n, u["speed"], u["steer"], u["yaw"], u["tcol"], u["tas"])
    assert np.all((status & int(bits)) == int(bits)), (case, np.unique(status))
    assert not np.any(status & Status.VALID)
    if counter is not None:
        assert sat[counter] == n
    assert np.all(np.abs(outs) < INT32)


def test_float_and_fixed_agree_on_fault_status_for_nonfinite_inputs(vehicle):
    """Non-finite inputs are faults in both backends (the same bits)."""
    n = 20
    for kw in (dict(steer=float("nan")), dict(yaw=float("inf")), dict(speed=float("nan"))):
        u = dict(speed=100 * KMH, steer=0.01, yaw=0.01, tcol=0.5, tas=1.0) | kw
        _, status, _ = _run(vehicle, n, u["speed"], u["steer"], u["yaw"], u["tcol"], u["tas"])
        cols = [np.full(n, u[k]) for k in ("speed", "steer", "yaw", "tcol", "tas")]
        t = np.arange(n, dtype=np.int64) * STEP_NS
        fl = float_run_batch(t, *cols, np.ones(n, bool), np.ones(n, bool), vehicle)
        np.testing.assert_array_equal(status, fl.status)


@settings(max_examples=20, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(
    speed=st.floats(min_value=8.4, max_value=69.4),  # min speed .. the model's maximum (250 km/h)
    steer=st.floats(min_value=-15.9, max_value=15.9),
    yaw=st.floats(min_value=-15.9, max_value=15.9),
    tcol=st.floats(min_value=-255.0, max_value=255.0),
    tas=st.floats(min_value=-255.0, max_value=255.0),
)
def test_extremes_saturate_without_wrapping(vehicle, speed, steer, yaw, tcol, tas):
    """Constant inputs anywhere inside the input formats (speed within the model's range: above it
    the fixed model is clamped on purpose), held for 8 s: the estimates never jump across the
    int32 range (a wrap would); a saturation shows as DEGRADED on every step (never VALID);
    without saturation a large float estimate is never answered with the opposite sign."""
    n = 2000
    est = FixedEstimator(vehicle)
    u = EstimatorInputs(speed, steer, yaw, tcol, tas)
    rows, status = [], []
    for k in range(n):
        before = int(est.state.sat.sum())
        r = est.step_ints(k * STEP_NS, u)
        rows.append(r[1:])
        status.append(r[0])
        if int(est.state.sat.sum()) > before:
            # a saturation in this step: DEGRADED, never VALID
            assert r[0] & Status.DEGRADED and not r[0] & Status.VALID, (k, r[0])
    outs = np.array(rows, dtype=np.int64)
    jumps = np.abs(np.diff(outs, axis=0))
    assert jumps.max() < INT32, "an output jumped by more than half the int32 range"
    if int(est.state.sat.sum()) > 0:
        return  # the measurement itself was clamped: the estimate may differ from the float one
    cols = [np.full(n, c) for c in (speed, steer, yaw, tcol, tas)]
    fl = float_run_batch(
        np.arange(n, dtype=np.int64) * STEP_NS, *cols, np.ones(n, bool), np.ones(n, bool), vehicle
    )
    tb = tables_for(vehicle)
    fw = outs[:, O_XF] * tb.state_lsb(2)
    mw = outs[:, O_XM] * tb.state_lsb(3)
    big = np.abs(fl.fw) > 1000.0
    assert np.all(np.sign(fw[big]) == np.sign(fl.fw[big]))
    big = np.abs(fl.mw) > 1000.0
    assert np.all(np.sign(mw[big]) == np.sign(fl.mw[big]))


def test_saturating_step_counts_and_flags_each_step(vehicle):
    """At the top of the torque format their sum saturates int32: counted on every step and
    DEGRADED on every step; the estimate keeps its sign and stays at a fixed point."""
    n = 1500
    outs, status, sat = _run(vehicle, n, 120 * KMH, 15.9, 15.9, 255.0, 255.0)
    assert sat["in_torque"] == n
    assert np.all(status & Status.DEGRADED)
    assert np.all(outs[100:, O_XF] > 0)
