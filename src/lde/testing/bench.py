"""The test bench: one CAN bus, one simulated clock, and whatever takes part.

A :class:`Bench` owns a channel (a fresh python-can ``virtual`` channel, or a real SocketCAN
interface such as ``vcan0``), a :class:`~lde.clock.SimulatedClock` and the one
:class:`~lde.testing.scheduler.Scheduler` that moves it. Participants join with:

* :meth:`Bench.simulator` - the vehicle simulator for a named scenario (closed loop on ``LDE_Overlay``);
* :meth:`Bench.service` - the lde service (the code of ``lde run``), its results kept;
* :meth:`Bench.feeder` - plain input frames without a plant;
* the user's code: a bus from :meth:`Bench.bus`, driven by :meth:`Bench.every` (a periodic
  ``step(t_ns)``), :meth:`Bench.on_frame` (a handler per received frame), ``bus.send_periodic``, or
  the simulator's ``overlay=`` callable (an ECU model applying the overlay torque).

:meth:`Bench.run` advances simulated time (a 60 s scenario takes seconds); :meth:`Bench.frames` and
:meth:`Bench.wait_for` give the frames seen on the bus, decoded by DBC name. The same test gives the
same frames, run after run, on ``virtual`` and on ``socketcan``.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import can
from can.interfaces import virtual as _virtual

from lde.can.frames import seconds_to_ns
from lde.can.profiles import Profile, load_profile
from lde.clock import SimulatedClock
from lde.errors import ConfigError, LdeError
from lde.params import Vehicle
from lde.testing.bus import BenchBus, Medium, unique_channel
from lde.testing.capture import Capture, Frame, FrameList
from lde.testing.participants import BenchService, BenchSimulator, InputFeeder, InputValue, OverlaySource
from lde.testing.scheduler import Rank, Scheduler, Task

__all__ = ["Bench", "BenchTimeout", "LeakedBus", "DEFAULT_START_NS"]

#: the bench's clock starts here by default: 1_700_000_000 s, an epoch time like the simulator's logs
DEFAULT_START_NS = 1_700_000_000 * 1_000_000_000
#: frame handlers answering each other at one instant more often than this is an endless loop
_MAX_SETTLE_ROUNDS = 1000


class BenchTimeout(LdeError, TimeoutError):
    """What :meth:`Bench.wait_for` / :meth:`Bench.run_until` waited for did not happen in time."""


class LeakedBus(LdeError, AssertionError):
    """A bus on the bench's virtual channel was still open when the bench closed."""


