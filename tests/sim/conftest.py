"""Shared simulator runs (module scope: each scenario is simulated once per test session)."""

from __future__ import annotations

import pytest

from lde.params import load_vehicle
from vcan_sim.config import sim_params_from_vehicle
from vcan_sim.run import SimResult, simulate

_CACHE: dict[tuple, SimResult] = {}


def run_cached(
    scenario: str, seed: int = 0, duration: float | None = None, profile: str = "lde"
) -> SimResult:
    key = (scenario, seed, duration, profile)
    if key not in _CACHE:
        _CACHE[key] = simulate(scenario, seed=seed, duration=duration, profile=profile)
    return _CACHE[key]


@pytest.fixture(scope="session")
def vehicle():
    return load_vehicle()


@pytest.fixture(scope="session")
def sim_params(vehicle):
    return sim_params_from_vehicle(vehicle)


@pytest.fixture(scope="session")
def heavy():
    return run_cached("heavy_load", seed=0)


@pytest.fixture(scope="session")
def light():
    return run_cached("light_load", seed=0)


@pytest.fixture(scope="session")
def sim_run():
    """``sim_run(name, seed=0, duration=None, profile="lde")`` -> cached :class:`SimResult`."""
    return run_cached
