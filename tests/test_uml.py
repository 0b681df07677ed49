"""Run the ``vcan``-marked tests inside user-mode Linux, where a real SocketCAN vcan0 exists.

The host kernel has no AF_CAN; ``tests/uml/run_in_uml.sh`` boots Debian's UML kernel on the host's
root, loads the CAN modules, creates vcan0 and runs pytest there. When UML cannot run on this
machine the test is skipped with the runner's reason (visible in pytest's ``-ra`` summary); when
UML runs, the vcan tests must pass and must not be skipped.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parent
ROOT = TESTS.parent
RUNNER = TESTS / "uml" / "run_in_uml.sh"
EXIT_SKIP = 77
#: the phrase of tests/conftest.py's skip reason when no real vcan0 exists
VCAN_SKIP_PHRASE = "run inside user-mode Linux via tests/test_uml.py"
_VCAN_MARK = re.compile(r"pytest\.mark\.vcan|mark\s*=\s*pytest\.mark\.vcan")


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
        r = subprocess.run(["bash", str(RUNNER), "--probe"], capture_output=True, text=True, timeout=300)
    except subprocess.TimeoutExpired:
        pytest.fail("user-mode Linux probe boot took more than 300 s")
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


def test_vcan_tests_pass_inside_uml(uml):
    files = vcan_test_files()
    assert files, "no vcan-marked tests found"
    cmd = [
        "bash",
        str(RUNNER),
        "--timeout",
        "900",
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
    r = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1000)
    print(r.stdout)
    print(r.stderr, file=sys.stderr)
    if r.returncode == EXIT_SKIP:
        pytest.skip(f"user-mode Linux cannot run here: {_skip_reason(r.stderr)}")
    assert r.returncode == 0, f"vcan tests inside UML failed (exit {r.returncode})"
    summary = r.stdout.strip().splitlines()[-1] if r.stdout.strip() else ""
    assert re.search(r"\d+ passed", summary), summary
    # inside UML vcan0 exists: a skip for a missing vcan0 means the setup is broken; a test's own
    # skip (e.g. "UML too slow here") is allowed but shown as a warning on the host
    skips = [ln for ln in r.stdout.splitlines() if ln.startswith("SKIPPED")]
    assert not [ln for ln in skips if VCAN_SKIP_PHRASE in ln], f"vcan0 missing inside UML: {skips}"
    for ln in skips:
        warnings.warn(f"inside user-mode Linux: {ln}", UserWarning, stacklevel=1)
