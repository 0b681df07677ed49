"""lde.clock: clocks, absolute deadlines, real-time helpers (no timing assertions: correctness only)."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from lde import clock as clock_mod
from lde.clock import (
    Clock,
    MonotonicClock,
    RealtimeResult,
    SimulatedClock,
    Ticker,
    enable_realtime,
)
from lde.errors import ConfigError
from lde.units import STEP_NS

T0 = 1_700_000_000_000_000_000


def test_both_clocks_satisfy_the_protocol():
    assert isinstance(MonotonicClock(), Clock)
    assert isinstance(SimulatedClock(), Clock)


def test_simulated_clock_moves_only_when_told():
    c = SimulatedClock(T0)
    assert c.now_ns() == T0
    assert c.now_ns() == T0
    c.sleep_until(T0 + 5)
    assert c.now_ns() == T0 + 5
    c.sleep_until(T0)  # the past: no change, never backwards
    assert c.now_ns() == T0 + 5
    assert c.advance(10) == T0 + 15
    c.set(T0 + 100)
    assert c.now_ns() == T0 + 100
    with pytest.raises(ConfigError):
        c.advance(-1)
    with pytest.raises(ConfigError):
        c.set(T0)


def test_monotonic_clock_never_returns_before_the_deadline():
    c = MonotonicClock()
    for wait_ns in (0, 50_000, 300_000, 2_000_000, -1_000_000):
        t = c.now_ns() + wait_ns
        c.sleep_until(t)
        assert c.now_ns() >= t
    pure_sleep = MonotonicClock(spin_ns=0)
    t = pure_sleep.now_ns() + 1_000_000
    pure_sleep.sleep_until(t)
    assert pure_sleep.now_ns() >= t
    with pytest.raises(ConfigError):
        MonotonicClock(spin_ns=-1)


def test_ticker_deadlines_are_absolute():
    c = SimulatedClock(T0)
    tk = Ticker(c, STEP_NS)
    ticks = [tk.wait() for _ in range(1000)]
    assert [t.t_ns for t in ticks] == [T0 + (k + 1) * STEP_NS for k in range(1000)]
    assert all(t.late_ns == 0 and t.skipped == 0 for t in ticks)


class _OversleepingClock(SimulatedClock):
    """Wakes up late by a random amount below one period (like a loaded host)."""

    def __init__(self, start_ns: int, seed: int) -> None:
        super().__init__(start_ns)
        self.rng = np.random.default_rng(seed)

    def sleep_until(self, t_ns: int) -> None:
        super().sleep_until(t_ns + int(self.rng.integers(0, STEP_NS // 2)))


def test_ticker_does_not_drift_with_late_wakeups():
    c = _OversleepingClock(T0, seed=3)
    tk = Ticker(c, STEP_NS, t0_ns=T0)
    ticks = [tk.wait() for _ in range(5000)]
    assert ticks[-1].t_ns == T0 + 4999 * STEP_NS  # lateness never accumulates
    assert all(0 <= t.late_ns < STEP_NS for t in ticks)
    assert sum(t.skipped for t in ticks) == 0


def test_ticker_skips_missed_deadlines():
    c = SimulatedClock(T0)
    tk = Ticker(c, STEP_NS, t0_ns=T0)
    assert tk.wait().k == 0
    c.advance(int(3.5 * STEP_NS))  # the step took 3.5 periods
    t = tk.wait()
    assert t.skipped == 2 and t.k == 3 and t.t_ns == T0 + 3 * STEP_NS
    assert t.late_ns == STEP_NS // 2
    assert tk.wait().t_ns == T0 + 4 * STEP_NS
    with pytest.raises(ConfigError):
        Ticker(c, 0)


# --- enable_realtime: argument checks and fallbacks in-process, the real calls in a subprocess ----


@pytest.mark.parametrize("prio", [0, 100, 1.5, True, "80"])
def test_enable_realtime_rejects_bad_priority(prio):
    with pytest.raises(ConfigError, match="priority"):
        enable_realtime(priority=prio, lock_memory=False)


@pytest.mark.parametrize("cpus", [[-1], ["0"], []])
def test_enable_realtime_rejects_bad_cpus(cpus):
    with pytest.raises(ConfigError):
        enable_realtime(priority=10, cpus=cpus, lock_memory=False)


def test_enable_realtime_falls_back_with_warnings(monkeypatch):
    def refuse(*a):
        raise PermissionError(1, "Operation not permitted")

    class FakeLibc:
        def mlockall(self, flags):
            return -1

    monkeypatch.setattr(clock_mod.os, "sched_setscheduler", refuse, raising=False)
    monkeypatch.setattr(clock_mod, "_libc", lambda: FakeLibc())
    monkeypatch.setattr(clock_mod.ctypes, "get_errno", lambda: 12)  # ENOMEM
    res = enable_realtime(priority=50, lock_memory=True)
    assert isinstance(res, RealtimeResult)
    assert not res.fifo and not res.memory_locked and not res.ok
    assert len(res.warnings) == 2
    assert any("SCHED_FIFO" in w and "CAP_SYS_NICE" in w for w in res.warnings)
    assert any("mlockall" in w and "ulimit -l" in w for w in res.warnings)


def test_cpu_latency_bound_is_written_and_held_open(monkeypatch, tmp_path):
    """``cpu_latency_us``: the 32-bit value goes to the PM QoS file, whose descriptor stays open (the
    kernel drops the request when it is closed); a file that cannot be opened is a warning."""
    qos = tmp_path / "cpu_dma_latency"
    qos.write_bytes(b"")
    monkeypatch.setattr(clock_mod, "_QOS_PATH", str(qos))
    monkeypatch.setattr(clock_mod, "_qos_fd", None)
    monkeypatch.setattr(clock_mod, "_set_fifo", lambda prio, warnings: True)
    res = enable_realtime(priority=10, lock_memory=False, cpu_latency_us=0)
    assert res.ok and res.cpu_latency_us == 0
    assert qos.read_bytes() == (0).to_bytes(4, sys.byteorder, signed=True)
    fd = clock_mod._qos_fd
    assert fd is not None and os.fstat(fd).st_ino == qos.stat().st_ino  # still open
    os.close(fd)
    monkeypatch.setattr(clock_mod, "_qos_fd", None)
    monkeypatch.setattr(clock_mod, "_QOS_PATH", str(tmp_path / "missing" / "cpu_dma_latency"))
    res = enable_realtime(priority=10, lock_memory=False, cpu_latency_us=0)
    assert res.cpu_latency_us is None and any("latency bound not set" in w for w in res.warnings)
    with pytest.raises(ConfigError, match="latency"):
        enable_realtime(priority=10, lock_memory=False, cpu_latency_us=-5)


@pytest.mark.skipif(not hasattr(os, "sched_getaffinity"), reason="Linux scheduling API needed")
def test_enable_realtime_unavailable_cpu_is_a_warning(monkeypatch):
    # never the real SCHED_FIFO call here: it made the test runner itself (and every process it
    # started after this test) SCHED_FIFO 10, whose busy CPUs starve the normal scheduler's tasks and
    # then the kernel's fair server stalls the real-time service on them for 50 ms
    monkeypatch.setattr(clock_mod, "_set_fifo", lambda prio, warnings: True)
    monkeypatch.setattr(clock_mod.os, "sched_setaffinity", lambda pid, cpus: None)
    res = enable_realtime(priority=10, cpus=[10_000], lock_memory=False)
    assert any("not available" in w for w in res.warnings)
    assert os.sched_getscheduler(0) != getattr(os, "SCHED_FIFO", -1)


_CHILD = """
import os, json
from lde.clock import enable_realtime
r = enable_realtime(priority=1, cpus=sorted(os.sched_getaffinity(0))[:1], lock_memory=True)
print(json.dumps({"fifo": r.fifo, "locked": r.memory_locked, "cpus": r.cpus, "warnings": r.warnings,
                  "policy": os.sched_getscheduler(0), "fifo_const": os.SCHED_FIFO,
                  "affinity": sorted(os.sched_getaffinity(0))}))
