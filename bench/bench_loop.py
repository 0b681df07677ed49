"""Benchmark of the live loop: the service on a python-can bus for N seconds, fed by the simulator.

Measured, not invented: the service runs its real loop (:meth:`lde.service.Service.run`) on the
monotonic clock; a feeder thread puts the simulator's MDPS_Sensors (3.9 ms) and ESC_Motion (10 ms)
frames on the bus in real time and applies the overlay request it receives (closed loop). At the end
the script prints the period error p50/p99/max, the step time p50/p99/max and the latency p50/p99/max
(microseconds), the deadline misses, and the machine it ran on.

    python bench/bench_loop.py --seconds 60                      # python-can virtual bus
    python bench/bench_loop.py --seconds 60 --interface socketcan --channel vcan0
    python bench/bench_loop.py --seconds 60 --realtime --cpu 1   # SCHED_FIFO where permitted
    python bench/bench_loop.py --seconds 60 --record /tmp/bench.mcap

On a real SocketCAN interface the feeder needs its own socket: it opens a second bus on the same
channel (frames sent on one socket are received by the other).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import threading
import time

import can

#: the simulator sends each period's frames this long before the service's step [ns]
FEED_LEAD_NS = 1_500_000


def _feeder_thread(bus: can.BusABC, scenario: str, stop: threading.Event, t_first_ns: int, seconds: float):
    """The simulator, closed loop, one 3.9 ms period per deadline on time.monotonic_ns().

    Its frames are stamped by the bus at send time (no preserved timestamps: as from a kernel).
    """
    from lde.demo import make_simulation

    sim = make_simulation(bus, scenario, seed=1, closed_loop=True, duration=seconds + 5.0)

    def loop() -> None:
        k = 0
        while not stop.is_set() and not sim.done:
            t_next = t_first_ns + k * sim.step_ns
            now = time.monotonic_ns()
            if t_next > now:
                time.sleep((t_next - now) / 1e9)
            sim.step()
            k += 1

    th = threading.Thread(target=loop, name="feeder", daemon=True)
    th.start()
    return th


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--interface", default="virtual")
    ap.add_argument("--channel", default="lde-bench")
    ap.add_argument("--scenario", default=None, help="simulator scenario (default: the demo's)")
    ap.add_argument("--backend", choices=("fixed", "float", "paper-fixed", "paper"), default="fixed")
    ap.add_argument("--record", default=None, help="also record to this MCAP file")
    ap.add_argument("--realtime", action="store_true")
    ap.add_argument("--priority", type=int, default=80)
    ap.add_argument("--cpu", type=int, action="append")
    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    args = ap.parse_args(argv)

    from lde.clock import MonotonicClock
    from lde.demo import DEFAULT_SCENARIO
    from lde.params import load_vehicle
    from lde.profiles import load_profile
    from lde.recording import Recorder
    from lde.service import Service
    from lde.units import STEP_NS

    sys.setswitchinterval(1e-4)  # a busy feeder/recorder thread must not hold the GIL for 5 ms
    rt_note = "normal scheduler"
    if args.realtime:
        from lde import clock as clock_mod

        res = clock_mod.enable_realtime(priority=args.priority, cpus=args.cpu, lock_memory=True)
        rt_note = str(res)
    elif args.cpu:
        os.sched_setaffinity(0, set(args.cpu))

    svc_bus = can.Bus(interface=args.interface, channel=args.channel)
    feed_bus = can.Bus(interface=args.interface, channel=args.channel)
    profile = load_profile("lde")
    vehicle = load_vehicle("reference")
    clock = MonotonicClock()
    rec = Recorder(args.record, metadata={"profile": "lde", "bench": "1"}) if args.record else None
    svc = Service(svc_bus, profile, vehicle, clock, backend=args.backend, recorder=rec, log_period_s=0)
    stop = threading.Event()
    # the service's grid starts in 0.3 s; the simulator's periods start FEED_LEAD_NS before each step
    t0_ns = clock.now_ns() + 300_000_000
    scenario = args.scenario or DEFAULT_SCENARIO
    feeder = _feeder_thread(feed_bus, scenario, stop, t0_ns - FEED_LEAD_NS, args.seconds)
    n_steps = int(args.seconds * 1e9 / STEP_NS)
    t0 = time.perf_counter()
    try:
        summary = svc.run(max_steps=n_steps, t0_ns=t0_ns)
    finally:
        stop.set()
        feeder.join(2.0)
        if rec is not None:
            rec.close()
        svc_bus.shutdown()
        feed_bus.shutdown()
    wall = time.perf_counter() - t0
    out = {
        "seconds": round(wall, 2),
        "steps": svc.steps,
        "interface": args.interface,
        "channel": args.channel,
        "backend": args.backend,
        "record": bool(args.record),
        "scheduling": rt_note,
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus, python {platform.python_version()}",
        **summary.as_dict(),
        "send_errors": svc.send_errors,
    }
    if args.json:
        print(json.dumps(out))
    else:
        print(f"lde live loop, {out['steps']} steps in {out['seconds']} s on {args.interface}:{args.channel}")
        print(f"  {out['machine']}; {rt_note}; backend {args.backend}; recording {bool(args.record)}")
        s = summary
        for label, p50, p99, mx in (
            ("period error", s.period_error_p50_us, s.period_error_p99_us, s.period_error_max_us),
            ("step time", s.step_time_p50_us, s.step_time_p99_us, s.step_time_max_us),
            ("latency", s.latency_p50_us, s.latency_p99_us, s.latency_max_us),
        ):
            print(f"  {label:<13} p50 {p50:8.1f} us  p99 {p99:8.1f} us  max {mx:8.1f} us")
        print(f"  deadline misses {summary.deadline_misses} (skipped grid points {summary.skipped})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
