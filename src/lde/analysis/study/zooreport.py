"""The zoo evaluation as a document: ``lde evaluate --zoo`` writes it to ``OUT/zoo_table.md``, beside
the runs it summarises, with the command, the machine and the date of the run:

- :func:`summary_block`: the summary lines (per target of :mod:`lde.analysis.metrics`, the wind force,
  the bank angle, the payload about both CGs, the backends' agreement);
- :func:`doc_block`: the run line, the legend, the same summary and, per mode, the table with a row per
  plant x profile x backend (:func:`lde.analysis.study.zoo.plant_table_markdown`).
"""

from __future__ import annotations

import contextlib
import datetime
import importlib.metadata
import os
import platform
from collections.abc import Sequence
from dataclasses import dataclass

from lde.analysis.study import zoo
from lde.analysis.study.spec import RunResult

LEGEND = (
    "Cells: NRMSE Fw / Mw in % after 2 s, Mw about the CG the estimator's vehicle file states (the "
    "spec sheet's: the unloaded car's); a payload plant's cell gives Mw about the other CG in brackets "
    "(spec-sheet rows: the true, loaded CG; `+ load` rows, whose file carries the loaded car's mass, "
    "yaw inertia and CG as a load signal would: the unloaded car's CG); disturbance-free drives "
    "(lane_change): RMS of the estimate in N / Nm. **Bold**: the run misses its target (cold: 10 %, "
    "60 N / 20 Nm; warm: 5 %, 20 N / 8 Nm; warm with defects, rough driver, 800 m curve, speed ramps: "
    "10 %). `wind <= 10 %`: runs with wind whose wind force `Fw_wind` is within 10 % NRMSE (worst); "
    "`bank <= 0.3 deg`: runs whose bank angle RMS error is within 0.3 deg (worst); `learn state`: "
    "the CSV's `learn_state` at the end of each run, one digit per scenario column (0 not learned, "
    "1 learning, 2 learned, 3 the backend does not learn)."
)


@dataclass(frozen=True)
class RunInfo:
    """How the table was made: the command line, the number of runs, wall time [s], Dask workers,
    the machine, the load average before and after, the local date and time."""

    command: str
    runs: int
    wall_s: float
    workers: int
    machine: str
    load_before: float
    load_after: float
    date: str


def machine_description() -> str:
    """ "N cores (CPU model), Python X, numba Y" of this machine."""
    cpu = ""
    with contextlib.suppress(OSError, StopIteration), open("/proc/cpuinfo") as fh:
        cpu = next(ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name"))
    try:
        numba = importlib.metadata.version("numba")
    except importlib.metadata.PackageNotFoundError:
        numba = "?"
    cores = f"{os.cpu_count()} cores" + (f" ({cpu})" if cpu else "")
    return f"{cores}, Python {platform.python_version()}, numba {numba}"


def load_average() -> float:
    """The 1-minute load average (NaN where the platform has none)."""
    try:
        return os.getloadavg()[0]
    except OSError:
        return float("nan")


def now() -> str:
    return datetime.datetime.now().strftime("%Y-%m-%d %H:%M")


def run_line(info: RunInfo) -> str:
    """One line: the command, the runs, the wall time, the machine, the load, the date."""
    return (
        f"Measured with `{info.command}`: {info.runs} runs in {info.wall_s:.0f} s wall on {info.machine}, "
        f"{info.workers} Dask workers; load average {info.load_before:.1f} before, {info.load_after:.1f} "
        f"after (the machine is shared); {info.date}."
    )


def summary_block(results: Sequence[RunResult]) -> list[str]:
    """The summary lines (targets, wind, bank, failures; then the payload, the backends' agreement)
    as markdown bullets."""
    lines = zoo.summary_lines(results) + zoo.payload_lines(results) + zoo.backend_lines(results)
    return [f"- {line}" for line in lines]


def doc_block(results: Sequence[RunResult], info: RunInfo) -> str:
    """``zoo_table.md``: the run line, the legend, the summary lines and per mode the
    table with a row per plant x profile x backend (warm once per prior drive: ``warm after NAME``)."""
    lines = [run_line(info), "", LEGEND, "", *summary_block(results)]
    for mode in dict.fromkeys(zoo.mode_label(r) for r in sorted(results, key=zoo.mode_order)):
        rs = [r for r in results if zoo.mode_label(r) == mode]
        lines += ["", f"**{mode.capitalize()}**", "", zoo.plant_table_markdown(rs)]
    return "\n".join(lines)
