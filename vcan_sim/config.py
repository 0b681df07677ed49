"""Simulator-only vehicle data: the ``[sim]`` table of a vehicle file, as typed dataclasses in SI.

The estimator's parameters (mass, yaw inertia, lf, lr, tread, steering ratio N) come from
:func:`lde.params.load_vehicle`; everything the richer plant needs on top lives in the optional
``[sim]`` table and its sub-tables. Every key has a documented default (the values below, chosen for
the paper's test vehicle, a Hyundai YF Sonata with 215/60R16 tires), so ``[sim]`` may be absent.
Keys carry their unit in their name like the rest of the file; unknown keys are errors.

Layout (all optional)::

    [sim]                  cg_height_m, roll_axis_height_m, ... (ChassisParams)
    [sim.tire]             Pacejka Magic Formula coefficients (TireCoeffs)
    [sim.steering]         column / rack / MDPS (SteeringSystemParams)
    [sim.aero]             frontal area, drag, crosswind coefficient curves (AeroParams)
    [sim.driver]           lane-keeping driver (DriverParams)
    [sim.sensors]          noise, bias, delay (SensorParams)
    [sim.seats.NAME]       payload positions: x_behind_front_axle_m, y_left_m, z_m
    [sim.payload]          what this car always carries: seat name = mass in kg (default: nothing)

Signs: ISO 8855 (x forward, y left, z up).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from lde.errors import ConfigError
from lde.params import Vehicle
from lde.units import DEG, KMH


@dataclass(frozen=True)
class ChassisParams:
    """Body data the 2-DOF estimator does not know.

    Attributes:
        cg_height: CG height above ground [m] (unloaded reference vehicle).
        roll_axis_height: roll-axis height at the CG station [m] (roll arm = cg_height - this).
        roll_stiffness_front: front roll stiffness [Nm/rad].
        roll_stiffness_rear: rear roll stiffness [Nm/rad].
        roll_damping_front: front roll damping [Nm s/rad].
        roll_damping_rear: rear roll damping [Nm s/rad].
        roll_inertia: sprung-mass roll inertia about the roll axis [kg m^2].
        sprung_fraction: sprung mass / total mass [-].
        rolling_resistance: rolling-resistance coefficient [-] (force = coeff * Fz).
        speed_gain: gain of the speed holder (cruise control) [1/s]: F = m k (v_ref - vx) + resistances.
        load_filter_time: time constant of the lateral acceleration used for load transfer [s]
            (breaks the algebraic loop tire force -> load -> tire force; a few ms).
    """

    cg_height: float = 0.55
    roll_axis_height: float = 0.12
    roll_stiffness_front: float = 52000.0
    roll_stiffness_rear: float = 38000.0
    roll_damping_front: float = 3200.0
    roll_damping_rear: float = 2600.0
    roll_inertia: float = 520.0
    sprung_fraction: float = 0.88
    rolling_resistance: float = 0.012
    speed_gain: float = 0.5
    load_filter_time: float = 0.005


@dataclass(frozen=True)
class TireCoeffs:
    """Pacejka Magic Formula (lateral force and aligning moment), pure side slip, per tire.

    Lateral force, with dfz = (Fz - Fz0)/Fz0::

        Fy = D sin(C atan(B a - E (B a - atan(B a))))
        D  = mu Fz,  mu = pDy1 (1 + pDy2 dfz)
        Ky = pKy1 Fz0 sin(2 atan(Fz / (pKy2 Fz0)))      cornering stiffness [N/rad]
        B  = Ky / (C D),  C = pCy1,  E = pEy1 + pEy2 dfz

    Pneumatic trail (falls with slip, grows with load) and aligning moment::

        t  = Dt cos(Ct atan(Bt a - Et (Bt a - atan(Bt a)))) cos(a)
        Dt = t0 (1 + qDz2 dfz),  Bt = qBz1 + qBz2 dfz
        Mz = -t Fy                                     (ISO, at the contact patch)

    On the steering axis the front tire adds the mechanical trail ``t_m`` (caster trail and the
    steering geometry's lever, lumped): T_align,i = (t + t_m) Fy (paper sign).

    Transient: the slip angle that makes the force lags the kinematic one by the relaxation length
    sigma [m] (``relaxation_length``; first order, time constant sigma / vx; 0 = instantaneous).

    Attributes: ``fz0`` [N], ``t0``, ``mech_trail`` and ``relaxation_length`` [m]; the rest dimensionless.
    The defaults give, for a 215/60R16 at the reference vehicle's static front load (~4.4 kN),
    a cornering stiffness of about 64 kN/rad and an aligning-torque slope on the steering axis of
    about 7.2 kNm/rad per tire (the paper measured 6750-7640 Nm/rad).
    """

    fz0: float = 4500.0
    pCy1: float = 1.30
    pDy1: float = 1.00
    pDy2: float = -0.08
    pEy1: float = -0.50
    pEy2: float = -0.20
    pKy1: float = 14.5
    pKy2: float = 1.20
    t0: float = 0.048
    qDz2: float = 0.35
    qBz1: float = 10.0
    qBz2: float = -2.0
    Ct: float = 1.25
    Et: float = -1.0
    mech_trail: float = 0.065
    relaxation_length: float = 0.45


@dataclass(frozen=True)
class SteeringSystemParams:
    """Column and rack (two inertias joined by the torsion bar that is the torque sensor), MDPS.

    All referred to the steering column (angles are steering-wheel angles, torques at the column).

    Attributes:
        wheel_inertia: steering wheel + upper column inertia [kg m^2].
        rack_inertia: lower column + motor (through its gear) + rack + road wheels about the
            kingpins, referred to the column [kg m^2].
        torsion_stiffness: torsion bar stiffness [Nm/rad] (column torque = k (th_sw - th_p)).
        torsion_damping: torsion bar damping [Nm s/rad].
        column_damping: upper column bearing viscous friction [Nm s/rad].
        rack_damping: rack viscous friction referred to the column [Nm s/rad].
        rack_coulomb: rack + gear Coulomb friction referred to the column [Nm].
        coulomb_smoothing: friction is Tc tanh(w / w_eps); w_eps [rad/s] (a fixed-step integrator
            cannot resolve stiction exactly; below w_eps the friction acts as viscous).
        boost_torque: column-torque breakpoints of the boost curve [Nm] (increasing, from 0).
        boost_assist: assist torque at those breakpoints [Nm] (odd-symmetric extension).
        boost_speed: vehicle-speed breakpoints of the boost scaling [m/s].
        boost_scale: boost scaling at those speeds [-] (less assist at speed).
        overlay_max: the MDPS clamps the applied overlay torque to +-this [Nm].
        overlay_time: first-order lag of the motor current loop applying the overlay [s].
    """

    wheel_inertia: float = 0.045
    rack_inertia: float = 0.090
    torsion_stiffness: float = 2.0 / DEG
    torsion_damping: float = 0.05
    column_damping: float = 0.05
    rack_damping: float = 0.40
    rack_coulomb: float = 0.35
    coulomb_smoothing: float = 0.05
    boost_torque: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 3.0, 4.0, 6.0, 10.0)
    boost_assist: tuple[float, ...] = (0.0, 0.25, 0.9, 3.2, 6.5, 10.5, 18.0, 30.0)
    boost_speed: tuple[float, ...] = (0.0, 60.0 * KMH, 100.0 * KMH, 160.0 * KMH)
    boost_scale: tuple[float, ...] = (1.6, 1.0, 0.8, 0.7)
    overlay_max: float = 5.0
    overlay_time: float = 0.01


@dataclass(frozen=True)
class AeroParams:
    """Aerodynamics (paper eqs. 1-2) with flat-plate-like coefficient curves.

    The airflow side-slip angle beta_cw is the angle between the vehicle's x axis and the air
    flowing over it (positive when the air moves toward +y, i.e. the wind comes from the right).
    Coefficients (A = frontal area as reference area, l = wheelbase as reference length,
    moment about the mid-wheelbase point, left positive)::

        Cy(b) = cy1 sin b |cos b| + cy2 sin b |sin b|   (slope cy1 at b = 0, cy2 at b = 90 deg)
        Cn(b) = cn1 sin b cos b                         (zero at 90 deg: the flow is symmetric)
        Cx(b) = cx cos b |cos b|                        (drag, along -x)

    Attributes:
        frontal_area: A [m^2]; air_density: rho [kg/m^3]; cy1, cy2, cn1, cx [-].
    """

    frontal_area: float = 2.2
    air_density: float = 1.20
    cy1: float = 2.5
    cy2: float = 3.0
    cn1: float = 0.8
    cx: float = 0.30


@dataclass(frozen=True)
class DriverParams:
    """Lane-keeping driver acting on the steering wheel with torque.

    The driver looks ``preview_time`` ahead, turns the lateral error there (plus a slow integral
    of it) into a wanted steering-wheel angle, lags it by ``lag_time`` (reaction and
    neuromuscular delay lumped) and produces wheel torque with arm stiffness and damping.

    Attributes:
        preview_time [s], lateral_gain [(m/s^2)/m], integral_gain [(m/s^2)/(m s)],
        heading_gain [rad(sw)/rad], understeer_gradient: the driver's learnt k_us [rad s^2/m],
        lag_time [s], arm_stiffness [Nm/rad], arm_damping [Nm s/rad],
        arm_integral [Nm/(rad s)] (slow build-up of holding torque),
        noise_torque: std of the driver's torque noise [Nm]; noise_time: its correlation time [s];
        gain_spread: relative per-seed spread of the gains (uniform +-) [-].
    """

    preview_time: float = 1.3
    lateral_gain: float = 4.0
    integral_gain: float = 0.3
    heading_gain: float = 0.0
    understeer_gradient: float = 0.0018
    lag_time: float = 0.15
    arm_stiffness: float = 60.0
    arm_damping: float = 1.2
    arm_integral: float = 150.0
    noise_torque: float = 0.04
    noise_time: float = 0.4
    gain_spread: float = 0.10


@dataclass(frozen=True)
class SensorParams:
    """Sensor noise (std), bias and delay. Quantisation is the DBC's scaling (done when encoding).

    Attributes:
        column_torque_noise [Nm], assist_torque_noise [Nm], steering_angle_noise [rad],
        steering_rate_noise [rad/s], yaw_rate_noise [rad/s], lat_accel_noise [m/s^2],
        speed_noise [m/s]; *_bias the same units (added constant offsets; default 0);
        mdps_delay: computation delay of the MDPS torque signals [s] (paper: 3.9 ms).
        mdps_angle_at_motor: the MDPS message's steering angle and rate are sensed at the motor,
            below the torsion bar (pinion angle = N delta_f), as a column MDPS does; False: at the
            steering wheel, above it (the torsion bar's twist T_column / k_tb included).
        sas_angle_at_motor: the separate steering-angle sensor message (hyundai SAS11) reads the
            pinion angle below the torsion bar (a car whose angle signal comes from the MDPS motor's
            position); False (default): the steering wheel, above the torsion bar, twist included.
    """

    column_torque_noise: float = 0.005
    assist_torque_noise: float = 0.005
    steering_angle_noise: float = 0.02 * DEG
    steering_rate_noise: float = 0.2 * DEG
    yaw_rate_noise: float = 0.02 * DEG
    lat_accel_noise: float = 0.02
    speed_noise: float = 0.02
    column_torque_bias: float = 0.0
    assist_torque_bias: float = 0.0
    steering_angle_bias: float = 0.0
    yaw_rate_bias: float = 0.0
    lat_accel_bias: float = 0.0
    mdps_delay: float = 0.0039
    mdps_angle_at_motor: bool = True
    sas_angle_at_motor: bool = False


@dataclass(frozen=True)
class Seat:
    """A payload position. x_behind_front_axle [m] (rearward positive, like eq. 18), y_left [m], z [m]."""

    x_behind_front_axle: float
    y_left: float
    z: float = 0.5


def default_seats() -> dict[str, Seat]:
    """Payload positions of a mid-size sedan (2.8 m wheelbase)."""
    return {
        "driver": Seat(1.25, 0.37, 0.55),
        "front_passenger": Seat(1.25, -0.37, 0.55),
        "rear_left": Seat(2.10, 0.40, 0.55),
        "rear_right": Seat(2.10, -0.40, 0.55),
        "rear_middle": Seat(2.10, 0.0, 0.55),
        "trunk": Seat(3.05, 0.0, 0.60),
        "roof": Seat(1.70, 0.0, 1.55),
    }


@dataclass(frozen=True)
class SimParams:
    """Everything in ``[sim]``.

    ``payload``: what the car always carries, as (seat name, mass [kg]) pairs (``[sim.payload]``);
    a scenario's payload comes on top of it (:func:`vcan_sim.payload.combined`). The vehicle
    file's ``[vehicle]`` body stays the unloaded car (what a spec sheet gives); the truth's
    ``Mw_ref`` is about its CG.
    """

    chassis: ChassisParams = field(default_factory=ChassisParams)
    tire: TireCoeffs = field(default_factory=TireCoeffs)
    steering: SteeringSystemParams = field(default_factory=SteeringSystemParams)
    aero: AeroParams = field(default_factory=AeroParams)
    driver: DriverParams = field(default_factory=DriverParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    seats: dict[str, Seat] = field(default_factory=default_seats)
    payload: tuple[tuple[str, float], ...] = ()


# ---------------------------------------------------------------------------------------------
# TOML keys (with units) -> attribute and factor to SI. A factor of None marks a list.

_KeyMap = Mapping[str, tuple[str, float | None]]

_CHASSIS_KEYS: _KeyMap = {
    "cg_height_m": ("cg_height", 1.0),
    "roll_axis_height_m": ("roll_axis_height", 1.0),
    "roll_stiffness_front_Nm_per_rad": ("roll_stiffness_front", 1.0),
    "roll_stiffness_rear_Nm_per_rad": ("roll_stiffness_rear", 1.0),
    "roll_damping_front_Nms_per_rad": ("roll_damping_front", 1.0),
    "roll_damping_rear_Nms_per_rad": ("roll_damping_rear", 1.0),
    "roll_inertia_kgm2": ("roll_inertia", 1.0),
    "sprung_fraction": ("sprung_fraction", 1.0),
    "rolling_resistance": ("rolling_resistance", 1.0),
    "speed_gain_per_s": ("speed_gain", 1.0),
    "load_filter_time_s": ("load_filter_time", 1.0),
}
_TIRE_UNITS = {
    "fz0": "fz0_N",
    "t0": "t0_m",
    "mech_trail": "mech_trail_m",
    "relaxation_length": "relaxation_length_m",
}  # the rest are dimensionless
_TIRE_KEYS: _KeyMap = {_TIRE_UNITS.get(f.name, f.name): (f.name, 1.0) for f in fields(TireCoeffs)}
_STEERING_KEYS: _KeyMap = {
    "wheel_inertia_kgm2": ("wheel_inertia", 1.0),
    "rack_inertia_kgm2": ("rack_inertia", 1.0),
    "torsion_stiffness_Nm_per_deg": ("torsion_stiffness", 1.0 / DEG),
    "torsion_damping_Nms_per_rad": ("torsion_damping", 1.0),
    "column_damping_Nms_per_rad": ("column_damping", 1.0),
    "rack_damping_Nms_per_rad": ("rack_damping", 1.0),
    "rack_coulomb_Nm": ("rack_coulomb", 1.0),
    "coulomb_smoothing_rad_per_s": ("coulomb_smoothing", 1.0),
    "boost_torque_Nm": ("boost_torque", None),
    "boost_assist_Nm": ("boost_assist", None),
    "boost_speed_kmh": ("boost_speed", KMH),
    "boost_scale": ("boost_scale", None),
    "overlay_max_Nm": ("overlay_max", 1.0),
    "overlay_time_s": ("overlay_time", 1.0),
}
_AERO_KEYS: _KeyMap = {
    "frontal_area_m2": ("frontal_area", 1.0),
    "air_density_kg_per_m3": ("air_density", 1.0),
    "cy1": ("cy1", 1.0),
    "cy2": ("cy2", 1.0),
    "cn1": ("cn1", 1.0),
    "cx": ("cx", 1.0),
}
_DRIVER_KEYS: _KeyMap = {
    "preview_time_s": ("preview_time", 1.0),
    "lateral_gain_per_s2": ("lateral_gain", 1.0),
    "integral_gain_per_s3": ("integral_gain", 1.0),
    "understeer_gradient_rad_s2_per_m": ("understeer_gradient", 1.0),
    "heading_gain": ("heading_gain", 1.0),
    "lag_time_s": ("lag_time", 1.0),
    "arm_stiffness_Nm_per_rad": ("arm_stiffness", 1.0),
    "arm_damping_Nms_per_rad": ("arm_damping", 1.0),
    "arm_integral_Nm_per_rads": ("arm_integral", 1.0),
    "noise_torque_Nm": ("noise_torque", 1.0),
    "noise_time_s": ("noise_time", 1.0),
    "gain_spread": ("gain_spread", 1.0),
}
_SENSOR_KEYS: _KeyMap = {
    "column_torque_noise_Nm": ("column_torque_noise", 1.0),
    "assist_torque_noise_Nm": ("assist_torque_noise", 1.0),
    "steering_angle_noise_deg": ("steering_angle_noise", DEG),
    "steering_rate_noise_deg_per_s": ("steering_rate_noise", DEG),
    "yaw_rate_noise_deg_per_s": ("yaw_rate_noise", DEG),
    "lat_accel_noise_m_per_s2": ("lat_accel_noise", 1.0),
    "speed_noise_m_per_s": ("speed_noise", 1.0),
    "column_torque_bias_Nm": ("column_torque_bias", 1.0),
    "assist_torque_bias_Nm": ("assist_torque_bias", 1.0),
    "steering_angle_bias_deg": ("steering_angle_bias", DEG),
    "yaw_rate_bias_deg_per_s": ("yaw_rate_bias", DEG),
    "lat_accel_bias_m_per_s2": ("lat_accel_bias", 1.0),
    "mdps_delay_s": ("mdps_delay", 1.0),
    "mdps_angle_at_motor": ("mdps_angle_at_motor", None),
    "sas_angle_at_motor": ("sas_angle_at_motor", None),
}
_SUBTABLES: dict[str, tuple[type, _KeyMap]] = {
    "tire": (TireCoeffs, _TIRE_KEYS),
    "steering": (SteeringSystemParams, _STEERING_KEYS),
    "aero": (AeroParams, _AERO_KEYS),
    "driver": (DriverParams, _DRIVER_KEYS),
    "sensors": (SensorParams, _SENSOR_KEYS),
}


def _num(src: str, where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ConfigError(f"{src}: [{where}] {key} must be a finite number, got {value!r}")
    return float(value)


def _build(cls: type, keymap: _KeyMap, raw: Any, src: str, where: str) -> Any:
    if not isinstance(raw, dict):
        raise ConfigError(f"{src}: [{where}] must be a table")
    unknown = sorted(set(raw) - set(keymap))
    if unknown:
        raise ConfigError(
            f"{src}: unknown key(s) in [{where}]: {', '.join(unknown)} (known: {', '.join(sorted(keymap))})"
        )
    kw: dict[str, Any] = {}
    for key, value in raw.items():
        attr, factor = keymap[key]
        default = next(f.default for f in fields(cls) if f.name == attr)
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{src}: [{where}] {key} must be true or false, got {value!r}")
            kw[attr] = value
        elif isinstance(default, tuple):
            if not isinstance(value, list) or not value:
                raise ConfigError(f"{src}: [{where}] {key} must be a non-empty list of numbers")
            scale = 1.0 if factor is None else factor
            kw[attr] = tuple(_num(src, where, key, x) * scale for x in value)
        else:
            kw[attr] = _num(src, where, key, value) * (1.0 if factor is None else factor)
    return cls(**kw)


def sim_params_from_vehicle(vehicle: Vehicle) -> SimParams:
    """Parse ``vehicle.sim`` (the raw ``[sim]`` table) into :class:`SimParams`; ConfigError on mistakes."""
    raw = dict(vehicle.sim)
    src = vehicle.source or vehicle.name
    subs = {k: raw.pop(k) for k in list(raw) if k in _SUBTABLES or k in ("seats", "payload")}
    chassis = _build(ChassisParams, _CHASSIS_KEYS, raw, src, "sim")
    parts = {
        name: _build(cls, keys, subs.get(name, {}), src, f"sim.{name}")
        for name, (cls, keys) in _SUBTABLES.items()
    }
    seats = default_seats()
    seat_raw = subs.get("seats", {})
    if not isinstance(seat_raw, dict):
        raise ConfigError(f"{src}: [sim.seats] must be a table of tables")
    seat_keys = {
        "x_behind_front_axle_m": ("x_behind_front_axle", 1.0),
        "y_left_m": ("y_left", 1.0),
        "z_m": ("z", 1.0),
    }
    for name, tab in seat_raw.items():
        if not isinstance(tab, dict) or "x_behind_front_axle_m" not in tab or "y_left_m" not in tab:
            raise ConfigError(f"{src}: [sim.seats.{name}] needs x_behind_front_axle_m and y_left_m")
        seats[name] = _build(Seat, seat_keys, tab, src, f"sim.seats.{name}")
    payload = _payload_items(subs.get("payload", {}), seats, src)
    sp = SimParams(chassis=chassis, seats=seats, payload=payload, **parts)
    validate_sim(sp, src)
    return sp


def _payload_items(raw: Any, seats: Mapping[str, Seat], src: str) -> tuple[tuple[str, float], ...]:
    """``[sim.payload]``: seat name = mass [kg] (0 < m <= 2000) at a known seat."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{src}: [sim.payload] must be a table of seat name = mass in kg")
    items = []
    for seat, mass in raw.items():
        if seat not in seats:
            raise ConfigError(
                f"{src}: [sim.payload] {seat}: unknown seat (known: {', '.join(sorted(seats))})"
            )
        m = _num(src, "sim.payload", seat, mass)
        if not 0.0 < m <= 2000.0:
            raise ConfigError(f"{src}: [sim.payload] {seat} must lie in (0, 2000] kg, got {m}")
        items.append((seat, m))
    return tuple(items)


def validate_sim(sp: SimParams, src: str = "<sim>") -> None:
    """Plausibility checks; ConfigError naming the field."""
    c, t, s = sp.chassis, sp.tire, sp.steering

    def check(cond: bool, msg: str) -> None:
        if not cond:
            raise ConfigError(f"{src}: [sim] {msg}")

    check(0.2 <= c.cg_height <= 2.5, "cg_height_m must lie in 0.2..2.5")
    check(0.0 <= c.roll_axis_height < c.cg_height, "roll_axis_height_m must lie in 0..cg_height_m")
    check(c.roll_stiffness_front > 0 and c.roll_stiffness_rear > 0, "roll stiffnesses must be > 0")
    check(c.roll_inertia > 0 and 0.5 <= c.sprung_fraction <= 1.0, "roll inertia > 0, sprung fraction 0.5..1")
    check(c.load_filter_time > 0, "load_filter_time_s must be > 0")
    check(0.0 <= c.rolling_resistance <= 0.1, "rolling_resistance must lie in 0..0.1")
    check(0.0 < c.speed_gain <= 50.0, "speed_gain_per_s must lie in (0, 50] (unstable speed holder at <= 0)")
    check(
        t.fz0 > 0 and t.pKy1 > 0 and t.pKy2 > 0 and t.pDy1 > 0 and t.pCy1 > 0, "tire coefficients must be > 0"
    )
    check(t.pEy1 <= 1.0 and t.Et <= 1.0, "Magic Formula E must be <= 1")
    check(0.0 <= t.relaxation_length <= 3.0, "tire relaxation_length_m must lie in 0..3")
    check(
        s.wheel_inertia > 0 and s.rack_inertia > 0 and s.torsion_stiffness > 0,
        "steering inertias, stiffness > 0",
    )
    check(s.coulomb_smoothing > 0, "coulomb_smoothing_rad_per_s must be > 0")
    check(len(s.boost_torque) == len(s.boost_assist) >= 2, "boost curve needs equal-length lists (>= 2)")
    check(
        all(b > a for a, b in zip(s.boost_torque, s.boost_torque[1:], strict=False)),
        "boost_torque_Nm must increase",
    )
    check(len(s.boost_speed) == len(s.boost_scale) >= 1, "boost speed/scale lists need equal length")
    check(
        all(b > a for a, b in zip(s.boost_speed, s.boost_speed[1:], strict=False)),
        "boost_speed_kmh must increase",
    )
    check(s.overlay_max > 0 and s.overlay_time > 0, "overlay_max_Nm and overlay_time_s must be > 0")
    check(sp.aero.frontal_area > 0 and sp.aero.air_density > 0, "aero area and density must be > 0")
    check(sp.driver.lag_time > 0 and sp.driver.noise_time > 0, "driver lag/noise times must be > 0")
    check(0.0 <= sp.sensors.mdps_delay <= 0.1, "mdps_delay_s must lie in 0..0.1")
