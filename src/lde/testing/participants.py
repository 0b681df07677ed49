"""What takes part on a bench: the simulator, the lde service, a plain input feeder.

Each has its own :class:`~lde.testing.bus.BenchBus` and acts only when the bench's scheduler calls it,
at its own instants (see :mod:`lde.testing.scheduler` for the order within one instant).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import can
import numpy as np

from lde.can.codec import MessageEncoder, si_to_dbc
from lde.can.frames import ns_to_seconds, seconds_to_ns
from lde.can.profiles import Profile
from lde.errors import ConfigError
from lde.io.recording import LEARNED_START_KEY, Recorder
from lde.params import Vehicle
from lde.service.service import Service, StepResult
from lde.testing.scheduler import Rank
from lde.units import STEP_NS
from vcan_sim.closed_loop import OverlayReceiver, OverlayStats
from vcan_sim.run import Simulation

if TYPE_CHECKING:
    from lde.testing.bench import Bench

__all__ = ["InputFeeder", "BenchSimulator", "BenchService", "TruthTable", "OverlaySource"]

#: a value of :class:`InputFeeder`: a constant or a function of the frame's time [ns]
InputValue = float | Callable[[int], float]
#: where the simulator's MDPS takes its overlay torque from: ``"bus"`` (``LDE_Overlay`` frames, E2E
#: checked), None (the scenario's script: open loop) or the user's ECU model ``f(t_ns) -> Nm``
#: (None from it: the script at that instant)
OverlaySource = str | None | Callable[[int], float | None]


class InputFeeder:
    """The profile's input messages at their DBC periods, values in SI, without a plant.

    Every input message of the profile (``MDPS_Sensors`` every 3.9 ms and ``ESC_Motion`` every 10 ms
    on ``lde``) is encoded by lde's codec (counters, CRCs) from :attr:`values`, the seven estimator
    inputs in SI (``column_torque`` Nm, ``assist_torque`` Nm, ``steering_angle`` rad,
    ``steering_rate`` rad/s, ``yaw_rate`` rad/s, ``lat_accel`` m/s^2, ``speed`` m/s), each a constant
    or a function of the frame's time [ns]. Frames carry their nominal times as timestamps.

    On a bench (:meth:`Bench.feeder`) the scheduler sends each frame at its time; by hand,
    :meth:`send_until` sends every frame due at or before a time (for tests that step the service
    themselves).

    Args:
        bus: where the frames go.
        profile: the CAN profile.
        first_ns: time of each message's first frame [ns]: one time for all, or per message name.
        silent: ``silent(message, t_ns)`` True: that frame is not sent (its counter does not advance).
        tamper: ``tamper(message, t_ns, msg)`` may change a frame after encoding (break its CRC...).
        **values: initial input values (default 0.0).
    """

    def __init__(
        self,
        bus: can.BusABC,
        profile: Profile,
        first_ns: int | Mapping[str, int],
        *,
        silent: Callable[[str, int], bool] | None = None,
        tamper: Callable[[str, int, can.Message], None] | None = None,
        **values: InputValue,
    ) -> None:
        self.bus = bus
        self.profile = profile
        self.messages = tuple(profile.messages)  # ties at one instant go in this order
        self.encoders = {m: MessageEncoder(profile, m) for m in self.messages}
        if isinstance(first_ns, Mapping):
            unknown = sorted(set(first_ns) - set(self.messages))
            if unknown:
                raise ConfigError(
                    f"first_ns names {unknown}; the profile's input messages are {list(self.messages)}"
                )
            self.next_ns = {m: int(first_ns[m]) for m in self.messages}
        else:
            self.next_ns = dict.fromkeys(self.messages, int(first_ns))
        self.period_ns = {m: profile.messages[m].period_ns for m in self.messages}
        self.values: dict[str, InputValue] = dict.fromkeys(profile.inputs, 0.0)
        self.set(**values)
        self.silent = silent
        self.tamper = tamper
        self.sent = 0

    def set(self, **values: InputValue) -> None:
        """Change input values (SI) from the next frame on."""
        unknown = sorted(set(values) - set(self.values))
        if unknown:
            raise ConfigError(f"unknown inputs {unknown}; the inputs are {list(self.values)}")
        self.values.update(values)

    def due_ns(self) -> int:
        """Time of the next frame [ns]."""
        return min(self.next_ns.values())

    def send_until(self, t_ns: int) -> int:
        """Send every frame due at or before ``t_ns``, in time order; returns how many were sent."""
        n = 0
        nxt = self.next_ns
        while True:
            m = min(self.messages, key=lambda k: nxt[k])  # first in profile order among equal times
            t = nxt[m]
            if t > t_ns:
                return n
            nxt[m] = t + self.period_ns[m]
            if self.silent is not None and self.silent(m, t):
                continue
            si = {i: self._value(i, t) for i in self.profile.messages[m].inputs}
            vals = cast(dict[str, float], si_to_dbc(self.profile, m, si))  # scalars in, scalars out
            msg = self.encoders[m].message(vals, t)
            if self.tamper is not None:
                self.tamper(m, t, msg)
            self.bus.send(msg)
            self.sent += 1
            n += 1

    def _value(self, name: str, t_ns: int) -> float:
        v = self.values[name]
        return float(v(t_ns)) if callable(v) else float(v)


class TruthTable(Mapping[str, np.ndarray]):
    """The simulator's ground truth, one row per 3.9 ms period (columns: :data:`vcan_sim.truth.TRUTH_COLUMNS`,
    SI, ISO signs; ``t`` in epoch seconds of the bench's time base).

    Args:
        columns: column name -> values.
        t_ns: the rows' times [ns].
        t0_ns: the simulation's start [ns].
    """

    def __init__(self, columns: Mapping[str, np.ndarray], t_ns: np.ndarray, t0_ns: int) -> None:
        self._cols = dict(columns)
        self.t_ns = np.asarray(t_ns, np.int64)
        self.t0_ns = int(t0_ns)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self._cols[name]
        except KeyError:
            raise KeyError(f"no truth column {name!r}; columns: {list(self._cols)}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._cols)

    def __len__(self) -> int:
        return len(self._cols)

    @property
    def elapsed(self) -> np.ndarray:
        """Seconds since the simulation started, per row."""
        return (self.t_ns - self.t0_ns) / 1e9

    def window(self, start_s: float, end_s: float | None = None) -> TruthTable:
        """The rows with ``start_s <= elapsed < end_s`` (seconds since the simulation started)."""
        e = self.elapsed
        keep = e >= start_s if end_s is None else (e >= start_s) & (e < end_s)
        return TruthTable({k: v[keep] for k, v in self._cols.items()}, self.t_ns[keep], self.t0_ns)

    def at(self, t_ns: int) -> dict[str, float]:
        """The last row at or before bench time ``t_ns`` (KeyError before the first row)."""
        k = int(np.searchsorted(self.t_ns, int(t_ns), side="right")) - 1
        if k < 0:
            raise KeyError(f"no truth at or before {t_ns} ns (first row {self.t_ns[:1]})")
        return {c: float(v[k]) for c, v in self._cols.items()}


class BenchSimulator:
    """The vehicle simulator (:class:`vcan_sim.run.Simulation`) on a bench.

    At every period start (3.9 ms from the bench's current time when added) it takes the overlay
    request (see ``overlay``), advances the plant one period and hands its frames to the scheduler,
    which puts each on the bus at its own time (so a participant reading the bus at ``t`` sees
    exactly the frames stamped ``<= t``, as on a real bus).

    Args:
        bench: the bench.
        scenario: a :mod:`vcan_sim.scenarios` name (``lde sim --list``) or a Scenario.
        seed: seeds every random part (same seed, same frames).
        duration: [s]; default the scenario's.
        vehicle: the simulated car (Vehicle, shipped name or TOML path; default the bench's).
        overlay: ``"bus"`` (default: the MDPS applies ``OverlayTorque`` of the ``LDE_Overlay`` frames
            it receives, E2E checked, :class:`vcan_sim.closed_loop.OverlayReceiver`), None (the
            scenario's scripted overlay: open loop), or a callable ``f(t_ns) -> Nm | None``: the
            user's MDPS ECU model decides the torque the motor applies in the period starting at
            ``t_ns`` (it reads the bus itself).
        speed_kmh: run the scenario at this constant speed.
        name: the participant's name.
    """

    def __init__(
        self,
        bench: Bench,
        scenario: Any,
        *,
        seed: int = 0,
        duration: float | None = None,
        vehicle: Vehicle | str | None = None,
        overlay: OverlaySource = "bus",
        speed_kmh: float | None = None,
        name: str = "simulator",
    ) -> None:
        if isinstance(overlay, str) and overlay != "bus":
            raise ConfigError(f"overlay={overlay!r}: use 'bus', None (the scenario's script) or a callable")
        self.bench = bench
        self.name = name
        self.sim = Simulation(
            scenario,
            bench.vehicle if vehicle is None else vehicle,
            bench.profile,
            seed=seed,
            duration=duration,
            t0_ns=bench.now_ns,
            speed_kmh=speed_kmh,
        )
        self.bus = bench.bus(name)
        self.receiver = OverlayReceiver(bench.profile) if overlay == "bus" else None
        self._overlay_fn = overlay if callable(overlay) else None
        self.frames_sent = 0
        self.steps = 0
        self._pending = 0  # frames handed to the scheduler, not yet on the bus
        bench.scheduler.at(self.sim.t_ns, self._step, Rank.SOURCE, f"{name} step")

    @property
    def t0_ns(self) -> int:
        """The simulation's start on the bench [ns]."""
        return self.sim.t0_ns

    @property
    def done(self) -> bool:
        """The scenario has ended and its last frames are on the bus."""
        return self.sim.done and self._pending == 0

    @property
    def overlay_stats(self) -> OverlayStats | None:
        """``LDE_Overlay`` frames received / used / rejected by the MDPS (``overlay="bus"`` only)."""
        return self.receiver.stats if self.receiver is not None else None

    def _step(self, t_ns: int) -> None:
        rx = self.receiver
        for msg in self.bus:  # the frames that reached the MDPS during the last period
            if rx is not None:
                rx.on_message(msg, seconds_to_ns(msg.timestamp))
        if rx is not None:
            req: float | None = rx.request(t_ns)
        elif self._overlay_fn is not None:
            v = self._overlay_fn(t_ns)
            req = None if v is None else float(v)
        else:
            req = None
        frames = self.sim.step(req)
        self.steps += 1
        sched = self.bench.scheduler
        n = len(frames)
        k = 0
        while k < n:  # one release per distinct frame time
            t = int(frames.t_ns[k])
            j = k
            while j < n and int(frames.t_ns[j]) == t:
                j += 1
            msgs = [
                can.Message(
                    timestamp=ns_to_seconds(t),
                    arbitration_id=int(frames.can_id[i]),
                    is_extended_id=bool(frames.is_extended[i]),
                    dlc=int(frames.dlc[i]),
                    data=bytes(frames.data[i, : int(frames.dlc[i])]),
                    is_fd=int(frames.dlc[i]) > 8,
                )
                for i in range(k, j)
            ]
            self._pending += len(msgs)
            sched.at(t, self._releaser(msgs), Rank.SOURCE, f"{self.name} frames")
            k = j
        if not self.sim.done:
            sched.at(self.sim.t_ns, self._step, Rank.SOURCE, f"{self.name} step")

    def _releaser(self, msgs: list[can.Message]) -> Callable[[int], None]:
        def release(t_ns: int) -> None:
            for msg in msgs:
                self.bus.send(msg)
            self._pending -= len(msgs)
            self.frames_sent += len(msgs)

        return release

    def truth(self) -> TruthTable:
        """The ground truth so far (one row per period stepped)."""
        cols, t = self.sim.truth()
        return TruthTable(cols, t, self.sim.t0_ns)


class BenchService:
    """The lde service (:class:`lde.service.service.Service`, the code of ``lde run``) on a bench.

    It runs :meth:`Service.step_once` at ``t_k = start + k * 3.9 ms`` on the bench's clock and keeps
    every :class:`~lde.service.service.StepResult` in :attr:`results`; its frames are on the bus (and in the
    bench's capture).

    Args:
        bench: the bench.
        backend: ``fixed`` (the product default: the firmware model with its float shadow) or ``float``.
        vehicle: the estimator's parameter set (default the bench's).
        overlay: False: the overlay request stays zero (``lde run --no-overlay``).
        drop: lde output messages kept off the bus (e.g. ``("LDE_Overlay",)`` when the user's
            controller sends the overlay request instead).
        phase_s: the first step this long after the bench's start (default 0: in step with the
            simulator's periods).
        record: write the service's MCAP recording there (as ``lde run --record``).
        learned: the learned-state file of ``lde run --learned``: read at the start when it exists,
            written every 60 s of bench time and at :meth:`close` (a learning backend).
        name: the participant's name.
    """

    def __init__(
        self,
        bench: Bench,
        *,
        backend: str = "fixed",
        vehicle: Vehicle | str | None = None,
        overlay: bool = True,
        drop: Iterable[str] = (),
        phase_s: float = 0.0,
        record: str | Path | None = None,
        learned: str | Path | None = None,
        name: str = "lde",
    ) -> None:
        profile = bench.profile
        drop = tuple(drop)
        for m in drop:
            if m not in profile.outputs:
                raise ConfigError(f"drop={m!r}: not an lde output message ({', '.join(profile.outputs)})")
        self.bench = bench
        self.name = name
        self.bus = bench.bus(name, drop=[profile.outputs[m].frame_id for m in drop])
        veh = bench.vehicle if vehicle is None else vehicle
        self.service = Service(
            self.bus,
            profile,
            veh,
            bench.clock,
            backend,
            overlay_enabled=overlay,
            log_period_s=0,
            learned=learned,
        )
        self.recorder: Recorder | None = None
        if record is not None:
            meta = {
                "profile": profile.name,
                "backend": backend,
                "step_ns": str(STEP_NS),
                "bench": bench.channel,
            }
            if self.service.learned_start:
                meta[LEARNED_START_KEY] = self.service.learned_start
            self.recorder = self.service.recorder = Recorder(
                record, metadata=meta, frame_bytes=self.service.rx_width
            )
        self.results: list[StepResult] = []
        self.task = bench.every(STEP_NS / 1e9, self._step, phase_s=phase_s, rank=Rank.SERVICE, name=name)

    def _step(self, t_ns: int) -> None:
        self.results.append(self.service.step_once(t_ns))

    @property
    def last(self) -> StepResult | None:
        return self.results[-1] if self.results else None

    def series(self, field: str) -> np.ndarray:
        """One :class:`~lde.service.service.StepResult` field over every step (``t_ns``, ``fw``, ``mw``,
        ``t_overlay``, ``status``, ...)."""
        if field not in StepResult.__dataclass_fields__:
            raise ConfigError(
                f"StepResult has no field {field!r}; fields: {list(StepResult.__dataclass_fields__)}"
            )
        return np.array([getattr(r, field) for r in self.results])

    def stop(self) -> None:
        """Ramp the overlay out and keep stepping (as SIGTERM does to ``lde run``)."""
        self.service.request_stop()

    def close(self) -> None:
        try:
            self.service.close()
        finally:
            self._close_recorder()

    def _close_recorder(self) -> None:
        if self.recorder is not None:
            self.recorder.close()
            self.recorder = None
