"""lde.can.watch: a missing input message is reported (name, id, where, profile, what arrived instead),
repeated at a slow rate, and its return is reported."""

from __future__ import annotations

from collections import Counter

import numpy as np

from lde.can.profiles import load_profile
from lde.can.watch import InputWatch, describe_ids, profile_fit

MS = 10**6
S = 10**9


def _ids(name: str) -> dict[str, int]:
    return {m: s.frame_id for m, s in load_profile(name).messages.items()}


def test_profile_fit_names_the_profile_the_ids_belong_to() -> None:
    hy = set(_ids("hyundai").values())
    fits = profile_fit(frozenset(hy | {0x7FF}))
    assert fits[0].profile == "hyundai" and fits[0].complete
    assert all(f.profile != "lde" for f in fits)  # no lde input id among them
    assert profile_fit(frozenset({0x7FF})) == []
    text = describe_ids(Counter({i: 10 for i in hy}), load_profile("lde"))
    assert "fit profile hyundai (4 of its 4" in text
    assert describe_ids(Counter(), load_profile("lde")) == "no frame arrived at all"
    assert "none of them is an input" in describe_ids(Counter({0x7FF: 3}), load_profile("lde"))
    lde_ids = set(_ids("lde").values())
    stalled = describe_ids(Counter({i: 10 for i in lde_ids}), load_profile("lde"))
    assert "all of this profile's (lde) inputs arrived before" in stalled and "only" not in stalled


def test_wrong_profile_warns_after_the_timeouts_then_slowly() -> None:
    lde = load_profile("lde")
    w = InputWatch(lde, "virtual channel 'x'", warn_timeouts=10, repeat_ns=30 * S)
    hy = _ids("hyundai")
    t = 0
    first_warning = None
    lines_total = []
    while t < 95 * S:
        for fid in hy.values():
            w.saw(fid, t)
        got = w.check(t)
        lines_total += got
        if got and first_warning is None:
            first_warning = t
        t += 10 * MS
    # MDPS_Sensors times out after 11.7 ms (10 timeouts: 117 ms), ESC_Motion after 30 ms (300 ms): a
    # bus where neither ever came gets one warning naming both, once the longer time has passed
    assert first_warning is not None and 300 * MS <= first_warning <= 310 * MS
    warns = [text for lvl, text in lines_total if lvl == "warning"]
    assert "MDPS_Sensors (0x2A0) never received" in warns[0]
    assert "ESC_Motion (0x2A8) never received" in warns[0]
    assert "virtual channel 'x'" in warns[0] and "profile lde" in warns[0]
    assert "fit profile hyundai" in warns[0]
    # then every 30 s: 0.3, 30.3, 60.3, 90.3
    assert len(warns) == 4, warns
    assert w.warnings == len(warns)


def test_a_message_that_stops_and_comes_back() -> None:
    lde = load_profile("lde")
    w = InputWatch(lde, "udp_multicast channel 'g'")
    ids = _ids("lde")
    lines: list[tuple[str, str]] = []
    for k in range(0, 3000):  # 10 ms per tick: 30 s
        t = k * 10 * MS
        stopped = 5 * S <= t < 8 * S
        w.saw(ids["ESC_Motion"], t)
        if not stopped:
            w.saw(ids["MDPS_Sensors"], t)
        lines += w.check(t)
    warns = [x for lvl, x in lines if lvl == "warning"]
    infos = [x for lvl, x in lines if lvl == "info"]
    assert len(warns) == 1 and "MDPS_Sensors (0x2A0) none for 0.1" in warns[0]
    assert "ESC_Motion" not in warns[0]
    assert len(infos) == 1 and "MDPS_Sensors (0x2A0) arrives again (missing for 3.0 s)" in infos[0]


def test_saw_many_equals_saw() -> None:
    lde = load_profile("lde")
    rng = np.random.default_rng(1)
    ids = rng.choice(np.array([0x2A0, 0x2A8, 0x123], np.uint32), 500)
    ts = np.sort(rng.integers(0, 5 * S, 500)).astype(np.int64)
    a, b = InputWatch(lde, "x"), InputWatch(lde, "x")
    a.saw_many(ids, ts)
    for i, t in zip(ids.tolist(), ts.tolist(), strict=True):
        b.saw(i, t)
    assert a.ids == b.ids
    assert a.missing(6 * S) == b.missing(6 * S)
    assert a.check(20 * S) == b.check(20 * S)
