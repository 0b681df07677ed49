"""Bench buses: python-can buses whose frames carry the bench's simulated time.

Each participant of a :class:`~lde.testing.Bench` (the simulator, the lde service, the user's code,
the frame capture) gets its own :class:`BenchBus` on the bench's channel. It is a ``can.BusABC``
(``send``, ``recv``, iteration, filters, ``send_periodic``) over a real python-can bus:

* ``virtual``: python-can's virtual bus (``preserve_timestamps=True``), which delivers a frame to
  every other bus of the channel inside ``send``;
* ``socketcan``: a raw socket on a real (v)CAN interface. The kernel delivers asynchronously, so
  ``send`` waits until every other bench bus has received the frame (a barrier: with one scheduler
  and the frames on the bus at the instant they were sent, the run is deterministic there too).

A frame is stamped with the simulated time at which it was sent (the sender's own timestamp with
``preserve_timestamps=True``) - on SocketCAN the receivers' copies are re-stamped so, since the
kernel stamps in wall-clock time - so the same test gives the same frames on both interfaces.

Time is simulated: ``recv(timeout)`` never waits (nothing can arrive while the bench stands still),
iterating over a bench bus yields the frames that have arrived and stops, and ``send_periodic``
sends on the bench's clock.
"""

from __future__ import annotations

import itertools
import os
import random
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from typing import Any

import can
from can.broadcastmanager import (
    CyclicSendTaskABC,
    LimitedDurationCyclicSendTaskABC,
    ModifiableCyclicTaskABC,
    RestartableCyclicTaskABC,
)

from lde.can.frames import ns_to_seconds, seconds_to_ns
from lde.errors import BusError, ConfigError
from lde.testing.scheduler import Rank, Scheduler, Task

__all__ = ["INTERFACES", "DELIVERY_TIMEOUT_S", "Medium", "BenchBus", "unique_channel", "private_multicast"]

#: the python-can interfaces a bench runs on
INTERFACES = ("virtual", "socketcan")
#: SocketCAN: how long a frame may take to reach every bench bus [s, wall clock]
DELIVERY_TIMEOUT_S = 5.0

_channel_ids = itertools.count()


def unique_channel(label: str = "") -> str:
    """A python-can ``virtual`` channel name no other bench in this process uses."""
    tail = f"-{label}" if label else ""
    return f"lde-bench-{os.getpid()}-{next(_channel_ids)}{tail}"[:120]


def private_multicast(rng: random.Random | None = None) -> dict[str, Any]:
    """``can.Bus`` keyword arguments of a python-can ``udp_multicast`` bus on a group and port of
    its own (239.74.x.y, 40000-60000): tests and benches running at the same time on one host do
    not hear each other. Two buses made from the same dict hear each other.

    ``hop_limit`` 0 (the IPv4 TTL): the datagrams stay on this host. They are delivered to the local
    members by the multicast loopback and not handed to the network card as well, whose transmit
    (on a VM a virtio queue kick, an exit to the hypervisor) cost about 20-45 us of the first send
    after an idle period and doubled a step's four sends (docs/guide/bus.md, "`udp_multicast` on one
    host")."""
    r = rng if rng is not None else random.Random()
    return {
        "interface": "udp_multicast",
        "channel": f"239.74.{r.randint(1, 254)}.{r.randint(1, 254)}",
        "port": r.randint(40000, 60000),
        "hop_limit": 0,
    }


def _key(msg: can.Message) -> tuple[int, bool, bytes]:
    return (msg.arbitration_id, msg.is_extended_id, bytes(msg.data))


class Medium:
    """The interface and channel under a bench, and the bench buses open on it.

    Args:
        interface: ``virtual`` or ``socketcan``.
        channel: the channel (a virtual channel name, or ``vcan0``, ``can0``...).
        scheduler: the bench's scheduler (its clock stamps the frames; periodic sends run on it).
        bus_kwargs: more ``can.Bus`` keyword arguments for every bus opened (SocketCAN: ``fd``...).
    """

    def __init__(
        self, interface: str, channel: str, scheduler: Scheduler, bus_kwargs: dict[str, Any] | None = None
    ) -> None:
        if interface not in INTERFACES:
            raise ConfigError(f"bench interface {interface!r}: use one of {', '.join(INTERFACES)}")
        self.interface = interface
        self.channel = channel
        self.scheduler = scheduler
        self.bus_kwargs = dict(bus_kwargs or {})
        self.buses: list[BenchBus] = []
        self.frames_sent = 0

    @property
    def now_s(self) -> float:
        return ns_to_seconds(self.scheduler.now_ns)

    def open_raw(self) -> can.BusABC:
        """A plain python-can bus on the channel (what a bench bus wraps)."""
        kw: dict[str, Any] = {"interface": self.interface, "channel": self.channel, **self.bus_kwargs}
        if self.interface == "virtual":
            kw["preserve_timestamps"] = True
        try:
            return can.Bus(**kw)
        except (can.CanError, OSError, ValueError, ImportError) as exc:
            raise BusError(f"cannot open {self.interface} bus {self.channel!r}: {exc}") from exc

    def deliver(self, sender: BenchBus, msg: can.Message, stamp_s: float) -> None:
        """Put ``msg`` on the bus, stamped ``stamp_s``; return once every bench bus has it."""
        if self.interface == "virtual":
            old = msg.timestamp
            msg.timestamp = stamp_s  # the virtual bus copies the frame (with this stamp) to every receiver
            try:
                sender.raw.send(msg)
            finally:
                msg.timestamp = old
        else:
            try:
                sender.raw.send(msg)
            except (can.CanError, OSError) as exc:
                raise BusError(f"{sender.name}: send on {self.channel} failed: {exc}") from exc
            key = _key(msg)
            deadline = time.monotonic() + DELIVERY_TIMEOUT_S
            for bus in self.buses:
                if bus is not sender:
                    bus._pull(key, stamp_s, deadline)
        self.frames_sent += 1


