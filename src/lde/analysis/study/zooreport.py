"""The zoo evaluation as a document: the README's accuracy headline and ``docs/study.md``'s tables.

``lde evaluate --zoo --readme README.md --doc docs/study.md`` writes the text between the markers
:data:`MARK_BEGIN` and :data:`MARK_END` of each file (as ``bench/run_all.py --readme`` does for the
bench table), so that the figures in the documents are the figures of one run, with the command, the
machine and the date:

- :func:`readme_block`: the run line and the summary lines (per target of :mod:`lde.analysis.metrics`, the
  wind force, the bank angle, the payload about both CGs);
- :func:`doc_block`: the same and, per mode, the table with a row per plant x profile x backend
  (:func:`lde.analysis.study.zoo.plant_table_markdown`).
"""

from __future__ import annotations

import contextlib
import datetime
import importlib.metadata
import os
import platform
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from lde.analysis.study import zoo
from lde.analysis.study.spec import RunResult
from lde.errors import ConfigError

MARK_BEGIN = "<!-- lde evaluate --zoo: begin -->"
MARK_END = "<!-- lde evaluate --zoo: end -->"

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


def readme_block(results: Sequence[RunResult], info: RunInfo) -> str:
    """The README's accuracy headline: the run line and the summary lines."""
    return "\n".join([run_line(info), "", *summary_block(results)])


def doc_block(results: Sequence[RunResult], info: RunInfo) -> str:
    """``docs/study.md``'s zoo section: the run line, the legend, the summary lines and per mode the
    table with a row per plant x profile x backend (warm once per prior drive: ``warm after NAME``)."""
    lines = [run_line(info), "", LEGEND, "", *summary_block(results)]
    for mode in dict.fromkeys(zoo.mode_label(r) for r in sorted(results, key=zoo.mode_order)):
        rs = [r for r in results if zoo.mode_label(r) == mode]
        lines += ["", f"**{mode.capitalize()}**", "", zoo.plant_table_markdown(rs)]
    return "\n".join(lines)


def marked_span(path: Path, begin: str = MARK_BEGIN, end: str = MARK_END) -> tuple[str, int, int]:
    """(the file's text, the end of ``begin``, the start of ``end``); ConfigError when the file
    cannot be read or has not both markers, once each, in that order."""
    try:
        s = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    a, b = s.find(begin), s.find(end)
    if a < 0 or b < a or s.count(begin) != 1 or s.count(end) != 1:
        raise ConfigError(f"{path}: no {begin} ... {end} markers (once each, in that order)")
    return s, a + len(begin), b


def replace_marked(path: Path, text: str, begin: str = MARK_BEGIN, end: str = MARK_END) -> None:
    """Put ``text`` between the ``begin`` and ``end`` markers of ``path`` (the markers and everything
    outside them stay; written atomically); ConfigError as :func:`marked_span`, or when it cannot be
    written."""
    replace_all_marked([(path, text)], begin, end)


def replace_all_marked(
    edits: Sequence[tuple[Path, str]], begin: str = MARK_BEGIN, end: str = MARK_END
) -> None:
    """:func:`replace_marked` for several files: every file's markers are checked before any is
    written, so that a bad file leaves all of them as they were."""
    new = []
    for path, text in edits:
        s, a, b = marked_span(path, begin, end)
        new.append((path, s[:a] + "\n" + text.strip("\n") + "\n" + s[b:]))
    for path, s in new:
        tmp = path.with_name(path.name + ".tmp")
        try:
            tmp.write_text(s)
            tmp.replace(path)
        except OSError as exc:
            raise ConfigError(f"{path}: cannot write ({exc.strerror})") from None
