"""The zoo evaluation (issue 11): the estimator on cars it was never fitted to, as a user runs it.

For every plant of :mod:`vcan_sim.zoo` x scenario x profile (``lde``, ``hyundai``) x backend
(``fixed``, ``float``): simulate (seeded), write the log, ``lde replay`` it with only the plant's
spec-sheet vehicle file (:mod:`lde.cli.engine`), score the CSV against the truth
(:mod:`lde.metrics`: NRMSE after 2 s; RMS on a disturbance-free drive; Mw about the true CG and
about the spec sheet's CG). Cold: ``lde replay LOG``; warm: after ``lde replay PRIOR --learned S``
on the plant's :data:`PRIOR_SCENARIO` with another seed (only a learning backend, ``lateral``, uses it).

Outputs (:func:`plant_table_markdown`, :func:`plant_table_rows`, :func:`summary_lines`): one row per
plant x profile x backend with a "Fw / Mw" cell per scenario, and one line per target of
:mod:`lde.metrics` saying in how many runs it is met and where it is missed by most.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Sequence
from typing import Any

from vcan_sim.scenarios import SCENARIOS
from vcan_sim.zoo import plant_names, read_true_values

from .. import metrics
from ..errors import ConfigError
from .engine import ZOO_PREFIX, plant_name
from .spec import SPEC_SHEET, Estimator, EstOptions, RunResult, RunSpec

#: the zoo evaluation's scenarios: crosswind steps, gusts, banks, the paper's loads, slalom, an
#: 800 m curve, speed ramps, a rough driver, and a disturbance-free drive
ZOO_SCENARIOS = (
    "wind_step",
    "gusty_wind",
    "bank_transition",
    "heavy_load",
    "light_load",
    "slalom",
    "curve_800m",
    "speed_ramp",
    "rough_driver",
    "lane_change",
)
#: the learner's tests (10 minutes each): a steady crosswind and a banked road must not be learned away
LONG_SCENARIOS = ("steady_crosswind_10min", "banked_road_10min")
#: the earlier drive a warm run learns on (disturbance-free, lane changes and a weave)
PRIOR_SCENARIO = "prior_drive"
PROFILES = ("lde", "hyundai")
BACKENDS = ("fixed", "float")
#: scenarios whose warm target is WARM_DEFECTS (rough driver, 800 m curve, speed ramps)
HARD_SCENARIOS = ("rough_driver", "curve_800m", "speed_ramp")
#: a plant with at least this rack friction [Nm], or any sensor offset, has "defects"
DEFECT_FRICTION_NM = 0.4


class Mode(str, enum.Enum):
    COLD = "cold"  #: `lde replay LOG` with only the spec-sheet file
    WARM = "warm"  #: after `lde replay PRIOR --learned S` on an earlier drive of the same car


def plants() -> tuple[str, ...]:
    """The zoo's plant names."""

    return plant_names()


def check_selection(plant_list: Sequence[str], scenarios: Sequence[str], profiles: Sequence[str]) -> None:
    """ConfigError naming what does not exist (before any run starts)."""

    known = plants()
    bad = [p for p in plant_list if p not in known]
    if bad:
        raise ConfigError(f"unknown zoo plant(s) {', '.join(bad)} (plants: {', '.join(known)})")
    bad = [s for s in scenarios if s not in SCENARIOS]
    if bad:
        raise ConfigError(f"unknown scenario(s) {', '.join(bad)} (see lde sim --list)")
    bad = [p for p in profiles if p not in PROFILES]
    if bad:
        raise ConfigError(f"unknown profile(s) {', '.join(bad)} (zoo profiles: {', '.join(PROFILES)})")


def zoo_specs(
    plant_list: Sequence[str] | None = None,
    scenarios: Sequence[str] = ZOO_SCENARIOS,
    profiles: Sequence[str] = PROFILES,
    backends: Sequence[str] = BACKENDS,
    seed: int = 0,
    mode: Mode = Mode.COLD,
    duration: float | None = None,
    work_dir: str = "",
) -> list[RunSpec]:
    """One ``cli`` run per plant x scenario x profile x backend (group = plant name)."""
    names = tuple(plant_list or plants())
    check_selection(names, scenarios, profiles)
    est = EstOptions(learned_prior=PRIOR_SCENARIO) if mode is Mode.WARM else EstOptions()
    return [
        RunSpec(
            scenario=sc,
            est_vehicle=SPEC_SHEET,
            sim_vehicle=f"{ZOO_PREFIX}{plant}",
            seed=seed,
            duration=duration,
            estimator=Estimator.CLI.value,
            backend=be,
            profile=prof,
            est_options=est,
            group=plant,
            work_dir=work_dir,
        )
        for plant in names
        for prof in profiles
        for be in backends
        for sc in scenarios
    ]


