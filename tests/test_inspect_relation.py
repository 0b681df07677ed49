"""The statistics under ``lde inspect``: interval coverage with autocorrelated data, the errors-in-
variables bracket, Student's t, and the low-passed common grid."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from lde.analysis.calibrate import gaussian_smooth
from lde.analysis.inspect.relation import fit_relation, fixed_b_quantile
from lde.analysis.inspect.resample import Series, common_grid


def test_the_fixed_b_quantile_starts_at_the_normal_one_and_grows_with_the_window():
    assert fixed_b_quantile(0.0) == pytest.approx(stats.norm.ppf(0.975))
    q = [fixed_b_quantile(b) for b in (0.0, 0.1, 0.2, 0.5, 1.0, 2.0)]
    assert all(a < b for a, b in zip(q[:-2], q[1:-1], strict=True)) and q[-1] == q[-2]


def _smooth_noise(rng: np.random.Generator, n: int, sigma: float) -> np.ndarray:
    e = gaussian_smooth(rng.standard_normal(n), sigma)
    return e / e.std()


def test_the_interval_covers_the_slope_of_autocorrelated_data():
    """Regressor and residual both low-passed (as the checks' signals are): the HAC interval covers
    the true slope in about 95 % of drives; the ordinary least-squares interval would not."""
    rng = np.random.default_rng(1)
    n, runs, hits, naive_hits = 600, 300, 0, 0
    use = np.ones(n, bool)
    use[200:260] = False  # a gap in the gates: lags still count on the time grid
    for _ in range(runs):
        x = _smooth_noise(rng, n, 8.0)
        y = 0.7 * x + 0.5 * _smooth_noise(rng, n, 8.0)
        rel = fit_relation(x, y, use)
        assert rel is not None
        hits += rel.slope_lo <= 0.7 <= rel.slope_hi
        res = stats.linregress(x[use], y[use])
        half = stats.t.ppf(0.975, use.sum() - 2) * res.stderr
        naive_hits += abs(res.slope - 0.7) <= half
    assert 0.88 <= hits / runs <= 0.995, hits / runs
    assert naive_hits / runs < 0.6, naive_hits / runs  # why the correction is needed


def test_the_effective_sample_size_counts_independent_stretches():
    rng = np.random.default_rng(2)
    x = _smooth_noise(rng, 2000, 10.0)
    y = x + 0.3 * _smooth_noise(rng, 2000, 10.0)
    rel = fit_relation(x, y, np.ones(2000, bool))
    assert rel is not None and 20 < rel.n_eff < 400 < rel.n


def test_the_bracket_holds_the_slope_when_the_regressor_is_noisy():
    """Noise in x biases the slope of y on x toward zero (its interval misses the truth); the
    bracket with the reverse fit still holds it."""
    rng = np.random.default_rng(3)
    n = 3000
    truth = rng.standard_normal(n)
    x = truth + 0.7 * rng.standard_normal(n)
    y = 1.0 * truth + 0.1 * rng.standard_normal(n)
    rel = fit_relation(x, y, np.ones(n, bool))
    assert rel is not None
    assert rel.slope_hi < 1.0  # attenuated
    lo, hi = rel.bracket
    assert lo <= 1.0 <= hi


def test_nothing_is_fitted_on_a_constant_or_a_handful_of_samples():
    x = np.zeros(100)
    assert fit_relation(x, np.arange(100.0), np.ones(100, bool)) is None
    use = np.zeros(100, bool)
    use[:2] = True
    assert fit_relation(np.arange(100.0), np.arange(100.0), use) is None
    rel = fit_relation(np.full(100, 2.0), np.full(100, 4.0), np.ones(100, bool), intercept=False)
    assert rel is not None and rel.slope == pytest.approx(2.0)


def test_signals_of_different_rates_meet_on_one_grid():
    """The same slow signal sent at 12 ms and 20 ms periods ends up equal on the grid; a gap
    longer than the timeout makes the grid points around it stale."""
    t0 = 1_700_000_000 * 10**9

    def sent(period_ms: float, gap: tuple[float, float] | None = None) -> Series:
        t = np.arange(0.0, 30.0, period_ms / 1000.0)
        if gap is not None:
            t = t[(t < gap[0]) | (t > gap[1])]
        return Series(
            t0 + np.rint(t * 1e9).astype(np.int64), np.sin(2 * np.pi * t / 7.0), int(3 * period_ms * 1e6)
        )

    g = common_grid({"fast": sent(12.0), "slow": sent(20.0, gap=(10.0, 11.0))})
    both = g.ok("fast", "slow")
    assert np.max(np.abs(g.values["fast"][both] - g.values["slow"][both])) < 1e-3
    t = np.arange(len(g)) * g.dt + (g.t0_ns - t0) * 1e-9
    assert not np.any(g.fresh["slow"][(t > 10.0) & (t < 11.0)])
    assert np.all(g.fresh["fast"][(t > 2.0) & (t < 28.0)])
    assert not g.fresh["fast"][0] and not g.fresh["fast"][-1]  # the low-pass runs off the ends
