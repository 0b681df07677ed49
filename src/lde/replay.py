"""Batch replay: a log through the one data path (:class:`lde.engine.Engine`) -> CSV / MCAP.

Replay runs exactly what the live service runs (:mod:`lde.pipeline`): the same receiver, grid,
corrections, estimator backend, output finalisation, overlay limiter and output encoding, over the
log's received frames (``is_rx``; lde's own sent frames in a recording are left out) in time order.

Step times are the anchored grid of :mod:`lde.grid` (from the first accepted MDPS frame; a silence
of the inputs longer than :data:`lde.grid.MAX_GAP_NS` starts a new segment), or, for an lde
recording (``/can/tx`` and ``/lde/estimate`` present), the recorded step times together with the
recorded overlay enable input and deadline-miss bits (``/lde/events``), so that a live run is
reproduced exactly. :attr:`ReplayResult.duration_s` is the stepped time (steps x 3.9 ms) and
:attr:`ReplayResult.segments` counts the grid's segments; ``t`` keeps each segment's own time base.

The CAN profile of a replay is the one given; when none is given (:func:`replay_log` with
``profile=None``, ``lde replay`` without ``--profile``), the one named in the log's ``lde`` metadata
record (:func:`recorded_profile`: lde recordings, ``lde sim --mcap`` files), else ``lde``.

Outputs: :func:`write_csv` (one row per step; ``t`` in seconds in the log's own time base) and
:func:`write_recording` (an MCAP recording that itself replays to the same estimates, written with
the live recorder's topic definitions, :class:`lde.recording.StepTopicWriter`).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .backends import get_backend
from .e2e import ReceiverStats
from .engine import OUTPUT_MESSAGES, Engine, StepBlock
from .errors import ConfigError, LogFormatError
from .frames import FrameBatch
from .grid import MAX_GAP_NS, InputGrid
from .logio import LogData, McapWriter, read_log
from .logio.textfmt import Column, format_rows, time_column
from .params import Vehicle
from .profiles import PROFILE_NAMES, Profile, load_profile
from .recording import ESTIMATE_TOPIC, EVENTS_TOPIC, StepTopicWriter
from .status import DEADLINE_MISS, VALID
from .units import STEP_NS

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
    "resolve_backend",
    "write_csv",
    "write_recording",
    "output_frames",
    "CSV_COLUMNS",
    "DEFAULT_BACKEND",
]

#: the backend of ``lde replay`` / ``lde run`` when none is named (SPEC section 4)
DEFAULT_BACKEND = "fixed"

#: CSV columns: name, decimals, unit/meaning (the first four are the SPEC's contract)
CSV_COLUMNS: tuple[tuple[str, int, str], ...] = (
    ("t", 6, "s, step time in the log's own time base"),
    ("Fw", 3, "N, disturbance force at the CG, left positive"),
    ("Mw", 3, "Nm, disturbance yaw moment, left positive"),
    ("T_overlay", 4, "Nm, overlay torque request at the column, left positive"),
    ("T_align", 4, "Nm, estimated aligning torque at the steering axis, paper sign"),
    ("status", 0, "LDE_Estimate.Status bit map"),
    ("overlay_state", 0, "0 off, 1 ramp-in, 2 active, 3 ramp-out, 4 fault"),
    ("beta", 7, "rad, estimated side slip"),
    ("yaw_rate", 6, "rad/s, estimated yaw rate"),
    ("speed", 4, "m/s, input speed (sample-and-hold)"),
    ("mdps_ok", 0, "1: MDPS inputs fresh and trusted"),
    ("esc_ok", 0, "1: ESC inputs fresh and trusted"),
)


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class FrameCounts:
    """Frames of a replay: total, lde's own (tx, not inputs), ignored ids, per input message
    (:class:`lde.e2e.ReceiverStats`: received = used + rejected + resync; malformed apart)."""

    total: int
    tx: int
    ignored: int
    messages: dict[str, ReceiverStats]

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
        block: the engine's rows (:class:`lde.engine.StepBlock`: every column, the output frames).
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
        """Runs of steps with no gap longer than :data:`lde.grid.MAX_GAP_NS` between consecutive
        steps (the grid's segments; 1 for an ordinary log, 0 without steps)."""
        if len(self) == 0:
            return 0
        return 1 + int(np.count_nonzero(np.diff(self.t_ns) > MAX_GAP_NS))


# ----------------------------------------------------------------------------- backends
def resolve_backend(backend: str | None) -> tuple[str, Callable[..., Any], str]:
    """(name, the backend's array-API ``run_batch``, note) from the registry (:mod:`lde.backends`);
    ``None`` is :data:`DEFAULT_BACKEND`. An unknown name raises ConfigError (never a fallback)."""
    b = get_backend(DEFAULT_BACKEND if backend is None else backend)
    return b.name, b.run_batch, ""


# ----------------------------------------------------------------------------- the path
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
) -> ReplayResult:
    """Replay ``frames`` (any order) through the data path.

    Args:
        frames: the log's frames; only received ones (``is_rx``) are inputs.
        profile: CAN profile (:func:`lde.profiles.load_profile`).
        vehicle: parameters and tuning (:func:`lde.params.load_vehicle`).
        backend: a registered backend name (None: :data:`DEFAULT_BACKEND`).
        step_times_ns: explicit step times (a recording's; non-decreasing); default the anchored grid.
        tx_frames: the log's count of frames lde sent, when the reader did not return them all.
        overlay_enable: the overlay limiter's enable input per step of ``step_times_ns`` (a
            recording's, so that a run ended by a signal replays exactly); default all on.
        extra_status: status bits to add per step of ``step_times_ns`` (a recording's DEADLINE_MISS).
    """
    name = DEFAULT_BACKEND if backend is None else backend
    t0 = time.perf_counter()
    engine = Engine(profile, vehicle, name, explicit=step_times_ns is not None)
    fs = frames.sort()
    n_tx = int(np.count_nonzero(~fs.is_rx))
    if step_times_ns is not None:
        steps = np.ascontiguousarray(step_times_ns, np.int64)
        if overlay_enable is not None and len(overlay_enable) != len(steps):
            overlay_enable = None  # not these steps: all on
        if extra_status is not None and len(extra_status) != len(steps):
            extra_status = None
        block = engine.feed(
            fs, step_times=steps, enable=overlay_enable, extra_status=extra_status, final=True
        )
    else:
        block = engine.feed(fs, final=True)
    t1 = time.perf_counter()
    counts = FrameCounts(
        total=len(fs),
        tx=n_tx if tx_frames is None else tx_frames,
        ignored=engine.n_ignored,
        messages=engine.stats(),
    )
    return ReplayResult.of(
        block, counts, engine.backend.name, recorded_steps=step_times_ns is not None,
        timings={"engine": t1 - t0},
    )  # fmt: skip


