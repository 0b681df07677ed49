"""Send -> receive latency and frame continuity on a real SocketCAN interface (vcan0 in UML).

Used by ``tests/uml/test_vcan_smoke.py`` (continuity asserted, latency only reported) and as a
script that prints the measurement as JSON:

    tests/uml/run_in_uml.sh python tests/uml/vcan_latency.py [--n 5000] [--period-us 1000]

Two python-can socketcan buses on the same interface: one sends frames carrying a counter, the
other receives them in a thread. Latencies per frame [us]:

* ``kernel``: kernel receive timestamp (SO_TIMESTAMP, ``msg.timestamp``) minus the wall time just
  before ``send()``;
* ``app``: wall time when ``recv()`` returned in the receiving thread minus the same send time.
"""

from __future__ import annotations

import argparse
import json
import socket
import struct
import threading
import time
from dataclasses import asdict, dataclass

import numpy as np


@dataclass
class LatencyResult:
    channel: str
    sent: int
    received: int
    in_order: bool
    lost: int
    kernel_us_p50: float
    kernel_us_p99: float
    app_us_p50: float
    app_us_p99: float
    app_us_max: float


def measure(
    channel: str = "vcan0",
    n: int = 2000,
    period_s: float = 0.001,
    can_id: int = 0x2A0,
    drain_s: float = 60.0,
) -> LatencyResult:
    """Send ``n`` frames at ``period_s`` on ``channel`` and time their reception (see module doc).

    The receiving socket gets a buffer for all ``n`` frames, so a receiver thread that a slow guest
    holds up loses nothing (a loss is then the interface's); after the last send it has up to
    ``drain_s`` to take the rest in.
    """
    import can

    tx = can.Bus(interface="socketcan", channel=channel)
    rx = can.Bus(interface="socketcan", channel=channel, can_filters=[{"can_id": can_id, "can_mask": 0x7FF}])
    _large_receive_buffer(rx, n * 1024)
    t_send = np.full(n, np.nan)
    t_kernel = np.full(n, np.nan)
    t_app = np.full(n, np.nan)
    order: list[int] = []
    done = threading.Event()

    def receiver() -> None:
        while len(order) < n and not done.is_set():
            msg = rx.recv(0.5)
            now = time.time()
            if msg is None:
                continue
            (k,) = struct.unpack_from("<I", msg.data, 0)
            if 0 <= k < n:
                t_kernel[k] = msg.timestamp
                t_app[k] = now
                order.append(k)

    th = threading.Thread(target=receiver, daemon=True)
    th.start()
    try:
        t_next = time.monotonic()
        for k in range(n):
            msg = can.Message(arbitration_id=can_id, is_extended_id=False, data=struct.pack("<I4x", k))
            t_send[k] = time.time()
            tx.send(msg)
            t_next += period_s
            delay = t_next - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        th.join(timeout=drain_s)
    finally:
        done.set()
        th.join(timeout=2.0)
        tx.shutdown()
        rx.shutdown()
    got = ~np.isnan(t_app)
    k_lat = (t_kernel[got] - t_send[got]) * 1e6
    a_lat = (t_app[got] - t_send[got]) * 1e6

    def pct(a: np.ndarray, q: float) -> float:
        return float(np.percentile(a, q)) if a.size else float("nan")

    return LatencyResult(
        channel=channel,
        sent=n,
        received=int(got.sum()),
        in_order=order == sorted(order),
        lost=int(n - got.sum()),
        kernel_us_p50=pct(k_lat, 50),
        kernel_us_p99=pct(k_lat, 99),
        app_us_p50=pct(a_lat, 50),
        app_us_p99=pct(a_lat, 99),
        app_us_max=float(a_lat.max()) if a_lat.size else float("nan"),
    )


def _large_receive_buffer(bus, size: int) -> None:
    """SO_RCVBUFFORCE (root, as in the guest) or SO_RCVBUF up to the system's limit."""
    sock = getattr(bus, "socket", None)
    if sock is None:
        return
    try:
        sock.setsockopt(socket.SOL_SOCKET, getattr(socket, "SO_RCVBUFFORCE", 33), size)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--channel", default="vcan0")
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--period-us", type=float, default=1000.0)
    a = ap.parse_args(argv)
    res = measure(a.channel, a.n, a.period_us * 1e-6)
    print(json.dumps(asdict(res), indent=1))
    return 0 if res.lost == 0 and res.in_order else 1


if __name__ == "__main__":
    raise SystemExit(main())
