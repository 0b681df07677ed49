"""What one output frame's send costs: python-can's ``udp_multicast`` datagram on the multicast socket
(as the live service sends it, :mod:`lde.busio`) against the same bytes on a plain unicast UDP socket.

Per round the four output datagrams of a step (``LDE_Estimate``, ``LDE_Overlay``, ``LDE_Disturbance``,
``LDE_Diag``: 165 bytes each) are sent back to back and each ``sendto`` is timed; "cold": a 3.5 ms
sleep before each round (as live, once per 3.9 ms period), "hot": rounds back to back. The multicast
group has two members besides the sender's loopback, as in ``bench/bench_loop.py``: the simulator's
socket (here one in this process, drained between rounds) and the service's own, which the service's
socket filter (:func:`lde.service.set_input_filters`) drops in the kernel; the unicast socket sends to
one bound receiver on 127.0.0.1, drained the same way.

    python bench/bench_sendto.py [--rounds 3000] [--json]

Medians and 99th percentiles in microseconds, the two kinds interleaved round by round (same load).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import time

import can
import numpy as np

from lde.busio import bus_io
from lde.profiles import load_profile
from lde.service import set_input_filters
from lde.testing.bus import private_multicast

_SLEEP_S = 0.0035


def _drain(sock: socket.socket) -> None:
    while True:
        try:
            sock.recv(4096, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3000)
    ap.add_argument("--frames", type=int, default=4, help="datagrams per round (a step's outputs)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    kw = private_multicast()
    bus = can.Bus(**kw)
    member = can.Bus(**kw)  # the simulator's socket
    set_input_filters(bus, load_profile("lde"))
    io = bus_io(bus)
    txs = [
        io.tx(can.Message(arbitration_id=0x3A0 + j, is_extended_id=False, dlc=8, data=bytes(8)))
        for j in range(args.frames)
    ]
    if any(tx.buf is None for tx in txs):
        print("bench_sendto: python-can's datagram layout is not the one lde.busio patches", file=sys.stderr)
        return 2
    msock = member._multicast._socket  # type: ignore[attr-defined]
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    uni = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dest = rx.getsockname()
    load0 = os.getloadavg()
    n, f = args.rounds, args.frames
    t = {(kind, cold): np.zeros((n, f), np.int64) for kind in ("multicast", "unicast") for cold in (0, 1)}
    pc = time.perf_counter_ns
    for r in range(n):
        for cold in (0, 1):
            for kind in ("multicast", "unicast"):
                _drain(msock)
                _drain(rx)
                out = t[kind, cold]
                if cold:
                    time.sleep(_SLEEP_S)
                for j, tx in enumerate(txs):
                    a = pc()
                    if kind == "multicast":
                        io.send(tx, time.time())
                    else:
                        uni.sendto(tx.buf, dest)  # type: ignore[arg-type]
                    out[r, j] = pc() - a
    skip = min(100, n // 10)
    res: dict[str, object] = {
        "load_avg": [round(x, 2) for x in (*load0, *os.getloadavg())],
        "rounds": n - skip,
        "frames": f,
        "bytes": len(txs[0].buf),  # type: ignore[arg-type]
    }
    for (kind, cold), a in t.items():
        a = a[skip:] / 1e3
        key = f"{kind}_{'cold' if cold else 'hot'}"
        res[key] = {
            "first_p50_us": round(float(np.median(a[:, 0])), 1),
            "first_p99_us": round(float(np.percentile(a[:, 0], 99)), 1),
            "next_p50_us": round(float(np.median(a[:, 1:])), 1),
            "next_p99_us": round(float(np.percentile(a[:, 1:], 99)), 1),
            "round_p50_us": round(float(np.median(a.sum(axis=1))), 1),
            "round_p99_us": round(float(np.percentile(a.sum(axis=1), 99)), 1),
            "first3_p50_us": round(float(np.median(a[:, :3].sum(axis=1))), 1),
        }
    bus.shutdown()
    member.shutdown()
    if args.json:
        print(json.dumps(res))
        return 0
    print(f"sendto of {f} datagrams of {res['bytes']} B per round, {n - skip} rounds; load {res['load_avg']}")
    print(f"{'':18} {'first p50/p99':>15} {'next p50/p99':>15} {'round p50/p99':>15} {'3 frames p50':>13}")
    for key in ("multicast_cold", "unicast_cold", "multicast_hot", "unicast_hot"):
        v = res[key]
        assert isinstance(v, dict)
        print(
            f"{key:18} {v['first_p50_us']:>7}/{v['first_p99_us']:<7}"
            f" {v['next_p50_us']:>7}/{v['next_p99_us']:<7}"
            f" {v['round_p50_us']:>7}/{v['round_p99_us']:<7} {v['first3_p50_us']:>13}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
