"""``lde run``: the live estimator service on a CAN bus.

The bus is opened the python-can way: ``--interface``/``--channel``/``--bitrate`` where given, else
python-can's environment variables (``CAN_INTERFACE``, ``CAN_CHANNEL``, ``CAN_BITRATE``) or its
config file (``~/can.conf``, ``$XDG_CONFIG_HOME/can.conf``, ...). On python-can's ``udp_multicast``
every program on this host with the same group (``--channel``) and port (``--bus-kwarg port=N``) is
on the same bus: give yours a group and port of its own, e.g. ``-c 239.74.163.77 --bus-kwarg
port=47311``. SIGINT/SIGTERM end the service cleanly: the overlay request ramps to zero, then the
learned state (``--learned``) is written and the recording is closed.

While it runs it prints one status line a second to stderr (valid share, Fw, Mw, bank, overlay,
learner, deadline misses, missing inputs). Exit status 3 when no input message ever arrived (nothing
usable, as ``lde replay``).
"""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
from types import FrameType
from typing import TYPE_CHECKING

from lde.cli import BACKEND_HELP, PROFILE_HELP
from lde.cli.replay import EXIT_NOTHING_USABLE
from lde.errors import BusError, ConfigError

if TYPE_CHECKING:
    from lde.service.service import Service, StepResult

log = logging.getLogger("lde.service.service")

#: GIL switch interval while the service runs [s] (CPython's default is 5 ms, longer than a step)
SWITCH_INTERVAL_S = 2e-4


def add_bus_arguments(p: argparse.ArgumentParser) -> None:
    """python-can bus options (shared with ``lde sim``-style commands)."""
    g = p.add_argument_group("CAN bus (python-can; omitted options come from its env/config)")
    g.add_argument("-i", "--interface", help="python-can interface: socketcan, virtual, pcan, vector, ...")
    g.add_argument(
        "-c",
        "--channel",
        help="channel: vcan0, can0, PCAN_USBBUS1, a udp_multicast group (239.74.X.Y: pick your own, with "
        "--bus-kwarg port=N, so that no other program on this host shares the bus), ...",
    )
    g.add_argument("-b", "--bitrate", type=int, help="bit rate [bit/s] where the interface sets it")
    g.add_argument(
        "--bus-kwarg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra keyword for can.Bus (repeatable), e.g. receive_own_messages=False; udp_multicast: "
        "port=N (python-can's default 43113 is shared by every user of that group) and hop_limit=0 (stay "
        "on this host)",
    )


def bus_kwargs(args: argparse.Namespace) -> dict[str, object]:
    kw: dict[str, object] = {"interface": args.interface, "channel": args.channel, "bitrate": args.bitrate}
    for item in args.bus_kwarg:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise BusError(f"--bus-kwarg {item!r}: expected KEY=VALUE")
        kw[key] = _parse_value(value)
    return kw


