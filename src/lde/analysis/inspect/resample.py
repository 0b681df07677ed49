"""Signals of different messages and rates on one low-passed time grid.

A car's signals come at their own rates (the RAV4's yaw rate every 12 ms, its torques every 20 ms)
and with their own noise and quantisation (its yaw rate in steps of 0.244 deg/s). The physics
checks compare steady-state relations, so every signal is

1. interpolated linearly onto a fine uniform grid (:data:`FINE_DT_S`; linear, not sample-and-hold,
   so that a slow message does not lag a fast one by half its period), where it is fresh: a grid
   point between two samples further apart than the signal's timeout (a gap in the log) is not;
2. low-passed by a zero-phase Gaussian of standard deviation :data:`SMOOTH_S` (the same for every
   signal, so none leads another; -3 dB at about 0.45 Hz: the yaw and lateral dynamics of a car,
   whose time constants are 0.1-0.3 s, are gone, the curves of a drive remain); a grid point whose
   kernel reaches a stale one or runs off the log's ends is not fresh;
3. decimated to :data:`DT_S` (10 samples/s: the Gaussian leaves nothing above 2 Hz to alias).

All times are integer nanoseconds in the log's own time base on the way in; the grid counts
seconds from its first point (:attr:`Grid.t0_ns`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lde.analysis.calibrate import gaussian_smooth

__all__ = ["Series", "Grid", "common_grid", "FINE_DT_S", "SMOOTH_S", "DT_S"]

#: the grid the signals are interpolated onto before the low-pass [s]
FINE_DT_S = 0.01
#: standard deviation of the Gaussian low-pass [s]
SMOOTH_S = 0.3
#: the grid the checks fit on [s]
DT_S = 0.1


@dataclass(frozen=True)
class Series:
    """One signal as it arrived: sample times [ns, the log's time base], values (SI, NaN where a
    frame did not decode), and the age after which a value is stale [ns]."""

    t_ns: np.ndarray
    values: np.ndarray
    timeout_ns: int


@dataclass(frozen=True)
class Grid:
    """Low-passed signals on one uniform grid.

    Attributes:
        t0_ns: the log time of the first grid point [ns].
        dt: the grid's period [s].
        values: signal name -> low-passed values (NaN never; check ``fresh``).
        fresh: signal name -> bool, the value rests on fresh samples only.
    """

    t0_ns: int
    dt: float
    values: Mapping[str, np.ndarray]
    fresh: Mapping[str, np.ndarray]

    def __len__(self) -> int:
        return int(next(iter(self.fresh.values())).size) if self.fresh else 0

    def has(self, *names: str) -> bool:
        """Every one of ``names`` is a signal of the grid."""
        return all(n in self.values for n in names)

    def ok(self, *names: str) -> np.ndarray:
        """Where every one of ``names`` is fresh (all False for a name the grid does not have)."""
        out = np.ones(len(self), dtype=bool)
        for n in names:
            out &= self.fresh.get(n, False)
        return out

    def rate(self, name: str) -> np.ndarray:
        """The time derivative of a low-passed signal [its unit per s] (central differences)."""
        v = self.values[name]
        return np.gradient(v, self.dt) if v.size > 1 else np.zeros_like(v)


def _fine(s: Series, t_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The series interpolated at ``t_ns`` and where that rests on two samples within its timeout."""
    good = np.isfinite(s.values)
    ts, vs = np.asarray(s.t_ns, np.int64)[good], np.asarray(s.values, np.float64)[good]
    if ts.size == 0:
        return np.zeros(t_ns.size), np.zeros(t_ns.size, dtype=bool)
    order = np.argsort(ts, kind="stable")
    ts, vs = ts[order], vs[order]
    j = np.searchsorted(ts, t_ns, side="right") - 1  # the sample at or before each grid point
    inside = (j >= 0) & (j < ts.size - 1)
    jj = np.clip(j, 0, max(ts.size - 2, 0))
    gap = ts[np.minimum(jj + 1, ts.size - 1)] - ts[jj]
    fresh = inside & (gap <= s.timeout_ns)
    # exactly on the last sample: fresh (nothing to interpolate toward)
    fresh |= t_ns == ts[-1]
    values = np.interp(t_ns.astype(np.float64), ts.astype(np.float64), vs)
    return values, fresh


def common_grid(
    series: Mapping[str, Series],
    *,
    fine_dt_s: float = FINE_DT_S,
    smooth_s: float = SMOOTH_S,
    dt_s: float = DT_S,
) -> Grid:
    """Every series on one grid (module doc) spanning the first to the last sample of any of them."""
    spans = [
        (int(np.min(s.t_ns[np.isfinite(s.values)])), int(np.max(s.t_ns[np.isfinite(s.values)])))
        for s in series.values()
        if np.any(np.isfinite(s.values))
    ]
    if not spans:
        return Grid(0, dt_s, {n: np.zeros(0) for n in series}, {n: np.zeros(0, bool) for n in series})
    t0 = min(a for a, _ in spans)
    t1 = max(b for _, b in spans)
    step_ns = int(round(fine_dt_s * 1e9))
    t_fine = t0 + step_ns * np.arange((t1 - t0) // step_ns + 1, dtype=np.int64)
    every = max(1, int(round(dt_s / fine_dt_s)))
    sigma = smooth_s / fine_dt_s
    edge = int(np.ceil(4.0 * sigma))
    values: dict[str, np.ndarray] = {}
    fresh: dict[str, np.ndarray] = {}
    for name, s in series.items():
        v, ok = _fine(s, t_fine)
        if np.any(ok) and not np.all(ok):  # bridge the stale stretches before smoothing (masked below)
            v = np.interp(np.arange(v.size), np.flatnonzero(ok), v[ok])
        smooth = gaussian_smooth(v, sigma)
        spoiled = gaussian_smooth((~ok).astype(np.float64), sigma) > 1e-3
        spoiled[:edge] = spoiled[v.size - edge :] = True  # the kernel runs off the log's ends
        values[name] = smooth[::every]
        fresh[name] = (ok & ~spoiled)[::every]
    return Grid(t0_ns=t0, dt=every * fine_dt_s, values=values, fresh=fresh)