"""


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="Linux scheduling API needed")
def test_enable_realtime_in_a_child_process_reports_what_it_got():
    """Runs in a child (never make the test runner itself SCHED_FIFO)."""
    import json

    out = subprocess.run(
        [sys.executable, "-c", _CHILD], capture_output=True, text=True, timeout=120, check=True
    )
    r = json.loads(out.stdout.strip().splitlines()[-1])
    # what it says is what the kernel has
    assert r["fifo"] == (r["policy"] == r["fifo_const"])
    assert r["fifo"] or any("SCHED_FIFO" in w for w in r["warnings"])
    assert r["locked"] or any("mlockall" in w for w in r["warnings"])
    assert r["cpus"] == r["affinity"] and len(r["affinity"]) == 1


_SLICE_CHILD = """
import json, os
from lde.clock import request_slice
why = request_slice(200_000)
p = "/proc/self/sched"
lines = [ln for ln in open(p) if ln.startswith("se.slice")] if os.path.exists(p) else []
print(json.dumps({"why": why, "slice": int(lines[0].split(":")[1]) if lines else None}))
"""


def test_request_slice_rejects_slices_the_kernel_would_not_take():
    for ns in (0, 99_999, 100_000_001):
        with pytest.raises(ConfigError, match="slice"):
            clock_mod.request_slice(ns)


@pytest.mark.skipif(sys.platform != "linux", reason="Linux scheduling API needed")
def test_request_slice_in_a_child_process_sets_the_threads_slice():
    """In a child (the test runner keeps its own slice); where the kernel shows the slice (EEVDF,
    /proc/self/sched's se.slice), it is the one asked for."""
    import json

    out = subprocess.run(
        [sys.executable, "-c", _SLICE_CHILD], capture_output=True, text=True, timeout=120, check=True
    )
    r = json.loads(out.stdout.strip().splitlines()[-1])
    if r["why"] is not None:
        pytest.skip(f"request_slice refused here: {r['why']}")
    if r["slice"] is not None:
        assert r["slice"] == 200_000