def _mode(r: RunResult) -> Mode:
    return Mode.WARM if r.spec.est_options.learned_prior else Mode.COLD


@functools.lru_cache(maxsize=1)
def _true_values() -> dict[str, Any]:

    return read_true_values()


def has_defects(plant: str) -> bool:
    """A plant with rack friction >= 0.4 Nm, an angle offset or a gyro bias (its true values)."""
    tv = _true_values().get(plant)
    if tv is None:
        return False
    return (
        tv.rack_friction_Nm >= DEFECT_FRICTION_NM - 1e-9
        or tv.steer_offset_deg != 0.0
        or tv.yaw_bias_deg_s != 0.0
    )


def target_of(r: RunResult) -> metrics.Target:
    """The issue-11 target a run is held to (cold; warm; warm with defects)."""
    if _mode(r) is Mode.COLD:
        return metrics.COLD
    if r.spec.scenario in HARD_SCENARIOS or has_defects(plant_name(r.spec.sim_vehicle)):
        return metrics.WARM_DEFECTS
    return metrics.WARM


def cell(acc: metrics.Accuracy | None, payload: bool = False) -> str:
    """A table cell: "Fw / Mw" NRMSE in % (Mw about the spec sheet's CG; with ``payload`` the Mw
    about the true CG in brackets), or "Fw N / Mw Nm" RMS on a disturbance-free drive."""
    if acc is None:
        return "failed"
    if acc.kind is metrics.Kind.UNDISTURBED:
        return f"{acc.rms_fw:.0f} N / {acc.rms_mw:.0f} Nm"
    f, m = metrics.target_figures(acc)
    text = f"{100 * f:.1f} / {100 * m:.1f}"
    if payload:
        text += f" ({100 * acc.nrmse_mw:.1f})"
    return text


def _key(r: RunResult) -> tuple[str, str, str, Mode, str]:
    return (plant_name(r.spec.sim_vehicle), r.spec.profile, r.spec.backend, _mode(r), r.spec.scenario)


def _rows(results: Sequence[RunResult]) -> tuple[list[tuple[str, str, str, Mode]], list[str]]:
    keys: list[tuple[str, str, str, Mode]] = []
    scen: list[str] = []
    for r in results:
        k = (plant_name(r.spec.sim_vehicle), r.spec.profile, r.spec.backend, _mode(r))
        if k not in keys:
            keys.append(k)
        if r.spec.scenario not in scen:
            scen.append(r.spec.scenario)
    return keys, scen


def _payload_plants(names: Sequence[str]) -> set[str]:
    tv = _true_values()
    return {n for n in names if n in tv and tv[n].payload_kg > 0.0}


def plant_table_rows(results: Sequence[RunResult]) -> list[dict[str, Any]]:
    """The per-plant table as CSV rows: plant, profile, backend, mode, per scenario the two target
    figures (``<scenario>_fw``, ``<scenario>_mw``: NRMSE fractions, or RMS in N / Nm on a
    disturbance-free drive) and for payload plants Mw about the true CG (``<scenario>_mw_true_cg``),
    and how many runs meet their target."""
    keys, scen = _rows(results)
    by = {_key(r): r for r in results}
    loaded = _payload_plants([k[0] for k in keys])
    rows = []
    for plant, prof, be, mode in keys:
        row: dict[str, Any] = {"plant": plant, "profile": prof, "backend": be, "mode": mode.value}
        met = n = 0
        for sc in scen:
            r = by.get((plant, prof, be, mode, sc))
            if r is None:
                continue
            n += 1
            if r.ok and r.accuracy is not None:
                f, m = metrics.target_figures(r.accuracy)
                row[f"{sc}_fw"], row[f"{sc}_mw"] = f, m
                if plant in loaded and r.accuracy.kind is not metrics.Kind.UNDISTURBED:
                    row[f"{sc}_mw_true_cg"] = r.accuracy.nrmse_mw
                met += metrics.meets(r.accuracy, target_of(r))
            else:
                row[f"{sc}_fw"] = row[f"{sc}_mw"] = math.nan
        row["targets_met"] = met
        row["runs"] = n
        rows.append(row)
    return rows


