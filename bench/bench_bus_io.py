"""What the service's bus I/O costs per step on python-can's ``udp_multicast``: the drain of the frames
that arrived (an MDPS frame every step, an ESC frame every 2.5 steps, as the simulator sends them) and
the four output sends (``LDE_Estimate``, ``LDE_Overlay``, ``LDE_Disturbance``, ``LDE_Diag``).

Three ways, side by side (one private group and port each, interleaved step by step, so that all see
the same load):

* ``lde.can.busio (python-can)`` (the service's path, :func:`lde.can.busio.bus_io`): ``bus.recv(0)``
until
  None and ``bus.send``, with the kernel socket filter :func:`lde.can.busio.receive_only` attaches (the
  service's own outputs, which the multicast loopback hands back, never reach Python);
* ``python-can, software filters``: the same with python-can's filters instead of the socket filter
  (what a bus without one costs: python-can decodes every frame, the service's own included, and
  the drain reads on past those it rejects);
* ``raw socket``: the reference, python-can bypassed: ``recvmsg`` on the bus's descriptor
  (``bus.fileno()``) with only the id read from the datagram, and python-can's datagram packed once,
  its timestamp patched and ``sendto`` per output (what lde did before it used python-can's API;
  its parse and its send were about this).

``--socketcan CHANNEL`` (a real vcan0, inside user-mode Linux: ``tests/uml/run_in_uml.sh``): the same
on SocketCAN with kernel filters, the service's path (the bus's descriptor,
:class:`lde.can.busio._SocketcanIO`) against python-can's ``recv``/``send``;
every bus is on the one channel, so each sees every way's input frames (the same
count for all).

Each step sleeps ``--gap-ms`` first (default 3.5: the live loop runs once per 3.9 ms, and the caches
cool in between). Medians and 99th percentiles in microseconds.

    python bench/bench_bus_io.py [--steps 3000] [--gap-ms 3.5] [--socketcan CH]
        [--json]
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import struct
import sys
import time
from collections.abc import Callable

import can
import numpy as np

from lde.can.busio import BusIO, bus_io, open_bus, receive_only
from lde.can.profiles import load_profile
from lde.testing.bus import private_multicast

_DONTWAIT = getattr(socket, "MSG_DONTWAIT", 0)


class RawSocketIO:
    """The reference: the bus's socket without python-can (recvmsg; prebuilt datagrams, sendto)."""

    def __init__(self, bus: can.BusABC, kw: dict) -> None:
        from can.interfaces.udp_multicast.utils import pack_message

        self.sock = socket.socket(fileno=socket.dup(bus.fileno()))
        self.dest = (kw["channel"], kw["port"])
        probe = [
            pack_message(can.Message(timestamp=ts, arbitration_id=0x100, is_extended_id=False, data=b""))
            for ts in (0.0, 1.5)
        ]
        self.ts_at = min(i for i in range(len(probe[0])) if probe[0][i] != probe[1][i])
        self.id_at = 36  # python-can 4.x's datagram: the 11-bit id's two bytes (checked below)
        d = pack_message(can.Message(arbitration_id=0x2A0, is_extended_id=False, data=b""))
        if d[self.id_at : self.id_at + 2] != b"\x02\xa0":
            raise SystemExit("bench_bus_io: python-can's datagram layout is not the one the reference reads")
        self.pack = pack_message

    def recv(self, timeout: float) -> tuple[int, int] | None:
        try:
            d, anc, _, _ = self.sock.recvmsg(256, 64, _DONTWAIT)
        except BlockingIOError:
            return None
        return (struct.unpack_from("@ll", anc[0][2])[0], (d[self.id_at] << 8) | d[self.id_at + 1])

    def tx(self, msg: can.Message) -> bytearray:
        return bytearray(self.pack(msg))

    def send(self, buf: bytearray, t_s: float) -> None:
        struct.pack_into(">d", buf, self.ts_at, t_s)
        self.sock.sendto(buf, self.dest)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--gap-ms", type=float, default=3.5, help="sleep before each step [ms]")
    ap.add_argument(
        "--socketcan", metavar="CHANNEL", help="on this SocketCAN channel instead of udp_multicast"
    )
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    ids = sorted({m.frame_id for m in load_profile("lde").messages.values()})
    outputs = [
        can.Message(arbitration_id=0x2B0 + j, is_extended_id=False, dlc=8, data=bytes(8)) for j in range(4)
    ]
    mdps = can.Message(arbitration_id=0x2A0, is_extended_id=False, data=bytes(8))
    esc = can.Message(arbitration_id=0x2A8, is_extended_id=False, data=bytes(8))

    ways: dict[str, tuple] = {}
    buses = []
    if args.socketcan:
        names = ["lde.can.busio (SocketCAN descriptor)", "python-can recv/send"]
    else:
        names = ["lde.can.busio (python-can)", "python-can, software filters", "raw socket"]
    for name in names:
        kw = {"interface": "socketcan", "channel": args.socketcan} if args.socketcan else private_multicast()
        svc, sim = open_bus(**kw), open_bus(**kw)
        buses += [svc, sim]
        if name == "python-can, software filters":
            svc.set_filters([{"can_id": i, "can_mask": 0x7FF, "extended": False} for i in ids])
            how = "python-can (software)"
        else:
            how = receive_only(svc, ids)
        io = (
            RawSocketIO(svc, kw)
            if name == "raw socket"
            else bus_io(svc)
            if name.startswith("lde")
            else BusIO(svc)
        )
        tx = [
            io.tx(can.Message(arbitration_id=m.arbitration_id, is_extended_id=False, dlc=8, data=bytes(8)))
            for m in outputs
        ]
        ways[name] = (sim, io, tx, how, np.zeros((args.steps, 3), np.int64))

    pc = time.perf_counter_ns
    load0 = os.getloadavg()
    for k in range(args.steps):
        for sim, io, tx, _, out in ways.values():
            sim.send(mdps)
            if k % 5 in (0, 2):
                sim.send(esc)
            while sim.recv(0.0) is not None:  # the simulator's own socket: keep it from filling
                pass
            time.sleep(args.gap_ms * 1e-3)
            recv: Callable = io.recv
            send: Callable = io.send
            t0 = pc()
            n = 0
            while recv(0.0) is not None:
                n += 1
            t1 = pc()
            t_s = time.time()
            for f in tx:
                send(f, t_s)
            t2 = pc()
            out[k] = (t1 - t0, t2 - t1, n)
    skip = min(200, args.steps // 10)
    res: dict[str, object] = {
        "steps": args.steps - skip,
        "gap_ms": args.gap_ms,
        "load_avg": [round(x, 2) for x in (*load0, *os.getloadavg())],
        "python_can": can.__version__,
    }
    for name, (_, _, _, how, out) in ways.items():
        a = out[skip:]
        drain, sends, both = a[:, 0] / 1e3, a[:, 1] / 1e3, (a[:, 0] + a[:, 1]) / 1e3
        res[name] = {
            "filters": how,
            "frames_per_step": round(float(a[:, 2].mean()), 2),
            "drain_p50_us": round(float(np.median(drain)), 1),
            "drain_p99_us": round(float(np.percentile(drain, 99)), 1),
            "sends_p50_us": round(float(np.median(sends)), 1),
            "sends_p99_us": round(float(np.percentile(sends, 99)), 1),
            "step_p50_us": round(float(np.median(both)), 1),
            "step_p99_us": round(float(np.percentile(both, 99)), 1),
        }
    for b in buses:
        b.shutdown()
    if args.json:
        print(json.dumps(res))
        return 0
    where = f"socketcan {args.socketcan}" if args.socketcan else "udp_multicast"
    print(
        f"{where} drain + 4 sends per step, {res['steps']} steps, {args.gap_ms} ms before each;"
        f" python-can {res['python_can']}; load {res['load_avg']}"
    )
    print(f"{'':32} {'frames':>6} {'drain p50/p99':>15} {'sends p50/p99':>15} {'step p50/p99':>15}")
    for name in ways:
        v = res[name]
        assert isinstance(v, dict)
        print(
            f"{name:32} {v['frames_per_step']:>6} {v['drain_p50_us']:>7}/{v['drain_p99_us']:<7}"
            f" {v['sends_p50_us']:>7}/{v['sends_p99_us']:<7} {v['step_p50_us']:>7}/{v['step_p99_us']:<7}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
