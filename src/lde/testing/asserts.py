"""Assertions on captured frames (:class:`~lde.testing.capture.FrameList`): timing, E2E, value ranges.

On a bench the frames carry simulated time, so timing is exact: ``assert_periodic(frames)`` checks
every interval against 3.9 ms with no tolerance by default, whatever the machine's load. Each
failure message says how many frames failed and shows the first ones (time, value).
"""

from __future__ import annotations

import numpy as np

from lde.testing.capture import FrameList
from lde.units import STEP_NS

__all__ = ["STEP_S", "assert_periodic", "assert_e2e_valid", "assert_in_range"]

#: the estimator's period, and the period of lde's output messages [s]
STEP_S = STEP_NS / 1e9
_SHOW = 3  # failures shown in a message


def _at(frames: FrameList, idx: np.ndarray) -> str:
    return ", ".join(f"#{int(k)} at t = {frames.t_ns[k] / 1e9:.6f} s" for k in idx[:_SHOW])


def assert_periodic(
    frames: FrameList, period_s: float = STEP_S, *, tolerance_s: float = 0.0, min_frames: int = 2
) -> None:
    """Every interval between consecutive frames is ``period_s`` within ``tolerance_s``, and there
    are at least ``min_frames`` frames."""
    n = len(frames)
    assert n >= min_frames, f"{frames.label}: {n} frames, expected at least {min_frames}"
    period = round(period_s * 1e9)
    tol = round(tolerance_s * 1e9)
    dt = np.diff(frames.t_ns)
    bad = np.flatnonzero(np.abs(dt - period) > tol)
    if bad.size:
        shown = ", ".join(f"{dt[k] / 1e6:.3f} ms before #{int(k) + 1}" for k in bad[:_SHOW])
        raise AssertionError(
            f"{frames.label}: {bad.size} of {dt.size} intervals are not {period / 1e6:g} ms "
            f"(+-{tol / 1e6:g} ms): {shown}"
        )


def assert_e2e_valid(frames: FrameList) -> None:
    """Every frame passes its message's integrity check (CRC / checksum, right length), and the
    counters run without a gap, repeat or invalid value (each the scheme's successor of the one
    before: +1 modulo 15 skipping 15 in AUTOSAR E2E Profile 1)."""
    spec = frames.spec
    assert spec is not None, f"{frames.label}: not a message of the profile: no E2E scheme to check"
    bad = np.flatnonzero(~frames.e2e_ok)
    if bad.size:
        raise AssertionError(
            f"{frames.label}: {bad.size} of {len(frames)} frames fail the CRC / checksum: {_at(frames, bad)}"
        )
    c = frames.counters
    sch = spec.scheme
    invalid = np.flatnonzero(c == sch.invalid_counter)
    if invalid.size:
        raise AssertionError(f"{frames.label}: invalid counter {sch.invalid_counter}: {_at(frames, invalid)}")
    breaks = [k for k in range(1, len(c)) if sch.next_counter(int(c[k - 1])) != int(c[k])]
    if breaks:
        shown = ", ".join(
            f"{int(c[k - 1])} -> {int(c[k])} at t = {frames.t_ns[k] / 1e9:.6f} s" for k in breaks[:_SHOW]
        )
        raise AssertionError(f"{frames.label}: {len(breaks)} counter breaks: {shown}")


def assert_in_range(frames: FrameList, signal: str, lo: float, hi: float) -> None:
    """Every value of ``signal`` [DBC units] is finite and within ``[lo, hi]``."""
    v = frames.signal(signal)
    bad = np.flatnonzero(~np.isfinite(v) | (v < lo) | (v > hi))
    if bad.size:
        shown = ", ".join(f"{v[k]:g} at t = {frames.t_ns[k] / 1e9:.6f} s" for k in bad[:_SHOW])
        raise AssertionError(
            f"{frames.label}.{signal}: {bad.size} of {v.size} values outside [{lo:g}, {hi:g}]: {shown}"
        )
