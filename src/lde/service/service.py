"""The live service: one step of the data path every 3.9 ms, right after the MDPS frame it consumes.

Two grids (``Service(grid=...)``, ``lde run --grid``; ``docs/service.md``, "The loop"):

* ``mdps`` (``lde run``'s default): the MDPS-locked grid of :mod:`lde.engine.grid`
(:func:`lde.engine.grid.new_lock`).
  The loop blocks on the bus; each MDPS frame that comes 0.5 to 1.5 periods after the previous step's
  reference time triggers a step at its receive time, so the outputs leave one step's compute time after
  the input; when none comes by 1.5 periods, a step runs then and the phase is kept. The step
  times are a function of the MDPS frames' receive times alone (:func:`lde.engine.grid.locked_step_times`).
* ``fixed``: absolute deadlines ``t_k = t_0 + k * 3.9 ms`` on the service clock (sleep, then spin).

One step (:meth:`Service.step_once`) at step time ``t_k``:

1. drain the bus; every frame is stamped with its receive time (the bus's timestamp, microsecond
   rounded exactly like the log readers do: :func:`lde.can.frames.seconds_to_ns`); a frame whose
   timestamp is at or before the previous step's time (the sender's kernel stamped it, but it
   reached the socket only after that step's drain: seen in user-mode Linux with a real-time
   sender) is re-stamped to the first microsecond after the previous step and counted
   (``Service.late_rx``), so that the recording says when it could be used;
2. run the data path (:class:`lde.engine.engine.Engine`, explicit step times) with the pending frames in
   time order: exactly those with receive time ``<= t_k`` are fed, then the step at ``t_k`` runs
   (inputs, corrections, backend step, finalisation, overlay limiter, output frames), a late start
   adding DEADLINE_MISS to its status; later frames stay pending for the next step;
3. send the engine's ``LDE_Estimate``, ``LDE_Overlay`` and ``LDE_Disturbance`` frames, then
   ``LDE_Diag`` with this step's timing;
4. hand the received and sent frames, the step's row and its timing to the recorder (preallocated
   rings in shared memory: the writing happens in the recorder's process);
5. with ``learned`` (``lde run --learned FILE``): every ``learned_period_s`` of step time hand a
   copy of the learned state to a writer thread (:class:`lde.estimator.learned.LearnedKeeper`);
   :meth:`Service.close` writes it once more.

The hot path allocates little: received frames go straight into preallocated pending arrays (the
engine reads slices of them), the output ``can.Message`` objects are built once and refilled in place
(``LDE_Diag`` too, by the compiled encoder), the kernel passes only the input messages
(:func:`set_input_filters`: SocketCAN filters, a socket filter on python-can's ``udp_multicast``), and
the garbage collector is off during :meth:`Service.run` (young objects are collected in the idle time
after a step's send, old ones were frozen at start).

Determinism: the step uses nothing but (the frames with receive time ``<= t_k``, ``t_k``, the
overlay enable input, the deadline-miss bit), all of which the recording keeps, so a replay of the
recording (:func:`lde.replay.replay.replay_log`) runs the same engine on the same inputs and gives the same
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
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import can
import numpy as np

from lde.can.busio import ERROR_FRAME, RxFrame, TxFrame, bus_io, describe_bus, open_bus, receive_only
from lde.can.codec import MessageCodec
from lde.can.frames import FrameBatch, data_width, seconds_to_ns
from lde.can.profiles import Profile, load_profile
from lde.can.watch import InputWatch, describe_ids
from lde.clock import SimulatedClock
from lde.engine.engine import Engine, StepBlock
from lde.engine.grid import L_REF, lock_anchor, lock_deadline, lock_frame, lock_timeout, new_lock
from lde.engine.receiver import Receiver
from lde.errors import ConfigError
from lde.estimator.learned import LearnedKeeper, LearnedSnapshot
from lde.estimator.outputs import O_BANK, O_LEARN
from lde.io.recording import StepRing
from lde.params import Vehicle, load_vehicle
from lde.service.busfaults import FLOOD_FOREIGN_HZ, BusFaults, E2EWindow, WindowCounts
from lde.service.diagnostics import DEADLINE_MISS_NS, ServiceStatus, StepTiming, TimingStats, TimingSummary
from lde.service.handoff import (
    I_DIAG_CTR,
    I_DIAG_SLOT,
    I_F_HEAD,
    I_N_RX,
    I_N_SENT,
    I_NEWEST,
    I_S_HEAD,
    I_T_K,
    I_T_SENT,
    I_T_START,
    N_INTS,
    RING_LAY,
    after_send,
)
from lde.status import DEADLINE_MISS, VALID
from lde.units import STEP_NS, STEP_S

__all__ = ["Service", "StepResult", "STATUS_DEADLINE_MISS", "GRIDS", "open_bus", "set_input_filters"]

log = logging.getLogger(__name__)

#: ``LDE_Estimate.Status`` bit7: this step ran more than 1 ms late (docs/ARCHITECTURE.md).
STATUS_DEADLINE_MISS = DEADLINE_MISS

#: a step may be at most this late before grid points are skipped (one whole period)
_SKIP_AFTER_NS = STEP_NS
#: bus timestamps further than this from the service clock are not in its time base [ns]
_RESTAMP_AFTER_NS = 1_000_000_000
#: after a stop request, the overlay ramps out for at most this long before the service ends
_MAX_RAMP_OUT_NS = 3_000_000_000
#: the live grids: MDPS-locked (steps triggered by the MDPS frames) or fixed deadlines on the clock
GRIDS = ("mdps", "fixed")
#: pending-frame buffer: initial capacity (grows if ever needed, which means the loop stood still)
_PENDING_CAP = 4096
#: a young generation this large is collected in the idle time after a step (gc is off in the loop)
_GC_YOUNG = 700
#: frames queued before the first step and older than this are left out [ns] (Service._leave_out_backlog)
_BACKLOG_NS = 100_000_000
#: received frames per step handed to the compiled hand-off for the recorder (more: from Python)
_RX_CAP = 256
#: a data word's 64 bits (a CAN FD frame's word is longer)
_WORD = (1 << 64) - 1


_WATCH_PERIOD_NS = 250_000_000  # how often the input watch looks (its warnings repeat every 30 s)
_PROBE_NS = 1_000_000_000  # SocketCAN filters lifted this long to name the ids on the bus
#: E2E rejection kinds, as the bus check names them (the wrong sequence of a counter that jumped)
_E2E_KINDS = ("wrong sequence (counter jumped)", "wrong CRC", "repeated counter", "malformed")


@dataclass(slots=True)
class StepResult:
    """What one step produced (SI; ``t_ns`` in the bus/log time base). Built once per live step, so
    not frozen: a frozen dataclass's ``__init__`` (``object.__setattr__`` per field) costs 3-4 times
    as much.

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
        backend: a registered backend name (:mod:`lde.engine.backends`): ``fixed`` (default) or ``float``.
        recorder: optional :class:`lde.io.recording.Recorder` (already started); may be set after
            construction (before the first step), e.g. with :attr:`learned_start` in its metadata.
        overlay_enabled: False keeps the overlay request at zero (the demo's "without overlay" run).
        timebase_offset_ns: bus time minus clock time [ns]; None: measured at start (0 for a
            simulated clock).
        log_period_s: period of the timing summary log line [s]; 0 disables it.
        grid: ``fixed`` (default: deadlines on the clock) or ``mdps`` (steps triggered by the MDPS
            frames, :mod:`lde.engine.grid`'s locked grid) for :meth:`run`.
        input_filters: pass only the profile's input messages up from the bus
            (:func:`set_input_filters`).
        bus_name: what the log lines call the bus (:func:`lde.can.busio.bus_label`:
        ``udp_multicast:239.74.1.2
            port 47311``, ``socketcan:vcan0``); None: python-can's ``channel_info``.
        learned: a learned-state file (``--learned``): read now when it exists (checked against the
            vehicle and profile), written every ``learned_period_s`` of step time and at
            :meth:`close`. Needs a backend that learns (ConfigError otherwise).
        learned_period_s: period of the learned-state writes [s] (SPEC: 60 s).
        flood_hz: frames of other messages on the bus above this rate [1/s] are logged as a flood
            (:mod:`lde.service.busfaults`).
        prewarm: on the MDPS grid with a clock that spins before the expected frame
            (``spin_ns`` > 0), make the engine's call once with no frame when the spin starts, so the
            step's call finds warm caches (:meth:`_prewarm`); False: not.
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
        grid: str = "fixed",
        input_filters: bool = True,
        bus_name: str | None = None,
        learned: str | Path | None = None,
        learned_period_s: float = 60.0,
        flood_hz: float = FLOOD_FOREIGN_HZ,
        prewarm: bool = True,
    ) -> None:
        if grid not in GRIDS:
            raise ConfigError(f"unknown grid {grid!r}: {' or '.join(GRIDS)}")
        self.bus = bus
        self.grid = grid
        self.profile = load_profile(profile) if isinstance(profile, str) else profile
        self.vehicle = vehicle if isinstance(vehicle, Vehicle) else load_vehicle(vehicle)
        self.clock = clock
        self.backend = backend
        self.overlay_enabled = overlay_enabled
        self.prewarm = prewarm
        if timebase_offset_ns is None:
            simulated = isinstance(clock, SimulatedClock)
            timebase_offset_ns = 0 if simulated else time.time_ns() - clock.now_ns()
        self.offset_ns = int(timebase_offset_ns)
        self.log_period_ns = int(log_period_s * 1e9)

        self.engine = Engine(self.profile, self.vehicle, backend, explicit=True)
        n_out = len(self.engine.outputs.names)
        self._block, self._block_mem = StepBlock.packed(1, n_out)
        self._tk = np.zeros(1, np.int64)
        self._enable = np.ones(1, np.bool_)
        self._extra = np.zeros(1, np.uint8)
        # per-step scalars go through memoryviews of these arrays (half a numpy item store each)
        self._tk_mv, self._enable_mv, self._extra_mv = self._tk.data, self._enable.data, self._extra.data
        self.io = bus_io(bus)
        # the output frames, built once and refilled in place (numpy views of their data bytes)
        self._tx = [
            self.io.tx(
                can.Message(arbitration_id=int(fid), is_extended_id=False, dlc=int(n), data=bytes(int(n)))
            )
            for fid, n in zip(self.engine.outputs.frame_id, self.engine.outputs.length, strict=True)
        ]
        self._out_views = [tx.view for tx in self._tx]
        # the encoded output frames' bytes (the StepBlock's) into each prebuilt frame: slice copies
        # between memoryviews, (destination, its slice, source slice) per output
        frames_mv = self._block.frames.data.cast("B")
        self._out_copy = [
            (tx.data, slice(tx.data_at, tx.data_at + tx.dlc), frames_mv[8 * j : 8 * j + tx.dlc])
            for j, tx in enumerate(self._tx)
        ]
        # the step's values for StepResult, read through memoryviews (a numpy item read and its float()
        # cost about three times as much)
        b = self._block
        self._est_mv = b.est.data.cast("B").cast("d")
        self._row_mvs = tuple(a.data for a in (b.status, b.overlay_state, b.frames_used, b.t_overlay))
        dc = MessageCodec(self.profile, "LDE_Diag")
        self._diag_tx = self.io.tx(
            can.Message(
                arbitration_id=dc.frame_id, is_extended_id=False, dlc=dc.length, data=bytes(dc.length)
            )
        )
        self._diag_view = self._diag_tx.view
        # the step's work after its sends, one compiled call (lde.service.handoff): timing, LDE_Diag, recorder
        lay = dc.layout
        slots = [dc.index[n] for n in ("PeriodError", "StepTime", "Latency", "DeadlineMisses", "E2ERejects")]
        rejects_at = self._block.e2e_rejects.ctypes.data - self._block_mem.ctypes.data
        self._ints = np.zeros(N_INTS, np.int64)
        self._ints_mv = self._ints.data
        self._tx_t = np.full(n_out + 1, -1, np.int64)
        self._ints[I_N_SENT] = n_out
        self.stats = TimingStats()
        self._handoff_args = [
            self._ints,
            self.stats.rows,
            self.stats.ctr,
            np.zeros(len(dc.order), np.float64),
            np.stack([lay.pos, lay.nbits, lay.little_endian, lay.signed, lay.is_value]).astype(np.int64),
            np.stack([lay.scale, lay.offset, lay.lo, lay.hi]).astype(np.float64),
            np.ascontiguousarray(dc.scheme.counter_parts),
            np.ascontiguousarray(dc.scheme.checksum_parts),
            np.array(
                [lay.length, dc.scheme.kind_code, lay.frame_id, dc.scheme.modulus, dc.scheme.invalid_counter]
                + slots
                + [rejects_at],
                np.int64,
            ),
            self._diag_view,
            self._block.frames,
            np.array([(tx.can_id, tx.dlc) for tx in (*self._tx, self._diag_tx)], np.int64),
            self._tx_t,
            self._block_mem,
            np.zeros(0, np.uint8),  # the recorder's rings (recorder setter)
            np.zeros((0, 3), np.int64),
            np.zeros(len(RING_LAY), np.int64),
            np.zeros((_RX_CAP, 3), np.int64),  # the received frames to record: time, id, dlc
            np.zeros(_RX_CAP, np.uint64),  # and their data words
        ]
        self._rx_mv = self._handoff_args[17].data.cast("B").cast("q")
        self._rxw_mv = self._handoff_args[18].data
        self._ring: StepRing | None = None
        self._recorder: Any = None
        after_send(*self._handoff_args)  # loads (or compiles) it now; no recorder yet: stores nothing
        self._after_send = after_send
        self._ints[I_DIAG_CTR] = 0  # the call above advanced it
        self.stats.ctr[:] = 0
        self.stats.rows[:] = 0
        self.recorder = recorder
        # the frames received and not fed yet, in preallocated columns (the engine reads slices); the
        # data column is as wide as the profile's longest input message (8 bytes but for CAN FD)
        self.rx_width = data_width(max(m.length for m in self.profile.messages.values()))
        self._np = 0
        self._pcols: tuple[np.ndarray, ...] = ()
        self._alloc_pending(_PENDING_CAP)
        self._unsorted = False
        self._anchor_id = self.profile.messages[self.profile.anchor_message].frame_id  # 11-bit
        #: input frames taken and not yet handed to the input watch and the recorder (_settle_rx)
        self._backlog: list[tuple[int, int, int, int]] = []
        self._lock: np.ndarray | None = None  # the MDPS-locked grid while run(grid="mdps") runs
        self._due: deque[int] = deque()  # step times the locked grid has made due, not run yet
        self._input_ids = frozenset(m.frame_id for m in self.profile.messages.values())
        self.filters = set_input_filters(bus, self.profile) if input_filters else "none"
        self.foreign = 0  # frames of other messages that reached the service (dropped)
        #: the bus's name in the log lines
        self.bus_name = where = bus_name if bus_name is not None else describe_bus(bus)
        #: loud when blind: a required input that does not arrive is logged (lde.can.watch)
        self.watch = InputWatch(self.profile, where)
        self._watch_next = 0  # bus time of the next check [ns]
        self._probe_until: int | None = None  # SocketCAN filters lifted to see what arrives, until
        #: live bus faults said once (lde.service.busfaults): failed sends/receives, error frames, E2E, floods
        self.faults = BusFaults(where, flood_hz=flood_hz)
        self._bus_counter = _open_bus_counter(bus)  # SocketCAN: the interface's rx_packets, or None
        self._window: tuple[int, ...] | None = None  # the counts at the previous bus check
        self._e2e_prev: dict[str, tuple[int, ...]] = {}  # message -> E2E counts at that check
        self._warm_up()
        self._run_engine_empty()  # the loop for the live argument types loaded now, not at step 1
        self._newest_input_ns = -1  # receive time of the newest frame fed so far
        self._restamp: bool | None = None  # stamp frames on receipt (decided at the first frame)
        self._last_t_k: int | None = None  # the latest step time run [ns, bus time base]
        self._last_due: int | None = None  # the latest step time the locked grid made due [ns]
        self.late_rx = 0  # frames delivered after a step later than their timestamp: re-stamped
        self._stopping = False  # ramp-out requested (shutdown)
        self.steps = 0
        self.send_errors = 0  # frames the bus refused (full tx queue, bus-off), counted, not raised
        self.recv_errors = 0  # failed receive calls, counted, not raised
        self.sent = 0  # frames the bus took
        self.received = 0  # frames received (any id, error frames included)
        self.error_frames = 0  # error frames received (counted; inputs stay in use while E2E passes)
        self._error_id = 0  # the last error frame's id (its classes)
        self._send_error = ""  # the last failed send's text
        self._recv_error = ""  # the last failed receive's text
        self.gc_collections = 0  # young-generation collections run in the idle time of run()
        self.prewarms = 0  # the engine's empty calls before an expected MDPS frame (_prewarm)
        self._warmed_for: int | None = None  # the expected MDPS time [ns, clock] of the last one
        self.last: StepResult | None = None
        self.valid_steps = 0  # steps with status VALID: the driving time the learner saw
        self._status_from = (0, 0)  # (steps, valid_steps) at the previous status()
        self.stale_at_start = 0  # frames queued before run()'s first step, left out (older than it)
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

    @property
    def recorder(self) -> Any:
        """The recorder (:class:`lde.io.recording.Recorder`, or any object with its ``frame`` and
        ``step`` methods), or None. A Recorder's rings are written by the step's compiled hand-off
        (:mod:`lde.service.handoff`); any other recorder is called per frame and per step."""
        return self._recorder

    @recorder.setter
    def recorder(self, rec: Any) -> None:
        self._recorder = rec
        ring = getattr(rec, "ring", None)
        a = self._handoff_args
        if isinstance(ring, StepRing) and ring.n_outputs == self._block.frames.shape[1]:
            self._ring = ring
            b, mem = self._block, self._block_mem
            tab = []
            for f in fields(StepBlock):
                col = getattr(b, f.name)
                tab.append((col.ctypes.data - mem.ctypes.data, ring.offsets[f.name], col.nbytes))
            a[14] = ring.memory()
            a[15] = np.array(tab, np.int64)
            a[16] = np.array([ring.offsets[k] for k in RING_LAY[:-2]] + [ring.nf, ring.ns], np.int64)
        else:
            self._ring = None
            a[14] = np.zeros(0, np.uint8)

    def _alloc_pending(self, cap: int) -> None:
        """(Re)allocate the pending columns with room for ``cap`` frames, keeping their contents."""
        n = self._np
        w = self.rx_width
        new: tuple[np.ndarray, ...] = (
            np.zeros(cap, np.int64),  # receive time [ns]
            np.zeros(cap, np.uint32),  # id
            np.zeros(cap, np.bool_),  # extended
            np.zeros(cap, np.uint8),  # dlc
            np.zeros((cap, w), np.uint8),  # data bytes
        )
        if n:
            for dst, src in zip(new, self._pcols, strict=True):
                dst[:n] = src[:n]
        self._pcols = new
        self._pt, self._pid, self._pext, self._pdlc, self._pdata = new
        # _take stores through memoryviews of the columns (half a numpy item store each): classic
        # frames' 8 bytes as one little-endian word, wider rows as bytes
        words = self._pdata.view(np.uint64).reshape(cap) if w == 8 else self._pdata.reshape(cap * w)
        self._pmv = (*(a.data for a in new[:4]), words.data)
        self._prx = np.ones(cap, np.bool_)
        #: n -> the engine's live arguments with the columns' first n rows (views)
        self._heads: dict[int, tuple] = {}

    def pending_times(self) -> list[int]:
        """Receive times of the frames received and not fed to a step yet [ns] (time order)."""
        self._sort_pending()
        return self._pt[: self._np].tolist()

    def _warm_up(self) -> None:
        """Run the compiled loop once on a throwaway engine, so the first real step is not late
        (numba loads or compiles a kernel at its first call)."""
        e = Engine(self.profile, self.vehicle, self.backend, explicit=True)
        e.feed(FrameBatch.empty(), step_times=np.arange(3, dtype=np.int64) * STEP_NS, final=True)
        # the locked grid's kernels too (loading them at the first MDPS frame made that step late)
        lock = new_lock(0)
        lock_deadline(lock)
        lock_timeout(lock, 2 * STEP_NS)
        lock_anchor(lock, 3 * STEP_NS)
        lock_frame(new_lock(0), 0)
        self._lock_frame = lock_frame

    @property
    def receiver(self) -> Receiver:
        """The engine's receiver state as a :class:`lde.engine.receiver.Receiver` (a view, not a copy)."""
        return Receiver.bound(self.profile, self.engine.rx_tables, self.engine.rx)

    # ------------------------------------------------------------------ one step
    def now_ns(self) -> int:
        """Now, in the bus/log time base [ns]."""
        return self.clock.now_ns() + self.offset_ns

    def _drain(self) -> None:
        """Move every frame waiting in the bus into the pending buffer (and the recording)."""
        recv = self.io.recv
        while True:
            try:
                f = recv(0.0)
            except (can.CanError, OSError) as exc:  # interface down, driver error: count, keep stepping
                self._recv_failed(exc)
                return
            if f is None:
                return
            self._take(f)

    def _recv_failed(self, exc: Exception) -> None:
        # said in the log once per fault by the bus check (lde.service.busfaults), not per call
        self.recv_errors += 1
        self._recv_error = str(exc)

    def _take(self, f: RxFrame) -> None:
        """One received frame (:mod:`lde.can.busio`'s five numbers) into the pending columns and, when it
        is the MDPS frame, the locked grid; frames of other messages are dropped (counted in
        ``foreign``), error frames counted (``error_frames``, the last one's class kept for the bus
        check). This runs between the MDPS frame and its step, so it does only what the step needs:
        the input watch and the recorder get the frame after the step's outputs are sent
        (:meth:`_settle_rx`)."""
        t_rx, can_id, ext, dlc, word = f
        self.received += 1
        if ext or can_id not in self._input_ids:
            self._take_other(can_id, word)
            return
        if self._restamp is not False:  # None: the first frame decides; True: stamped on receipt
            if self._restamp is None:
                self._decide_restamp(t_rx)
            if self._restamp:
                t_rx = seconds_to_ns(self.now_ns() / 1e9)
        anchor = can_id == self._anchor_id
        last = self._last_t_k
        if anchor and self._last_due is not None and (last is None or self._last_due > last):
            last = self._last_due
        if last is not None and t_rx <= last:
            # stamped (by the sender's kernel) before a step that has already run without it: it
            # reached our socket only after that step's drain. It takes part from the next step on,
            # so it is recorded with the first microsecond after that step (a replay then feeds it
            # where the live loop did). An MDPS frame is also late for a step the locked grid has
            # already made due without it (the grid's rule would have stepped at it instead).
            t_rx = (last // 1000 + 1) * 1000
            self.late_rx += 1
        n = self._np
        if n == self._pt.shape[0]:
            self._alloc_pending(2 * n)
        pt, pid, pext, pdlc, pdata = self._pmv
        if n and t_rx < pt[n - 1]:
            self._unsorted = True
        pt[n] = t_rx
        pid[n] = can_id
        pext[n] = False
        pdlc[n] = dlc
        w = self.rx_width
        if w == 8:
            pdata[n] = word & _WORD
        else:  # CAN FD: the frame's bytes (a longer frame is malformed for every input message)
            pdata[n * w : n * w + w] = (word & ((1 << (8 * w)) - 1)).to_bytes(w, "little")
        self._np = n + 1
        self._backlog.append((t_rx, can_id, dlc, word))
        if anchor and self._lock is not None:
            self._on_anchor(t_rx)

    def _take_other(self, can_id: int, word: int) -> None:
        """A frame that is not one of the profile's inputs: an error frame, a remote frame, another
        message (dropped, counted; its id kept for the blind warning's list)."""
        if can_id < 0:
            if can_id == ERROR_FRAME:
                self.error_frames += 1
                self._error_id = word
            return
        self.foreign += 1
        self.watch.saw(can_id, 0)

    def _settle_rx(self, handoff: bool = True) -> None:
        """The input frames taken since the last call into the input watch and the recorder (after a
        step's sends: off the path from the MDPS frame to the step). The recorder gets them in the
        order they were taken, before the step's sent frames, as when they were handed over in
        :meth:`_take`. ``handoff``: the compiled hand-off follows and writes them into a
        :class:`lde.io.recording.Recorder`'s ring; else they are handed over from here."""
        bl = self._backlog
        if not bl:
            return
        saw = self.watch.saw
        rec = self._recorder
        # recorded by the compiled hand-off (classic frames: one word each)
        if handoff and self._ring is not None and len(bl) <= _RX_CAP and self.rx_width == 8:
            rx, rxw = self._rx_mv, self._rxw_mv
            for k, (t_rx, can_id, dlc, word) in enumerate(bl):
                saw(can_id, t_rx)
                rx[3 * k] = t_rx
                rx[3 * k + 1] = can_id
                rx[3 * k + 2] = dlc
                rxw[k] = word & _WORD
            self._ints_mv[I_N_RX] = len(bl)
        else:
            for t_rx, can_id, dlc, word in bl:
                saw(can_id, t_rx)
                if rec is not None:
                    rec.frame(t_rx, can_id, False, dlc, word, True)
        bl.clear()

    def _on_anchor(self, t_rx: int) -> None:
        """An MDPS frame for the locked grid: the timeout steps before it, then maybe its own step
        (one compiled call when no timeout step is due: :func:`lde.engine.grid.lock_frame`)."""
        lock = self._lock
        assert lock is not None
        r = self._lock_frame(lock, t_rx)
        if r < 0:
            while (tk := int(lock_timeout(lock, t_rx))) >= 0:
                self._make_due(tk)
            r = lock_anchor(lock, t_rx)
        if r:
            self._make_due(t_rx)

    def _make_due(self, t_k: int) -> None:
        self._due.append(t_k)
        if self._last_due is None or t_k > self._last_due:
            self._last_due = t_k

    def _sort_pending(self) -> None:
        if not self._unsorted:
            return
        n = self._np
        order = np.argsort(self._pt[:n], kind="stable")  # stable: arrival order among equal times
        for a in self._pcols:
            a[:n] = a[:n][order]
        self._unsorted = False

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
        self._sort_pending()
        n = self._np
        self._tk_mv[0] = t_k
        self._enable_mv[0] = enable
        self._extra_mv[0] = DEADLINE_MISS if miss else 0
        eng = self.engine
        args = self._heads.get(n)
        # the arguments are made once per count of pending frames (a step sees 0 to a few)
        if args is None or not eng.live_args_valid(args):
            cols = (*(a[:n] for a in self._pcols), self._prx[:n])
            args = self._heads[n] = eng.live_args(cols, self._block, self._tk, self._enable, self._extra)
        fed, steps = eng.run_live(args)
        if steps != 1:  # the engine runs every given step when final: a broken invariant
            raise RuntimeError(f"the engine ran {steps} steps for one step time")
        if fed:
            self._newest_input_ns = int(self._pt[fed - 1])
            rest = n - fed
            if rest:
                for a in self._pcols:
                    a[:rest] = a[fed:n].copy()
            self._np = rest
        return fed

    def _prewarm(self) -> None:
        """The engine's live call with no frame and no step time (nothing runs, nothing changes),
        made when the service starts polling for the MDPS frame: it brings the call's code, its
        unboxing and the loop's arrays back into the caches that the idle period cooled, so the
        step after the frame does not pay for them (``docs/service.md``, "The frame-to-step path, the
        step's glue and an engine pre-warm")."""
        args = self._heads.get(-1)
        if args is None or not self.engine.live_args_valid(args):
            cols = (*(a[:0] for a in self._pcols), self._prx[:0])
            args = self._heads[-1] = self.engine.live_args(
                cols, self._block, self._tk[:0], self._enable[:0], self._extra[:0]
            )
        self.engine.run_live(args)
        self.prewarms += 1

    def _run_engine_empty(self) -> None:
        """The live call with no frame and no step time: nothing runs, nothing changes, but the
        compiled loop for the live argument types is loaded (or compiled) now, not at the first step."""
        pt, pid, pext, pdlc, pdata = (a[:0] for a in self._pcols)
        fed, steps = self.engine.run_arrays(
            pt,
            pid,
            pext,
            pdlc,
            pdata,
            self._prx[:0],
            self._block,
            step_times=self._tk[:0],
            enable=self._enable[:0],
            extra_status=self._extra[:0],
            final=True,
        )
        if fed or steps:
            raise RuntimeError(f"the engine ran {steps} steps on no step time")

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
        if self._last_t_k is None or t_k > self._last_t_k:
            self._last_t_k = t_k
        b = self._block
        tx_t = self._tx_t
        send = self._send
        for j, (dst, at, src) in enumerate(self._out_copy):
            dst[at] = src
            tx_t[j] = send(self._tx[j])
        t_sent = self.now_ns()
        diag = self._diag_tx
        t_diag = t_sent / 1e9  # LDE_Diag is stamped with the time its step time ends
        ints = self._ints_mv
        ints[I_T_K] = t_k
        ints[I_T_START] = t_start
        ints[I_T_SENT] = t_sent
        newest = self._newest_input_ns
        ints[I_NEWEST] = newest
        tx_t[-1] = seconds_to_ns(t_diag)
        self._settle_rx()
        self._after_send(*self._handoff_args)
        ring = self._ring
        diag_sent = send(diag, t_diag, ring is None) >= 0
        if ring is not None:
            ring.published(ints[I_F_HEAD] + (diag_sent and ints[I_DIAG_SLOT] != 0), ints[I_S_HEAD])

        step_time = t_sent - t_start
        latency = t_sent - newest if newest >= 0 else -1
        misses = self.stats.deadline_misses
        timing = StepTiming(period_error, step_time, latency, miss, misses)
        self.steps += 1
        m_status, m_state, m_used, m_overlay = self._row_mvs
        status = m_status[0]
        state = m_state[0]
        if status & VALID:
            self.valid_steps += 1
        if self.learned is not None and self.learned.due(t_k):
            self.learned.offer(self.learned_snapshot())
        est = self._est_mv
        res = StepResult(
            t_ns=t_k,
            fw=est[0],
            mw=est[1],
            t_align=est[2],
            t_overlay=m_overlay[0],
            overlay_state=state,
            overlay_active=state in (1, 2),
            status=status,
            frames_used=m_used[0],
            timing=timing,
            overlay_enable=enable,
        )
        self.last = res
        rec = self._recorder
        if rec is not None and ring is None:  # a recorder without rings: called
            row = (period_error, step_time, latency, int(miss), misses, self.stats.skipped)
            rec.step(b, 0, row)
        return res

    def _send(self, tx: TxFrame, t_s: float | None = None, record: bool = True) -> int:
        """Send ``tx`` stamped ``t_s`` [s] (None: now); returns its stamp [ns, microsecond-rounded as
        recorded] or -1 when the bus did not take it. ``record``: hand it to a recorder without rings
        (a recorder's rings get the sent frames from the compiled hand-off)."""
        if t_s is None:
            t_s = self.now_ns() / 1e9
        try:
            self.io.send(tx, t_s)
        except (can.CanError, OSError) as exc:
            # a full tx queue, a bus-off or the interface down must not kill the loop: count and go
            # on (said in the log once per fault by the bus check, lde.service.busfaults)
            self.send_errors += 1
            self._send_error = str(exc)
            return -1
        self.sent += 1
        t_ns = seconds_to_ns(t_s)
        rec = self._recorder
        if record and rec is not None and self._ring is None:
            rec.frame(t_ns, tx.can_id, tx.is_extended, tx.dlc, tx.word(), False)
        return t_ns

    # ------------------------------------------------------------------ what it does
    @property
    def inputs_received(self) -> int:
        """Frames of the profile's input messages received so far (any E2E result)."""
        return sum(st.received + st.malformed for st in self.engine.stats().values())

    def status(self) -> ServiceStatus:
        """What the service does now (the last step's estimate, overlay and learner; the share of
        valid steps since the previous call; the inputs missing now): ``lde run``'s status line."""
        steps, valid = self.steps - self._status_from[0], self.valid_steps - self._status_from[1]
        self._status_from = (self.steps, self.valid_steps)
        res, est = self.last, self._est_mv
        return ServiceStatus(
            steps=steps,
            valid=valid,
            fw=res.fw if res else 0.0,
            mw=res.mw if res else 0.0,
            bank=est[O_BANK],
            overlay_state=res.overlay_state if res else 0,
            t_overlay=res.t_overlay if res else 0.0,
            learn_state=int(est[O_LEARN]),
            deadline_misses=self.stats.deadline_misses,
            missing=tuple(self.watch.late(res.t_ns)) if res else (),
        )

    # ------------------------------------------------------------------ learned state
    def learned_snapshot(self) -> LearnedSnapshot:
        """A copy of what was learned so far (driving time: this run's valid steps)."""
        return self.engine.learned_snapshot(self.valid_steps * STEP_S)

    def close(self) -> None:
        """Write the learned state a last time (with ``learned``; ConfigError when that fails).
        The bus and the recorder belong to the caller."""
        if self._bus_counter is not None:
            os.close(self._bus_counter)
            self._bus_counter = None
        self.io.close()
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
        """Step until stopped, on the service's grid (``fixed``: deadlines ``t_k = t_0 + k * STEP_NS``
        on the clock; ``mdps``: the MDPS-locked grid, its first window around ``t_0``).

        Stops after ``max_steps`` steps, or after ``stop_event`` is set (or :meth:`request_stop`
        called) and the overlay has ramped to zero (at most 3 s). A step that would start more
        than one whole period late is skipped (counted as a deadline miss) when a later one is due
        too, instead of running a burst of stale steps.

        ``t0_ns`` (clock time base) is the first deadline; default one period from now.

        Returns the timing summary over the run (the last 65536 steps).
        """
        clock = self.clock
        # everything allocated so far (modules, tables, DBC objects) leaves the collector's view, and
        # the collector is off while the loop runs: the young objects a step leaves are collected in
        # the idle time after its send (:meth:`_idle`), never inside a step
        gc.collect()
        gc.freeze()
        was_enabled = gc.isenabled()
        gc.disable()
        t0 = clock.now_ns() + STEP_NS if t0_ns is None else int(t0_ns)
        if self.grid == "mdps":
            self._lock = new_lock(t0 + self.offset_ns)
            self._due.clear()
            next_step = self._next_locked
        else:
            self._k = 0
            self._t0 = t0
            next_step = self._next_fixed
        if self.steps == 0:
            self._leave_out_backlog(t0 + self.offset_ns)
        next_log = t0 + self.log_period_ns
        stop_at: int | None = None
        try:
            while True:
                t_k, now = next_step()
                res = self.step_once(t_k, now)
                if on_step is not None:
                    on_step(res)
                self.check_inputs(t_k)
                if self.log_period_ns > 0 and now - self.offset_ns >= next_log:
                    log.info("%s", self.stats.take_window().log_line())
                    late = now - self.offset_ns - next_log
                    next_log += self.log_period_ns * max(1, late // self.log_period_ns + 1)
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
                self._idle()
        finally:
            self._settle_rx(handoff=False)
            self._lock = None
            if was_enabled:
                gc.enable()
        return self.stats.summary()

    def _leave_out_backlog(self, t_first: int) -> None:
        """Before the first step of :meth:`run` (at ``t_first``, bus time base [ns]): the frames
        that queued on the bus while the service was starting (a simulator or a car already
        sending) and are more than :data:`_BACKLOG_NS` older than that step are read and left out
        (counted, logged). Fed to the first step they would all be stale, and the first of them
        would make the bus's timestamps look seconds off the service clock. Younger frames are
        taken as usual."""
        n = 0
        while True:
            try:
                f = self.io.recv(0.0)
            except (can.CanError, OSError) as exc:
                self._recv_failed(exc)
                break
            if f is None:
                break
            if f[1] >= 0 and f[0] < t_first - _BACKLOG_NS:
                n += 1
            else:
                self._take(f)
        if n:
            self.stale_at_start += n
            log.info(
                "left out %d frames that queued on %s while the service was starting (older than %.1f s)",
                n,
                self.bus_name,
                _BACKLOG_NS / 1e9,
            )

    def check_inputs(self, t_ns: int) -> None:
        """Loud when blind (:mod:`lde.can.watch`), at most every 0.25 s of bus time ``t_ns`` [ns]: log a
        missing input message with what arrived instead. Where the kernel filters the inputs
        (SocketCAN), the first warning lifts the filters for 1 s so that the ids on the bus can be
        named, then puts them back."""
        if self._probe_until is not None and t_ns >= self._probe_until:
            self._probe_until = None
            self.filters = set_input_filters(self.bus, self.profile)
            log.warning(
                "ids on %s while the input filters were lifted for 1 s: %s",
                self.watch.where,
                describe_ids(self.watch.ids, self.profile),
            )
        if t_ns < self._watch_next:
            return
        self._watch_next = t_ns + _WATCH_PERIOD_NS
        self.check_bus(t_ns)
        for level, text in self.watch.check(t_ns):
            (log.warning if level == "warning" else log.info)("%s", text)
            first = level == "warning" and self.watch.warnings == 1
            if first and self.filters.startswith("kernel (SocketCAN"):
                try:
                    self.bus.set_filters(None)
                    self._probe_until = t_ns + _PROBE_NS
                except (can.CanError, OSError) as exc:
                    log.info("could not lift the input filters to look at the bus: %s", exc)

    def check_bus(self, t_ns: int) -> None:
        """Hand the counts since the previous check to the fault trackers (:mod:`lde.service.busfaults`) and
        log what they say: a line when a fault starts, a reminder every 30 s, a line when it clears."""
        bus_frames = _read_counter(self._bus_counter)
        cur: tuple[int, ...] = (t_ns, self.send_errors, self.sent, self.recv_errors, self.received)
        cur += (self.error_frames, self.foreign, bus_frames)
        e2e = []
        n_input = self._np
        span_ns = t_ns - self._window[0] if self._window is not None else 0
        for name, st in self.engine.stats().items():
            n_input += st.received
            n_id = st.received + st.malformed
            now = (st.wrong_sequence, st.wrong_crc, st.repeated, st.malformed, st.used, n_id)
            was = self._e2e_prev.get(name, (0, 0, 0, 0, 0, 0))
            self._e2e_prev[name] = now
            dd = [a - b for a, b in zip(now, was, strict=True)]
            what = ", ".join(f"{k} {v}" for k, v in zip(_E2E_KINDS, dd[:4], strict=True) if v)
            spec = self.profile.messages[name]
            label = f"{name} (0x{spec.frame_id:X})"
            e2e.append(E2EWindow(label, sum(dd[:4]), dd[4], what, dd[5], span_ns / spec.period_ns))
        cur += (n_input,)
        prev, self._window = self._window, cur
        if prev is None:
            return
        d = [a - b for a, b in zip(cur, prev, strict=True)]
        w = WindowCounts(
            t_ns=t_ns,
            span_ns=d[0],
            send_errors=d[1],
            sent=d[2],
            recv_errors=d[3],
            received=d[4],
            error_frames=d[5],
            error_id=self._error_id,
            foreign=d[6],
            bus_frames=d[7] if bus_frames >= 0 and prev[7] >= 0 else -1,
            own_frames=d[8] + d[2],
            e2e=tuple(e2e),
            send_error=self._send_error,
            recv_error=self._recv_error,
        )
        for level, text in self.faults.check(w):
            (log.warning if level == "warning" else log.info)("%s", text)

    def fault_summary(self) -> str:
        """The bus fault counts over the run, for the last log line."""
        eps = ", ".join(f"{t.name} {t.episodes}x" for t in self.faults.trackers() if t.episodes) or "none"
        return (
            f"bus faults: send errors {self.send_errors}, receive errors {self.recv_errors}, error frames"
            f" {self.error_frames}, foreign frames that reached the service {self.foreign}; episodes: {eps}"
        )

    def _idle(self) -> None:
        """After a step's send: a young-generation collection when due (gc is off in the loop)."""
        if gc.get_count()[0] >= _GC_YOUNG:
            gc.collect(0)
            self.gc_collections += 1

    def _next_fixed(self) -> tuple[int, int]:
        """The fixed grid: sleep until deadline k; skip the grid points more than a period late.
        Returns (t_k, start) in the bus time base."""
        clock = self.clock
        t_clk = self._t0 + self._k * STEP_NS
        clock.sleep_until(t_clk)
        now = clock.now_ns()
        late = now - t_clk
        if late >= _SKIP_AFTER_NS:
            n = late // STEP_NS
            self.stats.record_skipped(n)
            self._k += n
            t_clk += n * STEP_NS
        self._k += 1
        return t_clk + self.offset_ns, now + self.offset_ns

    def _next_locked(self) -> tuple[int, int]:
        """The MDPS-locked grid: wait for the frame that triggers the next step, or for the end of its
        window (:mod:`lde.engine.grid`). A due step more than a period late is skipped when a later one is
        due too. Returns (t_k, start) in the bus time base."""
        clock = self.clock
        off = self.offset_ns
        lock = self._lock
        assert lock is not None
        due = self._due
        recv_until = getattr(clock, "recv_until", None)
        spin = int(getattr(clock, "spin_ns", 0)) if self.prewarm else 0
        while True:
            while not due:
                end = int(lock_deadline(lock))
                now = clock.now_ns() + off
                if now > end:  # every frame up to now is in: the window ended without an MDPS frame
                    self._drain()
                    if not due:
                        # behind by more than a period (no MDPS frame, a slow CPU): the windows that
                        # ended before the last one are skipped and counted, the phase is kept
                        n = (now - end - 1) // STEP_NS
                        if n > 0:
                            lock[L_REF] += n * STEP_NS
                            self.stats.record_skipped(int(n))
                        self._make_due(int(lock_timeout(lock, now)))
                    break
                try:
                    if recv_until is not None:  # the MDPS frame is expected one period after t_ref
                        expect = int(lock[L_REF]) + STEP_NS - off
                        warm_at = expect - spin
                        if spin and self._warmed_for != expect and now - off < warm_at:
                            # blocked until the spin starts, then the engine's empty call (_prewarm)
                            msg = recv_until(self.io, min(end + 1 - off, warm_at))
                            if msg is None:
                                self._prewarm()
                                self._warmed_for = expect
                        else:
                            msg = recv_until(self.io, end + 1 - off, expect)
                    else:  # a clock without it: poll, then sleep to the window's end
                        msg = self.io.recv(0.0)
                        if msg is None:
                            clock.sleep_until(end + 1 - off)
                except (can.CanError, OSError) as exc:
                    self._recv_failed(exc)
                    clock.sleep_until(min(end + 1 - off, clock.now_ns() + STEP_NS // 4))
                    continue
                if msg is not None:
                    self._take(msg)
            t_k = due.popleft()
            now = clock.now_ns() + off
            if t_k > now:  # a simulated clock: move it to the frame
                clock.sleep_until(t_k - off)
                now = clock.now_ns() + off
            if due and now - t_k >= _SKIP_AFTER_NS:
                self.stats.record_skipped(1)
                continue
            return t_k, now


def set_input_filters(bus: can.BusABC, profile: Profile) -> str:
    """Pass only the profile's input messages (11-bit ids) up from ``bus`` where the kernel can do it
    (:func:`lde.can.busio.receive_only`); returns how. The service drops any other frame itself as well
    (:meth:`Service._take`)."""
    return receive_only(bus, (m.frame_id for m in profile.messages.values()))


def _open_bus_counter(bus: can.BusABC) -> int | None:
    """A SocketCAN interface's received-frame counter (``/sys/class/net/IF/statistics/rx_packets``),
    opened once (read with one ``pread`` per check), or None elsewhere."""
    ch = getattr(bus, "channel", None)
    if type(bus).__name__ != "SocketcanBus" or not isinstance(ch, str) or not ch or "/" in ch:
        return None
    try:
        return os.open(f"/sys/class/net/{ch}/statistics/rx_packets", os.O_RDONLY)
    except OSError:
        return None


def _read_counter(fd: int | None) -> int:
    """The counter's value, -1 when there is none or it cannot be read."""
    if fd is None:
        return -1
    try:
        return int(os.pread(fd, 32, 0))
    except (OSError, ValueError):
        return -1
