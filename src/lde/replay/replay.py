"""Batch replay: a log through the one data path (:class:`lde.engine.engine.Engine`) -> CSV / MCAP.

Replay runs exactly what the live service runs (:mod:`lde.engine.loop`): the same receiver, grid,
corrections, estimator backend, output finalisation, overlay limiter and output encoding, over the
log's received frames (``is_rx``; lde's own sent frames in a recording are left out) in time order.

Step times are the anchored grid of :mod:`lde.engine.grid` (from the first accepted MDPS frame; a silence
of the inputs longer than :data:`lde.engine.grid.MAX_GAP_NS` starts a new segment), or, for an lde
recording (``/can/tx`` and ``/lde/estimate`` present), the recorded step times together with the
recorded overlay enable input and deadline-miss bits (``/lde/events``), so that a live run is
reproduced exactly. :attr:`ReplayResult.duration_s` is the stepped time (steps x 3.9 ms) and
:attr:`ReplayResult.segments` counts the grid's segments; ``t`` keeps each segment's own time base.

The CAN profile of a replay is the one given; when none is given (:func:`replay_log` with
``profile=None``, ``lde replay`` without ``--profile``), the one named in the log's ``lde`` metadata
record (:func:`recorded_profile`: lde recordings, ``lde sim --mcap`` files), else ``lde``.

Outputs: :func:`write_csv` (one row per step; ``t`` in seconds in the log's own time base) and
:func:`write_recording` (an MCAP recording that itself replays to the same estimates, written with
the live recorder's topic definitions, :class:`lde.io.recording.StepTopicWriter`).
"""

from __future__ import annotations

import contextlib
import time
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lde.can.channels import ChannelSelect
from lde.can.e2e import ReceiverStats
from lde.can.frames import FrameBatch
from lde.can.profiles import DOCS, PROFILE_NAMES, Profile, load_profile, observe_timeouts
from lde.can.watch import describe_ids
from lde.engine.backends import DEFAULT_BACKEND, get_backend
from lde.engine.engine import OUTPUT_MESSAGES, Engine, StepBlock, recorded_steps
from lde.engine.grid import MAX_GAP_NS, InputGrid
from lde.engine.receiver import I_SPEED
from lde.errors import ConfigError, LogFormatError, OutputError
from lde.io import (
    CHUNK_FRAMES,
    REORDER_WINDOW_NS,
    TOPIC_TX,
    LogData,
    LogStream,
    McapData,
    McapLog,
    McapWriter,
    ReadStats,
    open_log,
)
from lde.io.ending import FileEnd
from lde.io.mcap_read import can_counts
from lde.io.recording import (
    ESTIMATE_TOPIC,
    EVENTS_TOPIC,
    LEARNED_START_KEY,
    SmoothTopicWriter,
    StepTopicWriter,
)
from lde.io.stream import ReadAhead, split
from lde.io.textfmt import Column, format_rows, time_column
from lde.params import Vehicle
from lde.replay.columns import CSV_COLUMNS, SMOOTHED, STATUS_COLUMNS, csv_columns
from lde.replay.smoother import NS, S_BANK, SmoothTrack, check_backend, smooth_run
from lde.status import DEADLINE_MISS, STATUS_BITS, VALID
from lde.units import KMH, STEP_NS

__all__ = [
    "ReplayResult",
    "FrameCounts",
    "replay",
    "replay_log",
    "recorded_step_times",
    "recorded_events",
    "recorded_profile",
    "profile_metadata",
    "no_valid_note",
    "gaps_note",
    "late_note",
    "resolve_backend",
    "write_csv",
    "write_recording",
    "run_replay",
    "read_inputs",
    "LogInputs",
    "ReplaySummary",
    "CsvWriter",
    "RecordingWriter",
    "output_frames",
    "CSV_COLUMNS",
    "STATUS_COLUMNS",
    "csv_columns",
    "DEFAULT_BACKEND",
    "smoothed_columns",
]


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class FrameCounts:
    """Frames of a replay: total, lde's own (tx, not inputs), ignored ids, per input message
    (:class:`lde.can.e2e.ReceiverStats`: received = used + rejected + resync; malformed apart)."""

    total: int
    tx: int
    ignored: int
    messages: dict[str, ReceiverStats]
    ids: dict[int, int] = field(default_factory=dict)  # received frames per 11-bit id
    #: input-message frames on another bus than their message's (not fed), and each message's bus
    other_bus: int = 0
    buses: dict[str, str] = field(default_factory=dict)

    @property
    def used(self) -> int:
        return sum(m.used for m in self.messages.values())

    @property
    def rejected(self) -> int:
        """E2E rejections plus malformed frames."""
        return sum(m.rejected + m.malformed for m in self.messages.values())

    @property
    def resync(self) -> int:
        return sum(m.resync for m in self.messages.values())

    def rejected_by_cause(self) -> dict[str, int]:
        out = {"repeated": 0, "wrong_sequence": 0, "wrong_crc": 0, "malformed": 0}
        for m in self.messages.values():
            for k in out:
                out[k] += getattr(m, k)
        return out


