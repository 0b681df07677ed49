"""Named studies: the specs of the paper's study, ``lde evaluate``'s accuracy set, the improvement
ladder and the friction / offset cases (``lde study --preset``).

The paper's study (section 5): load cases that vary mass, yaw inertia and CG (Fig. 9; CG from wheel
loads by eqs. 17-18, done in the simulator's payload cases), each candidate set of Table 1 as the
estimator's nominal parameters, and the eq. (19) error index ``J = q1 RMS(e_F) + q2 RMS(e_M)``
(weights in :mod:`lde.analysis.metrics`) averaged over the load cases. The set with the smallest mean J wins
(:func:`lde.analysis.study.tables.rank_candidates`). The zoo evaluation's specs are in
:mod:`lde.analysis.study.zoo`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from lde.analysis.study.spec import EstOptions, RunSpec, SimOptions
from lde.errors import ConfigError
from vcan_sim.payload import PAYLOADS

#: no simulator / estimator options (the vehicle files as they are)
NO_SIM_OPTIONS = SimOptions()
NO_EST_OPTIONS = EstOptions()
#: Table 1 candidate sets (shipped vehicle files; est2 with the erratum-6 lr)
CANDIDATES = ("est1", "est2", "est3", "est4", "est5")
#: the paper's two lateral-load scenarios (section 5 / Figs. 13-14)
PAPER_SCENARIOS = ("heavy_load", "light_load")
#: the accuracy set of ``lde evaluate`` (simulator scenario names)
EVALUATE_SCENARIOS = (
    "heavy_load",
    "light_load",
    "payload_full",
    "payload_trunk",
    "payload_four",
    "payload_left",
    "bank_transition",
    "steady_wind",
    "lane_change",
)
#: scenarios of the accuracy target (issue 6, item 3)
TARGET_SCENARIOS = (
    "heavy_load",
    "light_load",
    "payload_full",
    "payload_trunk",
    "payload_four",
    "payload_left",
    "lane_change",
)


def candidate_specs(
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    payloads: Sequence[str] = ("none",),
    candidates: Sequence[str] = CANDIDATES,
    seeds: Sequence[int] = (0,),
    duration: float | None = None,
    sim_options: SimOptions = NO_SIM_OPTIONS,
    estimator: str = "replay",
    est_options: EstOptions = NO_EST_OPTIONS,
    group: str = "candidates",
    trace_candidate: str | None = None,
    backend: str = "float",
    profile: str = "lde",
) -> list[RunSpec]:
    """The paper's study: every candidate set on every (scenario, payload, seed) load case.

    ``trace_candidate``: keep traces of this candidate's unloaded seed-0 runs (Figs. 13-14).
    """
    return [
        RunSpec(
            scenario=sc,
            est_vehicle=cand,
            payload=pl,
            seed=seed,
            duration=duration,
            estimator=estimator,
            backend=backend,
            profile=profile,
            sim_options=sim_options,
            est_options=est_options,
            group=group,
            trace=(cand == trace_candidate and seed == seeds[0] and pl == payloads[0]),
        )
        for cand in candidates
        for sc in scenarios
        for pl in payloads
        for seed in seeds
    ]


def all_payloads() -> tuple[str, ...]:
    """The simulator's payload case names (``vcan_sim.payload.PAYLOADS``)."""
    return tuple(PAYLOADS)


def evaluation_specs(
    scenarios: Sequence[str] = EVALUATE_SCENARIOS,
    payloads: Sequence[str] = ("",),
    est_vehicle: str = "reference",
    sim_vehicle: str = "reference",
    seed: int = 0,
    duration: float | None = None,
    estimator: str = "replay",
    backend: str = "float",
    sim_options: SimOptions = NO_SIM_OPTIONS,
    est_options: EstOptions = NO_EST_OPTIONS,
    trace: bool = False,
    group: str = "evaluate",
    profile: str = "lde",
) -> list[RunSpec]:
    """One run per (scenario, payload) with one estimator vehicle (``lde evaluate``)."""
    return [
        RunSpec(
            scenario=sc,
            est_vehicle=est_vehicle,
            sim_vehicle=sim_vehicle,
            payload=pl,
            seed=seed,
            duration=duration,
            estimator=estimator,
            backend=backend,
            sim_options=sim_options,
            est_options=est_options,
            group=group,
            trace=trace,
            profile=profile,
        )
        for sc in scenarios
        for pl in payloads
    ]