def recorded_step_times(log: LogData) -> np.ndarray | None:
    """Step times of an lde recording: the log times of ``/lde/estimate`` (the recorders' contract:
    log time = the step time t_k, exact in ns), when the file has ``/can/tx`` and a non-empty
    ``/lde/estimate``; None for any other log."""
    m = log.mcap
    if m is None or ESTIMATE_TOPIC not in m.topics or "/can/tx" not in m.topics:
        return None
    if m.topics[ESTIMATE_TOPIC].count == 0:
        return None
    return np.asarray(m.times[ESTIMATE_TOPIC], np.int64)


def recorded_events(
    log: LogData, step_times_ns: np.ndarray | None
) -> tuple[np.ndarray | None, np.ndarray | None]:
    """(overlay enable, extra status) at each recorded step from the sparse ``/lde/events`` channel:
    the limiter's enable input sample-and-hold (an event at t_k applies from step t_k on) and
    DEADLINE_MISS at the steps whose event says so. (None, None) when the log has no events."""
    m = log.mcap
    if m is None or step_times_ns is None or EVENTS_TOPIC not in m.json:
        return None, None
    ev = m.json[EVENTS_TOPIC]
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
    """The ``lde`` metadata entries that name ``profile`` in a recording: ``profile`` (its name)
    and, for a profile loaded from a DBC file of the user's, ``profile_dbc`` (that file's path)."""
    out = {"profile": profile.name}
    if profile.name not in PROFILE_NAMES:
        out["profile_dbc"] = str(Path(profile.dbc_path).resolve())
    return out


