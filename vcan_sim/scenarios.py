"""Named, seeded, documented scenarios: disturbance, speed, lane and payload time profiles.

A :class:`Scenario` is data (steps of wind speed and bank angle, turbulence, discrete gusts, lane
changes, payload, speed, scripted overlay torque); :func:`disturbance_profile` turns it into
arrays on the simulator's sub-step grid, deterministically under a seed. ``lde sim --list`` prints
the registry (:data:`SCENARIOS`) with one line per scenario.

Profiles are piecewise constant with smooth transitions: a :class:`Step` ``(t, rise, value)``
moves the quantity from its previous value to ``value`` starting at ``t`` over ``rise`` seconds
along a half cosine (``rise = 0`` is a true step). Wind direction: the direction the air moves
toward, relative to the road (90 deg = toward the left, i.e. wind from the right). Turbulence is
a seeded Ornstein-Uhlenbeck process (intensity times the mean wind, correlation time
``turbulence_time``); discrete gusts are "1 - cos" pulses at seeded times.

Random streams: the seed feeds a ``numpy.random.SeedSequence`` spawned into independent streams
(wind, driver gains, driver noise, sensors) so one part's randomness never shifts another's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from lde.errors import ConfigError
from lde.units import DEG, KMH

from .config import DriverParams
from .faults import Fault, FaultKind

#: independent random streams, in this order, from SeedSequence(seed).spawn(N_STREAMS)
STREAM_WIND, STREAM_DRIVER_GAINS, STREAM_DRIVER_NOISE, STREAM_SENSORS = range(4)
N_STREAMS = 4


def rng_streams(seed: int) -> list[np.random.Generator]:
    """Independent generators for the scenario's random parts."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(int(seed)).spawn(N_STREAMS)]


@dataclass(frozen=True)
class Step:
    """From ``t`` [s], move to ``value`` over ``rise`` [s] (half-cosine blend; 0 = a step)."""

    t: float
    rise: float
    value: float


@dataclass(frozen=True)
class Gusts:
    """``count`` discrete 1-cos gusts of up to ``amplitude`` [m/s] lasting ``length`` [s], at seeded
    times in [t_start, t_end] (amplitudes uniform in 0.5..1 of ``amplitude``, random sign if
    ``two_sided``)."""

    count: int = 0
    amplitude: float = 0.0
    length: float = 2.0
    t_start: float = 2.0
    t_end: float = 1e9
    two_sided: bool = False


@dataclass(frozen=True)
class Weave:
    """A sinusoidal lane centre (a slalom): ``amplitude`` [m] (left first), ``period`` [s], from
    ``t_start`` for ``cycles`` whole periods; the amplitude ramps in over the first and out over the
    last half period (half cosine), so the lane centre and its slope start and end at zero."""

    t_start: float
    amplitude: float
    period: float
    cycles: int


@dataclass(frozen=True)
class DriverStyle:
    """How this drive's driver differs from the vehicle file's ``[sim.driver]``: factors on its
    torque noise (std and correlation time), its lateral and integral gains and its lag.
    The default (all 1) is the file's driver."""

    noise_torque: float = 1.0
    noise_time: float = 1.0
    gain: float = 1.0
    lag: float = 1.0

    def apply(self, d: DriverParams) -> DriverParams:
        return replace(
            d,
            noise_torque=d.noise_torque * self.noise_torque,
            noise_time=d.noise_time * self.noise_time,
            lateral_gain=d.lateral_gain * self.gain,
            integral_gain=d.integral_gain * self.gain,
            lag_time=d.lag_time * self.lag,
        )


#: a rougher driver: 8x the torque noise (0.32 Nm) with a shorter correlation time and 30 % less lag
#: (straight ahead: steering-rate std 2.2 deg/s instead of 0.24, wheel-angle std 0.24 deg instead of
#: 0.03; measured on `straight`, seed 0). Higher gains were tried: 1.5x
#: lets the fully loaded car (+450 kg) oscillate and spin on some seeds, so the gains stay.
ROUGH_DRIVER = DriverStyle(noise_torque=8.0, noise_time=0.75, gain=1.0, lag=0.7)


