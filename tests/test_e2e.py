"""AUTOSAR E2E Profile 1 CRC, the receiver state machine, the sender, and the hyundai integrity checks."""

from __future__ import annotations

import numpy as np
import pytest

from lde.can.e2e import (
    INTEGRITY,
    P01_SCHEME,
    E2EStatus,
    IntegrityScheme,
    P01Receiver,
    P01Sender,
    ReceiverConfig,
    check_batch,
    check_frame,
    new_state,
    p01_check,
    p01_crc,
    p01_crc_batch,
    protect_frame,
    read_counter,
    read_counter_batch,
    receive_batch,
    toyota_checksum,
    whl_spd11_checksum,
    whl_spd11_checksum_batch,
)

MS = 1_000_000  # ns per ms


def crc8_bitwise(data: bytes, poly: int = 0x1D, init: int = 0x00) -> int:
    """Independent reference: MSB-first CRC-8 bit by bit (no table, no final xor)."""
    crc = init
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def p01_crc_reference(data_id: int, payload: bytes) -> int:
    """SPEC section 3: CRC over data-id low byte, high byte, payload bytes 1..7."""
    return crc8_bitwise(bytes([data_id & 0xFF, (data_id >> 8) & 0xFF]) + payload[1:])


# ----------------------------------------------------------------------------------- CRC


def test_spec_example_crc_0x2f_all_three_implementations():
    frame = bytes([0x00, 0x01, 0, 0, 0, 0, 0, 0])
    assert p01_crc_reference(0x2A0, frame) == 0x2F
    assert p01_crc(0x2A0, frame) == 0x2F
    assert p01_crc_batch(0x2A0, np.frombuffer(frame, np.uint8).reshape(1, 8))[0] == 0x2F
    assert p01_check(0x2A0, bytes([0x2F]) + frame[1:])


@pytest.mark.parametrize("data_id", [0x2A0, 0x2A8, 0x3D0, 0x3D1, 0x3D2, 0x123, 0x7FF])
def test_batch_crc_matches_autosar_e2e_and_bitwise_on_random_frames(data_id):
    rng = np.random.default_rng(data_id)
    data = rng.integers(0, 256, size=(300, 8), dtype=np.uint8)
    batch = p01_crc_batch(data_id, data)
    for row, c in zip(data, batch, strict=True):
        assert c == p01_crc(data_id, row.tobytes()) == p01_crc_reference(data_id, row.tobytes())