def preset_specs(
    preset: str,
    seeds: Sequence[int] = (0, 1),
    candidates: Sequence[str] | None = None,
    scenarios: Sequence[str] | None = None,
    payloads: Sequence[str] | None = None,
    duration: float | None = None,
    estimator: str = "replay",
    backend: str = "float",
    sim_options: SimOptions = NO_SIM_OPTIONS,
    est_options: EstOptions = NO_EST_OPTIONS,
    profile: str = "lde",
) -> list[RunSpec]:
    """The specs of a named study (``lde study --preset``); None arguments take the preset's values.

    ``paper``: candidates x (heavy, light) x every payload x seeds (5 x 2 x 6 x 2 = 120 runs by
    default), traces of the unloaded runs of ``est3``. ``smoke``: est1/est3 x heavy/light, unloaded,
    one seed, 6 s (4 runs).
    """
    if preset == "paper":
        cands = tuple(candidates or CANDIDATES)
        return candidate_specs(
            scenarios=tuple(scenarios or PAPER_SCENARIOS),
            payloads=tuple(payloads or all_payloads()),
            candidates=cands,
            seeds=tuple(seeds),
            duration=duration,
            sim_options=sim_options,
            estimator=estimator,
            est_options=est_options,
            trace_candidate=next((c for c in cands if Path(c).stem.startswith("est3")), cands[0]),
            backend=backend,
            profile=profile,
        )
    if preset == "smoke":
        cands = tuple(candidates or ("est1", "est3"))
        return candidate_specs(
            scenarios=tuple(scenarios or PAPER_SCENARIOS),
            payloads=tuple(payloads or ("none",)),
            candidates=cands,
            seeds=tuple(seeds)[:1],
            duration=duration or 6.0,
            sim_options=sim_options,
            estimator=estimator,
            est_options=est_options,
            trace_candidate=cands[-1],
            backend=backend,
            profile=profile,
        )
    raise ConfigError(f"unknown study preset {preset!r} (known: paper, smoke)")


# --- the improvement ladder and the friction / offset study ---------------------------------------


def ladder_specs(
    winner: str,
    tire_vehicle: str,
    seeds: Sequence[int] = (0, 1),
    scenarios: Sequence[str] = TARGET_SCENARIOS,
    duration: float | None = None,
    winner_calibrated: str | None = None,
    curvature: tuple[float, float, float] | None = None,
) -> list[RunSpec]:
    """What each step buys, measured: the same scenarios under successive estimator versions.

    ``winner``: the Table 1 set chosen for the step as is; ``winner_calibrated``: the set chosen
    for the calibrated estimator (its mass sets the force scale of the calibration), default
    ``winner``; ``curvature``: (kappa_f, kappa_r, kappa_K) of
    :func:`lde.analysis.study.tires.identify_curvature` adds step 7.
    """
    wc = winner_calibrated or winner
    cal = EstOptions(calibrate="lane_change")
    loaded = EstOptions(calibrate="lane_change", payload_known=True)
    steps: list[tuple[str, dict[str, Any]]] = [
        ("0 reference", dict(est_vehicle="reference")),
        ("1 reference + lde calibrate", dict(est_vehicle="reference", est_options=cal)),
        (f"2 {Path(winner).stem} (Table 1 winner)", dict(est_vehicle=winner)),
        ("3 + Fig. 12 tires", dict(est_vehicle=tire_vehicle)),
        (f"4 {Path(wc).stem} + lde calibrate", dict(est_vehicle=wc, est_options=cal)),
        ("5 + load-scheduled m, Iz, CG", dict(est_vehicle=wc, estimator="adaptive", est_options=loaded)),
        (
            "6 + lateral acceleration (wind vs bank)",
            dict(est_vehicle=wc, estimator="adaptive", est_options=replace(loaded, lat_accel=True)),
        ),
    ]
    if curvature is not None:
        kf, kr, kk = (round(c, 1) for c in curvature)
        final = replace(loaded, lat_accel=True, kappa_f=kf, kappa_r=kr, kappa_k=kk)
        steps.append(
            ("7 + slip-scheduled secant tires", dict(est_vehicle=wc, estimator="adaptive", est_options=final))
        )
    return [
        RunSpec(scenario=sc, seed=seed, duration=duration, group=label, trace=(seed == seeds[0]), **kw)
        for label, kw in steps
        for sc in scenarios
        for seed in seeds
    ]


#: the friction / sensor-offset cases of the simulator (issue 6, item 5)
FAULT_CASES: tuple[tuple[str, SimOptions], ...] = (
    ("friction 0.35 Nm", SimOptions(friction_Nm=0.35)),
    ("friction 0.8 Nm", SimOptions(friction_Nm=0.8)),
    ("angle offset 1 deg", SimOptions(steer_offset_deg=1.0)),
    ("yaw-rate bias 0.2 deg/s", SimOptions(yaw_bias_deg_s=0.2)),
)


def fault_specs(
    winner: str,
    tire_vehicle: str,
    seeds: Sequence[int] = (0, 1),
    scenarios: Sequence[str] = ("light_load", "lane_change"),
    duration: float | None = None,
    winner_calibrated: str | None = None,
    curvature: tuple[float, float, float] | None = None,
) -> list[RunSpec]:
    """Friction and sensor offsets in the simulator, with the product estimator (``lde replay``)
    and the reference file, as shipped and with what ``lde calibrate`` writes from an undisturbed
    drive of the same car with the same fault: the input corrections alone (the file's tires
    kept) and the corrections with the calibrated tires. ``winner``, ``tire_vehicle``,
    ``winner_calibrated`` and ``curvature`` are accepted for the preset's common signature."""
    del winner, tire_vehicle, winner_calibrated, curvature
    estimators = (
        ("not compensated", EstOptions()),
        ("learned corrections", EstOptions(calibrate="lane_change", calibrate_tires=False)),
        ("learned corrections and tires", EstOptions(calibrate="lane_change")),
    )
    return [
        RunSpec(
            scenario=sc,
            seed=seed,
            duration=duration,
            sim_options=sim_opts,
            group=f"{case} / {est_label}",
            est_vehicle="reference",
            est_options=est_opts,
        )
        for case, sim_opts in FAULT_CASES
        for est_label, est_opts in estimators
        for sc in scenarios
        for seed in seeds
    ]