@dataclass
class ReplayResult:
    """One row per estimator step (SI, ISO 8855 signs; ``t_align`` with the paper's sign).

    Attributes:
        block: the engine's rows (:class:`lde.engine.engine.StepBlock`: every column, the output frames).
        t_ns: int64 step times [ns], the log's own time base.
        fw [N], mw [Nm], t_align [Nm], t_overlay [Nm], beta [rad], yaw_rate [rad/s]: float64.
        status: uint8 ``LDE_Estimate.Status`` bits; overlay_state: uint8; overlay_active: bool.
        grid: the estimator inputs at the steps.
        frames: frame counts (used / rejected by cause / re-synchronising).
        backend: the backend's name.
        recorded_steps: True when the step times came from a recording.
        timings: seconds spent per stage.
        diag: per step ``frames_used`` (input frames accepted since the previous step) and
            ``e2e_rejects`` (frames rejected since the start), as the live ``LDE_Diag``.
        profile: the CAN profile used; profile_origin: ``"given"``, ``"recording"`` or ``"default"``.
        max_speed: the highest fresh speed input at any step [m/s] (None: never fresh);
        min_speed: the model's minimum speed [m/s] (below it no estimate is valid).
    """

    block: StepBlock
    t_ns: np.ndarray
    fw: np.ndarray
    mw: np.ndarray
    t_align: np.ndarray
    t_overlay: np.ndarray
    status: np.ndarray
    overlay_state: np.ndarray
    overlay_active: np.ndarray
    beta: np.ndarray
    yaw_rate: np.ndarray
    grid: InputGrid
    frames: FrameCounts
    backend: str
    recorded_steps: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    diag: dict[str, np.ndarray] = field(default_factory=dict)
    profile: Profile | None = None
    profile_origin: str = ""
    #: with ``smooth``: the RTS smoother's outputs per step (n, :data:`lde.replay.smoother.NS`; SI, the
    #: bank in rad; :data:`lde.replay.smoother.SMOOTHED` order), else None
    smooth: np.ndarray | None = None
    max_speed: float | None = None
    min_speed: float = 0.0

    @classmethod
    def of(cls, block: StepBlock, frames: FrameCounts, backend: str, **kw: Any) -> ReplayResult:
        b = block
        return cls(
            block=b,
            t_ns=b.t_ns,
            fw=b.fw.copy(),
            mw=b.mw.copy(),
            t_align=b.t_align.copy(),
            t_overlay=b.t_overlay,
            status=b.status,
            overlay_state=b.overlay_state,
            overlay_active=b.overlay_active,
            beta=b.beta.copy(),
            yaw_rate=b.yaw_rate.copy(),
            grid=InputGrid.from_columns(b.t_ns, b.inputs, b.ages, b.valid_mask, b.ok),
            frames=frames,
            backend=backend,
            diag={"frames_used": b.frames_used, "e2e_rejects": b.e2e_rejects},
            **kw,
        )

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def columns(self) -> dict[str, np.ndarray]:
        """The per-step columns by their CSV / recording names (``t_ns``, ``Fw``, ``Mw``,
        ``T_align``, ``T_overlay``, ``status``, ``overlay_state``, ``overlay_active``, ``beta``,
        ``yaw_rate``)."""
        return {
            "t_ns": self.t_ns,
            "Fw": self.fw,
            "Mw": self.mw,
            "T_align": self.t_align,
            "T_overlay": self.t_overlay,
            "status": self.status,
            "overlay_state": self.overlay_state,
            "overlay_active": self.overlay_active,
            "beta": self.beta,
            "yaw_rate": self.yaw_rate,
        }

    @property
    def duration_s(self) -> float:
        """Stepped time [s]: steps x STEP_NS. Not the last minus the first step time, which also
        spans the gaps between grid segments (a log joining two time bases: ~1.7e9 s)."""
        return len(self) * STEP_NS * 1e-9

    @property
    def segments(self) -> int:
        """Runs of steps with no gap longer than :data:`lde.engine.grid.MAX_GAP_NS` between consecutive
        steps (the grid's segments; 1 for an ordinary log, 0 without steps)."""
        if len(self) == 0:
            return 0
        return 1 + int(np.count_nonzero(np.diff(self.t_ns) > MAX_GAP_NS))


# ----------------------------------------------------------------------------- backends
def resolve_backend(backend: str | None) -> str:
    """The registered backend's name (:mod:`lde.engine.backends`); ``None`` is :data:`DEFAULT_BACKEND`.
    An unknown or removed name raises ConfigError (never a fallback)."""
    return get_backend(DEFAULT_BACKEND if backend is None else backend).name


# ----------------------------------------------------------------------------- the path
Sink = Callable[[FrameBatch, StepBlock], None]


@dataclass
class ReplaySummary:
    """What a streamed replay reports (its rows went to the sinks).

    Attributes:
        steps: rows produced; valid_steps: rows with the VALID bit; segments: runs of steps without a
            gap longer than :data:`lde.engine.grid.MAX_GAP_NS`; frames: frame counts; backend; recorded_steps;
            timings [s]; profile, profile_origin, max_speed, min_speed (as :class:`ReplayResult`).
    """

    steps: int
    valid_steps: int
    segments: int
    frames: FrameCounts
    backend: str
    recorded_steps: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    profile: Profile | None = None
    profile_origin: str = ""
    learned: str = ""  # what the learner holds at the end (one line; empty without a learner)
    learned_origin: str = ""  # where learning started: a --learned file, the recording, "" (vehicle)
    #: silences in the received frames longer than :data:`JUMP_NS`: (log time before [ns], length [ns])
    input_gaps: list[tuple[int, int]] = field(default_factory=list)
    #: the replay was stopped (``stop``) before the end of the log; its rows so far went to the sinks
    stopped: bool = False
    last_step_ns: int | None = None  # the time of the last row [ns]
    max_speed: float | None = None  # the highest fresh speed input at any step [m/s]
    min_speed: float = 0.0  # the model's minimum speed [m/s]

    def __len__(self) -> int:
        return self.steps

    @property
    def duration_s(self) -> float:
        """Stepped time [s]: steps x STEP_NS."""
        return self.steps * STEP_NS * 1e-9


