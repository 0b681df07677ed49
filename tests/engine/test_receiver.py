"""Frame decoding to SI: batch decoder, live receiver, and their lockstep equality."""

from __future__ import annotations

import math

import numpy as np
import pytest

from lde.can.codec import encode_frames, si_to_dbc
from lde.can.e2e import E2EStatus
from lde.can.frames import FrameBatch
from lde.can.profiles import INPUT_NAMES, load_profile
from lde.engine.grid import build_grid
from lde.engine.receiver import Receiver, decode_batch
from lde.units import STEP_NS

T0 = 1_700_000_000_000_000_000  # ns, an epoch-based log time base


@pytest.fixture(scope="module")
def lde():
    return load_profile("lde")


@pytest.fixture(scope="module")
def hyundai():
    return load_profile("hyundai")


def si_columns(profile, message, n, rng):
    """Random SI inputs of one message (inside the DBC ranges) -> (si dict, dbc signal dict)."""
    si = {}
    for name in profile.spec(message).inputs:
        if name == "speed":
            si[name] = rng.uniform(5.0, 40.0, n)
        elif name == "steering_rate" and profile.name == "hyundai":
            si[name] = rng.uniform(0.0, 5.0, n)  # SAS_Speed is unsigned on the car
        elif name in ("steering_angle", "yaw_rate", "steering_rate"):
            si[name] = rng.uniform(-0.5, 0.5, n)
        elif name == "lat_accel":
            si[name] = rng.uniform(-8.0, 8.0, n)
        else:  # torques
            si[name] = rng.uniform(-8.0, 8.0, n)
    return si, si_to_dbc(profile, message, si)


def make_traffic(profile, seconds, rng, jitter_ns=200_000):
    """Periodic traffic of all input messages of ``profile`` -> (FrameBatch, {message: (t, si)})."""
    parts, truth = [], {}
    for k, spec in enumerate(profile.messages.values()):
        n = int(seconds * 1e9 / spec.period_ns)
        t = T0 + k * 1_000_000 + np.arange(n, dtype=np.int64) * spec.period_ns + rng.integers(0, jitter_ns, n)
        si, dbc = si_columns(profile, spec.name, n, rng)
        parts.append(encode_frames(profile, spec.name, t, dbc))
        truth[spec.name] = (t, si)
    return FrameBatch.concat(parts), truth


def resolution_si(profile, name):
    im = profile.inputs[name]
    msg = profile.db.get_message_by_name(im.message)
    return abs(im.factor) * max(msg.get_signal_by_name(s).scale for s in im.signals)


@pytest.mark.parametrize("pname", ["lde", "hyundai"])
def test_decode_of_encode_equals_input_within_resolution(pname):
    p = load_profile(pname)
    rng = np.random.default_rng(3)
    fb, truth = make_traffic(p, 2.0, rng)
    d = decode_batch(p, fb)
    for name in INPUT_NAMES:
        msg = p.inputs[name].message
        t, si = truth[msg]
        s = d.inputs[name]
        # clean traffic: every frame but the INITIAL one and the sync frame before trust is used
        assert np.array_equal(s.t_ns, t[2:])
        assert np.max(np.abs(s.value - si[name][2:])) <= resolution_si(p, name) / 2 + 1e-12, name
    for m in d.messages.values():
        assert m.stats.rejected == 0 and m.stats.lost == 0 and m.stats.malformed == 0
        assert m.stats.used == m.stats.received - 2


@pytest.mark.parametrize("pname", ["lde", "hyundai"])
def test_signs_left_positive_survive_the_bus(pname):
    p = load_profile(pname)
    si = {
        "column_torque": 1.0,
        "assist_torque": 3.0,
        "steering_angle": 0.2,
        "yaw_rate": 0.1,
        "lat_accel": 2.0,
    }
    frames = []
    for spec in p.messages.values():
        vals = {k: np.full(4, v) for k, v in si.items() if k in spec.inputs}
        if "speed" in spec.inputs:
            vals["speed"] = np.full(4, 20.0)
        t = T0 + np.arange(4, dtype=np.int64) * spec.period_ns
        frames.append(encode_frames(p, spec.name, t, si_to_dbc(p, spec.name, vals)))
    d = decode_batch(p, FrameBatch.concat(frames))
    for name, v in si.items():
        assert d.inputs[name].value[-1] == pytest.approx(v, abs=resolution_si(p, name))
        assert np.sign(d.inputs[name].value[-1]) == 1
    # and right (negative) stays negative
    frames = []
    for spec in p.messages.values():
        vals = {k: np.full(4, -v) for k, v in si.items() if k in spec.inputs}
        if "speed" in spec.inputs:
            vals["speed"] = np.full(4, 20.0)
        t = T0 + np.arange(4, dtype=np.int64) * spec.period_ns
        frames.append(encode_frames(p, spec.name, t, si_to_dbc(p, spec.name, vals)))
    d = decode_batch(p, FrameBatch.concat(frames))
    for name, v in si.items():
        assert d.inputs[name].value[-1] == pytest.approx(-v, abs=resolution_si(p, name))


