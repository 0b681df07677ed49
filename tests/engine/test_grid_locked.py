"""The MDPS-locked grid (lde.engine.grid.new_lock / lock_anchor / lock_timeout / locked_step_times): each
step right after the MDPS frame it consumes; a step at 1.5 periods when none comes; one rule for the
live loop and for a replay of the bare frames."""

from __future__ import annotations

import numpy as np
import pytest

from lde.engine.grid import (
    L_TIMEOUTS,
    L_TRIGGERED,
    lock_anchor,
    lock_deadline,
    lock_frame,
    lock_timeout,
    locked_step_times,
    new_lock,
)
from lde.units import STEP_NS

P = STEP_NS
T0 = 1_700_000_000_000_000_000


def _stream(anchor_t: np.ndarray, t_first: int, t_end: int) -> list[int]:
    """The lock fed one frame at a time, as the live loop feeds it (timeouts before each frame)."""
    s = new_lock(t_first)
    out = []
    for t in anchor_t.tolist():
        while (tk := int(lock_timeout(s, t))) >= 0:
            out.append(tk)
        if lock_anchor(s, t):
            out.append(t)
    while (tk := int(lock_timeout(s, t_end + 1))) >= 0:
        out.append(tk)
    return out


def test_every_mdps_frame_triggers_a_step_at_its_own_time_even_with_jitter() -> None:
    rng = np.random.default_rng(3)
    t = T0 + 700_000 + np.arange(500) * P + rng.integers(-800_000, 800_000, 500)  # +-0.8 ms jitter
    steps = locked_step_times(t, T0 + 700_000, int(t[-1]))
    np.testing.assert_array_equal(steps, t)


def test_a_missing_frame_gives_one_step_at_1p5_periods_and_the_phase_is_kept() -> None:
    t = T0 + 300_000 + np.arange(20) * P
    keep = np.ones(20, bool)
    keep[[7, 12, 13]] = False  # one frame lost, then two in a row
    steps = locked_step_times(t[keep], int(t[0]), int(t[-1]))
    expect = t.copy()
    expect[7] = t[6] + P + P // 2
    expect[12] = t[11] + P + P // 2
    expect[13] = t[11] + 2 * P + P // 2  # the reference moved by exactly P: the phase is kept
    np.testing.assert_array_equal(steps, expect)
    assert np.all(np.diff(steps) >= P // 2) and np.all(np.diff(steps) <= P + P // 2)


def test_before_the_first_frame_it_steps_every_period_and_locks_on_at_any_phase() -> None:
    t_first = T0
    t = T0 + 10 * P + 1_234_567 + np.arange(10) * P  # the sender starts late, at another phase
    steps = locked_step_times(t, t_first, int(t[-1]))
    free = steps[steps < t[0]]
    np.testing.assert_array_equal(free, t_first + P // 2 + np.arange(free.size) * P)
    np.testing.assert_array_equal(steps[free.size :], t)
    assert np.all(np.diff(steps) > P // 2)


def test_frames_closer_than_half_a_period_do_not_step_twice() -> None:
    t = np.array([T0, T0 + 100_000, T0 + P, T0 + P + P // 2, T0 + 2 * P])  # a repeat and a burst
    steps = locked_step_times(t, T0, int(t[-1]))
    np.testing.assert_array_equal(steps, [T0, T0 + P, T0 + 2 * P])


def test_the_rule_is_the_same_streamed_and_in_one_call() -> None:
    rng = np.random.default_rng(7)
    gaps = rng.choice([P, P, P, 2 * P, 3 * P, P // 3], 2000)
    t = T0 + np.cumsum(gaps) + rng.integers(-300_000, 300_000, 2000)
    t.sort()
    t_first, t_end = T0 + 2 * P, int(t[-1]) + 10 * P
    np.testing.assert_array_equal(locked_step_times(t, t_first, t_end), _stream(t, t_first, t_end))


def test_deadline_counters_and_unsorted_input() -> None:
    s = new_lock(T0)
    assert lock_deadline(s) == T0 + P // 2
    assert lock_timeout(s, T0 + P // 2) == -1  # the window's end itself is still in it
    assert lock_timeout(s, T0 + P // 2 + 1) == T0 + P // 2
    assert lock_anchor(s, T0 + P + 10)
    assert s[L_TRIGGERED] == 1 and s[L_TIMEOUTS] == 1
    with pytest.raises(ValueError):
        locked_step_times(np.array([T0 + P, T0]), T0, T0 + 2 * P)


def test_lock_frame_is_the_timeout_check_and_the_anchor_in_one_call() -> None:
    """The live service's one call per MDPS frame (lde.engine.grid.lock_frame) gives the same steps and the
    same lock state as lock_timeout then lock_anchor, and leaves the state alone when a timeout is due."""
    rng = np.random.default_rng(11)
    t = T0 + 300_000 + np.arange(300) * P + rng.integers(-2_500_000, 2_500_000, 300)
    t = np.sort(t[rng.random(300) > 0.1])  # lost frames: timeouts due before some frames
    a, b = new_lock(T0), new_lock(T0)
    got, want = [], []
    n_neg = 0
    for x in t.tolist():
        while (tk := int(lock_timeout(a, x))) >= 0:
            want.append(tk)
        if lock_anchor(a, x):
            want.append(x)
        before = b.copy()
        r = int(lock_frame(b, x))
        if r < 0:
            n_neg += 1
            np.testing.assert_array_equal(b, before)
            while (tk := int(lock_timeout(b, x))) >= 0:
                got.append(tk)
            r = int(lock_anchor(b, x))
        if r:
            got.append(x)
        np.testing.assert_array_equal(b, a)
    assert got == want
    assert n_neg > 0 and len(got) > len(t) // 2