@dataclass(frozen=True)
class Scenario:
    """One named test drive. Units: s, m/s (wind), km/h (speed), deg (bank, direction), m (lane).

    Attributes:
        name, description: registry key and the one-line description ``lde sim --list`` prints.
        duration: default length [s].
        speed_kmh: initial speed; speed_steps: later speed targets (km/h).
        wind_speed: steps of the mean wind speed [m/s]; wind_direction_deg: direction of the air's
            motion relative to the road (90 = toward the left); turbulence: intensity (std / mean);
            turbulence_floor: std [m/s] even at zero mean; turbulence_time: correlation time [s];
            gusts: discrete gusts added to the wind speed.
        bank_deg: steps of the bank angle [deg] (positive: left side lower).
        lane: steps of the lane centre [m] (lane changes; positive left); weave: a sinusoidal lane
            centre on top (slalom).
        curvature: steps of the road's curvature [1/m] (left turns positive; 1/800 = an 800 m
            radius to the left). The plant runs in road coordinates; wind and bank turn with the road.
        overlay: scripted overlay-torque request steps [Nm] (closed loop overrides it).
        payload: name in :data:`vcan_sim.payload.PAYLOADS`.
        driver: "lane" (holds the lane), "hands_off", or "angle" (follows ``steer_deg``).
        steer_deg: steering-wheel angle steps [deg] for driver "angle".
        faults: bus faults injected into the frames (:mod:`vcan_sim.faults`).
        driver_style: this drive's driver relative to the vehicle file's (:class:`DriverStyle`).
    """

    name: str
    description: str
    duration: float = 30.0
    speed_kmh: float = 100.0
    speed_steps: tuple[Step, ...] = ()
    wind_speed: tuple[Step, ...] = ()
    wind_direction_deg: float = 90.0
    turbulence: float = 0.0
    turbulence_floor: float = 0.0
    turbulence_time: float = 1.5
    gusts: Gusts = field(default_factory=Gusts)
    bank_deg: tuple[Step, ...] = ()
    lane: tuple[Step, ...] = ()
    weave: Weave | None = None
    curvature: tuple[Step, ...] = ()
    overlay: tuple[Step, ...] = ()
    payload: str = "none"
    driver: str = "lane"
    steer_deg: tuple[Step, ...] = ()
    faults: tuple[Fault, ...] = ()
    driver_style: DriverStyle = field(default_factory=DriverStyle)

    @property
    def disturbance_free(self) -> bool:
        """No wind (mean, turbulence floor, gusts) and no bank: the truth's Fw is only the few
        newtons of aero side force from the car's own side slip."""
        no_wind = all(s.value == 0.0 for s in self.wind_speed) and self.turbulence_floor == 0.0
        no_gusts = self.gusts.count == 0 or self.gusts.amplitude == 0.0
        return no_wind and no_gusts and all(s.value == 0.0 for s in self.bank_deg)

    def with_speed(self, speed_kmh: float) -> Scenario:
        """The same drive at another constant speed."""
        return replace(self, speed_kmh=float(speed_kmh), speed_steps=())


@dataclass(frozen=True)
class DisturbanceProfile:
    """Scenario inputs on the sub-step grid (n samples, SI).

    Attributes: wind_x, wind_y: air velocity in road axes [m/s]; wind_speed [m/s]; bank [rad];
    lane [m]; speed [m/s]; overlay [Nm]; steer [rad] (steering-wheel angle command); curvature
    [1/m] (the road's, left positive).
    """

    wind_x: np.ndarray
    wind_y: np.ndarray
    wind_speed: np.ndarray
    bank: np.ndarray
    lane: np.ndarray
    speed: np.ndarray
    overlay: np.ndarray
    steer: np.ndarray
    curvature: np.ndarray


def weave_profile(t: np.ndarray, w: Weave | None) -> np.ndarray:
    """The lane centre of a :class:`Weave` at times ``t`` [s] (0 outside it)."""
    if w is None or w.cycles <= 0:
        return np.zeros_like(t)
    u = (t - w.t_start) / w.period  # periods since the start
    n = float(w.cycles)
    inside = (u >= 0.0) & (u <= n)
    ramp = np.clip(np.minimum(u, n - u) / 0.5, 0.0, 1.0)
    env = 0.5 - 0.5 * np.cos(math.pi * ramp)
    return np.where(inside, w.amplitude * env * np.sin(2.0 * math.pi * u), 0.0)


