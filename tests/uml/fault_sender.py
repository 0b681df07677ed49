"""A light input sender with faults, for tests/uml/test_vcan_faults.py (standard library only).

    python fault_sender.py SCHEDULE CHANNEL RESULT.json [--rt-priority N]

SCHEDULE is a binary file of records ``<q B I B 8s``: time after the start [ns], kind, CAN id, dlc,
data. Kinds: 0 a frame (an error frame when the id has CAN_ERR_FLAG), 1 the interface down,
2 up, 3 a flood of foreign frames starts (``cangen -g 0`` at SCHED_FIFO 50: as fast as the guest
lets it), 4 the flood stops, 5 a mark (only its time is kept). The frames were encoded beforehand
(counters, CRCs, the faults), so the sender's step is one ``send`` on a raw socket: in user-mode
Linux, where ``lde sim`` and the service share one emulated CPU, the inputs keep their pace.

It paces the records on the monotonic clock (sleeping until each one), sends late records at once
but moves its schedule later when more than MAX_LAG_S behind (as ``lde sim`` does: no burst of stale
frames), and never stops on a failed send (ENETDOWN while the interface is down: counted). RESULT
gets the epoch time of every action and mark record (in order: the interface down and the flood's
start when their command began, the interface up and the flood's end when it had finished), the
counts, its lateness and CPU.
"""

from __future__ import annotations

import json
import os
import socket
import struct
import subprocess
import sys
import time

REC = struct.Struct("<qBIB8s")
FRAME = struct.Struct("=IB3x8s")  # struct can_frame
CAN_ERR_FLAG = 0x20000000
MAX_LAG_S = 0.0117  # three MDPS periods: the input timeout
FLOOD_ID = "123"  # not an input of the profile


def _counter(channel: str, name: str) -> int:
    with open(f"/sys/class/net/{channel}/statistics/{name}") as fh:
        return int(fh.read())


def main(argv: list[str]) -> int:
    sched_path, channel, result_path = argv[:3]
    if "--rt-priority" in argv:
        prio = int(argv[argv.index("--rt-priority") + 1])
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
    with open(sched_path, "rb") as fh:
        raw = fh.read()
    recs = [REC.unpack_from(raw, i) for i in range(0, len(raw), REC.size)]
    sock = socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW)
    sock.setsockopt(socket.SOL_CAN_RAW, socket.CAN_RAW_FILTER, b"")  # receives nothing
    sock.bind((channel,))
    frames = [FRAME.pack(cid, dlc, data) if kind == 0 else b"" for _, kind, cid, dlc, data in recs]
    counts = {"sent": 0, "failed": 0, "error_frames": 0, "slips": 0}
    slip_ns = 0
    late_ms: list[float] = []
    events: list[tuple[int, float]] = []  # (kind, epoch s)
    flood = None
    flood_rx: list[int] = []
    cpu0 = os.times()
    t0 = time.monotonic_ns() + 200_000_000
    for (t_off, kind, cid, _, _), fr in zip(recs, frames, strict=True):
        due = t0 + t_off + slip_ns
        now = time.monotonic_ns()
        if now < due:
            time.sleep((due - now) * 1e-9)
            now = time.monotonic_ns()
        late = now - due
        if late > MAX_LAG_S * 1e9:
            slip_ns += late
            counts["slips"] += 1
        late_ms.append(late * 1e-6)
        if kind == 0:
            try:
                sock.send(fr)
                counts["sent"] += 1
                counts["error_frames"] += bool(cid & CAN_ERR_FLAG)
            except OSError:
                counts["failed"] += 1
            continue
        t_before = time.time()  # the link goes down / the flood starts during the call: its start
        if kind in (1, 2):
            subprocess.run(["ip", "link", "set", channel, "down" if kind == 1 else "up"], check=True)
        elif kind == 3:
            flood_rx.append(_counter(channel, "rx_packets"))
            flood = subprocess.Popen(
                ["chrt", "-f", "50", "cangen", channel, "-g", "0", "-i", "-I", FLOOD_ID, "-L", "8"],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        elif kind == 4 and flood is not None:
            flood.terminate()
            flood.wait(timeout=30)
            flood_rx.append(_counter(channel, "rx_packets"))
        # a fault's start is when its action began, its end when the action had finished
        events.append((kind, t_before if kind in (1, 3) else time.time()))
    cpu1 = os.times()
    late_ms.sort()
    result = {
        **counts,
        "events": events,
        "flood_rx_packets": flood_rx,
        "late_ms_p50": late_ms[len(late_ms) // 2] if late_ms else 0.0,
        "late_ms_p99": late_ms[int(len(late_ms) * 0.99)] if late_ms else 0.0,
        "late_ms_max": late_ms[-1] if late_ms else 0.0,
        "slipped_ms": slip_ns * 1e-6,
        "cpu_s": (cpu1.user - cpu0.user) + (cpu1.system - cpu0.system),
        "wall_s": (time.monotonic_ns() - t0) * 1e-9,
    }
    with open(result_path, "w") as fh:
        json.dump(result, fh)
    print(json.dumps({k: v for k, v in result.items() if k != "events"}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