def _parse_value(v: str) -> object:
    low = v.lower()
    if low in ("true", "false"):
        return low == "true"
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    return v


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run",
        help="run the live estimator service on a CAN bus",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_bus_arguments(p)
    p.add_argument("--profile", default="lde", help=PROFILE_HELP + " (default: lde)")
    p.add_argument("--vehicle", default=None, help="vehicle TOML file or shipped name (default: reference)")
    p.add_argument("--backend", default="fixed", help=BACKEND_HELP)
    p.add_argument("--record", metavar="FILE.mcap", help="record frames, estimates and diagnostics to MCAP")
    p.add_argument(
        "--learned",
        metavar="FILE",
        help="what the estimator learned about this car: read at start when FILE exists (checked against "
        "the vehicle and profile), written atomically every 60 s and at the end (a learning backend)",
    )
    p.add_argument("--duration", type=float, metavar="SEC", help="stop after this many seconds")
    p.add_argument("--no-overlay", action="store_true", help="keep the overlay request at zero")
    p.add_argument(
        "--realtime", action="store_true", help="SCHED_FIFO, locked memory (falls back with a warning)"
    )
    p.add_argument("--priority", type=int, default=80, help="SCHED_FIFO priority with --realtime (1..99)")
    p.add_argument("--cpu", type=int, action="append", metavar="N", help="pin to CPU N (repeatable)")
    p.add_argument(
        "--grid",
        choices=("mdps", "fixed"),
        default="mdps",
        help="mdps (default): each step runs right after the MDPS frame it consumes (the MDPS-locked grid; "
        "a step at 1.5 periods when a frame is missing; windows it fell behind by are skipped and counted); "
        "fixed: absolute 3.9 ms deadlines on the clock (input-to-output latency up to a period)",
    )
    p.add_argument(
        "--spin-us",
        type=float,
        default=None,
        metavar="US",
        help="poll the bus from this long before to this long after the expected MDPS frame (mdps grid), "
        "busy-wait this long before each deadline (fixed grid) [us] (default 200; 0 blocks/sleeps only: "
        "on a CPU shared with the simulator, user-mode Linux say, the spin takes time the others need)",
    )
    p.add_argument(
        "--cpu-latency-us",
        type=int,
        default=0,
        metavar="US",
        help="with --realtime: hold the CPUs' wake-up latency at most US (PM QoS, /dev/cpu_dma_latency, "
        "all CPUs; default 0: idle CPUs poll instead of halting, the step runs on warmer caches; "
        "-1 leaves it alone)",
    )
    p.add_argument(
        "--flood-rate",
        type=float,
        default=None,
        metavar="HZ",
        help="frames of other messages per second on the bus logged as a flood (default 2000; SocketCAN "
        "counts them at the interface, elsewhere those that reach the service; raise it on a shared bus)",
    )
    p.add_argument("--log-period", type=float, default=10.0, metavar="SEC", help="timing log line period")
    p.add_argument(
        "--status-interval",
        type=float,
        default=1.0,
        metavar="S",
        help="print a status line to stderr every S seconds (default 1): valid share of the steps, Fw [N], "
        "Mw [Nm], bank [deg], overlay state and torque [Nm], learner state, deadline misses, missing inputs",
    )
    p.add_argument("--quiet", "-q", action="store_true", help="no status lines")
    p.set_defaults(func=run)


def _realtime(args: argparse.Namespace) -> None:
    from lde import clock

    enable = getattr(clock, "enable_realtime", None)
    if enable is None:
        log.warning("--realtime: lde.clock.enable_realtime is not available; normal scheduling")
        return
    latency = None if args.cpu_latency_us < 0 else args.cpu_latency_us
    result = enable(priority=args.priority, cpus=args.cpu, lock_memory=True, cpu_latency_us=latency)
    for w in getattr(result, "warnings", ()) or ():
        log.warning("--realtime: %s", w)


def _spin_ns(spin_us: float) -> int:
    if not (spin_us >= 0 and spin_us < 1e6):  # also rejects NaN
        raise ConfigError(f"--spin-us {spin_us}: need 0 <= US < 1000000")
    return int(round(spin_us * 1e3))