def steps_profile(t: np.ndarray, steps: tuple[Step, ...], initial: float = 0.0) -> np.ndarray:
    """Piecewise-constant profile with half-cosine transitions (see module doc)."""
    y = np.full(t.shape, float(initial))
    prev = float(initial)
    for s in sorted(steps, key=lambda s: s.t):
        if s.rise <= 0.0:
            blend = (t >= s.t).astype(np.float64)
        else:
            u = np.clip((t - s.t) / s.rise, 0.0, 1.0)
            blend = 0.5 - 0.5 * np.cos(math.pi * u)
        after = t >= s.t
        y = np.where(after, prev + (s.value - prev) * blend, y)
        prev = s.value
    return y


def ou_process(n: int, dt: float, sigma: float, tau: float, rng: np.random.Generator) -> np.ndarray:
    """Stationary Ornstein-Uhlenbeck samples (std ``sigma``, correlation time ``tau``), exact AR(1)."""
    if n == 0 or sigma <= 0.0:
        return np.zeros(n)
    a = math.exp(-dt / tau)
    e = rng.standard_normal(n) * sigma * math.sqrt(1.0 - a * a)
    e[0] = rng.standard_normal() * sigma
    return _ar1(e, a)


@numba.njit(cache=True)
def _ar1(e: np.ndarray, a: float) -> np.ndarray:
    """y[0] = e[0], y[k] = a y[k-1] + e[k]."""
    y = np.empty_like(e)
    acc = 0.0
    for k in range(e.shape[0]):
        acc = a * acc + e[k] if k else e[0]
        y[k] = acc
    return y


def gust_profile(t: np.ndarray, g: Gusts, rng: np.random.Generator) -> np.ndarray:
    """Sum of ``g.count`` 1-cos gusts at seeded times."""
    out = np.zeros_like(t)
    if g.count <= 0 or g.amplitude == 0.0:
        return out
    t_end = min(g.t_end, float(t[-1]) - g.length) if t.size else 0.0
    starts = np.sort(rng.uniform(g.t_start, max(t_end, g.t_start), g.count))
    amps = g.amplitude * rng.uniform(0.5, 1.0, g.count)
    if g.two_sided:
        amps *= rng.choice([-1.0, 1.0], g.count)
    for ts, a in zip(starts, amps, strict=True):
        u = (t - ts) / g.length
        inside = (u >= 0.0) & (u <= 1.0)
        out[inside] += 0.5 * a * (1.0 - np.cos(2.0 * math.pi * u[inside]))
    return out


def disturbance_profile(sc: Scenario, t: np.ndarray, rng_wind: np.random.Generator) -> DisturbanceProfile:
    """The scenario's inputs at times ``t`` [s] (uniform grid)."""
    dt = float(t[1] - t[0]) if t.size > 1 else 1e-3
    mean = steps_profile(t, sc.wind_speed)
    sigma = 1.0  # unit OU, scaled by the local intensity below
    turb = ou_process(t.size, dt, sigma, sc.turbulence_time, rng_wind)
    speed = mean + turb * (sc.turbulence * np.abs(mean) + sc.turbulence_floor)
    speed = speed + gust_profile(t, sc.gusts, rng_wind)
    direction = sc.wind_direction_deg * DEG
    return DisturbanceProfile(
        wind_x=speed * math.cos(direction),
        wind_y=speed * math.sin(direction),
        wind_speed=np.abs(speed),
        bank=steps_profile(t, sc.bank_deg) * DEG,
        lane=steps_profile(t, sc.lane) + weave_profile(t, sc.weave),
        speed=steps_profile(t, sc.speed_steps, sc.speed_kmh) * KMH,
        overlay=steps_profile(t, sc.overlay),
        steer=steps_profile(t, sc.steer_deg) * DEG,
        curvature=steps_profile(t, sc.curvature),
    )


# ---------------------------------------------------------------------------------- registry

_HEAVY_BANK = (Step(14.0, 2.0, 3.0), Step(24.0, 3.0, -3.0), Step(33.0, 2.0, 0.0))
_LIGHT_BANK = (Step(14.0, 2.0, 1.0), Step(24.0, 3.0, -1.0), Step(33.0, 2.0, 0.0))


