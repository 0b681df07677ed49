"""Clocks for the live loop, and real-time scheduling helpers.

The estimator never reads a clock (time arrives as ``t_ns``); only the live loop does, through a
:class:`Clock`:

* :class:`MonotonicClock` — ``time.monotonic_ns()``; :meth:`~MonotonicClock.sleep_until` sleeps
  until ``spin_ns`` (default 200 us) before the deadline and busy-waits the rest, because
  ``time.sleep`` alone overshoots by 50-100 us (timer slack, wake-up latency), which matters on a
  3.9 ms period; :meth:`~MonotonicClock.recv_until` likewise polls the bus from ``spin_ns`` before
  to ``spin_ns`` after the time a frame is expected (the MDPS-locked grid).
* :class:`SimulatedClock` — advances only when told; ``sleep_until`` jumps to the deadline. Tests
  and the demo run the same loop with it, as fast as the host allows.

The loop schedules on absolute deadlines ``t_k = t_0 + k * period`` (:class:`Ticker`), so sleep
errors never accumulate into drift.

:func:`enable_realtime` asks for SCHED_FIFO, locked memory and CPU pinning, and reports every part
that the system refused as a warning instead of failing (a bench PC or a container rarely allows
all three).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import os
import sys
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Generic, NamedTuple, Protocol, TypeVar, runtime_checkable

from lde.errors import ConfigError

__all__ = [
    "Clock",
    "MonotonicClock",
    "SimulatedClock",
    "Ticker",
    "Tick",
    "RealtimeResult",
    "enable_realtime",
    "request_slice",
    "DEFAULT_SPIN_NS",
]

_F = TypeVar("_F", covariant=True)
_T = TypeVar("_T")


class Receiver(Protocol, Generic[_F]):
    """What :meth:`MonotonicClock.recv_until` reads from: a ``can.BusABC``, or the service's frame I/O
    (:mod:`lde.can.busio`), whose ``recv(timeout)`` returns a frame or None."""

    def recv(self, timeout: float | None = ...) -> _F | None: ...


#: the last stretch before a deadline that MonotonicClock busy-waits instead of sleeping [ns]
DEFAULT_SPIN_NS = 200_000


@runtime_checkable
class Clock(Protocol):
    """What the live loop needs from a clock. Times are integer nanoseconds on the clock's own base."""

    def now_ns(self) -> int:
        """The current time [ns]."""
        ...

    def sleep_until(self, t_ns: int) -> None:
        """Return at (or as soon as possible after) ``t_ns`` [ns]; at once if it has passed."""
        ...


class MonotonicClock:
    """The host's monotonic clock, with sleep-then-spin deadlines.

    Args:
        spin_ns: busy-wait this long before each deadline [ns] (0: pure sleep).
    """

    def __init__(self, spin_ns: int = DEFAULT_SPIN_NS) -> None:
        if int(spin_ns) < 0:
            raise ConfigError(f"spin_ns must be >= 0, got {spin_ns}")
        self.spin_ns = int(spin_ns)

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def sleep_until(self, t_ns: int) -> None:
        now = time.monotonic_ns
        remaining = t_ns - now()
        if remaining > self.spin_ns:
            time.sleep((remaining - self.spin_ns) * 1e-9)
        while now() < t_ns:  # the last spin_ns: spin, the scheduler's wake-up is too coarse
            pass

    def recv_until(self, bus: Receiver[_T], t_ns: int, expect_ns: int | None = None) -> _T | None:
        """The next frame from ``bus``, waiting at most until ``t_ns``; None when none came.

        Blocked in the kernel, except around ``expect_ns`` (when a frame is expected, and ``spin_ns``
        > 0): from ``spin_ns`` before it to ``spin_ns`` after it the bus is polled without blocking,
        so the frame is taken the moment it arrives instead of after a wake-up of the process
        (about 80 us p50 on this project's VM).
        """
        now = time.monotonic_ns()
        spin = self.spin_ns
        if expect_ns is None or spin == 0:
            return bus.recv(max(0.0, (t_ns - now) * 1e-9))
        spin_from = expect_ns - spin
        if now < spin_from:
            msg = bus.recv((min(spin_from, t_ns) - now) * 1e-9)
            if msg is not None:
                return msg
        spin_end = min(t_ns, expect_ns + spin)
        while time.monotonic_ns() < spin_end:
            msg = bus.recv(0.0)
            if msg is not None:
                return msg
        now = time.monotonic_ns()
        return bus.recv((t_ns - now) * 1e-9) if now < t_ns else None


