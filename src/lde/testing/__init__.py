"""lde as a test bench for your own code: the simulator and the lde service on one CAN bus, one
simulated clock, and pytest fixtures for them.

The pytest plugin (:mod:`lde.testing.plugin`, installed with lde as the ``pytest11`` entry point
``lde``) gives the fixtures ``lde_bench``, ``lde_bus``, ``lde_sim`` and ``lde_service``; nothing
happens in a test that does not ask for one. Without pytest, use :class:`Bench` directly::

    with Bench() as bench:
        sim = bench.simulator("wind_step", seed=1)
        bench.service(backend="float")
        bench.run(10.0)
        assert_periodic(bench.frames("LDE_Overlay"))

Public API: :class:`Bench` (the bus, the clock, the scheduler; ``simulator``, ``service``,
``feeder``, ``bus``, ``every``, ``at``, ``on_frame``, ``run``, ``run_until``, ``wait_for``,
``frames``), :class:`BenchBus`, :class:`BenchSimulator`, :class:`BenchService`,
:class:`InputFeeder`, :class:`TruthTable`, :class:`Frame`, :class:`FrameList`, :class:`Rank`,
:func:`assert_periodic`, :func:`assert_e2e_valid`, :func:`assert_in_range`,
:func:`socketcan_unavailable`, the errors :class:`BenchTimeout` and :class:`LeakedBus`.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from lde.testing.asserts import STEP_S, assert_e2e_valid, assert_in_range, assert_periodic
    from lde.testing.bench import Bench, BenchTimeout, LeakedBus
    from lde.testing.bus import BenchBus
    from lde.testing.capture import Frame, FrameList
    from lde.testing.participants import BenchService, BenchSimulator, InputFeeder, TruthTable
    from lde.testing.scheduler import Rank, Task
    from lde.testing.socketcan import socketcan_unavailable

# Lazy exports (PEP 562): pytest imports this package's plugin in every project of an environment
# where lde is installed, so importing it must not import python-can, numba or the estimator.
_EXPORTS = {
    "Bench": "bench",
    "BenchTimeout": "bench",
    "LeakedBus": "bench",
    "BenchBus": "bus",
    "Frame": "capture",
    "FrameList": "capture",
    "BenchService": "participants",
    "BenchSimulator": "participants",
    "InputFeeder": "participants",
    "TruthTable": "participants",
    "Rank": "scheduler",
    "Task": "scheduler",
    "STEP_S": "asserts",
    "assert_e2e_valid": "asserts",
    "assert_in_range": "asserts",
    "assert_periodic": "asserts",
    "socketcan_unavailable": "socketcan",
}

__all__ = [
    "STEP_S",
    "Bench",
    "BenchBus",
    "BenchService",
    "BenchSimulator",
    "BenchTimeout",
    "Frame",
    "FrameList",
    "InputFeeder",
    "LeakedBus",
    "Rank",
    "Task",
    "TruthTable",
    "assert_e2e_valid",
    "assert_in_range",
    "assert_periodic",
    "socketcan_unavailable",
]


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
