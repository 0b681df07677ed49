"""The README's "Test your code against lde" example: under 20 lines, and it passes."""

from __future__ import annotations

import pytest
from numba.core.registry import cpu_target

import lde.testing.bench  # noqa: F401  (before pytester's inline run: it restores sys.modules)

from helpers import TESTS

# numba imports its extra registries (numpy polynomials, ...) at its first compile or cache load.
# Done inside pytester's inline run, those modules leave sys.modules afterwards while their
# registrations stay, and the next test's first kernel load fails ("duplicate registration").
cpu_target.target_context.refresh()

ROOT = TESTS.parent


def _readme_test() -> str:
    section = (ROOT / "README.md").read_text(encoding="utf-8").split("## Test your code against lde", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


def test_the_readme_example_is_short_and_passes(pytester: pytest.Pytester) -> None:
    code = _readme_test()
    assert len(code.strip().splitlines()) < 20
    assert "from my_ecu import HoldAssist" in code
    # "your code": the controller of examples/test_my_controller.py, as module my_ecu
    pytester.makepyfile(my_ecu=(ROOT / "examples" / "test_my_controller.py").read_text(encoding="utf-8"))
    pytester.makepyfile(test_readme=code)
    pytester.runpytest("-p", "lde.testing.plugin").assert_outcomes(passed=1)