def run(args: argparse.Namespace) -> int:
    if args.flood_rate is not None and not (args.flood_rate > 0 and math.isfinite(args.flood_rate)):
        raise ConfigError(f"--flood-rate {args.flood_rate}: need frames per second > 0")
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        raise ConfigError(f"--duration {args.duration}: need seconds > 0 (leave it out to run until stopped)")
    if not (args.status_interval > 0 and math.isfinite(args.status_interval)):
        raise ConfigError(f"--status-interval {args.status_interval}: need seconds > 0 (--quiet: none)")
    from lde.can.profiles import load_profile
    from lde.clock import MonotonicClock
    from lde.params import load_vehicle
    from lde.service import service as svc_mod
    from lde.units import STEP_NS

    logging.getLogger("lde.service.service").setLevel(logging.INFO)
    # no other thread runs in the service's process (the recorder writes from its own process); should
    # one ever hold the interpreter lock, the loop must get it back within a fraction of a step
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
    profile = load_profile(args.profile)
    for line in profile.notes():
        log.warning("%s", line)
    vehicle = load_vehicle(args.vehicle)
    if vehicle.defaults:
        log.info("%s", vehicle.defaults_note())
    if args.realtime:
        _realtime(args)
    elif args.cpu:
        import os

        try:
            os.sched_setaffinity(0, set(args.cpu))
        except (OSError, ValueError) as exc:
            raise ConfigError(f"--cpu {args.cpu}: cannot pin to these CPUs: {exc}") from exc

    from lde.can.busio import bus_label

    kw = bus_kwargs(args)
    bus = svc_mod.open_bus(**kw)
    name = bus_label(**kw)
    recorder = None
    service = None
    stop = threading.Event()

    def _on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    old = {s: signal.signal(s, _on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    code = 0
    try:
        service = svc_mod.Service(
            bus,
            profile,
            vehicle,
            MonotonicClock() if args.spin_us is None else MonotonicClock(spin_ns=_spin_ns(args.spin_us)),
            backend=args.backend,
            overlay_enabled=not args.no_overlay,
            log_period_s=args.log_period,
            grid=args.grid,
            learned=args.learned,
            bus_name=name,
            **({} if args.flood_rate is None else {"flood_hz": args.flood_rate}),
        )
        if args.record:
            from lde.io.recording import LEARNED_START_KEY, Recorder

            meta = {
                **profile.metadata(),
                "vehicle": vehicle.name,
                "vehicle_source": vehicle.source,
                "backend": args.backend,
                "step_ns": str(STEP_NS),
                "bus": name,
            }
            if vehicle.defaults:  # what the vehicle file left to lde's defaults, as the log said
                meta["vehicle_defaults"] = "; ".join(vehicle.defaults)
            if service.learned_start:
                meta[LEARNED_START_KEY] = service.learned_start
            recorder = service.recorder = Recorder(args.record, metadata=meta, frame_bytes=service.rx_width)
        ends = _Ends(service, stop, args.duration, None if args.quiet else args.status_interval)
        log.info(
            "lde run: %s, profile %s, vehicle %s, backend %s, %s grid, input filters: %s%s",
            name,
            profile.name,
            vehicle.name,
            args.backend,
            args.grid,
            service.filters,
            f", recording to {args.record}" if args.record else "",
        )
        if name.startswith("udp_multicast:"):
            log.info(
                "%s: every program on this host with this group and port is on this bus; give each bus a"
                " group and port of its own (--channel 239.74.X.Y --bus-kwarg port=N)",
                name,
            )
        summary = service.run(stop_event=stop, on_step=ends.on_step)
        log.info("%s", summary.log_line())
        log.info("%s", service.fault_summary())
        if service.late_rx:
            log.info("frames that reached the service after the step of their timestamp: %d", service.late_rx)
        if service.valid_steps == 0:
            log.warning("%s", _nothing_usable(service))
            if service.inputs_received == 0:
                code = EXIT_NOTHING_USABLE
    finally:
        for s, h in old.items():
            signal.signal(s, h)
        try:
            if service is not None:
                service.close()  # the learned state's last write
        finally:
            if recorder is not None:
                recorder.close()
            bus.shutdown()
    return code


class _Ends:
    """Per step of ``lde run``: the status line every ``status_s`` [s] of step time (None: none), and
    the stop after ``duration_s`` [s] (None: until a signal), which ends like a signal does (the
    overlay ramps out, then the service stops)."""

    def __init__(
        self, service: Service, stop: threading.Event, duration_s: float | None, status_s: float | None
    ):
        from lde.units import STEP_NS

        self.service = service
        self.stop = stop
        self.span_ns = None if duration_s is None else max(STEP_NS, int(duration_s * 1e9))
        self.status_ns = None if status_s is None else max(STEP_NS, int(status_s * 1e9))
        self.first: int | None = None
        self.next_status = 0

    def on_step(self, res: StepResult) -> None:
        t = res.t_ns
        if self.first is None:
            self.first = t
            self.next_status = t + (self.status_ns or 0)
        elif self.span_ns is not None and t - self.first >= self.span_ns:
            self.stop.set()
        if self.status_ns is not None and t >= self.next_status:
            self.next_status += self.status_ns * max(1, (t - self.next_status) // self.status_ns + 1)
            print(f"lde run: {self.service.status().line()}", file=sys.stderr, flush=True)


def _nothing_usable(service: Service) -> str:
    """Why a run gave no valid estimate, for its last line."""
    where = f"on {service.bus_name} with profile {service.profile.name}"
    if service.inputs_received == 0:
        from lde.can.watch import describe_ids

        seen = describe_ids(service.watch.ids, service.profile)
        return (
            f"no input ever arrived {where} in {service.steps} steps ({seen}); no valid estimate, nothing"
            " usable: check --interface/--channel and --profile"
        )
    return (
        f"no valid estimate in {service.steps} steps {where} ({service.inputs_received} input frames"
        " arrived; see the warnings above); nothing usable"
    )