def _payload_drive(name: str, description: str, payload: str) -> Scenario:
    """The payload cases' common drive: 8 m/s crosswind, then bank +-2 deg, 100 km/h, 40 s."""
    return Scenario(
        name,
        description,
        duration=40.0,
        speed_kmh=100.0,
        wind_speed=(Step(3.0, 1.5, 8.0), Step(20.0, 1.5, 0.0)),
        turbulence=0.1,
        bank_deg=(Step(24.0, 2.0, 2.0), Step(32.0, 2.0, -2.0), Step(37.0, 1.0, 0.0)),
        payload=payload,
    )


_LIST = [
    Scenario(
        "heavy_load",
        "paper heavy load: 15 m/s crosswind from the right (gusty), bank -3..3 deg, 100 km/h",
        duration=40.0,
        speed_kmh=100.0,
        wind_speed=(Step(3.0, 1.5, 15.0), Step(28.0, 2.0, 0.0)),
        turbulence=0.08,
        bank_deg=_HEAVY_BANK,
    ),
    Scenario(
        "light_load",
        "paper light load: 2 m/s crosswind from the right, bank -1..1 deg, 100 km/h",
        duration=40.0,
        speed_kmh=100.0,
        wind_speed=(Step(3.0, 1.5, 2.0), Step(28.0, 2.0, 0.0)),
        turbulence=0.08,
        bank_deg=_LIGHT_BANK,
    ),
    Scenario(
        "steady_wind",
        "steady 10 m/s crosswind from the right after a 2 s ramp, 120 km/h",
        duration=30.0,
        speed_kmh=120.0,
        wind_speed=(Step(3.0, 2.0, 10.0),),
    ),
    Scenario(
        "wind_step",
        "12 m/s crosswind step (0.3 s rise) at 5 s, off at 20 s, 100 km/h",
        duration=30.0,
        speed_kmh=100.0,
        wind_speed=(Step(5.0, 0.3, 12.0), Step(20.0, 0.3, 0.0)),
    ),
    Scenario(
        "gusty_wind",
        "8 m/s mean crosswind, 25 % turbulence and 6 discrete gusts up to 6 m/s, 130 km/h",
        duration=60.0,
        speed_kmh=130.0,
        wind_speed=(Step(2.0, 3.0, 8.0),),
        turbulence=0.25,
        gusts=Gusts(count=6, amplitude=6.0, length=2.0, t_start=8.0),
    ),
    Scenario(
        "wind_left",
        "10 m/s crosswind from the left (blowing right), 90 km/h",
        duration=30.0,
        speed_kmh=90.0,
        wind_speed=(Step(3.0, 1.0, 10.0),),
        wind_direction_deg=-90.0,
    ),
    Scenario(
        "oblique_wind",
        "14 m/s wind from 45 deg ahead-right, 110 km/h",
        duration=30.0,
        speed_kmh=110.0,
        wind_speed=(Step(3.0, 2.0, 14.0),),
        wind_direction_deg=135.0,
        turbulence=0.1,
    ),
    Scenario(
        "bank_transition",
        "bank 0 -> +3 -> -3 -> 0 deg with 2-3 s transitions, no wind, 90 km/h",
        duration=40.0,
        speed_kmh=90.0,
        bank_deg=(Step(5.0, 2.0, 3.0), Step(15.0, 3.0, -3.0), Step(28.0, 2.0, 0.0)),
    ),
    _payload_drive(
        "payload_full",
        "full load (+450 kg: 4 occupants + trunk), 8 m/s wind then bank +-2 deg, 100 km/h",
        "full",
    ),
    _payload_drive(
        "payload_trunk",
        "+150 kg in the trunk (CG moves back), 8 m/s wind then bank +-2 deg, 100 km/h",
        "trunk",
    ),
    _payload_drive(
        "payload_four", "+225 kg (3 passengers), 8 m/s wind then bank +-2 deg, 100 km/h", "four_occupants"
    ),
    _payload_drive(
        "payload_left",
        "+160 kg on the rear left seat (lateral CG offset), 8 m/s wind then bank, 100 km/h",
        "left_side",
    ),
    Scenario(
        "lane_change",
        "no disturbance: 3.5 m lane change to the left at 8 s and back at 20 s, 100 km/h",
        duration=30.0,
        speed_kmh=100.0,
        lane=(Step(8.0, 4.0, 3.5), Step(20.0, 4.0, 0.0)),
    ),
    Scenario("straight", "no disturbance, straight lane keeping, 100 km/h", duration=30.0, speed_kmh=100.0),
    Scenario(
        "speed_sweep",
        "speed 60 -> 160 km/h with a 6 m/s crosswind and bank +-1.5 deg",
        duration=60.0,
        speed_kmh=60.0,
        speed_steps=(Step(5.0, 45.0, 160.0),),
        wind_speed=(Step(2.0, 2.0, 6.0),),
        turbulence=0.15,
        bank_deg=(Step(20.0, 2.0, 1.5), Step(38.0, 3.0, -1.5), Step(52.0, 2.0, 0.0)),
    ),
    Scenario(
        "heavy_load_60",
        "paper heavy load at 60 km/h",
        duration=40.0,
        speed_kmh=60.0,
        wind_speed=(Step(3.0, 1.5, 15.0), Step(28.0, 2.0, 0.0)),
        turbulence=0.08,
        bank_deg=_HEAVY_BANK,
    ),
    Scenario(
        "heavy_load_140",
        "paper heavy load at 140 km/h (wind 12 m/s so that the wheel stays within 15 deg)",
        duration=40.0,
        speed_kmh=140.0,
        wind_speed=(Step(3.0, 1.5, 12.0), Step(28.0, 2.0, 0.0)),
        turbulence=0.08,
        bank_deg=_HEAVY_BANK,
    ),
    Scenario(
        "overlay_step",
        "no disturbance, a scripted 2 Nm overlay torque from 5 s to 15 s: the driver's reaction",
        duration=25.0,
        speed_kmh=100.0,
        overlay=(Step(5.0, 0.4, 2.0), Step(15.0, 0.4, 0.0)),
    ),
]