def run_replay(
    frames: FrameBatch | Iterable[FrameBatch],
    profile: Profile,
    vehicle: Vehicle,
    backend: str | None = "float",
    *,
    sinks: tuple[Sink, ...] = (),
    step_times_ns: np.ndarray | None = None,
    tx_frames: int | Callable[[], int | None] | None = None,
    overlay_enable: np.ndarray | None = None,
    extra_status: np.ndarray | None = None,
    output_frames: bool = True,
    chunk_frames: int = CHUNK_FRAMES,
    learned: str | Path | None = None,
    learned_start: str | None = None,
    stop: Callable[[], bool] | None = None,
    read_ahead: bool = True,
) -> ReplaySummary:
    """Stream frames through the data path; every piece's rows go to each sink as
    ``sink(piece, rows)``, the steps after the log's last frame with an empty piece.

    ``frames``: one batch (any order: sorted here, then cut in pieces of ``chunk_frames``) or an
    iterable of pieces already in time order (a :class:`lde.io.LogStream`), read one at a time.
    ``tx_frames``: the log's count of frames lde sent when the pieces do not hold them all (or a
    function giving it once the pieces are read). ``learned``: a learned-state file
    (``--learned``), read first when it exists and written (atomically) at the end.
    ``learned_start``: the text of the learned state a live run started from (its recording's
    ``learned_start``): used by a learning backend when ``learned`` names no existing file, so that
    the recording replays to the live estimates. ``stop``: asked after
    every piece; True ends the replay there (SIGINT / SIGTERM: the sinks have every row so far
    and can be closed; :attr:`ReplaySummary.stopped`). ``read_ahead`` (default True): an iterable of
    pieces is read in a thread one piece ahead of the engine (:class:`lde.io.stream.ReadAhead`: a
    candump block parsed, an MCAP chunk decompressed and walked on the other core; the timing
    ``read`` is then the time the engine waited for a piece; an error of the reader is raised here
    after the pieces before it). The piece in flight costs an MCAP replay about 10 MiB of peak RSS
    (the decompressed chunk and its columns). Other arguments as :func:`replay`.
    """
    name = DEFAULT_BACKEND if backend is None else backend
    t0 = time.perf_counter()
    explicit = step_times_ns is not None
    ahead: ReadAhead[FrameBatch] | None = None
    if isinstance(frames, FrameBatch):
        pieces: Iterable[FrameBatch] = split(frames.sort(), chunk_frames)
    elif read_ahead:
        # the next piece is read (parsed, decompressed) while the engine runs this one
        pieces = ahead = ReadAhead(frames)
    else:
        pieces = frames
    it = iter(pieces)
    # each input message's frames of its own bus; timeouts the DBC does not give from the first piece
    select = ChannelSelect(profile)
    tr = time.perf_counter()
    try:
        head = next(it, None)
        if not profile.timeouts_known:
            profile = observe_timeouts(profile, select(head) if head is not None else FrameBatch.empty())
        engine = Engine(
            profile,
            vehicle,
            name,
            explicit=explicit,
            encode_outputs=output_frames,
        )
    except BaseException:
        if ahead is not None:
            ahead.close()
        raise
    t_read = time.perf_counter() - tr
    origin = ""
    if learned is not None and engine.load_learned(learned) is not None:
        origin = str(learned)
    elif learned_start and engine.learns:
        engine.load_learned_text(learned_start, "the recording's learned start")
        origin = "the recording's learned start"
    n = n_tx = 0
    id_counts = np.zeros(0x800, np.int64)
    input_gaps: list[tuple[int, int]] = []
    last_rx: int | None = None
    steps = valid = gaps = 0
    last_t: int | None = None
    max_speed: float | None = None
    t_sinks = 0.0
    first = True
    stopped = False
    try:
        while True:
            tr = time.perf_counter()
            chunk = head if first else next(it, None)
            t_read += time.perf_counter() - tr
            final = chunk is None
            if chunk is None:
                chunk = FrameBatch.empty()
            n += len(chunk)
            n_tx += int(np.count_nonzero(~chunk.is_rx))
            if len(chunk):  # received frames per 11-bit id (the summary names them when inputs are missing)
                rx = chunk.is_rx
                rx_ids = chunk.can_id[rx & ~chunk.is_extended]
                id_counts += np.bincount(rx_ids & 0x7FF, minlength=0x800)[:0x800]
                t_rx = chunk.t_ns[rx]
                if len(t_rx):
                    if last_rx is not None and int(t_rx[0]) - last_rx > JUMP_NS:
                        input_gaps.append((last_rx, int(t_rx[0]) - last_rx))
                    d = np.diff(t_rx)
                    for i in np.flatnonzero(d > JUMP_NS)[:_MAX_GAPS_KEPT].tolist():
                        input_gaps.append((int(t_rx[i]), int(d[i])))
                    last_rx = int(t_rx[-1])
            kw: dict[str, Any] = {}
            if step_times_ns is not None and first:
                kw = recorded_steps(step_times_ns, overlay_enable, extra_status)
            first = False
            block = engine.feed(select(chunk), final=final, **kw)
            m = len(block)
            if m:
                steps += m
                valid += int(np.count_nonzero(block.status & VALID))
                fresh = (block.valid_mask >> I_SPEED) & 1 != 0
                if np.any(fresh):
                    top = float(np.max(block.inputs[fresh, I_SPEED]))
                    max_speed = top if max_speed is None else max(max_speed, top)
                t = block.t_ns
                gaps += int(np.count_nonzero(np.diff(t) > MAX_GAP_NS))
                if last_t is not None and int(t[0]) - last_t > MAX_GAP_NS:
                    gaps += 1
                last_t = int(t[-1])
            ts = time.perf_counter()
            if m or len(chunk):
                for sink in sinks:
                    sink(chunk, block)
            t_sinks += time.perf_counter() - ts
            if final:
                break
            if stop is not None and stop():
                stopped = True
                break
    finally:
        if ahead is not None:
            ahead.close()
    known_tx = tx_frames() if callable(tx_frames) else tx_frames
    counts = FrameCounts(
        total=n,
        tx=n_tx if known_tx is None else known_tx,
        ignored=engine.n_ignored,
        messages=engine.stats(),
        ids={int(i): int(id_counts[i]) for i in np.flatnonzero(id_counts)},
        other_bus=select.dropped,
        buses=dict(select.chosen),
    )
    if learned is not None:
        engine.save_learned(learned, valid * STEP_NS * 1e-9)
    return ReplaySummary(
        steps=steps,
        valid_steps=valid,
        segments=(gaps + 1) if steps else 0,
        frames=counts,
        backend=engine.backend.name,
        recorded_steps=explicit,
        timings={
            "read": t_read,
            "engine": time.perf_counter() - t0 - t_sinks - t_read,
            "outputs": t_sinks,
        },
        learned=engine.learn_summary,
        learned_origin=origin,
        input_gaps=input_gaps,
        stopped=stopped,
        last_step_ns=last_t,
        max_speed=max_speed,
        min_speed=vehicle.estimator.min_speed,
    )


