"""The pytest plugin of lde: fixtures for testing your code against the simulator and the lde service.

Installed with lde (entry point ``pytest11``: ``lde = "lde.testing.plugin"``); opt-in per test: a test
that asks for none of these fixtures is not touched (this module imports nothing heavy until then).

Fixtures (function scope; each test gets a fresh bus):

``lde_bench``
    a :class:`lde.testing.Bench`: a fresh python-can virtual channel (unique per test), a simulated
    clock and its scheduler; closed after the test, and the test errors if a bus on its channel was
    left open (python-can's own leak check, for this channel).
``lde_bus``
    a bus on that bench for the test's own code (``can.BusABC``; frames stamped with bench time).
``lde_sim``
    the vehicle simulator on the bench (default ``heavy_load``, seed 0, closed loop on ``LDE_Overlay``).
``lde_service``
    the lde service on the bench (default backend ``fixed``), its step results captured.

Markers configure them with the keyword arguments of the matching :class:`~lde.testing.Bench` method:
``@pytest.mark.lde_bench(profile=..., vehicle=..., interface=..., channel=...)``,
``@pytest.mark.lde_sim(scenario=..., seed=..., duration=..., vehicle=..., overlay=...)``,
``@pytest.mark.lde_service(backend=..., vehicle=..., overlay=..., drop=..., record=...)``.

Options: ``--lde-interface socketcan --lde-channel vcan0`` runs every bench of the session on a real
SocketCAN interface (a test's ``lde_bench`` marker wins); where the kernel has no CAN those tests are
skipped with the reason.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from lde.testing.bench import Bench
    from lde.testing.bus import BenchBus
    from lde.testing.participants import BenchService, BenchSimulator

__all__ = [
    "pytest_addoption",
    "pytest_configure",
    "lde_bench",
    "lde_bus",
    "lde_sim",
    "lde_service",
    "SOCKETCAN_HINT",
]

#: what a skip on a machine without SocketCAN suggests
SOCKETCAN_HINT = (
    "run where the kernel has CAN (`ip link add dev vcan0 type vcan && ip link set up vcan0`) "
    "or inside user-mode Linux (lde's tests/uml/run_in_uml.sh)"
)

_MARKERS = (
    "lde_bench(**kwargs): keyword arguments of lde.testing.Bench for the lde_bench fixture "
    "(interface, channel, profile, vehicle, start_ns, capture)",
    "lde_sim(**kwargs): keyword arguments of Bench.simulator for the lde_sim fixture "
    "(scenario, seed, duration, vehicle, overlay, speed_kmh)",
    "lde_service(**kwargs): keyword arguments of Bench.service for the lde_service fixture "
    "(backend, vehicle, overlay, drop, phase_s, record)",
)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("lde", "lde test bench (fixtures lde_bench, lde_bus, lde_sim, lde_service)")
    group.addoption(
        "--lde-interface",
        choices=("virtual", "socketcan"),
        default=None,
        help="python-can interface of every lde bench (default: virtual, a fresh channel per test)",
    )
    group.addoption(
        "--lde-channel",
        default=None,
        help="channel of every lde bench (socketcan default: vcan0)",
    )


def pytest_configure(config: pytest.Config) -> None:
    for line in _MARKERS:
        config.addinivalue_line("markers", line)


def _marker_kwargs(request: pytest.FixtureRequest, name: str) -> dict[str, Any]:
    mark = request.node.get_closest_marker(name)
    if mark is None:
        return {}
    if mark.args:
        raise pytest.UsageError(f"@pytest.mark.{name} takes keyword arguments only, got {mark.args!r}")
    return dict(mark.kwargs)


@pytest.fixture
def lde_bench(request: pytest.FixtureRequest) -> Iterator[Bench]:
    """A :class:`lde.testing.Bench` on a fresh channel; closed and leak-checked after the test."""
    from lde.testing.bench import Bench
    from lde.testing.socketcan import socketcan_unavailable

    kw = _marker_kwargs(request, "lde_bench")
    interface = kw.pop("interface", None) or request.config.getoption("lde_interface") or "virtual"
    channel = kw.pop("channel", None) or request.config.getoption("lde_channel")
    if interface == "socketcan":
        channel = channel or "vcan0"
        reason = socketcan_unavailable(channel, hint=SOCKETCAN_HINT)
        if reason is not None:
            pytest.skip(f"lde bench on socketcan {channel}: {reason}")
    bench = Bench(interface=interface, channel=channel, label=request.node.name, **kw)
    yield bench
    bench.close()


@pytest.fixture
def lde_bus(lde_bench: Bench) -> BenchBus:
    """A bus on the test's bench for the test's own code (closed with the bench)."""
    return lde_bench.bus("test")


@pytest.fixture
def lde_sim(lde_bench: Bench, request: pytest.FixtureRequest) -> BenchSimulator:
    """The vehicle simulator on the test's bench (``@pytest.mark.lde_sim(...)`` configures it)."""
    return lde_bench.simulator(**_marker_kwargs(request, "lde_sim"))


@pytest.fixture
def lde_service(lde_bench: Bench, request: pytest.FixtureRequest) -> BenchService:
    """The lde service on the test's bench (``@pytest.mark.lde_service(...)`` configures it)."""
    return lde_bench.service(**_marker_kwargs(request, "lde_service"))
