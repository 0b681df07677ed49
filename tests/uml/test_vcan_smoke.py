"""Real SocketCAN smoke tests: python-can's socketcan interface and can-utils on vcan0.

Marked ``vcan``: they run only where a real vcan0 exists, i.e. inside user-mode Linux
(``tests/test_uml.py`` drives them there through ``tests/uml/run_in_uml.sh``); elsewhere they are
skipped with the reason (tests/conftest.py).
"""

from __future__ import annotations

import contextlib
import queue
import re
import shutil
import subprocess
import threading
import time

import pytest
from uml_bounds import stop_process

can = pytest.importorskip("can")

pytestmark = pytest.mark.vcan

CHANNEL = "vcan0"
CANSEND_S = 60.0  # bound of one cansend call [s]
CANDUMP_READY_S = 120.0  # bound for candump to print its first frame [s]
_CANDUMP_LINE = re.compile(r"^\((\d+\.\d+)\)\s+(\S+)\s+([0-9A-Fa-f]+)#([0-9A-Fa-f]*)$")


@pytest.fixture
def bus_pair():
    a = can.Bus(interface="socketcan", channel=CHANNEL)
    b = can.Bus(interface="socketcan", channel=CHANNEL)
    yield a, b
    a.shutdown()
    b.shutdown()


def _drain(bus) -> None:
    while bus.recv(0.0) is not None:
        pass


def test_python_can_round_trip(bus_pair):
    a, b = bus_pair
    _drain(b)
    sent = []
    for k in range(200):
        ext = k % 3 == 0
        can_id = (0x1ABC000 + k) if ext else (0x100 + k)
        msg = can.Message(
            arbitration_id=can_id, is_extended_id=ext, data=bytes([k & 0xFF, 0, 1, 2, 3, 4, 5, k >> 8])
        )
        a.send(msg)
        sent.append(msg)
    got = [b.recv(5.0) for _ in sent]
    assert all(m is not None for m in got)
    for s, r in zip(sent, got, strict=True):
        assert r.arbitration_id == s.arbitration_id
        assert r.is_extended_id == s.is_extended_id
        assert bytes(r.data) == bytes(s.data)
        assert r.channel == CHANNEL
    ts = [m.timestamp for m in got]
    assert ts == sorted(ts) and ts[0] > 1e9  # kernel receive timestamps, epoch seconds


def test_receive_filters(bus_pair):
    a, _ = bus_pair
    f = can.Bus(interface="socketcan", channel=CHANNEL, can_filters=[{"can_id": 0x2A0, "can_mask": 0x7FF}])
    try:
        for can_id in (0x111, 0x2A0, 0x2A8, 0x2A0):
            a.send(can.Message(arbitration_id=can_id, is_extended_id=False, data=b"\x01"))
        ids = []
        while (m := f.recv(0.5)) is not None:
            ids.append(m.arbitration_id)
        assert ids == [0x2A0, 0x2A0]
    finally:
        f.shutdown()


def test_can_fd_frame():
    a = can.Bus(interface="socketcan", channel=CHANNEL, fd=True)
    b = can.Bus(interface="socketcan", channel=CHANNEL, fd=True)
    try:
        payload = bytes(range(64))
        a.send(
            can.Message(
                arbitration_id=0x3D0, is_extended_id=False, is_fd=True, bitrate_switch=True, data=payload
            )
        )
        m = b.recv(5.0)
        assert m is not None and m.is_fd and bytes(m.data) == payload and m.dlc == 64
    finally:
        a.shutdown()
        b.shutdown()


@pytest.mark.skipif(shutil.which("cansend") is None, reason="can-utils (cansend) not installed")
def test_cansend_reaches_python_can():
    b = can.Bus(interface="socketcan", channel=CHANNEL)
    try:
        _drain(b)
        for frame in ("2A0#0011223344556677", "1ABCDEF0#CAFE"):
            t0 = time.monotonic()
            try:
                subprocess.run(["cansend", CHANNEL, frame], check=True, timeout=CANSEND_S)
            except subprocess.TimeoutExpired:
                pytest.skip(f"cansend did not end in {time.monotonic() - t0:.0f} s (guest too slow)")
        m1, m2 = b.recv(5.0), b.recv(5.0)
        assert (m1.arbitration_id, m1.is_extended_id, bytes(m1.data)) == (
            0x2A0,
            False,
            bytes.fromhex("0011223344556677"),
        )
        assert (m2.arbitration_id, m2.is_extended_id, bytes(m2.data)) == (0x1ABCDEF0, True, b"\xca\xfe")
    finally:
        b.shutdown()


@pytest.mark.skipif(shutil.which("candump") is None, reason="can-utils (candump) not installed")
def test_candump_logs_python_can_frames(tmp_path):
    """candump -L sees what python-can sends; its log reads back with python-can's reader."""
    proc = subprocess.Popen(["candump", "-L", CHANNEL], stdout=subprocess.PIPE, text=True, bufsize=1)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x.rstrip("\n")) for x in proc.stdout], daemon=True).start()
    a = can.Bus(interface="socketcan", channel=CHANNEL)
    try:
        # candump is ready once it prints our sync frame (no sleeps guessing its start-up time)
        t0 = time.monotonic()
        deadline = t0 + CANDUMP_READY_S
        first = None
        while first is None and time.monotonic() < deadline:
            a.send(can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"sync"))
            with contextlib.suppress(queue.Empty):
                first = lines.get(timeout=0.2)
        if first is None:
            pytest.skip(
                f"candump printed nothing in {time.monotonic() - t0:.0f} s (still running: "
                f"{proc.poll() is None}): guest too slow to start it"
            )
        frames = [(0x2A0 + k, bytes([k] * (k % 9))) for k in range(30)]
        for can_id, data in frames:
            a.send(can.Message(arbitration_id=can_id, is_extended_id=False, data=data))
        seen = []
        while len(seen) < len(frames) and time.monotonic() < deadline:
            try:
                line = lines.get(timeout=1.0)
            except queue.Empty:
                continue
            m = _CANDUMP_LINE.match(line)
            assert m, f"not a candump -L line: {line!r}"
            if int(m.group(3), 16) != 0x7FF:
                seen.append(line)
    finally:
        stop_process(proc, 30.0)
        a.shutdown()
    assert len(seen) == len(frames)
    log = tmp_path / "dump.log"
    log.write_text("\n".join(seen) + "\n")
    back = list(can.CanutilsLogReader(str(log)))
    assert [(m.arbitration_id, bytes(m.data)) for m in back] == frames
    assert all(m.channel == CHANNEL for m in back)


def test_latency_and_continuity(record_property):
    """Every frame arrives, in order; the latency is measured and reported, not asserted."""
    from vcan_latency import measure

    res = measure(CHANNEL, n=2000, period_s=0.001)
    for k, v in res.__dict__.items():
        record_property(k, v)
    print(
        f"\nvcan0 send->receive latency over {res.received} frames: kernel p50 {res.kernel_us_p50:.0f} us, "
        f"p99 {res.kernel_us_p99:.0f} us; application p50 {res.app_us_p50:.0f} us, "
        f"p99 {res.app_us_p99:.0f} us, max {res.app_us_max:.0f} us"
    )
    assert res.lost == 0
    assert res.in_order