def replay(
    frames: FrameBatch,
    profile: Profile,
    vehicle: Vehicle,
    backend: str | None = "float",
    *,
    step_times_ns: np.ndarray | None = None,
    tx_frames: int | None = None,
    overlay_enable: np.ndarray | None = None,
    extra_status: np.ndarray | None = None,
    output_frames: bool = True,
    learned: str | Path | None = None,
    learned_start: str | None = None,
    smooth: bool = False,
) -> ReplayResult:
    """Replay ``frames`` (any order) through the data path; every row is kept (:class:`ReplayResult`).

    Args:
        frames: the log's frames; only received ones (``is_rx``) are inputs.
        profile: CAN profile (:func:`lde.can.profiles.load_profile`).
        vehicle: parameters and tuning (:func:`lde.params.load_vehicle`).
        backend: a registered backend name (None: :data:`DEFAULT_BACKEND`).
        step_times_ns: explicit step times (a recording's; non-decreasing); default the anchored grid.
        tx_frames: the log's count of frames lde sent, when the reader did not return them all.
        overlay_enable: the overlay limiter's enable input per step of ``step_times_ns`` (a
            recording's, so that a run ended by a signal replays exactly); default all on.
        extra_status: status bits to add per step of ``step_times_ns`` (a recording's DEADLINE_MISS).
        output_frames: encode lde's output frames (needed by :func:`write_recording`).
        learned: a learned-state file (read when it exists, written at the end).
        learned_start: a recording's learned start (:func:`run_replay`).
        smooth: also the RTS smoother's outputs (:mod:`lde.replay.smoother`; :attr:`ReplayResult.smooth`).
    """
    name = DEFAULT_BACKEND if backend is None else get_backend(backend).name
    smoothed = None
    if smooth:
        check_backend(name)
        with smooth_run(
            split(frames.sort(), CHUNK_FRAMES),
            profile,
            vehicle,
            step_times_ns=step_times_ns,
            overlay_enable=overlay_enable,
            extra_status=extra_status,
            learned=learned,
            learned_start=learned_start,
        ) as track:
            t_s, smoothed = track.read_all()
    blocks: list[StepBlock] = []
    summary = run_replay(
        frames,
        profile,
        vehicle,
        backend,
        sinks=(lambda _frames, rows: blocks.append(rows),),
        step_times_ns=step_times_ns,
        tx_frames=tx_frames,
        overlay_enable=overlay_enable,
        extra_status=extra_status,
        output_frames=output_frames,
        learned=learned,
        learned_start=learned_start,
    )
    block = StepBlock.concat(blocks) if len(blocks) != 1 else blocks[0]
    res = ReplayResult.of(
        block,
        summary.frames,
        summary.backend,
        recorded_steps=summary.recorded_steps,
        timings=summary.timings,
        max_speed=summary.max_speed,
        min_speed=summary.min_speed,
    )
    if smoothed is not None:
        if not np.array_equal(t_s, block.t_ns):
            raise RuntimeError("smoothed run and causal replay are not on the same step grid")
        res.smooth = smoothed
    return res


def _mcap_of(log: LogData | LogStream) -> McapData | McapLog | None:
    return log.mcap


def recorded_step_times(log: LogData | LogStream) -> np.ndarray | None:
    """Step times of an lde recording: the log times of ``/lde/estimate`` (the recorders' contract:
    log time = the step time t_k, exact in ns), when the file has ``/can/tx`` and a non-empty
    ``/lde/estimate``; None for any other log."""
    m = _mcap_of(log)
    if m is None or ESTIMATE_TOPIC not in m.topics or TOPIC_TX not in m.topics:
        return None
    times = m.times[ESTIMATE_TOPIC] if isinstance(m, McapData) else m.times(ESTIMATE_TOPIC)
    return np.asarray(times, np.int64) if len(times) else None


