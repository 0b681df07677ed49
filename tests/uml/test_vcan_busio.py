"""lde.can.busio on a real vcan0: the input filters are SocketCAN's kernel filters, a drain takes every
frame that passes them, and what the service reads and sends on the bus's own socket is what
python-can reads and receives (ids, data, kernel timestamps).

Marked ``vcan``: runs only inside user-mode Linux (``tests/test_uml.py``); elsewhere skipped.
"""

from __future__ import annotations

import time

import pytest

can = pytest.importorskip("can")

from lde.can.busio import bus_io, drain, message_fields, receive_only  # noqa: E402
from lde.can.frames import seconds_to_ns  # noqa: E402

pytestmark = pytest.mark.vcan

CHANNEL = "vcan0"


@pytest.fixture
def buses():
    bs = [can.Bus(interface="socketcan", channel=CHANNEL) for _ in range(3)]
    yield bs
    for b in bs:
        b.shutdown()


def test_kernel_filters_pass_the_inputs_and_a_drain_takes_them_all(buses) -> None:
    tx, rx, _ = buses
    assert receive_only(rx, [0x2A0, 0x2A8]) == "kernel (SocketCAN filters)"
    for k in range(40):
        for cid in (0x2A0, 0x3D0, 0x2B0, 0x2A8):
            tx.send(can.Message(arbitration_id=cid, is_extended_id=False, data=bytes([k, 1, 2])))
    time.sleep(0.2)
    got = [(m.arbitration_id, m.data[0]) for m in drain(rx)]
    assert got == [(cid, k) for k in range(40) for cid in (0x2A0, 0x2A8)]


def test_the_services_frames_are_python_cans(buses) -> None:
    tx, svc_bus, ref_bus = buses
    io = bus_io(svc_bus)
    assert io.kind == "socketcan (descriptor)"
    sent = []
    for k in range(50):
        ext = k % 5 == 0
        msg = can.Message(
            arbitration_id=(0x1ABC000 + k) if ext else (0x100 + k),
            is_extended_id=ext,
            data=bytes([k, 1, 2, 3, 4, 5, 6, 7])[: k % 9],
        )
        tx.send(msg)
        sent.append(msg)
    got = [io.recv(5.0) for _ in sent]
    ref = [ref_bus.recv(5.0) for _ in sent]
    assert all(f is not None for f in got) and all(m is not None for m in ref)
    for s, f, m in zip(sent, got, ref, strict=True):
        assert f[1:] == message_fields(m)[1:]  # id, extended, dlc, data
        assert f[1] == s.arbitration_id and f[3] == len(s.data)
        # two sockets, one frame: the same kernel stamp (one skb), or within a millisecond
        assert abs(f[0] - m.timestamp * 1e9) <= 1_000_000 and f[0] == seconds_to_ns(f[0] / 1e9)
    assert io.recv(0.0) is None


def test_the_services_sends_reach_python_can(buses) -> None:
    svc_bus, rx, _ = buses
    io = bus_io(svc_bus)
    out = io.tx(can.Message(arbitration_id=0x3D1, is_extended_id=False, dlc=8, data=bytes(8)))
    for k in range(20):
        out.view[:] = [k, 0xA5, 0, 0, 0, 0, 0, 0xFF]
        io.send(out, time.time())
        m = rx.recv(5.0)
        assert m is not None and m.arbitration_id == 0x3D1 and not m.is_extended_id
        assert bytes(m.data) == bytes([k, 0xA5, 0, 0, 0, 0, 0, 0xFF])
    ext = io.tx(can.Message(arbitration_id=0x1ABCDEF, is_extended_id=True, dlc=3, data=bytes(3)))
    ext.view[:] = [7, 8, 9]
    io.send(ext, time.time())
    m = rx.recv(5.0)
    assert m is not None and (m.arbitration_id, m.is_extended_id, bytes(m.data)) == (
        0x1ABCDEF,
        True,
        b"\x07\x08\x09",
    )
    io.close()
