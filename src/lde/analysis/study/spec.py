"""The study's spec model: one run (:class:`RunSpec`) with typed simulator and estimator options,
and what a worker sends back (:class:`RunResult`, :class:`Estimate`).

Options have types and names (:class:`SimOptions`, :class:`EstOptions`). They can still be written
as ``(name, value)`` pairs — the command line's ``--sim-option KEY=VALUE`` and older callers do —
and are parsed into the dataclasses when a :class:`RunSpec` is made; iterating an options object
gives back the ``(name, value)`` pairs of the options that are set (labels, CSV rows,
``dict(spec.est_options)``). A name the spec does not know is kept in ``unknown`` and the engine
rejects it with the list of known names, so that the run becomes a failure row like any other bad
run (:meth:`SimOptions.parse` with ``strict=True`` rejects it at once: the command line does).
"""

from __future__ import annotations

import enum
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field, fields
from typing import Any, NamedTuple

import numpy as np

from lde.analysis import metrics
from lde.errors import ConfigError
from lde.params import CORRECTION_KEYS

OptionValue = float | int | str | bool
OptionPairs = tuple[tuple[str, OptionValue], ...]


class Estimator(str, enum.Enum):  # noqa: UP042 - str() keeps the "Estimator.X" form
    """How a run estimates: the product in process, a prototype, or the CLI on a written log."""

    REPLAY = "replay"  #: lde.replay.replay.replay on the simulated frames (the product pipeline, in process)
    ADAPTIVE = "adaptive"  #: the prototype extensions of lde.analysis.adaptive
    CLI = "cli"  #: `lde replay LOG ... --csv OUT` through lde.cli.main on a written candump log


#: ``RunSpec.est_vehicle`` value: derive the spec-sheet file from the simulated vehicle
SPEC_SHEET = "spec-sheet"
#: ``RunSpec.est_vehicle`` value: the spec sheet with the load (the loaded car's mass, yaw inertia
#: and CG, what a load signal gives through the paper's eqs. 17-18); Mw is then about the true CG
SPEC_SHEET_LOADED = "spec-sheet+load"


def _as_bool(name: str, v: OptionValue) -> bool:
    if isinstance(v, bool):
        return v
    if isinstance(v, (int, float)) and v in (0, 1):
        return bool(v)
    if isinstance(v, str) and v.lower() in ("0", "1", "true", "false"):
        return v.lower() in ("1", "true")
    raise ConfigError(f"option {name}={v!r}: expected 0/1 or true/false")


def _as_float(name: str, v: OptionValue) -> float:
    if isinstance(v, bool):
        raise ConfigError(f"option {name}={v!r}: expected a number")
    try:
        return float(v)
    except (TypeError, ValueError):
        raise ConfigError(f"option {name}={v!r}: expected a number") from None


def _pairs_out(obj: Any, skip: tuple[str, ...]) -> Iterator[tuple[str, OptionValue]]:
    """(name, value) of the fields that differ from their defaults; bools as 0/1."""
    for f in fields(obj):
        if f.name in skip:
            continue
        v = getattr(obj, f.name)
        if v != f.default:
            yield f.name, int(v) if isinstance(v, bool) else v


@dataclass(frozen=True)
class SimOptions:
    """Simulator options of a run (None: the simulated vehicle file's own value).

    Attributes:
        friction_Nm: rack + column Coulomb friction at the column [Nm] (``[sim.steering]``).
        steer_offset_deg: steering-angle sensor offset, measured minus true [deg].
        yaw_bias_deg_s: yaw-rate sensor bias [deg/s].
        column_torque_bias_Nm: column-torque sensor offset [Nm].
        lat_accel_bias: lateral-acceleration sensor offset [m/s^2].
        speed_kmh: run the scenario at this constant speed [km/h].
        unknown: names the spec does not know (rejected by the engine).
    """

    friction_Nm: float | None = None
    steer_offset_deg: float | None = None
    yaw_bias_deg_s: float | None = None
    column_torque_bias_Nm: float | None = None
    lat_accel_bias: float | None = None
    speed_kmh: float | None = None
    unknown: OptionPairs = ()

    @classmethod
    def parse(cls, pairs: Iterable[tuple[str, OptionValue]] | SimOptions, strict: bool = False) -> SimOptions:
        """From ``(name, value)`` pairs; ``strict``: an unknown name is a ConfigError."""
        if isinstance(pairs, SimOptions):
            return pairs
        known = {f.name for f in fields(cls)} - {"unknown"}
        kw: dict[str, Any] = {}
        unknown = []
        for name, value in pairs:
            if name in known:
                kw[name] = _as_float(name, value)
            elif strict:
                raise ConfigError(f"unknown simulator option {name!r} (known: {', '.join(sorted(known))})")
            else:
                unknown.append((name, value))
        return cls(**kw, unknown=tuple(unknown))

    @classmethod
    def known(cls) -> tuple[str, ...]:
        return tuple(f.name for f in fields(cls) if f.name != "unknown")

    def __iter__(self) -> Iterator[tuple[str, OptionValue]]:
        yield from _pairs_out(self, ("unknown",))
        yield from self.unknown