_LIST.append(
    Scenario(
        "bus_faults",
        "10 m/s crosswind at 100 km/h with bus faults: MDPS frames lost, corrupted, repeated; ESC silent",
        duration=30.0,
        speed_kmh=100.0,
        wind_speed=(Step(3.0, 1.5, 10.0),),
        faults=(
            Fault(FaultKind.DROP, "mdps", 8.0, 2.0, every=5),
            Fault(FaultKind.CORRUPT, "mdps", 12.0, 0.05),
            Fault(FaultKind.REPEAT, "mdps", 15.0, 0.02),
            Fault(FaultKind.SILENCE, "esc", 18.0, 0.2),
            Fault(FaultKind.DROP, "mdps", 22.0, 0.015),
        ),
    )
)

# --- the accuracy targets of issue 11 (zoo evaluation) and the learner's tests ---------------------

#: an 800 m radius: a motorway curve (0.96 m/s^2 at 100 km/h)
CURVE_RADIUS_M = 800.0

_LIST += [
    Scenario(
        "slalom",
        "slalom: lane centre weaving +-1.2 m with a 5 s period at 90 km/h, 10 m/s crosswind from 12 to 30 s",
        duration=40.0,
        speed_kmh=90.0,
        weave=Weave(t_start=4.0, amplitude=1.2, period=5.0, cycles=6),
        wind_speed=(Step(12.0, 1.0, 10.0), Step(30.0, 1.0, 0.0)),
        turbulence=0.05,
    ),
    Scenario(
        "curve_800m",
        "800 m radius left curve at 100 km/h (2 deg superelevation), 10 m/s crosswind from 14 to 28 s",
        duration=44.0,
        speed_kmh=100.0,
        curvature=(Step(6.0, 4.0, 1.0 / CURVE_RADIUS_M), Step(36.0, 4.0, 0.0)),
        bank_deg=(Step(6.0, 4.0, 2.0), Step(36.0, 4.0, 0.0)),
        wind_speed=(Step(14.0, 1.0, 10.0), Step(28.0, 1.0, 0.0)),
        turbulence=0.05,
    ),
    Scenario(
        "speed_ramp",
        "speed 80 -> 130 -> 80 km/h with an 8 m/s crosswind (15 % turbulence) and bank +-1.5 deg",
        duration=60.0,
        speed_kmh=80.0,
        speed_steps=(Step(5.0, 20.0, 130.0), Step(38.0, 16.0, 80.0)),
        wind_speed=(Step(2.0, 2.0, 8.0),),
        turbulence=0.15,
        bank_deg=(Step(26.0, 2.0, 1.5), Step(32.0, 2.0, -1.5), Step(37.0, 1.0, 0.0)),
    ),
    Scenario(
        "rough_driver",
        "a rougher driver (8x torque noise, quicker reactions), 10 m/s gusty crosswind then bank +-2 deg",
        duration=40.0,
        speed_kmh=100.0,
        wind_speed=(Step(3.0, 1.5, 10.0), Step(22.0, 1.5, 0.0)),
        turbulence=0.15,
        gusts=Gusts(count=3, amplitude=5.0, length=2.0, t_start=6.0, t_end=20.0),
        bank_deg=(Step(25.0, 2.0, 2.0), Step(31.0, 2.0, -2.0), Step(37.0, 1.0, 0.0)),
        driver_style=ROUGH_DRIVER,
    ),
    Scenario(
        "steady_crosswind_10min",
        "10 min of steady 8 m/s crosswind from the right (5 % turbulence), 100 km/h: not to be learned away",
        duration=600.0,
        speed_kmh=100.0,
        wind_speed=(Step(5.0, 2.0, 8.0),),
        turbulence=0.05,
    ),
    Scenario(
        "banked_road_10min",
        "10 minutes on a road banked +2.5 deg (left side lower), no wind, 100 km/h: not to be learned away",
        duration=600.0,
        speed_kmh=100.0,
        bank_deg=(Step(5.0, 3.0, 2.5),),
    ),
    Scenario(
        "prior_drive",
        "no disturbance: 2 min with 6 lane changes and a short weave at 80-120 km/h (a drive to learn on)",
        duration=120.0,
        speed_kmh=90.0,
        speed_steps=(Step(40.0, 10.0, 120.0), Step(85.0, 10.0, 80.0)),
        lane=(
            Step(8.0, 4.0, 3.5),
            Step(20.0, 4.0, 0.0),
            Step(50.0, 3.5, -3.5),
            Step(62.0, 3.5, 0.0),
            Step(100.0, 4.0, 3.5),
            Step(110.0, 4.0, 0.0),
        ),
        weave=Weave(t_start=28.0, amplitude=0.8, period=4.0, cycles=2),
    ),
    Scenario(
        "banked_lane_changes",
        "no wind: 4 lane changes on a road banked 0 -> +3 -> -3 -> 0 deg, 90 km/h (a prior drive with bank)",
        duration=60.0,
        speed_kmh=90.0,
        bank_deg=(Step(5.0, 3.0, 3.0), Step(30.0, 3.0, -3.0), Step(52.0, 3.0, 0.0)),
        lane=(
            Step(10.0, 4.0, 3.5),
            Step(20.0, 4.0, 0.0),
            Step(36.0, 3.5, -3.5),
            Step(45.0, 3.5, 0.0),
        ),
    ),
]


