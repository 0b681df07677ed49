"""lde.can.busio, how lde uses a python-can bus: a drain takes every frame that arrived whatever the bus
does with filters, udp_multicast buses hear only their own group, the kernel socket filter passes
exactly the input ids (and any datagram it does not recognise), and buses are named as python-can
names them."""

from __future__ import annotations

import socket
import time

import can
import pytest

from lde.can.busio import (
    ERROR_FRAME,
    NOT_DATA,
    BusIO,
    bus_label,
    drain,
    message_fields,
    open_bus,
    receive_only,
    udp_datagram_layout,
)
from lde.can.frames import seconds_to_ns
from lde.testing.bus import private_multicast

msgpack = pytest.importorskip("msgpack")

INPUTS = [0x2A0, 0x2A8]
OVERLAY = 0x2B0


def _open(kw: dict) -> can.BusABC:
    try:
        return open_bus(**kw)
    except Exception as exc:  # pragma: no cover - no multicast on this host
        pytest.skip(f"udp_multicast not available: {exc}")


@pytest.fixture
def udp():
    kw = private_multicast()
    a, b = _open(kw), _open(kw)
    try:
        yield a, b
    finally:
        a.shutdown()
        b.shutdown()


def _burst(tx: can.BusABC, rounds: int) -> None:
    """A simulator's view of the bus: per round its own MDPS frame, the service's overlay frame, its
    own ESC frame (the multicast loopback hands a sender its own datagrams too)."""
    for _ in range(rounds):
        for cid in (0x2A0, OVERLAY, 0x2A8):
            tx.send(can.Message(arbitration_id=cid, is_extended_id=False, data=bytes(8)))
    time.sleep(0.2)


def test_python_cans_software_filter_ends_a_poll_loop_early_and_drain_does_not(udp) -> None:
    """The root cause of the open loop over udp_multicast: with filters set, python-can filters in
    software and ``recv(0)`` returns None at the first frame it rejects, frames still queued."""
    rx, tx = udp
    rx.set_filters([{"can_id": OVERLAY, "can_mask": 0x7FF, "extended": False}])
    _burst(tx, 30)
    polled = []
    while (m := rx.recv(0.0)) is not None:
        polled.append(m)
    assert len(polled) < 30  # python-can's behaviour: the loop stopped at a rejected frame
    rest = list(drain(rx))
    assert len(polled) + len(rest) == 30
    assert all(m.arbitration_id == OVERLAY for m in rest)


def test_the_services_poll_reads_past_frames_the_filter_rejects(udp) -> None:
    rx, tx = udp
    rx.set_filters([{"can_id": OVERLAY, "can_mask": 0x7FF, "extended": False}])
    _burst(tx, 20)
    io = BusIO(rx)
    got = []
    while (f := io.recv(0.0)) is not None:
        got.append(f)
    assert len(got) == 20 and {f[1] for f in got} == {OVERLAY}


def test_drain_keeps_what_is_over_its_limit_for_the_next_call(udp) -> None:
    rx, tx = udp
    _burst(tx, 10)
    first = list(drain(rx, 16))
    assert len(first) == 16
    assert len(list(drain(rx))) == 14


def test_udp_socket_filter_passes_the_input_ids_only(udp) -> None:
    rx, tx = udp
    assert receive_only(rx, INPUTS) == "kernel (socket filter on udp_multicast)"
    assert rx.filters is None  # python-can itself filters nothing: every frame it reads is wanted
    for fid in (0x7F, 0x2A0, 0x3D0, 0x3D1, 0x2A8, 0x7FF, 0x2B0):
        tx.send(can.Message(arbitration_id=fid, data=bytes(8), is_extended_id=False))
    tx.send(can.Message(arbitration_id=0x2A0, data=bytes(8), is_extended_id=True))
    time.sleep(0.1)
    got = [m.arbitration_id for m in drain(rx) if not m.is_extended_id]
    assert got == [0x2A0, 0x2A8]


def test_udp_socket_filter_passes_a_datagram_of_another_layout() -> None:
    """The filter knows python-can's datagram layout; anything else reaches python-can, which decodes
    it, and the consumer filters: a layout change costs speed, never a frame."""
    # the same fields in another key order: python-can decodes it (a map), the filter does not know it
    fields = {
        "arbitration_id": 0x2A0,
        "timestamp": 0.0,
        "is_extended_id": False,
        "is_remote_frame": False,
        "is_error_frame": False,
        "channel": None,
        "dlc": 2,
        "data": b"\x01\x02",
        "is_fd": False,
        "bitrate_switch": False,
        "error_state_indicator": False,
    }
    kw = private_multicast()
    a = _open(kw)
    try:
        assert receive_only(a, [0x3D0]) == "kernel (socket filter on udp_multicast)"
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
            s.sendto(msgpack.packb(fields, use_bin_type=True), (kw["channel"], kw["port"]))
        time.sleep(0.1)
        got = list(drain(a))
        assert [(m.arbitration_id, bytes(m.data)) for m in got] == [(0x2A0, b"\x01\x02")]
    finally:
        a.shutdown()