def recorded_events(
    log: LogData | LogStream, step_times_ns: np.ndarray | None
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(overlay enable, extra status) at each recorded step from the sparse ``/lde/events`` channel:
    the limiter's enable input sample-and-hold (an event at t_k applies from step t_k on) and
    DEADLINE_MISS at the steps whose event says so. (None, None) when the log has no events."""
    m = _mcap_of(log)
    if m is None or step_times_ns is None or EVENTS_TOPIC not in m.topics:
        return None, None
    if isinstance(m, McapData):
        if EVENTS_TOPIC not in m.json:
            return None, None
        ev = m.json[EVENTS_TOPIC]
    else:
        ev = m.json(EVENTS_TOPIC)
    t_ev = np.asarray(ev.get("log_time", []), np.int64)
    val = np.asarray(ev.get("overlay_enable", []))
    if len(t_ev) == 0 or len(val) != len(t_ev):
        return None, None
    order = np.argsort(t_ev, kind="stable")
    t_ev, val = t_ev[order], val[order]
    idx = np.searchsorted(t_ev, step_times_ns, side="right") - 1
    enable = np.where(idx >= 0, val[np.maximum(idx, 0)] != 0, True)
    extra = np.zeros(len(step_times_ns), np.uint8)
    miss = np.asarray(ev.get("deadline_miss", np.zeros(len(order))))[order]
    t_miss = t_ev[np.nan_to_num(miss) != 0]
    if t_miss.size:
        extra[np.isin(step_times_ns, t_miss)] = DEADLINE_MISS
    return enable, extra


def profile_metadata(profile: Profile) -> dict[str, str]:
    """The ``lde`` metadata entries that name ``profile`` in a recording
    (:meth:`lde.can.profiles.Profile.metadata`)."""
    return profile.metadata()


def recorded_profile(log: LogData | LogStream) -> str | None:
    """The CAN profile an MCAP log says it was made with, as :func:`lde.can.profiles.load_profile`
    takes it: ``profile_file`` of its ``lde`` metadata record when that file exists, else the shipped
    profile named ``profile``; None when the log names none (candump, ASC, ... or a foreign MCAP).

    Raises:
        ConfigError: the log names a profile that cannot be found here (a profile file of another
            machine, or a DBC that older versions took as a profile): give ``--profile``.
    """
    meta = log.mcap.metadata.get("lde", {}) if log.mcap is not None else {}
    name, file = meta.get("profile", ""), meta.get("profile_file", "")
    dbc = meta.get("profile_dbc", "")  # recordings of versions that took a .dbc as the profile
    if file and Path(file).is_file():
        return file
    if name in PROFILE_NAMES and not file and not dbc:
        return name
    if name or file or dbc:
        where = (
            f" (file {file}, not found)"
            if file
            else f" (DBC {dbc}: write a profile file for it, {DOCS})"
            if dbc
            else " (not a shipped profile)"
        )
        raise ConfigError(
            f"{log.path}: recorded with CAN profile {name or file or dbc!r}{where}: give --profile "
            f"({', '.join(PROFILE_NAMES)} or a profile file)"
        )
    return None


def no_valid_note(res: ReplayResult | ReplaySummary) -> str | None:
    """A one-line explanation when a replay has not one VALID estimate (no step, or steps that all
    stayed invalid), else None: the missing input messages, named with the ids the log has and the
    profile they fit (:mod:`lde.can.watch`); a car that never reached the model's minimum speed (a
    standing car: the profile is right, the estimator has nothing to estimate); else most often
    the wrong CAN profile."""
    if isinstance(res, ReplaySummary):
        if res.valid_steps:
            return None
    elif len(res) and np.any(res.status & VALID):
        return None
    anchor = res.profile.anchor_message if res.profile is not None else ""
    m = res.frames.messages.get(anchor)
    if res.profile is not None:
        missing = [
            f"{name} (0x{spec.frame_id:X})"
            for name, spec in res.profile.messages.items()
            if (st := res.frames.messages.get(name)) is None or st.received == 0
        ]
        if missing:
            counts = res.frames.ids
            if counts:
                ids = "; " + describe_ids(counts, res.profile)
            else:
                ids = "; no received frame at all" if res.frames.total == res.frames.tx else ""
            return (
                f"no valid estimate: no frame of {', '.join(missing)} in the log (profile"
                f" {res.profile.name}, {_ORIGIN.get(res.profile_origin, res.profile_origin)}){ids}"
            )
    if m is not None and m.used and res.max_speed is not None and res.max_speed < res.min_speed:
        return (
            f"no valid estimate: below the minimum speed of {res.min_speed / KMH:.0f} km/h for the whole log"
            f" (highest {res.max_speed / KMH:.1f} km/h): the estimator needs the car moving"
        )
    if m is None or m.received == 0:
        why = f"no {anchor or 'MDPS'} frames of this profile in the log"
    elif m.used == 0:
        why = f"all {m.received} {anchor} frames rejected (E2E/length)"
    else:
        why = f"{anchor} frames used {m.used} of {m.received}; the estimate never became valid"
    if res.profile is None:
        return f"no valid estimate: {why}"
    origin = _ORIGIN.get(res.profile_origin, res.profile_origin)
    return f"no valid estimate: {why} — wrong --profile? (used {res.profile.name}, {origin})"


_ORIGIN = {"given": "given", "recording": "from the recording", "default": "the default"}


#: a silence in the received frames longer than this is reported as a time jump (a logger paused, a
#: clock stepped, logs joined): the inputs time out and the estimate restarts after it, as live
JUMP_NS = 1_000_000_000
_MAX_GAPS_KEPT = 1000


def gaps_note(res: ReplaySummary) -> str | None:
    """A one-line warning naming the time jumps in the received frames (:data:`JUMP_NS`), else None."""
    if not res.input_gaps:
        return None
    t, d = max(res.input_gaps, key=lambda g: g[1])
    n = len(res.input_gaps)
    return (
        f"{n} time jump{'s' if n > 1 else ''} in the received frames (silences > {JUMP_NS / 1e9:.0f} s;"
        f" longest {d / 1e9:.3f} s after log time {t / 1e9:.6f} s): the inputs timed out there and the"
        f" estimate restarted after {'each' if n > 1 else 'it'}"
    )


def late_note(stats: ReadStats, window_ns: int | None) -> str | None:
    """A one-line warning when a streamed log had frames too far out of time order, else None."""
    if not stats.late_frames:
        return None
    w = "" if window_ns is None else f" by more than {window_ns / 1e9:g} s"
    return (
        f"{stats.late_frames} frames were out of time order{w} and were skipped: "
        "sort the log or give --reorder-window 0 (sorts the whole log in memory)"
    )


_NOT_CLOSED = {
    "mcap": "no MCAP footer",
    "asc": "no End TriggerBlock line",
    "blf": "its header's file size was never written",
}


def end_note(stream: LogStream) -> str | None:
    """A one-line warning when a log was not closed by its writer or is cut short, saying where
    reading stopped (log time of the latest frame read, byte offset, line), else None. Call it
    once the stream has been read."""
    e = stream.end
    if e is None or not e.lossy:
        return None
    return f"file {describe_end(e, stream.format)}; {_read_up_to(stream.last_t_ns)}; anything after is lost"


def describe_end(e: FileEnd, fmt: str) -> str:
    """What :class:`lde.io.FileEnd` ``e`` of a ``fmt`` log says, and where (no time)."""
    inner = fmt.removesuffix(".gz")
    parts = []
    de = " decompressed" if e.compressed else ""
    if e.closed is False:
        why = [_NOT_CLOSED[inner]] if inner in _NOT_CLOSED else []
        if e.compressed and fmt.endswith(".gz") and e.cut:
            why.append("the gzip stream has no end")
        parts.append(
            f"not closed by its writer ({'; '.join(why) or 'no closing record'}:"
            " a crash, a kill, a full disk?)"
        )
    if e.cut and e.what == "line":
        parts.append(
            f"cut short inside line {e.line + 1} at byte {e.offset} of {e.size}{de} (the line is skipped)"
        )
    elif e.cut:
        lost = "its frames are lost" if inner == "mcap" else "read as far as it goes"
        parts.append(
            f"cut short inside the {inner.upper()} {e.what} at byte {e.offset} of {e.size}{de} ({lost})"
        )
    else:
        parts.append(f"its complete {e.what}s end at byte {e.offset} of {e.size}{de}")
    return " and ".join(parts) if e.cut else ", ".join(parts)


def _read_up_to(t_ns: int | None) -> str:
    return (
        "no frame was read" if t_ns is None else f"read up to log time {t_ns / 1e9:.6f} s (the latest frame)"
    )


@dataclass
class LogInputs:
    """A log opened for a replay: its frame stream and what an lde recording adds (step times,
    events). ``read_s``: the time taken to open it (the frames are read while replaying)."""

    stream: LogStream
    profile: Profile
    profile_origin: str
    step_times_ns: np.ndarray | None
    overlay_enable: np.ndarray | None
    extra_status: np.ndarray | None
    read_s: float
    learned_start: str | None = None  # the learned state a live run started from (its recording's)

    def tx_frames(self) -> int | None:
        """The count of frames lde sent (``/can/tx`` and the other sent topics) of an lde MCAP log, else
        None."""
        m = self.stream.mcap
        if m is not None and TOPIC_TX in m.topics:
            return can_counts(m.topics)[1]
        return None


def read_inputs(
    path: str | Path,
    profile: Profile | None,
    *,
    use_recorded_steps: bool = True,
    profiles: dict[str, Profile] | None = None,
    reorder_window_ns: int | None = REORDER_WINDOW_NS,
    chunk_frames: int = CHUNK_FRAMES,
) -> LogInputs:
    """Open a log (any format of :func:`lde.io.open_log`) for a replay; its frames are read
    while replaying. ``profile`` None: the profile the log names (:func:`recorded_profile`), else
    ``lde``; ``profiles`` caches loaded profiles by name across calls. An lde recording's step times
    (and ``/lde/events``) are read now, unless ``use_recorded_steps`` is False. Close the stream
    (``LogInputs.stream.close()``) when done.

    Raises:
        LogFormatError: unreadable log. ConfigError: a recorded profile that cannot be loaded.
    """
    t0 = time.perf_counter()
    stream = open_log(
        Path(path), skip_tx=True, reorder_window_ns=reorder_window_ns, chunk_frames=chunk_frames
    )
    try:
        origin = "given"
        if profile is None:
            key = recorded_profile(stream)
            origin = "recording" if key else "default"
            key = key or "lde"
            cache = profiles if profiles is not None else {}
            if key not in cache:
                cache[key] = load_profile(key)
            profile = cache[key]
        steps = recorded_step_times(stream) if use_recorded_steps else None
        enable, extra = recorded_events(stream, steps)
    except BaseException:
        stream.close()
        raise
    meta = stream.mcap.metadata.get("lde", {}) if stream.mcap is not None else {}
    return LogInputs(
        stream,
        profile,
        origin,
        steps,
        enable,
        extra,
        time.perf_counter() - t0,
        meta.get(LEARNED_START_KEY) or None,
    )


def replay_log(
    path: str | Path,
    profile: Profile | None,
    vehicle: Vehicle,
    backend: str | None = "float",
    *,
    use_recorded_steps: bool = True,
    profiles: dict[str, Profile] | None = None,
    output_frames: bool = True,
    learned: str | Path | None = None,
) -> tuple[LogData, ReplayResult]:
    """Read a log (:func:`read_inputs`) and replay it, every row and every frame kept
    (:class:`lde.io.LogData`, :class:`ReplayResult`).

    Raises:
        LogFormatError: unreadable log. ConfigError: a recorded profile that cannot be loaded.
    """
    li = read_inputs(path, profile, use_recorded_steps=use_recorded_steps, profiles=profiles)
    blocks: list[StepBlock] = []
    pieces: list[FrameBatch] = []

    def keep(frames: FrameBatch, rows: StepBlock) -> None:
        pieces.append(frames)
        blocks.append(rows)

    with li.stream as stream:
        summary = run_replay(
            stream,
            li.profile,
            vehicle,
            backend,
            sinks=(keep,),
            step_times_ns=li.step_times_ns,
            tx_frames=li.tx_frames,
            overlay_enable=li.overlay_enable,
            extra_status=li.extra_status,
            output_frames=output_frames,
            learned=learned,
            learned_start=li.learned_start,
        )
        frames = FrameBatch.concat(pieces, sort=False)
        log = LogData(stream.path, stream.format, frames, stream.stats, mcap=_mcap_data(stream.mcap, frames))
    block = StepBlock.concat(blocks) if len(blocks) != 1 else blocks[0]
    res = ReplayResult.of(
        block,
        summary.frames,
        summary.backend,
        recorded_steps=summary.recorded_steps,
        timings=summary.timings,
        max_speed=summary.max_speed,
        min_speed=summary.min_speed,
    )
    res.timings["open"] = li.read_s
    res.profile, res.profile_origin = li.profile, li.profile_origin
    return log, res


def _mcap_data(m: McapLog | None, frames: FrameBatch) -> McapData | None:
    """What a streamed MCAP log was (topics, metadata, times of its other channels)."""
    if m is None:
        return None
    can = set(m.can_topics)
    return McapData(
        frames=frames,
        topics=dict(m.topics),
        times={t: m.times(t) for t in m.topics if t not in can},
        bad_can_messages=m.bad_can_messages,
        fast_path=m.fast_path,
        chunks_read=m.chunks_read,
        chunks_skipped=m.chunks_skipped,
        truncated=m.truncated,
        metadata=m.metadata,
    )


# ----------------------------------------------------------------------------- outputs
#: rows a :class:`CsvWriter` hands its thread at once (a copy of their CSV columns, 1 MB), and how
#: many such parts may wait: the memory the thread adds stays a few MB, whatever the engine's block
CSV_ROWS = 8192
CSV_PENDING = 2


def _csv_columns(b: StepBlock) -> list[Column]:
    data: dict[str, np.ndarray] = {
        "Fw": b.fw,
        "Mw": b.mw,
        "T_overlay": b.t_overlay,
        "T_align": b.t_align,
        "status": b.status,
        "overlay_state": b.overlay_state,
        "beta": b.beta,
        "yaw_rate": b.yaw_rate,
        "speed": b.input("speed"),
        "mdps_ok": b.mdps_ok,
        "esc_ok": b.esc_ok,
        "Fw_wind": b.fw_wind,
        "Mw_wind": b.mw_wind,
        "bank_deg": np.degrees(b.bank),
        "learn_state": b.learn_state,
    }
    cols = [time_column("t", b.t_ns)]
    cols += [Column(name, data[name], dec) for name, dec, _ in CSV_COLUMNS[1:]]
    return cols


def _status_columns(b: StepBlock) -> list[Column]:
    """The decoded status (:data:`lde.replay.columns.STATUS_COLUMNS`): a 0/1 column per bit, then
    ``overlay_active``."""
    bits = [Column(name, (b.status >> i) & 1, 0) for i, name in enumerate(STATUS_BITS)]
    return bits + [Column("overlay_active", b.overlay_active.astype(np.uint8), 0)]


def smoothed_columns(rows: np.ndarray) -> list[Column]:
    """The smoother's outputs (:data:`lde.replay.smoother.SMOOTHED`; the bank in degrees) as columns."""
    vals = [rows[:, i] for i in range(NS)]
    vals[S_BANK] = np.degrees(vals[S_BANK])
    return [Column(name, v, dec) for (name, dec, _), v in zip(SMOOTHED, vals, strict=True)]


