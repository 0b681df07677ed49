"""Tire identification for the study (the paper's Fig. 12 question on the simulator).

Linear-equivalent C_f, C_r, K per load level fitted to the simulator's truth
(:mod:`vcan_sim.identify`), their representative (mean) values, the tire curvature that the heavy
load's slip reaches, and a vehicle file that extends a candidate set with the representative tires.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lde.analysis.study.presets import PAPER_SCENARIOS
from vcan_sim.identify import identify_scenarios
from vcan_sim.run import simulate


@dataclass(frozen=True)
class TireIdentification:
    """Per-tire linear-equivalent parameters fitted to a scenario's truth (``vcan_sim.identify``)."""

    scenario: str
    cf: float  # N/rad, bicycle equivalent
    cr: float  # N/rad
    k: float  # Nm/rad
    cf_tire: float  # N/rad, tire level (Fy / alpha)
    cr_tire: float  # N/rad
    max_alpha_f: float  # rad


def identify_tires(
    scenarios: Sequence[str] = PAPER_SCENARIOS, seeds: Sequence[int] = (0, 1)
) -> list[TireIdentification]:
    """The paper's Fig. 12 question on the simulator: Cf, Cr, K per load level (truth-based fit)."""

    out = identify_scenarios(list(scenarios), seeds=tuple(seeds))
    return [
        TireIdentification(name, le.cf, le.cr, le.k, le.cf_tire, le.cr_tire, le.max_alpha_f)
        for name, le in out.items()
    ]


def identify_curvature(
    scenario: str = "heavy_load", seeds: Sequence[int] = (0, 1)
) -> tuple[float, float, float]:
    """Tire curvature (kappa_f, kappa_r, kappa_K) [1/rad^2] fitted to a scenario's truth.

    Least squares of ``F/2 = C alpha (1 - kappa alpha^2)`` (per tire, front and rear lateral force)
    and ``T_align/2 = K alpha_f (1 - kappa_K alpha_f^2)``: how fast the secant stiffnesses fall with
    slip (the heavy load reaches alpha_f ~ 0.02 rad).
    """

    runs = [simulate(scenario, seed=s) for s in seeds]
    col = {
        k: np.concatenate([r.truth[k] for r in runs])
        for k in ("vx", "alpha_f", "alpha_r", "Fy_front", "Fy_rear", "T_align")
    }
    use = col["vx"] > 50.0 / 3.6
    out = []
    for alpha, y in (
        (col["alpha_f"], col["Fy_front"] / 2.0),
        (col["alpha_r"], col["Fy_rear"] / 2.0),
        (col["alpha_f"], col["T_align"] / 2.0),
    ):
        a = alpha[use]
        (c0, c3), *_ = np.linalg.lstsq(np.column_stack([a, -(a**3)]), y[use], rcond=None)
        out.append(float(c3 / c0))
    return out[0], out[1], out[2]


def representative_tires(ids: Sequence[TireIdentification]) -> tuple[float, float, float]:
    """Mean (Cf, Cr, K) over the load levels: the representative values (the paper's conclusion)."""
    return (
        float(np.mean([i.cf for i in ids])),
        float(np.mean([i.cr for i in ids])),
        float(np.mean([i.k for i in ids])),
    )


def write_tire_vehicle(path: Path, base: str, cf: float, cr: float, k: float, note: str) -> Path:
    """A vehicle file extending ``base`` with the given per-tire [tires]."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        f"# {note}\n"
        f'extends = "{base}"\n'
        f'name = "{path.stem}"\n'
        f'description = "{base} with representative linear-equivalent tires (lde study, Fig. 12)"\n\n'
        "[tires]\n"
        f"cf_N_per_rad = {cf:.0f}\n"
        f"cr_N_per_rad = {cr:.0f}\n"
        f"align_rate_Nm_per_rad = {k:.0f}\n"
    )
    return path
