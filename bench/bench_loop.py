"""Benchmark of the live loop: the service on a kernel bus, fed by the simulator in its own process.

Measured, not invented, and only the service: this process runs :class:`lde.service.service.Service` exactly
as
``lde run`` does (its loop in the main thread, no other thread; the recorder, when asked for, in its
own process); the simulator (``lde sim``, closed loop on ``LDE_Overlay``, real-time pacing) runs as a
separate process and talks to it through the kernel: python-can's ``udp_multicast`` bus on a host
without CAN (a multicast group and port of its own per run), SocketCAN ``vcan0`` where it exists
(user-mode Linux: ``tests/uml/run_in_uml.sh``).

    python bench/bench_loop.py --seconds 60                        # udp_multicast, MDPS-locked grid
    python bench/bench_loop.py --seconds 60 --realtime --cpu 1     # SCHED_FIFO 80, mlockall, CPU 1
    python bench/bench_loop.py --seconds 60 --busy                 # a busy loop on the other core
    python bench/bench_loop.py --seconds 600 --realtime --busy --record /tmp/b.mcap --json
    python bench/bench_loop.py --interface socketcan --channel vcan0 --seconds 60

Figures (microseconds) over the simulator's traffic window (its first to its last MDPS frame seen by
the service), per step:

* period error: start of the step minus its step time ``t_k`` (MDPS grid: ``t_k`` is the trigger
  frame's kernel receive timestamp, so this is the wake-up; fixed grid: the deadline);
* step time: start to the send of ``LDE_Estimate`` and ``LDE_Overlay`` (what ``LDE_Diag`` carries);
* step cost: start to the end of the step (drain, decode, estimate, overlay, encode, all three sends,
  the recorder hand-off: issue 12's "per-step service cost");
* latency: kernel receive timestamp of the newest input frame the step used to the send of its
  outputs;
* deadline misses: steps that started more than 1 ms late plus skipped grid points; grid points: the
  window's length over 3.9 ms, and the share of them at which the service sent its outputs.

The JSON (``--json``, or ``--out FILE`` to append one line per run) keeps the keys of the earlier
benchmark (``period_error_p50_us`` ... ``deadline_misses``, ``skipped``, ``steps``) so the README table
reads from it, plus ``step_cost_*``, ``grid``, ``busy``, ``load_avg``, ``outputs_per_grid_point``, the
simulator's own summary line and, for ``--profile``, py-spy's top functions.

The simulator runs at SCHED_FIFO 90 where permitted (``--sim-rt-priority``; it stands for the other
ECUs, which have CPUs of their own: its frames must not wait behind the service), and sends on time:
it sleeps until 300 us before each frame and spins the rest (``--sim-spin-us``; the MDPS-locked grid
follows its frames, so its sleep's wake-up jitter, 30 us p50 and 300 us-2.5 ms p99 here, was the grid's
input). ``--trace F.npz`` takes the period error apart (``bench/loop_trace.py``). ``--busy`` starts
``--busy`` busy loops pinned to the CPUs the service is not pinned to (or unpinned). Run with
``PYTHONPATH`` pointing at another checkout to measure that one on the same harness (a ``Service``
without ``grid`` runs its fixed grid).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import can
import numpy as np

from lde.can.profiles import load_profile
from lde.clock import MonotonicClock, enable_realtime
from lde.io.recording import Recorder
from lde.params import load_vehicle
from lde.service.service import Service
from lde.testing.bus import private_multicast
from lde.units import STEP_NS

#: the service runs this long before the simulator's first frame can come (its start-up) [s]
SIM_START_S = 4.0


class TimedBus:
    """The bus, with the time spent in its ``send`` and ``recv`` while ``active`` (inside a step)
    added up (``--io-split``: what python-can and the kernel cost, apart from lde's own work)."""

    def __init__(self, bus: can.BusABC) -> None:
        self._bus = bus
        self.active = False
        self.io_ns = 0

    def __getattr__(self, name: str):
        return getattr(self._bus, name)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.active:
            return self._bus.send(msg, timeout)
        t = time.perf_counter_ns()
        try:
            return self._bus.send(msg, timeout)
        finally:
            self.io_ns += time.perf_counter_ns() - t

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if not self.active:
            return self._bus.recv(timeout)
        t = time.perf_counter_ns()
        try:
            return self._bus.recv(timeout)
        finally:
            self.io_ns += time.perf_counter_ns() - t


class Phases:
    """``--phases``: the time spent in each part of a step, per step (only inside ``step_once``; a
    wrapper costs about 0.2 us per call, so the step cost of such a run is a little higher)."""

    #: "handoff": the compiled hand-off after the sends (timing, LDE_Diag, recorder rings:
    #: lde.service.handoff);
    #: "diag": the LDE_Diag encoding of a service before it (run the same harness on an older checkout)
    NAMES = ("recv", "take", "engine", "send", "handoff", "diag", "rec_step", "rec_frame")

    def __init__(self, svc: Service, rec: Recorder | None) -> None:
        self.acc = dict.fromkeys(self.NAMES, 0)
        self.active = False
        targets = [
            (svc.io, "recv", "recv"),
            (svc, "_take", "take"),
            (svc.engine, "run_live" if hasattr(svc.engine, "run_live") else "run_arrays", "engine"),
            (svc.io, "send", "send"),
        ]
        for a, n in (("_after_send", "handoff"), ("_encode_diag", "diag")):
            if hasattr(svc, a):
                targets.append((svc, a, n))
        if rec is not None:
            targets += [(rec, "step", "rec_step"), (rec, "frame", "rec_frame")]
        for obj, attr, name in targets:
            setattr(obj, attr, self._wrap(getattr(obj, attr), name))
        step_once = svc.step_once

        def timed(t_k: int, t_start: int | None = None):
            for k in self.acc:
                self.acc[k] = 0
            self.active = True
            try:
                return step_once(t_k, t_start)
            finally:
                self.active = False

        svc.step_once = timed  # type: ignore[method-assign]

    def _wrap(self, f, name: str):
        acc = self.acc
        clock = time.perf_counter_ns

        def w(*a, **k):
            if not self.active:
                return f(*a, **k)
            t = clock()
            try:
                return f(*a, **k)
            finally:
                acc[name] += clock() - t

        return w


class RecvTrace:
    """``--trace``: each MDPS frame's receive as the service saw it: its kernel stamp (bus time base),
    when the receive call that returned it started and returned (monotonic), and whether that call
    polled (timeout 0: the spin around the expected frame, or the step's drain) or blocked."""

    def __init__(self, svc: Service, n_max: int) -> None:
        self.cols = np.zeros((n_max, 4), np.int64)  # t_rx (bus), call start, return (mono), blocked
        self.n = 0
        anchor = svc.profile.messages[svc.profile.anchor_message].frame_id
        recv = svc.io.recv
        clock = time.monotonic_ns
        cols = self.cols

        self.empty = np.zeros(1 << 16, np.int64)  # durations of the last empty polls (a ring) [ns]
        self.n_empty = 0
        empty = self.empty

        def traced(timeout: float | None):
            t0 = clock()
            f = recv(timeout)
            if f is None:
                if timeout == 0:
                    empty[self.n_empty & 0xFFFF] = clock() - t0
                    self.n_empty += 1
            elif f[1] == anchor and self.n < n_max:
                cols[self.n] = (f[0], t0, clock(), timeout is None or timeout > 0)
                self.n += 1
            return f

        svc.io.recv = traced  # type: ignore[method-assign]


def _schedstat_fd() -> int | None:
    try:
        return os.open("/proc/thread-self/schedstat", os.O_RDONLY)
    except OSError:
        return None


def _run_delay_ns(fd: int | None) -> int:
    """Time this thread has spent runnable but not running, in all [ns] (-1 where unknown)."""
    if fd is None:
        return -1
    return int(os.pread(fd, 128, 0).split()[1])


def _steal_ticks() -> int:
    """The hypervisor's steal time over all CPUs so far [USER_HZ ticks] (``/proc/stat``)."""
    with open("/proc/stat") as fh:
        f = fh.readline().split()
    return int(f[8]) if len(f) > 8 else -1


def _pctl(a: np.ndarray, q: float) -> float:
    return round(float(np.percentile(a, q)) / 1e3, 1) if a.size else float("nan")


def _max(a: np.ndarray) -> float:
    return round(float(a.max()) / 1e3, 1) if a.size else float("nan")


def _hogs(n: int, avoid: set[int]) -> list[subprocess.Popen]:
    """``n`` busy loops on the CPUs not in ``avoid`` (all CPUs when that leaves none)."""
    cpus = sorted(set(range(os.cpu_count() or 1)) - avoid) or sorted(range(os.cpu_count() or 1))
    out = []
    for i in range(n):
        cpu = cpus[i % len(cpus)]
        code = f"import os; os.sched_setaffinity(0, {{{cpu}}})\nwhile True: pass"
        out.append(subprocess.Popen([sys.executable, "-c", code]))
    return out


def _py_spy_top(pid: int, seconds: float, out_dir: Path) -> tuple[subprocess.Popen | None, Path]:
    raw = out_dir / f"pyspy-{pid}.txt"
    cmd = ["py-spy", "record", "--pid", str(pid), "--duration", str(int(seconds)), "--rate", "1000"]
    cmd += ["--format", "raw", "--output", str(raw), "--nonblocking"]  # --native needs blocking
    try:
        return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL), raw
    except OSError:
        return None, raw