def recorded_profile(log: LogData) -> str | None:
    """The CAN profile an MCAP log says it was made with, as :func:`lde.profiles.load_profile`
    takes it: ``profile_dbc`` of its ``lde`` metadata record when that file exists, else the shipped
    profile named ``profile``; None when the log names none (candump, ASC, ... or a foreign MCAP).

    Raises:
        ConfigError: the log names a profile that cannot be found here (a DBC file of another
            machine): give ``--profile``.
    """
    meta = log.mcap.metadata.get("lde", {}) if log.mcap is not None else {}
    name, dbc = meta.get("profile", ""), meta.get("profile_dbc", "")
    if dbc and Path(dbc).is_file():
        return dbc
    if name in PROFILE_NAMES and not dbc:
        return name
    if name or dbc:
        raise ConfigError(
            f"{log.path}: recorded with CAN profile {name or dbc!r}"
            + (f" (DBC {dbc}, not found)" if dbc else " (not a shipped profile)")
            + ": give --profile (lde, hyundai or the .dbc path)"
        )
    return None


def no_valid_note(res: ReplayResult) -> str | None:
    """A one-line explanation when a replay has steps but not one VALID estimate (all zeros: most
    often the wrong CAN profile), else None."""
    if len(res) == 0 or np.any(res.status & VALID):
        return None
    anchor = res.profile.anchor_message if res.profile is not None else ""
    m = res.frames.messages.get(anchor)
    if m is None or m.received == 0:
        why = f"no {anchor or 'MDPS'} frames of this profile in the log"
    elif m.used == 0:
        why = f"all {m.received} {anchor} frames rejected (E2E/length)"
    else:
        why = f"{anchor} frames used {m.used} of {m.received}; the estimate never became valid"
    if res.profile is None:
        return f"no valid estimate: {why}"
    where = {"given": "given", "recording": "from the recording", "default": "the default"}
    origin = where.get(res.profile_origin, res.profile_origin)
    return f"no valid estimate: {why} — wrong --profile? (used {res.profile.name}, {origin})"


def replay_log(
    path: str | Path,
    profile: Profile | None,
    vehicle: Vehicle,
    backend: str | None = "float",
    *,
    use_recorded_steps: bool = True,
    profiles: dict[str, Profile] | None = None,
) -> tuple[LogData, ReplayResult]:
    """Read a log (any format of :func:`lde.logio.read_log`) and replay it.

    An lde recording is replayed on its recorded step times unless ``use_recorded_steps`` is False.
    ``profile`` None: the profile the log names (:func:`recorded_profile`), else ``lde``;
    ``profiles`` caches loaded profiles by name across calls.

    Raises:
        LogFormatError: unreadable log. ConfigError: a recorded profile that cannot be loaded.
    """
    t0 = time.perf_counter()
    log = read_log(Path(path), skip_tx=True, json_topics=[EVENTS_TOPIC], json_optional=True)
    origin = "given"
    if profile is None:
        key = recorded_profile(log)
        origin = "recording" if key else "default"
        key = key or "lde"
        cache = profiles if profiles is not None else {}
        if key not in cache:
            cache[key] = load_profile(key)
        profile = cache[key]
    steps = recorded_step_times(log) if use_recorded_steps else None
    enable, extra = recorded_events(log, steps)
    n_tx = None
    if log.mcap is not None and "/can/tx" in log.mcap.topics:
        n_tx = log.mcap.topics["/can/tx"].count
    t1 = time.perf_counter()
    res = replay(
        log.frames,
        profile,
        vehicle,
        backend,
        step_times_ns=steps,
        tx_frames=n_tx,
        overlay_enable=enable,
        extra_status=extra,
    )
    res.timings = {"read": t1 - t0, **res.timings}
    res.profile, res.profile_origin = profile, origin
    return log, res


