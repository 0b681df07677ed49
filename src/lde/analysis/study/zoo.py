"""The zoo evaluation (issue 11): the estimator on cars it was never fitted to, as a user runs it.

For every plant of :mod:`vcan_sim.zoo` x scenario x profile (``lde``, ``hyundai``) x backend
(``fixed``, ``float``): simulate (seeded), write the log, ``lde replay`` it with only the plant's
spec-sheet vehicle file (:mod:`lde.cli.replay_in_process`), score the CSV against the truth
(:mod:`lde.analysis.metrics`: NRMSE after 2 s; RMS on a disturbance-free drive; Mw about the true CG and
about the spec sheet's CG). Cold: ``lde replay LOG``; warm: after ``lde replay PRIOR --learned S``
on the plant's prior drive with another seed (only a learning backend, ``lateral``, uses it): the
shipped :data:`PRIOR_SCENARIO` by default, or any scenario (``priors``), each reported apart
(:func:`mode_label`: ``warm`` for the default, ``warm after NAME`` otherwise).

A plant that carries a payload is run twice: with its spec sheet (the unloaded car) and with the
spec sheet plus the load (:data:`~lde.analysis.study.spec.SPEC_SHEET_LOADED`: the loaded car's mass, yaw
inertia and CG, what a load signal would give; row label ``PLANT + load``). Every payload cell gives
Mw about both CGs.

Outputs (:func:`plant_table_markdown`, :func:`plant_table_rows`, :func:`summary_lines`): one row per
plant x profile x backend x mode with a "Fw / Mw" cell per scenario, the wind force and bank angle
figures and the learner's state at the end of each run, and one line per target of
:mod:`lde.analysis.metrics` saying in how many runs it is met and where it is missed by most.
"""

from __future__ import annotations

import enum
import functools
import math
from collections.abc import Sequence
from typing import Any

from lde.analysis import metrics
from lde.analysis.study.execute import ZOO_PREFIX, plant_name
from lde.analysis.study.spec import SPEC_SHEET, SPEC_SHEET_LOADED, Estimator, EstOptions, RunResult, RunSpec
from lde.errors import ConfigError
from vcan_sim.scenarios import SCENARIOS
from vcan_sim.zoo import plant_names, read_true_values

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


class Mode(str, enum.Enum):  # noqa: UP042 - str() keeps the "Mode.X" form
    COLD = "cold"  #: `lde replay LOG` with only the spec-sheet file
    WARM = "warm"  #: after `lde replay PRIOR --learned S` on an earlier drive of the same car


def plants() -> tuple[str, ...]:
    """The zoo's plant names."""

    return plant_names()


def check_selection(
    plant_list: Sequence[str],
    scenarios: Sequence[str],
    profiles: Sequence[str],
    priors: Sequence[str] = (PRIOR_SCENARIO,),
) -> None:
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
    bad = [s for s in priors if s not in SCENARIOS]
    if bad:
        raise ConfigError(f"unknown prior scenario(s) {', '.join(bad)} (see lde sim --list)")
    if not priors:
        raise ConfigError("--prior needs at least one scenario")