def _collapse(raw: Path, top: int = 15) -> dict[str, object]:
    """Self and total samples per function from py-spy's collapsed stacks (samples in the loop only)."""
    self_n: collections.Counter[str] = collections.Counter()
    total_n: collections.Counter[str] = collections.Counter()
    n = 0
    idle = 0
    for line in raw.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        if not stack:
            continue
        c = int(count)
        frames = [f.split(" (")[0] for f in stack.split(";")]
        n += c
        leaf = frames[-1]
        if any(k in stack for k in ("recv_until", "select", "sleep_until")) and "step_once" not in stack:
            idle += c
            continue
        self_n[leaf] += c
        for f in set(frames):
            total_n[f] += c
    busy = max(n - idle, 1)
    return {
        "samples": n,
        "idle_share": round(idle / max(n, 1), 3),
        "self_share_of_busy": {k: round(v / busy, 3) for k, v in self_n.most_common(top)},
        "total_share_of_busy": {k: round(v / busy, 3) for k, v in total_n.most_common(top)},
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=60.0, help="simulator traffic [s]")
    ap.add_argument("--interface", default="udp_multicast")
    ap.add_argument("--channel", default=None, help="default: a multicast group of its own (udp_multicast)")
    ap.add_argument("--port", type=int, default=None, help="udp_multicast port (default: random)")
    ap.add_argument("--scenario", default="heavy_load")
    ap.add_argument("--backend", choices=("fixed", "float", "paper"), default="fixed")
    ap.add_argument("--grid", choices=("mdps", "fixed"), default="mdps")
    ap.add_argument("--record", default=None, help="also record to this MCAP file")
    ap.add_argument("--realtime", action="store_true", help="the service at SCHED_FIFO --priority, mlockall")
    ap.add_argument("--priority", type=int, default=80)
    ap.add_argument(
        "--cpu-latency-us", type=int, default=0, help="with --realtime: PM QoS bound as lde run (-1: none)"
    )
    ap.add_argument(
        "--no-prewarm",
        action="store_true",
        help="no engine pre-warm when the spin before the MDPS frame starts (Service(prewarm=False))",
    )
    ap.add_argument("--cpu", type=int, action="append", help="pin the service to this CPU (repeatable)")
    ap.add_argument(
        "--spin-us",
        type=float,
        default=200.0,
        help="the service's busy-wait: polls around the expected MDPS frame (fixed grid: before a deadline)",
    )
    ap.add_argument("--busy", type=int, nargs="?", const=1, default=0, help="busy loops on the other core(s)")
    ap.add_argument("--sim-rt-priority", type=int, default=90, help="the simulator's SCHED_FIFO (0: normal)")
    ap.add_argument(
        "--phases", action="store_true", help="time each part of the step (lde.can.busio I/O too)"
    )
    ap.add_argument("--io-split", action="store_true", help="time python-can's send/recv inside the step")
    ap.add_argument(
        "--hop-limit",
        type=int,
        default=0,
        help="udp_multicast TTL (0: this host only, the default; python-can's own default is 1)",
    )
    ap.add_argument("--sim-pythonpath", default=None, help="PYTHONPATH of the simulator (another checkout's)")
    ap.add_argument("--profile", action="store_true", help="sample the service with py-spy (30 s)")
    ap.add_argument(
        "--trace",
        default=None,
        metavar="F.npz",
        help="decompose the period error: per-step stages, the MDPS receives, the simulator's send times",
    )
    ap.add_argument(
        "--slice-us",
        type=float,
        default=0.0,
        help="without --realtime: the service's EEVDF slice (lde.clock.request_slice; 0: the kernel's)",
    )
    ap.add_argument(
        "--sim-spin-us",
        type=float,
        default=300.0,
        help="the simulator sleeps until this long before each frame, then spins (lde sim --spin-us; "
        "default 300: an ECU's frames come on its clock, not 30-300 us late like a timed sleep's wake-up; "
        "0: sleep only, as before)",
    )

    ap.add_argument("--json", action="store_true", help="print the figures as one JSON object")
    ap.add_argument("--out", default=None, help="append the JSON object as one line to this file")
    ap.add_argument("--label", default="", help="a name for this run in the JSON")
    args = ap.parse_args(argv)

    own = private_multicast()
    port = args.port or own["port"]
    channel = args.channel or own["channel"]
    bus_kw: dict[str, object] = {"interface": args.interface, "channel": channel}
    if args.interface == "udp_multicast":
        bus_kw["port"] = port
        bus_kw["hop_limit"] = args.hop_limit

    # as lde run does (lde.cli.run): another thread of the service's process (an older recorder's) must
    # not keep the loop from the interpreter lock for CPython's default 5 ms
    sys.setswitchinterval(min(sys.getswitchinterval(), 2e-4))
    load_before = os.getloadavg()
    hogs = _hogs(args.busy, set(args.cpu or ())) if args.busy else []
    rt_note = "normal scheduler"
    if args.realtime:
        lat = None if args.cpu_latency_us < 0 else args.cpu_latency_us
        try:
            res = enable_realtime(priority=args.priority, cpus=args.cpu, lock_memory=True, cpu_latency_us=lat)
        except TypeError:  # a checkout before the PM QoS bound
            res = enable_realtime(priority=args.priority, cpus=args.cpu, lock_memory=True)
        rt_note = f"SCHED_FIFO {args.priority}, mlockall" if res.ok else f"refused: {res.warnings}"
        if getattr(res, "cpu_latency_us", None) is not None:
            rt_note += f", cpu_dma_latency {res.cpu_latency_us} us"
    elif args.cpu:
        os.sched_setaffinity(0, set(args.cpu))
    if args.slice_us and not args.realtime:
        from lde.clock import request_slice

        why = request_slice(int(args.slice_us * 1e3))
        rt_note += f", slice {args.slice_us:g} us" if why is None else f", slice refused: {why}"

    raw_bus = can.Bus(**bus_kw)
    bus = TimedBus(raw_bus) if args.io_split else raw_bus
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    clock = MonotonicClock(spin_ns=int(args.spin_us * 1e3))
    rec = Recorder(args.record, metadata={"profile": "lde", "bench": "1"}) if args.record else None
    kw: dict[str, object] = {"grid": args.grid}
    if args.no_prewarm:
        kw["prewarm"] = False
    try:
        svc = Service(bus, profile, vehicle, clock, backend=args.backend, recorder=rec, log_period_s=0, **kw)
        grid = args.grid
    except TypeError:  # a checkout before the MDPS-locked grid: its fixed grid
        svc = Service(bus, profile, vehicle, clock, backend=args.backend, recorder=rec, log_period_s=0)
        grid = "fixed (no grid option)"

    n_max = int((args.seconds + SIM_START_S + 30.0) * 1e9 / STEP_NS)
    cols = {k: np.zeros(n_max, np.int64) for k in ("t", "pe", "st", "lat", "cost", "used", "skipped", "io")}
    phases = Phases(svc, rec) if args.phases else None
    if phases is not None:
        cols.update({f"ph_{k}": np.zeros(n_max, np.int64) for k in Phases.NAMES})
    if isinstance(bus, TimedBus):
        step_once = svc.step_once

        def timed_step(t_k: int, t_start: int | None = None):
            bus.active = True
            bus.io_ns = 0
            try:
                return step_once(t_k, t_start)
            finally:
                bus.active = False

        svc.step_once = timed_step  # type: ignore[method-assign]
    n = [0]
    off = svc.offset_ns
    rtrace = RecvTrace(svc, 4 * n_max) if args.trace else None
    sched_fd = _schedstat_fd() if args.trace else None
    if args.trace:
        cols["run_delay"] = np.zeros(n_max, np.int64)

    def on_step(r) -> None:
        i = n[0]
        if i >= n_max:
            svc.request_stop()
            return
        tm = r.timing
        cols["t"][i] = r.t_ns
        cols["pe"][i] = tm.period_error_ns
        cols["st"][i] = tm.step_time_ns
        cols["lat"][i] = tm.latency_ns
        cols["cost"][i] = clock.now_ns() + off - (r.t_ns + tm.period_error_ns)
        cols["used"][i] = r.frames_used
        cols["io"][i] = bus.io_ns if isinstance(bus, TimedBus) else 0
        cols["skipped"][i] = svc.stats.skipped
        if rtrace is not None:
            cols["run_delay"][i] = _run_delay_ns(sched_fd)
        if phases is not None:
            for k, v in phases.acc.items():
                cols[f"ph_{k}"][i] = v
        n[0] = i + 1

    sim_cmd = [sys.executable, "-m", "lde", "sim", "--interface", args.interface, "--channel", channel]
    if args.interface == "udp_multicast":
        sim_cmd += ["--bus-kwarg", f"port={port}", "--bus-kwarg", f"hop_limit={args.hop_limit}"]
    sim_cmd += ["--scenario", args.scenario, "--seed", "1", "--duration", str(args.seconds)]
    if args.sim_rt_priority:
        sim_cmd += ["--rt-priority", str(args.sim_rt_priority)]
    if args.sim_spin_us:
        sim_cmd += ["--spin-us", str(args.sim_spin_us)]
    tmp = Path(tempfile.mkdtemp(prefix="lde-bench-loop-"))
    if args.trace:
        sim_cmd += ["--send-trace", str(tmp / "send_trace.npy")]
    steal0 = _steal_ticks()
    sim_err = (tmp / "sim.err").open("w")
    env = dict(os.environ)
    if args.sim_pythonpath:
        env["PYTHONPATH"] = args.sim_pythonpath
    all_cpus = set(range(os.cpu_count() or 1))
    sim_cpus = sorted(all_cpus - set(args.cpu or ())) or sorted(all_cpus) if args.cpu else sorted(all_cpus)

    def pin_sim() -> None:  # the simulator stands for ECUs with CPUs of their own: not the service's
        os.sched_setaffinity(0, sim_cpus)

    sim = subprocess.Popen(
        sim_cmd, stdout=subprocess.DEVNULL, stderr=sim_err, env=env, cwd=tmp, preexec_fn=pin_sim
    )
    spy = None
    raw = tmp / "none"
    if args.profile:
        spy, raw = _py_spy_top(os.getpid(), min(30.0, args.seconds), tmp)

    stop = [False]

    def watch(res) -> None:
        on_step(res)
        if not stop[0] and sim.poll() is not None:  # the simulator has ended: two more seconds
            stop[0] = True
            stop_at[0] = res.t_ns + 2_000_000_000
        if stop[0] and res.t_ns >= stop_at[0]:
            svc.request_stop()

    stop_at = [0]
    t_wall = time.perf_counter()
    try:
        svc.run(on_step=watch)
    finally:
        if sim.poll() is None:
            sim.send_signal(signal.SIGINT)
            sim.wait(10)
        for h in hogs:
            h.kill()
            h.wait()
        if rec is not None:
            rec.close()
        raw_bus.shutdown()
        sim_err.close()
    wall = time.perf_counter() - t_wall
    load_after = os.getloadavg()
    steal = _steal_ticks() - steal0
    m = n[0]
    c = {k: v[:m] for k, v in cols.items()}
    # the simulator's traffic window: steps that used an MDPS frame, from the first to the last
    sim_line = (tmp / "sim.err").read_text().strip().splitlines()
    fresh = np.flatnonzero(c["used"] > 0)
    if fresh.size == 0:
        print("no frame from the simulator reached the service:", *sim_line[-3:], sep="\n", file=sys.stderr)
        return 1
    a, b = int(fresh[0]), int(fresh[-1]) + 1
    w = {k: v[a:b] for k, v in c.items()}
    span_ns = int(w["t"][-1] - w["t"][0])
    grid_points = span_ns // STEP_NS + 1
    steps = b - a
    skipped = int(w["skipped"][-1] - (c["skipped"][a - 1] if a else 0))
    late = int(np.count_nonzero(w["pe"] > 1_000_000))
    lat = w["lat"][w["lat"] >= 0]
    out: dict[str, object] = {
        "label": args.label,
        "seconds": round(wall, 2),
        "window_s": round(span_ns / 1e9, 2),
        "steps": steps,
        "grid_points": int(grid_points),
        "outputs_per_grid_point": round(steps / grid_points, 4),
        "interface": args.interface,
        "hop_limit": args.hop_limit if args.interface == "udp_multicast" else None,
        "grid": grid,
        "backend": args.backend,
        "record": bool(args.record),
        "scheduling": rt_note,
        "cpu": args.cpu,
        "busy": args.busy,
        "sim_rt_priority": args.sim_rt_priority,
        "sim_cpus": sim_cpus,
        "filters": getattr(svc, "filters", "none"),
        "io": getattr(getattr(svc, "io", None), "kind", "python-can"),
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus, python {platform.python_version()}",
        "load_avg": [round(x, 2) for x in (*load_before, *load_after)],
        "period_error_p50_us": _pctl(w["pe"], 50),
        "period_error_p99_us": _pctl(w["pe"], 99),
        "period_error_max_us": _max(w["pe"]),
        "step_time_p50_us": _pctl(w["st"], 50),
        "step_time_p99_us": _pctl(w["st"], 99),
        "step_time_max_us": _max(w["st"]),
        "step_cost_p50_us": _pctl(w["cost"], 50),
        "step_cost_p99_us": _pctl(w["cost"], 99),
        "step_cost_max_us": _max(w["cost"]),
        "step_io_p50_us": _pctl(w["io"], 50) if args.io_split else None,
        "step_io_p99_us": _pctl(w["io"], 99) if args.io_split else None,
        "step_cost_without_io_p50_us": _pctl(w["cost"] - w["io"], 50) if args.io_split else None,
        "step_cost_without_io_p99_us": _pctl(w["cost"] - w["io"], 99) if args.io_split else None,
        "latency_p50_us": _pctl(lat, 50),
        "latency_p99_us": _pctl(lat, 99),
        "latency_max_us": _max(lat),
        "deadline_misses": late + skipped,
        "late_steps": late,
        "skipped": skipped,
        "late_rx": svc.late_rx,
        "send_errors": svc.send_errors,
        "gc_collections": getattr(svc, "gc_collections", None),
        "recording_failed": bool(rec.failed) if rec is not None else None,
        "recording_dropped": list(getattr(rec, "dropped", ())) if rec is not None else None,
        "sim": sim_line[-1] if sim_line else "",
        "sim_spin_us": args.sim_spin_us,
        "spin_us": args.spin_us,
        "steal_s": round(steal / os.sysconf("SC_CLK_TCK"), 2),
    }
    if rtrace is not None:
        from loop_trace import decompose

        sent = tmp / "send_trace.npy"
        arrays = {f"step_{k}": v for k, v in c.items()}
        arrays["recv"] = rtrace.cols[: rtrace.n]
        arrays["empty_poll"] = rtrace.empty[: min(rtrace.n_empty, rtrace.empty.size)]
        arrays["send"] = np.load(sent) if sent.exists() else np.zeros((0, 4), np.int64)
        arrays["window"] = np.array([a, b], np.int64)
        arrays["offset_ns"] = np.array([off], np.int64)
        arrays["anchor_id"] = np.array([svc.profile.messages[svc.profile.anchor_message].frame_id])
        np.savez_compressed(args.trace, **arrays)
        out["trace"] = decompose(arrays)
    if phases is not None:
        out["phases_p50_p99_us"] = {
            k: [_pctl(w[f"ph_{k}"], 50), _pctl(w[f"ph_{k}"], 99)] for k in Phases.NAMES
        }
    if spy is not None:
        spy.wait(60)
        if raw.exists():
            out["py_spy"] = _collapse(raw)
    if args.out:
        with open(args.out, "a") as fh:
            fh.write(json.dumps(out) + "\n")
    if args.json:
        print(json.dumps(out))
    else:
        print(
            f"lde live loop, {steps} steps over {out['window_s']} s of simulator traffic on "
            f"{args.interface} ({grid} grid, {out['outputs_per_grid_point']:.2%} of the grid points)"
        )
        print(f"  {out['machine']}; {rt_note}; busy loops {args.busy}; load {out['load_avg']}")
        for label, key in (
            ("period error", "period_error"),
            ("step time", "step_time"),
            ("step cost", "step_cost"),
            ("latency", "latency"),
        ):
            print(
                f"  {label:<13} p50 {out[key + '_p50_us']:8.1f} us  p99 {out[key + '_p99_us']:8.1f} us  "
                f"max {out[key + '_max_us']:8.1f} us"
            )
        if args.io_split:
            print(
                f"  of the step cost: python-can send/recv p50 {out['step_io_p50_us']} us, p99 "
                f"{out['step_io_p99_us']} us; the rest (lde) p50 {out['step_cost_without_io_p50_us']} us, "
                f"p99 {out['step_cost_without_io_p99_us']} us"
            )
        print(f"  deadline misses {out['deadline_misses']} (late {late}, skipped {skipped})")
        print(f"  simulator: {out['sim']}")
        if "phases_p50_p99_us" in out:
            print("  phases p50/p99 us:", out["phases_p50_p99_us"])
        if "py_spy" in out:
            print("  py-spy:", json.dumps(out["py_spy"], indent=1))
    return 0 if re.match(r"lde sim", str(out["sim"])) else 1


if __name__ == "__main__":
    sys.exit(main())