def test_unknown_and_extended_ids_are_ignored(lde):
    rng = np.random.default_rng(4)
    fb, _ = make_traffic(lde, 0.5, rng)
    ref = decode_batch(lde, fb)
    n = 50
    noise = FrameBatch(
        t_ns=T0 + rng.integers(0, 500_000_000, n),
        can_id=np.where(np.arange(n) % 2 == 0, 0x2A0, 0x123).astype(np.uint32),  # 0x2A0 as a 29-bit id
        is_extended=np.arange(n) % 2 == 0,
        dlc=np.full(n, 8, np.uint8),
        data=rng.integers(0, 256, (n, 8), dtype=np.uint8),
        is_rx=np.ones(n, np.bool_),
    )
    d = decode_batch(lde, FrameBatch.concat([fb, noise]))
    assert d.n_ignored == n
    for name in INPUT_NAMES:
        assert np.array_equal(d.inputs[name].value, ref.inputs[name].value)
    assert d.stats == ref.stats
    r = Receiver(lde)
    assert r.feed(T0, 0x2A0, bytes(8), 8, is_extended=True).ignored
    assert r.feed(T0, 0x7FF, bytes(8), 8).ignored
    assert r.n_ignored == 2


def test_malformed_frames_are_counted_never_raised(lde, hyundai):
    rng = np.random.default_rng(5)
    fb, _ = make_traffic(lde, 0.5, rng)
    idx = np.flatnonzero(fb.can_id == 0x2A0)[10:60:10]
    fb.dlc[idx] = 7  # truncated MDPS frames
    fb.dlc[np.flatnonzero(fb.can_id == 0x2A8)[3]] = 12  # an FD frame longer than the message
    d = decode_batch(lde, fb)
    assert d.messages["MDPS_Sensors"].stats.malformed == 5
    assert d.messages["ESC_Motion"].stats.malformed == 1
    assert d.messages["MDPS_Sensors"].stats.lost == 5  # the receiver saw the counter gaps
    assert d.messages["MDPS_Sensors"].stats.nonewdata == 0
    r = Receiver(lde)
    for data, dlc in [(b"", 0), (bytes(3), 3), (bytes(64), 64), (bytes(8), 7), (bytes(4), 8)]:
        st = r.feed(T0, 0x2A0, data, dlc)
        assert st.malformed and st.message == "MDPS_Sensors"
    assert r.stats["MDPS_Sensors"].malformed == 5
    assert r.e2e_rejects == 5
    # SAS11 is 5 bytes on the car: 8 bytes is malformed there
    rh = Receiver(hyundai)
    assert rh.feed(T0, 688, bytes(8), 8).malformed
    assert not rh.feed(T0, 688, bytes(5), 5).malformed


def inject_faults(fb: FrameBatch, rng, n_crc=5, n_dup=4, n_drop=6, gap_at=None, gap_ns=0):
    """Corrupt, duplicate and drop some frames; optionally open a gap (timeout) after ``gap_at``."""
    n = len(fb)
    crc_idx = rng.choice(np.arange(20, n - 20), n_crc, replace=False)
    data = fb.data.copy()
    data[crc_idx, 4] ^= 0x01
    t = fb.t_ns.copy()
    if gap_at is not None:
        t[t > gap_at] += gap_ns
    out = FrameBatch(t, fb.can_id, fb.is_extended, fb.dlc, data, fb.is_rx)
    dup_idx = rng.choice(np.setdiff1d(np.arange(20, n - 20), crc_idx), n_dup, replace=False)
    keep = np.ones(n, np.bool_)
    drop_idx = rng.choice(
        np.setdiff1d(np.arange(20, n - 20), np.concatenate([crc_idx, dup_idx])), n_drop, replace=False
    )
    keep[drop_idx] = False
    dups = out.take(dup_idx)
    dups = FrameBatch(dups.t_ns + 1000, dups.can_id, dups.is_extended, dups.dlc, dups.data, dups.is_rx)
    return FrameBatch.concat([out.select(keep), dups]), crc_idx, dup_idx, drop_idx


