"""The study's engine: simulate a run with :mod:`vcan_sim`, estimate, score with :mod:`lde.analysis.metrics`.

:func:`run_one` executes one :class:`~lde.analysis.study.spec.RunSpec` on a worker and never raises: any
failure becomes ``RunResult.error`` (a sweep must survive one bad case). The engine is chosen by
``spec.estimator``:

- ``replay``: the product pipeline in process (:func:`lde.replay.replay.replay` on the simulated frames),
  with the input corrections or calibration of ``spec.est_options``;
- ``adaptive``: the prototype extensions of :mod:`lde.analysis.adaptive`;
- ``cli``: exactly what a user runs, ``lde replay LOG ... --csv OUT`` through :func:`lde.cli.main` on a
  written candump log (:mod:`lde.cli.replay_in_process`, passed in by the CLI; the zoo evaluation).

A run in which the simulated driver loses control is discarded (:func:`check_plant`), not scored.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from lde.analysis import adaptive, metrics
from lde.analysis.calibrate import calibrate
from lde.analysis.study.spec import (
    SPEC_SHEET,
    SPEC_SHEET_LOADED,
    Estimate,
    Estimator,
    EstOptions,
    RunResult,
    RunSpec,
    SimOptions,
)
from lde.can.profiles import load_profile
from lde.errors import ConfigError, LdeError
from lde.estimator.paper import Status
from lde.params import Vehicle, load_vehicle, with_corrections
from lde.replay.replay import replay
from lde.units import DEG
from vcan_sim.config import sim_params_from_vehicle
from vcan_sim.run import scenario_with, simulate
from vcan_sim.scenarios import SCENARIOS, get_scenario
from vcan_sim.zoo import load_plant

Engine = Callable[[RunSpec], Estimate]

#: trace decimation: keep every n-th estimator step in returned traces (3.9 ms * 8 = 31 ms)
TRACE_DECIMATION = 8
#: the calibration drive of ``EstOptions.calibrate`` runs with seed + this
CALIBRATION_SEED_OFFSET = 1000
#: a run whose simulated driver needs more steering than this lost control [rad]
MAX_STEERING_WHEEL = 180.0 * DEG
#: a zoo plant as a simulated vehicle: ``zoo:NAME`` (:mod:`vcan_sim.zoo`)
ZOO_PREFIX = "zoo:"

#: SimOptions field -> (SimParams section, attribute, factor to SI)
SIM_OPTION_FIELDS: dict[str, tuple[str, str, float]] = {
    "friction_Nm": ("steering", "rack_coulomb", 1.0),
    "steer_offset_deg": ("sensors", "steering_angle_bias", DEG),
    "yaw_bias_deg_s": ("sensors", "yaw_rate_bias", DEG),
    "column_torque_bias_Nm": ("sensors", "column_torque_bias", 1.0),
    "lat_accel_bias": ("sensors", "lat_accel_bias", 1.0),
}


def load_sim_vehicle(name: str) -> Vehicle:
    """A simulated vehicle: ``zoo:NAME`` (a zoo plant), a shipped name or a TOML path."""
    if name.startswith(ZOO_PREFIX):
        return load_plant(name[len(ZOO_PREFIX) :])
    return load_vehicle(name)


def sim_params(vehicle: Vehicle, options: SimOptions) -> Any:
    """The vehicle's ``[sim]`` parameters with the run's simulator options applied."""

    if options.unknown:
        raise ConfigError(
            f"unknown simulator option(s) {', '.join(k for k, _ in options.unknown)} "
            f"(known: {', '.join(SimOptions.known())})"
        )
    sp = sim_params_from_vehicle(vehicle)
    for key, (section, attr, factor) in SIM_OPTION_FIELDS.items():
        value = getattr(options, key)
        if value is not None:
            sub = replace(getattr(sp, section), **{attr: float(value) * factor})
            sp = replace(sp, **{section: sub})
    return sp


def simulate_run(spec: RunSpec, scenario: str, seed: int) -> Any:
    """Simulate ``scenario`` with the run's simulated vehicle, payload and options (a
    :class:`vcan_sim.run.SimResult`). The run's ``duration`` applies to its own scenario only."""
    vehicle = load_sim_vehicle(spec.sim_vehicle)
    # another drive of the run (calibration, prior) carries the same payload as the run
    payload = spec.payload or get_scenario(spec.scenario).payload
    sc = scenario_with(scenario, payload=payload)
    so = spec.sim_options
    return simulate(
        sc,
        vehicle,
        profile=spec.profile,
        seed=seed,
        duration=spec.duration if scenario == spec.scenario else None,
        sim_params=sim_params(vehicle, so),
        speed_kmh=so.speed_kmh,
    )