def plant_table_markdown(results: Sequence[RunResult], backend: str | None = None) -> str:
    """The per-plant table in markdown: a row per plant x profile (x backend unless one is
    chosen), a "Fw / Mw" cell per scenario (NRMSE % with Mw about the spec sheet's CG, payload
    plants with Mw about the true CG in brackets; RMS N / Nm on a disturbance-free drive; **bold**:
    the run misses its target), and the number of runs that meet their target."""
    use = [r for r in results if backend is None or r.spec.backend == backend]
    keys, scen = _rows(use)
    by = {_key(r): r for r in use}
    loaded = _payload_plants([k[0] for k in keys])
    show_be = backend is None and len({k[2] for k in keys}) > 1
    show_mode = len({k[3] for k in keys}) > 1
    head = ["plant", "profile"] + (["backend"] if show_be else []) + (["mode"] if show_mode else [])
    lines = [
        "| " + " | ".join(head + scen + ["met"]) + " |",
        "|" + "---|" * (len(head) + len(scen) + 1),
    ]
    for plant, prof, be, mode in keys:
        row = [plant, prof] + ([be] if show_be else []) + ([mode.value] if show_mode else [])
        met = n = 0
        for sc in scen:
            r = by.get((plant, prof, be, mode, sc))
            if r is None:
                row.append("")
                continue
            n += 1
            ok = r.ok and r.accuracy is not None and metrics.meets(r.accuracy, target_of(r))
            met += ok
            text = cell(r.accuracy if r.ok else None, plant in loaded)
            row.append(text if ok else f"**{text}**")
        row.append(f"{met}/{n}")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def summary_lines(results: Sequence[RunResult]) -> list[str]:
    """One line per target and scenario kind: runs that meet it, and the worst figures (where)."""
    out = []
    groups: dict[tuple[str, bool], list[RunResult]] = {}
    failed = [r for r in results if not r.ok]
    for r in results:
        if r.ok and r.accuracy is not None:
            undisturbed = r.accuracy.kind is metrics.Kind.UNDISTURBED
            groups.setdefault((target_of(r).name, undisturbed), []).append(r)
    targets = {t.name: t for t in (metrics.COLD, metrics.WARM, metrics.WARM_DEFECTS)}
    for (name, undisturbed), rs in sorted(groups.items()):
        t = targets[name]
        met = sum(metrics.meets(r.accuracy, t) for r in rs if r.accuracy is not None)
        worst_f = max(rs, key=lambda r: metrics.target_figures(r.accuracy)[0])  # type: ignore[arg-type]
        worst_m = max(rs, key=lambda r: metrics.target_figures(r.accuracy)[1])  # type: ignore[arg-type]
        wf = metrics.target_figures(worst_f.accuracy)[0]  # type: ignore[arg-type]
        wm = metrics.target_figures(worst_m.accuracy)[1]  # type: ignore[arg-type]
        if undisturbed:
            what = f"disturbance-free drive, RMS <= {t.max_rms_fw:g} N / {t.max_rms_mw:g} Nm"
            worst = f"worst Fw {wf:.0f} N ({_where(worst_f)}), worst Mw {wm:.0f} Nm ({_where(worst_m)})"
        else:
            what = (
                f"crosswind/bank scenarios, NRMSE <= {100 * t.max_nrmse:g} % Fw and Mw "
                "(Mw about the spec sheet's CG)"
            )
            worst = (
                f"worst Fw {100 * wf:.1f} % ({_where(worst_f)}), "
                f"worst Mw {100 * wm:.1f} % ({_where(worst_m)})"
            )
        out.append(f"{name}, {what}: met in {met} of {len(rs)} runs; {worst}")
    if failed:
        out.append(
            f"{len(failed)} run(s) failed or were discarded: "
            + "; ".join(f"{r.spec.label}: {r.error[:80]}" for r in failed[:5])
        )
    return out


def _where(r: RunResult) -> str:
    s = r.spec
    return f"{plant_name(s.sim_vehicle)}, {s.scenario}, {s.profile}, {s.backend}"
