"""Shared pytest setup.

* lde's own pytest plugin (:mod:`lde.testing.plugin`: the fixtures ``lde_bench``, ``lde_bus``,
  ``lde_sim``, ``lde_service``) is what these tests use for buses, the simulator and the service on a
  simulated clock. pytest loads it through lde's ``pytest11`` entry point, which is named after the
  module so that naming it here as well is harmless (an editable install made before the entry point
  existed lacks it).
* The suite keeps numba's kernels where the ``lde`` command keeps them (:mod:`lde.cli.kernels`), so
  that the ``lde`` processes it starts load what the tests compiled and the other way round.
* Tests marked ``vcan`` need a real SocketCAN ``vcan0``. They run only where one exists (inside
  user-mode Linux: ``tests/test_uml.py`` drives them through ``tests/uml/run_in_uml.sh``);
  elsewhere they are skipped with the reason shown (``-ra`` is in the pytest options).
"""

from __future__ import annotations

import pytest

from lde.cli.kernels import use_kernel_cache
from lde.testing.socketcan import socketcan_unavailable

# the suite's kernels in the directory where the `lde` commands it starts look for theirs (as the
# `lde` command does it: before numba is imported), so that they are compiled once
use_kernel_cache()

pytest_plugins = ["lde.testing.plugin", "pytester"]

VCAN = "vcan0"
#: tests/test_uml.py looks for this phrase to tell a missing vcan0 from a test's own skip
UML_HINT = "the vcan tests run inside user-mode Linux via tests/test_uml.py"


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    vcan_items = [it for it in items if it.get_closest_marker("vcan") is not None]
    if not vcan_items:
        return
    reason = socketcan_unavailable(VCAN, hint=UML_HINT)
    if reason is None:
        return
    skip = pytest.mark.skip(reason=reason)
    for it in vcan_items:
        it.add_marker(skip)