@dataclass(frozen=True)
class EstOptions:
    """Estimator options of a run.

    Attributes:
        calibrate: a scenario name: identify tires and input corrections on that (undisturbed)
            scenario of the same simulated car, payload and options (seed + 1000), as
            ``lde calibrate`` does, then estimate with them.
        calibrate_tires: False keeps the file's tires (corrections only).
        torsion: torsion-bar term in the calibration (None: only where the profile's angle is the
            steering-wheel angle, i.e. not on ``lde``, whose angle is the MDPS's pinion angle).
        corrections: vehicle-file ``[corrections]`` keys and values (``lde.params.CORRECTION_KEYS``).
        payload_known: (adaptive) the estimator's mass, yaw inertia and CG are the loaded
            vehicle's (what a wheel-load or mass signal gives through eqs. 17-18).
        lat_accel: (adaptive) the 5-state filter with a_y; q_fa_factor scales its wind random walk.
        kappa_f, kappa_r, kappa_k: (adaptive) slip-scheduled secant tires [1/rad^2].
        learned_prior: (cli) warm start: first ``lde replay PRIOR --learned S`` on this scenario of
            the same car (another seed), then the run with ``--learned S`` (:mod:`lde.analysis.study.zoo`).
        unknown: names the spec does not know (rejected by the engine).
    """

    calibrate: str | None = None
    calibrate_tires: bool = True
    torsion: bool | None = None
    corrections: tuple[tuple[str, float], ...] = ()
    payload_known: bool = False
    lat_accel: bool = False
    q_fa_factor: float | None = None
    kappa_f: float | None = None
    kappa_r: float | None = None
    kappa_k: float | None = None
    learned_prior: str | None = None
    unknown: OptionPairs = ()

    _BOOLS = ("calibrate_tires", "torsion", "payload_known", "lat_accel")
    _FLOATS = ("q_fa_factor", "kappa_f", "kappa_r", "kappa_k")
    _STRINGS = ("calibrate", "learned_prior")
    #: options only the prototype estimator (lde.analysis.adaptive) takes
    ADAPTIVE_ONLY = ("payload_known", "lat_accel", "q_fa_factor", "kappa_f", "kappa_r", "kappa_k")

    @classmethod
    def parse(cls, pairs: Iterable[tuple[str, OptionValue]] | EstOptions, strict: bool = False) -> EstOptions:
        """From ``(name, value)`` pairs; ``[corrections]`` keys go to ``corrections``; ``strict``:
        an unknown name is a ConfigError."""
        if isinstance(pairs, EstOptions):
            return pairs
        kw: dict[str, Any] = {}
        corr: list[tuple[str, float]] = []
        unknown = []
        for name, value in pairs:
            if name in cls._BOOLS:
                kw[name] = _as_bool(name, value)
            elif name in cls._FLOATS:
                kw[name] = _as_float(name, value)
            elif name in cls._STRINGS:
                kw[name] = str(value)
            elif name in CORRECTION_KEYS:
                corr.append((name, _as_float(name, value)))
            elif strict:
                raise ConfigError(
                    f"unknown estimator option {name!r} (known: {', '.join(cls.known())} and the vehicle "
                    f"file's [corrections] keys {', '.join(CORRECTION_KEYS)})"
                )
            else:
                unknown.append((name, value))
        return cls(**kw, corrections=tuple(corr), unknown=tuple(unknown))

    @classmethod
    def known(cls) -> tuple[str, ...]:
        return cls._STRINGS + cls._BOOLS + cls._FLOATS

    @property
    def curvature(self) -> tuple[float, float, float] | None:
        """(kappa_f, kappa_r, kappa_K) when any is set (the others 0), else None."""
        ks = (self.kappa_f, self.kappa_r, self.kappa_k)
        return None if all(k is None for k in ks) else tuple(k or 0.0 for k in ks)  # type: ignore[return-value]

    def __iter__(self) -> Iterator[tuple[str, OptionValue]]:
        yield from _pairs_out(self, ("corrections", "unknown"))
        yield from self.corrections
        yield from self.unknown


