"""The service's own per-step cost, without a bus: :meth:`lde.service.service.Service.step_once` on a bus
that takes frames from a list and throws sent frames away, recorder on (its writer process drains the
rings as live).

It separates what lde does per step (drain, decode, estimate, overlay, encode, the three output
frames, the recorder hand-off) from what a bus costs (python-can's ``udp_multicast`` pack/unpack and
``sendto``: ``bench_loop.py --io-split``), and shows how much of the live figure is the machine: the
same step run back to back ("hot") and with a 3.5 ms pause before each step ("cold", as live, where
the step runs once per 3.9 ms period and the caches are refilled by whatever ran in between).

    python bench/bench_service_step.py [--steps 4000] [--backend fixed] [--realtime --cpu 1]
        [--cpu-latency-us 0] [--phases] [--empty-call] [--json]

``--empty-call``: only the engine's live call (``Engine.run_live``) with no frame and no step time,
``5 * --steps`` times back to back and a tenth of that after a 0.5 ms sleep each: the cost of
numba unboxing the loop's arrays (how many: ``arrays``).

``--cpu-latency-us 0`` holds ``/dev/cpu_dma_latency`` at 0 as ``lde run --realtime`` does (idle CPUs
poll instead of halting: the "cold" step then runs on warmer caches).

Per phase (``--phases``; adds a few microseconds of timing overhead per call): the drain, the engine
(receiver, grid, estimator, overlay, output frames), the ``LDE_Diag`` encoding, the three sends and
the recorder's ``step`` hand-off.
"""

from __future__ import annotations

import argparse
import collections
import gc
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np

from lde.can.codec import MessageEncoder, si_to_dbc
from lde.can.profiles import load_profile
from lde.clock import SimulatedClock, enable_realtime
from lde.io.recording import Recorder
from lde.params import load_vehicle
from lde.service.service import Service
from lde.units import DEG, KMH, STEP_NS


class ListBus(can.BusABC):
    """Receives the frames put in ``queue``; sends nowhere."""

    def __init__(self) -> None:
        super().__init__(channel="list")
        self.queue: collections.deque[can.Message] = collections.deque()

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return (self.queue.popleft() if self.queue else None), False

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        pass


def _timed(obj: object, name: str, acc: dict[str, list[int]]) -> None:
    f = getattr(obj, name)

    def w(*a, **k):
        t = time.perf_counter_ns()
        try:
            return f(*a, **k)
        finally:
            acc[name].append(time.perf_counter_ns() - t)

    setattr(obj, name, w)


