"""The study's outputs as numbers: candidate ranking (eq. 19), pivot tables, CSV files, text tables.

Rows are plain dicts written with the csv module (fractions as is, not percent); markdown and text
tables print NRMSE in % and, for undisturbed scenarios, the RMS of the estimate in N and Nm. The zoo
evaluation's per-plant table is in :mod:`lde.analysis.study.zoo`.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lde.analysis import metrics
from lde.analysis.study.spec import RunResult


@dataclass(frozen=True)
class CandidateScore:
    """Mean eq. (19) index over the load cases of one candidate set, and its worst NRMSEs."""

    candidate: str
    n_runs: int
    mean_j: float  # N
    mean_rms_fw: float  # N
    mean_rms_mw: float  # Nm
    worst_nrmse_fw: float  # fraction
    worst_nrmse_mw: float  # fraction


def rank_candidates(results: Sequence[RunResult], key: str = "est_vehicle") -> list[CandidateScore]:
    """Candidates (by ``key`` of the spec) sorted by mean J, best first. Failed runs are skipped."""
    groups: dict[str, list[metrics.Accuracy]] = {}
    for r in results:
        if r.ok and r.accuracy is not None:
            name = str(getattr(r.spec, key))
            groups.setdefault(Path(name).stem if name.endswith(".toml") else name, []).append(r.accuracy)
    scores = []
    for name, accs in groups.items():
        scores.append(
            CandidateScore(
                candidate=name,
                n_runs=len(accs),
                mean_j=metrics.mean_error_index((a.rms_fw, a.rms_mw) for a in accs),
                mean_rms_fw=float(np.mean([a.rms_fw for a in accs])),
                mean_rms_mw=float(np.mean([a.rms_mw for a in accs])),
                worst_nrmse_fw=nanmax([a.nrmse_fw for a in accs]),
                worst_nrmse_mw=nanmax([a.nrmse_mw for a in accs]),
            )
        )
    return sorted(scores, key=lambda s: s.mean_j)


def nanmax(xs: Sequence[float]) -> float:
    """The largest finite value (NaN when there is none)."""
    finite = [x for x in xs if math.isfinite(x)]
    return max(finite) if finite else math.nan


def pivot_markdown(results: Sequence[RunResult], value: str = "nrmse") -> str:
    """A markdown table: one row per scenario, one column per group; cells "Fw / Mw" (mean over
    seeds; NRMSE in %, or RMS in N / Nm for undisturbed scenarios)."""
    groups: list[str] = []
    scen: list[str] = []
    cells: dict[tuple[str, str], list[metrics.Accuracy]] = {}
    for r in results:
        g, sc = r.spec.group, r.spec.scenario
        if g not in groups:
            groups.append(g)
        if sc not in scen:
            scen.append(sc)
        if r.ok and r.accuracy is not None:
            cells.setdefault((sc, g), []).append(r.accuracy)
    lines = ["| scenario | " + " | ".join(groups) + " |", "|---|" + "---|" * len(groups)]
    for sc in scen:
        row = [sc]
        for g in groups:
            accs = cells.get((sc, g), [])
            if not accs:
                row.append("failed")
            elif accs[0].kind is metrics.Kind.UNDISTURBED:
                row.append(
                    f"{np.mean([a.rms_fw for a in accs]):.0f} N / {np.mean([a.rms_mw for a in accs]):.0f} Nm"
                )
            else:
                f = 100 * np.mean([a.nrmse_fw for a in accs])
                m = 100 * np.mean([a.nrmse_mw for a in accs])
                row.append(f"{f:.1f} / {m:.1f}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def write_rows(rows: Sequence[dict[str, Any]], path: Path) -> Path:
    """A CSV of dict rows (columns: union of the rows' keys, in first-seen order; floats to 6
    significant digits, NaN as empty)."""
    cols: list[str] = []
    for row in rows:
        cols += [k for k in row if k not in cols]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols or ["empty"], restval="")
        w.writeheader()
        for row in rows:
            w.writerow({k: _fmt(v) for k, v in row.items()})
    return path


def write_csv(results: Sequence[RunResult], path: Path) -> Path:
    """One row per run (columns: union of all rows' keys, in first-seen order)."""
    return write_rows([r.as_row() for r in results], path)


def write_scores_csv(scores: Sequence[CandidateScore], path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(asdict(scores[0])) if scores else ["candidate"])
        w.writeheader()
        for s in scores:
            w.writerow({k: _fmt(v) for k, v in asdict(s).items()})
    return path


def _fmt(v: Any) -> Any:
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return v


def pct(x: float) -> str:
    """A fraction as "12.3%" ("-" when not finite)."""
    return "-" if not math.isfinite(x) else f"{100 * x:.1f}%"


#: columns of the printed accuracy table (key, header, format)
TABLE_COLUMNS = (
    ("label", "run", ""),
    ("kind", "kind", ""),
    ("nrmse_fw", "NRMSE Fw", ".1%"),
    ("nrmse_mw", "NRMSE Mw", ".1%"),
    ("nrmse_mw_ref", "Mw (ref CG)", ".1%"),
    ("rms_fw_N", "RMS Fw [N]", ".0f"),
    ("rms_mw_Nm", "RMS Mw [Nm]", ".0f"),
    ("J_N", "J [N]", ".0f"),
    ("error", "error", ""),
)


def scores_table(scores: Sequence[CandidateScore]) -> str:
    """The candidate ranking as text."""
    rows = [asdict(s) for s in scores]
    cols = (
        ("candidate", "set", ""),
        ("n_runs", "runs", "d"),
        ("mean_j", "mean J [N]", ".1f"),
        ("mean_rms_fw", "RMS e_F [N]", ".1f"),
        ("mean_rms_mw", "RMS e_M [Nm]", ".1f"),
        ("worst_nrmse_fw", "worst NRMSE Fw", ".1%"),
        ("worst_nrmse_mw", "worst NRMSE Mw", ".1%"),
    )
    return metrics.format_table(rows, cols)


def table(results: Sequence[RunResult]) -> str:
    """The accuracy table as text (fractions printed as %)."""
    rows = []
    for r in results:
        row = r.as_row()
        row["label"] = r.spec.label
        err = str(row.get("error", ""))
        row["error"] = err if len(err) <= 100 else err[:97] + "..."
        rows.append(row)
    return metrics.format_table(rows, TABLE_COLUMNS)