# --- the first drive and the light loads (the learner's first minutes; light disturbances) ---------

#: the first drive's lane changes: one every FIRST_DRIVE_LANE_GAP s (uniform, a fixed draw: the
#: same schedule on every seed; the seed varies the wind, the gusts, the driver and the sensors)
FIRST_DRIVE_LANE_GAP = (18.0, 32.0)
#: the first drive's slalom (no lane change in it) [s]
_FD_WEAVE = Weave(t_start=150.0, amplitude=1.0, period=5.0, cycles=4)


def _first_drive_lanes(duration: float) -> tuple[Step, ...]:
    """3.5 m lane changes to the left and back, one every 18-32 s (rise 3.5-5 s), none within the
    slalom (:data:`_FD_WEAVE`)."""
    rng = np.random.default_rng(2027)
    lo, hi = FIRST_DRIVE_LANE_GAP
    w0, w1 = _FD_WEAVE.t_start - 5.0, _FD_WEAVE.t_start + _FD_WEAVE.period * _FD_WEAVE.cycles + 2.0
    steps = []
    t, left = 10.0, True
    while t < duration - 8.0:
        if not (w0 <= t <= w1):
            steps.append(Step(round(t, 1), round(float(rng.uniform(3.5, 5.0)), 2), 3.5 if left else 0.0))
            left = not left
        t += float(rng.uniform(lo, hi))
    return tuple(steps)


