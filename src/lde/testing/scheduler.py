"""One scheduler on one simulated clock: every participant of a bench acts at its own instants.

Simulated time moves only here. The scheduler keeps the pending actions in time order and, for each,
sets the clock to its instant and runs it; participants never move the clock themselves (the lde
service's :class:`~lde.clock.SimulatedClock` is this clock, read-only for it). At one instant the
actions run by rank, then by creation order:

1. :attr:`Rank.SOURCE` - the simulator (plant step, frames due at that instant), input feeders;
2. :attr:`Rank.USER` - the user's periodic code (default for :meth:`Scheduler.every`);
3. :attr:`Rank.SERVICE` - the lde service's step at ``t_k`` (it sees every frame stamped ``<= t_k``);
4. :attr:`Rank.LATE` - user code that must see the service's frames of the same instant.

After every action the bench's ``settle`` hook runs (frame handlers react at the same instant).
Nothing here reads the wall clock: the same actions give the same order, run after run.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from enum import IntEnum

from lde.clock import SimulatedClock
from lde.errors import ConfigError

__all__ = ["Rank", "Task", "Scheduler"]


class Rank(IntEnum):
    """Order of the actions due at the same instant (lower first)."""

    SOURCE = 0
    USER = 50
    SERVICE = 100
    LATE = 150


class Task:
    """``fn(t_ns)`` at ``next_ns`` and then every ``period_ns`` [ns] (0: once); :meth:`cancel` stops it."""

    __slots__ = ("fn", "next_ns", "period_ns", "rank", "name", "id", "active", "runs")

    def __init__(
        self, fn: Callable[[int], object], next_ns: int, period_ns: int, rank: int, name: str, id_: int
    ) -> None:
        self.fn = fn
        self.next_ns = int(next_ns)
        self.period_ns = int(period_ns)
        self.rank = int(rank)
        self.name = name
        self.id = id_
        self.active = True
        self.runs = 0

    def cancel(self) -> None:
        """No more runs (a run in progress completes)."""
        self.active = False

    def __repr__(self) -> str:
        return f"Task({self.name!r}, next_ns={self.next_ns}, period_ns={self.period_ns}, rank={self.rank})"


class Scheduler:
    """Pending actions in ``(time, rank, creation)`` order on a :class:`SimulatedClock`.

    Args:
        clock: the simulated clock (the scheduler is the only one that moves it).
        settle: called after every action (the bench dispatches frames to handlers there).
    """

    def __init__(self, clock: SimulatedClock, settle: Callable[[], None] | None = None) -> None:
        self.clock = clock
        self._settle = settle
        self._heap: list[tuple[int, int, int, Task]] = []
        self._ids = itertools.count()
        self.actions = 0  # actions run so far

    @property
    def now_ns(self) -> int:
        return self.clock.now_ns()

    def at(self, t_ns: int, fn: Callable[[int], object], rank: int = Rank.USER, name: str = "") -> Task:
        """Run ``fn(t_ns)`` once at ``t_ns`` (not before now)."""
        return self._add(Task(fn, t_ns, 0, rank, name, next(self._ids)))

    def every(
        self,
        period_ns: int,
        fn: Callable[[int], object],
        start_ns: int | None = None,
        rank: int = Rank.USER,
        name: str = "",
    ) -> Task:
        """Run ``fn(t)`` at ``start_ns`` (default now) and every ``period_ns`` after it."""
        if int(period_ns) <= 0:
            raise ConfigError(f"period must be > 0 ns, got {period_ns}")
        t0 = self.now_ns if start_ns is None else int(start_ns)
        return self._add(Task(fn, t0, int(period_ns), rank, name, next(self._ids)))

    def _add(self, task: Task) -> Task:
        if task.next_ns < self.now_ns:
            raise ConfigError(
                f"task {task.name or task.fn!r}: cannot start at {task.next_ns} ns, "
                f"before now ({self.now_ns} ns)"
            )
        heapq.heappush(self._heap, (task.next_ns, task.rank, task.id, task))
        return task

    def next_ns(self) -> int | None:
        """Time of the next pending action, or None."""
        while self._heap and not self._heap[0][3].active:
            heapq.heappop(self._heap)
        return self._heap[0][0] if self._heap else None

    def run(
        self, end_ns: int | None = None, stop: Callable[[], bool] | None = None, *, inclusive: bool = False
    ) -> bool:
        """Run the actions due before ``end_ns`` (at or before it with ``inclusive``), then set the
        clock to ``end_ns``.

        ``stop()`` is asked after each instant (once every action due at it has run); True ends the
        run at that instant and is returned. With neither ``end_ns`` nor ``stop`` the run ends when
        nothing is pending (never, while a periodic task is active).
        """
        heap = self._heap
        clock = self.clock
        settle = self._settle
        while heap:
            t, _, _, task = heap[0]
            if end_ns is not None and (t > end_ns if inclusive else t >= end_ns):
                break
            heapq.heappop(heap)
            if not task.active:
                continue
            clock.sleep_until(t)
            task.runs += 1
            self.actions += 1
            if task.period_ns:
                task.next_ns = t + task.period_ns
                heapq.heappush(heap, (task.next_ns, task.rank, task.id, task))
            else:
                task.active = False
            task.fn(t)
            if settle is not None:
                settle()
            if stop is not None:
                nxt = self.next_ns()
                if (nxt is None or nxt > t) and stop():
                    return True
        if end_ns is not None:
            clock.sleep_until(end_ns)
        return stop() if stop is not None else False
