"""``lde sim``: the vehicle simulator (vcan_sim) as its own process.

Three ways to run (SPEC section 4)::

    lde sim --list                                              the scenarios, one line each
    lde sim --scenario NAME --log OUT.log --truth OUT.csv [--mcap OUT.mcap]
                                                                as fast as possible, to files
    lde sim --interface I --channel C --scenario NAME [--fast]  on a live bus (real time by default),
                                                                closed loop on LDE_Overlay

Files: ``--log`` a candump ``-L`` text log, ``--truth`` the ground-truth CSV (``t`` in the log's own
time base, ``Fw``, ``Mw``, ``Mw_ref``, ... see docs/simulator.md), ``--mcap`` an MCAP recording with
the frames on ``/can/rx`` and the truth as JSON on ``/truth``. On a live bus the same files may be
written too (the frames that were sent). The files stream while the simulation runs
(:class:`vcan_sim.output.Streamer`): a SIGKILL loses at most about the last 0.25 s. The bus opens
the python-can way: the options given, else
python-can's environment variables or config file.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from types import FrameType

from lde.cli import PROFILE_HELP
from lde.cli.run import add_bus_arguments, bus_kwargs
from lde.errors import ConfigError

log = logging.getLogger("lde.sim")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim",
        help="vehicle simulator: CAN traffic of a nonlinear car under crosswind/bank (files or a live bus)",
        description=__doc__.split("\n\n")[0],
    )
    p.add_argument("--list", action="store_true", help="list the scenarios and exit")
    p.add_argument("--scenario", "-s", metavar="NAME", help="scenario name (see --list)")
    p.add_argument("--profile", default="lde", help=PROFILE_HELP + " (default: lde)")
    p.add_argument("--vehicle", default=None, help="vehicle TOML file or shipped name (default: reference)")
    p.add_argument("--seed", type=int, default=0, help="seed of every random part (default 0)")
    p.add_argument("--duration", type=float, metavar="SEC", help="length [s] (default: the scenario's)")
    p.add_argument("--speed", type=float, metavar="KMH", help="run at this constant speed [km/h] instead")
    p.add_argument(
        "--t0",
        type=float,
        metavar="SEC",
        help="start of the simulated clock, epoch seconds (default 1700000000 + seed)",
    )
    p.add_argument("--log", metavar="OUT.log", help="write a candump -L log of the frames")
    p.add_argument("--log-channel", default="vcan0", help="channel name written in the candump log")
    p.add_argument("--truth", metavar="OUT.csv", help="write the ground truth CSV")
    p.add_argument("--mcap", metavar="OUT.mcap", help="write an MCAP recording (frames + /truth channel)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument(
        "--realtime",
        dest="realtime",
        action="store_true",
        default=None,
        help="live bus: send each frame at its time (default on a live bus)",
    )
    mode.add_argument(
        "--fast",
        dest="realtime",
        action="store_false",
        help="live bus: as fast as possible with simulated timestamps",
    )
    p.add_argument("--open-loop", action="store_true", help="live bus: ignore LDE_Overlay frames")
    p.add_argument(
        "--rt-priority",
        type=int,
        metavar="N",
        help="live bus: run the simulator SCHED_FIFO at priority N (1..99; warns where refused), from its "
        "start-up on; it never waits for another process (sleeps until its next frame, reads the overlay "
        "without blocking)",
    )
    p.add_argument(
        "--spin-us",
        type=float,
        default=0.0,
        metavar="US",
        help="live bus, real time: sleep until US microseconds before each frame's time, then busy-wait "
        "(a precise sender where the simulator has a CPU of its own; default 0: sleep only)",
    )
    p.add_argument(
        "--send-trace",
        metavar="OUT.npy",
        help="live bus: write each frame's scheduled, before-send and after-send times (monotonic ns) "
        "and CAN id, one int64 row per frame (the live loop's benchmark)",
    )
    p.add_argument(
        "--nice",
        type=int,
        metavar="N",
        help="live bus: run the simulator at nice level N (-20..19; negative needs root or CAP_SYS_NICE): "
        "on a shared CPU it then goes before loggers and recorders (warns where refused)",
    )
    p.add_argument(
        "--fault",
        action="append",
        default=[],
        metavar="KIND:TARGET:START:DURATION[:EVERY]",
        help="inject a bus fault (repeatable): KIND drop|silence|corrupt|repeat, TARGET mdps|esc|MESSAGE, "
        "START and DURATION in s from the start, every EVERY-th frame (default 1), e.g. drop:mdps:5:2:4",
    )
    add_bus_arguments(p)
    p.set_defaults(func=run)


def _print_list() -> int:
    from vcan_sim.scenarios import SCENARIOS

    width = max(len(n) for n in SCENARIOS)
    for name, sc in SCENARIOS.items():
        print(f"{name:<{width}}  {sc.description} [{sc.duration:.0f} s]")
    return 0


def _live_requested(args: argparse.Namespace) -> bool:
    if args.interface or args.channel or args.bus_kwarg:
        return True
    if args.log or args.truth or args.mcap:
        return False
    import can

    try:
        cfg = can.util.load_config()
    except (can.CanError, ValueError):  # no (usable) python-can configuration
        return False
    return bool(cfg.get("interface"))


def _check_outputs(args: argparse.Namespace) -> None:
    """Fail before simulating (a live run may take minutes) on output paths that cannot be written."""
    if args.log and (not args.log_channel or any(c.isspace() for c in args.log_channel)):
        raise ConfigError(
            f"--log-channel {args.log_channel!r}: need a channel name without blanks, e.g. vcan0"
        )
    outs = (("--log", args.log), ("--truth", args.truth), ("--mcap", args.mcap))
    for opt, value in (*outs, ("--send-trace", getattr(args, "send_trace", None))):
        if not value:
            continue
        path = Path(value)
        if path.is_dir():
            raise ConfigError(f"{opt} {path}: is a directory")
        parent = path.parent if str(path.parent) else Path(".")
        if not parent.is_dir():
            raise ConfigError(f"{opt} {path}: no such directory {parent}")


def _renice(level: int) -> None:
    import os

    if not -20 <= level <= 19:
        raise ConfigError(f"--nice {level}: need -20..19")
    try:
        os.setpriority(os.PRIO_PROCESS, 0, level)
    except (AttributeError, OSError) as exc:
        log.warning("--nice %d refused (%s); normal priority", level, exc)


def _sched_fifo(priority: int) -> None:
    from lde.clock import enable_realtime

    result = enable_realtime(priority=priority, cpus=None, lock_memory=False)
    for w in getattr(result, "warnings", ()) or ():
        log.warning("--rt-priority: %s", w)


class _Stopped(BaseException):
    """A second SIGINT or SIGTERM: leave the simulation at once."""


#: offline (as fast as possible) the files are flushed after every piece of this many steps (1 s
#: simulated, about 25 ms of wall time here): deterministic files, and little lost to a SIGKILL
OFFLINE_PIECE_STEPS = 256


@contextlib.contextmanager
def _signals_stop() -> Iterator[list[str]]:
    """SIGINT and SIGTERM end the simulation as a normal stop: the first one is noted in the list
    yielded (the simulation loop asks it before each step or piece, so that a stop never falls into
    the middle of a write), and the files are then closed with what was simulated (SIGTERM's default
    would kill the process: its files would end at their last flush, without the MCAP footer). A
    second signal leaves the body at once. The previous handlers are restored."""
    stopped: list[str] = []

    def _note(signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        if stopped:
            raise _Stopped(name)
        stopped.append(name)

    old = {}
    if threading.current_thread() is threading.main_thread():
        old = {s: signal.signal(s, _note) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stopped
    except KeyboardInterrupt:  # not the main thread: Ctrl-C as python-can's default
        stopped.append("SIGINT")
    except _Stopped:
        pass
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def run(args: argparse.Namespace) -> int:
    if args.list:
        return _print_list()
    if not args.scenario:
        raise ConfigError("--scenario NAME is required (lde sim --list names them)")
    if args.t0 is not None and not math.isfinite(args.t0):
        raise ConfigError(f"--t0 {args.t0}: need finite epoch seconds")
    live = _live_requested(args)
    if not live and not (args.log or args.truth or args.mcap):
        raise ConfigError("nothing to do: give --log/--truth/--mcap, or a bus (--interface/--channel)")
    _check_outputs(args)
    realtime = True if args.realtime is None else args.realtime
    if not args.spin_us >= 0:
        raise ConfigError(f"--spin-us {args.spin_us}: need >= 0")
    if live:
        if args.rt_priority is not None and not realtime:
            # --fast never sleeps: at a real-time priority it would starve everything below it
            raise ConfigError("--rt-priority needs real-time pacing: drop --fast")
        if args.nice is not None:
            _renice(args.nice)
        if args.rt_priority is not None:
            # before the imports and the set-up: started on one CPU beside a real-time service, the
            # simulator's start-up at the normal scheduler got the few percent the service left it and
            # sent nothing for 240 s (CI, user-mode Linux). Its start-up now goes first, once; the
            # service counts the steps it could not make meanwhile.
            _sched_fifo(args.rt_priority)
    from vcan_sim.faults import parse_fault
    from vcan_sim.output import Streamer, open_outputs, warm_up
    from vcan_sim.run import Simulation
    from vcan_sim.scenarios import get_scenario

    t0_ns = None if args.t0 is None else int(round(args.t0 * 1e6)) * 1000
    scenario = get_scenario(args.scenario)
    if args.fault:
        scenario = replace(scenario, faults=scenario.faults + tuple(parse_fault(f) for f in args.fault))
    sim = Simulation(
        scenario,
        vehicle=args.vehicle,
        profile=args.profile,
        seed=args.seed,
        duration=args.duration,
        t0_ns=t0_ns,
        speed_kmh=args.speed,
    )
    wall = time.monotonic()
    # the files stream while the simulation runs (lde run --record's flush policy): a SIGKILL loses
    # at most the last flush interval, not the whole run
    outputs = open_outputs(sim, log=args.log, truth=args.truth, mcap=args.mcap, channel=args.log_channel)
    streamer = Streamer(sim, outputs)
    try:
        if live:
            warm_up()  # the writers' compiled kernels loaded now, not at the first flush
            _run_live(args, sim, realtime, streamer)
        else:
            with _signals_stop() as stopped:
                while not sim.done and not stopped:
                    sim.run_steps(OFFLINE_PIECE_STEPS)
                    streamer.flush()
            if stopped:
                print(f"lde sim: stopped by {stopped[0]}; closing what was simulated", file=sys.stderr)
        streamer.flush()
        outputs.close()
    finally:
        outputs.abort()  # after an error: the files keep what was flushed (a no-op once closed)
    if not live:
        dest = f" -> {', '.join(map(str, outputs.paths))}" if outputs.paths else ""
        print(
            f"lde sim: {args.scenario} (seed {args.seed}, profile {sim.profile.name}): {outputs.frames} "
            f"frames, {outputs.truth_rows} truth rows, {sim.duration:.2f} s simulated in "
            f"{time.monotonic() - wall:.2f} s{dest}",
            file=sys.stderr,
        )
    return 0


def _run_live(args: argparse.Namespace, sim, realtime: bool, streamer) -> None:
    """Pump ``sim`` onto the bus until its end or a signal; ``streamer`` writes the files as it goes."""
    from lde.can.busio import bus_label, open_bus, receive_only
    from vcan_sim.closed_loop import OverlayReceiver
    from vcan_sim.emitter import LATE_S, MAX_LAG_S, PumpStats, pump

    receiver = None if args.open_loop else OverlayReceiver(sim.profile)
    kw = bus_kwargs(args)
    bus = open_bus(**kw)
    if receiver is not None:
        # where the kernel can, it hands the simulator only the frame it reads, LDE_Overlay: on a slow
        # single CPU (user-mode Linux) reading every LDE_Estimate/LDE_Diag frame too starves its sending
        receive_only(bus, [sim.profile.spec("LDE_Overlay").frame_id])
    st: PumpStats | None = None
    trace: list[tuple[int, int, int, int]] | None = [] if args.send_trace else None
    print(
        f"lde sim: {args.scenario} on {bus_label(**kw)} ({'real time' if realtime else 'fast'}, "
        f"{sim.duration:.0f} s); SIGINT/SIGTERM stop it",
        file=sys.stderr,
        flush=True,
    )
    try:
        with _signals_stop() as stopped:
            st = pump(
                sim,
                bus,
                realtime=realtime,
                closed_loop=not args.open_loop,
                receiver=receiver,
                stop=lambda: bool(stopped),
                after_step=streamer.poll,
                spin_s=args.spin_us * 1e-6,
                send_trace=trace,
            )
    finally:
        bus.shutdown()
        if trace is not None:
            import numpy as np

            np.save(args.send_trace, np.array(trace, np.int64).reshape(-1, 4))
    if stopped:
        print(f"lde sim: stopped by {stopped[0]}; closing what was simulated", file=sys.stderr)
        return
    if st is not None:
        used = receiver.stats.used if receiver else 0
        # closed loop: the steps that found no new overlay frame ran on the last request
        stale = ""
        if receiver:
            rs, es = receiver.stats, receiver.e2e.stats
            stale = (
                f" of {rs.received} received (re-synchronising {es.resync} after {es.initial} (re)starts,"
                f" E2E rejected {rs.rejected}, malformed {rs.malformed}), "
                f"steps on the last overlay request {st.stale_overlay_steps} of {st.steps}"
            )
            if st.rx_full_steps:
                stale += f", steps that left frames queued for the next {st.rx_full_steps}"
        print(
            f"lde sim: {args.scenario}: sent {st.sent} frames over {st.sim_s:.2f} s simulated in "
            f"{st.wall_s:.2f} s wall ({'real time' if realtime else 'fast'}, CPU {st.cpu_s:.2f} s); "
            f"overlay frames used {used}{stale}, send errors {st.send_errors}, "
            f"max lateness {st.max_late_s * 1e3:.2f} ms, "
            f"frames late > {LATE_S * 1e3:.0f} ms {st.late_frames}, "
            f"schedule slipped {st.slips}x by {st.slipped_s * 1e3:.0f} ms "
            f"(> {MAX_LAG_S * 1e3:.1f} ms behind)",
            file=sys.stderr,
        )
