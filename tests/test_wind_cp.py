"""The reported wind moment's centre-of-pressure blend (lde.estimator.lateral.wind_moment_output; issue 11
cold)."""

from __future__ import annotations

import numpy as np
import pytest

from lde.errors import ConfigError
from lde.estimator import lateral as E
from lde.estimator.outputs import N_OUT, O_FW_WIND, O_MW, O_MW_WIND
from lde.params import load_vehicle


def _out(fw_wind: float, mw_wind: float) -> np.ndarray:
    out = np.zeros(N_OUT)
    out[O_FW_WIND], out[O_MW_WIND], out[O_MW] = fw_wind, mw_wind, mw_wind
    return out


def test_shipped_default_is_off_and_leaves_the_moment():
    p = E.params_vector(load_vehicle("reference"))
    assert p[E.P_WCP] == 0.0 and p[E.P_XCP] == pytest.approx(0.3)
    out = _out(1000.0, -300.0)
    E.wind_moment_output(p, out)
    assert out[O_MW] == -300.0 and out[O_MW_WIND] == -300.0


def test_blend_weights_the_prior(tmp_path):
    f = tmp_path / "v.toml"
    f.write_text('extends = "reference"\nname = "v"\n[estimator]\nwind_cp_m = 0.3\nwind_cp_weight = 0.7\n')
    p = E.params_vector(load_vehicle(f))
    out = _out(1000.0, 500.0)
    E.wind_moment_output(p, out)
    assert out[O_MW] == pytest.approx(0.3 * 500.0 + 0.7 * 0.3 * 1000.0)  # 360 Nm
    assert out[O_MW_WIND] == out[O_MW]
    out = _out(0.0, 0.0)  # no wind (a bank has no moment): stays 0
    E.wind_moment_output(p, out)
    assert out[O_MW] == 0.0


@pytest.mark.parametrize("key,value", [("wind_cp_weight", 1.5), ("wind_cp_weight", -0.1), ("wind_cp_m", 3.0)])
def test_out_of_range_is_a_clear_error(tmp_path, key, value):
    f = tmp_path / "v.toml"
    f.write_text(f'extends = "reference"\nname = "v"\n[estimator]\n{key} = {value}\n')
    with pytest.raises(ConfigError, match=key):
        load_vehicle(f)


@pytest.mark.parametrize("backend", ["float", "fixed"])
def test_both_backends_report_the_blend_and_keep_the_filter(backend):
    """With w > 0 the reported Mw (and Mw_wind) is the blend of the w = 0 run's own M_wind and F_wind:
    the filter, the learner and Fw are untouched (they see the filter's M_wind), on both backends."""
    from dataclasses import replace
    from pathlib import Path

    from lde.can.profiles import load_profile
    from lde.io import read_log
    from lde.replay.replay import replay

    data = Path(__file__).parent / "data"
    frames = read_log(data / "sample_linear.log").frames
    profile = load_profile("lde")
    v0 = load_vehicle(data / "sample_linear_vehicle.toml")
    v1 = replace(v0, estimator=replace(v0.estimator, wind_cp=0.3, wind_cp_weight=0.7))
    r0 = replay(frames, profile, v0, backend)
    r1 = replay(frames, profile, v1, backend)
    np.testing.assert_array_equal(r1.fw, r0.fw)
    np.testing.assert_array_equal(r1.block.fw_wind, r0.block.fw_wind)
    expect = 0.3 * r0.block.mw_wind + 0.7 * 0.3 * r0.block.fw_wind
    np.testing.assert_allclose(r1.mw, expect, atol=1e-6 * (1.0 + np.abs(expect).max()))
    np.testing.assert_allclose(r1.block.mw_wind, expect, atol=1e-6 * (1.0 + np.abs(expect).max()))
    assert np.abs(r1.mw - r0.mw).max() > 100.0  # the sample's 800 N wind: the blend shows