def zoo_specs(
    plant_list: Sequence[str] | None = None,
    scenarios: Sequence[str] = ZOO_SCENARIOS,
    profiles: Sequence[str] = PROFILES,
    backends: Sequence[str] = BACKENDS,
    seed: int = 0,
    mode: Mode | None = None,
    duration: float | None = None,
    work_dir: str = "",
    modes: Sequence[Mode] = (Mode.COLD,),
    load_signal: bool = True,
    priors: Sequence[str] = (PRIOR_SCENARIO,),
) -> list[RunSpec]:
    """One ``cli`` run per mode x plant x profile x backend x scenario, warm once per prior drive
    in ``priors`` (group = plant name; ``mode`` alone overrides ``modes``). With ``load_signal`` a
    payload plant also runs with the spec sheet plus the load (:data:`SPEC_SHEET_LOADED`)."""
    names = tuple(plant_list or plants())
    priors = tuple(dict.fromkeys(priors))
    check_selection(names, scenarios, profiles, priors)
    loaded = _payload_plants(names) if load_signal else set()
    specs = []
    ests = []
    for m in (mode,) if mode is not None else tuple(modes):
        if m is Mode.WARM:
            ests += [EstOptions(learned_prior=pr) for pr in priors]
        else:
            ests.append(EstOptions())
    for est in ests:
        for plant in names:
            sheets = (SPEC_SHEET, SPEC_SHEET_LOADED) if plant in loaded else (SPEC_SHEET,)
            for sheet in sheets:
                specs += [
                    RunSpec(
                        scenario=sc,
                        est_vehicle=sheet,
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
                    for prof in profiles
                    for be in backends
                    for sc in scenarios
                ]
    return specs


def mode_of(r: RunResult) -> Mode:
    """Cold or warm (warm: the run learned on a prior drive first)."""
    return Mode.WARM if r.spec.est_options.learned_prior else Mode.COLD


def prior_of(r: RunResult) -> str:
    """The prior drive a warm run learned on ("" for a cold run)."""
    return r.spec.est_options.learned_prior or ""


def mode_label(r: RunResult) -> str:
    """``cold``, ``warm`` (after the shipped :data:`PRIOR_SCENARIO`) or ``warm after NAME``."""
    prior = prior_of(r)
    if not prior:
        return Mode.COLD.value
    return Mode.WARM.value if prior == PRIOR_SCENARIO else f"{Mode.WARM.value} after {prior}"


def load_known(r: RunResult) -> bool:
    """The estimator's file carries the load (its CG is the true one)."""
    return r.spec.est_vehicle == SPEC_SHEET_LOADED


def row_label(r: RunResult) -> str:
    """The table's plant label: the plant, ``PLANT + load`` when its file carries the load."""
    name = plant_name(r.spec.sim_vehicle)
    return f"{name} + load" if load_known(r) else name


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
    if mode_of(r) is Mode.COLD:
        return metrics.COLD
    if r.spec.scenario in HARD_SCENARIOS or has_defects(plant_name(r.spec.sim_vehicle)):
        return metrics.WARM_DEFECTS
    return metrics.WARM


def figures(r: RunResult) -> tuple[float, float]:
    """The run's two target figures (:func:`lde.analysis.metrics.target_figures`; Mw about the CG its
    vehicle file states). The run must have an accuracy."""
    assert r.accuracy is not None
    return metrics.target_figures(r.accuracy, load_known(r))


def meets(r: RunResult) -> bool:
    """The run succeeded and meets its target."""
    return r.ok and r.accuracy is not None and metrics.meets(r.accuracy, target_of(r), load_known(r))


def cell(acc: metrics.Accuracy | None, payload: bool = False, file_cg_is_true: bool = False) -> str:
    """A table cell: "Fw / Mw" NRMSE in % (Mw about the CG the vehicle file states; with ``payload``
    Mw about the other CG in brackets: the true CG for a spec sheet, the unloaded car's for a file
    with the load), or "Fw N / Mw Nm" RMS on a disturbance-free drive."""
    if acc is None:
        return "failed"
    if acc.kind is metrics.Kind.UNDISTURBED:
        return f"{acc.rms_fw:.0f} N / {acc.rms_mw:.0f} Nm"
    f, m = metrics.target_figures(acc, file_cg_is_true)
    text = f"{100 * f:.1f} / {100 * m:.1f}"
    if payload:
        other = acc.nrmse_mw_ref if file_cg_is_true else acc.nrmse_mw
        text += f" ({100 * other:.1f})"
    return text


RowKey = tuple[str, str, str, str]


def _row_key(r: RunResult) -> RowKey:
    return (row_label(r), r.spec.profile, r.spec.backend, mode_label(r))


def _rows(results: Sequence[RunResult]) -> tuple[list[RowKey], list[str], dict[RowKey, dict[str, RunResult]]]:
    keys: list[RowKey] = []
    scen: list[str] = []
    by: dict[RowKey, dict[str, RunResult]] = {}
    for r in results:
        k = _row_key(r)
        if k not in by:
            keys.append(k)
            by[k] = {}
        by[k][r.spec.scenario] = r
        if r.spec.scenario not in scen:
            scen.append(r.spec.scenario)
    return keys, scen, by


def _payload_plants(names: Sequence[str]) -> set[str]:
    tv = _true_values()
    return {n for n in names if n in tv and tv[n].payload_kg > 0.0}


def _is_payload(r: RunResult) -> bool:
    return bool(_payload_plants([plant_name(r.spec.sim_vehicle)]))


def _extra(r: RunResult, key: str) -> float:
    v = r.extra.get(key, math.nan) if r.ok else math.nan
    return float(v)


def wind_bank(rs: Sequence[RunResult]) -> dict[str, float]:
    """Over runs: how many have wind (``wind_runs``) and meet the wind-force bound (``wind_met``),
    the worst wind NRMSE; runs with a bank figure (``bank_runs``), within 0.3 deg (``bank_met``),
    the worst bank RMS [deg]."""
    wind = [w for w in (_extra(r, "wind_nrmse") for r in rs) if math.isfinite(w)]
    bank = [b for b in (_extra(r, "bank_rms_deg") for r in rs) if math.isfinite(b)]
    return {
        "wind_met": sum(w <= metrics.WIND_MAX_NRMSE for w in wind),
        "wind_runs": len(wind),
        "wind_worst": max(wind, default=math.nan),
        "bank_met": sum(b <= metrics.BANK_MAX_RMS_DEG for b in bank),
        "bank_runs": len(bank),
        "bank_worst_deg": max(bank, default=math.nan),
    }


def learn_string(rs: Sequence[RunResult | None]) -> str:
    """The learner's state at the end of each run, one character per run in scenario order
    (0 not learned, 1 learning, 2 learned, 3 the backend does not learn, - unknown)."""
    out = []
    for r in rs:
        v = _extra(r, "learn_state") if r is not None else math.nan
        out.append(str(int(v)) if math.isfinite(v) else "-")
    return "".join(out)


def plant_table_rows(results: Sequence[RunResult]) -> list[dict[str, Any]]:
    """The per-plant table as CSV rows: plant (``PLANT + load`` for a file with the load), profile,
    backend, mode, prior, per scenario the two target figures (``<scenario>_fw``, ``<scenario>_mw``: NRMSE
    fractions with Mw about the file's CG, or RMS in N / Nm on a disturbance-free drive), for
    payload plants Mw about the true CG (``<scenario>_mw_true_cg``) and about the unloaded CG
    (``<scenario>_mw_unloaded_cg``), the wind force NRMSE (``<scenario>_wind``), bank RMS
    (``<scenario>_bank_deg``) and learner state at the end (``<scenario>_learn_state``); per row how
    many runs meet their target, the wind and bank counts (:func:`wind_bank`) and the learn string.
    ``prior``: the drive a warm row learned on ("" cold)."""
    keys, scen, by = _rows(results)
    rows = []
    for key in keys:
        plant, prof, be, _ = key
        runs = [by[key].get(sc) for sc in scen]
        first = next(r for r in runs if r is not None)
        row: dict[str, Any] = {
            "plant": plant,
            "profile": prof,
            "backend": be,
            "mode": mode_of(first).value,
            "prior": prior_of(first),
        }
        met = n = 0
        for sc, r in zip(scen, runs, strict=True):
            if r is None:
                continue
            n += 1
            if r.ok and r.accuracy is not None:
                row[f"{sc}_fw"], row[f"{sc}_mw"] = figures(r)
                if _is_payload(r) and r.accuracy.kind is not metrics.Kind.UNDISTURBED:
                    row[f"{sc}_mw_true_cg"] = r.accuracy.nrmse_mw
                    row[f"{sc}_mw_unloaded_cg"] = r.accuracy.nrmse_mw_ref
                met += meets(r)
            else:
                row[f"{sc}_fw"] = row[f"{sc}_mw"] = math.nan
            row[f"{sc}_wind"] = _extra(r, "wind_nrmse")
            row[f"{sc}_bank_deg"] = _extra(r, "bank_rms_deg")
            row[f"{sc}_learn_state"] = _extra(r, "learn_state")
        row["targets_met"] = met
        row["runs"] = n
        row.update(wind_bank([r for r in runs if r is not None]))
        row["learn_states"] = learn_string(runs)
        rows.append(row)
    return rows


def _count(met: float, n: float, worst: str) -> str:
    return "-" if not n else f"{met:.0f}/{n:.0f} ({worst})"


def plant_table_markdown(
    results: Sequence[RunResult], backend: str | None = None, extras: bool = True
) -> str:
    """The per-plant table in markdown: a row per plant x profile (x backend, x mode where there are
    several), a "Fw / Mw" cell per scenario (NRMSE % with Mw about the file's CG, payload plants
    with Mw about the other CG in brackets; RMS N / Nm on a disturbance-free drive; **bold**: the run
    misses its target), the number of runs that meet their target and with ``extras`` the wind
    force (runs within 10 %, worst), the bank angle (runs within 0.3 deg, worst) and the learner's
    state at the end of each run (:func:`learn_string`)."""
    use = [r for r in results if backend is None or r.spec.backend == backend]
    keys, scen, by = _rows(use)
    show_be = backend is None and len({k[2] for k in keys}) > 1
    show_mode = len({k[3] for k in keys}) > 1
    head = ["plant", "profile"] + (["backend"] if show_be else []) + (["mode"] if show_mode else [])
    tail = ["met"] + (["wind <= 10 %", "bank <= 0.3 deg", "learn state"] if extras else [])
    lines = [
        "| " + " | ".join(head + scen + tail) + " |",
        "|" + "---|" * (len(head) + len(scen) + len(tail)),
    ]
    for key in keys:
        plant, prof, be, mode = key
        row = [plant, prof] + ([be] if show_be else []) + ([mode] if show_mode else [])
        runs = [by[key].get(sc) for sc in scen]
        met = n = 0
        for r in runs:
            if r is None:
                row.append("")
                continue
            n += 1
            ok = meets(r)
            met += ok
            text = cell(r.accuracy if r.ok else None, _is_payload(r), load_known(r))
            row.append(text if ok else f"**{text}**")
        row.append(f"{met}/{n}")
        if extras:
            wb = wind_bank([r for r in runs if r is not None])
            row.append(_count(wb["wind_met"], wb["wind_runs"], f"{100 * wb['wind_worst']:.1f} %"))
            row.append(_count(wb["bank_met"], wb["bank_runs"], f"{wb['bank_worst_deg']:.2f} deg"))
            row.append(f"`{learn_string(runs)}`")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def summary_lines(results: Sequence[RunResult]) -> list[str]:
    """One line per target and scenario kind (runs on a spec sheet; a file with the load is
    reported by :func:`payload_lines`): runs that meet it and the worst figures (where); per mode
    the wind force and the bank angle; failed runs."""
    out = []
    groups: dict[tuple[str, int, str, bool], list[RunResult]] = {}
    failed = [r for r in results if not r.ok]
    order = {metrics.COLD.name: 0, metrics.WARM.name: 1, metrics.WARM_DEFECTS.name: 2}
    for r in results:
        if r.ok and r.accuracy is not None and not load_known(r):
            undisturbed = r.accuracy.kind is metrics.Kind.UNDISTURBED
            name = target_of(r).name
            groups.setdefault((_prior_sort(r), order[name], name, undisturbed), []).append(r)
    targets = {t.name: t for t in (metrics.COLD, metrics.WARM, metrics.WARM_DEFECTS)}
    for (prior, _, name, undisturbed), rs in sorted(groups.items()):
        t = targets[name]
        met = sum(meets(r) for r in rs)
        worst_f = max(rs, key=lambda r: figures(r)[0])
        worst_m = max(rs, key=lambda r: figures(r)[1])
        wf, wm = figures(worst_f)[0], figures(worst_m)[1]
        if undisturbed:
            what = f"disturbance-free drive, RMS <= {t.max_rms_fw:g} N / {t.max_rms_mw:g} Nm"
            worst = f"worst Fw {wf:.0f} N ({_where(worst_f)}), worst Mw {wm:.0f} Nm ({_where(worst_m)})"
        else:
            what = (
                f"crosswind/bank scenarios, NRMSE <= {100 * t.max_nrmse:g} % Fw and Mw "
                "(Mw about the spec sheet's CG)"
            )
            fs = [figures(r) for r in rs]
            worst = (
                f"mean Fw {100 * _mean(f for f, _ in fs):.1f} %, Mw {100 * _mean(m for _, m in fs):.1f} %; "
                f"worst Fw {100 * wf:.1f} % ({_where(worst_f)}), "
                f"worst Mw {100 * wm:.1f} % ({_where(worst_m)})"
            )
        after = f" after {prior[1:]}" if prior else ""
        out.append(f"{name}{after}, {what}: met in {met} of {len(rs)} runs; {worst}")
    for mode in _labels(results):
        rs = [r for r in results if r.ok and mode_label(r) == mode and not load_known(r)]
        if not rs:
            continue
        wb = wind_bank(rs)
        if wb["wind_runs"]:
            out.append(
                f"{mode}, wind force NRMSE <= {100 * metrics.WIND_MAX_NRMSE:g} % (runs with wind): "
                f"met in {wb['wind_met']:.0f} of {wb['wind_runs']:.0f} runs; "
                f"worst {100 * wb['wind_worst']:.1f} %"
            )
        if wb["bank_runs"]:
            out.append(
                f"{mode}, bank angle RMS <= {metrics.BANK_MAX_RMS_DEG:g} deg: "
                f"met in {wb['bank_met']:.0f} of {wb['bank_runs']:.0f} runs; "
                f"worst {wb['bank_worst_deg']:.2f} deg"
            )
    if failed:
        out.append(
            f"{len(failed)} run(s) failed or were discarded: "
            + "; ".join(f"{r.spec.label}: {r.error[:80]}" for r in failed[:5])
        )
    return out


def payload_lines(results: Sequence[RunResult]) -> list[str]:
    """Per mode and payload plant: mean Mw NRMSE over its crosswind/bank runs about the unloaded
    CG and about the true CG, with the spec sheet and with the spec sheet plus the load."""
    out = []
    for mode in _labels(results):
        for plant in dict.fromkeys(plant_name(r.spec.sim_vehicle) for r in results if _is_payload(r)):
            rs = [
                r
                for r in results
                if r.ok
                and r.accuracy is not None
                and r.accuracy.kind is not metrics.Kind.UNDISTURBED
                and mode_label(r) == mode
                and plant_name(r.spec.sim_vehicle) == plant
            ]
            parts = []
            for known, what in ((False, "spec sheet"), (True, "spec sheet + load")):
                sel = [r.accuracy for r in rs if load_known(r) is known and r.accuracy is not None]
                if sel:
                    parts.append(
                        f"{what}: Fw {100 * _mean(a.nrmse_fw for a in sel):.1f} %, Mw about the unloaded CG "
                        f"{100 * _mean(a.nrmse_mw_ref for a in sel):.1f} %, about the true CG "
                        f"{100 * _mean(a.nrmse_mw for a in sel):.1f} % ({len(sel)} runs)"
                    )
            if parts:
                out.append(f"{mode}, payload {plant} (mean NRMSE): " + "; ".join(parts))
    return out


def backend_lines(results: Sequence[RunResult]) -> list[str]:
    """Per pair of backends run on the same drives: the largest difference in any run's RMS error
    of Fw [N] and Mw [Nm], and in how many runs one meets its target and the other does not."""
    by: dict[tuple[Any, ...], dict[str, RunResult]] = {}
    for r in results:
        if r.ok and r.accuracy is not None:
            s = r.spec
            key = (row_label(r), s.profile, mode_label(r), s.scenario, s.seed)
            by.setdefault(key, {})[s.backend] = r
    backends = list(dict.fromkeys(r.spec.backend for r in results))
    out = []
    for i, a in enumerate(backends):
        for b in backends[i + 1 :]:
            pairs = [(v[a], v[b]) for v in by.values() if a in v and b in v]
            if not pairs:
                continue
            df = max(abs(x.accuracy.rms_fw - y.accuracy.rms_fw) for x, y in pairs)  # type: ignore[union-attr]
            dm = max(abs(x.accuracy.rms_mw - y.accuracy.rms_mw) for x, y in pairs)  # type: ignore[union-attr]
            split = sum(meets(x) != meets(y) for x, y in pairs)
            out.append(
                f"backends {a} and {b}: any run's RMS error differs by at most {df:.3g} N (Fw) and "
                f"{dm:.3g} Nm (Mw) over {len(pairs)} pairs of runs; the target verdict differs in {split}"
            )
    return out


def _prior_sort(r: RunResult) -> str:
    """Sorts the shipped prior (and cold) first: "" for them, "~NAME" after another prior."""
    prior = prior_of(r)
    return "" if prior in ("", PRIOR_SCENARIO) else f"~{prior}"


def mode_order(r: RunResult) -> tuple[int, str]:
    """Sort key of a run's mode: cold, warm (the shipped prior), then warm after other priors."""
    return (0 if mode_of(r) is Mode.COLD else 1, _prior_sort(r))


def _labels(results: Sequence[RunResult]) -> list[str]:
    """The mode labels present, in :func:`mode_order`."""
    return list(dict.fromkeys(mode_label(r) for r in sorted(results, key=mode_order)))


def _mean(xs: Any) -> float:
    v = [float(x) for x in xs if math.isfinite(float(x))]
    return sum(v) / len(v) if v else math.nan


def _where(r: RunResult) -> str:
    s = r.spec
    return f"{row_label(r)}, {s.scenario}, {s.profile}, {s.backend}"
