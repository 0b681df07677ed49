"""Run the ``vcan``-marked tests inside user-mode Linux, where a real SocketCAN vcan0 exists.

The host kernel has no AF_CAN; ``tests/uml/run_in_uml.sh`` boots Debian's UML kernel on the host's
root, loads the CAN modules, creates vcan0 and runs pytest there. When UML cannot run on this
machine the test is skipped with the runner's reason (visible in pytest's ``-ra`` summary); when
UML runs, the vcan tests must not fail; their own skips (a guest too slow to judge timing, with what
was measured) make ``test_no_vcan_test_skipped_inside_uml`` skip with their reasons.

Bounds: the tests inside the guest share a budget of ``GUEST_BUDGET_S`` (``LDE_UML_BUDGET_S``,
tests/uml/conftest.py) and bound every subprocess by it; the runner's timeout lies above that budget
and this test's own above the runner's. ``LDE_UML_HOG=N`` in the environment starts N busy loops in
the guest (a slow guest on purpose, tests/uml/run_in_uml.sh).
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
RUNNER = TESTS / "uml" / "run_in_uml.sh"
EXIT_SKIP = 77
EXIT_TIMEOUT = 124
#: the phrase of tests/conftest.py's skip reason when no real vcan0 exists
VCAN_SKIP_PHRASE = "run inside user-mode Linux via tests/test_uml.py"
_VCAN_MARK = re.compile(r"pytest\.mark\.vcan|mark\s*=\s*pytest\.mark\.vcan")
PROBE_S = 300  #: bound of the probe boot [s]
GUEST_BUDGET_S = 1200  #: the vcan tests inside the guest, all together [s]
RUNNER_S = GUEST_BUDGET_S + 300  #: the runner's timeout: boot, pytest's start-up, the last bound's reserve


def _skip_reason(stderr: str) -> str:
    for line in stderr.splitlines():
        if "SKIP:" in line:
            return line.split("SKIP:", 1)[1].strip()
    return stderr.strip()[-300:] or "user-mode Linux cannot run here"


@pytest.fixture(scope="module")
def uml() -> None:
    if os.environ.get("LDE_IN_UML"):
        pytest.skip("already inside user-mode Linux")
    try:
        r = subprocess.run(["bash", str(RUNNER), "--probe"], capture_output=True, text=True, timeout=PROBE_S)
    except subprocess.TimeoutExpired:
        pytest.skip(f"user-mode Linux did not boot and run `true` in {PROBE_S} s (host too slow or busy)")
    if r.returncode == EXIT_SKIP:
        pytest.skip(f"user-mode Linux cannot run here: {_skip_reason(r.stderr)}")
    assert r.returncode == 0, f"user-mode Linux probe failed (exit {r.returncode}):\n{r.stdout}\n{r.stderr}"


def vcan_test_files() -> list[Path]:
    """Test files that use the ``vcan`` marker (only those are collected inside UML: faster)."""
    out = []
    for p in sorted(TESTS.rglob("test_*.py")):
        if p.name == Path(__file__).name:
            continue
        if _VCAN_MARK.search(p.read_text(encoding="utf-8", errors="replace")):
            out.append(p)
    return out


def _host_speed() -> str:
    """The host's figures for the guest's speed probe (tests/uml/uml_bounds.py), "loop_s,syscall_us"."""
    spec = importlib.util.spec_from_file_location("uml_bounds", TESTS / "uml" / "uml_bounds.py")
    assert spec is not None and spec.loader is not None
    mod = sys.modules.get("uml_bounds") or importlib.util.module_from_spec(spec)
    if "uml_bounds" not in sys.modules:
        sys.modules["uml_bounds"] = mod  # its dataclass needs the module registered
        spec.loader.exec_module(mod)
    loop = min(mod.python_loop() for _ in range(3))
    sys_us = min(mod.syscall_us() for _ in range(3))
    return f"{loop:.5f},{sys_us:.4f}"


@dataclass
class GuestRun:
    """The vcan tests' run inside user-mode Linux: exit code, output, wall time [s]."""

    rc: int
    stdout: str
    stderr: str
    wall_s: float

    def skipped(self) -> list[str]:
        return [ln for ln in self.stdout.splitlines() if ln.startswith("SKIPPED")]


@pytest.fixture(scope="module")
def guest_run(uml) -> GuestRun:
    """One boot: every vcan-marked test file inside UML, bounded (see the module docstring)."""
    files = vcan_test_files()
    assert files, "no vcan-marked tests found"
    env = {
        **os.environ,
        "LDE_UML_BUDGET_S": str(GUEST_BUDGET_S),
        "LDE_UML_HOST_SPEED": _host_speed(),
    }
    cmd = [
        "bash",
        str(RUNNER),
        "--timeout",
        str(RUNNER_S),
        sys.executable,
        "-m",
        "pytest",
        "-q",
        "-s",
        "-rs",
        "-p",
        "no:cacheprovider",
        "-m",
        "vcan",
        *[str(f.relative_to(ROOT)) for f in files],
    ]
    t0 = time.monotonic()
    try:
        r = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, timeout=RUNNER_S + 60)
    except subprocess.TimeoutExpired as exc:  # the runner's own timeout should have ended it first
        out = exc.stdout.decode(errors="replace") if isinstance(exc.stdout, bytes) else (exc.stdout or "")
        pytest.skip(
            f"user-mode Linux did not end in {RUNNER_S + 60} s; its output so far ends: {out[-500:]!r}"
        )
    run = GuestRun(r.returncode, r.stdout, r.stderr, time.monotonic() - t0)
    print(r.stdout)
    print(r.stderr, file=sys.stderr)
    if r.returncode == EXIT_SKIP:
        pytest.skip(f"user-mode Linux cannot run here: {_skip_reason(r.stderr)}")
    if r.returncode == EXIT_TIMEOUT:
        # every test inside has its own bound from the budget: only a guest far too slow for pytest
        # itself gets here
        tail = " | ".join(r.stdout.strip().splitlines()[-3:])
        pytest.skip(
            f"the vcan tests inside user-mode Linux did not end in the runner's {RUNNER_S} s"
            f" (guest budget {GUEST_BUDGET_S} s, {run.wall_s:.0f} s in all): {tail[-400:]}"
        )
    return run


def test_vcan_tests_pass_inside_uml(guest_run: GuestRun) -> None:
    """No failure and no error inside the guest; passes there (skips are the next test's)."""
    r = guest_run
    assert r.rc == 0, f"vcan tests inside UML failed (exit {r.rc})"
    summary = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
    assert re.search(r"\d+ (passed|skipped)", summary), summary
    assert not re.search(r"\d+ (failed|error)", summary), summary
    # inside UML vcan0 exists: a skip for a missing vcan0 means the setup is broken
    assert not [ln for ln in r.skipped() if VCAN_SKIP_PHRASE in ln], (
        f"vcan0 missing inside UML: {r.skipped()}"
    )


def test_no_vcan_test_skipped_inside_uml(guest_run: GuestRun) -> None:
    """A test inside the guest that skipped (a guest too slow to judge timing: the reason carries
    what was measured) shows here as a skip with its reasons, and as a warning each."""
    skips = guest_run.skipped()
    for ln in skips:
        warnings.warn(f"inside user-mode Linux: {ln}", UserWarning, stacklevel=1)
    if skips:
        pytest.skip(
            f"{len(skips)} skip(s) inside user-mode Linux ({guest_run.wall_s:.0f} s): "
            + " || ".join(ln.removeprefix("SKIPPED ") for ln in skips)
        )