def truth_of(sim: Any) -> metrics.Truth:
    """The metric's truth (Fw, Mw about the actual CG, Mw_ref about the unloaded CG) of a run."""
    tr = sim.truth
    return metrics.Truth(
        t=np.asarray(tr["t"]),
        fw=tr["Fw"],
        mw=tr["Mw"],
        mw_ref=tr["Mw_ref"],
        fw_wind=tr["Fy_wind"],
        bank=tr["bank"],
    )


def check_plant(truth: dict[str, np.ndarray]) -> None:
    """Reject a run in which the simulated car left the straight-driving domain (a spin)."""
    dsw = float(np.max(np.abs(truth["delta_sw"])))
    vx = np.asarray(truth["vx"])
    if dsw > MAX_STEERING_WHEEL or float(vx.min()) < 0.5 * float(vx[0]):
        raise LdeError(
            f"the simulated vehicle lost control (|steering wheel| up to {dsw / DEG:.0f} deg, "
            f"speed down to {float(vx.min()):.1f} m/s): not a straight-driving case, run discarded"
        )


def calibrate_on(spec: RunSpec, scenario: str, vehicle: Vehicle, profile: Any, identify_torsion: bool) -> Any:
    """Calibrate on an undisturbed drive of the same simulated car (another seed), as
    ``lde calibrate`` does (friction only where the profile's steering rate is signed)."""

    cal_sim = simulate_run(spec, scenario, spec.seed + CALIBRATION_SEED_OFFSET)
    grid = adaptive.grid_from_frames(cal_sim.frames, profile)
    return calibrate(
        adaptive.drive_from_grid(grid),
        vehicle,
        identify_torsion=identify_torsion,
        identify_friction=profile.steering_rate_signed,
    )


def with_tires(vehicle: Vehicle, cf: float, cr: float, k: float) -> Vehicle:
    """``vehicle`` with the per-tire C_f, C_r [N/rad] and K [Nm/rad] replaced."""
    return replace(vehicle, tires=replace(vehicle.tires, cf=cf, cr=cr, align_rate=k))


def estimator_vehicle(spec: RunSpec, sim: Any, profile: Any) -> tuple[Vehicle, Any]:
    """The estimator's vehicle of an in-process run with ``spec.est_options`` applied (calibration,
    corrections, the known load); also the calibration result (or None)."""
    opts: EstOptions = spec.est_options
    if spec.est_vehicle in (SPEC_SHEET, SPEC_SHEET_LOADED):
        raise ConfigError(f"est_vehicle {spec.est_vehicle!r} needs the cli estimator")
    vehicle = load_vehicle(spec.est_vehicle)
    # the `lde` profile's angle is the MDPS's motor-side (pinion) angle: no torsion-bar twist in it
    use_torsion = opts.torsion if opts.torsion is not None else spec.profile != "lde"
    if opts.payload_known:
        if spec.estimator != Estimator.ADAPTIVE.value:
            raise ConfigError("estimator option payload_known needs --estimator adaptive")
        # scheduled on the measured load: mass, Iz and CG from the wheel loads (eqs. 17-18)
        b = sim.body
        vehicle = vehicle.with_body(mass=b.mass, yaw_inertia=b.yaw_inertia, lf=b.lf, lr=b.lr)
    cal = None
    if opts.calibrate:
        # what `lde calibrate` writes: tires and input corrections identified on an undisturbed drive
        cal = calibrate_on(spec, opts.calibrate, vehicle, profile, identify_torsion=use_torsion)
        vehicle = replace(vehicle, corrections=cal.corrections())
        if opts.calibrate_tires:
            vehicle = with_tires(vehicle, cal.cf, cal.cr, cal.align_rate)
    if opts.corrections:
        vehicle = with_corrections(vehicle, dict(opts.corrections), "estimator options")
    return vehicle, cal


