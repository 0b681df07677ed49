"""The study's plots: error index bars (Fig. 11), estimates against truth (Figs. 13-14), tires (Fig. 12).

Every plot is a :class:`matplotlib.figure.Figure` made without pyplot and saved with its own canvas:
no global backend is selected (``matplotlib.use`` would change every caller's backend) and no figure
is left in pyplot's registry.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lde.analysis.study.spec import RunResult
from lde.analysis.study.tables import CandidateScore, pct
from lde.analysis.study.tires import TireIdentification
from lde.errors import ConfigError


def _save(fig: Figure, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    return path


def plot_error_index(scores: Sequence[CandidateScore], path: Path, title: str = "") -> Path:
    """Bar chart of the mean eq. (19) index per candidate set (like the paper's Fig. 11)."""
    if not scores:
        raise ConfigError("no successful runs to plot")
    ordered = sorted(scores, key=lambda s: s.candidate)
    fig = Figure(figsize=(6, 3.5), layout="tight")
    ax = fig.subplots()
    best = min(scores, key=lambda s: s.mean_j).candidate
    colors = ["tab:green" if s.candidate == best else "tab:blue" for s in ordered]
    ax.bar([s.candidate for s in ordered], [s.mean_j for s in ordered], color=colors)
    ax.set_ylabel("error index J [N]  (q1 = 1/N, q2 = 1/Nm)")
    ax.set_title(title or "Error index of the parameter sets (mean over load cases)")
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def plot_traces(results: Sequence[RunResult], path: Path, title: str = "") -> Path:
    """Estimates against truth, one column per traced run (like the paper's Figs. 13-14)."""
    traced = [r for r in results if r.trace is not None]
    if not traced:
        raise ConfigError("no traced runs to plot")
    fig = Figure(figsize=(4.5 * len(traced), 5.5), layout="tight")
    axes = fig.subplots(2, len(traced), squeeze=False, sharex="col")
    for j, r in enumerate(traced):
        tr = r.trace or {}
        ax_f, ax_m = axes[0, j], axes[1, j]
        ax_f.plot(tr["t"], tr["fw"], "k-", lw=1.2, label="truth")
        ax_f.plot(tr["t"], tr["fw_hat"], "r--", lw=1.0, label="estimate")
        ax_m.plot(tr["t"], tr["mw"], "k-", lw=1.2, label="truth (actual CG)")
        ax_m.plot(tr["t"], tr["mw_ref"], color="0.6", lw=0.8, label="truth (unloaded CG)")
        ax_m.plot(tr["t"], tr["mw_hat"], "r--", lw=1.0, label="estimate")
        a = r.accuracy
        sp = r.spec
        sub = f"{sp.scenario} ({sp.payload or 'scenario payload'}, seed {sp.seed})\n"
        sub += (
            sp.group if sp.group and sp.group not in ("candidates", "evaluate") else Path(sp.est_vehicle).stem
        )
        if a is not None:
            sub += f"\nNRMSE Fw {pct(a.nrmse_fw)}, Mw {pct(a.nrmse_mw)}"
        ax_f.set_title(sub, fontsize=7)
        ax_f.set_ylabel("Fw [N]")
        ax_m.set_ylabel("Mw [Nm]")
        ax_m.set_xlabel("t [s]")
        for ax in (ax_f, ax_m):
            ax.grid(alpha=0.3)
        ax_m.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def plot_tires(ids: Sequence[TireIdentification], path: Path) -> Path:
    """Cornering stiffness and aligning-torque rate per load level (like the paper's Fig. 12)."""
    fig = Figure(figsize=(8, 3.2), layout="tight")
    a1, a2 = fig.subplots(1, 2)
    x = np.arange(len(ids))
    w = 0.38
    a1.bar(x - w / 2, [i.cf / 1000 for i in ids], w, label="C_f")
    a1.bar(x + w / 2, [i.cr / 1000 for i in ids], w, label="C_r")
    a1.set_xticks(x, [i.scenario for i in ids])
    a1.set_ylabel("per tire [kN/rad]")
    a1.set_title("cornering stiffness (bicycle equivalent)", fontsize=9)
    a1.legend(fontsize=8)
    a2.bar(x, [i.k for i in ids], 0.5, color="tab:orange")
    a2.set_xticks(x, [i.scenario for i in ids])
    a2.set_ylabel("K [Nm/rad]")
    a2.set_title("aligning-torque rate", fontsize=9)
    for ax in (a1, a2):
        ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)
