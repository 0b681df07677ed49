"""lde.testing on real SocketCAN: the same bench, the same fixtures, on vcan0.

Marked ``vcan``: they run only where a real vcan0 exists, i.e. inside user-mode Linux
(``tests/test_uml.py`` runs them there through ``tests/uml/run_in_uml.sh``); elsewhere they are
skipped with the reason (tests/conftest.py).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import can
import pytest

from lde.testing import Bench, Rank, assert_e2e_valid, assert_periodic

from helpers import TESTS

pytestmark = pytest.mark.vcan

ROOT = TESTS.parent
IDS = (0x2A0, 0x2A8, 0x3D0, 0x3D1, 0x3D2, 0x6E0)


def _closed_loop(interface: str) -> tuple[list, list]:
    """2 s of closed loop with lde's service, a user's periodic task and a frame handler."""
    with Bench(interface=interface) as bench:
        bench.simulator("wind_step", seed=2, duration=2.0)
        svc = bench.service(backend="float")
        user = bench.bus("user")
        bench.every(
            0.010,
            lambda t: user.send(can.Message(arbitration_id=0x6E0, data=b"\x01", is_extended_id=False)),
            rank=Rank.LATE,
        )
        echo = bench.bus("echo")
        bench.on_frame(
            "ESC_Motion",
            lambda f: echo.send(can.Message(arbitration_id=0x6E1, data=f.data, is_extended_id=False)),
            bus=echo,
        )
        bench.run()
        frames = []
        for i in (*IDS, 0x6E1):
            fl = bench.frames(i)
            frames += [(int(t), i, bytes(d)) for t, d in zip(fl.t_ns, fl.data, strict=True)]
        results = [(r.t_ns, r.fw, r.mw, r.t_overlay, r.status, r.frames_used) for r in svc.results]
        assert_periodic(bench.frames("LDE_Overlay"))
        assert_e2e_valid(bench.frames("LDE_Estimate"))
        return sorted(frames), results


def test_vcan0_gives_the_same_frames_and_outputs_as_the_virtual_bus() -> None:
    on_vcan0 = _closed_loop("socketcan")
    assert len(on_vcan0[1]) == 513 and len(on_vcan0[0]) > 2500
    assert on_vcan0 == _closed_loop("virtual")


@pytest.mark.lde_bench(interface="socketcan", channel="vcan0")
@pytest.mark.lde_sim(scenario="light_load", seed=1, duration=1.0)
@pytest.mark.lde_service(backend="float")
def test_the_fixtures_run_on_vcan0(lde_bench, lde_sim, lde_service) -> None:
    assert lde_bench.interface == "socketcan" and lde_bench.channel == "vcan0"
    assert lde_sim.bus.raw.channel_info.startswith("socketcan")
    lde_bench.run()
    assert len(lde_service.results) == 257
    assert_periodic(lde_bench.frames("MDPS_Sensors"))
    assert_e2e_valid(lde_bench.frames("LDE_Overlay"))


def test_the_example_runs_on_vcan0_with_the_option(tmp_path: Path) -> None:
    """The example's frame-level test (one 12 s closed loop: the others take minutes in UML) and a
    check that the option really put the bench on vcan0."""
    check = tmp_path / "test_on_vcan0.py"
    check.write_text(
        "def test_bench_is_on_vcan0(lde_bench):\n    assert lde_bench.interface == 'socketcan'\n"
    )
    cmd = [
        sys.executable,
        "-m",
        "pytest",
        "-q",
        "-rs",
        "-p",
        "lde.testing.plugin",
        "-p",
        "no:cacheprovider",
        "--lde-interface",
        "socketcan",
        "--lde-channel",
        "vcan0",
        str(ROOT / "examples" / "test_my_controller.py")
        + "::test_hold_assist_sends_a_protected_request_every_step",
        str(check),
    ]
    r = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 passed" in r.stdout and "skipped" not in r.stdout, r.stdout