def simulate_and_estimate(spec: RunSpec) -> Estimate:
    """The in-process engines (``replay``, ``adaptive``): :mod:`vcan_sim` -> CAN frames -> estimator."""

    opts = spec.est_options
    if opts.unknown:
        raise ConfigError(
            f"unknown estimator option(s) {sorted(k for k, _ in opts.unknown)} (known: "
            f"{', '.join(EstOptions.known())} and the vehicle file's [corrections] keys)"
        )
    if spec.estimator not in (Estimator.REPLAY.value, Estimator.ADAPTIVE.value):
        raise ConfigError(f"unknown estimator {spec.estimator!r} (replay, adaptive or cli)")
    if opts.learned_prior:
        raise ConfigError("estimator option learned_prior needs the cli estimator")
    sim = simulate_run(spec, spec.scenario, spec.seed)
    check_plant(sim.truth)
    profile = load_profile(spec.profile)
    vehicle, cal = estimator_vehicle(spec, sim, profile)
    if spec.estimator == Estimator.REPLAY.value:
        proto = [k for k in EstOptions.ADAPTIVE_ONLY if dict(opts).get(k) not in (None, 0)]
        if proto:
            raise ConfigError(f"estimator options {sorted(proto)} need --estimator adaptive")
        out = replay(sim.frames, profile, vehicle, spec.backend)
        t_ns, fw, mw, status = out.t_ns, out.fw, out.mw, out.status
        valid = (np.asarray(status) & int(Status.VALID)) != 0
        b = out.block
        return Estimate(
            np.asarray(t_ns, dtype=np.float64) * 1e-9,
            fw,
            mw,
            valid,
            truth_of(sim),
            fw_wind=np.asarray(b.fw_wind, dtype=np.float64),
            bank=np.asarray(b.bank, dtype=np.float64),
            learn_state=np.asarray(b.learn_state),
        )
    else:
        grid = adaptive.grid_from_frames(sim.frames, profile)
        if opts.lat_accel:
            ay_kw: dict[str, Any] = {}
            if opts.q_fa_factor is not None:
                ay_kw["q_fa_factor"] = opts.q_fa_factor
            if opts.curvature is not None:
                ay_kw["curvature"] = opts.curvature
            t_ns, fw, mw, ok = adaptive.augmented_estimate(
                grid, vehicle, accel_scale=cal.accel_scale if cal is not None else 1.0, **ay_kw
            )
            status = np.where(ok, int(Status.VALID), 0)
        else:
            est = replay(sim.frames, profile, vehicle, "float")  # the product's data path (float)
            t_ns, fw, mw, status = est.t_ns, est.fw, est.mw, est.status
    valid = (np.asarray(status) & int(Status.VALID)) != 0
    return Estimate(np.asarray(t_ns, dtype=np.float64) * 1e-9, fw, mw, valid, truth_of(sim))


def default_engine(spec: RunSpec) -> Estimate:
    """The in-process engine (``replay``, ``adaptive``). The ``cli`` estimator runs the command
    line, which sits above the study: ``lde evaluate`` / ``lde study`` pass
    :func:`lde.cli.replay_in_process.engine` as the engine."""
    if spec.estimator == Estimator.CLI.value:
        raise ConfigError(
            "the cli estimator runs `lde replay` in process: give engine=lde.cli.replay_in_process.engine "
            "(lde evaluate / lde study do)"
        )
    return simulate_and_estimate(spec)


