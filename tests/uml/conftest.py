"""Bounds for the ``vcan`` tests inside user-mode Linux (docs/guide/bus.md, "User-mode Linux").

Every subprocess of these tests has a wall-clock bound taken from one budget for the whole run in
the guest: ``LDE_UML_BUDGET_S`` seconds from the start of this pytest session (``tests/test_uml.py``
sets it a margin below the runner's own timeout; 1200 when unset). A guest too slow to finish a test
within its bound, or to keep the real-time pace a timing judgement needs, makes that test skip
with what was measured; the correctness checks (E2E, counters, overlay limits, replay equal to live)
run on whatever was recorded.

``guest_speed`` measures how much slower than the host this guest runs a fixed piece of Python and a
system call (``LDE_UML_HOST_SPEED``: the host's figures, measured by ``tests/test_uml.py``), so that
skip reasons can say how slow the guest was.
"""

from __future__ import annotations

import os

import pytest
from uml_bounds import Budget, python_loop, syscall_us

BUDGET_ENV = "LDE_UML_BUDGET_S"
HOST_SPEED_ENV = "LDE_UML_HOST_SPEED"  # "python_loop seconds,syscall_us" on the host
DEFAULT_BUDGET_S = 1200.0


@pytest.fixture(scope="session")
def budget() -> Budget:
    raw = os.environ.get(BUDGET_ENV, "")
    try:
        total = float(raw) if raw else DEFAULT_BUDGET_S
    except ValueError:
        raise pytest.UsageError(f"{BUDGET_ENV}={raw!r}: need seconds") from None
    return Budget(total)


@pytest.fixture(scope="session")
def guest_speed() -> str:
    """'; guest: a Python loop N x the host's time, a system call X us (host Y us)' for skip reasons."""
    loop = min(python_loop() for _ in range(3))
    sys_us = min(syscall_us() for _ in range(3))
    host = _host_figures()
    if host is None:
        return f"; guest: a Python loop {loop:.3f} s, a system call {sys_us:.1f} us"
    h_loop, h_sys = host
    return (
        f"; guest: a Python loop {loop / h_loop:.1f}x the host's time ({loop:.3f} s), a system call"
        f" {sys_us:.1f} us ({sys_us / h_sys:.0f}x the host's {h_sys:.2f} us)"
    )


def _host_figures() -> tuple[float, float] | None:
    """(python_loop seconds, syscall_us) measured on the host by tests/test_uml.py, if given."""
    try:
        loop, sys_us = (float(x) for x in os.environ.get(HOST_SPEED_ENV, "").split(","))
    except ValueError:
        return None
    return (loop, sys_us) if loop > 0 and sys_us > 0 else None
