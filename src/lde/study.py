"""Parameter studies on Dask (issue 6, items 2 and 6): run specs -> futures -> CSV + PNG.

A study is a list of :class:`RunSpec` (scenario, seed, simulated vehicle + payload, estimator
vehicle, options). Each spec runs independently on a worker (:func:`run_one`: simulate with
:mod:`vcan_sim`, estimate with :func:`lde.replay.replay` or a prototype estimator, score with
:mod:`lde.metrics`) and returns a :class:`RunResult`. :func:`run_specs` maps the specs on a
``dask.distributed`` cluster — a ``LocalCluster(n_workers=2, threads_per_worker=1)`` by default or
an existing scheduler by address — with a tqdm progress bar fed by ``distributed.as_completed``.
Results are plain rows (dicts) written with the csv module; plots use matplotlib's Agg backend.

The paper's study (section 5): load cases that vary mass, yaw inertia and CG (Fig. 9; CG from wheel
loads by eqs. 17-18, done in the simulator's payload cases), each candidate set of Table 1 as the
estimator's nominal parameters, and the eq. (19) error index
``J = q1 RMS(e_F) + q2 RMS(e_M)`` (weights in :mod:`lde.metrics`) averaged over the load cases.
The set with the smallest mean J wins (:func:`rank_candidates`).

A run that fails is a row with its error message (a sweep must survive one bad case); the CLI
exits non-zero when any row failed.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from . import metrics
from .errors import ConfigError, LdeError
from .params import CORRECTION_KEYS, with_corrections
from .units import DEG

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
#: trace decimation: keep every n-th estimator step in returned traces (3.9 ms * 8 = 31 ms)
TRACE_DECIMATION = 8

OptionValue = float | int | str | bool


@dataclass(frozen=True)
class RunSpec:
    """One simulation + estimation run.

    Attributes:
        scenario: a :mod:`vcan_sim` scenario name (``lde sim --list``).
        est_vehicle: the estimator's vehicle file (shipped name or path).
        sim_vehicle: the simulated vehicle (shipped name or path).
        payload: the simulator's payload case name ("none" = unloaded; "": the scenario's own).
        seed: the simulator's random seed.
        duration: simulated time [s] (None: the scenario's own length).
        estimator: "replay" (the product pipeline, :func:`lde.replay.replay`) or "adaptive"
            (the prototype in :mod:`lde.adaptive`).
        backend: replay backend ("float" or "fixed").
        profile: CAN profile name.
        sim_options: extra simulator options as (name, value) pairs (e.g. steering friction,
            sensor offsets), passed as keyword arguments to ``vcan_sim.simulate``.
        est_options: estimator options as (name, value) pairs (prototype estimator only).
        group: a free label used to group rows in summaries and plots.
        trace: return decimated traces (estimate and truth) for plots.
    """

    scenario: str
    est_vehicle: str = "reference"
    sim_vehicle: str = "reference"
    payload: str = ""
    seed: int = 0
    duration: float | None = None
    estimator: str = "replay"
    backend: str = "float"
    profile: str = "lde"
    sim_options: tuple[tuple[str, OptionValue], ...] = ()
    est_options: tuple[tuple[str, OptionValue], ...] = ()
    group: str = ""
    trace: bool = False

    @property
    def label(self) -> str:
        """A short human-readable id of the run."""
        parts = [self.scenario, self.payload or "-", self.est_vehicle, f"s{self.seed}"]
        parts += [f"{k}={v}" for k, v in self.sim_options + self.est_options]
        return "/".join(parts)


@dataclass
class RunResult:
    """What a worker sends back: the spec, the accuracy (None on failure) and optional traces."""

    spec: RunSpec
    accuracy: metrics.Accuracy | None
    error: str = ""
    elapsed_s: float = 0.0
    extra: dict[str, float] = field(default_factory=dict)
    trace: dict[str, np.ndarray] | None = None

    @property
    def ok(self) -> bool:
        return self.accuracy is not None and not self.error

    def as_row(self) -> dict[str, Any]:
        """A flat CSV row: spec fields, accuracy figures, extra figures, error text."""
        s = asdict(self.spec)
        s.pop("trace")
        s["sim_options"] = ";".join(f"{k}={v}" for k, v in self.spec.sim_options)
        s["est_options"] = ";".join(f"{k}={v}" for k, v in self.spec.est_options)
        s["duration"] = "" if self.spec.duration is None else self.spec.duration
        if self.accuracy is not None:
            s.update(self.accuracy.as_row())
        s.update(self.extra)
        s["elapsed_s"] = round(self.elapsed_s, 3)
        s["error"] = self.error
        return s


# --- one run (executes on a worker) ---------------------------------------------------------------


Engine = Callable[[RunSpec], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, metrics.Truth]]


#: simulator options of a RunSpec: name -> (SimParams section, field, factor to SI)
SIM_OPTIONS: dict[str, tuple[str, str, float]] = {
    "friction_Nm": ("steering", "rack_coulomb", 1.0),
    "steer_offset_deg": ("sensors", "steering_angle_bias", DEG),
    "yaw_bias_deg_s": ("sensors", "yaw_rate_bias", DEG),
    "column_torque_bias_Nm": ("sensors", "column_torque_bias", 1.0),
    "lat_accel_bias": ("sensors", "lat_accel_bias", 1.0),
}
#: estimator options. Both estimators: the vehicle file's [corrections] keys (CORRECTION_KEYS);
#: calibrate = a scenario name: identify tires and input corrections on that (undisturbed)
#: scenario with the same simulated vehicle, payload and options (seed + 1000), as `lde calibrate`
#: does, then estimate with them; calibrate_tires = 0 to keep the file's tires (corrections only);
#: torsion (below). The "adaptive" estimator (lde.adaptive) also takes ADAPTIVE_OPTIONS:
#: payload_known = 1: the estimator's mass, yaw inertia and CG are the loaded vehicle's (what a
#: wheel-load or mass signal would give through eqs. 17-18) instead of the vehicle file's;
#: torsion = 0/1: torsion-bar term in the calibration (default: only when the profile's angle is the
#: steering-wheel angle, i.e. not on `lde`, whose angle is the MDPS's pinion angle);
#: lat_accel = 1: the 5-state filter with a_y (q_fa_factor scales its wind random walk);
#: kappa_f, kappa_r, kappa_k: slip-scheduled secant tire parameters [1/rad^2].
ADAPTIVE_OPTIONS = ("payload_known", "lat_accel", "q_fa_factor", "kappa_f", "kappa_r", "kappa_k")
CALIBRATION_SEED_OFFSET = 1000


def _sim_params(vehicle: Any, options: dict[str, OptionValue]) -> Any:
    from vcan_sim.config import sim_params_from_vehicle

    sp = sim_params_from_vehicle(vehicle)
    for key, value in options.items():
        if key == "speed_kmh":
            continue
        if key not in SIM_OPTIONS:
            raise ConfigError(
                f"unknown simulator option {key!r} (known: speed_kmh, {', '.join(SIM_OPTIONS)})"
            )
        section, attr, factor = SIM_OPTIONS[key]
        sub = replace(getattr(sp, section), **{attr: float(value) * factor})
        sp = replace(sp, **{section: sub})
    return sp


def _simulate(spec: RunSpec, scenario: str, seed: int) -> Any:
    try:
        from vcan_sim.run import scenario_with, simulate
    except ImportError as exc:
        raise LdeError("the simulator package vcan_sim is not importable") from exc
    from vcan_sim.scenarios import get_scenario

    from .params import load_vehicle

    opts = dict(spec.sim_options)
    vehicle = load_vehicle(spec.sim_vehicle)
    # the calibration drive carries the same payload as the run (learned while driving undisturbed)
    payload = spec.payload or get_scenario(spec.scenario).payload
    sc = scenario_with(scenario, payload=payload)
    speed = opts.get("speed_kmh")
    return simulate(
        sc,
        vehicle,
        profile=spec.profile,
        seed=seed,
        duration=spec.duration if scenario == spec.scenario else None,
        sim_params=_sim_params(vehicle, opts),
        speed_kmh=None if speed is None else float(speed),
    )


def simulate_and_estimate(
    spec: RunSpec,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, metrics.Truth]:
    """The product engine: :mod:`vcan_sim` -> CAN frames -> estimator. Returns t [s], Fw_hat [N],
    Mw_hat [Nm], VALID mask, truth (Fw, Mw about the actual CG, Mw_ref about the unloaded CG)."""
    from .params import load_vehicle
    from .profiles import load_profile
    from .step import Status

    sim = _simulate(spec, spec.scenario, spec.seed)
    _check_plant(sim.truth)
    vehicle = load_vehicle(spec.est_vehicle)
    profile = load_profile(spec.profile)
    if spec.estimator not in ("replay", "adaptive"):
        raise ConfigError(f"unknown estimator {spec.estimator!r} (replay or adaptive)")
    opts = dict(spec.est_options)
    cal_scenario = opts.pop("calibrate", None)
    cal_tires = bool(opts.pop("calibrate_tires", 1))
    # the `lde` profile's angle is the MDPS's motor-side (pinion) angle: no torsion-bar twist in it
    use_torsion = bool(opts.pop("torsion", spec.profile != "lde"))
    if opts.pop("payload_known", 0):
        if spec.estimator != "adaptive":
            raise ConfigError("estimator option payload_known needs --estimator adaptive")
        # scheduled on the measured load: mass, Iz and CG from the wheel loads (eqs. 17-18)
        b = sim.body
        vehicle = vehicle.with_body(mass=b.mass, yaw_inertia=b.yaw_inertia, lf=b.lf, lr=b.lr)
    cal = None
    if cal_scenario:
        # what `lde calibrate` writes: tires and input corrections identified on an undisturbed drive
        cal = _calibrate_on(spec, str(cal_scenario), vehicle, profile, identify_torsion=use_torsion)
        vehicle = replace(vehicle, corrections=cal.corrections())
        if cal_tires:
            vehicle = _with_tires(vehicle, cal.cf, cal.cr, cal.align_rate)
    corr = {k: opts.pop(k) for k in list(opts) if k in CORRECTION_KEYS}
    if corr:
        vehicle = with_corrections(vehicle, corr, "estimator options")
    if spec.estimator == "replay":
        from .replay import replay

        if opts:
            raise ConfigError(f"estimator options {sorted(opts)} need --estimator adaptive")
        out = replay(sim.frames, profile, vehicle, spec.backend)
        t_ns, fw, mw, status = out.t_ns, out.fw, out.mw, out.status
    else:
        from . import adaptive

        use_ay = bool(opts.pop("lat_accel", 0))
        ay_kw: dict[str, Any] = {}
        if "q_fa_factor" in opts:
            ay_kw["q_fa_factor"] = float(opts.pop("q_fa_factor"))
        if "kappa_f" in opts or "kappa_r" in opts or "kappa_k" in opts:
            ay_kw["curvature"] = tuple(float(opts.pop(k, 0.0)) for k in ("kappa_f", "kappa_r", "kappa_k"))
        if opts:
            raise ConfigError(
                f"unknown estimator option(s) {sorted(opts)} (known: {', '.join(sorted(ADAPTIVE_OPTIONS))} "
                f"and the vehicle file's [corrections] keys {', '.join(CORRECTION_KEYS)})"
            )
        grid = adaptive.grid_from_frames(sim.frames, profile)
        if use_ay:
            t_ns, fw, mw, ok = adaptive.augmented_estimate(
                grid, vehicle, accel_scale=cal.accel_scale if cal is not None else 1.0, **ay_kw
            )
            status = np.where(ok, int(Status.VALID), 0)
        else:
            from .replay import replay

            est = replay(sim.frames, profile, vehicle, "float")  # the product's data path (float)
            t_ns, fw, mw, status = est.t_ns, est.fw, est.mw, est.status

    valid = (np.asarray(status) & int(Status.VALID)) != 0
    tr = sim.truth
    truth = metrics.Truth(t=np.asarray(tr["t"]), fw=tr["Fw"], mw=tr["Mw"], mw_ref=tr["Mw_ref"])
    return np.asarray(t_ns, dtype=np.float64) * 1e-9, fw, mw, valid, truth


#: a run whose simulated driver needs more steering than this lost control [rad]
MAX_STEERING_WHEEL = 180.0 * DEG


def _check_plant(truth: dict[str, np.ndarray]) -> None:
    """Reject a run in which the simulated car left the straight-driving domain (a spin)."""
    dsw = float(np.max(np.abs(truth["delta_sw"])))
    vx = np.asarray(truth["vx"])
    if dsw > MAX_STEERING_WHEEL or float(vx.min()) < 0.5 * float(vx[0]):
        raise LdeError(
            f"the simulated vehicle lost control (|steering wheel| up to {dsw / DEG:.0f} deg, "
            f"speed down to {float(vx.min()):.1f} m/s): not a straight-driving case, run discarded"
        )


def _calibrate_on(
    spec: RunSpec, scenario: str, vehicle: Any, profile: Any, identify_torsion: bool = True
) -> Any:
    """Calibrate on an undisturbed drive of the same simulated car (another seed), as
    ``lde calibrate`` does (friction only where the profile's steering rate is signed)."""
    from . import adaptive
    from .calibrate import calibrate

    cal_sim = _simulate(spec, scenario, spec.seed + CALIBRATION_SEED_OFFSET)
    grid = adaptive.grid_from_frames(cal_sim.frames, profile)
    return calibrate(
        adaptive.drive_from_grid(grid),
        vehicle,
        identify_torsion=identify_torsion,
        identify_friction=profile.steering_rate_signed,
    )


def _with_tires(vehicle: Any, cf: float, cr: float, k: float) -> Any:
    from dataclasses import replace

    return replace(vehicle, tires=replace(vehicle.tires, cf=cf, cr=cr, align_rate=k))


def run_one(spec: RunSpec, engine: Engine | None = None) -> RunResult:
    """Run one spec and score it; any failure becomes ``RunResult.error`` (never raised)."""
    t0 = time.perf_counter()
    eng = engine or simulate_and_estimate
    try:
        t, fw_hat, mw_hat, valid, truth = eng(spec)
        acc = metrics.accuracy(t, fw_hat, mw_hat, truth, valid=valid)
    except Exception as exc:  # a sweep must survive one bad case: the error is reported per row
        return RunResult(spec, None, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)
    trace = None
    if spec.trace:
        fw, mw, mw_ref = metrics.truth_at(truth, t)
        sl = slice(None, None, TRACE_DECIMATION)
        trace = {
            "t": t[sl] - t[0],
            "fw_hat": fw_hat[sl],
            "mw_hat": mw_hat[sl],
            "fw": fw[sl],
            "mw": mw[sl],
            "mw_ref": mw_ref[sl],
        }
    return RunResult(spec, acc, "", time.perf_counter() - t0, trace=trace)


def synthetic_engine(spec: RunSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, metrics.Truth]:
    """A plumbing-test engine (no simulator): a disturbance step and a lagged, noisy estimate.

    The estimate's moment error grows with the estimator's CG error ``|lf_est - 1.071 m|`` so that
    candidate rankings are deterministic; used by the tests of the Dask machinery only.
    """
    from .params import load_vehicle

    v = load_vehicle(spec.est_vehicle)
    rng = np.random.default_rng(spec.seed)
    dur = spec.duration or 6.0
    t = np.arange(0.0, dur, 0.0039)
    amp = {"heavy": 2000.0, "light": 300.0}.get(spec.scenario, 1000.0)
    fw = np.where(t > 1.0, amp, 0.0)
    mw = 0.4 * fw
    lag = np.exp(-0.0039 / 0.2)
    fw_hat = np.empty_like(fw)
    acc = 0.0
    for i, f in enumerate(fw):
        acc = lag * acc + (1.0 - lag) * f
        fw_hat[i] = acc
    bias = 2.0 * abs(v.body.lf - 1.071) * fw_hat
    mw_hat = 0.4 * fw_hat + bias + rng.normal(0.0, 0.01 * amp, t.size)
    return t, fw_hat, mw_hat, np.ones(t.size, dtype=bool), metrics.Truth(t, fw, mw, mw)


# --- the sweep on Dask ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ClusterConfig:
    """Where to run: ``scheduler`` address (None: a local cluster of ``n_workers`` processes)."""

    scheduler: str | None = None
    n_workers: int = 2
    threads_per_worker: int = 1
    connect_timeout: float = 10.0  # s, to reach an existing scheduler


def run_specs(
    specs: Sequence[RunSpec],
    cluster: ClusterConfig | None = None,
    engine: Engine | None = None,
    progress: bool = True,
) -> list[RunResult]:
    """Run every spec on a Dask cluster; results in the order of ``specs``.

    With ``cluster.n_workers == 0`` and no scheduler the specs run in this process (debugging).
    """
    cfg = cluster or ClusterConfig()
    if not specs:
        return []
    if cfg.scheduler is None and cfg.n_workers == 0:
        it: Iterable[RunSpec] = _progress(specs, progress, len(specs))
        return [run_one(s, engine) for s in it]
    import logging

    from distributed import Client, LocalCluster, as_completed

    # the scheduler and nanny INFO lines would drown the progress bar (-v shows them)
    if logging.getLogger().getEffectiveLevel() >= logging.WARNING:
        logging.getLogger("distributed").setLevel(logging.WARNING)

    local = None
    try:
        if cfg.scheduler is None:
            local = LocalCluster(
                n_workers=cfg.n_workers,
                threads_per_worker=cfg.threads_per_worker,
                processes=True,
                dashboard_address=None,
            )
            client = Client(local)
        else:
            client = Client(cfg.scheduler, timeout=cfg.connect_timeout)
    except (OSError, TimeoutError) as exc:
        raise LdeError(f"cannot reach the Dask scheduler {cfg.scheduler!r}: {exc}") from exc
    try:
        futures = client.map(run_one, list(specs), engine=engine, pure=False)
        index = {f.key: i for i, f in enumerate(futures)}
        out: list[RunResult | None] = [None] * len(specs)
        for fut in _progress(as_completed(futures), progress, len(futures)):
            i = index[fut.key]
            try:
                out[i] = fut.result()
            except Exception as exc:  # a worker died or could not unpickle: report, keep going
                out[i] = RunResult(specs[i], None, f"worker: {type(exc).__name__}: {exc}")
        return [r for r in out if r is not None]
    finally:
        client.close()
        if local is not None:
            local.close()


def _progress(it: Iterable[Any], enabled: bool, total: int) -> Iterable[Any]:
    if not enabled:
        return it
    from tqdm import tqdm

    return tqdm(it, total=total, unit="run", desc="lde study")


# --- study definitions --------------------------------------------------------------------------------


def candidate_specs(
    scenarios: Sequence[str] = PAPER_SCENARIOS,
    payloads: Sequence[str] = ("none",),
    candidates: Sequence[str] = CANDIDATES,
    seeds: Sequence[int] = (0,),
    duration: float | None = None,
    sim_options: tuple[tuple[str, OptionValue], ...] = (),
    estimator: str = "replay",
    est_options: tuple[tuple[str, OptionValue], ...] = (),
    group: str = "candidates",
    trace_candidate: str | None = None,
    backend: str = "float",
    profile: str = "lde",
) -> list[RunSpec]:
    """The paper's study: every candidate set on every (scenario, payload, seed) load case.

    ``trace_candidate``: keep traces of this candidate's unloaded seed-0 runs (Figs. 13-14).
    """
    specs = []
    for cand in candidates:
        for sc in scenarios:
            for pl in payloads:
                for seed in seeds:
                    specs.append(
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
                    )
    return specs


def all_payloads() -> tuple[str, ...]:
    """The simulator's payload case names (``vcan_sim.payload.PAYLOADS``)."""
    try:
        from vcan_sim.payload import PAYLOADS
    except ImportError as exc:
        raise LdeError("the simulator package vcan_sim is not importable") from exc
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
    sim_options: tuple[tuple[str, OptionValue], ...] = (),
    est_options: tuple[tuple[str, OptionValue], ...] = (),
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
    sim_options: tuple[tuple[str, OptionValue], ...] = (),
    est_options: tuple[tuple[str, OptionValue], ...] = (),
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


# --- Fig. 12: linear-equivalent tires under heavy and light load --------------------------------


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
    from vcan_sim.identify import identify_scenarios

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
    from vcan_sim.run import simulate

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


def plot_tires(ids: Sequence[TireIdentification], path: Path) -> Path:
    """Cornering stiffness and aligning-torque rate per load level (like the paper's Fig. 12)."""
    plt = _pyplot()
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(8, 3.2))
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
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


# --- the improvement ladder and the friction / offset study ---------------------------------------

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
    ``winner``; ``curvature``: (kappa_f, kappa_r, kappa_K) of :func:`identify_curvature` adds step 7.
    """
    wc = winner_calibrated or winner
    cal = (("calibrate", "lane_change"),)
    steps: list[tuple[str, dict[str, Any]]] = [
        ("0 reference", dict(est_vehicle="reference")),
        ("1 reference + lde calibrate", dict(est_vehicle="reference", est_options=cal)),
        (f"2 {Path(winner).stem} (Table 1 winner)", dict(est_vehicle=winner)),
        ("3 + Fig. 12 tires", dict(est_vehicle=tire_vehicle)),
        (f"4 {Path(wc).stem} + lde calibrate", dict(est_vehicle=wc, est_options=cal)),
        (
            "5 + load-scheduled m, Iz, CG",
            dict(est_vehicle=wc, estimator="adaptive", est_options=cal + (("payload_known", 1),)),
        ),
        (
            "6 + lateral acceleration (wind vs bank)",
            dict(
                est_vehicle=wc,
                estimator="adaptive",
                est_options=cal + (("payload_known", 1), ("lat_accel", 1)),
            ),
        ),
    ]
    if curvature is not None:
        kap = tuple(zip(("kappa_f", "kappa_r", "kappa_k"), (round(c, 1) for c in curvature), strict=True))
        steps.append(
            (
                "7 + slip-scheduled secant tires",
                dict(
                    est_vehicle=wc,
                    estimator="adaptive",
                    est_options=cal + (("payload_known", 1), ("lat_accel", 1)) + kap,
                ),
            )
        )
    return [
        RunSpec(scenario=sc, seed=seed, duration=duration, group=label, trace=(seed == seeds[0]), **kw)
        for label, kw in steps
        for sc in scenarios
        for seed in seeds
    ]


#: the friction / sensor-offset cases of the simulator (issue 6, item 5)
FAULT_CASES: tuple[tuple[str, tuple[tuple[str, OptionValue], ...]], ...] = (
    ("friction 0.35 Nm", (("friction_Nm", 0.35),)),
    ("friction 0.8 Nm", (("friction_Nm", 0.8),)),
    ("angle offset 1 deg", (("steer_offset_deg", 1.0),)),
    ("yaw-rate bias 0.2 deg/s", (("yaw_bias_deg_s", 0.2),)),
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
    cal: tuple[tuple[str, OptionValue], ...] = (("calibrate", "lane_change"),)
    specs = []
    for case, sim_opts in FAULT_CASES:
        for est_label, est_opts in (
            ("not compensated", ()),
            ("learned corrections", cal + (("calibrate_tires", 0),)),
            ("learned corrections and tires", cal),
        ):
            for sc in scenarios:
                for seed in seeds:
                    specs.append(
                        RunSpec(
                            scenario=sc,
                            seed=seed,
                            duration=duration,
                            sim_options=sim_opts,
                            group=f"{case} / {est_label}",
                            est_vehicle="reference",
                            est_options=est_opts,
                        )
                    )
    return specs


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


# --- summaries ---------------------------------------------------------------------------------------


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
                worst_nrmse_fw=_nanmax([a.nrmse_fw for a in accs]),
                worst_nrmse_mw=_nanmax([a.nrmse_mw for a in accs]),
            )
        )
    return sorted(scores, key=lambda s: s.mean_j)


def _nanmax(xs: Sequence[float]) -> float:
    finite = [x for x in xs if math.isfinite(x)]
    return max(finite) if finite else math.nan


# --- output -----------------------------------------------------------------------------------------


def write_csv(results: Sequence[RunResult], path: Path) -> Path:
    """One row per run (columns: union of all rows' keys, in first-seen order)."""
    rows = [r.as_row() for r in results]
    cols: list[str] = []
    for row in rows:
        cols += [k for k in row if k not in cols]
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, restval="")
        w.writeheader()
        for row in rows:
            w.writerow({k: _fmt(v) for k, v in row.items()})
    return path


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


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_error_index(scores: Sequence[CandidateScore], path: Path, title: str = "") -> Path:
    """Bar chart of the mean eq. (19) index per candidate set (like the paper's Fig. 11)."""
    if not scores:
        raise ConfigError("no successful runs to plot")
    plt = _pyplot()
    ordered = sorted(scores, key=lambda s: s.candidate)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    best = min(scores, key=lambda s: s.mean_j).candidate
    colors = ["tab:green" if s.candidate == best else "tab:blue" for s in ordered]
    ax.bar([s.candidate for s in ordered], [s.mean_j for s in ordered], color=colors)
    ax.set_ylabel("error index J [N]  (q1 = 1/N, q2 = 1/Nm)")
    ax.set_title(title or "Error index of the parameter sets (mean over load cases)")
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_traces(results: Sequence[RunResult], path: Path, title: str = "") -> Path:
    """Estimates against truth, one column per traced run (like the paper's Figs. 13-14)."""
    traced = [r for r in results if r.trace is not None]
    if not traced:
        raise ConfigError("no traced runs to plot")
    plt = _pyplot()
    fig, axes = plt.subplots(2, len(traced), figsize=(4.5 * len(traced), 5.5), squeeze=False, sharex="col")
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
            sub += f"\nNRMSE Fw {_pct(a.nrmse_fw)}, Mw {_pct(a.nrmse_mw)}"
        ax_f.set_title(sub, fontsize=7)
        ax_f.set_ylabel("Fw [N]")
        ax_m.set_ylabel("Mw [Nm]")
        ax_m.set_xlabel("t [s]")
        for ax in (ax_f, ax_m):
            ax.grid(alpha=0.3)
        ax_m.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _pct(x: float) -> str:
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
