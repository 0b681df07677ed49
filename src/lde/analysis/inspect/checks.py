"""Physics checks of a profile's signs and scales, from a drive alone.

Each check fits one steady-state relation of the bicycle model (:mod:`lde.analysis.inspect.relation`)
over the parts of the drive where it holds, on signals low-passed onto one grid
(:mod:`lde.analysis.inspect.resample`), all in SI with the profile's signs applied (ISO 8855: x
forward, y left, z up; left turns positive):

a. **lateral acceleration** against speed x yaw rate, ``a_y = s v r + c``: in a steady turn the
   accelerometer reads the centripetal acceleration. ``s`` is 1 plus the roll tilt (the body rolls
   out of the turn and tips the sensor toward gravity: 1.03-1.15 for a road car) and the sensors'
   scale errors: plausible :data:`ACCEL_SLOPE`. The intercept ``c`` is a bank or a sensor offset.
b. **yaw rate against steering**: ``r = v delta_sw / (N L (1 + K_us v^2))`` at low lateral
   acceleration (the tires' linear range), fitted as ``N L r / v = s (delta_sw - delta_0)``: the
   slope ``s = 1 / (1 + K_us v^2)`` gives the understeer coefficient K_us [s^2/m^2] (reported as the
   understeer gradient ``K_us L g`` in deg/g, plausible for a road car: :data:`UNDERSTEER_DEG_PER_G`;
   N and L from the vehicle file), the intercept the steering-angle offset ``delta_0`` (the angle at
   zero yaw rate, taking the yaw rate as unbiased).
c. **wheel speeds** left against right, ``(v_R - v_L) / v = s r t / v + c``: in a left turn the
   right wheels run on the larger circle (t the mean tread). ``c`` is a difference of tire radii.
   Only where the profile's DBC has per-wheel speeds named front/rear left/right.
d. **torque** against the steering it causes: in steady cornering the tires' aligning torque turns
   the wheel out of the turn, and the driver's torque plus the assist holds it in: both torques
   have the sign of the turn (``v r``). Sign only: the torque needed depends on the boost curve, the
   speed and who steers (a lane-keeping system's command is a torque toward the turn as well, so a
   sign found while it steers is the EPS torque's, and says nothing about its scale or its share).
e. **speed** against the mean of the wheel speeds, ``v = s v_wheels`` (through the origin): a
   vehicle-speed signal with a wrong unit shows here. Only where the speed is another signal than
   the wheel speeds' mean.
f. **steering rate** against the time derivative of the steering angle, ``rate = s d(delta_sw)/dt +
   c``: the same sensor's two readings, so the slope is 1 up to the sensor's own filtering
   (:data:`RATE_SLOPE`). Only where the rate is signed (a magnitude has no sign to check), and, as
   every check, on the car moving (a standing car's sensors may still be starting up).

**Outcomes.** *not enough excitation* when fewer than :data:`MIN_SAMPLES` grid samples pass the
gates, the effective sample size is below :data:`MIN_EFFECTIVE`, the regressor barely moves, or the
slope's interval includes zero while it also reaches the physical range (the data cannot tell the
sign): never a pass. *fail* when the slope's interval excludes zero on the wrong side (a sign), or
the bracket of the slope (:attr:`Relation.bracket`) misses the physical range (a scale, or no
response at all). *pass* otherwise. *not applicable* when the profile lacks what the check needs.

**Which sign is wrong.** A check relates two signals, and a mirror-image drive (every lateral
signal negated) is as physical as the real one: lateral signals alone can say which signs disagree,
never which side is left. The wheel speeds can: their names (front left, ...) are a fact about the
car, not a sign convention. Every check relates one input to the yaw rate, so
:func:`attribute_signs` decides the yaw rate first (from check c when it decided; else from the
majority of the others: one wrong yaw-rate sign fails them all) and each other input relative to it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum

import numpy as np

from lde.analysis.calibrate import MAX_ACCEL_SCALE, MIN_ACCEL_SCALE
from lde.analysis.inspect.relation import Relation, fit_relation
from lde.analysis.inspect.resample import Grid
from lde.params import Vehicle
from lde.units import DEG, KMH, G

__all__ = [
    "Outcome",
    "Geometry",
    "Check",
    "SignFinding",
    "run_checks",
    "attribute_signs",
    "with_fixes",
    "sign_line",
    "ACCEL_SLOPE",
    "UNDERSTEER_DEG_PER_G",
    "WHEEL_SLOPE",
    "SPEED_SCALE",
    "RATE_SLOPE",
    "MIN_RATE_SPREAD",
    "MIN_SAMPLES",
    "MIN_EFFECTIVE",
    "MAX_STEER_RATE",
    "MAX_LAT_ACCEL",
    "LOW_LAT_ACCEL",
    "WHEELS",
]

#: a: plausible slope of a_y on v r: the roll tilt and sensor scale (as lde.analysis.calibrate)
ACCEL_SLOPE = (MIN_ACCEL_SCALE, MAX_ACCEL_SCALE)
#: b: plausible understeer gradient of a road car [deg/g] (sedans 1-4, SUVs up to 6, with room for
#: a steering ratio in the vehicle file that is the spec's rather than the effective one)
UNDERSTEER_DEG_PER_G = (0.0, 8.0)
#: c: plausible slope of the wheel-speed difference on r t: the tread and tire-radius differences
WHEEL_SLOPE = (0.8, 1.25)
#: e: plausible ratio of the speed signal to the wheels' mean (a reference speed, tire wear)
SPEED_SCALE = (0.95, 1.05)
#: f: plausible slope of the steering rate on the angle's derivative (one sensor, its own filter)
RATE_SLOPE = (0.8, 1.25)
#: f: the least spread (std) of the angle's low-passed derivative that counts as excitation [rad/s]
#: (half the 1 deg/s step of a typical rate signal: its low-passed mean resolves that much)
MIN_RATE_SPREAD = 0.5 * DEG
#: fewer grid samples than this through a check's gates: not enough excitation (5 s at 10/s)
MIN_SAMPLES = 50
#: fewer effective independent samples than this: not enough excitation
MIN_EFFECTIVE = 10.0
#: the steady-state gate: steering-wheel rate (low-passed) at most [rad/s]
MAX_STEER_RATE = 10.0 * DEG
#: the tires' linear range: |v r| at most [m/s^2] (checks a, c, d)
MAX_LAT_ACCEL = 4.0
#: "low lateral acceleration" of check b [m/s^2]
LOW_LAT_ACCEL = 2.0
#: the per-wheel signal names of the grid: front left, front right, rear left, rear right
WHEELS = ("wheel_fl", "wheel_fr", "wheel_rl", "wheel_rr")


class Outcome(StrEnum):
    """What a check says."""

    PASS = "pass"
    FAIL = "fail"
    NOT_ENOUGH_EXCITATION = "not enough excitation"
    NOT_APPLICABLE = "not applicable"


@dataclass(frozen=True)
class Geometry:
    """What the checks take from the vehicle file (SI).

    Attributes:
        wheelbase: L [m]; steering_ratio: N, steering-wheel per road-wheel angle [-];
        track: mean of the front and rear treads [m]; min_speed: the model's minimum speed [m/s]
            (below it the estimator is not used, and the checks use no sample).
    """

    wheelbase: float
    steering_ratio: float
    track: float
    min_speed: float

    @classmethod
    def of(cls, vehicle: Vehicle) -> Geometry:
        b = vehicle.body
        return cls(
            wheelbase=b.wheelbase,
            steering_ratio=vehicle.steering.ratio,
            track=0.5 * (b.track_front + b.track_rear),
            min_speed=vehicle.estimator.min_speed,
        )


@dataclass(frozen=True)
class Check:
    """One check's result.

    Attributes:
        key: ``lat_accel``, ``yaw_vs_steering``, ``wheel_speeds``, ``column_torque``,
            ``assist_torque``, ``speed``, ``steering_rate``; label: its letter in the report (a-f);
            title: what it relates.
        outcome: :class:`Outcome`; why: one line with the numbers behind it.
        relates: the profile inputs whose relative sign it tests (the input it is about first;
            ``wheels`` stands for the DBC's wheel names), empty for a scale-only check.
        relation: the fit (None when nothing was fitted).
        expected: the physical range of the slope, None for a sign-only check.
        numbers: the figures behind the outcome, SI unless the name says otherwise.
        fix: the lines of the profile or vehicle file to change, on a fail.
    """

    key: str
    label: str
    title: str
    outcome: Outcome
    why: str
    relates: tuple[str, ...] = ()
    relation: Relation | None = None
    expected: tuple[float, float] | None = None
    numbers: Mapping[str, float] = field(default_factory=dict)
    fix: tuple[str, ...] = ()

    @property
    def sign(self) -> int:
        """The sign the data decided (+1 agrees with ISO 8855, -1 disagrees), 0 when undecided."""
        if self.relation is None or self.outcome in (Outcome.NOT_ENOUGH_EXCITATION, Outcome.NOT_APPLICABLE):
            return 0
        return self.relation.sign


@dataclass(frozen=True)
class SignFinding:
    """What the checks say of one input's sign.

    Attributes:
        input: the profile input (``yaw_rate``, ``lat_accel``, ...).
        ok: True (agrees with ISO 8855), False (flip it), None (no check decided).
        checks: the keys of the checks the verdict rests on.
        basis: how the yaw rate's own sign was decided (the wheel names, or the majority).
        ambiguous: the checks are as well explained by flipping the yaw rate instead.
    """

    input: str
    ok: bool | None
    checks: tuple[str, ...]
    basis: str = ""
    ambiguous: bool = False


# --------------------------------------------------------------------------- judging a fit


def _fmt(x: float) -> str:
    return f"{x:.3g}" if math.isfinite(x) else ("inf" if x > 0 else "-inf")


def _interval(lo: float, hi: float) -> str:
    return f"[{_fmt(lo)}, {_fmt(hi)}]"


def _meets(lo: float, hi: float, band: tuple[float, float]) -> bool:
    return lo <= band[1] and hi >= band[0]


def _judge(
    rel: Relation | None, n_gated: int, floor: float, expected: tuple[float, float] | None, gates: str
) -> tuple[Outcome, str]:
    """Outcome and its reason from a fit (module doc); ``floor``: the least regressor spread (std)
    that counts as excitation; ``gates``: the gates in words (said when too few samples pass)."""
    if n_gated < MIN_SAMPLES:
        return (
            Outcome.NOT_ENOUGH_EXCITATION,
            f"{n_gated} samples pass the gates ({gates}); {MIN_SAMPLES} needed",
        )
    if rel is None or rel.x_std < floor:
        spread = 0.0 if rel is None else rel.x_std
        return (
            Outcome.NOT_ENOUGH_EXCITATION,
            f"the regressor barely moves over the {n_gated} samples (std {_fmt(spread)},"
            f" at least {_fmt(floor)} needed)",
        )
    if rel.n_eff < MIN_EFFECTIVE:
        return (
            Outcome.NOT_ENOUGH_EXCITATION,
            f"{rel.n_eff:.1f} effective independent samples of {rel.n} ({MIN_EFFECTIVE:g} needed): one event",
        )
    lo, hi = rel.bracket
    fit = (
        f"slope {_fmt(rel.slope)}, 95 % interval {_interval(rel.slope_lo, rel.slope_hi)}, "
        f"with noise in both {_interval(lo, hi)}; n {rel.n}, n_eff {rel.n_eff:.0f}"
    )
    want = "positive" if expected is None else f"{_interval(*expected)}"
    if rel.sign == 0:
        if expected is None or _meets(lo, hi, expected):
            return Outcome.NOT_ENOUGH_EXCITATION, f"the interval includes zero: the sign is undecided ({fit})"
        return Outcome.FAIL, f"no response: the slope is near zero, expected {want} ({fit})"
    if rel.sign < 0:
        scale = ""
        if expected is not None and not _meets(-hi, -lo, expected):
            scale = f"; flipped it is {_interval(-hi, -lo)}, still outside {want}: its scale is off as well"
        return Outcome.FAIL, f"wrong sign: {fit}; expected {want}{scale}"
    if expected is not None and not _meets(lo, hi, expected):
        return Outcome.FAIL, f"wrong scale: {fit}; expected {want}"
    return Outcome.PASS, f"{fit}; expected {want}"


def _numbers(rel: Relation | None, n_gated: int, **extra: float) -> dict[str, float]:
    out: dict[str, float] = {"samples": float(n_gated)}
    if rel is not None:
        lo, hi = rel.bracket
        out.update(
            slope=rel.slope,
            slope_lo=rel.slope_lo,
            slope_hi=rel.slope_hi,
            bracket_lo=lo,
            bracket_hi=hi,
            intercept=rel.intercept,
            intercept_lo=rel.intercept_lo,
            intercept_hi=rel.intercept_hi,
            corr=rel.corr,
            n=float(rel.n),
            n_eff=rel.n_eff,
            x_std=rel.x_std,
        )
    out.update(extra)
    return out


# --------------------------------------------------------------------------- the checks


@dataclass(frozen=True)
class _Base:
    """The gates every check shares, on the grid."""

    v: np.ndarray
    r: np.ndarray
    moving: np.ndarray  # speed fresh and at least the model's minimum
    steady: np.ndarray  # steering rate small (where the angle is known)
    gates: str

    @classmethod
    def of(cls, grid: Grid, geo: Geometry) -> _Base:
        v = grid.values["speed"] if grid.has("speed") else np.zeros(len(grid))
        r = grid.values["yaw_rate"] if grid.has("yaw_rate") else np.zeros(len(grid))
        moving = grid.ok("speed") & (v >= geo.min_speed)
        if grid.has("steering_angle"):
            steady = grid.ok("steering_angle") & (np.abs(grid.rate("steering_angle")) <= MAX_STEER_RATE)
        else:
            steady = np.ones(len(grid), dtype=bool)
        gates = f"speed >= {geo.min_speed / KMH:.0f} km/h, steering rate <= {MAX_STEER_RATE / DEG:.0f} deg/s"
        return cls(v=v, r=r, moving=moving, steady=steady, gates=gates)


def _lat_accel(grid: Grid, geo: Geometry, base: _Base) -> Check:
    title = "lateral acceleration against speed x yaw rate"
    if not grid.has("lat_accel"):
        return Check(
            "lat_accel", "a", title, Outcome.NOT_APPLICABLE, "the profile has no lateral acceleration"
        )
    x = base.v * base.r
    use = base.moving & base.steady & grid.ok("yaw_rate", "lat_accel") & (np.abs(x) <= MAX_LAT_ACCEL)
    rel = fit_relation(x, grid.values["lat_accel"], use)
    n = int(np.count_nonzero(use))
    outcome, why = _judge(rel, n, 0.05, ACCEL_SLOPE, f"{base.gates}, |v r| <= {MAX_LAT_ACCEL:g} m/s^2")
    extra = {}
    if rel is not None:  # the intercept as a bank angle (or a sensor offset: the two are one number)
        extra["bank_deg"] = math.asin(max(-1.0, min(1.0, rel.intercept / G))) / DEG
    return Check(
        "lat_accel",
        "a",
        title,
        outcome,
        why,
        ("lat_accel", "yaw_rate"),
        rel,
        ACCEL_SLOPE,
        _numbers(rel, n, **extra),
    )


def _yaw_vs_steering(grid: Grid, geo: Geometry, base: _Base) -> Check:
    title = "yaw rate against steering angle / ratio / wheelbase"
    if not grid.has("steering_angle", "yaw_rate", "speed"):
        return Check(
            "yaw_vs_steering", "b", title, Outcome.NOT_APPLICABLE, "the profile lacks an input it needs"
        )
    nl = geo.steering_ratio * geo.wheelbase
    x = grid.values["steering_angle"]
    y = nl * base.r / np.maximum(base.v, 1.0)  # the steering-wheel angle of a neutral-steer car at this r
    use = (
        base.moving
        & base.steady
        & grid.ok("yaw_rate", "steering_angle")
        & (np.abs(base.v * base.r) <= LOW_LAT_ACCEL)
    )
    n = int(np.count_nonzero(use))
    rel = fit_relation(x, y, use)
    # s = 1 / (1 + K v^2) at the least-squares weighted mean of v^2
    v2 = float(np.sum(x[use] ** 2 * base.v[use] ** 2) / np.sum(x[use] ** 2)) if n and np.any(x[use]) else 0.0
    k_gain = geo.wheelbase * G / DEG  # deg/g per s^2/m^2
    lo_k, hi_k = (u / k_gain for u in UNDERSTEER_DEG_PER_G)
    expected = (1.0 / (1.0 + hi_k * v2), 1.0 / (1.0 + lo_k * v2)) if v2 > 0 else (0.0, 1.0)
    outcome, why = _judge(rel, n, 0.2 * DEG, expected, f"{base.gates}, |v r| <= {LOW_LAT_ACCEL:g} m/s^2")
    extra: dict[str, float] = {"speed_rms": math.sqrt(v2)}
    if rel is not None and rel.slope > 0.0 and v2 > 0.0:
        lo, hi = rel.bracket

        def k_of(s: float) -> float:
            return (1.0 / s - 1.0) / v2 if s > 0.0 else math.inf

        extra.update(
            k_us=k_of(rel.slope),
            k_us_lo=k_of(hi),
            k_us_hi=k_of(lo),
            understeer_deg_per_g=k_of(rel.slope) * k_gain,
            understeer_lo_deg_per_g=k_of(hi) * k_gain,
            understeer_hi_deg_per_g=k_of(lo) * k_gain,
            steering_offset_deg=-rel.intercept / rel.slope / DEG,
            steering_offset_lo_deg=-rel.intercept_hi / rel.slope / DEG,
            steering_offset_hi_deg=-rel.intercept_lo / rel.slope / DEG,
        )
        why += (
            f"; understeer gradient {extra['understeer_deg_per_g']:.2f} deg/g "
            f"{_interval(extra['understeer_lo_deg_per_g'], extra['understeer_hi_deg_per_g'])}, plausible "
            f"{_interval(*UNDERSTEER_DEG_PER_G)} deg/g (N {geo.steering_ratio:g}, L {geo.wheelbase:g} m)"
        )
    return Check(
        "yaw_vs_steering",
        "b",
        title,
        outcome,
        why,
        ("steering_angle", "yaw_rate"),
        rel,
        expected,
        _numbers(rel, n, **extra),
    )


def _wheel_speeds(grid: Grid, geo: Geometry, base: _Base) -> Check:
    title = "wheel speeds right minus left against yaw rate x track"
    left = [w for w in WHEELS if w.endswith("l") and grid.has(w)]
    right = [w for w in WHEELS if w.endswith("r") and grid.has(w)]
    if not left or not right or not grid.has("yaw_rate", "speed"):
        return Check(
            "wheel_speeds", "c", title, Outcome.NOT_APPLICABLE, "the profile's DBC has no per-wheel speeds"
        )
    pairs = [(lw, rw) for lw, rw in zip(left, right, strict=False) if lw[:-1] == rw[:-1]] or [
        (left[0], right[0])
    ]
    v = np.maximum(base.v, 1.0)
    y = np.mean([grid.values[rw] - grid.values[lw] for lw, rw in pairs], axis=0) / v
    x = base.r * geo.track / v
    names = [w for p in pairs for w in p]
    use = base.moving & base.steady & grid.ok("yaw_rate", *names) & (np.abs(base.v * base.r) <= MAX_LAT_ACCEL)
    n = int(np.count_nonzero(use))
    rel = fit_relation(x, y, use)
    floor = 0.1 * DEG * geo.track / max(float(np.mean(v[use])) if n else 1.0, 1.0)  # r moving by 0.1 deg/s
    outcome, why = _judge(rel, n, floor, WHEEL_SLOPE, f"{base.gates}, |v r| <= {MAX_LAT_ACCEL:g} m/s^2")
    pair_text = ", ".join(f"{rw[-2:].upper()}-{lw[-2:].upper()}" for lw, rw in pairs)
    return Check(
        "wheel_speeds",
        "c",
        f"{title} ({pair_text})",
        outcome,
        why,
        ("wheels", "yaw_rate"),
        rel,
        WHEEL_SLOPE,
        _numbers(rel, n),
    )


def _torque(grid: Grid, geo: Geometry, base: _Base, name: str, unit: str) -> Check:
    title = f"{name.replace('_', ' ')} against the turn it holds (v r)"
    if not grid.has(name, "yaw_rate", "speed"):
        return Check(name, "d", title, Outcome.NOT_APPLICABLE, f"the profile has no {name.replace('_', ' ')}")
    x = base.v * base.r
    use = base.moving & base.steady & grid.ok("yaw_rate", name) & (np.abs(x) <= MAX_LAT_ACCEL)
    n = int(np.count_nonzero(use))
    rel = fit_relation(x, grid.values[name], use)
    outcome, why = _judge(rel, n, 0.05, None, f"{base.gates}, |v r| <= {MAX_LAT_ACCEL:g} m/s^2")
    why += (
        f" (slope in {unit} per m/s^2; sign only: a torque toward the turn, whoever applies it, the driver,"
        " the boost or a lane-keeping command; its scale and the boost's share are not checked)"
    )
    return Check(name, "d", title, outcome, why, (name, "yaw_rate"), rel, None, _numbers(rel, n))


def _speed(grid: Grid, geo: Geometry, base: _Base, speed_is_wheels: bool) -> Check:
    title = "speed against the wheel speeds' mean"
    have = [w for w in WHEELS if grid.has(w)]
    if speed_is_wheels or not have or not grid.has("speed"):
        why = (
            "the speed is the wheel speeds' mean"
            if speed_is_wheels
            else "the profile's DBC has no per-wheel speeds"
        )
        return Check("speed", "e", title, Outcome.NOT_APPLICABLE, why)
    x = np.mean([grid.values[w] for w in have], axis=0)
    use = base.moving & grid.ok(*have)
    n = int(np.count_nonzero(use))
    rel = fit_relation(x, base.v, use, intercept=False)
    outcome, why = _judge(rel, n, 0.0, SPEED_SCALE, base.gates.split(",")[0])
    return Check("speed", "e", title, outcome, why, (), rel, SPEED_SCALE, _numbers(rel, n))


def _steering_rate(grid: Grid, base: _Base, signed: bool) -> Check:
    title = "steering rate against the steering angle's derivative"
    if not grid.has("steering_rate", "steering_angle"):
        return Check(
            "steering_rate", "f", title, Outcome.NOT_APPLICABLE, "the profile lacks an input it needs"
        )
    if not signed:
        why = "the steering rate is a magnitude (signed = false): it has no sign to check"
        return Check("steering_rate", "f", title, Outcome.NOT_APPLICABLE, why)
    x = grid.rate("steering_angle")
    use = base.moving & grid.ok("steering_angle", "steering_rate")
    n = int(np.count_nonzero(use))
    rel = fit_relation(x, grid.values["steering_rate"], use)
    outcome, why = _judge(rel, n, MIN_RATE_SPREAD, RATE_SLOPE, base.gates.split(",")[0])
    return Check(
        "steering_rate",
        "f",
        title,
        outcome,
        why,
        ("steering_rate", "steering_angle"),
        rel,
        RATE_SLOPE,
        _numbers(rel, n),
    )


def _below_min_speed(check: Check, grid: Grid, geo: Geometry) -> Check:
    """A check without samples because the car never reached the model's minimum speed says so."""
    if check.outcome is not Outcome.NOT_ENOUGH_EXCITATION or not grid.has("speed"):
        return check
    fresh = grid.ok("speed")
    top = float(np.max(grid.values["speed"][fresh])) if np.any(fresh) else 0.0
    if top >= geo.min_speed:
        return check
    why = (
        f"below the minimum speed of {geo.min_speed / KMH:.0f} km/h for the whole log (highest "
        f"{top / KMH:.1f} km/h): drive some curves above {geo.min_speed / KMH:.0f} km/h"
    )
    return replace(check, why=why)


def run_checks(
    grid: Grid,
    geo: Geometry,
    *,
    torque_units: Mapping[str, str] | None = None,
    speed_is_wheels: bool = False,
    rate_signed: bool = True,
) -> list[Check]:
    """The checks a-f over ``grid`` (signals named as the profile's inputs, plus :data:`WHEELS`
    where the DBC has them; SI, the profile's signs applied). ``torque_units``: the unit of each
    torque input (``Nm``, or ``counts`` for an unknown scale); ``speed_is_wheels``: the speed input
    is the wheel speeds' mean (check e does not apply); ``rate_signed``: the steering rate carries
    its direction (else check f does not apply). The signs are not yet attributed:
    :func:`attribute_signs` then :func:`with_fixes`."""
    units = dict(torque_units or {})
    base = _Base.of(grid, geo)
    checks = [
        _lat_accel(grid, geo, base),
        _yaw_vs_steering(grid, geo, base),
        _wheel_speeds(grid, geo, base),
        *(_torque(grid, geo, base, t, units.get(t, "Nm")) for t in ("column_torque", "assist_torque")),
        _speed(grid, geo, base, speed_is_wheels),
        _steering_rate(grid, base, rate_signed),
    ]
    return [_below_min_speed(c, grid, geo) for c in checks]


# --------------------------------------------------------------------------- which sign is wrong


def attribute_signs(checks: list[Check]) -> dict[str, SignFinding]:
    """Each input's sign verdict from the checks' decided signs (module doc, "Which sign is wrong")."""
    by_input: dict[str, list[Check]] = {}
    for c in checks:
        if len(c.relates) == 2 and c.relates[1] == "yaw_rate" and c.sign != 0:
            by_input.setdefault(c.relates[0], []).append(c)
    wheel = by_input.pop("wheels", [])
    others = [c for cs in by_input.values() for c in cs]
    ambiguous = False
    if wheel:
        yaw_ok = wheel[0].sign > 0
        basis = "the wheel speeds (their left and right names)"
        yaw_checks: tuple[str, ...] = (wheel[0].key,)
    elif others:
        neg = sum(c.sign < 0 for c in others)
        pos = len(others) - neg
        yaw_ok = neg <= pos
        ambiguous = neg == pos and neg > 0
        basis = (
            f"the majority of the checks ({max(neg, pos)} of {len(others)}):"
            " no wheel speeds to say which side is left"
        )
        yaw_checks = tuple(c.key for c in others)
    else:
        return {}
    yaw_sign = 1 if yaw_ok else -1
    out = {"yaw_rate": SignFinding("yaw_rate", yaw_ok, yaw_checks, basis, ambiguous)}
    for name, cs in by_input.items():
        votes = sum(c.sign * yaw_sign for c in cs)
        out[name] = SignFinding(
            name, None if votes == 0 else votes > 0, tuple(c.key for c in cs), basis, ambiguous
        )
    # the steering rate relative to the steering angle's verdict
    angle = out.get("steering_angle")
    for c in checks:
        if c.relates == ("steering_rate", "steering_angle") and c.sign != 0 and angle is not None:
            ok = None if angle.ok is None else (c.sign > 0) == angle.ok
            out["steering_rate"] = SignFinding("steering_rate", ok, (c.key,), basis, ambiguous)
    return out


def sign_line(name: str, current: float) -> str:
    """The profile line that flips input ``name`` whose sign is ``current`` now."""
    return f"[inputs.{name}] sign = {-int(math.copysign(1, current))}"


#: the lines to look at when a check's slope is off in scale, not in sign
_SCALE_FIX: Mapping[str, tuple[str, ...]] = {
    "lat_accel": ("[inputs.lat_accel] scale (or [inputs.yaw_rate] / [inputs.speed] scale)",),
    "yaw_vs_steering": (
        "the vehicle file's [steering] ratio and lf_m + lr_m (the wheelbase)",
        "[inputs.steering_angle] scale (or [inputs.yaw_rate] scale)",
    ),
    "wheel_speeds": ("the vehicle file's track_front_m / track_rear_m (or [inputs.yaw_rate] scale)",),
    "speed": ("[inputs.speed] scale",),
    "steering_rate": ("[inputs.steering_rate] scale (or [inputs.steering_angle] scale)",),
}


def with_fixes(
    checks: list[Check], findings: Mapping[str, SignFinding], signs: Mapping[str, float]
) -> list[Check]:
    """The checks with the lines to change on each fail: the sign of the input the attribution
    blames (``signs``: each input's sign in the profile now), else the scale lines."""
    out = []
    for c in checks:
        if c.outcome is not Outcome.FAIL:
            out.append(c)
            continue
        fix: list[str] = []
        blamed = [n for n in c.relates if n in findings and findings[n].ok is False]
        if c.sign < 0:
            for n in blamed:
                fix.append(sign_line(n, signs.get(n, 1.0)))
            if "wheels" in c.relates and not blamed:
                fix.append("the DBC's left and right wheel signals may be swapped")
        lo_hi = c.relation.bracket if c.relation is not None else (math.nan, math.nan)
        if c.expected is not None and c.relation is not None:
            s = -1.0 if c.sign < 0 else 1.0
            lo, hi = sorted((s * lo_hi[0], s * lo_hi[1]))
            if not _meets(lo, hi, c.expected):
                fix.extend(_SCALE_FIX.get(c.key, ()))
        out.append(replace(c, fix=tuple(fix)))
    return out
