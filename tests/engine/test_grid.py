"""The 3.9 ms step grid: anchoring, sample-and-hold, staleness, trust (lde.engine.grid)."""

from __future__ import annotations

import numpy as np
import pytest

from lde.can.codec import encode_frames
from lde.can.frames import FrameBatch
from lde.can.profiles import INPUT_NAMES, load_profile
from lde.engine.grid import build_grid, step_times
from lde.engine.receiver import decode_batch
from lde.units import STEP_NS

T0 = 1_700_000_000_000_000_000
MS = 1_000_000


@pytest.fixture(scope="module")
def lde():
    return load_profile("lde")


def mdps(p, t, torque):
    return encode_frames(
        p, "MDPS_Sensors", np.asarray(t, np.int64), {"ColumnTorque": np.asarray(torque, float)}
    )


def esc(p, t, speed_kmh):
    return encode_frames(
        p, "ESC_Motion", np.asarray(t, np.int64), {"VehicleSpeed": np.asarray(speed_kmh, float)}
    )


def test_grid_anchored_at_first_accepted_mdps_frame(lde):
    t_m = T0 + 500_000 + np.arange(300) * STEP_NS + np.arange(300) % 7 * 10_000
    t_e = T0 + np.arange(120) * 10 * MS
    fb = FrameBatch.concat([mdps(lde, t_m, np.arange(300) * 0.001), esc(lde, t_e, 80.0)])
    d = decode_batch(lde, fb)
    g = build_grid(d, lde)
    # frames 0 (INITIAL) and 1 (sync) are not used: the grid starts at the third MDPS frame
    assert g.t_ns[0] == t_m[2]
    assert np.all(np.diff(g.t_ns) == STEP_NS)
    assert g.t_ns[-1] <= fb.t_ns[-1] < g.t_ns[-1] + STEP_NS
    assert g.column_torque[0] == pytest.approx(0.002)
    g2 = build_grid(d, lde, t_start_ns=T0, t_end_ns=T0 + 10 * STEP_NS)
    assert np.array_equal(g2.t_ns, step_times(T0, T0 + 10 * STEP_NS))
    assert len(g2) == 11


def test_sample_and_hold_is_latest_accepted_at_or_before_step(lde):
    rng = np.random.default_rng(2)
    t_m = T0 + np.cumsum(rng.integers(1 * MS, 4 * MS, 200))  # irregular but within the timeout
    tq = rng.uniform(-5, 5, 200)
    fb = mdps(lde, t_m, tq)
    d = decode_batch(lde, fb)
    steps = np.sort(T0 + rng.integers(0, int(t_m[-1] - T0) + 20 * MS, 300))
    steps = np.concatenate([steps, t_m[50:55]])  # steps exactly on frame times take that frame
    steps.sort()
    g = build_grid(d, lde, step_times_ns=steps)
    assert np.array_equal(g.t_ns, steps)
    acc_t = d.inputs["column_torque"].t_ns
    acc_v = d.inputs["column_torque"].value
    for k, tk in enumerate(steps):
        before = np.flatnonzero(acc_t <= tk)
        if before.size == 0:
            assert np.isnan(g.column_torque[k]) and not g.valid["column_torque"][k]
        else:
            j = before[-1]
            assert g.column_torque[k] == acc_v[j]
            assert g.age_ns["column_torque"][k] == tk - acc_t[j]
            assert g.valid["column_torque"][k] == (tk - acc_t[j] <= lde.messages["MDPS_Sensors"].timeout_ns)


def test_stale_exactly_after_the_timeout_and_value_held(lde):
    t_e = T0 + np.arange(5) * 10 * MS  # ESC frames at 0..40 ms, then silence
    t_m = T0 + np.arange(40) * STEP_NS
    d = decode_batch(lde, FrameBatch.concat([esc(lde, t_e, 72.0), mdps(lde, t_m, 0.5)]))
    timeout = lde.messages["ESC_Motion"].timeout_ns  # 30 ms
    last = t_e[-1]
    g = build_grid(d, lde, step_times_ns=np.array([T0 + 5 * MS, last, last + timeout, last + timeout + 1]))
    assert np.isnan(g.speed[0]) and not g.esc_ok[0]  # before the first accepted ESC frame
    assert g.valid["speed"][1] and g.esc_ok[1]
    assert g.valid["speed"][2] and g.esc_ok[2]  # age == timeout is still fresh
    assert not g.valid["speed"][3] and not g.esc_ok[3]  # one ns later: stale
    assert g.speed[3] == pytest.approx(20.0)  # the stale value is held (72 km/h)
    assert all(g.mdps_ok[1:3])  # the MDPS side is unaffected


def test_mdps_not_ok_while_untrusted_after_a_crc_error(lde):
    t_m = T0 + np.arange(30) * STEP_NS
    fb = mdps(lde, t_m, 1.0)
    fb.data[10, 3] ^= 0x40  # frame 10 fails its CRC
    fb = FrameBatch.concat([fb, esc(lde, T0 + np.arange(13) * 10 * MS, 50.0)])
    d = decode_batch(lde, fb)
    g = build_grid(d, lde, step_times_ns=t_m)
    # frames 2..9 trusted; 10 WRONGCRC, 11 first good (sync 1 left), 12 trusted again
    assert all(g.mdps_ok[3:10])
    assert not g.mdps_ok[10] and not g.mdps_ok[11]
    assert g.valid["column_torque"][10] and g.valid["column_torque"][11]  # fresh, but not trusted
    assert g.mdps_ok[12]


def test_empty_and_mdps_less_input_give_an_empty_grid(lde):
    d = decode_batch(lde, FrameBatch.empty())
    g = build_grid(d, lde)
    assert len(g) == 0 and all(g.values(n).shape == (0,) for n in INPUT_NAMES)
    d = decode_batch(lde, esc(lde, T0 + np.arange(10) * 10 * MS, 50.0))
    assert len(build_grid(d, lde)) == 0
    g = build_grid(d, lde, t_start_ns=T0)
    assert len(g) > 0 and not g.mdps_ok.any() and g.esc_ok.any()


def test_merge_lookup_equals_searchsorted():
    from lde.engine.grid import latest_at_or_before

    rng = np.random.default_rng(9)
    ref = np.sort(rng.integers(0, 1000, 300))  # with duplicates
    for query in (np.sort(rng.integers(-10, 1010, 500)), rng.integers(-10, 1010, 500), ref.copy()):
        assert np.array_equal(latest_at_or_before(ref, query), np.searchsorted(ref, query, side="right") - 1)
    assert np.array_equal(latest_at_or_before(ref[:0], np.arange(3)), np.full(3, -1))