@dataclass(frozen=True)
class RunSpec:
    """One simulation + estimation run.

    Attributes:
        scenario: a :mod:`vcan_sim` scenario name (``lde sim --list``).
        est_vehicle: the estimator's vehicle file (shipped name or path), or :data:`SPEC_SHEET`:
            the spec-sheet file of the simulated vehicle (:mod:`lde.analysis.study.specsheet`), or
            :data:`SPEC_SHEET_LOADED`: that file with the loaded car's mass, inertia and CG.
        sim_vehicle: the simulated vehicle (shipped name, path, or ``zoo:NAME`` for a zoo plant).
        payload: the simulator's payload case name ("none" = unloaded; "": the scenario's own).
        seed: the simulator's random seed.
        duration: simulated time [s] (None: the scenario's own length).
        estimator: :class:`Estimator` value ("replay", "adaptive" or "cli").
        backend: replay backend (:mod:`lde.engine.backends`; default ``paper``, the filter the study's
            tables were measured with).
        profile: CAN profile name.
        sim_options: :class:`SimOptions` (or ``(name, value)`` pairs).
        est_options: :class:`EstOptions` (or ``(name, value)`` pairs).
        group: a free label used to group rows in summaries and plots.
        trace: return decimated traces (estimate and truth) for plots.
        work_dir: (cli) keep the run's files (log, truth, spec sheet, estimate CSV) under this
            directory; "" = a temporary directory, removed after scoring.
    """

    scenario: str
    est_vehicle: str = "reference"
    sim_vehicle: str = "reference"
    payload: str = ""
    seed: int = 0
    duration: float | None = None
    estimator: str = Estimator.REPLAY.value
    backend: str = "paper"
    profile: str = "lde"
    sim_options: SimOptions = field(default_factory=SimOptions)
    est_options: EstOptions = field(default_factory=EstOptions)
    group: str = ""
    trace: bool = False
    work_dir: str = ""

    def __post_init__(self) -> None:
        object.__setattr__(self, "sim_options", SimOptions.parse(self.sim_options))
        object.__setattr__(self, "est_options", EstOptions.parse(self.est_options))
        if isinstance(self.estimator, Estimator):
            object.__setattr__(self, "estimator", self.estimator.value)

    @property
    def label(self) -> str:
        """A short human-readable id of the run."""
        parts = [self.scenario, self.payload or "-", self.est_vehicle]
        if self.sim_vehicle != "reference":
            parts.append(f"on {self.sim_vehicle}")
        if self.profile != "lde":
            parts.append(self.profile)
        parts.append(f"s{self.seed}")
        parts += [f"{k}={v}" for k, v in tuple(self.sim_options) + tuple(self.est_options)]
        return "/".join(parts)


class Estimate(NamedTuple):
    """What an engine returns: step times t [s] (the log's time base), Fw_hat [N], Mw_hat [Nm],
    the VALID mask, and the truth (Fw, Mw about the actual CG, Mw_ref about the unloaded CG); where
    the engine has them, the wind's part of Fw [N], the bank angle [rad] (NaN where the backend does
    not tell them apart) and the learner's state per step (0 not learned, 1 learning, 2 learned,
    3 the backend does not learn)."""

    t: np.ndarray
    fw: np.ndarray
    mw: np.ndarray
    valid: np.ndarray
    truth: metrics.Truth
    fw_wind: np.ndarray | None = None
    bank: np.ndarray | None = None
    learn_state: np.ndarray | None = None


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
