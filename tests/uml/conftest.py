"""Bounds for the ``vcan`` tests inside user-mode Linux (docs/overlay.md, "UML notes").

Every subprocess of these tests has a wall-clock bound taken from one budget for the whole run in
the guest: ``LDE_UML_BUDGET_S`` seconds from the start of this pytest session (``tests/test_uml.py``
sets it a margin below the runner's own timeout; 1200 when unset). A guest too slow to finish a test
within its bound, or to keep the real-time pace a timing judgement needs, makes that test skip
with what was measured; the correctness checks (E2E, counters, overlay limits, replay equal to live)
run on whatever was recorded.

``guest_speed`` measures how much slower than the host this guest runs a fixed piece of Python
(``LDE_UML_HOST_LOOP_S``: the host's time for :func:`python_loop`, measured by ``tests/test_uml.py``),
so that skip reasons can say how slow the guest was.
"""

from __future__ import annotations

import os

import pytest
from uml_bounds import Budget, python_loop

BUDGET_ENV = "LDE_UML_BUDGET_S"
HOST_LOOP_ENV = "LDE_UML_HOST_LOOP_S"
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
    """'; guest N x slower than the host at Python' (or the guest's loop time when no host figure)."""
    guest = min(python_loop() for _ in range(3))
    raw = os.environ.get(HOST_LOOP_ENV, "")
    try:
        host = float(raw) if raw else 0.0
    except ValueError:
        host = 0.0
    if host > 0:
        ratio = guest / host
        return f"; guest {ratio:.1f}x slower than the host at a Python loop ({guest:.3f} s vs {host:.3f} s)"
    return f"; a Python loop takes {guest:.3f} s in the guest"
