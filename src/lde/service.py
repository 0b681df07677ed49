"""The live service: one estimator step every 3.9 ms on absolute deadlines.

One step (:meth:`Service.step_once`) at step time ``t_k``:

1. drain the bus; every frame is stamped with its receive time (the bus's timestamp, microsecond
   rounded exactly like the log readers do: :func:`lde.frames.seconds_to_ns`); a frame whose
   timestamp is at or before the previous step's time (the sender's kernel stamped it, but it
   reached the socket only after that step's drain: seen in user-mode Linux with a real-time
   sender) is re-stamped to the first microsecond after the previous step and counted
   (``Service.late_rx``), so that the recording says when it could be used;
2. feed the E2E receiver (:class:`lde.signals.Receiver`) with exactly the frames whose receive
   timestamp is ``<= t_k``, in timestamp order; later frames stay buffered for the next step;
3. sample the latest valid inputs (sample-and-hold, staleness) at ``t_k``;
4. one Kalman step (backend ``fixed`` = :mod:`firmware_model` or ``float`` = :mod:`lde.step`);
5. the overlay feed-forward law and limiter (:mod:`lde.overlay`);
6. send ``LDE_Estimate`` and ``LDE_Overlay`` (counters and CRCs by :mod:`lde.codec`), then
   ``LDE_Diag`` with this step's timing;
7. hand the received and sent frames, the estimate and the diagnostics to the recorder (a queue:
   the writing happens in the recorder's thread).

Determinism: the step uses nothing but (the frames with receive time ``<= t_k``, ``t_k``), so a replay
of the recording on the recorded step times (``/lde/estimate`` field ``t_ns``) with the same
receiver and grid semantics gives the same ``Fw``, ``Mw`` and ``T_overlay`` bit for bit.

Time bases: the loop's deadlines live on the service's :class:`lde.clock` clock (monotonic live,
simulated in the demo); step times ``t_k`` handed to the estimator and written to the recording live
in the *bus's* time base (the frames' receive timestamps: epoch time for SocketCAN and python-can's
virtual bus). ``t_k = t_clock + offset`` with ``offset`` measured once at start
(``time.time_ns() - clock.now_ns()`` for a live clock, 0 for a simulated one).
"""

from __future__ import annotations

import gc
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can

from .conditioning import check_profile
from .diagnostics import DEADLINE_MISS_NS, StepTiming, TimingStats, TimingSummary, diag_signals
from .errors import BusError, ConfigError
from .frames import ns_to_seconds, seconds_to_ns
from .units import STEP_NS

__all__ = ["Service", "StepResult", "STATUS_DEADLINE_MISS", "make_estimator"]

log = logging.getLogger(__name__)

STATUS_VALID = 0x01
STATUS_DEGRADED = 0x02
#: ``LDE_Estimate.Status`` bit7: this step ran more than 1 ms late (docs/ARCHITECTURE.md).
STATUS_DEADLINE_MISS = 0x80

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
        frames_used: input frames fed to the receiver in this step.
        timing: this step's timing (None in lockstep mode without timing).
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


def _finite(x: float) -> float:
    return x if math.isfinite(x) else 0.0


def make_estimator(vehicle: Any, backend: str = "fixed") -> Any:
    """The estimator for ``backend``: ``fixed`` (firmware model, float shadow) or ``float`` (lde.step).

    Both have ``step(t_ns, inputs)`` and ``reset()``. ``fixed`` falls back to ``float`` with a warning
    while the firmware model is not installed.
    """
    if backend not in ("fixed", "float"):
        raise ConfigError(f"unknown backend {backend!r} (choose fixed or float)")
    if backend == "fixed":
        try:
            from firmware_model import FixedEstimator
        except ImportError:
            try:
                from firmware_model.fast import FixedEstimator
            except ImportError:
                log.warning("backend 'fixed': firmware_model.FixedEstimator not available, using 'float'")
                FixedEstimator = None  # noqa: N806
        if FixedEstimator is not None:
            return FixedEstimator(vehicle)
    from .step import Estimator

    return Estimator(vehicle)


def _load_profile(profile: Any) -> Any:
    if isinstance(profile, str):
        from .profiles import load_profile

        return load_profile(profile)
    return profile


def _load_vehicle(vehicle: Any) -> Any:
    if vehicle is None or isinstance(vehicle, str):
        from .params import load_vehicle

        return load_vehicle(vehicle)
    return vehicle


def _is_simulated(clock: Any) -> bool:
    return type(clock).__name__ == "SimulatedClock"