def first_drive() -> Scenario:
    """Ten minutes of ordinary motorway driving for a car's first drive (module registry)."""
    duration = 600.0
    return Scenario(
        "first_drive",
        "10 min motorway first drive: lane changes every 18-32 s, a slalom, two gentle curves, a "
        "crosswind episode in every minute (2-14 m/s, both sides), gusts, banks coming and going, "
        "90-120 km/h",
        duration=duration,
        speed_kmh=100.0,
        speed_steps=(
            Step(90.0, 15.0, 120.0),
            Step(250.0, 15.0, 90.0),
            Step(400.0, 15.0, 110.0),
            Step(520.0, 10.0, 100.0),
        ),
        # m/s, positive: from the right (air toward the left); negative: from the left
        wind_speed=(
            Step(20.0, 2.0, 3.0),
            Step(50.0, 2.0, 0.0),
            Step(75.0, 1.5, 12.0),
            Step(110.0, 2.0, 0.0),
            Step(130.0, 2.0, 6.0),
            Step(185.0, 2.0, 0.0),
            Step(210.0, 2.0, -3.0),
            Step(235.0, 2.0, 0.0),
            Step(280.0, 1.5, -10.0),
            Step(330.0, 2.0, 0.0),
            Step(390.0, 2.0, 2.0),
            Step(415.0, 2.0, 0.0),
            Step(435.0, 2.0, 5.0),
            Step(470.0, 2.0, 0.0),
            Step(480.0, 1.5, 14.0),
            Step(530.0, 2.0, 0.0),
            Step(560.0, 2.0, -4.0),
            Step(590.0, 2.0, 0.0),
        ),
        turbulence=0.1,
        gusts=Gusts(count=8, amplitude=5.0, length=2.0, t_start=30.0, t_end=590.0, two_sided=True),
        # deg; 200-260 s and 420-470 s: the curves' superelevation
        bank_deg=(
            Step(55.0, 3.0, 1.0),
            Step(70.0, 3.0, 0.0),
            Step(200.0, 4.0, 1.5),
            Step(256.0, 4.0, 0.0),
            Step(340.0, 3.0, -2.5),
            Step(370.0, 3.0, 0.0),
            Step(420.0, 4.0, -1.0),
            Step(466.0, 4.0, 0.0),
            Step(540.0, 3.0, 2.0),
            Step(575.0, 3.0, 0.0),
        ),
        curvature=(
            Step(200.0, 4.0, 1.0 / 1500.0),
            Step(256.0, 4.0, 0.0),
            Step(420.0, 4.0, -1.0 / 2000.0),
            Step(466.0, 4.0, 0.0),
        ),
        lane=_first_drive_lanes(duration),
        weave=_FD_WEAVE,
    )


_LIGHT_WIND = (Step(3.0, 1.5, 2.0), Step(33.0, 2.0, 0.0))

_LIST += [
    first_drive(),
    Scenario(
        "light_crosswind",
        "light load: 2 m/s crosswind from the right (8 % turbulence) from 3 to 33 s, 100 km/h",
        duration=40.0,
        speed_kmh=100.0,
        wind_speed=_LIGHT_WIND,
        turbulence=0.08,
    ),
    Scenario(
        "light_bank",
        "light load: bank 0 -> +1 -> -1 -> 0 deg with 3 s transitions, no wind, 100 km/h",
        duration=40.0,
        speed_kmh=100.0,
        bank_deg=(Step(5.0, 3.0, 1.0), Step(18.0, 3.0, -1.0), Step(31.0, 3.0, 0.0)),
    ),
    Scenario(
        "light_crosswind_rough",
        "light_crosswind with the rough driver (short, fast corrections)",
        duration=40.0,
        speed_kmh=100.0,
        wind_speed=_LIGHT_WIND,
        turbulence=0.08,
        driver_style=ROUGH_DRIVER,
    ),
]

SCENARIOS: dict[str, Scenario] = {s.name: s for s in _LIST}


def get_scenario(name: str) -> Scenario:
    """Scenario by name; ConfigError listing the names otherwise."""
    try:
        return SCENARIOS[name]
    except KeyError:
        raise ConfigError(
            f"unknown scenario {name!r} (known: {', '.join(SCENARIOS)}; see lde sim --list)"
        ) from None


def scenario_list() -> list[tuple[str, str]]:
    """(name, one-line description) of every scenario, in registry order."""
    return [(s.name, s.description) for s in _LIST]