class SimulatedClock:
    """A clock that moves only when told: :meth:`advance`, :meth:`set`, or :meth:`sleep_until`.

    Args:
        start_ns: the initial time [ns] (for example an epoch time, so that it matches bus
            timestamps).
    """

    def __init__(self, start_ns: int = 0) -> None:
        self._t = int(start_ns)

    def now_ns(self) -> int:
        return self._t

    def sleep_until(self, t_ns: int) -> None:
        """Jump to ``t_ns`` (never backwards)."""
        if t_ns > self._t:
            self._t = int(t_ns)

    def recv_until(self, bus: Receiver[_T], t_ns: int, expect_ns: int | None = None) -> _T | None:
        """A frame already on ``bus``; if there is none, jump to ``t_ns`` and return None."""
        msg = bus.recv(0.0)
        if msg is None:
            self.sleep_until(t_ns)
        return msg

    def advance(self, dt_ns: int) -> int:
        """Move forward by ``dt_ns`` >= 0 [ns]; returns the new time."""
        if dt_ns < 0:
            raise ConfigError(f"SimulatedClock cannot go backwards (dt_ns={dt_ns})")
        self._t += int(dt_ns)
        return self._t

    def set(self, t_ns: int) -> None:
        """Set the time to ``t_ns`` [ns] (not earlier than now)."""
        if t_ns < self._t:
            raise ConfigError(f"SimulatedClock cannot go backwards ({t_ns} < {self._t})")
        self._t = int(t_ns)


class Tick(NamedTuple):
    """One deadline of a :class:`Ticker`.

    Attributes:
        k: the index of the deadline (``t_k = t0 + k * period``); jumps when deadlines were skipped.
        t_ns: the deadline [ns, clock base].
        late_ns: how late the wake-up was [ns] (``now - t_ns`` right after the sleep).
        skipped: deadlines skipped before this one because the caller was more than a period late.
    """

    k: int
    t_ns: int
    late_ns: int
    skipped: int


class Ticker:
    """Absolute deadlines ``t0 + k * period`` on a clock (no drift).

    A wake-up more than one whole period late skips the missed deadlines (reported in
    :attr:`Tick.skipped`) instead of running a burst of late steps.

    Args:
        clock: the clock.
        period_ns: the period [ns] (> 0).
        t0_ns: the first deadline [ns]; default: one period from now.
    """

    def __init__(self, clock: Clock, period_ns: int, t0_ns: int | None = None) -> None:
        if int(period_ns) <= 0:
            raise ConfigError(f"period_ns must be > 0, got {period_ns}")
        self.clock = clock
        self.period_ns = int(period_ns)
        self.t0_ns = clock.now_ns() + self.period_ns if t0_ns is None else int(t0_ns)
        self.k = 0

    def wait(self) -> Tick:
        """Sleep until the next deadline and return it."""
        t_k = self.t0_ns + self.k * self.period_ns
        self.clock.sleep_until(t_k)
        late = self.clock.now_ns() - t_k
        skipped = 0
        if late >= self.period_ns:
            skipped = late // self.period_ns
            t_k += skipped * self.period_ns
            late -= skipped * self.period_ns
        tick = Tick(self.k + skipped, t_k, late, skipped)
        self.k += skipped + 1
        return tick


# --- real-time scheduling -----------------------------------------------------------------------

_MCL_CURRENT = 1
_MCL_FUTURE = 2


