"""Wall-clock bounds for the ``vcan`` tests inside user-mode Linux (see tests/uml/conftest.py)."""

from __future__ import annotations

import os
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

_T0 = time.monotonic()  # the session's start (imported by conftest before collection)


def python_loop(n: int = 300_000) -> float:
    """Seconds this process takes for a fixed pure-Python loop (the host/guest speed probe)."""
    t0 = time.perf_counter()
    acc = 0
    for i in range(n):
        acc += i * i % 7
    return time.perf_counter() - t0


def syscall_us(n: int = 2000) -> float:
    """Microseconds per system call (``os.getppid``): what user-mode Linux makes slow (every call is
    trapped and emulated), unlike plain Python code."""
    t0 = time.perf_counter()
    for _ in range(n):
        os.getppid()
    return (time.perf_counter() - t0) / n * 1e6


@dataclass(frozen=True)
class Budget:
    """The wall-clock budget of the run inside the guest [s]."""

    total_s: float

    def used(self) -> float:
        return time.monotonic() - _T0

    def left(self) -> float:
        return self.total_s - self.used()

    def bound(self, want_s: float, reserve_s: float = 30.0) -> float:
        """``want_s``, or less when the budget (minus ``reserve_s`` for what follows) has less left."""
        return max(1.0, min(want_s, self.left() - reserve_s))

    def require(self, need_s: float, what: str, speed: str = "") -> None:
        """Skip (with the figures) unless ``need_s`` seconds are left for ``what``."""
        if self.left() < need_s:
            pytest.skip(
                f"{what}: the guest's budget of {self.total_s:.0f} s has {self.left():.0f} s left after"
                f" {self.used():.0f} s of earlier tests (needs {need_s:.0f} s){speed}"
            )


def stop_process(proc: subprocess.Popen, grace_s: float = 30.0) -> str:
    """SIGTERM, then SIGKILL after ``grace_s``: '' when it ended on SIGTERM, else what was done."""
    if proc.poll() is not None:
        return ""
    proc.terminate()
    try:
        proc.wait(timeout=grace_s)
        return ""
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(timeout=grace_s)
        return f"did not end {grace_s:.0f} s after SIGTERM: killed"


def run_bounded(cmd: list[str], out: Path, timeout_s: float) -> tuple[int | None, float, str]:
    """Run ``cmd`` with stdout and stderr to the file ``out`` (never a pipe: a real-time child must
    not wait for this process to read), killed after ``timeout_s``. (exit code or None when it was
    killed, wall seconds, its output)."""
    t0 = time.monotonic()
    with out.open("w") as fh:
        proc = subprocess.Popen(cmd, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        try:
            rc: int | None = proc.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=60)
            rc = None
    return rc, time.monotonic() - t0, out.read_text(errors="replace")