class CsvWriter:
    """The replay CSV (:func:`lde.replay.columns.csv_columns`: :data:`CSV_COLUMNS`, then with
    ``smooth`` the smoother's :data:`~lde.replay.columns.SMOOTHED`, then the decoded
    :data:`STATUS_COLUMNS`; NaN as ``nan``) written block by block: a sink of
    :func:`run_replay`. ``t`` is the step time in seconds in the log's own time base, printed exactly
    from the integer ns (6 decimals when every step time of a block is a whole microsecond, else 9).

    Blocks are formatted and written by one writer thread (the formatter and the file write release
    the GIL), so that the CSV does not take the engine's core: rows go in parts of :data:`CSV_ROWS`, at
    most :data:`CSV_PENDING` waiting (memory stays bounded), in order. The smoothed rows are read in
    the caller (``smooth.rows_for`` follows the causal replay's blocks in order, shared with the MCAP
    sink). A write error surfaces, as :class:`lde.errors.OutputError`, at the next :meth:`write` or at
    :meth:`close`; ``background=False`` formats and writes in the caller."""

    def __init__(
        self, path: str | Path, smooth: SmoothTrack | None = None, *, background: bool = True
    ) -> None:
        self.path = Path(path)
        self._smooth = smooth
        names = [name for name, _, _ in csv_columns(smooth is not None)]
        try:
            self._fh = open(self.path, "wb")  # noqa: SIM115 - closed by close()
            self._fh.write((",".join(names) + "\n").encode())
        except OSError as exc:
            raise LogFormatError(f"{path}: cannot write: {exc}") from exc
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="lde-csv") if background else None
        self._pending: deque[Future[None]] = deque()

    def _write_now(self, cols: list[Column]) -> None:
        text, _ = format_rows(cols, [""] + [","] * (len(cols) - 1), "\n")
        try:
            self._fh.write(text.data)
        except OSError as exc:
            raise OutputError(f"{self.path}: cannot write: {exc}") from exc

    def write(self, block: StepBlock) -> None:
        """Write ``block``'s rows (queued: a copy of its CSV columns, so that the block itself is
        not held)."""
        if len(block) == 0:
            return
        cols = _csv_columns(block)
        if self._smooth is not None:
            cols += smoothed_columns(self._smooth.rows_for(block))
        cols += _status_columns(block)
        if self._pool is None:
            self._write_now(cols)
            return
        for a in range(0, len(block), CSV_ROWS):
            part = [
                Column(c.name, np.array(c.values[a : a + CSV_ROWS]), c.decimals, c.prescaled) for c in cols
            ]
            while len(self._pending) >= CSV_PENDING:
                self._pending.popleft().result()
            self._pending.append(self._pool.submit(self._write_now, part))

    def __call__(self, _frames: FrameBatch, block: StepBlock) -> None:
        self.write(block)

    def _drain(self) -> None:
        try:
            while self._pending:
                self._pending.popleft().result()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True, cancel_futures=True)

    def close(self) -> None:
        try:
            self._drain()
        finally:
            try:
                self._fh.close()
            except OSError as exc:
                raise OutputError(f"{self.path}: cannot write: {exc}") from exc

    def abort(self, keep: bool = False) -> None:
        """The replay failed: close and remove the incomplete file (``keep``: leave the rows
        written so far, an output that could not be written further)."""
        with contextlib.suppress(Exception):
            self._drain()
        with contextlib.suppress(OSError):
            self._fh.close()
        if not keep:
            with contextlib.suppress(OSError):
                self.path.unlink()

    def __enter__(self) -> CsvWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def write_csv(path: str | Path, res: ReplayResult) -> None:
    """A replay's rows as CSV (:class:`CsvWriter`)."""
    with CsvWriter(path) as w:
        w.write(res.block)


