"""What one output frame's send costs: python-can's ``udp_multicast`` send (as the live service sends
it, :mod:`lde.can.busio`) against python-can's datagram bytes on a plain unicast UDP socket.

Two multicast buses: ``multicast`` with ``hop_limit`` 0 (the IPv4 TTL; what
:func:`lde.testing.bus.private_multicast` and ``bench/bench_loop.py`` use: the datagram is delivered
to this host's members by the multicast loopback only) and ``multicast_ttl1`` with python-can's
default ``hop_limit`` 1, where each datagram is also handed to the network card (``eth0``; on this VM
a virtio queue whose kick is an exit to the hypervisor: ``perf record -g`` shows ``vp_notify`` /
``iowrite16`` under ``udp_sendmsg``).

Per round the four output datagrams of a step (``LDE_Estimate``, ``LDE_Overlay``, ``LDE_Disturbance``,
``LDE_Diag``: 165 bytes each) are sent back to back and each ``sendto`` is timed; "cold": a 3.5 ms
sleep before each round (as live, once per 3.9 ms period), "hot": rounds back to back. The multicast
group has two members besides the sender's loopback, as in ``bench/bench_loop.py``: the simulator's
socket (here one in this process, drained between rounds) and the service's own, which the service's
socket filter (:func:`lde.can.busio.receive_only`) drops in the kernel; the unicast socket sends to one
bound receiver on 127.0.0.1, drained the same way.

    python bench/bench_sendto.py [--rounds 3000] [--idle sleep|spin] [--json]

``--idle spin``: instead of sleeping 3.5 ms before a "cold" round, keep the CPU busy for 3.5 ms (a
loop on the clock): does the first send's extra cost come from the CPU's idle state?

Medians and 99th percentiles in microseconds, the kinds interleaved round by round (same load).
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

from lde.can.busio import bus_io, drain
from lde.can.profiles import load_profile
from lde.service.service import set_input_filters
from lde.testing.bus import private_multicast

_SLEEP_S = 0.0035


def _drain(sock: socket.socket) -> None:
    while True:
        try:
            sock.recv(4096, socket.MSG_DONTWAIT)
        except BlockingIOError:
            return


def _datagram(msg: can.Message) -> bytes:
    """python-can's ``udp_multicast`` datagram of ``msg`` (what its ``send`` puts on the wire)."""
    from can.interfaces.udp_multicast.utils import pack_message

    return bytes(pack_message(msg))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3000)
    ap.add_argument("--frames", type=int, default=4, help="datagrams per round (a step's outputs)")
    ap.add_argument("--idle", choices=("sleep", "spin"), default="sleep", help="before a cold round")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    profile = load_profile("lde")
    buses, ios, txs, members = [], {}, {}, []
    for kind, hop in (("multicast", 0), ("multicast_ttl1", 1)):
        kw = {**private_multicast(), "hop_limit": hop}
        bus = can.Bus(**kw)
        member = can.Bus(**kw)  # the simulator's socket
        buses += [bus, member]
        set_input_filters(bus, profile)
        io = ios[kind] = bus_io(bus)
        txs[kind] = [
            io.tx(can.Message(arbitration_id=0x3A0 + j, is_extended_id=False, dlc=8, data=bytes(8)))
            for j in range(args.frames)
        ]
        members.append(member)
    datagrams = [_datagram(tx.msg) for tx in txs["multicast"]]
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    uni = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    dest = rx.getsockname()
    load0 = os.getloadavg()
    n, f = args.rounds, args.frames
    kinds = ("multicast", "multicast_ttl1", "unicast")
    t = {(kind, cold): np.zeros((n, f), np.int64) for kind in kinds for cold in (0, 1)}
    pc = time.perf_counter_ns
    for r in range(n):
        for cold in (0, 1):
            for kind in kinds:
                for m in members:
                    for _ in drain(m):
                        pass
                _drain(rx)
                out = t[kind, cold]
                if cold and args.idle == "sleep":
                    time.sleep(_SLEEP_S)
                elif cold:
                    busy_until = pc() + int(_SLEEP_S * 1e9)
                    while pc() < busy_until:
                        pass
                if kind == "unicast":
                    for j, d in enumerate(datagrams):
                        a = pc()
                        uni.sendto(d, dest)
                        out[r, j] = pc() - a
                    continue
                io = ios[kind]
                for j, tx in enumerate(txs[kind]):
                    a = pc()
                    io.send(tx, time.time())
                    out[r, j] = pc() - a
    skip = min(100, n // 10)
    res: dict[str, object] = {
        "load_avg": [round(x, 2) for x in (*load0, *os.getloadavg())],
        "rounds": n - skip,
        "frames": f,
        "bytes": len(datagrams[0]),
        "idle": args.idle,
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
    for b in buses:
        b.shutdown()
    if args.json:
        print(json.dumps(res))
        return 0
    print(
        f"sendto of {f} datagrams of {res['bytes']} B per round, {n - skip} rounds, cold: {args.idle} 3.5 ms;"
        f" load {res['load_avg']}"
    )
    print(f"{'':18} {'first p50/p99':>15} {'next p50/p99':>15} {'round p50/p99':>15} {'3 frames p50':>13}")
    for key in [f"{k}_{c}" for c in ("cold", "hot") for k in kinds]:
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