# ----------------------------------------------------------------------------- outputs
def _csv_columns(res: ReplayResult) -> list[Column]:
    data: dict[str, np.ndarray] = {
        "Fw": res.fw,
        "Mw": res.mw,
        "T_overlay": res.t_overlay,
        "T_align": res.t_align,
        "status": res.status,
        "overlay_state": res.overlay_state,
        "beta": res.beta,
        "yaw_rate": res.yaw_rate,
        "speed": res.grid.speed,
        "mdps_ok": res.grid.mdps_ok,
        "esc_ok": res.grid.esc_ok,
    }
    cols = [time_column("t", res.t_ns)]
    cols += [Column(name, data[name], dec) for name, dec, _ in CSV_COLUMNS[1:]]
    return cols


def write_csv(path: str | Path, res: ReplayResult) -> None:
    """CSV with a header and one row per step (columns :data:`CSV_COLUMNS`; NaN as ``nan``).

    ``t`` is the step time in seconds in the log's own time base, printed exactly from the integer
    ns (6 decimals when all step times are whole microseconds, else 9).
    """
    cols = _csv_columns(res)
    text, _ = format_rows(cols, [""] + [","] * (len(cols) - 1), "\n")
    try:
        with open(path, "wb") as fh:
            fh.write((",".join(c.name for c in cols) + "\n").encode())
            fh.write(text.data)
    except OSError as exc:
        raise LogFormatError(f"{path}: cannot write: {exc}") from exc


def output_frames(res: ReplayResult, profile: Profile) -> FrameBatch:
    """lde's sent frames per step as the engine encoded them (:data:`lde.engine.OUTPUT_MESSAGES`:
    ``LDE_Estimate`` then ``LDE_Overlay``), stamped with the step time, ``is_rx`` False."""
    b = res.block
    n, k = len(b), len(OUTPUT_MESSAGES)
    ids = np.array([profile.spec(m).frame_id for m in OUTPUT_MESSAGES], np.uint32)
    lens = np.array([profile.spec(m).length for m in OUTPUT_MESSAGES], np.uint8)
    return FrameBatch(
        t_ns=np.repeat(b.t_ns, k),
        can_id=np.tile(ids, n),
        is_extended=np.zeros(n * k, np.bool_),
        dlc=np.tile(lens, n),
        data=b.frames.reshape(n * k, 8),
        is_rx=np.zeros(n * k, np.bool_),
    )


def write_recording(
    path: str | Path,
    frames: FrameBatch,
    res: ReplayResult,
    profile: Profile,
    *,
    metadata: dict[str, str] | None = None,
    extra_frames: FrameBatch | None = None,
) -> None:
    """An lde MCAP recording of a replay: the input frames (``/can/rx``), the frames lde sends
    (``/can/tx``), and the recorder's step topics (:class:`lde.recording.StepTopicWriter`).

    Replaying it (:func:`replay_log`) uses the recorded step times and gives the same estimates.
    ``extra_frames`` are recorded too (``/can/rx`` or ``/can/tx`` by their ``is_rx``).
    """
    rx = frames.select(frames.is_rx) if not frames.is_rx.all() else frames
    with McapWriter(path, metadata=metadata) as w:
        w.write_frames(rx)
        w.write_frames(output_frames(res, profile))
        if extra_frames is not None:
            w.write_frames(extra_frames)
        StepTopicWriter(w).write(res.block)
