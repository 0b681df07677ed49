"""lde.service.busio: the socket fast paths read and write exactly what python-can's recv/send would, and
every
bus that is not one of them (or a frame they do not recognise) goes through python-can."""

from __future__ import annotations

import time

import can
import numpy as np
import pytest

from lde.can.frames import seconds_to_ns
from lde.can.profiles import load_profile
from lde.params import load_vehicle
from lde.service.busio import ERROR_FRAME, NOT_DATA, BusIO, bus_io, message_fields, socketcan_fields
from lde.testing.bus import private_multicast

msgpack = pytest.importorskip("msgpack")
from can.interfaces.udp_multicast.utils import pack_message, unpack_message  # noqa: E402

TS = 1_790_000_000.123456789  # a receive timestamp [s] (epoch time, as the kernel gives it)

#: frames of every kind the fast paths must read like python-can: data frames of every length, ids
#: across the msgpack integer encodings, extended, remote, error, a channel name, an FD frame
FRAMES = [
    can.Message(arbitration_id=0x2A0, data=bytes(range(1, 9)), is_extended_id=False),
    can.Message(arbitration_id=0x2A8, data=b"\xff\x00\x7f", is_extended_id=False),
    can.Message(arbitration_id=0x100, data=b"", is_extended_id=False),
    can.Message(arbitration_id=0x7FF, data=b"\x80" * 8, is_extended_id=False),
    can.Message(arbitration_id=0x05, data=b"\x01", is_extended_id=False),  # msgpack fixint id
    can.Message(arbitration_id=0xC8, data=b"\x01\x02", is_extended_id=False),  # msgpack uint8 id
    can.Message(arbitration_id=0x18DAF110, data=b"\x02\x10\x03", is_extended_id=True),
    can.Message(arbitration_id=0x2A0, is_remote_frame=True, dlc=8, is_extended_id=False),
    can.Message(arbitration_id=0x2A0, data=b"\x01\x02", channel="can1", is_extended_id=False),
    can.Message(is_error_frame=True, arbitration_id=0x4, data=bytes(8)),
]


def _udp_pair() -> tuple[can.BusABC, can.BusABC]:
    kw = private_multicast()
    try:
        return can.Bus(**kw), can.Bus(**kw)
    except (can.CanError, OSError) as exc:  # pragma: no cover - no multicast on this host
        pytest.skip(f"udp_multicast not available: {exc}")


@pytest.fixture
def udp():
    a, b = _udp_pair()
    try:
        yield a, b
    finally:
        a.shutdown()
        b.shutdown()


def test_udp_multicast_gets_the_socket_path_and_other_buses_python_can(udp) -> None:
    a, _ = udp
    assert bus_io(a).kind == "udp_multicast (socket)"
    assert bus_io(a, fast=False).kind == "python-can"
    v = can.Bus(interface="virtual", channel="lde-test-busio")
    try:
        assert type(bus_io(v)) is BusIO
    finally:
        v.shutdown()


@pytest.mark.parametrize("msg", FRAMES, ids=lambda m: f"{m.arbitration_id:x}-{len(m.data)}")
def test_udp_datagram_parse_equals_python_cans_unpacking(udp, msg) -> None:
    io = bus_io(udp[0])
    msg.timestamp = 12.5  # the sender's stamp: replaced by the receive time, as python-can does
    d = pack_message(msg)
    want = message_fields(unpack_message(d, replace={"timestamp": TS}, check=True))
    assert io._parse(d, TS) == want
    if not (msg.is_error_frame or msg.is_remote_frame):
        assert want[0] == seconds_to_ns(TS) and want[1] == msg.arbitration_id


def test_udp_unreadable_datagram_is_a_can_error_like_python_cans(udp) -> None:
    io = bus_io(udp[0])
    with pytest.raises(can.CanOperationError):
        io._parse(b"\x8b not msgpack at all", TS)


def test_udp_prebuilt_datagram_is_python_cans_byte_for_byte(udp) -> None:
    io = bus_io(udp[0])
    tx = io.tx(can.Message(arbitration_id=0x3D1, is_extended_id=False, dlc=8, data=bytes(8)))
    tx.view[:] = np.arange(8, dtype=np.uint8) * 31
    from lde.service.busio import _BE_DOUBLE

    _BE_DOUBLE.pack_into(tx.buf, tx.ts_at, TS)
    ref = can.Message(timestamp=TS, arbitration_id=0x3D1, is_extended_id=False, data=bytes(tx.view))
    assert bytes(tx.buf) == pack_message(ref)
    assert tx.word() == int.from_bytes(bytes(tx.view), "little")