class Service:
    """The live estimator service on one python-can bus.

    Args:
        bus: an open ``can.BusABC`` (the CLI or the test opens it; the service never does).
        profile: a CAN profile object or name (``lde``, ``hyundai``).
        vehicle: a :class:`lde.params.Vehicle`, a shipped vehicle name or None (reference).
        clock: a :mod:`lde.clock` clock (``now_ns()``, ``sleep_until(t_ns)``).
        backend: ``fixed`` (default) or ``float``.
        recorder: optional :class:`lde.recording.Recorder` (already started).
        overlay_enabled: False keeps the overlay request at zero (the demo's "without overlay" run).
        timebase_offset_ns: bus time minus clock time [ns]; None: measured at start (0 for a
            simulated clock).
        log_period_s: period of the timing summary log line [s]; 0 disables it.
    """

    def __init__(
        self,
        bus: can.BusABC,
        profile: Any,
        vehicle: Any,
        clock: Any,
        backend: str = "fixed",
        recorder: Any = None,
        *,
        overlay_enabled: bool = True,
        timebase_offset_ns: int | None = None,
        log_period_s: float = 10.0,
    ) -> None:
        from .codec import MessageEncoder
        from .overlay import OverlayLimiter
        from .signals import Receiver

        self.bus = bus
        self.profile = _load_profile(profile)
        self.vehicle = _load_vehicle(vehicle)
        self.clock = clock
        self.backend = backend
        self.recorder = recorder
        self.overlay_enabled = overlay_enabled
        if timebase_offset_ns is None:
            timebase_offset_ns = 0 if _is_simulated(clock) else time.time_ns() - clock.now_ns()
        self.offset_ns = int(timebase_offset_ns)
        self.log_period_ns = int(log_period_s * 1e9)

        self.receiver = Receiver(self.profile)
        check_profile(self.vehicle, self.profile.steering_rate_signed, self.profile.name)
        self.estimator = make_estimator(self.vehicle, backend)
        self.limiter = OverlayLimiter(self.vehicle)
        self._enc_estimate = MessageEncoder(self.profile, "LDE_Estimate")
        self._enc_overlay = MessageEncoder(self.profile, "LDE_Overlay")
        self._enc_diag = MessageEncoder(self.profile, "LDE_Diag")

        self._warm_up()
        self.stats = TimingStats()
        self._pending: list[tuple[int, can.Message]] = []  # (t_rx_ns, msg), not yet used
        self._newest_input_ns = -1  # receive time of the newest frame used so far
        self._restamp: bool | None = None  # stamp frames on receipt (decided at the first frame)
        self._last_t_k: int | None = None  # step time of the last step run [ns, bus time base]
        self.late_rx = 0  # frames delivered after a step later than their timestamp: re-stamped
        self._stopping = False  # ramp-out requested (shutdown)
        self.steps = 0
        self.send_errors = 0  # frames the bus refused (full tx queue, bus-off), counted, not raised
        self.recv_errors = 0  # failed receive calls, counted, not raised
        self.last: StepResult | None = None

    def _warm_up(self) -> None:
        """Run the compiled kernels once on throwaway objects so the first real step is not late
        (numba loads or compiles a kernel at its first call)."""
        from .overlay import OverlayLimiter
        from .signals import Receiver

        rx = Receiver(self.profile)
        est = make_estimator(self.vehicle, self.backend)
        lim = OverlayLimiter(self.vehicle)
        for k in range(3):
            t = k * STEP_NS
            inputs = rx.sample(t)
            lim.step(t, est.step(t, inputs), inputs, enable=True)

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

    def _feed_ready(self, t_k: int) -> int:
        """Feed the receiver with the pending frames received at or before ``t_k`` (time order)."""
        pending = self._pending
        if not pending:
            return 0
        ready = [p for p in pending if p[0] <= t_k]
        if not ready:
            return 0
        if len(ready) == len(pending):
            pending.clear()
        else:
            self._pending = [p for p in pending if p[0] > t_k]
        ready.sort(key=lambda p: p[0])  # stable: arrival order among equal timestamps
        feed = self.receiver.feed
        for t_rx, msg in ready:
            feed(t_rx, msg.arbitration_id, msg.data, msg.dlc, msg.is_extended_id)
        self._newest_input_ns = ready[-1][0]
        return len(ready)

    def step_once(self, t_k: int, t_start: int | None = None) -> StepResult:
        """Run one step at step time ``t_k`` [ns, bus time base] and send its outputs.

        ``t_start`` is the actual start time (bus time base); None reads the clock. The period
        error is ``t_start - t_k``.
        """
        if t_start is None:
            t_start = self.now_ns()
        self._drain()
        n_used = self._feed_ready(t_k)
        self._last_t_k = t_k
        inputs = self.receiver.sample(t_k)
        est = self.estimator.step(t_k, inputs)
        enable = self.overlay_enabled and not self._stopping
        ov = self.limiter.step(t_k, est, inputs, enable=enable)

        period_error = t_start - t_k
        miss = period_error > DEADLINE_MISS_NS
        status = int(est.status) | (STATUS_DEADLINE_MISS if miss else 0)
        fw, mw, t_align = float(est.fw), float(est.mw), float(est.t_align)
        t_ov = float(ov.torque)
        if not (math.isfinite(fw) and math.isfinite(mw) and math.isfinite(t_align) and math.isfinite(t_ov)):
            # never put NaN on the bus: zeros, VALID cleared, DEGRADED set
            fw, mw, t_align, t_ov = _finite(fw), _finite(mw), _finite(t_align), _finite(t_ov)
            status = (status & ~STATUS_VALID) | STATUS_DEGRADED
        m_est = self._enc_estimate.message(
            {"LatForce": fw, "YawMoment": mw, "AligningTorque": t_align, "Status": status}, t_k
        )
        m_ov = self._enc_overlay.message(
            {"OverlayTorque": t_ov, "Active": int(ov.active), "State": int(ov.state)}, t_k
        )
        self._send(m_est)
        self._send(m_ov)
        t_sent = self.now_ns()
        latency = t_sent - self._newest_input_ns if self._newest_input_ns >= 0 else -1
        timing = self.stats.record(period_error, t_sent - t_start, latency)
        rejects = self._e2e_rejects()
        m_diag = self._enc_diag.message(diag_signals(timing, rejects), t_k)
        self._send(m_diag)

        self.steps += 1
        res = StepResult(
            t_ns=t_k,
            fw=fw,
            mw=mw,
            t_align=t_align,
            t_overlay=t_ov,
            overlay_state=int(ov.state),
            overlay_active=bool(ov.active),
            status=status,
            frames_used=n_used,
            timing=timing,
            overlay_enable=enable,
        )
        self.last = res
        if self.recorder is not None:
            self.recorder.step(res, inputs, rejects, self.stats.skipped)
        return res

    def _e2e_rejects(self) -> int:
        return int(getattr(self.receiver, "e2e_rejects", 0))

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
