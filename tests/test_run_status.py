"""``lde run`` shows what it does: a status line a second, the bus named as python-can names it, one
warning on a silent bus once the inputs' timeouts have passed, and exit status 3 when no input ever
arrived (as ``lde replay``)."""

from __future__ import annotations

import math
import re

import pytest

from lde.cli import main
from lde.cli.replay import EXIT_NOTHING_USABLE
from lde.service.diagnostics import ServiceStatus, TimingSummary


@pytest.mark.lde_bench(capture=False)
def test_a_silent_bus_warns_once_says_so_at_the_end_and_exits_3(lde_bench, caplog, capsys) -> None:
    ch = lde_bench.channel  # a fresh virtual channel nobody sends on
    with caplog.at_level("INFO", logger="lde.service.service"):
        rc = main(["run", "-i", "virtual", "-c", ch, "--duration", "2.2", "--backend", "float"])
    assert rc == EXIT_NOTHING_USABLE
    lines = [(r.levelname, r.getMessage()) for r in caplog.records if r.name == "lde.service.service"]
    text = "\n".join(m for _, m in lines)
    assert f"lde run: virtual:{ch}, profile lde" in text  # python-can's interface:channel
    warns = [m for lvl, m in lines if lvl == "WARNING" and m.startswith("no input:")]
    # one warning naming both inputs (MDPS_Sensors' 10 timeouts pass first, ESC_Motion's later)
    assert len(warns) == 1, warns
    assert (
        "MDPS_Sensors (0x2A0) never received" in warns[0] and "ESC_Motion (0x2A8) never received" in warns[0]
    )
    assert f"on virtual:{ch}" in warns[0]
    assert "nan" not in text
    assert "latency: no input frame used" in text
    end = [m for lvl, m in lines if lvl == "WARNING" and "no input ever arrived" in m]
    assert (
        len(end) == 1
        and f"on virtual:{ch} with profile lde" in end[0]
        and "no frame arrived at all" in end[0]
    )
    # the status lines: about one a second, each naming what is missing
    status = [x for x in capsys.readouterr().err.splitlines() if x.startswith("lde run: valid")]
    assert 2 <= len(status) <= 3, status
    assert all(x.endswith("missing: MDPS_Sensors, ESC_Motion") for x in status), status
    # no input: nothing valid, the overlay limiter in its input-fault state, at zero
    assert all("valid 0 %" in x and "overlay fault 0.00 Nm" in x for x in status), status


@pytest.mark.lde_bench(capture=False)
def test_quiet_prints_no_status(lde_bench, capsys) -> None:
    rc = main(
        [
            "run",
            "-i",
            "virtual",
            "-c",
            lde_bench.channel,
            "--duration",
            "1.2",
            "--quiet",
            "--backend",
            "float",
        ]
    )
    assert rc == EXIT_NOTHING_USABLE
    assert "lde run: valid" not in capsys.readouterr().err


def test_the_status_line_names_every_quantity_with_its_unit() -> None:
    st = ServiceStatus(
        steps=256,
        valid=250,
        fw=2105.4,
        mw=-311.7,
        bank=math.radians(-1.23),
        overlay_state=2,
        t_overlay=-2.853,
        learn_state=1,
        deadline_misses=3,
    )
    assert st.line() == (
        "valid 98 %, Fw 2105 N, Mw -312 Nm, bank -1.2 deg, overlay active -2.85 Nm, learner learning, "
        "deadline misses 3"
    )
    blind = ServiceStatus(0, 0, 0.0, 0.0, float("nan"), 4, 0.0, 3, 41, ("MDPS_Sensors",))
    assert re.fullmatch(
        r"no step, Fw 0 N, Mw 0 Nm, bank n/a, overlay fault 0.00 Nm, learner none, deadline misses 41, "
        r"missing: MDPS_Sensors",
        blind.line(),
    )


def test_the_timing_line_without_inputs_has_no_nan() -> None:
    nan = float("nan")
    s = TimingSummary(10, 5.0, 9.0, 12.0, 80.0, 90.0, 95.0, nan, nan, nan, 0, 0)
    assert "nan" not in s.log_line() and "latency: no input frame used" in s.log_line()
    empty = TimingSummary(0, nan, nan, nan, nan, nan, nan, nan, nan, nan, 2, 2)
    assert "nan" not in empty.log_line()