def test_the_layout_comes_from_python_cans_packer_and_another_one_gets_no_filter() -> None:
    layout = udp_datagram_layout()
    assert layout is not None
    fixed, at, two_bytes = layout
    from can.interfaces.udp_multicast.utils import pack_message

    for cid in (0x100, 0x2A0, 0x7FF):
        d = pack_message(
            can.Message(timestamp=123.456, arbitration_id=cid, is_extended_id=False, data=b"\x01")
        )
        assert int.from_bytes(d[at : at + 2], "big") == cid and d[at - 1] == two_bytes
        assert all(d[i] == b for i, b in fixed)

    def as_text(msg: can.Message) -> bytes:  # a packer of another shape
        return f"{msg.timestamp}:{msg.arbitration_id}".encode()

    assert udp_datagram_layout(as_text) is None


def test_a_udp_bus_hears_its_own_group_only() -> None:
    """Linux hands a socket bound to a port the datagrams of every group joined on that port; two
    users with different groups and the same port would hear each other."""
    kw = private_multicast()
    other = dict(kw, channel=kw["channel"].rsplit(".", 1)[0] + ".255")
    mine, theirs, peer = _open(kw), _open(other), _open(kw)
    try:
        theirs.send(can.Message(arbitration_id=0x2A0, data=bytes(8), is_extended_id=False))
        peer.send(can.Message(arbitration_id=0x2A8, data=bytes(8), is_extended_id=False))
        time.sleep(0.1)
        assert [m.arbitration_id for m in drain(mine)] == [0x2A8]
    finally:
        for b in (mine, theirs, peer):
            b.shutdown()


def test_a_virtual_bus_gets_no_filter_the_consumer_filters() -> None:
    v = can.Bus(interface="virtual", channel="lde-test-busio-virtual")
    try:
        assert receive_only(v, INPUTS).startswith("none")
        assert v.filters is None
    finally:
        v.shutdown()


def test_buses_are_named_interface_colon_channel() -> None:
    assert bus_label(interface="socketcan", channel="vcan0") == "socketcan:vcan0"
    assert bus_label(interface="udp_multicast", channel="239.74.1.2", port=47311) == (
        "udp_multicast:239.74.1.2 port 47311"
    )
    # python-can's own defaults, named (the group and port every user who gives none shares)
    from can.interfaces.udp_multicast import UdpMulticastBus

    assert (
        bus_label(interface="udp_multicast")
        == f"udp_multicast:{UdpMulticastBus.DEFAULT_GROUP_IPv6} port 43113"
    )


def test_message_fields_of_every_kind_of_frame() -> None:
    ts = 1_790_000_000.123456
    data = can.Message(timestamp=ts, arbitration_id=0x2A0, data=bytes(range(1, 9)), is_extended_id=False)
    assert message_fields(data) == (
        seconds_to_ns(ts),
        0x2A0,
        False,
        8,
        int.from_bytes(bytes(range(1, 9)), "little"),
    )
    err = can.Message(timestamp=ts, is_error_frame=True, arbitration_id=0x4, data=bytes(8))
    assert message_fields(err) == (seconds_to_ns(ts), ERROR_FRAME, False, 0, 0x4)
    rtr = can.Message(timestamp=ts, arbitration_id=0x2A0, is_remote_frame=True, dlc=8, is_extended_id=False)
    assert message_fields(rtr)[1] == NOT_DATA
    fd = can.Message(
        timestamp=ts, arbitration_id=0x123, data=bytes(range(12)), is_fd=True, is_extended_id=False
    )
    assert message_fields(fd)[3:] == (12, int.from_bytes(bytes(range(12)), "little"))  # every byte


#: frames of every kind the SocketCAN path must read like python-can
FRAMES = [
    can.Message(arbitration_id=0x2A0, data=bytes(range(1, 9)), is_extended_id=False),
    can.Message(arbitration_id=0x2A8, data=b"\xff\x00\x7f", is_extended_id=False),
    can.Message(arbitration_id=0x100, data=b"", is_extended_id=False),
    can.Message(arbitration_id=0x18DAF110, data=b"\x02\x10\x03", is_extended_id=True),
    can.Message(arbitration_id=0x2A0, is_remote_frame=True, dlc=8, is_extended_id=False),
    can.Message(is_error_frame=True, arbitration_id=0x4, data=bytes(8)),
    can.Message(arbitration_id=0x123, data=bytes(range(12)), is_fd=True, is_extended_id=False),
]


@pytest.mark.parametrize("msg", FRAMES, ids=lambda m: f"{m.arbitration_id:x}-{len(m.data)}")
def test_socketcan_frames_read_as_python_can_reads_them(msg) -> None:
    """Linux's can_frame / canfd_frame (the kernel ABI) against python-can's own packing and reading."""
    from can.interfaces.socketcan.socketcan import build_can_frame

    from lde.can.busio import socketcan_fields

    ts = 1_790_000_000.123456
    msg.timestamp = ts
    assert socketcan_fields(build_can_frame(msg), ts) == message_fields(msg)


def test_socketcan_len8_dlc_as_python_can_reads_it() -> None:
    from can.interfaces.socketcan.socketcan import build_can_frame, dissect_can_frame

    from lde.can.busio import socketcan_fields

    cf = bytearray(build_can_frame(can.Message(arbitration_id=0x2A0, data=bytes(8), is_extended_id=False)))
    cf[7] = 12  # a classic frame's len8_dlc (9..15 at 8 bytes of data)
    assert socketcan_fields(bytes(cf), 0.0)[3] == dissect_can_frame(bytes(cf))[1] == 12