def test_udp_round_trip_both_ways_through_the_kernel(udp) -> None:
    """Fast send -> python-can recv, python-can send -> fast recv: the same frames, kernel stamps."""
    a, b = udp
    fa = bus_io(a)
    tx = fa.tx(can.Message(arbitration_id=0x3D0, is_extended_id=False, dlc=6, data=bytes(6)))
    tx.view[:] = [1, 2, 3, 4, 5, 6]
    t_send = time.time()
    fa.send(tx, t_send)
    got = b.recv(2.0)
    assert got is not None and got.arbitration_id == 0x3D0 and bytes(got.data) == bytes([1, 2, 3, 4, 5, 6])
    assert abs(got.timestamp - t_send) < 1.0  # the receiver's kernel stamp, not the sender's
    b.send(can.Message(arbitration_id=0x2A0, data=b"\x11\x22", is_extended_id=False))
    f = None
    deadline = time.monotonic() + 2.0
    while f is None or f[1] != 0x2A0:  # a's own datagram comes back by the multicast loopback
        f = fa.recv(0.5)
        assert time.monotonic() < deadline
    t_ns, can_id, ext, dlc, word = f
    assert (can_id, ext, dlc, word) == (0x2A0, False, 2, 0x2211)
    assert abs(t_ns / 1e9 - time.time()) < 1.0 and t_ns % 1000 == 0
    t = time.monotonic()
    while fa.recv(0.0) is not None:
        pass
    assert fa.recv(0.05) is None and time.monotonic() - t < 1.0


def test_service_over_udp_multicast_with_and_without_the_fast_path_gives_the_same_steps(udp) -> None:
    """The same frames in the same pending columns on both paths, so the same estimator steps."""
    from lde.can.codec import MessageEncoder, si_to_dbc
    from lde.clock import SimulatedClock
    from lde.service.service import Service
    from lde.units import DEG, KMH

    a, b = udp
    c = can.Bus(interface="udp_multicast", channel=a._multicast.group, port=a._multicast.port)
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    t0 = time.time_ns()
    try:
        svcs = [
            Service(bus, profile, vehicle, SimulatedClock(t0), backend="float", log_period_s=0, fast_io=fast)
            for bus, fast in ((a, True), (b, False))
        ]
        assert [s.io.kind for s in svcs] == ["udp_multicast (socket)", "python-can"]
        mdps = MessageEncoder(profile, "MDPS_Sensors")
        esc = MessageEncoder(profile, "ESC_Motion")
        mv = si_to_dbc(
            profile,
            "MDPS_Sensors",
            {"column_torque": 0.5, "assist_torque": 1.0, "steering_angle": 0.4 * DEG, "steering_rate": 0.0},
        )
        ev = si_to_dbc(profile, "ESC_Motion", {"yaw_rate": 0.01, "lat_accel": 0.1, "speed": 80 * KMH})
        rows: list[list[tuple]] = [[], []]
        times: list[list[int]] = [[], []]
        for k in range(60):
            c.send(mdps.message(mv, 0.0))
            if k % 3 == 0:
                c.send(esc.message(ev, 0.0))
            time.sleep(0.002)
            for s in svcs:
                s._drain()
            # each socket has its own kernel stamps: one step time after both sets of frames
            t_k = max(int(s._pt[s._np - 1]) for s in svcs if s._np) + 1000 if any(s._np for s in svcs) else t0
            for s, r, tt in zip(svcs, rows, times, strict=True):
                tt.extend(s._pt[: s._np].tolist())
                ids, words = s._pid[: s._np].tolist(), s._pdata[: s._np].tolist()
                r.append((ids, words, s.step_once(int(t_k)).fw))
        assert rows[0] == rows[1]
        assert sum(len(r[0]) for r in rows[0]) == 80
        assert np.abs(np.subtract(*times)).max() < 5_000_000  # two sockets' stamps of one datagram
        for s in svcs:
            assert s.send_errors == 0 and s.foreign == 0
    finally:
        c.shutdown()


def test_socketcan_frame_parse_equals_python_cans() -> None:
    from can.interfaces.socketcan.socketcan import build_can_frame, dissect_can_frame

    cases = [
        *(m for m in FRAMES if m.channel is None),
        can.Message(arbitration_id=0x123, data=bytes(range(12)), is_fd=True, is_extended_id=False),
    ]
    for msg in cases:
        cf = build_can_frame(msg)
        can_id, dlc, flags, data = dissect_can_frame(cf)
        ext = bool(can_id & 0x80000000)
        want = (
            (seconds_to_ns(TS), ERROR_FRAME, False, 0, can_id & 0x1FFFFFFF)
            if can_id & 0x20000000
            else (0, NOT_DATA, False, 0, 0)
            if can_id & 0x40000000
            else (
                seconds_to_ns(TS),
                can_id & (0x1FFFFFFF if ext else 0x7FF),
                ext,
                dlc,
                int.from_bytes(data, "little"),  # every data byte (CAN FD: up to 64)
            )
        )
        assert socketcan_fields(cf, TS) == want, msg
    # a classic frame's len8_dlc (9..15 at 8 bytes of data), as python-can reads it
    cf = bytearray(build_can_frame(can.Message(arbitration_id=0x2A0, data=bytes(8), is_extended_id=False)))
    cf[7] = 12
    assert socketcan_fields(bytes(cf), TS)[3] == dissect_can_frame(bytes(cf))[1] == 12
