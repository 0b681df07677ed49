"""Typed, validated parameters loaded from TOML vehicle files.

A vehicle file (``src/lde/vehicles/*.toml``, or any path given with ``--vehicle FILE``) has the
tables ``[vehicle]``, ``[steering]``, ``[tires]``, ``[overlay]``, ``[estimator]``, the optional
``[corrections]`` (input corrections, :mod:`lde.estimator.conditioning`) and an optional ``[sim]`` table
that only the simulator reads. Keys carry their unit in their name
(``mass_kg``, ``min_speed_kmh``); the loader converts to SI, so every attribute of these
dataclasses is SI (kg, m, rad, N/rad, Nm/rad, m/s, Nm, Nm/s) with the unit in its docstring.

A file may start with ``extends = "reference"`` (a shipped vehicle name) or
``extends = "other.toml"`` (relative to the file) and override only what differs; this is how the
paper's Table 1 candidate sets are written. Unknown keys are errors (a typo must not silently
fall back to a default).

Sign conventions: ISO 8855 everywhere (x forward, y left, z up, left turns positive).
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import MISSING, Field, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from lde.errors import ConfigError
from lde.units import DEG, KMH, G

VEHICLE_DIR = Path(__file__).with_name("vehicles")
DEFAULT_VEHICLE = "reference"


@dataclass(frozen=True)
class VehicleParams:
    """Rigid-body and axle geometry of the 2-DOF bicycle model (paper eqs. 7-9).

    Attributes (SI):
        mass: m [kg].
        yaw_inertia: Iz [kg m^2] about the CG.
        lf: CG to front axle [m], > 0.
        lr: CG to rear axle [m], > 0.
        track_front: full front tread [m] (paper Table 2 ``t_f``, see SPEC erratum 5).
        track_rear: full rear tread [m].
    """

    mass: float
    yaw_inertia: float
    lf: float
    lr: float
    track_front: float
    track_rear: float

    @property
    def wheelbase(self) -> float:
        """L = lf + lr [m]."""
        return self.lf + self.lr


@dataclass(frozen=True)
class SteeringParams:
    """Steering gear.

    Attributes:
        ratio: N, steering-wheel angle per road-wheel angle [-] (delta_f = delta_sw / N).
    """

    ratio: float


@dataclass(frozen=True)
class TireParams:
    """Linear tire model of the estimator, per tire (paper eqs. 9 and 12).

    Attributes:
        cf: front cornering stiffness C_f per tire [N/rad] (F_f = C_f alpha_f).
        cr: rear cornering stiffness C_r per tire [N/rad].
        align_rate: K, aligning-torque rate per front tire on the steering axis [Nm/rad]
            (T_align = 2 K alpha_f; the paper measured 6750-7640).
    """

    cf: float
    cr: float
    align_rate: float


@dataclass(frozen=True)
class OverlayLimits:
    """Limits of the MDPS overlay-torque request (SPEC section 5). Torques at the column.

    Attributes:
        max_torque: |T_overlay| bound [Nm].
        max_rate: |dT_overlay/dt| bound [Nm/s]; also the ramp-out rate on faults.
        min_speed: the overlay is active only above this speed [m/s].
        max_speed: ... and below this speed [m/s].
        max_steering_angle: ... and within |delta_sw| <= this [rad] (steering-wheel angle).
        driver_override_torque: the driver overrides when |T_column| lies this far outside the band
            from 0 to the whole holding torque (see lde.estimator.overlay) [Nm].
        hold_off: after the last overriding step, wait this long before re-engaging [s].
        rearm_delay: all engage conditions must hold this long before (re-)engaging [s].
        fault_persist: an input fault lasting this long enters FAULT [s].
        fault_recover: FAULT is left after the input fault has been clear this long [s].
        law_time: time constant of the first-order low-pass on the law's input, the disturbance
            moment about the rear axle ``lr Fw + Mw`` [s]: the law is a steady state and must stay
            below the band where the steering's own dynamics carry the overlay (docs/overlay.md,
            "Closed loop: why the law is band-limited"); 0 is the unfiltered law.
    """

    max_torque: float = 3.0
    max_rate: float = 5.0
    min_speed: float = 60.0 * KMH
    max_speed: float = 180.0 * KMH
    max_steering_angle: float = 15.0 * DEG
    driver_override_torque: float = 3.0
    hold_off: float = 1.0
    rearm_delay: float = 0.2
    fault_persist: float = 0.5
    fault_recover: float = 1.0
    law_time: float = 0.3


@dataclass(frozen=True)
class EstimatorTuning:
    """Kalman filter tuning (reasons and measured time constants in ``docs/tuning.md``).

    The process noise is a continuous white-noise density W = diag(q_beta, q_yaw, q_fw, q_mw) on
    every state; the discrete covariance is Qd = W dt (SPEC erratum 8, :mod:`lde.estimator.model`).

    Attributes:
        q_beta: process noise density on beta [rad^2/s]. 1e-8: unmodelled lateral dynamics
            (tire relaxation, roll steer) small; a larger value lets beta absorb what Fw should.
        q_yaw: process noise density on r [(rad/s)^2/s]. 1e-8, same reasoning.
        q_fw: random-walk density of Fw [N^2/s]. 1e4: slowest closed-loop time constant
            0.11-0.20 s from 60 to 160 km/h, so a 1000 N gust step settles within ~0.3-0.6 s,
            with an a-posteriori std of 43-52 N (0.2 Nm of overlay torque).
        q_mw: random-walk density of Mw [(Nm)^2/s]. 1e4, same reasoning.
        r_yaw: yaw-rate measurement variance [(rad/s)^2]: (0.1 deg/s)^2, ESC gyro noise and
            body vibration; the 0.01 deg/s resolution alone would be (0.003 deg/s)^2.
        r_align: aligning-torque measurement variance [(Nm)^2] at the steering axis: (10 Nm)^2.
            T_align = N (T_column + T_assist) carries steering friction, inertia and assist
            dynamics (0.5 Nm at the column is 7.5 Nm here at N = 15), far above the 0.001 Nm
            quantisation.
        p0_beta, p0_yaw, p0_fw, p0_mw: initial standard deviations [rad, rad/s, N, Nm].
        min_speed: below this the model is not used, the filter holds [m/s] (SPEC: 30 km/h).
        converge_time: time after a (re)start before the estimate counts as converged [s]
            (5 slowest time constants at 160 km/h).

    The lateral filter (:mod:`lde.estimator.lateral`, states beta, r, F_wind, M_wind, F_bank; the product's
    default) uses q_beta, q_yaw, r_yaw, r_align, the p0 and min_speed/converge_time above, and:

        q_wind: random-walk density of the wind force F_wind [N^2/s], 1e5.
        q_wind_moment: random-walk density of the wind moment M_wind [(Nm)^2/s], 3e4.
        q_bank: random-walk density of the bank force F_bank = m g sin(phi) [N^2/s], 5e4.
        r_lat_accel: lateral-acceleration measurement variance [(m/s^2)^2]: (0.10 m/s^2)^2.
        p0_bank: initial standard deviation of F_bank [N].
        wind_cp: the wind's centre of pressure ahead of the CG [m] (a generic prior, 0.3): the
            learner's starting value for its angle-offset split, and the reported moment's blend.
        wind_cp_weight: weight w of that prior in the reported moment,
            ``Mw = (1 - w) M_wind + w wind_cp F_wind``. 0 (shipped): the filter's M_wind alone; 0.7 is
            best on the zoo's tuning plants with spec-sheet tires (docs/estimator.md, "Cold: the wind's
            centre of pressure", with why it is not the default).

    (docs/estimator.md: chosen on the tuning plants with their identified tires; the zoo results are
    flat within 0.5 points across the sweep.)
    """

    q_beta: float = 1e-8
    q_yaw: float = 1e-8
    q_fw: float = 1.0e4
    q_mw: float = 1.0e4
    r_yaw: float = (0.1 * DEG) ** 2
    r_align: float = 10.0**2
    p0_beta: float = 0.01
    p0_yaw: float = 0.01
    p0_fw: float = 3000.0
    p0_mw: float = 3000.0
    min_speed: float = 30.0 * KMH
    converge_time: float = 1.0
    q_wind: float = 1.0e5
    q_wind_moment: float = 3.0e4
    q_bank: float = 5.0e4
    r_lat_accel: float = 0.10**2
    p0_bank: float = 3000.0
    wind_cp: float = 0.3
    wind_cp_weight: float = 0.0


#: default steering-wheel rate scale of the smoothed friction sign tanh(rate / w) [rad/s]
FRICTION_RATE_WIDTH = 2.0 * DEG


@dataclass(frozen=True)
class InputCorrections:
    """What the paper's model neglects, removed from the inputs before the step
    (:mod:`lde.estimator.conditioning`).

    All zero (the default) is the paper's estimator. ``lde calibrate`` identifies them from a drive
    without disturbance. Signs: "measured minus true", ISO 8855.

    Attributes:
        friction: Coulomb friction of the steering referred to the column [Nm] (eq. 11 drops it;
            real racks and columns have 0.3-1 Nm). Needs a signed steering rate.
        friction_rate_width: steering-wheel rate scale w of the smoothed sign tanh(rate / w) [rad/s].
        torsion_compliance: steering-wheel angle per column torque [rad/Nm]: the twist of the
            torsion bar when the angle sensor sits above it (0: the angle is the pinion's).
        steer_offset: steering-wheel angle offset [rad].
        yaw_bias: yaw-rate sensor bias [rad/s].
        align_offset: offset of N (T_column + T_assist) [Nm at the steering axis].
    """

    friction: float = 0.0
    friction_rate_width: float = FRICTION_RATE_WIDTH
    torsion_compliance: float = 0.0
    steer_offset: float = 0.0
    yaw_bias: float = 0.0
    align_offset: float = 0.0

    @property
    def is_identity(self) -> bool:
        """No correction at all (the inputs pass through unchanged)."""
        terms = (self.friction, self.torsion_compliance, self.steer_offset, self.yaw_bias, self.align_offset)
        return all(v == 0.0 for v in terms)


@dataclass(frozen=True)
class LearningSettings:
    """Online learning of what a spec sheet does not give (:mod:`lde.estimator.learner`).

    Attributes:
        enabled: 1 learns tires, friction and sensor offsets while driving; 0 keeps the vehicle
            file's (and a ``--learned`` file's) values.
        accel_scale: prior of the accelerometer's roll-tilt scale s = 1 + g k_roll [-] (a sedan's
            ~4 deg/g roll gradient gives 1.06; learned).
        friction_prior: prior of the steering Coulomb friction at the column [Nm] (learned; the
            vehicle file's ``[corrections] steering_friction_Nm`` overrides it when set).
        torsion_above_bar: generic torsion-bar twist used when the profile's angle sensor sits above
            the torsion bar and ``[corrections] torsion_deg_per_Nm`` is 0 [rad/Nm] (not learnable
            from driving: the column torque follows the aligning torque).
    """

    enabled: float = 1.0
    accel_scale: float = 1.06
    friction_prior: float = 0.3
    torsion_above_bar: float = 0.5 * DEG


#: generic tires when a vehicle file gives none (a spec sheet): per-tire cornering stiffness per
#: newton of static tire load [1/rad], front and rear, and the total trail K / C_f [m]; the values of
#: the shipped reference.toml's tires on its own body (a mid-size sedan on 215/60R16)
GENERIC_CORNERING_FRONT = 13.98
GENERIC_CORNERING_REAR = 20.33
GENERIC_TRAIL_M = 0.1161


def generic_tires(body: VehicleParams) -> TireParams:
    """Tires for a body without a ``[tires]`` table: the generic cornering coefficients times the
    static per-tire loads, K from the generic trail (the learner refines them while driving)."""
    L = body.wheelbase
    fz_f = body.mass * G * body.lr / (2.0 * L)
    fz_r = body.mass * G * body.lf / (2.0 * L)
    cf = GENERIC_CORNERING_FRONT * fz_f
    return TireParams(cf=cf, cr=GENERIC_CORNERING_REAR * fz_r, align_rate=GENERIC_TRAIL_M * cf)


@dataclass(frozen=True)
class Vehicle:
    """Everything a vehicle file holds. ``sim`` is the raw ``[sim]`` table for :mod:`vcan_sim`."""

    name: str
    body: VehicleParams
    steering: SteeringParams
    tires: TireParams
    overlay: OverlayLimits = field(default_factory=OverlayLimits)
    estimator: EstimatorTuning = field(default_factory=EstimatorTuning)
    corrections: InputCorrections = field(default_factory=InputCorrections)
    learning: LearningSettings = field(default_factory=LearningSettings)
    sim: dict[str, Any] = field(default_factory=dict)
    source: str = ""
    #: file keys that took lde's defaults (``[table] key``): not in the file or a file it extends
    defaults: tuple[str, ...] = field(default=(), compare=False)

    def defaults_note(self) -> str:
        """One line naming the keys that took defaults ('' when none did)."""
        if not self.defaults:
            return ""
        tables: dict[str, list[str]] = {}
        for d in self.defaults:
            t, k = d.split(" ", 1)
            tables.setdefault(t, []).append(k)
        parts = []
        for t, keys in tables.items():
            total = len(_SCHEMA[t.strip("[]")][1])
            parts.append(f"{t} all {total} keys" if len(keys) == total else f"{t} {', '.join(keys)}")
        return f"vehicle {self.name!r}: lde's defaults used for " + "; ".join(parts)

    def with_body(self, **changes: float) -> Vehicle:
        """A copy with some body parameters replaced (SI), re-validated."""
        v = replace(self, body=replace(self.body, **changes))
        validate(v)
        return v


# --- file schema: TOML key -> (attribute, factor to SI) -------------------------------------

_SCHEMA: dict[str, tuple[type, dict[str, tuple[str, float | None]]]] = {
    "vehicle": (
        VehicleParams,
        {
            "mass_kg": ("mass", 1.0),
            "yaw_inertia_kgm2": ("yaw_inertia", 1.0),
            "lf_m": ("lf", 1.0),
            "lr_m": ("lr", 1.0),
            "track_front_m": ("track_front", 1.0),
            "track_rear_m": ("track_rear", 1.0),
        },
    ),
    "steering": (SteeringParams, {"ratio": ("ratio", 1.0)}),
    "tires": (
        TireParams,
        {
            "cf_N_per_rad": ("cf", 1.0),
            "cr_N_per_rad": ("cr", 1.0),
            "align_rate_Nm_per_rad": ("align_rate", 1.0),
        },
    ),
    "overlay": (
        OverlayLimits,
        {
            "max_torque_Nm": ("max_torque", 1.0),
            "max_rate_Nm_per_s": ("max_rate", 1.0),
            "min_speed_kmh": ("min_speed", KMH),
            "max_speed_kmh": ("max_speed", KMH),
            "max_steering_angle_deg": ("max_steering_angle", DEG),
            "driver_override_Nm": ("driver_override_torque", 1.0),
            "hold_off_s": ("hold_off", 1.0),
            "rearm_delay_s": ("rearm_delay", 1.0),
            "fault_persist_s": ("fault_persist", 1.0),
            "fault_recover_s": ("fault_recover", 1.0),
            "law_time_constant_s": ("law_time", 1.0),
        },
    ),
    "estimator": (
        EstimatorTuning,
        {
            "q_beta_rad2_per_s": ("q_beta", 1.0),
            "q_yaw_rad2_per_s3": ("q_yaw", 1.0),
            "q_fw_N2_per_s": ("q_fw", 1.0),
            "q_mw_Nm2_per_s": ("q_mw", 1.0),
            "r_yaw_deg_per_s": ("r_yaw", None),  # given as a std dev in deg/s, stored as variance
            "r_align_Nm": ("r_align", None),  # given as a std dev in Nm, stored as variance
            "p0_beta_rad": ("p0_beta", 1.0),
            "p0_yaw_rad_per_s": ("p0_yaw", 1.0),
            "p0_fw_N": ("p0_fw", 1.0),
            "p0_mw_Nm": ("p0_mw", 1.0),
            "min_speed_kmh": ("min_speed", KMH),
            "converge_time_s": ("converge_time", 1.0),
            "q_wind_N2_per_s": ("q_wind", 1.0),
            "q_wind_moment_Nm2_per_s": ("q_wind_moment", 1.0),
            "q_bank_N2_per_s": ("q_bank", 1.0),
            "r_lat_accel_m_per_s2": ("r_lat_accel", None),  # a std dev, stored as variance
            "p0_bank_N": ("p0_bank", 1.0),
            "wind_cp_m": ("wind_cp", 1.0),
            "wind_cp_weight": ("wind_cp_weight", 1.0),
        },
    ),
    "learning": (
        LearningSettings,
        {
            "enabled": ("enabled", 1.0),
            "accel_scale": ("accel_scale", 1.0),
            "friction_prior_Nm": ("friction_prior", 1.0),
            "torsion_above_bar_deg_per_Nm": ("torsion_above_bar", DEG),
        },
    ),
    "corrections": (
        InputCorrections,
        {
            "steering_friction_Nm": ("friction", 1.0),
            "friction_rate_deg_s": ("friction_rate_width", DEG),
            "torsion_deg_per_Nm": ("torsion_compliance", DEG),
            "steering_angle_offset_deg": ("steer_offset", DEG),
            "yaw_rate_bias_deg_s": ("yaw_bias", DEG),
            "align_offset_Nm": ("align_offset", 1.0),
        },
    ),
}
_REQUIRED_TABLES = ("vehicle", "steering")
#: the ``[corrections]`` keys of a vehicle file (units in the names)
CORRECTION_KEYS: tuple[str, ...] = tuple(_SCHEMA["corrections"][1])


def _std_to_var(key: str, value: float) -> float:
    if key == "r_yaw_deg_per_s":
        return (value * DEG) ** 2
    return value**2  # r_align_Nm, r_lat_accel_m_per_s2


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _read_toml(path: Path, seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    if path.resolve() in {q.resolve() for q in seen}:
        raise ConfigError(f"{path}: 'extends' cycle through {', '.join(map(str, seen))}")
    try:
        with path.open("rb") as fh:
            data = tomllib.load(fh)
    except FileNotFoundError as exc:
        raise ConfigError(f"vehicle file not found: {path}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from exc
    parent = data.pop("extends", None)
    if parent is None:
        return data
    if not isinstance(parent, str):
        raise ConfigError(f"{path}: 'extends' must be a string")
    try:
        base_path = resolve_vehicle_path(parent, relative_to=path.parent)
    except ConfigError as exc:
        raise ConfigError(f"{path}: extends = {parent!r}: {exc}") from exc
    merged = _merge(_read_toml(base_path, seen + (path,)), data)
    if "name" not in data:
        merged.pop("name", None)  # not the parent's name: the file is named after itself
    return merged


def resolve_vehicle_path(name_or_path: str | Path, relative_to: Path | None = None) -> Path:
    """A shipped vehicle name (``reference``, ``est3``) or a path to a TOML file.

    A relative path is taken relative to ``relative_to`` (the directory of the file that
    ``extends`` it) when that file exists there, else relative to the working directory.
    """
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.parent != Path("."):
        if not p.is_absolute() and relative_to is not None:
            beside = relative_to / p
            if beside.exists() or not p.exists():
                return beside
        return p
    shipped = VEHICLE_DIR / f"{p.name}.toml"
    if shipped.exists():
        return shipped
    names = ", ".join(shipped_vehicles())
    raise ConfigError(f"no shipped vehicle named {str(name_or_path)!r} (shipped: {names})")


def shipped_vehicles() -> list[str]:
    """Names of the vehicle files shipped with lde."""
    return sorted(p.stem for p in VEHICLE_DIR.glob("*.toml"))


def _build(cls: type, table: str, raw: dict[str, Any], src: str, defaults: list[str] | None = None) -> Any:
    """The dataclass of ``[table]`` from its raw TOML keys (units converted); keys that are absent
    and have a default are appended to ``defaults`` as ``[table] key``."""
    keymap = _SCHEMA[table][1]
    if not isinstance(raw, dict):
        raise ConfigError(f"{src}: [{table}] must be a table")
    unknown = sorted(set(raw) - set(keymap))
    if unknown:
        raise ConfigError(
            f"{src}: unknown key(s) in [{table}]: {', '.join(unknown)} (known: {', '.join(sorted(keymap))})"
        )
    kwargs: dict[str, float] = {}
    for key, value in raw.items():
        attr, factor = keymap[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{src}: [{table}] {key} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ConfigError(f"{src}: [{table}] {key} must be finite, got {value!r}")
        kwargs[attr] = _std_to_var(key, float(value)) if factor is None else float(value) * factor
    names = {a: k for k, (a, _) in keymap.items()}
    missing = [f.name for f in fields(cls) if f.name not in kwargs and _has_no_default(f)]
    if missing:
        raise ConfigError(f"{src}: [{table}] is missing {', '.join(names[m] for m in missing)}")
    if defaults is not None:
        defaults += [
            f"[{table}] {names[f.name]}" for f in fields(cls) if f.name not in kwargs and f.name in names
        ]
    return cls(**kwargs)


def _has_no_default(f: Field[Any]) -> bool:
    return f.default is MISSING and f.default_factory is MISSING


def vehicle_from_dict(data: dict[str, Any], src: str = "<dict>") -> Vehicle:
    """Build and validate a :class:`Vehicle` from a parsed TOML mapping (keys with units)."""
    data = dict(data)
    name = data.pop("name", None)
    if name is None and src.endswith(".toml"):
        name = Path(src).stem  # a file without 'name' is named after itself
    if not isinstance(name, str) or not name:
        raise ConfigError(f"{src}: top-level 'name' (a non-empty string) is required")
    data.pop("description", None)
    sim = data.pop("sim", {})
    if not isinstance(sim, dict):
        raise ConfigError(f"{src}: [sim] must be a table")
    for t in _REQUIRED_TABLES:
        if t not in data:
            raise ConfigError(f"{src}: missing table [{t}]")
    unknown = sorted(set(data) - set(_SCHEMA))
    if unknown:
        raise ConfigError(f"{src}: unknown table(s) {', '.join(unknown)}")
    defaults: list[str] = []
    parts = {
        t: _build(_SCHEMA[t][0], t, data.get(t, {}), src, defaults)
        for t in _SCHEMA
        if t != "tires" or t in data
    }
    if "tires" not in parts:  # a spec sheet: generic tires from the axle loads (the learner refines them)
        parts["tires"] = generic_tires(parts["vehicle"])
        defaults.append("[tires] generic from the axle loads")
    v = Vehicle(
        name=name,
        body=parts["vehicle"],
        steering=parts["steering"],
        tires=parts["tires"],
        overlay=parts["overlay"],
        estimator=parts["estimator"],
        corrections=parts["corrections"],
        learning=parts["learning"],
        sim=sim,
        source=src,
        defaults=tuple(defaults),
    )
    validate(v)
    return v


def with_corrections(vehicle: Vehicle, keys: dict[str, Any], src: str = "<options>") -> Vehicle:
    """``vehicle`` with some ``[corrections]`` keys replaced (file key names and units, e.g.
    ``steering_friction_Nm``; unknown keys are errors), re-validated."""
    keymap = _SCHEMA["corrections"][1]
    current = {k: getattr(vehicle.corrections, attr) / (f or 1.0) for k, (attr, f) in keymap.items()}
    v = replace(vehicle, corrections=_build(InputCorrections, "corrections", {**current, **keys}, src))
    validate(v)
    return v


def load_vehicle(name_or_path: str | Path | None = None) -> Vehicle:
    """Load a vehicle file (default: the shipped reference vehicle), validated, in SI units."""
    path = resolve_vehicle_path(name_or_path or DEFAULT_VEHICLE)
    return vehicle_from_dict(_read_toml(path), src=str(path))


def _check(cond: bool, src: str, msg: str) -> None:
    if not cond:
        raise ConfigError(f"{src}: {msg}")


#: plausibility ranges of a road vehicle with MDPS (cars, SUVs, light vans; docs/tuning.md)
MASS_RANGE_KG = (300.0, 8000.0)
WHEELBASE_RANGE_M = (1.5, 5.0)
AXLE_SHARE_RANGE = (0.2, 0.8)  # lf / L and lr / L: the CG lies between the axles, not at one
YAW_INDEX_RANGE = (0.5, 1.6)  # Iz / (m lf lr), the dynamic index (about 1 for a car)
TRACK_RANGE_M = (0.9, 2.2)
RATIO_RANGE = (8.0, 30.0)
CORNERING_COEF_RANGE = (4.0, 45.0)  # per-tire cornering stiffness / static tire load [1/rad]
TRAIL_RANGE_M = (0.02, 0.3)  # K / C_f: the total (pneumatic + mechanical) trail


def _in(x: float, rng: tuple[float, float]) -> bool:
    return rng[0] <= x <= rng[1]


def _fmt(rng: tuple[float, float]) -> str:
    return f"{rng[0]:g}..{rng[1]:g}"


def validate(v: Vehicle) -> None:
    """Physical plausibility of a road vehicle with MDPS; raise :class:`ConfigError` in one line that
    names the file, the key(s) and the range."""
    s = v.source or v.name
    b, t, o, e = v.body, v.tires, v.overlay, v.estimator
    _check(_in(b.mass, MASS_RANGE_KG), s, f"[vehicle] mass_kg {b.mass:g} outside {_fmt(MASS_RANGE_KG)} kg")
    _check(b.lf > 0.0 and b.lr > 0.0, s, f"[vehicle] lf_m {b.lf:g} and lr_m {b.lr:g} must be > 0")
    L = b.wheelbase
    _check(
        _in(L, WHEELBASE_RANGE_M),
        s,
        f"[vehicle] lf_m + lr_m = wheelbase {L:g} m outside {_fmt(WHEELBASE_RANGE_M)} m",
    )
    _check(
        _in(b.lf / L, AXLE_SHARE_RANGE),
        s,
        f"[vehicle] lf_m {b.lf:g} is {b.lf / L:.2f} of the wheelbase, outside {_fmt(AXLE_SHARE_RANGE)}",
    )
    di = b.yaw_inertia / (b.mass * b.lf * b.lr)
    _check(
        _in(di, YAW_INDEX_RANGE),
        s,
        f"[vehicle] yaw_inertia_kgm2 {b.yaw_inertia:g} is {di:.2f} x mass lf lr, "
        f"outside {_fmt(YAW_INDEX_RANGE)}",
    )
    for key, tr in (("track_front_m", b.track_front), ("track_rear_m", b.track_rear)):
        _check(_in(tr, TRACK_RANGE_M), s, f"[vehicle] {key} {tr:g} outside {_fmt(TRACK_RANGE_M)} m")
    _check(
        _in(v.steering.ratio, RATIO_RANGE),
        s,
        f"[steering] ratio {v.steering.ratio:g} outside {_fmt(RATIO_RANGE)}",
    )
    fz_f = b.mass * G * b.lr / (2.0 * L)  # static load per front tire [N]
    fz_r = b.mass * G * b.lf / (2.0 * L)
    for key, stiff, fz in (("cf_N_per_rad", t.cf, fz_f), ("cr_N_per_rad", t.cr, fz_r)):
        _check(
            _in(stiff / fz, CORNERING_COEF_RANGE),
            s,
            f"[tires] {key} {stiff:g} is {stiff / fz:.1f} x the static tire load ({fz:.0f} N) per rad, "
            f"outside {_fmt(CORNERING_COEF_RANGE)}",
        )
    _check(
        _in(t.align_rate / t.cf, TRAIL_RANGE_M),
        s,
        f"[tires] align_rate_Nm_per_rad {t.align_rate:g} / cf_N_per_rad = trail {t.align_rate / t.cf:.3f} m, "
        f"outside {_fmt(TRAIL_RANGE_M)} m",
    )
    _check(0.0 < o.max_torque <= 10.0, s, "overlay max_torque_Nm must lie in (0, 10]")
    _check(0.0 < o.max_rate <= 100.0, s, "overlay max_rate_Nm_per_s must lie in (0, 100]")
    _check(0.0 <= o.min_speed < o.max_speed, s, "overlay needs 0 <= min_speed_kmh < max_speed_kmh")
    _check(0.0 < o.max_steering_angle <= math.pi, s, "overlay max_steering_angle_deg must lie in (0, 180]")
    _check(o.driver_override_torque > 0.0, s, "overlay driver_override_Nm must be > 0")
    for key, val in (
        ("hold_off_s", o.hold_off),
        ("rearm_delay_s", o.rearm_delay),
        ("fault_persist_s", o.fault_persist),
        ("fault_recover_s", o.fault_recover),
        ("law_time_constant_s", o.law_time),
    ):
        _check(0.0 <= val <= 60.0, s, f"overlay {key} must lie in 0..60 s, got {val}")
    for name in ("q_beta", "q_yaw", "q_fw", "q_mw", "r_yaw", "r_align"):
        _check(getattr(e, name) > 0.0, s, f"estimator {name} must be > 0")
    for name in ("p0_beta", "p0_yaw", "p0_fw", "p0_mw"):
        _check(getattr(e, name) > 0.0, s, f"estimator {name} must be > 0")
    _check(e.min_speed > 0.5, s, "estimator min_speed_kmh must be > 1.8 km/h (the model divides by vx)")
    _check(e.converge_time >= 0.0, s, "estimator converge_time_s must be >= 0")
    c = v.corrections
    _check(0.0 <= c.friction <= 5.0, s, f"corrections steering_friction_Nm {c.friction} outside 0..5")
    _check(c.friction_rate_width > 0.0, s, "corrections friction_rate_deg_s must be > 0")
    _check(abs(c.torsion_compliance) <= 5.0 * DEG, s, "corrections torsion_deg_per_Nm must lie in -5..5")
    _check(abs(c.steer_offset) <= 20.0 * DEG, s, "corrections steering_angle_offset_deg must lie in -20..20")
    _check(abs(c.yaw_bias) <= 5.0 * DEG, s, "corrections yaw_rate_bias_deg_s must lie in -5..5")
    _check(abs(c.align_offset) <= 200.0, s, "corrections align_offset_Nm must lie in -200..200")
    lg = v.learning
    _check(lg.enabled in (0.0, 1.0), s, f"[learning] enabled must be 0 or 1, got {lg.enabled:g}")
    _check(0.9 <= lg.accel_scale <= 1.3, s, f"[learning] accel_scale {lg.accel_scale:g} outside 0.9..1.3")
    _check(
        0.0 <= lg.friction_prior <= 2.0, s, f"[learning] friction_prior_Nm {lg.friction_prior:g} outside 0..2"
    )
    _check(
        0.0 <= lg.torsion_above_bar <= 3.0 * DEG,
        s,
        "[learning] torsion_above_bar_deg_per_Nm must lie in 0..3",
    )
    _check(
        e.q_wind > 0 and e.q_wind_moment > 0 and e.q_bank > 0, s, "estimator q_wind/q_bank keys must be > 0"
    )
    _check(e.r_lat_accel > 0 and e.p0_bank > 0, s, "estimator r_lat_accel_m_per_s2 and p0_bank_N must be > 0")
    _check(0.0 <= e.wind_cp_weight <= 1.0, s, "estimator wind_cp_weight must be within 0..1")
    _check(abs(e.wind_cp) <= 2.0, s, "estimator wind_cp_m must be within -2..2 m")