class RecordingWriter:
    """An lde MCAP recording of a replay, written block by block (a sink of :func:`run_replay`):
    the input frames (``/can/rx``), lde's output frames (``/can/tx``, as the engine encoded them) and
    the step topics (:class:`lde.io.recording.StepTopicWriter`); with ``smooth`` also the smoother's
    outputs (``/lde/smooth``). It replays to the same estimates."""

    def __init__(
        self,
        path: str | Path,
        profile: Profile,
        metadata: dict[str, str] | None = None,
        *,
        compression: str = "zstd",
        indexed: bool = False,
        smooth: SmoothTrack | None = None,
    ) -> None:
        self.path = Path(path)
        self._w = McapWriter(
            path, metadata=metadata, compression=compression, indexed=indexed, buffer_bytes=32 << 20
        )
        self._steps = StepTopicWriter(self._w)
        self._smooth = smooth
        self._smooth_topic = (
            SmoothTopicWriter(self._w, tuple((n, d) for n, _, d in SMOOTHED)) if smooth is not None else None
        )
        self._ids = np.array([profile.spec(m).frame_id for m in OUTPUT_MESSAGES], np.uint32)
        self._lens = np.array([profile.spec(m).length for m in OUTPUT_MESSAGES], np.uint8)

    def __call__(self, frames: FrameBatch, block: StepBlock) -> None:
        rx = frames.select(frames.is_rx) if not frames.is_rx.all() else frames
        self._w.write_frames(rx)
        self.write_block(block)

    def write_block(self, block: StepBlock, extra_frames: FrameBatch | None = None) -> None:
        self._w.write_frames(_output_frames(block, self._ids, self._lens))
        if extra_frames is not None:
            self._w.write_frames(extra_frames)
        self._steps.write(block)
        if self._smooth is not None and self._smooth_topic is not None and len(block):
            self._smooth_topic.write(block.t_ns, smoothed_columns(self._smooth.rows_for(block)))

    def close(self) -> None:
        self._w.close()

    def abort(self, keep: bool = False) -> None:
        """The replay failed: close and remove the incomplete recording (``keep``: leave it, without
        its summary: it reads up to its last complete chunk)."""
        self._w.abort(keep)

    def __enter__(self) -> RecordingWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _output_frames(b: StepBlock, ids: np.ndarray, lens: np.ndarray) -> FrameBatch:
    n, k = len(b), len(ids)
    return FrameBatch(
        t_ns=np.repeat(b.t_ns, k),
        can_id=np.tile(ids, n),
        is_extended=np.zeros(n * k, np.bool_),
        dlc=np.tile(lens, n),
        data=b.frames.reshape(n * k, 8),
        is_rx=np.zeros(n * k, np.bool_),
    )


def output_frames(res: ReplayResult, profile: Profile) -> FrameBatch:
    """lde's sent frames per step as the engine encoded them (:data:`lde.engine.engine.OUTPUT_MESSAGES`:
    ``LDE_Estimate`` then ``LDE_Overlay``), stamped with the step time, ``is_rx`` False."""
    ids = np.array([profile.spec(m).frame_id for m in OUTPUT_MESSAGES], np.uint32)
    lens = np.array([profile.spec(m).length for m in OUTPUT_MESSAGES], np.uint8)
    return _output_frames(res.block, ids, lens)


def write_recording(
    path: str | Path,
    frames: FrameBatch,
    res: ReplayResult,
    profile: Profile,
    *,
    metadata: dict[str, str] | None = None,
    extra_frames: FrameBatch | None = None,
) -> None:
    """An lde MCAP recording of a replay (:class:`RecordingWriter` over all of it at once).
    ``extra_frames`` are recorded too (``/can/rx`` or ``/can/tx`` by their ``is_rx``)."""
    with RecordingWriter(path, profile, metadata) as w:
        rx = frames.select(frames.is_rx) if not frames.is_rx.all() else frames
        w._w.write_frames(rx)
        w.write_block(res.block, extra_frames)