class BenchBus(can.BusABC):
    """A participant's bus on a bench (see the module docstring). Opened by :meth:`Bench.bus`.

    Args:
        medium: the bench's medium.
        name: the participant's name (in ``channel_info`` and error messages).
        preserve_timestamps: keep the timestamp of the frames sent (default: stamp them with the
            bench's time, as a kernel would).
        drop: CAN ids whose frames ``send`` swallows (counted in :attr:`dropped`): unplugs one of the
            participant's messages, e.g. lde's ``LDE_Overlay`` when the user's controller sends it.
        can_filters: python-can receive filters (applied in software).
    """

    def __init__(
        self,
        medium: Medium,
        name: str,
        *,
        preserve_timestamps: bool = False,
        drop: Iterable[int] = (),
        can_filters: Any = None,
    ) -> None:
        self.medium = medium
        self.name = name
        self.preserve_timestamps = preserve_timestamps
        self.drop = frozenset(int(i) for i in drop)
        self.dropped = 0
        self.sent = 0
        self.raw = medium.open_raw()
        self._rx: deque[can.Message] = deque()  # SocketCAN: frames taken from the socket, stamped
        super().__init__(channel=medium.channel, can_filters=can_filters)
        self.channel_info = f"lde bench {medium.interface} {medium.channel}: {name}"
        medium.buses.append(self)

    # ------------------------------------------------------------------ sending
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.name}: the bench bus is shut down")
        if msg.arbitration_id in self.drop:
            self.dropped += 1
            return
        stamp = msg.timestamp if self.preserve_timestamps else self.medium.now_s
        self.medium.deliver(self, msg, stamp)
        self.sent += 1

    def _send_periodic_internal(
        self,
        msgs: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None = None,
        autostart: bool = True,
        modifier_callback: Callable[[can.Message], None] | None = None,
    ) -> CyclicSendTaskABC:
        return BenchCyclicTask(self, msgs, period, duration, autostart, modifier_callback)

    # ------------------------------------------------------------------ receiving
    def _pull(self, key: tuple[int, bool, bytes], stamp_s: float, deadline: float) -> None:
        """SocketCAN barrier: take frames from the socket until the one sent (``key``) is here."""
        while True:
            remaining = deadline - time.monotonic()
            msg = self.raw.recv(max(remaining, 0.0))
            if msg is None:
                raise BusError(
                    f"{self.name}: a frame sent on {self.medium.channel} (id 0x{key[0]:X}) did not arrive "
                    f"within {DELIVERY_TIMEOUT_S} s"
                )
            if _key(msg) == key:
                msg.timestamp = stamp_s
                self._rx.append(msg)
                return
            msg.timestamp = self.medium.now_s  # a frame from outside the bench: it arrives now
            self._rx.append(msg)

    def _next(self) -> can.Message | None:
        if self._rx:
            return self._rx.popleft()
        msg = self.raw.recv(0.0)
        if msg is not None and self.medium.interface != "virtual":
            msg.timestamp = self.medium.now_s  # from outside the bench
        return msg

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self._next(), False

    def recv(self, timeout: float | None = None) -> can.Message | None:
        """The next frame that has arrived (and passes the filters), or None. Never waits: the bench's
        time moves only when the bench runs."""
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.name}: the bench bus is shut down")
        while (msg := self._next()) is not None:
            if self._matches_filters(msg):
                return msg
        return None

    def __iter__(self) -> Iterator[can.Message]:
        """The frames that have arrived, then stop (python-can's own iterator would wait forever)."""
        while (msg := self.recv()) is not None:
            yield msg

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self.raw.shutdown()
        if self in self.medium.buses:
            self.medium.buses.remove(self)


class BenchCyclicTask(LimitedDurationCyclicSendTaskABC, ModifiableCyclicTaskABC, RestartableCyclicTaskABC):
    """``bus.send_periodic(...)`` on the bench's clock: the first frame at once, then every period."""

    def __init__(
        self,
        bus: BenchBus,
        messages: Sequence[can.Message] | can.Message,
        period: float,
        duration: float | None,
        autostart: bool,
        modifier_callback: Callable[[can.Message], None] | None,
    ) -> None:
        super().__init__(messages, period, duration)
        self.bus = bus
        self.modifier_callback = modifier_callback
        self._task: Task | None = None
        self._index = 0
        self._end_ns: int | None = None
        if autostart:
            self.start()

    def start(self) -> None:
        if self._task is not None and self._task.active:
            return
        sched = self.bus.medium.scheduler
        now = sched.now_ns
        self._end_ns = None if self.duration is None else now + seconds_to_ns(self.duration)
        self._task = sched.every(
            self.period_ns,
            self._send,
            start_ns=now,
            rank=Rank.USER,
            name=f"send_periodic 0x{self.arbitration_id:X}",
        )

    def _send(self, t_ns: int) -> None:
        if self._end_ns is not None and t_ns >= self._end_ns:
            self.stop()
            return
        msg = self.messages[self._index]
        if self.modifier_callback is not None:
            self.modifier_callback(msg)
        self.bus.send(msg)
        self._index = (self._index + 1) % len(self.messages)

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
