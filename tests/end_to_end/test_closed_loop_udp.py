"""The closed loop as a user runs it: ``lde sim`` and ``lde run`` as two processes on python-can's
``udp_multicast`` bus (a group and port of this test's own, ``hop_limit=0``: the datagrams stay on
this host), heavy crosswind.

The simulator must take in the ``LDE_Overlay`` frames that reach it and apply them: its truth has the
overlay torque in most rows once the wind is up, and where it was applied the driver's mean holding
torque falls by at least 15 % against the same seed without the service (``lde demo`` on the virtual
bus: about 20 % on this stretch, 21 % over the whole scenario, the overlay saturated).

The judgement is on what reached the simulator, not on the host's timing: a 3.9 ms loop of two
Python processes on two loaded cores misses inputs now and then, a late MDPS frame makes the estimate
invalid and restarts its convergence time, and the overlay ramps out meanwhile. Both processes ask
for real-time scheduling (``lde run --realtime``, ``lde sim --rt-priority``) as a user on a shared
machine would; where that is refused they run at the normal priority.
"""

from __future__ import annotations

import csv
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from lde.testing.bus import private_multicast

pytest.importorskip("msgpack")

SCENARIO = "heavy_load"  # the paper's heavy lateral load: gusty 15 m/s crosswind from 3 s on
SEED = 3
DURATION_S = 14.0
#: the overlay's share is judged from here [s]: the wind is up (3-4 s) and the estimate has converged
SETTLE_S = 5.0
#: an applied overlay torque [Nm] (the plant's lag leaves a trace below this after a ramp-out)
APPLIED_NM = 0.05
#: the service's start-up (numba loads its kernels; compiles them on a cold cache) [s]
START_TIMEOUT_S = 300.0


def _lde(*args: str) -> list[str]:
    return [sys.executable, "-m", "lde", *args]


def _truth(path: Path) -> dict[str, np.ndarray]:
    with path.open() as f:
        rows = list(csv.DictReader(f))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("t", "T_driver", "T_overlay")}


def _after_settle(tr: dict[str, np.ndarray]) -> np.ndarray:
    return tr["t"] - tr["t"][0] >= SETTLE_S


class _Lines:
    """A process's stderr, read line by line in a thread (so it never blocks on a full pipe)."""

    def __init__(self, proc: subprocess.Popen) -> None:
        self.lines: list[str] = []
        assert proc.stderr is not None
        self._stream = proc.stderr
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        for line in self._stream:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, pattern: str, timeout_s: float, proc: subprocess.Popen) -> str:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for x in list(self.lines):
                if re.search(pattern, x):
                    return x
            if proc.poll() is not None:
                break
            time.sleep(0.1)
        raise AssertionError(f"no line matching {pattern!r}:\n" + "\n".join(self.lines))

    def join(self) -> list[str]:
        self._thread.join(10)
        return self.lines


def test_lde_sim_and_lde_run_close_the_loop_on_udp_multicast(tmp_path) -> None:
    t_start = time.monotonic()
    kw = private_multicast()
    group, port = kw["channel"], kw["port"]
    bus = ["-i", "udp_multicast", "-c", group, "--bus-kwarg", f"port={port}", "--bus-kwarg", "hop_limit=0"]
    sim = ["sim", "-s", SCENARIO, "--seed", str(SEED), "--duration", str(DURATION_S)]
    env = dict(os.environ, PYTHONUNBUFFERED="1")

    # the same drive without the service (the simulator alone, as fast as it goes)
    base = tmp_path / "base.csv"
    subprocess.run(_lde(*sim, "--truth", str(base)), check=True, env=env, capture_output=True, timeout=300)

    service = subprocess.Popen(
        _lde("run", *bus, "--realtime", "--priority", "60", "--cpu-latency-us", "-1"),
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    svc_err = _Lines(service)
    try:
        start = svc_err.wait_for(r"lde run: udp_multicast:", START_TIMEOUT_S, service)
        assert f"udp_multicast:{group} port {port}" in start  # the service says which group and port
        t_ready = time.monotonic()
        loop = tmp_path / "loop.csv"
        done = subprocess.run(
            _lde(*sim, *bus, "--rt-priority", "70", "--truth", str(loop)),
            env=env,
            capture_output=True,
            text=True,
            timeout=DURATION_S + 120,
        )
        assert done.returncode == 0, done.stderr
    finally:
        service.send_signal(signal.SIGINT)
        try:
            service.wait(30)
        finally:
            if service.poll() is None:
                service.kill()
    svc_lines = svc_err.join()
    t_end = time.monotonic()
    print(f"wall time: {t_ready - t_start:.1f} s to the service's start, {t_end - t_ready:.1f} s after")
    assert f"on udp_multicast:{group} port {port}" in done.stderr  # the simulator says it too

    # what reached the simulator: every LDE_Overlay frame it read passed its E2E check and was used
    m = re.search(r"overlay frames used (\d+) of (\d+) received", done.stderr)
    assert m, done.stderr
    used, received = int(m[1]), int(m[2])
    steps = int(DURATION_S / 0.0039)
    assert used >= 0.95 * received, done.stderr
    assert received >= 0.5 * steps, done.stderr  # one per service step: the service answered

    # the simulator applied them: the overlay torque in most rows once the wind is up ...
    on, off = _truth(loop), _truth(base)
    assert len(on["t"]) == len(off["t"]) and np.array_equal(on["t"], off["t"])
    late = _after_settle(on)
    applied = np.abs(on["T_overlay"]) > APPLIED_NM
    share = float(np.mean(applied[late]))
    # "most": at load 10 on two cores the two processes fall behind real time now and then and the
    # share fell to 66 % (100 % on a quiet machine); an overlay that never arrives gives 0 %
    assert share > 0.5, f"overlay applied in {share:.0%} of the rows after {SETTLE_S} s"
    # ... and where it was, the driver holds less than on the same drive without the service
    hold_on = float(np.mean(np.abs(on["T_driver"][late & applied])))
    hold_off = float(np.mean(np.abs(off["T_driver"][late & applied])))
    reduction = 1.0 - hold_on / hold_off
    whole_on = float(np.mean(np.abs(on["T_driver"][late])))
    whole_off = float(np.mean(np.abs(off["T_driver"][late])))
    print(
        f"udp_multicast closed loop: overlay frames used {used} of {received}; applied in {share:.0%} of the"
        f" rows after {SETTLE_S:.0f} s; driver mean |T| there {hold_off:.2f} -> {hold_on:.2f} Nm"
        f" ({-reduction:+.1%}); all rows after {SETTLE_S:.0f} s {whole_off:.2f} -> {whole_on:.2f} Nm"
        f" ({whole_on / whole_off - 1:+.1%})"
    )
    assert reduction >= 0.15, (hold_off, hold_on, "\n".join(svc_lines[-15:]))

    # the service showed what it did: a status line a second, the overlay active once the wind was up
    status = [x for x in svc_lines if x.startswith("lde run: valid ")]
    assert len(status) >= DURATION_S - 2, svc_lines
    assert any(
        re.search(r"valid (9\d|100) %, Fw -?\d+ N, .*overlay active -?\d\.\d\d Nm", x) for x in status
    ), status
    assert service.returncode == 0, "\n".join(svc_lines)