def test_faults_rejected_and_counted_by_cause(lde):
    rng = np.random.default_rng(6)
    mdps = encode_frames(
        lde, "MDPS_Sensors", T0 + np.arange(1000, dtype=np.int64) * STEP_NS, {"ColumnTorque": 1.0}
    )
    fb, crc_idx, dup_idx, drop_idx = inject_faults(mdps, rng, n_crc=5, n_dup=4, n_drop=1)
    d = decode_batch(lde, fb)
    s = d.messages["MDPS_Sensors"].stats
    assert s.wrong_crc == 5
    assert s.repeated == 4
    assert s.lost == 5 + 1  # the CRC-rejected frames and the dropped one are gaps in the sequence
    assert s.wrong_sequence == 0
    counts = d.messages["MDPS_Sensors"].status_counts()
    assert counts[E2EStatus.WRONGCRC] == 5 and counts[E2EStatus.REPEATED] == 4
    # after each fault the message is untrusted for sync_frames - 1 good frames
    assert s.used == s.received - s.rejected - 2 - 5


def _same(a, b):
    return a == b or (isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b))


def assert_samples_equal(a, b):
    assert a.t_ns == b.t_ns
    for name in INPUT_NAMES:
        assert _same(a.value(name), b.value(name)), (name, a.value(name), b.value(name))
    assert dict(a.valid) == dict(b.valid)
    assert dict(a.age_ns) == dict(b.age_ns)
    assert (a.mdps_ok, a.esc_ok) == (b.mdps_ok, b.esc_ok)


@pytest.mark.parametrize("pname", ["lde", "hyundai"])
def test_lockstep_live_receiver_equals_batch_decode_and_grid(pname):
    """Feeding frames one by one and sampling at the grid times gives the batch grid exactly."""
    p = load_profile(pname)
    rng = np.random.default_rng(8)
    fb, _ = make_traffic(p, 3.0, rng)
    fb, *_ = inject_faults(
        fb, rng, n_crc=12, n_dup=8, n_drop=15, gap_at=T0 + 1_500_000_000, gap_ns=150_000_000
    )
    n = 30
    extra = FrameBatch(  # unknown ids, 29-bit frames, malformed frames
        t_ns=T0 + rng.integers(0, 3_000_000_000, n),
        can_id=rng.choice([m.frame_id for m in p.messages.values()] + [0x100], n).astype(np.uint32),
        is_extended=rng.random(n) < 0.3,
        dlc=rng.choice([3, 8], n).astype(np.uint8),
        data=rng.integers(0, 256, (n, 8), dtype=np.uint8),
        is_rx=np.ones(n, np.bool_),
    )
    fb = FrameBatch.concat([fb, extra])
    d = decode_batch(p, fb)
    g = build_grid(d, p)
    assert len(g) > 500 and g.mdps_ok.any() and (~g.mdps_ok).any()

    r = Receiver(p)
    statuses = {m: [] for m in p.messages}
    i = 0
    for k in range(len(g)):
        tk = int(g.t_ns[k])
        while i < len(fb) and fb.t_ns[i] <= tk:
            dlc = int(fb.dlc[i])
            st = r.feed(
                int(fb.t_ns[i]),
                int(fb.can_id[i]),
                fb.data[i, : min(dlc, 8)].tobytes(),
                dlc,
                bool(fb.is_extended[i]),
            )
            if st.status is not None:
                statuses[st.message].append(int(st.status))
            i += 1
        assert_samples_equal(r.sample(tk), g.row(k))
    for m, md in d.messages.items():
        k = len(statuses[m])
        assert statuses[m] == list(md.status[:k])
    # feed the rest: the counters then equal the batch's
    while i < len(fb):
        dlc = int(fb.dlc[i])
        r.feed(
            int(fb.t_ns[i]),
            int(fb.can_id[i]),
            fb.data[i, : min(dlc, 8)].tobytes(),
            dlc,
            bool(fb.is_extended[i]),
        )
        i += 1
    assert r.stats == d.stats
    assert r.n_ignored == d.n_ignored


def test_receiver_sample_before_any_frame_is_nan_and_not_ok(lde):
    s = Receiver(lde).sample(T0)
    assert all(math.isnan(s.value(n)) for n in INPUT_NAMES)
    assert not any(s.valid.values()) and not s.mdps_ok and not s.esc_ok


def test_receiver_timed_out_reports_nonewdata_per_message(lde):
    r = Receiver(lde)
    fb = encode_frames(lde, "ESC_Motion", T0 + np.arange(4, dtype=np.int64) * 10_000_000, {})
    for i in range(len(fb)):
        r.feed(int(fb.t_ns[i]), int(fb.can_id[i]), fb.data[i].tobytes(), 8)
    last = int(fb.t_ns[-1])
    assert r.timed_out(last) == {"MDPS_Sensors": True, "ESC_Motion": False}
    assert r.timed_out(last + 30_000_001)["ESC_Motion"]


