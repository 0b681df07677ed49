"""The live service: one step of the data path every 3.9 ms on absolute deadlines.

One step (:meth:`Service.step_once`) at step time ``t_k``:

1. drain the bus; every frame is stamped with its receive time (the bus's timestamp, microsecond
   rounded exactly like the log readers do: :func:`lde.frames.seconds_to_ns`); a frame whose
   timestamp is at or before the previous step's time (the sender's kernel stamped it, but it
   reached the socket only after that step's drain: seen in user-mode Linux with a real-time
   sender) is re-stamped to the first microsecond after the previous step and counted
   (``Service.late_rx``), so that the recording says when it could be used;
2. run the data path (:class:`lde.engine.Engine`, explicit step times) with the pending frames in
   time order: exactly those with receive time ``<= t_k`` are fed, then the step at ``t_k`` runs
   (inputs, corrections, backend step, finalisation, overlay limiter, output frames), a late start
   adding DEADLINE_MISS to its status; later frames stay pending for the next step;
3. send the engine's ``LDE_Estimate`` and ``LDE_Overlay`` frames, then ``LDE_Diag`` with this step's
   timing;
4. hand the received and sent frames, the step's row and its timing to the recorder (a queue: the
   writing happens in the recorder's thread);
5. with ``learned`` (``lde run --learned FILE``): every ``learned_period_s`` of step time hand a
   copy of the learned state to a writer thread (:class:`lde.learned.LearnedKeeper`);
   :meth:`Service.close` writes it once more.

Determinism: the step uses nothing but (the frames with receive time ``<= t_k``, ``t_k``, the
overlay enable input, the deadline-miss bit), all of which the recording keeps, so a replay of the
recording (:func:`lde.replay.replay_log`) runs the same engine on the same inputs and gives the same
rows bit for bit.

Time bases: the loop's deadlines live on the service's :class:`lde.clock` clock (monotonic live,
simulated in the demo); step times ``t_k`` handed to the engine and written to the recording live
in the *bus's* time base (the frames' receive timestamps: epoch time for SocketCAN and python-can's
virtual bus). ``t_k = t_clock + offset`` with ``offset`` measured once at start
(``time.time_ns() - clock.now_ns()`` for a live clock, 0 for a simulated one).
"""

from __future__ import annotations

import gc
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np

from .clock import SimulatedClock
from .codec import MessageEncoder
from .diagnostics import DEADLINE_MISS_NS, StepTiming, TimingStats, TimingSummary, diag_signals
from .engine import Engine, StepBlock
from .errors import BusError, ConfigError
from .frames import FrameBatch, ns_to_seconds, seconds_to_ns
from .learned import LearnedKeeper, LearnedSnapshot
from .params import Vehicle, load_vehicle
from .profiles import Profile, load_profile
from .recording import Timing
from .signals import Receiver
from .status import DEADLINE_MISS, VALID
from .units import STEP_NS, STEP_S

__all__ = ["Service", "StepResult", "STATUS_DEADLINE_MISS", "open_bus"]

log = logging.getLogger(__name__)

#: ``LDE_Estimate.Status`` bit7: this step ran more than 1 ms late (docs/ARCHITECTURE.md).
STATUS_DEADLINE_MISS = DEADLINE_MISS

#: a step may be at most this late before grid points are skipped (one whole period)
_SKIP_AFTER_NS = STEP_NS
#: bus timestamps further than this from the service clock are not in its time base [ns]
_RESTAMP_AFTER_NS = 1_000_000_000
#: after a stop request, the overlay ramps out for at most this long before the service ends
_MAX_RAMP_OUT_NS = 3_000_000_000