@dataclass(frozen=True)
class RealtimeResult:
    """What :func:`enable_realtime` achieved.

    Attributes:
        fifo: SCHED_FIFO is in effect at ``priority``.
        memory_locked: ``mlockall(MCL_CURRENT | MCL_FUTURE)`` succeeded.
        cpus: the CPU set in effect after pinning (None: not requested or not supported).
        cpu_latency_us: the CPU wake-up latency held through ``/dev/cpu_dma_latency`` [us] (None:
            not requested or refused).
        warnings: one line per part that the system refused, with the reason and the fix.
    """

    fifo: bool = False
    memory_locked: bool = False
    cpus: tuple[int, ...] | None = None
    cpu_latency_us: int | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        """Everything asked for was granted."""
        return not self.warnings


def _libc() -> ctypes.CDLL | None:
    name = ctypes.util.find_library("c")
    try:
        return ctypes.CDLL(name, use_errno=True) if name else ctypes.CDLL(None, use_errno=True)
    except OSError:
        return None


def _set_fifo(priority: int, warnings: list[str]) -> bool:
    if not hasattr(os, "sched_setscheduler"):
        warnings.append(f"SCHED_FIFO not available on {sys.platform}; normal scheduling")
        return False
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError as exc:
        warnings.append(
            f"SCHED_FIFO priority {priority} refused ({exc.strerror}); run as root or grant "
            "CAP_SYS_NICE / an rtprio limit (ulimit -r); normal scheduling"
        )
        return False
    except OSError as exc:
        warnings.append(f"SCHED_FIFO priority {priority} failed ({exc.strerror}); normal scheduling")
        return False
    return True


def _lock_memory(warnings: list[str]) -> bool:
    libc = _libc()
    if libc is None or not hasattr(libc, "mlockall"):
        warnings.append("mlockall not available; memory may be paged out")
        return False
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        err = ctypes.get_errno()
        hint = " (raise ulimit -l or grant CAP_IPC_LOCK)" if err in (errno.EPERM, errno.ENOMEM) else ""
        warnings.append(f"mlockall failed: {os.strerror(err)}{hint}; memory may be paged out")
        return False
    return True


def _pin(cpus: Iterable[int], warnings: list[str]) -> tuple[int, ...] | None:
    want = set()
    for c in cpus:
        if isinstance(c, bool) or not isinstance(c, int) or c < 0:
            raise ConfigError(f"CPU numbers must be integers >= 0, got {c!r}")
        want.add(c)
    if not want:
        raise ConfigError("an empty CPU set was given to pin to")
    if not hasattr(os, "sched_setaffinity"):
        warnings.append(f"CPU pinning not available on {sys.platform}")
        return None
    allowed = os.sched_getaffinity(0)
    missing = sorted(want - allowed)
    if missing:
        warnings.append(f"CPU(s) {missing} not available to this process (allowed: {sorted(allowed)})")
    use = want & allowed
    if not use:
        return tuple(sorted(allowed))
    try:
        os.sched_setaffinity(0, use)
    except OSError as exc:
        warnings.append(f"CPU pinning to {sorted(use)} failed ({exc.strerror})")
    return tuple(sorted(os.sched_getaffinity(0)))


def enable_realtime(
    priority: int = 80,
    cpus: Iterable[int] | None = None,
    lock_memory: bool = True,
    cpu_latency_us: int | None = None,
) -> RealtimeResult:
    """Ask for SCHED_FIFO at ``priority`` (1..99), ``mlockall``, pinning to ``cpus`` and, with
    ``cpu_latency_us``, a bound on the CPUs' wake-up latency [us] (PM QoS: ``/dev/cpu_dma_latency``,
    held until the process ends, as ``cyclictest`` does; 0 keeps idle CPUs polling instead of
    halting, which on this project's VM cuts a step's cost after an idle period by about 2.5x:
    docs/service.md, "The hot path"; it applies to all CPUs and costs their idle power).

    Applies to the calling thread's process (SCHED_FIFO and affinity are per thread on Linux:
    call it from the loop's thread before starting other threads, which inherit it). What the
    system refuses is returned in ``warnings`` (never raised); invalid arguments raise
    :class:`~lde.errors.ConfigError`.
    """
    if isinstance(priority, bool) or not isinstance(priority, int) or not 1 <= priority <= 99:
        raise ConfigError(f"SCHED_FIFO priority must be an integer 1..99, got {priority!r}")
    warnings: list[str] = []
    pinned = _pin(cpus, warnings) if cpus is not None else None
    locked = _lock_memory(warnings) if lock_memory else False
    fifo = _set_fifo(priority, warnings)
    latency = _hold_cpu_latency(cpu_latency_us, warnings) if cpu_latency_us is not None else None
    return RealtimeResult(
        fifo=fifo, memory_locked=locked, cpus=pinned, cpu_latency_us=latency, warnings=warnings
    )


