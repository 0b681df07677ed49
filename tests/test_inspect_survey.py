"""The log survey of ``lde inspect`` and which profile fits, on frames with known ids, channels,
periods and lengths."""

from __future__ import annotations

import numpy as np
import pytest

from lde.analysis.inspect.match import Wanted, match_profile, rank
from lde.analysis.inspect.survey import survey_log

T0 = 1_700_000_000 * 10**9


def frames(spec: list[tuple[int, int, float, int, float]], seconds: float = 10.0, seed: int = 0):
    """Columns of periodic frames: (channel index, id, period ms, length, jitter sd ms) each."""
    rng = np.random.default_rng(seed)
    cols: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "id", "dlc", "ch")}
    for ch, fid, period, length, sd in spec:
        n = int(seconds * 1000 / period)
        t = T0 + np.rint((np.arange(n) * period + sd * rng.standard_normal(n)) * 1e6).astype(np.int64)
        cols["t"].append(t)
        cols["id"].append(np.full(n, fid))
        cols["dlc"].append(np.full(n, length))
        cols["ch"].append(np.full(n, ch))
    c = {k: np.concatenate(v) for k, v in cols.items()}
    order = np.argsort(c["t"], kind="stable")
    return {k: v[order] for k, v in c.items()}


def test_the_survey_counts_each_id_per_channel_with_its_period_and_lengths():
    f = frames(
        [
            (0, 0x24, 12.0, 8, 0.0),
            (1, 0x24, 20.0, 8, 0.0),
            (0, 0x260, 20.0, 8, 1.0),
            (1, 0x7FF, 100.0, 3, 0.0),
        ]
    )
    s = survey_log(f["t"], f["id"], np.zeros(f["t"].size, bool), f["dlc"], f["ch"], ("can0", "can1"))
    assert s.channels == ("can0", "can1")
    assert [(x.channel, x.can_id) for x in s.ids] == [
        ("can0", 0x24),
        ("can0", 0x260),
        ("can1", 0x24),
        ("can1", 0x7FF),
    ]
    by = {(x.channel, x.can_id): x for x in s.ids}
    assert by["can0", 0x24].period_ms == pytest.approx(12.0) and by["can0", 0x24].jitter_ms == pytest.approx(
        0.0
    )
    assert by["can1", 0x24].frames == 500 and by["can1", 0x24].rate_hz == pytest.approx(50.0)
    # 1 ms sd on each time: periods of sd sqrt(2) ms, whose 5-95 % spread is 2 x 1.645 x sqrt(2) ms
    assert by["can0", 0x260].jitter_ms == pytest.approx(2 * 1.645 * 2**0.5, rel=0.15)
    assert by["can1", 0x7FF].lengths == (3,)
    assert s.duration_s == pytest.approx(10.0, abs=0.05)


def test_a_profile_fits_when_all_its_messages_arrive_with_their_length_on_one_channel():
    f = frames(
        [(1, 0x24, 12.0, 8, 0.0), (1, 0x25, 12.0, 8, 0.0), (0, 0x24, 12.0, 8, 0.0), (0, 0xAA, 12.0, 6, 0.0)]
    )
    s = survey_log(f["t"], f["id"], np.zeros(f["t"].size, bool), f["dlc"], f["ch"], ("can0", "can1"))
    car = match_profile(s, "car", [Wanted("A", 0x24, 8), Wanted("B", 0x25, 8)])
    assert car.fits and car.channel == "can1" and car.present == 2
    other = match_profile(s, "other", [Wanted("A", 0x24, 8), Wanted("W", 0xAA, 8), Wanted("Z", 0x123, 8)])
    assert not other.fits and other.present == 1
    why = other.why()
    assert (
        "W (0xAA, 8 B) arrives with another length (6 B on 'can0')" in why and "Z (0x123, 8 B) missing" in why
    )
    named = match_profile(s, "named", [Wanted("A", 0x24, 8), Wanted("B", 0x25, 8, channel="can0")])
    assert not named.fits and "B (0x25, 8 B) only on 'can1'" in named.why()
    assert [m.profile for m in rank([other, named, car])] == ["car", "named", "other"]


def test_an_empty_log_surveys_to_nothing():
    s = survey_log(np.zeros(0, np.int64), np.zeros(0), np.zeros(0, bool), np.zeros(0))
    assert s.frames == 0 and s.ids == ()
    assert match_profile(s, "x", [Wanted("A", 1, 8)]).present == 0
