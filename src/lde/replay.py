"""Batch replay: log -> FrameBatch -> signals -> 3.9 ms grid -> estimator -> overlay -> CSV / MCAP.

The same semantics as the live service (:mod:`lde.service`), over whole arrays::

    frames (rx only)  --lde.signals.decode_batch-->  accepted samples per input (E2E receiver)
                      --lde.grid.build_grid------->  inputs on the step grid (sample-and-hold)
                      --backend run_batch--------->  Fw, Mw, T_align, status per step
                      --lde.overlay--------------->  T_overlay per step (zeros until lde.overlay has
                                                     ``run_batch_overlay``)

Decoding (:func:`decode`) and the filter loop (:func:`estimate`) are separate functions so that each
can be timed and tested alone; :func:`replay` runs both. Step times are the grid anchored at the
first accepted MDPS frame, or, for an lde recording (``/can/tx`` and ``/lde/estimate`` present), the
recorded step times, so that a live run is reproduced exactly.

Segments: a silence of the inputs longer than :data:`lde.grid.MAX_GAP_NS` (60 s) splits the grid
into segments, each anchored again at its own first MDPS frame (see :mod:`lde.grid`); a log that
joins two time bases (relative and epoch timestamps) thus replays as two segments. The steps then
jump between segments: :attr:`ReplayResult.duration_s` is the stepped time (steps x 3.9 ms) and
:attr:`ReplayResult.segments` counts the segments; ``t`` keeps each segment's own time base.

The CAN profile of a replay is the one given; when none is given (:func:`replay_log` with
``profile=None``, ``lde replay`` without ``--profile``), the one named in the log's ``lde`` metadata
record (:func:`recorded_profile`: lde recordings, ``lde sim --mcap`` files), else ``lde``.

Outputs: :func:`write_csv` (one row per step; ``t`` in seconds in the log's own time base) and
:func:`write_recording` (an MCAP recording that itself replays to the same estimates; its ``lde``
metadata record names the profile, see :func:`profile_metadata`).
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .conditioning import check_profile
from .e2e import E2EStatus
from .errors import ConfigError, LogFormatError
from .frames import FrameBatch
from .grid import MAX_GAP_NS, InputGrid, build_grid
from .logio import LogData, McapWriter, read_log
from .logio.textfmt import Column, format_rows, time_column
from .params import Vehicle
from .profiles import PROFILE_NAMES, Profile, load_profile

# the recording format's channels and field names are lde.recording's (one definition)
from .recording import DIAG_TOPIC, ESTIMATE_TOPIC, EVENTS_TOPIC, INPUT_FIELDS, INPUTS_TOPIC, STATUS_BITS
from .signals import Decoded, decode_batch
from .units import STEP_NS

__all__ = [
    "ReplayResult",
    "FrameCounts",
    "decode",
    "estimate",
    "replay",
    "replay_log",
    "recorded_step_times",
    "recorded_profile",
    "profile_metadata",
    "no_valid_note",
    "resolve_backend",
    "receiver_diag",
    "write_csv",
    "write_recording",
    "CSV_COLUMNS",
    "ESTIMATE_TOPIC",
    "INPUTS_TOPIC",
    "DIAG_TOPIC",
]

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
class MessageCounts:
    """Receiver counts of one input message over the replay."""

    received: int
    used: int
    lost: int
    repeated: int
    wrong_sequence: int
    wrong_crc: int
    malformed: int

    @property
    def rejected(self) -> int:
        return self.repeated + self.wrong_sequence + self.wrong_crc + self.malformed


@dataclass(frozen=True)
class FrameCounts:
    """Frames of a replay: total, lde's own (tx, not inputs), ignored ids, per input message."""

    total: int
    tx: int
    ignored: int
    messages: dict[str, MessageCounts]

    @property
    def used(self) -> int:
        return sum(m.used for m in self.messages.values())

    @property
    def rejected(self) -> int:
        return sum(m.rejected for m in self.messages.values())

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
        t_ns: int64 step times [ns], the log's own time base.
        fw [N], mw [Nm], t_align [Nm], t_overlay [Nm], beta [rad], yaw_rate [rad/s]: float64.
        status: uint8 ``LDE_Estimate.Status`` bits.
        overlay_state: uint8 limiter state; overlay_active: bool.
        grid: the estimator inputs on the grid.
        frames: frame counts (used / rejected by cause).
        backend: ``"float"`` or ``"fixed"``; overlay: False when T_overlay is zeros (no lde.overlay).
        recorded_steps: True when the step times came from a recording.
        timings: seconds spent per stage (decode, grid, filter, overlay).
        diag: per-step receiver diagnostics (:func:`receiver_diag`): ``frames_used`` (input frames
            accepted since the previous step), ``e2e_rejects`` (frames rejected since the start).
        profile: the CAN profile used (set by :func:`replay_log`; None from :func:`replay`).
        profile_origin: where it came from: ``"given"``, ``"recording"`` (the log's ``lde``
            metadata record) or ``"default"`` (``lde``); empty from :func:`replay`.
    """

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
    overlay: bool
    recorded_steps: bool = False
    timings: dict[str, float] = field(default_factory=dict)
    diag: dict[str, np.ndarray] = field(default_factory=dict)
    profile: Profile | None = None
    profile_origin: str = ""

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
    """(name, run_batch, note). ``None`` -> ``fixed`` if :mod:`firmware_model` has ``run_batch``,
    else ``float`` with a note. Unknown names and an unavailable ``fixed`` raise ConfigError."""
    fixed = None
    try:
        fm = importlib.import_module("firmware_model")
        fixed = getattr(fm, "run_batch", None)
    except ImportError:
        fm = None
    if backend is None:
        if fixed is not None:
            return "fixed", fixed, ""
        from .step import run_batch

        return "float", run_batch, "fixed-point backend not available (firmware_model.run_batch): using float"
    if backend == "float":
        from .step import run_batch

        return "float", run_batch, ""
    if backend == "fixed":
        if fixed is None:
            raise ConfigError("backend 'fixed' is not available: firmware_model has no run_batch")
        return "fixed", fixed, ""
    raise ConfigError(f"unknown backend {backend!r}: use 'fixed' or 'float'")


# ----------------------------------------------------------------------------- pipeline
def decode(frames: FrameBatch, profile: Profile) -> tuple[Decoded, int]:
    """Decode the received frames (``is_rx``); returns (decoded, number of tx frames left out)."""
    rx = frames.is_rx
    n_tx = int(np.count_nonzero(~rx))
    return decode_batch(profile, frames if n_tx == 0 else frames.select(rx)), n_tx


def _frame_counts(decoded: Decoded, n_tx: int) -> FrameCounts:
    msgs = {}
    for name, m in decoded.messages.items():
        s = m.stats
        msgs[name] = MessageCounts(
            received=s.received,
            used=s.used,
            lost=s.lost,
            repeated=s.repeated,
            wrong_sequence=s.wrong_sequence,
            wrong_crc=s.wrong_crc,
            malformed=s.malformed,
        )
    return FrameCounts(total=decoded.n_frames + n_tx, tx=n_tx, ignored=decoded.n_ignored, messages=msgs)


_REJECTED = (E2EStatus.REPEATED, E2EStatus.WRONGSEQUENCE, E2EStatus.WRONGCRC)


def receiver_diag(decoded: Decoded, t_ns: np.ndarray) -> dict[str, np.ndarray]:
    """Per step k (time t_k): ``frames_used`` = input frames accepted in (t_{k-1}, t_k] (all up to
    t_0 for the first step) and ``e2e_rejects`` = frames rejected (E2E repeated / wrong sequence /
    wrong CRC, or a wrong length) with time <= t_k, like the live service's ``LDE_Diag``."""
    t = np.asarray(t_ns, np.int64)
    used = np.zeros(t.size, np.int64)
    rejects = np.zeros(t.size, np.int64)
    for m in decoded.messages.values():
        acc_t = m.t_ns[m.accepted]
        used += np.searchsorted(acc_t, t, side="right")
        bad_t = np.sort(np.concatenate([m.t_ns[np.isin(m.status, _REJECTED)], m.malformed_t_ns]))
        rejects += np.searchsorted(bad_t, t, side="right")
    frames_used = np.diff(used, prepend=0)
    return {"frames_used": frames_used, "e2e_rejects": rejects}