def run(n: int, backend: str, gap_s: float, phases: bool, rec_dir: Path) -> dict[str, object]:
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    t0 = time.time_ns()
    bus = ListBus()
    clock = SimulatedClock(t0)
    rec = Recorder(rec_dir / f"step-{gap_s}.mcap")
    svc = Service(
        bus, profile, vehicle, clock, backend=backend, recorder=rec, log_period_s=0, timebase_offset_ns=0
    )
    acc: dict[str, list[int]] = collections.defaultdict(list)
    if phases:
        for name in ("_drain", "_after_send", "_encode_diag", "_send"):
            if hasattr(svc, name):
                _timed(svc, name, acc)
        _timed(svc.engine, "run_arrays", acc)
        _timed(svc.engine, "run_live", acc)
        _timed(rec, "step", acc)
    mdps, esc = MessageEncoder(profile, "MDPS_Sensors"), MessageEncoder(profile, "ESC_Motion")
    mv = si_to_dbc(
        profile,
        "MDPS_Sensors",
        {"column_torque": 0.5, "assist_torque": 1.0, "steering_angle": 0.4 * DEG, "steering_rate": 0.0},
    )
    ev = si_to_dbc(profile, "ESC_Motion", {"yaw_rate": 0.0, "lat_accel": 0.1, "speed": 100 * KMH})
    frames = []
    for k in range(n):
        t_k = t0 + (k + 1) * STEP_NS
        m = [mdps.message(mv, t_k)]  # the step's trigger frame (the MDPS grid)
        if k % 5 in (0, 3):  # ESC every 10 ms
            m.insert(0, esc.message(ev, t_k - 1_000_000))
        frames.append((t_k, m))
    cost = np.zeros(n, np.int64)
    gc.collect()
    gc.freeze()
    gc.disable()
    try:
        for k, (t_k, m) in enumerate(frames):
            bus.queue.extend(m)
            clock.sleep_until(t_k)
            if gap_s:
                time.sleep(gap_s)
            t = time.perf_counter_ns()
            svc.step_once(t_k, t_start=t_k)
            cost[k] = time.perf_counter_ns() - t
            if gc.get_count()[0] >= 700:
                gc.collect(0)
    finally:
        gc.enable()
        rec.close()
    skip = min(200, n // 10)
    c = cost[skip:] / 1e3
    out: dict[str, object] = {
        "gap_ms": gap_s * 1e3,
        "steps": n - skip,
        "step_cost_p50_us": round(float(np.percentile(c, 50)), 1),
        "step_cost_p99_us": round(float(np.percentile(c, 99)), 1),
        "recording_dropped": list(rec.dropped),
    }
    for name, v in acc.items():
        a = np.array(v[skip:]) / 1e3
        out[f"{name}_p50_us"] = round(float(np.percentile(a, 50)), 1)
        out[f"{name}_p99_us"] = round(float(np.percentile(a, 99)), 1)
    return out


def empty_call(n: int, backend: str) -> dict[str, object]:
    """The engine's live call with no frame and no step time (``Engine.run_live`` as the service
    makes it): what numba's unboxing of the loop's arguments costs, hot and after a 0.5 ms sleep."""
    from lde.engine.engine import Engine, StepBlock

    eng = Engine(load_profile("lde"), load_vehicle("reference"), backend, explicit=True)
    cols = tuple(np.zeros(0, dt) for dt in (np.int64, np.uint32, np.bool_, np.uint8, np.uint64, np.bool_))
    block, _ = StepBlock.packed(1)
    tk, en, ex = np.zeros(0, np.int64), np.zeros(0, np.bool_), np.zeros(0, np.uint8)
    eng.run_arrays(*cols, block, step_times=tk, enable=en, extra_status=ex, final=True)
    args = eng.live_args(cols, block, tk, en, ex)

    def arrays(x: object) -> int:
        return 1 if isinstance(x, np.ndarray) else sum(map(arrays, x)) if isinstance(x, tuple) else 0

    hot, slept = np.zeros(n, np.int64), np.zeros(n, np.int64)
    pc = time.perf_counter_ns
    for k in range(n):
        t = pc()
        eng.run_live(args)
        hot[k] = pc() - t
    for k in range(n // 10):
        time.sleep(0.0005)
        t = pc()
        eng.run_live(args)
        slept[k] = pc() - t
    slept = slept[: n // 10]
    return {
        "arrays": arrays(args),
        "hot_p50_us": round(float(np.median(hot)) / 1e3, 2),
        "hot_p99_us": round(float(np.percentile(hot, 99)) / 1e3, 2),
        "after_sleep_p50_us": round(float(np.median(slept)) / 1e3, 2),
        "after_sleep_p99_us": round(float(np.percentile(slept, 99)) / 1e3, 2),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--backend", choices=("fixed", "float"), default="fixed")
    ap.add_argument("--realtime", action="store_true", help="SCHED_FIFO 80, mlockall")
    ap.add_argument("--cpu", type=int, action="append")
    ap.add_argument(
        "--cpu-latency-us", type=int, default=None, help="PM QoS bound (lde.clock.enable_realtime)"
    )
    ap.add_argument("--phases", action="store_true", help="time each phase (small overhead)")
    ap.add_argument(
        "--empty-call", action="store_true", help="only the engine's live call on no frame (unboxing)"
    )
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.realtime:
        res = enable_realtime(80, cpus=args.cpu, lock_memory=True, cpu_latency_us=args.cpu_latency_us)
        if not res.ok:
            print("; ".join(res.warnings), file=sys.stderr)
    else:
        if args.cpu:
            os.sched_setaffinity(0, set(args.cpu))
        if args.cpu_latency_us is not None:
            from lde.clock import _hold_cpu_latency

            warnings: list[str] = []
            _hold_cpu_latency(args.cpu_latency_us, warnings)
            for w in warnings:
                print(w, file=sys.stderr)
    load = os.getloadavg()
    if args.empty_call:
        r = empty_call(args.steps * 5, args.backend)
        r["load_avg"] = [round(x, 2) for x in (*load, *os.getloadavg())]
        print(json.dumps(r) if args.json else f"engine live call, no frame: {r}")
        return 0
    tmp = Path(tempfile.mkdtemp(prefix="lde-bench-step-"))
    results = [run(args.steps, args.backend, gap, args.phases, tmp) for gap in (0.0, 0.0035)]
    summary = {
        "load_avg": [round(x, 2) for x in (*load, *os.getloadavg())],
        "backend": args.backend,
        "cpu_latency_us": args.cpu_latency_us,
    }
    if args.json:
        print(json.dumps({**summary, "hot": results[0], "cold": results[1]}))
        return 0
    print(
        f"Service.step_once without a bus, recorder on, backend {args.backend}, cpu_dma_latency "
        f"{args.cpu_latency_us}; load {summary['load_avg']}"
    )
    for label, r in zip(("hot (back to back)", "cold (3.5 ms pause)"), results, strict=True):
        extra = ", ".join(
            f"{k[:-7]} {r[k]}/{r[k[:-7] + '_p99_us']}"
            for k in r
            if k.endswith("_p50_us") and "step_cost" not in k
        )
        print(
            f"  {label:<20} p50 {r['step_cost_p50_us']:7.1f} us  p99 {r['step_cost_p99_us']:7.1f} us  {extra}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
