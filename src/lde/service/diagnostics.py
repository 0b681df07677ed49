"""Timing diagnostics of the live 3.9 ms loop: period error, step compute time, input-to-output latency.

Definitions (all integer nanoseconds inside, microseconds on the bus and in the log line):

- period error ``e_k = t_start,k - t_k``: actual start of step k minus its nominal grid time
  ``t_k = t_0 + k * STEP_NS`` (absolute deadlines, so errors never accumulate). Positive = late.
- step time ``c_k = t_sent,k - t_start,k``: compute time from the wake-up to the moment the step's
  output frames were handed to the bus.
- latency ``l_k = t_sent,k - t_in,k``: from the receive timestamp of the newest input frame the
  step used to the send of the step's outputs.
- deadline miss: a step that starts more than :data:`DEADLINE_MISS_NS` (1 ms) late, or a grid point
  that was skipped because the loop overran a whole period. Counted since start.

The hot path only writes three integers into preallocated numpy ring buffers
(:meth:`TimingStats.record`); percentiles are computed on demand (:meth:`TimingStats.summary`),
e.g. once per periodic log line, never per step.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

__all__ = [
    "DEADLINE_MISS_NS",
    "ServiceStatus",
    "StepTiming",
    "TimingSummary",
    "TimingStats",
    "diag_signals",
    "diag_values",
    "is_deadline_miss",
]

#: A step that starts more than this late counts as a deadline miss (issue 4, ``Status`` bit7).
DEADLINE_MISS_NS = 1_000_000  # ns

#: LDE_Diag signal ranges (dbc/lde.dbc); values beyond saturate at the boundary.
_PERIOD_ERROR_US = (-8192, 8191)
_STEP_TIME_US = (0, 4095)
_LATENCY_US = (0, 8191)
_E2E_REJECTS_MAX = 31


def is_deadline_miss(period_error_ns: int) -> bool:
    """True when a step started more than :data:`DEADLINE_MISS_NS` after its grid time."""
    return period_error_ns > DEADLINE_MISS_NS


@dataclass(slots=True)
class StepTiming:
    """Timing of one step (ns). ``latency_ns`` is -1 when no input frame has been used yet. Built
    once per live step: not frozen (see :class:`lde.service.service.StepResult`)."""

    period_error_ns: int
    step_time_ns: int
    latency_ns: int
    deadline_miss: bool
    deadline_misses: int  # total since start (includes skipped grid points)


@dataclass(frozen=True)
class TimingSummary:
    """Percentiles of the timing figures over a window of steps, in microseconds.

    ``steps`` is the number of steps in the window; ``deadline_misses`` / ``skipped`` are totals
    since start. Percentiles are NaN for an empty window.
    """

    steps: int
    period_error_p50_us: float
    period_error_p99_us: float
    period_error_max_us: float
    step_time_p50_us: float
    step_time_p99_us: float
    step_time_max_us: float
    latency_p50_us: float
    latency_p99_us: float
    latency_max_us: float
    deadline_misses: int
    skipped: int

    def as_dict(self) -> dict[str, float | int]:
        return asdict(self)

    def log_line(self) -> str:
        """One human-readable line (the periodic log line of the service)."""
        if self.steps == 0:
            return (
                f"timing: no step ran; deadline misses {self.deadline_misses} (skipped steps {self.skipped})"
            )
        if math.isnan(self.latency_p50_us):
            latency = "latency: no input frame used"
        else:
            latency = f"latency p50 {self.latency_p50_us:.0f} us, p99 {self.latency_p99_us:.0f} us"
        return (
            f"timing over {self.steps} steps: period error p50 {self.period_error_p50_us:.0f} us, "
            f"p99 {self.period_error_p99_us:.0f} us, max {self.period_error_max_us:.0f} us; "
            f"step time p50 {self.step_time_p50_us:.0f} us, p99 {self.step_time_p99_us:.0f} us; "
            f"{latency}; deadline misses {self.deadline_misses} (skipped steps {self.skipped})"
        )


#: ``LDE_Overlay.State`` names (dbc/lde.dbc; :class:`lde.estimator.overlay.OverlayState`)
_OVERLAY_STATES = ("off", "ramp-in", "active", "ramp-out", "fault")
#: the learner's state (``learn_state`` in the CSV)
_LEARN_STATES = ("not learned", "learning", "learned", "none")


@dataclass(frozen=True)
class ServiceStatus:
    """What the live service does, for the status line ``lde run`` prints once a second (SI inside,
    degrees for the bank in the line).

    Attributes:
        steps: steps since the previous status; valid: of them with a VALID estimate.
        fw: the last step's disturbance force Fw [N], left positive; mw: its yaw moment Mw [Nm].
        bank: road bank angle [rad] (NaN: the backend does not separate bank from wind).
        overlay_state: the limiter's state (0 off .. 4 fault); t_overlay: the request [Nm].
        learn_state: 0 not learned, 1 learning, 2 learned, 3 the backend does not learn.
        deadline_misses: since start.
        missing: the input messages missing now (none for longer than their timeout).
    """

    steps: int
    valid: int
    fw: float
    mw: float
    bank: float
    overlay_state: int
    t_overlay: float
    learn_state: int
    deadline_misses: int
    missing: tuple[str, ...] = ()

    def line(self) -> str:
        """One line, e.g. ``valid 100 %, Fw 2105 N, Mw -312 Nm, bank -1.2 deg, overlay active
        -2.85 Nm, learner learning, deadline misses 3``, then ``, missing: MDPS_Sensors`` if any."""
        valid = f"valid {100.0 * self.valid / self.steps:.0f} %" if self.steps else "no step"
        bank = f"bank {math.degrees(self.bank):.1f} deg" if math.isfinite(self.bank) else "bank n/a"
        state = (
            _OVERLAY_STATES[self.overlay_state] if 0 <= self.overlay_state < 5 else str(self.overlay_state)
        )
        learn = _LEARN_STATES[self.learn_state] if 0 <= self.learn_state < 4 else str(self.learn_state)
        text = (
            f"{valid}, Fw {self.fw:.0f} N, Mw {self.mw:.0f} Nm, {bank}, overlay {state} "
            f"{self.t_overlay:.2f} Nm, learner {learn}, deadline misses {self.deadline_misses}"
        )
        if self.missing:
            text += f", missing: {', '.join(self.missing)}"
        return text


def _pct(a: np.ndarray, q: float) -> float:
    return float(np.percentile(a, q)) / 1e3 if a.size else float("nan")


def _max(a: np.ndarray) -> float:
    return float(a.max()) / 1e3 if a.size else float("nan")


class TimingStats:
    """Ring buffers of the last ``capacity`` steps' timing plus totals since start.

    Two views: the whole ring (``summary()``; with the default capacity about 4 minutes of steps)
    and a *window* since the last :meth:`take_window` (for the periodic log line).
    """

    def __init__(self, capacity: int = 65536) -> None:
        if capacity <= 0:
            raise ValueError("capacity must be > 0")
        self.capacity = int(capacity)
        #: the ring: period error, step time, latency [ns] (rows), one column per step
        self.rows = np.zeros((3, self.capacity), np.int64)
        self._period, self._step, self._lat = self.rows
        #: steps recorded, deadline misses (late steps + skipped grid points), skipped grid points,
        #: since start (an array: the live step's compiled hand-off, lde.service.handoff, updates it in place)
        self.ctr = np.zeros(3, np.int64)
        self._window_start = 0

    @property
    def count(self) -> int:
        """Steps recorded since start."""
        return int(self.ctr[0])

    @property
    def deadline_misses(self) -> int:
        """Late steps + skipped grid points since start."""
        return int(self.ctr[1])

    @property
    def skipped(self) -> int:
        """Grid points skipped after an overrun, since start."""
        return int(self.ctr[2])

    def record(self, period_error_ns: int, step_time_ns: int, latency_ns: int) -> StepTiming:
        """Store one step's timing (three array stores and a compare)."""
        i = self.count % self.capacity
        self._period[i] = period_error_ns
        self._step[i] = step_time_ns
        self._lat[i] = latency_ns
        miss = is_deadline_miss(period_error_ns)
        self.ctr[0] += 1
        self.ctr[1] += miss
        return StepTiming(period_error_ns, step_time_ns, latency_ns, miss, self.deadline_misses)

    def record_skipped(self, n: int) -> None:
        """``n`` grid points were skipped (the loop overran): each is a deadline miss."""
        self.ctr[2] += n
        self.ctr[1] += n

    def _slice(self, start: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        start = max(start, self.count - self.capacity)
        n = self.count - start
        idx = np.arange(start, self.count) % self.capacity
        if n <= 0:
            idx = idx[:0]
        return self._period[idx], self._step[idx], self._lat[idx]

    def _summarise(self, start: int) -> TimingSummary:
        p, s, lat = self._slice(start)
        lat = lat[lat >= 0]
        return TimingSummary(
            steps=int(p.size),
            period_error_p50_us=_pct(p, 50),
            period_error_p99_us=_pct(p, 99),
            period_error_max_us=_max(p),
            step_time_p50_us=_pct(s, 50),
            step_time_p99_us=_pct(s, 99),
            step_time_max_us=_max(s),
            latency_p50_us=_pct(lat, 50),
            latency_p99_us=_pct(lat, 99),
            latency_max_us=_max(lat),
            deadline_misses=self.deadline_misses,
            skipped=self.skipped,
        )

    def summary(self) -> TimingSummary:
        """Percentiles over the ring (the last ``capacity`` steps)."""
        return self._summarise(0)

    def take_window(self) -> TimingSummary:
        """Percentiles over the steps since the previous call, and start a new window."""
        out = self._summarise(self._window_start)
        self._window_start = self.count
        return out

    def arrays(self) -> dict[str, np.ndarray]:
        """Copies of the ring's contents in step order (ns): ``period_error``, ``step_time``, ``latency``."""
        p, s, lat = self._slice(0)
        return {"period_error": p.copy(), "step_time": s.copy(), "latency": lat.copy()}


def _sat(x: float, lo: int, hi: int) -> int:
    return int(min(max(round(x), lo), hi))


def diag_values(timing: StepTiming, e2e_rejects: int) -> tuple[int, int, int, int, int]:
    """``LDE_Diag`` physical values (``PeriodError``, ``StepTime``, ``Latency`` [us],
    ``DeadlineMisses``, ``E2ERejects``) from one step's timing (the live loop's path: no dict).

    Out-of-range values saturate at the DBC range; ``DeadlineMisses`` wraps modulo 256 and
    ``E2ERejects`` saturates at 31, as documented in ``dbc/lde.dbc``.
    """
    lat_us = timing.latency_ns / 1e3 if timing.latency_ns >= 0 else 0.0
    return (
        _sat(timing.period_error_ns / 1e3, *_PERIOD_ERROR_US),
        _sat(timing.step_time_ns / 1e3, *_STEP_TIME_US),
        _sat(lat_us, *_LATENCY_US),
        timing.deadline_misses % 256,
        min(max(int(e2e_rejects), 0), _E2E_REJECTS_MAX),
    )


def diag_signals(timing: StepTiming, e2e_rejects: int) -> dict[str, int]:
    """``LDE_Diag`` physical values by signal name (:func:`diag_values`)."""
    names = ("PeriodError", "StepTime", "Latency", "DeadlineMisses", "E2ERejects")
    return dict(zip(names, diag_values(timing, e2e_rejects), strict=True))