def estimate(grid: InputGrid, vehicle: Vehicle, run_batch: Callable[..., Any]) -> Any:
    """The filter loop over the grid (a backend's ``run_batch``) -> its BatchResult."""
    return run_batch(
        grid.t_ns,
        grid.speed,
        grid.steering_angle,
        grid.yaw_rate,
        grid.column_torque,
        grid.assist_torque,
        grid.mdps_ok,
        grid.esc_ok,
        vehicle,
        steering_rate=grid.steering_rate,
    )


def _overlay(
    est: Any, grid: InputGrid, vehicle: Vehicle, enable: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
    """T_overlay [Nm], limiter state, active per step from :func:`lde.overlay.run_batch_overlay` (the
    live limiter's kernel), or zeros when :mod:`lde.overlay` is not there. ``enable``: the limiter's
    enable input per step (a recording's, see :func:`recorded_overlay_enable`; default all on)."""
    n = len(grid)
    try:
        from .overlay import run_batch_overlay
    except ImportError:
        return np.zeros(n), np.zeros(n, np.uint8), np.zeros(n, np.bool_), False
    t_ov, active, state = run_batch_overlay(
        grid.t_ns,
        est.fw,
        est.mw,
        est.status,
        grid.speed,
        grid.steering_angle,
        grid.column_torque,
        vehicle,
        enable=enable,
    )
    return (
        np.asarray(t_ov, np.float64),
        np.asarray(state).astype(np.uint8),
        np.asarray(active).astype(np.bool_),
        True,
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
) -> ReplayResult:
    """Replay ``frames`` (any order) through the estimator.

    Args:
        frames: the log's frames; only received ones (``is_rx``) are inputs.
        profile: CAN profile (:func:`lde.profiles.load_profile`).
        vehicle: parameters and tuning (:func:`lde.params.load_vehicle`).
        backend: ``"float"``, ``"fixed"`` or None (fixed if available, else float).
        step_times_ns: explicit step times (a recording's); default the grid from the first
            accepted MDPS frame to the last frame.
        tx_frames: the log's count of frames lde sent, when the reader did not return them all.
        overlay_enable: the overlay limiter's enable input per step (bool, one per step of
            ``step_times_ns``; a recording's, so that a run ended by a signal replays exactly).
    """
    name, run_batch, _note = resolve_backend(backend)
    check_profile(vehicle, profile.steering_rate_signed, profile.name)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    decoded, n_tx = decode(frames, profile)
    t1 = time.perf_counter()
    grid = build_grid(decoded, profile, step_times_ns=step_times_ns)
    t2 = time.perf_counter()
    est = estimate(grid, vehicle, run_batch)
    t3 = time.perf_counter()
    if overlay_enable is not None and len(overlay_enable) != len(grid):
        overlay_enable = None  # not this grid's steps (e.g. --no-recorded-steps): all on
    t_ov, ov_state, ov_active, have_overlay = _overlay(est, grid, vehicle, overlay_enable)
    t4 = time.perf_counter()
    diag = receiver_diag(decoded, grid.t_ns)
    timings.update(decode=t1 - t0, grid=t2 - t1, filter=t3 - t2, overlay=t4 - t3)
    return ReplayResult(
        t_ns=np.asarray(grid.t_ns, np.int64),
        fw=np.asarray(est.fw, np.float64),
        mw=np.asarray(est.mw, np.float64),
        t_align=np.asarray(est.t_align, np.float64),
        t_overlay=t_ov,
        status=np.asarray(est.status).astype(np.uint8),
        overlay_state=ov_state,
        overlay_active=ov_active,
        beta=np.asarray(est.beta, np.float64),
        yaw_rate=np.asarray(est.yaw_rate, np.float64),
        grid=grid,
        frames=_frame_counts(decoded, n_tx if tx_frames is None else tx_frames),
        backend=name,
        overlay=have_overlay,
        recorded_steps=step_times_ns is not None,
        timings=timings,
        diag=diag,
    )


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


def recorded_overlay_enable(log: LogData, step_times_ns: np.ndarray | None) -> np.ndarray | None:
    """The overlay limiter's enable input at each recorded step, from the sparse ``/lde/events``
    channel (sample-and-hold: an event at t_k applies from step t_k on); None when the log has none."""
    m = log.mcap
    if m is None or step_times_ns is None or EVENTS_TOPIC not in m.json:
        return None
    ev = m.json[EVENTS_TOPIC]
    t_ev = np.asarray(ev.get("log_time", []), np.int64)
    val = np.asarray(ev.get("overlay_enable", []))
    if len(t_ev) == 0 or len(val) != len(t_ev):
        return None
    order = np.argsort(t_ev, kind="stable")
    t_ev, val = t_ev[order], val[order]
    idx = np.searchsorted(t_ev, step_times_ns, side="right") - 1
    return np.where(idx >= 0, val[np.maximum(idx, 0)] != 0, True)


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
    if len(res) == 0 or np.any(res.status & 1):
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
    enable = recorded_overlay_enable(log, steps)
    n_tx = None
    if log.mcap is not None and "/can/tx" in log.mcap.topics:
        n_tx = log.mcap.topics["/can/tx"].count
    t1 = time.perf_counter()
    res = replay(
        log.frames, profile, vehicle, backend, step_times_ns=steps, tx_frames=n_tx, overlay_enable=enable
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


def _json_payloads(columns: list[Column]) -> tuple[np.ndarray, np.ndarray]:
    seps = [("{" if i == 0 else ",") + f'"{c.name}":' for i, c in enumerate(columns)]
    return format_rows(columns, seps, "}", nan_text="null")


def output_frames(res: ReplayResult, profile: Profile) -> FrameBatch:
    """lde's sent frames per step, ``LDE_Estimate`` then ``LDE_Overlay`` (E2E counters and CRCs by
    :func:`lde.codec.encode_batch`), stamped with the step time, ``is_rx`` False."""
    from .codec import encode_batch

    n = len(res)
    est = encode_batch(
        profile,
        "LDE_Estimate",
        {
            "LatForce": np.nan_to_num(res.fw),
            "YawMoment": np.nan_to_num(res.mw),
            "AligningTorque": np.nan_to_num(res.t_align),
            "Status": res.status.astype(np.float64),
        },
    )
    ovl = encode_batch(
        profile,
        "LDE_Overlay",
        {
            "OverlayTorque": np.nan_to_num(res.t_overlay),
            "Active": res.overlay_active.astype(np.float64),
            "State": res.overlay_state.astype(np.float64),
        },
    )
    batches = []
    for name, data in (("LDE_Estimate", est), ("LDE_Overlay", ovl)):
        spec = profile.spec(name)
        batches.append(
            FrameBatch(
                t_ns=res.t_ns,
                can_id=np.full(n, spec.frame_id),
                is_extended=np.zeros(n, np.bool_),
                dlc=np.full(n, spec.length),
                data=data,
                is_rx=np.zeros(n, np.bool_),
            )
        )
    # interleave per step: estimate, overlay (stable sort keeps this order at equal times)
    both = FrameBatch.concat(batches, sort=False)
    order = np.argsort(np.concatenate([np.arange(n) * 2, np.arange(n) * 2 + 1]), kind="stable")
    return both.take(order)


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
    (``/can/tx``), and per step ``/lde/estimate``, ``/lde/inputs``, ``/lde/diag`` (JSON).

    Replaying it (:func:`replay_log`) uses the recorded step times and gives the same estimates.
    ``extra_frames`` are recorded too (``/can/rx`` or ``/can/tx`` by their ``is_rx``).
    """
    rx = frames.select(frames.is_rx) if not frames.is_rx.all() else frames
    with McapWriter(path, metadata=metadata) as w:
        w.write_frames(rx)
        w.write_frames(output_frames(res, profile))
        if extra_frames is not None:
            w.write_frames(extra_frames)
        t = res.t_ns
        bits = {b: (res.status >> i) & 1 for i, b in enumerate(STATUS_BITS)}
        est_cols = [
            Column("t_ns", t, 0),
            time_column("t", t),
            Column("Fw", res.fw, 3),
            Column("Mw", res.mw, 3),
            Column("T_align", res.t_align, 4),
            Column("T_overlay", res.t_overlay, 4),
            Column("overlay_state", res.overlay_state, 0),
            Column("overlay_active", res.overlay_active, 0),
            Column("status", res.status, 0),
            Column("beta", res.beta, 7),
            Column("yaw_rate", res.yaw_rate, 6),
            *[Column(b, v, 0) for b, v in bits.items()],
        ]
        _write_json_channel(w, ESTIMATE_TOPIC, "lde.Estimate", t, est_cols)
        g = res.grid
        in_cols = [Column("t_ns", t, 0)] + [Column(n, g.values(n), 6) for n in INPUT_FIELDS]
        in_cols += [Column("mdps_ok", g.mdps_ok, 0), Column("esc_ok", g.esc_ok, 0)]
        _write_json_channel(w, INPUTS_TOPIC, "lde.Inputs", t, in_cols)
        diag_cols = [Column("t_ns", t, 0), Column("status", res.status, 0)]
        diag_cols += [Column(k, v, 0) for k, v in res.diag.items()]
        _write_json_channel(w, DIAG_TOPIC, "lde.Diag", t, diag_cols)


def _write_json_channel(w: McapWriter, topic: str, title: str, t: np.ndarray, cols: list[Column]) -> None:
    props = {c.name: {"type": "integer" if (c.decimals == 0 and not c.prescaled) else "number"} for c in cols}
    cid = w.add_json_channel(topic, props, title=title)
    text, off = _json_payloads(cols)
    w.write_json_payloads(cid, t, text, off)