class _SchedAttr(ctypes.Structure):
    # struct sched_attr (include/uapi/linux/sched/types.h), SCHED_ATTR_SIZE_VER0
    _fields_ = [
        ("size", ctypes.c_uint32),
        ("policy", ctypes.c_uint32),
        ("flags", ctypes.c_uint64),
        ("nice", ctypes.c_int32),
        ("priority", ctypes.c_uint32),
        ("runtime", ctypes.c_uint64),
        ("deadline", ctypes.c_uint64),
        ("period", ctypes.c_uint64),
    ]


_SYS_SCHED_SETATTR = {"x86_64": 314, "aarch64": 274}
#: the kernel's bounds of a normal task's custom slice (kernel/sched/syscalls.c) [ns]
SLICE_MIN_NS, SLICE_MAX_NS = 100_000, 100_000_000


def request_slice(slice_ns: int) -> str | None:
    """Ask the normal scheduler (Linux >= 6.12, EEVDF) for a time slice of ``slice_ns`` [ns] for the
    calling thread: a short slice gives the thread an early virtual deadline, so when it wakes up
    (a frame arrived) it preempts the task running on its CPU instead of waiting for that task's
    slice to end. Needs no privilege. Returns None when the call succeeded (a kernel before 6.12
    takes it and keeps its own slice), else why not (never raises for what the system refuses)."""
    if not SLICE_MIN_NS <= int(slice_ns) <= SLICE_MAX_NS:
        raise ConfigError(f"slice must be {SLICE_MIN_NS}..{SLICE_MAX_NS} ns, got {slice_ns}")
    nr = _SYS_SCHED_SETATTR.get(os.uname().machine) if hasattr(os, "uname") else None
    libc = _libc()
    if nr is None or libc is None or sys.platform != "linux":
        return f"sched_setattr not available on {sys.platform}"
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        return "not on the normal scheduler"
    attr = _SchedAttr(ctypes.sizeof(_SchedAttr), os.SCHED_OTHER, 0, os.getpriority(os.PRIO_PROCESS, 0))
    attr.runtime = int(slice_ns)
    if libc.syscall(nr, 0, ctypes.byref(attr), 0) != 0:
        return f"sched_setattr refused: {os.strerror(ctypes.get_errno())}"
    return None


_QOS_PATH = "/dev/cpu_dma_latency"
_qos_fd: int | None = None  # held open: the kernel drops the request when it is closed


def _hold_cpu_latency(us: int, warnings: list[str]) -> int | None:
    global _qos_fd
    if isinstance(us, bool) or not isinstance(us, int) or us < 0:
        raise ConfigError(f"CPU latency bound must be an integer >= 0 us, got {us!r}")
    try:
        fd = os.open(_QOS_PATH, os.O_WRONLY)
    except OSError as exc:
        warnings.append(
            f"CPU wake-up latency bound not set ({_QOS_PATH}: {exc.strerror}); idle CPUs may halt"
        )
        return None
    try:
        os.write(fd, int(us).to_bytes(4, sys.byteorder, signed=True))
    except OSError as exc:
        os.close(fd)
        warnings.append(
            f"CPU wake-up latency bound not set ({_QOS_PATH}: {exc.strerror}); idle CPUs may halt"
        )
        return None
    if _qos_fd is not None:
        os.close(_qos_fd)
    _qos_fd = fd
    return int(us)
