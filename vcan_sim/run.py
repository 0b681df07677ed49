"""Running a scenario: the :class:`Simulation` (step by step, for the bus and the closed loop) and the
:func:`simulate` fast path (the whole run in a few jitted calls, frames as a FrameBatch + truth).

Time: the simulated clock starts at ``t0_ns`` (default :func:`default_t0_ns`: 1_700_000_000 s plus
a seed-derived offset of whole seconds, so logs look like a real epoch and different seeds do not
share timestamps). The plant runs on sub-steps of ``h = STEP_NS / 4`` (0.975 ms); one
:meth:`Simulation.step` advances one estimator period, ``STEP_NS`` = 3.9 ms, and returns the frames
due in it. The truth is sampled every ``STEP_NS`` from ``t0_ns`` (the anchor message's times).

Open loop, stepping and the fast path produce identical frames and truth for the same seed: both
integrate with the same kernel and draw sensor noise per frame up front.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lde.can.frames import FrameBatch
from lde.can.profiles import Profile, load_profile
from lde.errors import ConfigError, LdeError
from lde.params import Vehicle, load_vehicle
from lde.units import STEP_NS

from . import plant as P
from .config import SimParams, sim_params_from_vehicle
from .driver import DRIVER_ANGLE, DRIVER_HANDS_OFF, DRIVER_LANE
from .emitter import MessageStream, build_streams, emit_range
from .payload import LoadedBody, combined, payload_by_name
from .scenarios import (
    STREAM_DRIVER_GAINS,
    STREAM_DRIVER_NOISE,
    STREAM_SENSORS,
    STREAM_WIND,
    DisturbanceProfile,
    Scenario,
    disturbance_profile,
    get_scenario,
    ou_process,
    rng_streams,
)
from .sensors import delay_substeps
from .truth import concat_truth, truth_rows

SUBSTEPS = 4  #: plant sub-steps per STEP_NS
H_NS = STEP_NS // SUBSTEPS  #: sub-step [ns] (0.975 ms)
H = H_NS * 1e-9  #: sub-step [s]
MAX_DURATION = 3600.0  #: [s]
EPOCH_NS = 1_700_000_000 * 1_000_000_000
MAX_T0_NS = 9_000_000_000 * 1_000_000_000  #: latest start [ns]: t0 + MAX_DURATION stays within int64
_CHUNK_STEPS = 4096  # estimator steps per fast-path chunk (16 s)

_DRIVER_MODES = {"lane": DRIVER_LANE, "angle": DRIVER_ANGLE, "hands_off": DRIVER_HANDS_OFF}


class SimulationError(LdeError, RuntimeError):
    """The simulation cannot go on (the plant diverged: unphysical parameters)."""


def default_t0_ns(seed: int) -> int:
    """1_700_000_000 s + (seed mod 10^6) s, in ns."""
    return EPOCH_NS + (int(seed) % 1_000_000) * 1_000_000_000


@dataclass
class SimResult:
    """A finished run.

    Attributes:
        frames: every input frame, stably sorted by time (is_rx True: they are what lde receives).
        truth: columns of :data:`vcan_sim.truth.TRUTH_COLUMNS` at the 3.9 ms grid; ``truth_t_ns`` the
            same times as integers.
        scenario, seed, t0_ns, profile (name), body (the loaded vehicle's mass properties).
    """

    frames: FrameBatch
    truth: dict[str, np.ndarray]
    truth_t_ns: np.ndarray
    scenario: Scenario
    seed: int
    t0_ns: int
    profile: str
    body: LoadedBody


class Simulation:
    """One scenario run, advanced by :meth:`step` (3.9 ms) or :meth:`run` (to the end, fast).

    Args:
        scenario: a :class:`Scenario` or its registry name.
        vehicle: a :class:`lde.params.Vehicle`, a shipped name or a TOML path (default: reference).
        profile: CAN profile name / DBC path or a loaded :class:`Profile`.
        seed: seeds every random part (wind, driver, sensors).
        duration: [s], default the scenario's.
        t0_ns: start of the simulated clock (default :func:`default_t0_ns`).
        speed_kmh: run the scenario at this constant speed instead.
        sim_params: override the vehicle's ``[sim]`` data.
        keep_truth: collect the truth (default True).
    """

    def __init__(
        self,
        scenario: Scenario | str,
        vehicle: Vehicle | str | None = None,
        profile: Profile | str = "lde",
        seed: int = 0,
        duration: float | None = None,
        t0_ns: int | None = None,
        speed_kmh: float | None = None,
        sim_params: SimParams | None = None,
        keep_truth: bool = True,
    ) -> None:
        sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
        if speed_kmh is not None:
            if not 10.0 <= speed_kmh <= 250.0:
                raise ConfigError(f"speed {speed_kmh} km/h outside 10..250")
            sc = sc.with_speed(speed_kmh)
        self.scenario = sc
        self.vehicle = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
        self.profile = profile if isinstance(profile, Profile) else load_profile(profile)
        if isinstance(seed, bool) or int(seed) != seed or seed < 0:
            raise ConfigError(f"seed {seed!r} must be a non-negative integer")
        self.seed = int(seed)
        dur = sc.duration if duration is None else float(duration)
        if not (0.0 < dur <= MAX_DURATION):
            raise ConfigError(f"duration {dur} s outside (0, {MAX_DURATION:.0f}]")
        self.duration = dur
        self.t0_ns = default_t0_ns(seed) if t0_ns is None else int(t0_ns)
        if not 0 <= self.t0_ns <= MAX_T0_NS:
            raise ConfigError(
                f"start time t0 {self.t0_ns * 1e-9:.9g} s outside 0..{MAX_T0_NS // 1_000_000_000} s "
                "(epoch seconds; timestamps are int64 ns)"
            )
        sp = sim_params if sim_params is not None else sim_params_from_vehicle(self.vehicle)
        self.sp = replace(sp, driver=sc.driver_style.apply(sp.driver))
        if sc.driver not in _DRIVER_MODES:
            raise ConfigError(f"scenario {sc.name}: unknown driver {sc.driver!r}")
        rngs = rng_streams(self.seed)
        self.model = P.build_plant(
            self.vehicle,
            self.sp,
            combined(self.sp, payload_by_name(sc.payload)),
            _DRIVER_MODES[sc.driver],
            rngs[STREAM_DRIVER_GAINS],
        )
        n_steps = int(np.ceil(dur * 1e9 / STEP_NS))
        self.n_steps = n_steps
        self.n_sub = n_steps * SUBSTEPS
        t = np.arange(self.n_sub + 1) * H
        self.disturbance = disturbance_profile(sc, t, rngs[STREAM_WIND])
        self.drive = self._drive_matrix(self.disturbance, t, rngs[STREAM_DRIVER_NOISE])
        self.streams: list[MessageStream] = build_streams(
            self.profile, n_steps * STEP_NS, H_NS, self.sp.sensors, rngs[STREAM_SENSORS], sc.faults
        )
        self.delay = delay_substeps(self.sp.sensors, H)
        ring = SUBSTEPS * _CHUNK_STEPS + 4 * max(self.delay, 1) + 64
        self.out = np.zeros((ring, P.N_OUT))
        self.x = P.initial_state(self.disturbance.speed[0])
        self.k = 0  # next sub-step to integrate
        self.keep_truth = keep_truth
        self._truth: list[dict[str, np.ndarray]] = []
        self._truth_t: list[np.ndarray] = []
        self._frames: list[FrameBatch] = []
        self._drained = (0, 0)  # (frame pieces, truth pieces) handed out by drain_new

    # ---------------------------------------------------------------- inputs
    def _drive_matrix(self, d: DisturbanceProfile, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        n = t.size
        drive = np.zeros((n, P.N_DRIVE))
        drive[:, P.D_WX] = d.wind_x
        drive[:, P.D_WY] = d.wind_y
        drive[:, P.D_BANK] = d.bank
        # lane centre the driver sees at its preview point
        shift = int(round(self.sp.driver.preview_time / H))
        drive[:, P.D_YREFP] = _ahead(d.lane, shift)
        drive[:, P.D_KAPPA] = d.curvature
        drive[:, P.D_KAPPAP] = _ahead(d.curvature, shift)
        drive[:, P.D_TNOISE] = ou_process(n, H, self.sp.driver.noise_torque, self.sp.driver.noise_time, rng)
        drive[:, P.D_VREF] = d.speed
        drive[:, P.D_TOVREQ] = d.overlay
        drive[:, P.D_SWCMD] = d.steer
        return drive

    # ---------------------------------------------------------------- time
    @property
    def t_ns(self) -> int:
        """Absolute simulated time of the next sub-step to integrate [ns]."""
        return self.t0_ns + self.k * H_NS

    @property
    def done(self) -> bool:
        return self.k >= self.n_sub

    # ---------------------------------------------------------------- advancing
    def _advance(self, n_sub: int, ov_req: float | None) -> FrameBatch:
        k0 = self.k
        k1 = min(self.n_sub, k0 + n_sub)
        r = self.out.shape[0]
        k = k0
        while k < k1:  # split at the ring's end
            stop = min(k1, k + (r - k % r))
            P.run_span(self.model, self.x, self.drive, k, stop, H, self.out, k % r, ov_req)
            k = stop
        self.k = k1
        if not np.all(np.isfinite(self.x)):
            raise SimulationError(
                f"{self.scenario.name}: the plant diverged before t = {(k1 * H_NS) * 1e-9:.3f} s "
                "(check the vehicle's [sim] parameters)"
            )
        parts = [
            emit_range(self.profile, s, k0, k1, self.out, self.delay, self.sp.sensors, self.t0_ns)
            for s in self.streams
        ]
        frames = FrameBatch.concat([p for p in parts if p is not None] or [FrameBatch.empty()], sort=True)
        if self.keep_truth:
            first = -(-k0 // SUBSTEPS) * SUBSTEPS
            idx = np.arange(first, k1, SUBSTEPS)
            if idx.size:
                t_ns = self.t0_ns + idx * H_NS
                self._truth.append(truth_rows(t_ns, self.out[idx % r]))
                self._truth_t.append(t_ns)
        return frames

    def step(self, overlay_request: float | None = None) -> FrameBatch:
        """Advance one estimator period (3.9 ms); the frames due in it, sorted by time.

        ``overlay_request`` [Nm at the column, left positive] replaces the scenario's scripted
        overlay (closed loop); None keeps the script.
        """
        frames = self._advance(SUBSTEPS, overlay_request)
        self._frames.append(frames)
        return frames

    def run(self) -> None:
        """Open loop to the end, in large jitted chunks."""
        while not self.done:
            self.run_steps(_CHUNK_STEPS)

    def run_steps(self, n_steps: int) -> None:
        """Open loop for ``n_steps`` estimator periods (fewer at the end) in one jitted call: the
        same frames and truth however a run is cut into such pieces."""
        self._frames.append(self._advance(SUBSTEPS * max(1, int(n_steps)), None))

    def drain_new(self) -> tuple[FrameBatch, dict[str, np.ndarray], np.ndarray]:
        """(frames, truth columns, truth times [ns]) produced since the previous call (from the
        start at the first): what a streaming writer has not written yet. Frames sorted by time;
        pieces drained one after the other join into :meth:`frames` and :meth:`truth`."""
        f0, t0 = self._drained
        self._drained = (len(self._frames), len(self._truth))
        new_frames, new_truth, new_t = self._frames[f0:], self._truth[t0:], self._truth_t[t0:]
        if len(new_frames) == 1 and len(new_truth) <= 1:  # one step's worth (live): no copies
            truth = new_truth[0] if new_truth else concat_truth([])
            return new_frames[0], truth, new_t[0] if new_t else np.zeros(0, np.int64)
        frames = FrameBatch.concat(new_frames or [FrameBatch.empty()], sort=True)
        t = np.concatenate(new_t) if new_t else np.zeros(0, np.int64)
        return frames, concat_truth(new_truth), t

    # ---------------------------------------------------------------- results
    def frames(self) -> FrameBatch:
        """All frames emitted so far, stably sorted by time."""
        return FrameBatch.concat(self._frames or [FrameBatch.empty()], sort=True)

    def truth(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """(truth columns, their times [ns]) collected so far."""
        t = np.concatenate(self._truth_t) if self._truth_t else np.zeros(0, np.int64)
        return concat_truth(self._truth), t

    def result(self) -> SimResult:
        truth, t = self.truth()
        return SimResult(
            frames=self.frames(),
            truth=truth,
            truth_t_ns=t,
            scenario=self.scenario,
            seed=self.seed,
            t0_ns=self.t0_ns,
            profile=self.profile.name,
            body=self.model.body,
        )


def _ahead(x: np.ndarray, shift: int) -> np.ndarray:
    """``x`` advanced by ``shift`` samples (what lies ahead), its last value held at the end."""
    n = x.size
    return np.concatenate([x[shift:], np.full(min(shift, n), x[-1])])[:n]


def simulate(
    scenario: Scenario | str,
    vehicle: Vehicle | str | None = None,
    profile: Profile | str = "lde",
    seed: int = 0,
    duration: float | None = None,
    **kw,
) -> SimResult:
    """Fast path: run ``scenario`` open loop to the end; frames + truth (see :class:`Simulation`)."""
    sim = Simulation(scenario, vehicle, profile, seed, duration, **kw)
    sim.run()
    return sim.result()


def scenario_with(scenario: Scenario | str, **changes) -> Scenario:
    """A registry scenario with some fields replaced (tests, studies)."""
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    return replace(sc, **changes)
