"""lde.service.busio's SocketCAN fast path on a real vcan0: what it reads is what python-can's ``recv`` reads
(ids, data, the kernel's receive timestamp), and what it sends python-can receives.

Marked ``vcan``: runs only inside user-mode Linux (``tests/test_uml.py``); elsewhere skipped.
"""

from __future__ import annotations

import time

import pytest

can = pytest.importorskip("can")

from lde.can.frames import seconds_to_ns  # noqa: E402
from lde.service.busio import bus_io, message_fields  # noqa: E402

pytestmark = pytest.mark.vcan

CHANNEL = "vcan0"


@pytest.fixture
def buses():
    bs = [can.Bus(interface="socketcan", channel=CHANNEL) for _ in range(3)]
    yield bs
    for b in bs:
        b.shutdown()


def test_socketcan_fast_path_reads_what_python_can_reads(buses) -> None:
    tx, fast_bus, ref_bus = buses
    fast = bus_io(fast_bus)
    assert fast.kind == "socketcan (socket)"
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
    got_fast = [fast.recv(5.0) for _ in sent]
    got_ref = [ref_bus.recv(5.0) for _ in sent]
    assert all(f is not None for f in got_fast) and all(m is not None for m in got_ref)
    for s, f, m in zip(sent, got_fast, got_ref, strict=True):
        ref = message_fields(m)
        assert f[1:] == ref[1:]  # id, extended, dlc, data
        assert f[1] == s.arbitration_id and f[3] == len(s.data)
        # two sockets, one frame: the same kernel stamp (one skb), or within a millisecond
        assert abs(f[0] - ref[0]) <= 1_000_000 and f[0] == seconds_to_ns(f[0] / 1e9)
    assert fast.recv(0.0) is None


def test_socketcan_fast_path_sends_what_python_can_receives(buses) -> None:
    fast_bus, rx, _ = buses
    fast = bus_io(fast_bus)
    out = fast.tx(can.Message(arbitration_id=0x3D1, is_extended_id=False, dlc=8, data=bytes(8)))
    for k in range(20):
        out.view[:] = [k, 0xA5, 0, 0, 0, 0, 0, 0xFF]
        fast.send(out, time.time())
        m = rx.recv(5.0)
        assert m is not None and m.arbitration_id == 0x3D1 and not m.is_extended_id
        assert bytes(m.data) == bytes([k, 0xA5, 0, 0, 0, 0, 0, 0xFF])
