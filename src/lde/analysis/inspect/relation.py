"""A straight line through two signals of a drive, with an honest 95 % confidence interval.

The physics checks of :mod:`lde.analysis.inspect.checks` each fit ``y = slope x + intercept`` over
the samples of a drive where the relation holds (a boolean ``use`` mask on a uniform time grid).
Consecutive samples of a low-passed signal are not independent: at 10 samples/s after a 0.3 s
low-pass, one curve is tens of samples that all say the same thing. Ordinary least-squares
standard errors would count each sample as new evidence and give intervals several times too
narrow. Here the standard errors are Newey-West (HAC, Bartlett kernel) over the time grid: the
per-sample score ``x_i e_i`` is summed with its neighbours up to a window of
:data:`HAC_LAG_FACTOR` integrated correlation times of the residual (the same estimator as
:mod:`lde.analysis.calibrate`), and samples outside ``use`` contribute zero, so lags are true time
lags even where the mask leaves gaps. The effective sample size ``n_eff`` is the number of
independent samples that would give the same slope variance (``n`` times the OLS variance over the
HAC variance). The interval's critical value is the fixed-b one of Kiefer and Vogelsang
(:func:`fixed_b_quantile`): with a window that spans a good part of a short drive, the HAC
variance is itself uncertain, and the normal 1.96 would cover the slope in 80 % of drives, not 95 %
(tests/test_inspect_relation.py measures it).

Both signals are measured: noise in ``x`` (quantised sensors, lags not removed by the low-pass)
biases the slope of ``y`` on ``x`` toward zero, and noise in ``y`` biases the slope of ``x`` on
``y`` (inverted) away from zero. The true slope lies between the two (for errors uncorrelated
with the signals), so :attr:`Relation.bracket` spans both fits' intervals: a scale check passes
when the bracket reaches the physical value, a sign check needs the interval of the slope of ``y``
on ``x`` to exclude zero.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lde.analysis.calibrate import HAC_LAG_FACTOR, hac_covariance

__all__ = ["Relation", "fit_relation", "fixed_b_quantile", "masked_correlation_time"]

#: the two-sided 95 % normal quantile
_Z95 = 1.959963984540054


def fixed_b_quantile(b: float) -> float:
    """Two-sided 95 % critical value of a t statistic whose standard error is Newey-West with a
    Bartlett window of ``b`` times the sample (Kiefer & Vogelsang 2005, "fixed-b" asymptotics:
    the window's share of the data, not the data's length, sets how noisy the variance estimate is;
    their fitted polynomial, 1.96 at b = 0, 2.57 at b = 0.2; ``b`` is clipped to [0, 1])."""
    b = min(max(float(b), 0.0), 1.0)
    return _Z95 + 2.9694 * b + 0.4160 * b**2 - 0.5324 * b**3


def masked_correlation_time(e: np.ndarray, use: np.ndarray) -> float:
    """Integrated autocorrelation time [samples] of ``e`` over the samples where ``use`` holds,
    with lags counted on the full grid: ``1 + 2 sum_k rho_k`` up to the first lag whose
    autocorrelation is not positive (1 for white noise, ~2 tau for an AR(1) of time constant tau)."""
    m = np.asarray(use, dtype=np.float64)
    x = np.where(m > 0, np.asarray(e, dtype=np.float64), 0.0)
    n = x.size
    if n < 2 or not np.any(x):
        return 1.0
    x = np.where(m > 0, x - x.sum() / m.sum(), 0.0)
    size = 1 << int(math.ceil(math.log2(2 * n)))
    fx, fm = np.fft.rfft(x, size), np.fft.rfft(m, size)
    acf = np.fft.irfft(fx * np.conj(fx), size)[:n]
    pairs = np.rint(np.fft.irfft(fm * np.conj(fm), size)[:n])  # sample pairs at each lag
    if acf[0] <= 0.0:  # constant over the samples
        return 1.0
    ok = pairs >= max(10.0, 0.1 * pairs[0])
    rho = np.where(ok, acf / np.maximum(pairs, 1.0), 0.0) / (acf[0] / pairs[0])
    stop = np.flatnonzero(rho[1:] <= 0.0)
    k = int(stop[0]) + 1 if stop.size else n
    return float(max(1.0, 1.0 + 2.0 * np.sum(rho[1:k])))


@dataclass(frozen=True)
class Relation:
    """``y = slope x + intercept`` fitted over ``n`` samples (units: those of y per unit of x).

    Attributes:
        n: samples used; n_eff: effective independent samples for the slope (HAC; <= n in practice).
        slope, slope_lo, slope_hi: the least-squares slope of y on x and its 95 % interval.
        intercept, intercept_lo, intercept_hi: the intercept (y at x = 0) and its 95 % interval.
        reverse, reverse_lo, reverse_hi: 1 / (slope of x on y) and its 95 % interval (inf where
            that slope's interval reaches zero).
        corr: the correlation of x and y over the samples (NaN where one of them is constant).
        x_std, y_std: their standard deviations over the samples.
    """

    n: int
    n_eff: float
    slope: float
    slope_lo: float
    slope_hi: float
    intercept: float
    intercept_lo: float
    intercept_hi: float
    reverse: float
    reverse_lo: float
    reverse_hi: float
    corr: float
    x_std: float
    y_std: float

    @property
    def sign(self) -> int:
        """+1 or -1 when the slope's 95 % interval excludes zero, else 0 (undecided)."""
        if self.slope_lo > 0.0:
            return 1
        if self.slope_hi < 0.0:
            return -1
        return 0

    @property
    def bracket(self) -> tuple[float, float]:
        """Where the true slope lies (95 %), with noise in x or in y: the hull of both fits' intervals."""
        ends = (self.slope_lo, self.slope_hi, self.reverse_lo, self.reverse_hi)
        return min(ends), max(ends)


def _ols_hac(
    x: np.ndarray, y: np.ndarray, use: np.ndarray, intercept: bool
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """(coefficients [slope, intercept], their HAC standard errors, n_eff of the slope, the 95 %
    critical value); without ``intercept`` the line runs through the origin and the intercept is 0
    with standard error 0."""
    xu, yu = x[use], y[use]
    n = xu.size
    X = np.column_stack([xu, np.ones(n)]) if intercept else xu[:, None]
    coef, *_ = np.linalg.lstsq(X, yu, rcond=None)
    e = yu - X @ coef
    ginv = np.linalg.inv(X.T @ X)
    psi = np.zeros((x.size, X.shape[1]))
    psi[use] = (X * e[:, None]) @ ginv  # each sample's share of the estimate's error
    e_full = np.zeros(x.size)
    e_full[use] = e
    tau = masked_correlation_time(e_full, use)
    lags = int(min(math.ceil(HAC_LAG_FACTOR * tau), max(n // 2, 1)))
    cov = hac_covariance(psi, lags)
    se = np.sqrt(np.maximum(np.diag(cov), 0.0))
    var_ols = float(ginv[0, 0] * np.dot(e, e) / max(n - X.shape[1], 1))
    n_eff = float(n) if cov[0, 0] <= 0.0 else min(float(n), n * var_ols / float(cov[0, 0]))
    if not intercept:
        coef, se = np.append(coef, 0.0), np.append(se, 0.0)
    return coef, se, n_eff, fixed_b_quantile((lags + 1) / n)


def fit_relation(x: np.ndarray, y: np.ndarray, use: np.ndarray, *, intercept: bool = True) -> Relation | None:
    """The relation of ``y`` to ``x`` over the samples where ``use`` holds (arrays on one uniform
    time grid, in time order); ``intercept=False`` fits ``y = slope x``. None when fewer than 3
    samples are used or ``x`` or ``y`` does not vary over them (no line to fit)."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    use = np.asarray(use, dtype=bool) & np.isfinite(x) & np.isfinite(y)
    n = int(np.count_nonzero(use))
    if n < 3:
        return None
    x_std, y_std = float(np.std(x[use])), float(np.std(y[use]))
    if intercept and (x_std == 0.0 or y_std == 0.0) or not (np.any(x[use]) and np.any(y[use])):
        return None
    (b, a), (se_b, se_a), n_eff, q = _ols_hac(x, y, use, intercept)
    (c, _), (se_c, _), _, q_r = _ols_hac(y, x, use, intercept)
    c_lo, c_hi = c - q_r * se_c, c + q_r * se_c
    if c_lo > 0.0 or c_hi < 0.0:  # the inverse of an interval that excludes zero
        r_lo, r_hi = sorted((1.0 / c_hi, 1.0 / c_lo))
    else:
        r_lo, r_hi = -math.inf, math.inf
    return Relation(
        n=n,
        n_eff=n_eff,
        slope=float(b),
        slope_lo=float(b - q * se_b),
        slope_hi=float(b + q * se_b),
        intercept=float(a),
        intercept_lo=float(a - q * se_a),
        intercept_hi=float(a + q * se_a),
        reverse=float(1.0 / c) if c != 0.0 else math.inf,
        reverse_lo=float(r_lo),
        reverse_hi=float(r_hi),
        corr=float(np.corrcoef(x[use], y[use])[0, 1]) if x_std > 0.0 and y_std > 0.0 else math.nan,
        x_std=x_std,
        y_std=y_std,
    )
