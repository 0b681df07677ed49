"""lde.analysis.metrics on synthetic arrays: each test pins a number a wrong formula would miss."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lde.analysis import metrics
from lde.analysis.metrics import Kind, MetricsError, Truth


def _truth(t, fw, mw, mw_ref=None):
    return Truth(t=t, fw=fw, mw=mw, mw_ref=mw if mw_ref is None else mw_ref)


def test_rms_and_nrmse_known_values():
    assert metrics.rms(np.array([3.0, -3.0, 3.0, -3.0])) == pytest.approx(3.0)
    truth = np.array([0.0, 500.0, -1000.0, 250.0])
    est = truth + np.array([10.0, -10.0, 10.0, -10.0])
    # RMS error 10 N over max|truth| 1000 N
    assert metrics.nrmse(est, truth) == pytest.approx(0.01)
    assert metrics.nrmse(est, truth, scale=100.0) == pytest.approx(0.1)


def test_nrmse_rejects_zero_scale_and_shape_mismatch():
    with pytest.raises(MetricsError):
        metrics.nrmse(np.ones(3), np.zeros(3))
    with pytest.raises(MetricsError):
        metrics.nrmse(np.ones(3), np.ones(4))
    with pytest.raises(MetricsError):
        metrics.rms(np.array([]))


def test_error_index_eq19_weights():
    assert metrics.error_index(100.0, 50.0) == pytest.approx(150.0)
    assert metrics.error_index(100.0, 50.0, q1=0.5, q2=2.0) == pytest.approx(150.0)
    assert metrics.mean_error_index([(100.0, 0.0), (0.0, 300.0)]) == pytest.approx(200.0)
    with pytest.raises(MetricsError):
        metrics.mean_error_index([])


def test_settling_window_drops_the_first_two_seconds():
    t = np.arange(0.0, 10.0, 0.01) + 1000.0  # log time base, not starting at 0
    fw_true = np.full_like(t, 1000.0)
    mw_true = np.full_like(t, 400.0)
    fw_hat = fw_true.copy()
    mw_hat = mw_true.copy()
    early = t < 1002.0
    fw_hat[early] = 0.0  # a huge transient inside the window must not count
    mw_hat[early] = -5000.0
    a = metrics.accuracy(t, fw_hat, mw_hat, _truth(t, fw_true, mw_true))
    assert a.kind is Kind.DISTURBED
    assert a.rms_fw == pytest.approx(0.0, abs=1e-9)
    assert a.rms_mw == pytest.approx(0.0, abs=1e-9)
    assert a.n == int(np.count_nonzero(~early))
    # with no settling window the transient is counted
    b = metrics.accuracy(t, fw_hat, mw_hat, _truth(t, fw_true, mw_true), settle=0.0)
    assert b.nrmse_fw == pytest.approx(math.sqrt(0.2), rel=1e-2)


def test_disturbed_nrmse_and_moment_about_reference_cg():
    rng = np.random.default_rng(1)
    t = np.arange(0.0, 20.0, 0.0039)
    fw = 2000.0 * np.sin(0.5 * t)
    mw = 800.0 * np.sin(0.5 * t + 0.3)
    d = 0.1  # payload moved the CG 0.1 m back: about the unloaded CG the moment differs by d*Fw
    mw_ref = mw + d * fw
    noise_f = rng.normal(0.0, 40.0, t.size)
    noise_m = rng.normal(0.0, 16.0, t.size)
    a = metrics.accuracy(t, fw + noise_f, mw + noise_m, _truth(t, fw, mw, mw_ref))
    keep = t >= 2.0
    assert a.nrmse_fw == pytest.approx(metrics.rms(noise_f[keep]) / np.max(np.abs(fw[keep])))
    assert a.nrmse_mw == pytest.approx(metrics.rms(noise_m[keep]) / np.max(np.abs(mw[keep])))
    assert a.nrmse_fw == pytest.approx(0.02, rel=0.05)
    assert a.nrmse_mw == pytest.approx(0.02, rel=0.05)
    # the estimate is about the actual CG, so against the reference-CG truth the error is ~ d*Fw
    expected_ref = metrics.rms(noise_m[keep] - d * fw[keep]) / np.max(np.abs(mw_ref[keep]))
    assert a.nrmse_mw_ref == pytest.approx(expected_ref)
    assert a.nrmse_mw_ref > 3 * a.nrmse_mw
    assert a.j == pytest.approx(a.rms_fw + a.rms_mw)


def test_bank_only_normalises_moment_by_one_metre_times_force():
    t = np.arange(0.0, 10.0, 0.01)
    fw = np.where(t > 3.0, 1500.0, 0.0)  # bank: force, no moment about the actual CG
    mw = np.zeros_like(t)
    mw_hat = np.full_like(t, 30.0)  # 30 Nm constant moment error
    a = metrics.accuracy(t, fw, mw_hat, _truth(t, fw, mw))
    assert a.kind is Kind.FORCE_ONLY
    assert a.scale_mw == pytest.approx(1500.0)
    assert a.nrmse_mw == pytest.approx(30.0 / 1500.0)
    assert a.nrmse_fw == pytest.approx(0.0)


def test_undisturbed_reports_rms_of_estimate_not_a_ratio():
    t = np.arange(0.0, 10.0, 0.01)
    z = np.zeros_like(t)
    fw_hat = np.where(np.arange(t.size) % 2 == 0, 50.0, -50.0)
    mw_hat = np.full_like(t, -20.0)
    a = metrics.accuracy(t, fw_hat, mw_hat, _truth(t, z, z))
    assert a.kind is Kind.UNDISTURBED
    assert a.rms_fw == pytest.approx(50.0)
    assert a.rms_mw == pytest.approx(20.0)
    assert math.isnan(a.nrmse_fw) and math.isnan(a.nrmse_mw)


def test_truth_is_interpolated_onto_the_estimate_times():
    # truth on a coarse 10 ms grid, estimates on the 3.9 ms grid: a ramp must match exactly
    tt = np.arange(0.0, 10.0, 0.01)
    te = np.arange(0.0, 9.9, 0.0039)
    a = metrics.accuracy(te, 100.0 * te, 50.0 * te, _truth(tt, 100.0 * tt, 50.0 * tt))
    assert a.rms_fw == pytest.approx(0.0, abs=1e-9)
    assert a.rms_mw == pytest.approx(0.0, abs=1e-9)


def test_valid_mask_and_nonfinite_samples_are_dropped():
    t = np.arange(0.0, 10.0, 0.01)
    fw = np.full_like(t, 1000.0)
    mw = np.full_like(t, 500.0)
    fw_hat = fw.copy()
    fw_hat[500:600] = 9999.0
    fw_hat[700] = np.nan
    valid = np.ones(t.size, dtype=bool)
    valid[500:600] = False
    a = metrics.accuracy(t, fw_hat, mw, _truth(t, fw, mw), valid=valid)
    assert a.rms_fw == pytest.approx(0.0)
    assert a.n == int(np.count_nonzero(t >= 2.0)) - 100 - 1
    with pytest.raises(MetricsError):
        metrics.accuracy(t, fw, mw, _truth(t, fw, mw), valid=np.zeros(t.size, dtype=bool))


def test_bad_inputs_raise_metrics_error():
    t = np.arange(0.0, 5.0, 0.01)
    fw = np.ones_like(t) * 100.0
    with pytest.raises(MetricsError):
        metrics.accuracy(t, fw, fw[:-1], _truth(t, fw, fw))
    with pytest.raises(MetricsError):
        metrics.accuracy(t, fw, fw, _truth(t[::-1].copy(), fw, fw))
    with pytest.raises(MetricsError):
        metrics.accuracy(t[:10], fw[:10], fw[:10], _truth(t, fw, fw))  # all inside the window


def test_classify_thresholds():
    z = np.zeros(10)
    assert metrics.classify(z + 5.0, z + 5.0) is Kind.UNDISTURBED
    assert metrics.classify(z + 1000.0, z + 5.0) is Kind.FORCE_ONLY
    assert metrics.classify(z + 1000.0, z + 300.0) is Kind.DISTURBED


def test_format_table_prints_percent_and_dash_for_nan():
    rows = [{"s": "heavy", "x": 0.0412}, {"s": "free", "x": float("nan")}]
    text = metrics.format_table(rows, [("s", "scenario", ""), ("x", "NRMSE", ".1%")])
    assert "4.1%" in text and "-" in text.splitlines()[-1]


def test_issue_11_targets_use_mw_about_the_vehicle_files_cg():
    """A payload moves the true CG: the target figure is Mw about the CG the vehicle file states
    (the truth's Mw_ref), not about the true CG; a disturbance-free drive is bounded by RMS."""
    t = np.arange(0.0, 10.0, 0.01)
    fw = np.full_like(t, 1000.0)
    mw = np.full_like(t, 200.0)  # about the true (loaded) CG
    mw_ref = mw - 0.1 * fw  # about the file's CG, 0.1 m ahead of the true one (dx = -0.1 m)
    # the estimate is right about the file's CG, 50 % off about the true CG
    a = metrics.accuracy(t, fw + 60.0, mw_ref, _truth(t, fw, mw, mw_ref))
    assert metrics.target_figures(a) == pytest.approx((0.06, 0.0))
    assert a.nrmse_mw == pytest.approx(0.5)
    assert metrics.meets(a, metrics.COLD) and not metrics.meets(a, metrics.WARM)
    b = metrics.accuracy(t, fw + 120.0, mw_ref, _truth(t, fw, mw, mw_ref))
    assert not metrics.meets(b, metrics.COLD)  # 12 % Fw
    quiet = np.zeros_like(t)
    c = metrics.accuracy(t, quiet + 55.0, quiet - 19.0, _truth(t, quiet, quiet))
    assert c.kind is Kind.UNDISTURBED and metrics.target_figures(c) == pytest.approx((55.0, 19.0))
    assert metrics.meets(c, metrics.COLD) and not metrics.meets(c, metrics.WARM)
    d = metrics.accuracy(t, quiet + 15.0, quiet + 21.0, _truth(t, quiet, quiet))
    assert not metrics.meets(d, metrics.COLD)  # 21 Nm > 20 Nm
    bounds = (metrics.COLD.max_nrmse, metrics.WARM.max_nrmse, metrics.WARM_DEFECTS.max_nrmse)
    assert bounds == (0.1, 0.05, 0.1)
    assert "60 N / 20 Nm" in metrics.COLD.describe()


def test_wind_apart_from_bank_known_values():
    t = np.arange(0.0, 10.0, 0.01)
    wind = np.where(t > 4.0, 1000.0, 0.0)
    bank = np.full_like(t, np.radians(2.0))
    truth = metrics.Truth(t, wind, 0 * t, 0 * t, fw_wind=wind, bank=bank)
    sp = metrics.split_accuracy(t, wind + 50.0, bank + np.radians(0.2), truth)
    assert sp.wind_nrmse == pytest.approx(0.05) and sp.wind_scale == pytest.approx(1000.0)
    assert sp.bank_rms_deg == pytest.approx(0.2)
    assert sp.wind_met() and sp.bank_met()
    far = metrics.split_accuracy(t, wind + 150.0, bank + np.radians(0.4), truth)
    assert far.wind_met() is False and far.bank_met() is False
    # no wind in the truth (the car's own slip makes tens of newtons), or a backend that does not tell
    calm = metrics.Truth(t, 0 * t, 0 * t, 0 * t, fw_wind=np.full_like(t, 30.0), bank=bank)
    assert math.isnan(metrics.split_accuracy(t, 0 * t, bank, calm).wind_nrmse)
    nan = np.full_like(t, np.nan)
    blind = metrics.split_accuracy(t, nan, nan, truth)
    assert math.isnan(blind.wind_nrmse) and math.isnan(blind.bank_rms_deg) and blind.wind_met() is None
    with pytest.raises(metrics.MetricsError, match="no wind force"):
        metrics.split_accuracy(t, wind, bank, metrics.Truth(t, wind, 0 * t, 0 * t))