# ------------------------------------------------------------------ FrameBatch (the decoder's input)


def test_frame_batch_messages_round_trip_and_microsecond_timestamps():
    import can

    from lde.can.frames import ns_to_seconds, seconds_to_ns

    msgs = [
        can.Message(
            timestamp=1_700_000_000.123457, arbitration_id=0x2A0, is_extended_id=False, data=bytes(range(8))
        ),
        can.Message(
            timestamp=1_700_000_000.000001, arbitration_id=0x18FF0001, is_extended_id=True, data=b"\x01\x02"
        ),
        can.Message(
            timestamp=1_700_000_000.5, arbitration_id=0x1, is_extended_id=False, is_remote_frame=True, dlc=8
        ),
        can.Message(timestamp=1_700_000_000.6, is_error_frame=True),
        can.Message(
            timestamp=1_700_000_000.7, arbitration_id=0x3D1, is_extended_id=False, data=b"\x00", is_rx=False
        ),
    ]
    fb = FrameBatch.from_messages(msgs)
    assert len(fb) == 3  # remote and error frames carry no data: skipped
    assert list(fb.t_ns) == [1_700_000_000_000_001_000, 1_700_000_000_123_457_000, 1_700_000_000_700_000_000]
    assert list(fb.dlc) == [2, 8, 1] and list(fb.is_extended) == [True, False, False]
    assert list(fb.is_rx) == [True, True, False]
    assert fb.data[0].tobytes() == b"\x01\x02" + bytes(6)
    back = fb.to_messages()
    assert [m.timestamp for m in back] == [1_700_000_000.000001, 1_700_000_000.123457, 1_700_000_000.7]
    assert back[1].data == bytes(range(8)) and back[0].data == b"\x01\x02" and not back[2].is_rx
    for ts in (0.0, 2e-6, 1_700_000_000.999999, 1_234_567.000001):
        assert ns_to_seconds(seconds_to_ns(ts)) == ts


def test_frame_batch_sort_is_stable_and_select_concat():
    t = np.array([5, 1, 5, 3, 1], np.int64)
    fb = FrameBatch(t, np.arange(5), np.zeros(5, bool), np.full(5, 8), np.zeros((5, 8)), np.ones(5, bool))
    s = fb.sort()
    assert list(s.t_ns) == [1, 1, 3, 5, 5] and list(s.can_id) == [1, 4, 3, 0, 2]
    assert s.sort() is s
    both = FrameBatch.concat([s, s.select(s.can_id > 2)])
    assert list(both.t_ns) == [1, 1, 1, 3, 3, 5, 5]
    assert list(both.can_id) == [1, 4, 4, 3, 3, 0, 2]  # equal times keep their order
    assert len(FrameBatch.concat([])) == 0 and len(fb[1:3]) == 2
    with pytest.raises(ValueError):
        fb.select(np.ones(3, bool))


def test_hyundai_whl_spd_checksum_verified_mdps12_checksum_not(hyundai):
    t = T0 + np.arange(20, dtype=np.int64) * 20_000_000
    whl = encode_frames(
        hyundai, "WHL_SPD11", t, si_to_dbc(hyundai, "WHL_SPD11", {"speed": np.full(20, 25.0)})
    )
    whl.data[10, 0] ^= 0x04  # a wheel-speed bit: the checksum no longer matches
    mdps = encode_frames(hyundai, "MDPS12", t, {"CR_Mdps_StrTq": 1.0})
    mdps.data[10, 3] ^= 0xFF  # CF_Mdps_Chksum2 (24|8): algorithm unknown, not verified
    mdps.data[12, 2] = (int(mdps.data[12, 2]) + 5) % 256  # CF_Mdps_MsgCount2 jumps: the counter is checked
    d = decode_batch(hyundai, FrameBatch.concat([whl, mdps]))
    assert d.messages["WHL_SPD11"].stats.wrong_crc == 1
    assert d.messages["WHL_SPD11"].status[10] == E2EStatus.WRONGCRC
    assert d.messages["MDPS12"].stats.wrong_crc == 0
    assert d.messages["MDPS12"].status[10] == E2EStatus.OK
    assert d.messages["MDPS12"].status[12] == E2EStatus.WRONGSEQUENCE
    assert d.inputs["speed"].value == pytest.approx(25.0, abs=0.03125 / 3.6)