class Bench:
    """One CAN bus, one simulated clock, and the participants (see the module docstring).

    Args:
        interface: ``virtual`` (default) or ``socketcan``.
        channel: the channel; default a fresh virtual channel (``socketcan``: ``vcan0``).
        profile: the CAN profile of every participant (``lde`` or ``hyundai``, or a Profile).
        vehicle: the default vehicle of the simulator and the service (Vehicle, shipped name, path).
        start_ns: the clock's start [ns, epoch time].
        capture: keep every frame seen on the bus (:meth:`frames`, :meth:`wait_for`).
        label: added to a generated channel name (the test's name).
        bus_kwargs: more ``can.Bus`` keyword arguments (SocketCAN: ``fd=True``...).
    """

    def __init__(
        self,
        *,
        interface: str = "virtual",
        channel: str | None = None,
        profile: Profile | str = "lde",
        vehicle: Vehicle | str | None = None,
        start_ns: int = DEFAULT_START_NS,
        capture: bool = True,
        label: str = "",
        bus_kwargs: dict[str, Any] | None = None,
    ) -> None:
        if channel is None:
            channel = "vcan0" if interface == "socketcan" else unique_channel(label)
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.vehicle = vehicle
        self.clock = SimulatedClock(int(start_ns))
        self.t0_ns = int(start_ns)
        self.scheduler = Scheduler(self.clock, settle=self._settle)
        self.medium = Medium(interface, channel, self.scheduler, bus_kwargs)
        self.simulators: list[BenchSimulator] = []
        self.services: list[BenchService] = []
        self.feeders: list[InputFeeder] = []
        self._handlers: dict[BenchBus, dict[int | None, list[Callable[[Frame], object]]]] = {}
        self._handler_capture: dict[BenchBus, Capture] = {}
        self._closed = False
        self.capture: Capture | None = None
        if capture:
            self.capture = Capture(self.bus("capture"), self.profile)

    # ------------------------------------------------------------------ basics
    @property
    def interface(self) -> str:
        return self.medium.interface

    @property
    def channel(self) -> str:
        """The channel; a user's own ``can.Bus(interface=bench.interface, channel=bench.channel)``
        joins the bus (its frames then carry its own timestamps; on SocketCAN they are not part of
        the deterministic delivery: prefer :meth:`bus`)."""
        return self.medium.channel

    @property
    def now_ns(self) -> int:
        """The bench's time [ns]."""
        return self.clock.now_ns()

    @property
    def elapsed_s(self) -> float:
        """Seconds since the bench's start."""
        return (self.now_ns - self.t0_ns) / 1e9

    def bus(
        self,
        name: str = "user",
        *,
        preserve_timestamps: bool = False,
        drop: Iterable[int] = (),
        can_filters: Any = None,
    ) -> BenchBus:
        """A new bus on the bench for one participant (closed with the bench); see :class:`BenchBus`."""
        self._check_open()
        return BenchBus(
            self.medium, name, preserve_timestamps=preserve_timestamps, drop=drop, can_filters=can_filters
        )

    # ------------------------------------------------------------------ participants
    def simulator(
        self,
        scenario: Any = "heavy_load",
        *,
        seed: int = 0,
        duration: float | None = None,
        vehicle: Vehicle | str | None = None,
        overlay: OverlaySource = "bus",
        speed_kmh: float | None = None,
        name: str = "simulator",
    ) -> BenchSimulator:
        """The vehicle simulator for ``scenario``, starting now (see :class:`BenchSimulator`)."""
        self._check_open()
        sim = BenchSimulator(
            self,
            scenario,
            seed=seed,
            duration=duration,
            vehicle=vehicle,
            overlay=overlay,
            speed_kmh=speed_kmh,
            name=name,
        )
        self.simulators.append(sim)
        return sim

    def service(
        self,
        *,
        backend: str = "fixed",
        vehicle: Vehicle | str | None = None,
        overlay: bool = True,
        drop: Iterable[str] = (),
        phase_s: float = 0.0,
        record: str | Path | None = None,
        learned: str | Path | None = None,
        name: str = "lde",
    ) -> BenchService:
        """The lde service, stepping every 3.9 ms (see :class:`BenchService`)."""
        self._check_open()
        svc = BenchService(
            self,
            backend=backend,
            vehicle=vehicle,
            overlay=overlay,
            drop=drop,
            phase_s=phase_s,
            record=record,
            learned=learned,
            name=name,
        )
        self.services.append(svc)
        return svc

    def feeder(
        self,
        *,
        start_s: float = 0.0,
        silent: Callable[[str, int], bool] | None = None,
        tamper: Callable[[str, int, can.Message], None] | None = None,
        name: str = "feeder",
        **values: InputValue,
    ) -> InputFeeder:
        """Input frames without a plant (see :class:`InputFeeder`), the first ``start_s`` from now."""
        self._check_open()
        fd = InputFeeder(
            self.bus(name), self.profile, self.now_ns + seconds_to_ns(start_s), silent=silent, tamper=tamper
        )
        fd.set(**values)

        def send(t_ns: int) -> None:
            fd.send_until(t_ns)
            self.scheduler.at(fd.due_ns(), send, Rank.SOURCE, name)

        self.scheduler.at(fd.due_ns(), send, Rank.SOURCE, name)
        self.feeders.append(fd)
        return fd

    # ------------------------------------------------------------------ the user's code
    def every(
        self,
        period_s: float,
        fn: Callable[[int], object],
        *,
        phase_s: float = 0.0,
        rank: int = Rank.USER,
        name: str = "",
    ) -> Task:
        """Call ``fn(t_ns)`` every ``period_s`` at ``bench start + phase_s + k * period_s`` (from now on).

        At one instant it runs after the simulator's frames due then and before the lde service's
        step (``rank=Rank.LATE``: after the service's step, so it sees that step's frames).
        """
        self._check_open()
        period = seconds_to_ns(period_s)
        if period <= 0:
            raise ConfigError(f"period_s must be at least 1 us, got {period_s}")
        start = self.t0_ns + seconds_to_ns(phase_s)
        if start < self.now_ns:
            start += -(-(self.now_ns - start) // period) * period
        return self.scheduler.every(period, fn, start, rank, name or getattr(fn, "__qualname__", "task"))

    def at(self, t_s: float, fn: Callable[[int], object], *, rank: int = Rank.USER) -> Task:
        """Call ``fn(t_ns)`` once, ``t_s`` seconds after the bench's start."""
        self._check_open()
        return self.scheduler.at(self.t0_ns + seconds_to_ns(t_s), fn, rank, getattr(fn, "__qualname__", "at"))

    def on_frame(
        self, message: str | int | None, handler: Callable[[Frame], object], *, bus: BenchBus | None = None
    ) -> BenchBus:
        """Call ``handler(frame)`` for every ``message`` frame (DBC name, CAN id, None: any) that
        reaches ``bus`` (default: a new bench bus), at the instant it arrives; returns the bus (send
        the answers there). A bus with handlers is read by the bench: do not read it yourself."""
        self._check_open()
        if bus is None:
            bus = self.bus("handler")
        cap = self._handler_capture.setdefault(bus, Capture(bus, self.profile))
        key = None if message is None else cap.resolve(message)[1]
        self._handlers.setdefault(bus, {}).setdefault(key, []).append(handler)
        return bus

    def _settle(self) -> None:
        """Dispatch the frames that reached handler buses (handlers may answer: until quiet)."""
        if not self._handlers:
            return
        for _ in range(_MAX_SETTLE_ROUNDS):
            quiet = True
            for bus, table in list(self._handlers.items()):
                cap = self._handler_capture[bus]
                for msg in bus:
                    quiet = False
                    fns = [*table.get(msg.arbitration_id, ()), *table.get(None, ())]
                    if not fns:
                        continue
                    frame = cap.decode(msg)
                    for fn in fns:
                        fn(frame)
            if quiet:
                return
        raise LdeError(f"frame handlers kept answering each other at t = {self.now_ns} ns")

    # ------------------------------------------------------------------ running
    def run(self, seconds: float | None = None) -> None:
        """Advance ``seconds`` of simulated time (every action due before then runs); without
        ``seconds``, until every simulator's scenario has ended."""
        self._check_open()
        if seconds is not None:
            if seconds < 0:
                raise ConfigError(f"seconds must be >= 0, got {seconds}")
            self.scheduler.run(end_ns=self.now_ns + seconds_to_ns(seconds))
            return
        if not self.simulators:
            raise ConfigError("run() without seconds runs to the end of the scenario: add a simulator first")
        self.scheduler.run(stop=lambda: all(s.done for s in self.simulators))

    def run_until(self, condition: Callable[[], bool], timeout_s: float, what: str = "the condition") -> None:
        """Run until ``condition()`` is true (asked after every instant) or raise :class:`BenchTimeout`
        after ``timeout_s`` of simulated time."""
        self._check_open()
        if condition():
            return
        t_start = self.now_ns
        if not self.scheduler.run(t_start + seconds_to_ns(timeout_s), stop=condition, inclusive=True):
            raise BenchTimeout(
                f"{what} did not happen within {timeout_s} s of bench time "
                f"(from t = {(t_start - self.t0_ns) / 1e9:.4f} s); frames seen: {self._summary()}"
            )

    def wait_for(
        self, message: str | int, timeout_s: float = 1.0, where: Callable[[Frame], bool] | None = None
    ) -> Frame:
        """Run until a new ``message`` frame (DBC name or CAN id; ``where(frame)`` true, if given)
        is on the bus and return it decoded; :class:`BenchTimeout` after ``timeout_s`` of bench time."""
        cap = self._capture()
        can_id = cap.resolve(message)[1]
        cap.drain()
        seen = cap.count_of(can_id)
        found: list[Frame] = []

        def arrived() -> bool:
            cap.drain()
            n = cap.count_of(can_id)
            nonlocal seen
            if n > seen:
                for f in cap.frames(message, start=seen):
                    if where is None or where(f):
                        found.append(f)
                        return True
                seen = n
            return False

        label = message if isinstance(message, str) else f"0x{message:X}"
        self.run_until(
            arrived, timeout_s, what=f"a {label} frame" + ("" if where is None else " matching where=")
        )
        return found[0]

    def frames(self, message: str | int) -> FrameList:
        """Every ``message`` frame (DBC name or CAN id) seen on the bus so far, decoded."""
        return self._capture().frames(message)

    def _capture(self) -> Capture:
        if self.capture is None:
            raise ConfigError("this bench was made with capture=False: it keeps no frames")
        return self.capture

    def _summary(self) -> str:
        return self.capture.summary() if self.capture is not None else "(not captured)"

    # ------------------------------------------------------------------ closing
    def _check_open(self) -> None:
        if self._closed:
            raise ConfigError("the bench is closed")

    def close(self) -> None:
        """Close the participants and every bench bus; then check that no other bus was left open
        on the bench's virtual channel (:class:`LeakedBus`: python-can's own leak check, for this
        channel; closing those buses is their owner's job)."""
        if self._closed:
            return
        self._closed = True
        errors: list[BaseException] = []
        for svc in self.services:
            try:
                svc.close()
            except Exception as exc:  # close every bus even when a recorder fails
                errors.append(exc)
        for bus in list(self.medium.buses):
            bus.shutdown()
        leaked = _leaked_virtual(self.medium.channel) if self.interface == "virtual" else 0
        if errors:
            raise errors[0]
        if leaked:
            raise LeakedBus(
                f"{leaked} bus(es) on the bench's channel {self.medium.channel!r} were not shut down "
                "(open them with bench.bus(), or close your own can.Bus: `with can.Bus(...) as bus:`)"
            )

    def __enter__(self) -> Bench:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _leaked_virtual(channel: str) -> int:
    """How many python-can virtual buses are still open on ``channel``."""
    with _virtual.channels_lock:
        return len(_virtual.channels.get(channel, ()))