@dataclass(frozen=True)
class StepResult:
    """What one step produced (SI; ``t_ns`` in the bus/log time base).

    Attributes:
        t_ns: step time t_k [ns].
        fw: estimated disturbance force Fw [N], left positive.
        mw: estimated disturbance yaw moment Mw [Nm], left positive.
        t_align: estimated aligning torque T_align_hat [Nm] (paper sign).
        t_overlay: overlay torque request sent [Nm] at the column, left positive.
        overlay_state: limiter state (0 off, 1 ramp-in, 2 active, 3 ramp-out, 4 fault).
        overlay_active: the Active bit sent.
        status: ``LDE_Estimate.Status`` bit map sent (incl. bit7 DEADLINE_MISS).
        frames_used: input frames accepted since the previous step.
        timing: this step's timing.
        overlay_enable: the limiter's ``enable`` input (False: overlay switched off or shutting
            down); a replay needs it to reproduce a shutdown ramp-out.
    """

    t_ns: int
    fw: float
    mw: float
    t_align: float
    t_overlay: float
    overlay_state: int
    overlay_active: bool
    status: int
    frames_used: int
    timing: StepTiming | None
    overlay_enable: bool = True


class Service:
    """The live estimator service on one python-can bus.

    Args:
        bus: an open ``can.BusABC`` (the CLI or the test opens it; the service never does).
        profile: a CAN profile object or name (``lde``, ``hyundai``).
        vehicle: a :class:`lde.params.Vehicle`, a shipped vehicle name or None (reference).
        clock: a :mod:`lde.clock` clock (``now_ns()``, ``sleep_until(t_ns)``).
        backend: a registered backend name (:mod:`lde.backends`): ``fixed`` (default) or ``float``.
        recorder: optional :class:`lde.recording.Recorder` (already started); may be set after
            construction (before the first step), e.g. with :attr:`learned_start` in its metadata.
        overlay_enabled: False keeps the overlay request at zero (the demo's "without overlay" run).
        timebase_offset_ns: bus time minus clock time [ns]; None: measured at start (0 for a
            simulated clock).
        log_period_s: period of the timing summary log line [s]; 0 disables it.
        learned: a learned-state file (``--learned``): read now when it exists (checked against the
            vehicle and profile), written every ``learned_period_s`` of step time and at
            :meth:`close`. Needs a backend that learns (ConfigError otherwise).
        learned_period_s: period of the learned-state writes [s] (SPEC: 60 s).
    """

    def __init__(
        self,
        bus: can.BusABC,
        profile: Profile | str,
        vehicle: Vehicle | str | None,
        clock: Any,
        backend: str = "fixed",
        recorder: Any = None,
        *,
        overlay_enabled: bool = True,
        timebase_offset_ns: int | None = None,
        log_period_s: float = 10.0,
        learned: str | Path | None = None,
        learned_period_s: float = 60.0,
    ) -> None:
        self.bus = bus
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.vehicle = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
        self.clock = clock
        self.backend = backend
        self.recorder = recorder
        self.overlay_enabled = overlay_enabled
        if timebase_offset_ns is None:
            simulated = isinstance(clock, SimulatedClock)
            timebase_offset_ns = 0 if simulated else time.time_ns() - clock.now_ns()
        self.offset_ns = int(timebase_offset_ns)
        self.log_period_ns = int(log_period_s * 1e9)

        self.engine = Engine(self.profile, self.vehicle, backend, explicit=True)
        self._block = StepBlock.empty(1, len(self.engine.outputs.names))
        self._tk = np.zeros(1, np.int64)
        self._enable = np.ones(1, np.bool_)
        self._extra = np.zeros(1, np.uint8)
        self._out_msgs = [
            can.Message(arbitration_id=int(fid), is_extended_id=False, dlc=int(n), data=bytearray(int(n)))
            for fid, n in zip(self.engine.outputs.frame_id, self.engine.outputs.length, strict=True)
        ]
        self._enc_diag = MessageEncoder(self.profile, "LDE_Diag")
        self._warm_up()
        self.stats = TimingStats()
        self._pending: list[tuple[int, can.Message]] = []  # (t_rx_ns, msg), not yet fed
        self._newest_input_ns = -1  # receive time of the newest frame fed so far
        self._restamp: bool | None = None  # stamp frames on receipt (decided at the first frame)
        self._last_t_k: int | None = None  # step time of the last step run [ns, bus time base]
        self.late_rx = 0  # frames delivered after a step later than their timestamp: re-stamped
        self._stopping = False  # ramp-out requested (shutdown)
        self.steps = 0
        self.send_errors = 0  # frames the bus refused (full tx queue, bus-off), counted, not raised
        self.recv_errors = 0  # failed receive calls, counted, not raised
        self.last: StepResult | None = None
        self.valid_steps = 0  # steps with status VALID: the driving time the learner saw
        self.learned: LearnedKeeper | None = None
        #: the learned-state file's text this run started from ("" without one): a recording keeps it
        self.learned_start = ""
        if learned is not None:
            if not learned_period_s > 0:
                raise ConfigError(f"learned period {learned_period_s} s: must be > 0")
            got = self.engine.load_learned(learned)
            if got is None:
                log.info("learned state: %s does not exist yet; learning from the vehicle file", learned)
            else:
                self.learned_start = got.text
                log.info(
                    "learned state from %s (%d drives, %.0f s): %s",
                    learned,
                    got.drives,
                    got.seconds,
                    self.engine.learn_summary,
                )
            self.learned = LearnedKeeper(learned, int(learned_period_s * 1e9))

    def _warm_up(self) -> None:
        """Run the compiled loop once on a throwaway engine, so the first real step is not late
        (numba loads or compiles a kernel at its first call)."""
        e = Engine(self.profile, self.vehicle, self.backend, explicit=True)
        e.feed(FrameBatch.empty(), step_times=np.arange(3, dtype=np.int64) * STEP_NS, final=True)

    @property
    def receiver(self) -> Receiver:
        """The engine's receiver state as a :class:`lde.signals.Receiver` (a view, not a copy)."""
        return Receiver.bound(self.profile, self.engine.rx_tables, self.engine.rx)

    # ------------------------------------------------------------------ one step
    def now_ns(self) -> int:
        """Now, in the bus/log time base [ns]."""
        return self.clock.now_ns() + self.offset_ns

    def _drain(self) -> None:
        """Move every frame waiting in the bus into the pending buffer (and the recording)."""
        recv = self.bus.recv
        rec = self.recorder
        pending = self._pending
        while True:
            try:
                msg = recv(0.0)
            except (can.CanError, OSError) as exc:  # interface down, driver error: count, keep stepping
                self.recv_errors += 1
                if self.recv_errors == 1 or self.recv_errors % 1000 == 0:
                    log.warning("CAN receive failed (%d so far): %s", self.recv_errors, exc)
                return
            if msg is None:
                return
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            t_rx = seconds_to_ns(msg.timestamp)
            if self._restamp is None:
                self._decide_restamp(t_rx)
            if self._restamp:
                t_rx = seconds_to_ns(self.now_ns() / 1e9)
                msg.timestamp = t_rx / 1e9
            last = self._last_t_k
            if last is not None and t_rx <= last:
                # stamped (by the sender's kernel) before a step that has already run without it: it
                # reached our socket only after that step's drain. It takes part from the next step
                # on, so it is recorded with the first microsecond after that step (a replay then
                # feeds it where the live loop did).
                t_rx = (last // 1000 + 1) * 1000
                msg.timestamp = ns_to_seconds(t_rx)
                self.late_rx += 1
            pending.append((t_rx, msg))
            if rec is not None:
                rec.rx(msg)

    def _decide_restamp(self, t_rx: int) -> None:
        """At the first frame: does the bus stamp frames in our time base? An interface whose
        timestamps are not epoch time (device uptime, say) is off by more than :data:`_RESTAMP_AFTER_NS`;
        its frames are then stamped with the service clock when drained (and recorded so)."""
        off = t_rx - self.now_ns()
        self._restamp = abs(off) > _RESTAMP_AFTER_NS
        if self._restamp:
            log.warning(
                "bus timestamps are %.3f s off the service clock: stamping frames on receipt instead",
                off / 1e9,
            )

    def _run_engine(self, t_k: int, enable: bool, miss: bool) -> int:
        """The engine over the pending frames (time order) and the step ``t_k``; returns the
        number of frames it fed (those with receive time <= t_k), which leave the pending buffer."""
        pending = self._pending
        pending.sort(key=lambda p: p[0])  # stable: arrival order among equal timestamps
        n = len(pending)
        t = np.empty(n, np.int64)
        ids = np.empty(n, np.uint32)
        ext = np.empty(n, np.bool_)
        dlc = np.empty(n, np.uint8)
        words = np.empty(n, np.uint64)
        for k, (t_rx, msg) in enumerate(pending):
            t[k] = t_rx
            ids[k] = msg.arbitration_id
            ext[k] = msg.is_extended_id
            dlc[k] = msg.dlc
            words[k] = int.from_bytes(bytes(msg.data[:8]), "little")
        self._tk[0] = t_k
        self._enable[0] = enable
        self._extra[0] = DEADLINE_MISS if miss else 0
        fed, steps = self.engine.run_arrays(
            t, ids, ext, dlc, words, np.ones(n, np.bool_), self._block,
            step_times=self._tk, enable=self._enable, extra_status=self._extra, final=True,
        )  # fmt: skip
        if steps != 1:  # the engine runs every given step when final: a broken invariant
            raise RuntimeError(f"the engine ran {steps} steps for one step time")
        if fed:
            self._newest_input_ns = int(t[fed - 1])
            del pending[:fed]
        return fed

    def step_once(self, t_k: int, t_start: int | None = None) -> StepResult:
        """Run one step at step time ``t_k`` [ns, bus time base] and send its outputs.

        ``t_start`` is the actual start time (bus time base); None reads the clock. The period
        error is ``t_start - t_k``.
        """
        if t_start is None:
            t_start = self.now_ns()
        self._drain()
        period_error = t_start - t_k
        miss = period_error > DEADLINE_MISS_NS
        enable = self.overlay_enabled and not self._stopping
        self._run_engine(t_k, enable, miss)
        self._last_t_k = t_k
        b = self._block
        for j, msg in enumerate(self._out_msgs):
            msg.data[:] = b.frames[0, j, : msg.dlc].tobytes()
            self._send(msg)
        t_sent = self.now_ns()
        latency = t_sent - self._newest_input_ns if self._newest_input_ns >= 0 else -1
        timing = self.stats.record(period_error, t_sent - t_start, latency)
        rejects = int(b.e2e_rejects[0])
        self._send(self._enc_diag.message(diag_signals(timing, rejects), t_k))

        self.steps += 1
        status = int(b.status[0])
        if status & VALID:
            self.valid_steps += 1
        if self.learned is not None and self.learned.due(t_k):
            self.learned.offer(self.learned_snapshot())
        res = StepResult(
            t_ns=t_k,
            fw=float(b.est[0, 0]),
            mw=float(b.est[0, 1]),
            t_align=float(b.est[0, 2]),
            t_overlay=float(b.t_overlay[0]),
            overlay_state=int(b.overlay_state[0]),
            overlay_active=bool(b.overlay_state[0] in (1, 2)),
            status=status,
            frames_used=int(b.frames_used[0]),
            timing=timing,
            overlay_enable=enable,
        )
        self.last = res
        if self.recorder is not None:
            tm = Timing(
                np.array([timing.period_error_ns]),
                np.array([timing.step_time_ns]),
                np.array([timing.latency_ns]),
                np.array([int(timing.deadline_miss)]),
                np.array([timing.deadline_misses]),
                np.array([self.stats.skipped]),
            )
            self.recorder.steps(b.copy(), tm)
        return res

    def _send(self, msg: can.Message) -> None:
        msg.timestamp = self.now_ns() / 1e9
        try:
            self.bus.send(msg)
        except (can.CanError, OSError) as exc:
            # a full tx queue or a bus-off must not kill the loop: count and go on
            self.send_errors += 1
            if self.send_errors == 1 or self.send_errors % 1000 == 0:
                log.warning("CAN send failed (%d so far): %s", self.send_errors, exc)
            return
        if self.recorder is not None:
            self.recorder.tx(msg)  # only frames the bus took

    # ------------------------------------------------------------------ learned state
    def learned_snapshot(self) -> LearnedSnapshot:
        """A copy of what was learned so far (driving time: this run's valid steps)."""
        return self.engine.learned_snapshot(self.valid_steps * STEP_S)

    def close(self) -> None:
        """Write the learned state a last time (with ``learned``; ConfigError when that fails).
        The bus and the recorder belong to the caller."""
        if self.learned is not None:
            keeper, self.learned = self.learned, None
            keeper.close(self.learned_snapshot())
            log.info("learned state written to %s: %s", keeper.path, self.engine.learn_summary)

    # ------------------------------------------------------------------ the loop
    def request_stop(self) -> None:
        """Ask a running :meth:`run` to ramp the overlay out and end (thread/signal safe)."""
        self._stopping = True

    def run(
        self,
        stop_event: threading.Event | None = None,
        max_steps: int | None = None,
        on_step: Callable[[StepResult], None] | None = None,
        t0_ns: int | None = None,
    ) -> TimingSummary:
        """Step on absolute deadlines ``t_k = t_0 + k * STEP_NS`` until stopped.

        Stops after ``max_steps`` steps, or after ``stop_event`` is set (or :meth:`request_stop`
        called) and the overlay has ramped to zero (at most 3 s). A step that would start more
        than one whole period late skips the missed grid points (each counted as a deadline
        miss) instead of running a burst of stale steps.

        ``t0_ns`` (clock time base) is the first deadline; default one period from now.

        Returns the timing summary over the run (the last 65536 steps).
        """
        clock = self.clock
        step = STEP_NS
        # everything allocated so far (modules, tables, DBC objects) leaves the collector's view, so a
        # full collection during the loop scans only what the loop itself allocates
        gc.collect()
        gc.freeze()
        t0 = clock.now_ns() + step if t0_ns is None else int(t0_ns)
        k = 0
        next_log = t0 + self.log_period_ns
        stop_at: int | None = None
        while True:
            t_clk = t0 + k * step
            clock.sleep_until(t_clk)
            now = clock.now_ns()
            late = now - t_clk
            if late >= _SKIP_AFTER_NS:
                n = late // step
                self.stats.record_skipped(n)
                k += n
                t_clk += n * step
            res = self.step_once(t_clk + self.offset_ns, now + self.offset_ns)
            k += 1
            if on_step is not None:
                on_step(res)
            if self.log_period_ns > 0 and now >= next_log:
                log.info("%s", self.stats.take_window().log_line())
                next_log += self.log_period_ns * max(1, (now - next_log) // self.log_period_ns + 1)
            if max_steps is not None and self.steps >= max_steps:
                break
            if not self._stopping and stop_event is not None and stop_event.is_set():
                self._stopping = True
            if self._stopping:
                if stop_at is None:
                    stop_at = now + _MAX_RAMP_OUT_NS
                    log.info("stopping: ramping the overlay out")
                if res.t_overlay == 0.0 or now >= stop_at:
                    break
        return self.stats.summary()


def open_bus(**kwargs: Any) -> can.BusABC:
    """Open a python-can bus the python-can way (arguments, environment, config file).

    ``kwargs`` with value None are left out so that python-can's environment variables
    (``CAN_INTERFACE``, ``CAN_CHANNEL``, ...) and config file fill them in.
    """
    kw = {k: v for k, v in kwargs.items() if v is not None}
    try:
        return can.Bus(**kw)
    except (can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
        raise BusError(f"cannot open CAN bus {kw or '(from python-can config)'}: {exc}") from exc