def plant_name(sim_vehicle: str) -> str:
    """A short name of the simulated vehicle (a zoo plant's name, a file's stem)."""
    if sim_vehicle.startswith(ZOO_PREFIX):
        return sim_vehicle[len(ZOO_PREFIX) :]
    return Path(sim_vehicle).stem


def scenario_kind(name: str) -> metrics.Kind | None:
    """UNDISTURBED for a simulator scenario without wind and bank (scored by the RMS of the
    estimate whatever the few newtons of aero side force from the car's side slip: a large car's
    exceeds the truth-based threshold); None (decided from the truth) otherwise."""
    sc = SCENARIOS.get(name)
    return metrics.Kind.UNDISTURBED if sc is not None and sc.disturbance_free else None


def run_one(spec: RunSpec, engine: Engine | None = None) -> RunResult:
    """Run one spec and score it; any failure becomes ``RunResult.error`` (never raised)."""
    t0 = time.perf_counter()
    eng = engine or default_engine
    try:
        est = eng(spec)
        t, fw_hat, mw_hat, truth = est.t, est.fw, est.mw, est.truth
        kind = scenario_kind(spec.scenario)
        acc = metrics.accuracy(t, fw_hat, mw_hat, truth, valid=est.valid, kind=kind)
        extra = split_figures(est)
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
    return RunResult(spec, acc, "", time.perf_counter() - t0, extra=extra, trace=trace)


def split_figures(est: Estimate) -> dict[str, float]:
    """The run's extra figures where the engine gives them: wind force NRMSE (``wind_nrmse``,
    fraction; NaN without wind), its scale (``wind_scale_N``), bank RMS error (``bank_rms_deg``)
    and the learner's state at the last step (``learn_state``); for a drive of at least
    :data:`~lde.analysis.metrics.LONG_DRIVE_MIN_S` the figures of
    :func:`~lde.analysis.metrics.long_drive`: ``scored_fw`` / ``scored_mw`` from minute 2 on,
    ``minutes``, per minute ``min<k>_fw`` / ``min<k>_mw`` (NRMSE fractions; Mw about the unloaded CG)
    and ``min<k>_rms_fw`` [N], and ``learned_s`` (NaN: never)."""
    out: dict[str, float] = {}
    if est.fw_wind is not None and est.bank is not None and est.truth.fw_wind is not None:
        sp = metrics.split_accuracy(est.t, est.fw_wind, est.bank, est.truth, valid=est.valid)
        out.update(wind_nrmse=sp.wind_nrmse, wind_scale_N=sp.wind_scale, bank_rms_deg=sp.bank_rms_deg)
    if est.learn_state is not None and len(est.learn_state):
        out["learn_state"] = float(est.learn_state[-1])
    if len(est.t) and float(est.t[-1] - est.t[0]) >= metrics.LONG_DRIVE_MIN_S:
        ld = metrics.long_drive(
            est.t, est.fw, est.mw, est.truth, valid=est.valid, learn_state=est.learn_state
        )
        out["scored_fw"], out["scored_mw"] = metrics.target_figures(ld.scored)
        out["minutes"] = float(len(ld.windows))
        for k, w in enumerate(ld.windows):
            f, m = metrics.target_figures(w) if w is not None else (math.nan, math.nan)
            out[f"min{k + 1}_fw"], out[f"min{k + 1}_mw"] = f, m
            out[f"min{k + 1}_rms_fw"] = w.rms_fw if w is not None else math.nan
        out["learned_s"] = ld.learned_s
    return out


def synthetic_engine(spec: RunSpec) -> Estimate:
    """A plumbing-test engine (no simulator): a disturbance step and a lagged, noisy estimate.

    The estimate's moment error grows with the estimator's CG error ``|lf_est - 1.071 m|`` so that
    candidate rankings are deterministic; used by the tests of the Dask machinery only.
    """
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
    return Estimate(t, fw_hat, mw_hat, np.ones(t.size, dtype=bool), metrics.Truth(t, fw, mw, mw))