def test_crc_detects_single_bit_flips_and_wrong_data_id():
    buf = bytearray([0, 3, 0x12, 0x34, 0x56, 0x78, 0x9A, 0xBC])
    protect_frame(P01_SCHEME, 0x2A0, buf, counter=3)
    assert p01_check(0x2A0, buf)
    assert not p01_check(0x2A8, buf)  # masquerade: same payload, other message
    for bit in range(8, 64):
        bad = bytearray(buf)
        bad[bit // 8] ^= 1 << (bit % 8)
        assert not p01_check(0x2A0, bad)
        assert not check_batch(P01_SCHEME, 0x2A0, np.frombuffer(bytes(bad), np.uint8).reshape(1, 8))[0]


def test_counter_read_scalar_and_batch():
    rng = np.random.default_rng(1)
    data = rng.integers(0, 256, size=(50, 8), dtype=np.uint8)
    batch = read_counter_batch(P01_SCHEME, data)
    assert [read_counter(P01_SCHEME, r.tobytes()) for r in data] == list(batch)
    assert list(batch) == list(data[:, 1] & 0x0F)


# ----------------------------------------------------------------------------------- sender


def test_sender_counts_0_to_14_and_wraps_and_every_frame_checks():
    s = P01Sender(0x3D1, counter_start=12)
    seen = []
    for _ in range(20):
        buf = bytearray([0, 0xA0, 1, 2, 3, 4, 5, 6])
        s.protect(buf)
        seen.append(buf[1] & 0x0F)
        assert buf[1] >> 4 == 0x0A  # high nibble of byte 1 is payload, kept
        assert p01_check(0x3D1, buf)
    assert seen[:5] == [12, 13, 14, 0, 1]
    assert 15 not in seen


def test_sender_rejects_invalid_counter_start():
    with pytest.raises(ValueError):
        P01Sender(0x3D1, counter_start=15)


# ----------------------------------------------------------------------------------- receiver


def _rx(sync_frames: int = 2, timeout_ms: int = 30, max_delta: int = 2) -> P01Receiver:
    return P01Receiver(
        ReceiverConfig(timeout_ns=timeout_ms * MS, max_delta=max_delta, sync_frames=sync_frames)
    )


def feed_counters(rx: P01Receiver, counters, period_ms: int = 10, crc_ok=None):
    out = []
    for i, c in enumerate(counters):
        ok = True if crc_ok is None else crc_ok[i]
        out.append(rx.receive(i * period_ms * MS, c, ok))
    return out


def test_initial_then_ok_and_trust_after_two_good_frames():
    rx = _rx()
    assert rx.status_at(0) is E2EStatus.NONEWDATA
    st = []
    acc = []
    for i, c in enumerate([5, 6, 7, 8]):
        st.append(rx.receive(i * 10 * MS, c, True))
        acc.append(rx.accepted)
    assert st == [E2EStatus.INITIAL, E2EStatus.OK, E2EStatus.OK, E2EStatus.OK]
    assert acc == [False, False, True, True]
    assert rx.trusted
    assert rx.stats.used == 2 and rx.stats.initial == 1


@pytest.mark.parametrize("sync", [0, 1, 3])
def test_sync_frames_is_configurable(sync):
    rx = _rx(sync_frames=sync)
    acc = []
    for i in range(6):
        rx.receive(i * 10 * MS, i, True)
        acc.append(rx.accepted)
    # INITIAL is never used; then `sync` good frames are needed (the last of them is used)
    first_used = acc.index(True)
    assert first_used == max(sync, 1)
    assert all(acc[first_used:])


def test_counter_wraps_14_to_0_as_ok_and_15_is_rejected():
    rx = _rx()
    st = feed_counters(rx, [12, 13, 14, 0, 1, 15, 2])
    assert st[:5] == [E2EStatus.INITIAL, E2EStatus.OK, E2EStatus.OK, E2EStatus.OK, E2EStatus.OK]
    assert st[5] is E2EStatus.WRONGSEQUENCE
    assert rx.stats.wrong_sequence == 1
    # 15 is not taken as the new reference: 2 follows 1 in sequence
    assert st[6] is E2EStatus.OK


def test_each_status_reached_and_counted_by_cause():
    rx = _rx()
    st = feed_counters(
        rx,
        [0, 1, 2, 2, 4, 10, 11, 12, 13, 14],
        crc_ok=[True, True, True, True, True, True, True, False, True, True],
    )
    assert st == [
        E2EStatus.INITIAL,
        E2EStatus.OK,
        E2EStatus.OK,
        E2EStatus.REPEATED,
        E2EStatus.OKSOMELOST,  # 3 lost
        E2EStatus.WRONGSEQUENCE,  # jump of 6 > MaxDeltaCounter 2
        E2EStatus.OK,
        E2EStatus.WRONGCRC,
        E2EStatus.OKSOMELOST,  # 13 after 11: the CRC-rejected 12 counts as lost
        E2EStatus.OK,
    ]
    s = rx.stats
    assert (s.repeated, s.wrong_sequence, s.wrong_crc) == (1, 1, 1)
    assert s.rejected == 3
    assert s.lost == 2
    assert s.received == 10
    # timeout without frames: NONEWDATA, then a re-init at the next frame
    assert rx.status_at(9 * 10 * MS + 31 * MS) is E2EStatus.NONEWDATA
    assert rx.status_at(9 * 10 * MS + 30 * MS) is None
    assert rx.receive(200 * MS, 0, True) is E2EStatus.INITIAL
    assert rx.stats.nonewdata == 1
    assert not rx.trusted


def test_faults_drop_trust_until_sync_frames_good_frames():
    rx = _rx(sync_frames=2)
    feed_counters(rx, [0, 1, 2, 3])
    assert rx.trusted
    t = 40 * MS
    assert rx.receive(t, 4, False) is E2EStatus.WRONGCRC
    assert not rx.trusted and not rx.accepted
    assert rx.receive(t + 10 * MS, 5, True) is E2EStatus.OKSOMELOST
    assert not rx.trusted and not rx.accepted
    assert rx.receive(t + 20 * MS, 6, True) is E2EStatus.OK
    assert rx.trusted and rx.accepted
    # a repeated frame is rejected but does not cost trust
    assert rx.receive(t + 30 * MS, 6, True) is E2EStatus.REPEATED
    assert rx.trusted and not rx.accepted


def test_max_delta_counter_configurable():
    rx = _rx(max_delta=4)
    st = feed_counters(rx, [0, 1, 2, 6, 11])
    assert st[3] is E2EStatus.OKSOMELOST and rx.stats.lost == 3
    assert st[4] is E2EStatus.WRONGSEQUENCE


def test_receive_frame_checks_crc_itself_with_autosar_e2e():
    tx = P01Sender(0x2A0)
    rx = P01Receiver(ReceiverConfig(timeout_ns=12 * MS), data_id=0x2A0)
    for i in range(5):
        buf = tx.protect(bytearray([0, 0, i, 0, 0, 0, 0, 0]))
        if i == 3:
            buf[4] ^= 0x10
        st = rx.receive_frame(i * 4 * MS, buf)
    assert st is E2EStatus.OKSOMELOST  # frame 3 was rejected (WRONGCRC) and counted as lost
    assert rx.stats.wrong_crc == 1


def test_lockstep_scalar_receiver_equals_jitted_batch_loop():
    """The live class and the batch loop share one jitted step: same statuses, flags and counts."""
    rng = np.random.default_rng(42)
    n = 3000
    cfg = ReceiverConfig(timeout_ns=30 * MS)
    counters = np.zeros(n, np.int64)
    t = np.zeros(n, np.int64)
    c, tt = 0, 0
    for i in range(n):
        r = rng.random()
        if r < 0.03:
            c = (c + int(rng.integers(2, 6))) % 15  # losses / jumps
        elif r < 0.05:
            pass  # repeat
        elif r < 0.06:
            c = 15  # invalid
        else:
            c = (c + 1) % 15 if c != 15 else 0
        counters[i] = c
        tt += 10 * MS if rng.random() > 0.01 else 45 * MS  # occasional timeout gap
        t[i] = tt
    crc_ok = rng.random(n) > 0.02

    rx = P01Receiver(cfg)
    s_live, a_live, tr_live = [], [], []
    for i in range(n):
        s_live.append(int(rx.receive(int(t[i]), int(counters[i]), bool(crc_ok[i]))))
        a_live.append(rx.accepted)
        tr_live.append(rx.trusted)

    state = new_state()
    st = np.empty(n, np.uint8)
    acc = np.empty(n, np.bool_)
    tr = np.empty(n, np.bool_)
    receive_batch(state, cfg.as_array(), t, counters, crc_ok, st, acc, tr)
    assert list(st) == s_live
    assert list(acc) == a_live
    assert list(tr) == tr_live
    assert np.array_equal(state, rx.state)
    seen = set(s_live)
    assert {int(s) for s in E2EStatus if s is not E2EStatus.NONEWDATA} <= seen
    assert rx.stats.nonewdata > 0


# ----------------------------------------------------------------------------------- hyundai

WHL = IntegrityScheme.of(
    INTEGRITY["hyundai_whl_spd11"],
    counter_fields=((14, 2, True), (30, 2, True)),
    checksum_fields=((46, 2, True), (62, 2, True)),
)


def whl_checksum_reference(data: bytes) -> int:
    """SPEC: count the 1-bits of all 8 bytes except the top two bits of bytes 1, 3, 5, 7; (count ^ 9) & 15."""
    count = 0
    for i, b in enumerate(data):
        for j in range(8):
            if i in (1, 3, 5, 7) and j >= 6:
                continue
            count += (b >> j) & 1
    return (count ^ 9) & 15


def test_whl_spd11_checksum_scalar_batch_reference_agree():
    rng = np.random.default_rng(7)
    data = rng.integers(0, 256, size=(500, 8), dtype=np.uint8)
    batch = whl_spd11_checksum_batch(data)
    for row, c in zip(data, batch, strict=True):
        assert c == whl_spd11_checksum(row.tobytes()) == whl_checksum_reference(row.tobytes())


def test_whl_spd11_protect_and_check_split_fields():
    buf = bytearray((90 * 32).to_bytes(2, "little") * 4)  # 90 km/h on all wheels, counter/checksum 0
    protect_frame(WHL, 902, buf, counter=13)  # 13 = 0b1101: LSB half 0b01 at bit 14, MSB half 0b11 at 30
    assert (buf[1] >> 6) == 0b01 and (buf[3] >> 6) == 0b11
    assert read_counter(WHL, buf) == 13
    chk = (buf[5] >> 6) | ((buf[7] >> 6) << 2)
    assert chk == whl_checksum_reference(bytes(buf))
    assert check_frame(WHL, 902, buf)
    assert check_batch(WHL, 902, np.frombuffer(bytes(buf), np.uint8).reshape(1, 8))[0]
    bad = bytearray(buf)
    bad[0] ^= 0x01  # one more/less 1-bit in a wheel speed
    assert not check_frame(WHL, 902, bad)


def test_counter_only_scheme_wraps_at_its_width():
    sch = IntegrityScheme.of(INTEGRITY["counter"], counter_fields=((16, 8, True),), checksum_fields=())
    assert (sch.modulus, sch.invalid_counter) == (256, -1)
    rx = P01Receiver(ReceiverConfig.for_scheme(sch, timeout_ns=30 * MS), scheme=sch)
    st = feed_counters(rx, [253, 254, 255, 0, 1, 3])
    assert st[3] is E2EStatus.OK and st[5] is E2EStatus.OKSOMELOST
    assert check_frame(sch, 593, bytes(8))  # checksum not verified: always passes


# ----------------------------------------------------------------------------------- toyota


def toyota_reference(can_id: int, data: bytes) -> int:
    """The README's formula: (id & 0xFF) + (id >> 8) + DLC + sum(bytes 0..len-2), mod 256."""
    return ((can_id & 0xFF) + (can_id >> 8) + len(data) + sum(data[:-1])) & 0xFF


TOYOTA = IntegrityScheme.of(
    INTEGRITY["toyota_checksum"], counter_fields=(), checksum_fields=((63, 8, False),)
)


def test_toyota_checksum_matches_the_formula_and_protect_check_round_trip():
    rng = np.random.default_rng(3)
    for _ in range(200):
        can_id = int(rng.integers(0, 0x800))
        data = bytes(rng.integers(0, 256, 8, dtype=np.uint8))
        assert toyota_checksum(can_id, data) == toyota_reference(can_id, data)
        buf = bytearray(data)
        protect_frame(TOYOTA, can_id, buf, counter=0)
        assert buf[:7] == data[:7] and buf[7] == toyota_reference(can_id, data)
        assert check_frame(TOYOTA, can_id, buf)
        bad = bytearray(buf)
        bad[int(rng.integers(0, 7))] ^= 1 << int(rng.integers(0, 8))
        assert not check_frame(TOYOTA, can_id, bad)


def test_a_message_without_counter_is_trusted_after_its_sync_frames_and_never_out_of_sequence():
    rx = P01Receiver(ReceiverConfig.for_scheme(TOYOTA, timeout_ns=60 * MS), data_id=0x260, scheme=TOYOTA)
    statuses = []
    for k in range(6):
        buf = bytearray(8)
        buf[0] = k  # any content; no counter
        protect_frame(TOYOTA, 0x260, buf, counter=0)
        statuses.append(rx.receive_frame(k * 20 * MS, buf))
    assert statuses[0] is E2EStatus.INITIAL and all(s is E2EStatus.OK for s in statuses[1:])
    assert rx.trusted and rx.stats.used == 4 and rx.stats.lost == 0
    buf = bytearray(8)
    protect_frame(TOYOTA, 0x260, buf, counter=0)
    buf[7] ^= 0xFF
    assert rx.receive_frame(6 * 20 * MS, buf) is E2EStatus.WRONGCRC and not rx.trusted


def test_integrity_registry_names_what_each_check_needs():
    assert set(INTEGRITY) == {"none", "counter", "autosar_e2e_p01", "toyota_checksum", "hyundai_whl_spd11"}
    assert INTEGRITY["autosar_e2e_p01"].counter == "required"
    assert (
        INTEGRITY["toyota_checksum"].checksum == "required"
        and INTEGRITY["toyota_checksum"].counter == "optional"
    )
    assert not INTEGRITY["counter"].verifies_checksum and INTEGRITY["hyundai_whl_spd11"].verifies_checksum
    assert len({i.code for i in INTEGRITY.values()}) == len(INTEGRITY)
