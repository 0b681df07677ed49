"""Replays of many logs: one job per log, in this process or on a ``dask.distributed`` cluster.

:func:`replay_job` is what ``lde replay`` runs for one log (open the log, stream it through the
data path into its CSV / MCAP outputs, report); :func:`run_jobs` runs a list of them in this
process, :func:`lde.replay.fleet_dask.run_jobs_on_dask` maps them on a cluster: a ``LocalCluster`` of
``n_workers`` processes (``lde replay --jobs N``) or an existing scheduler by address
(``--scheduler ADDR``: ``dask scheduler`` and ``dask worker ADDR`` processes on any machines that
see the logs, the output directories and lde under the same paths; kept apart because importing
``distributed`` costs ~0.5 s of every start-up). The same function runs everywhere, so a fleet
gives the same files as one replay after another. Each job returns a :class:`LogReport` (a failed
log is a report with its error, the others go on); :func:`summary_table` prints them.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lde.can.profiles import load_profile
from lde.errors import LdeError, OutputError
from lde.io import REORDER_WINDOW_NS, describe_skipped
from lde.params import load_vehicle
from lde.replay.replay import (
    CsvWriter,
    RecordingWriter,
    end_note,
    gaps_note,
    late_note,
    no_valid_note,
    profile_metadata,
    read_inputs,
    resolve_backend,
    run_replay,
)
from lde.replay.smoother import SmoothTrack, check_backend, smooth_run
from lde.units import STEP_NS

__all__ = ["ReplayJob", "LogReport", "replay_job", "run_jobs", "summary_table", "progress_bar", "job_done"]


@dataclass(frozen=True)
class ReplayJob:
    """One log to replay and where its outputs go (paths as the worker sees them).

    ``profile`` None: the profile the log names, else ``lde``; ``vehicle``: a TOML path or a
    shipped name; ``reorder_window_ns`` None: text logs sorted whole; ``learned``: a learned-state
    file read at the start (when it exists) and written at the end (:func:`lde.replay.replay.run_replay`).
    """

    log: Path
    csv: Path | None = None
    mcap: Path | None = None
    profile: str | None = None
    vehicle: str = "reference"
    backend: str | None = None
    use_recorded_steps: bool = True
    reorder_window_ns: int | None = REORDER_WINDOW_NS
    mcap_index: bool = False
    learned: Path | None = None
    smooth: bool = False  # also the RTS smoother's columns / topic (lde.replay.smoother): a second pass
    # the log read one piece ahead and the CSV written in threads of their own (on a spare core);
    # off where every core already replays a log of its own (a Dask worker: lde.replay.fleet_dask)
    helper_threads: bool = True


@dataclass
class LogReport:
    """What one replay did (``error``: why it failed; the other fields are then empty)."""

    log: Path
    error: str = ""
    format: str = ""
    frames: int = 0
    used: int = 0
    rejected: int = 0
    rejected_by_cause: dict[str, int] = field(default_factory=dict)
    resync: int = 0
    ignored: int = 0
    #: frames of input messages on another bus than the one each is read from (not used)
    other_bus: int = 0
    #: the bus each input message was read from, when the log names buses
    buses: dict[str, str] = field(default_factory=dict)
    tx: int = 0
    steps: int = 0
    valid_steps: int = 0
    segments: int = 0
    recorded_steps: bool = False
    skipped: dict[str, int] = field(default_factory=dict)
    profile: str = ""
    profile_origin: str = ""
    backend: str = ""
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    host: str = ""
    learned: str = ""  # what the learner holds at the end (empty without a learner)
    learned_origin: str = ""  # where learning started: a --learned file, the recording, "" (vehicle)
    stopped: bool = False  # stopped by a signal before the end of the log (outputs closed, partial)
    last_step_ns: int | None = None  # the time of the last step [ns]
    #: what the reader skipped, in words, with line numbers or byte offsets (lde.io.describe_skipped)
    not_read: list[str] = field(default_factory=list)
    #: the files this replay wrote: (what, path), e.g. ("CSV", "/data/x.csv")
    written: list[tuple[str, str]] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return not self.error

    @property
    def error_line(self) -> str:
        """The error naming the log once (most errors start with its path already)."""
        return self.error if self.error.startswith(str(self.log)) else f"{self.log}: {self.error}"

    @property
    def usable(self) -> bool:
        """Replayed, and at least one step gave a VALID estimate (else the outputs hold nothing
        usable: the exit code says so)."""
        return self.ok and self.valid_steps > 0

    @property
    def duration_s(self) -> float:
        """Stepped time [s]."""
        return self.steps * STEP_NS * 1e-9


_SKIPPED = (
    "error_frames",
    "remote_frames",
    "malformed_lines",
    "truncated_last_line",
    "bad_messages",
    "late_frames",
)


def replay_job(job: ReplayJob, stop: Callable[[], bool] | None = None) -> LogReport:
    """Replay one log into its outputs (removed again if the replay fails). A user's mistake or
    a bad log is reported in :attr:`LogReport.error`, never raised. ``stop`` (in process: a
    signal): asked between pieces; True ends the replay there with its outputs closed
    (:attr:`LogReport.stopped`)."""
    t0 = time.perf_counter()
    rep = LogReport(job.log, host=socket.gethostname())
    try:
        _replay(job, rep, stop)
    except LdeError as exc:
        rep.error = str(exc)
    rep.seconds = time.perf_counter() - t0
    return rep


#: per process: profiles and vehicles loaded once (a worker replays many logs)
_PROFILES: dict[str, Any] = {}
_VEHICLES: dict[str, Any] = {}


def _replay(job: ReplayJob, rep: LogReport, stop: Callable[[], bool] | None = None) -> None:
    profile = None
    if job.profile is not None:
        if job.profile not in _PROFILES:
            _PROFILES[job.profile] = load_profile(job.profile)
        profile = _PROFILES[job.profile]
    if job.vehicle not in _VEHICLES:
        _VEHICLES[job.vehicle] = load_vehicle(job.vehicle)
    vehicle = _VEHICLES[job.vehicle]
    backend = resolve_backend(job.backend)
    track = _smoothed(job, profile, vehicle, backend) if job.smooth else None
    try:
        _replay_outputs(job, rep, profile, vehicle, backend, track, stop)
    finally:
        if track is not None:
            track.close()
    if track is not None:
        rep.timings.update(track.timings or {})
        if track.bad:
            rep.warnings.append(
                f"--smooth: at {track.bad} steps the predicted covariance was not positive definite;"
                " the smoothed value there is the filtered one"
            )


def _inputs(job: ReplayJob, profile: Any) -> Any:
    """The job's log opened for the data path (its own stream each call: the smoother and the
    causal replay each read it once)."""
    return read_inputs(
        job.log,
        profile,
        use_recorded_steps=job.use_recorded_steps,
        profiles=_PROFILES,
        reorder_window_ns=job.reorder_window_ns,
    )


def _smoothed(job: ReplayJob, profile: Any, vehicle: Any, backend: str) -> SmoothTrack:
    """The smoother's forward and backward passes over the job's log (opened on its own: the causal
    replay reads it again, on the same step grid)."""
    check_backend(backend)
    li = _inputs(job, profile)
    with li.stream as stream:
        return smooth_run(
            stream,
            li.profile,
            vehicle,
            step_times_ns=li.step_times_ns,
            overlay_enable=li.overlay_enable,
            extra_status=li.extra_status,
            learned=job.learned,
            learned_start=li.learned_start,
        )


def _replay_outputs(
    job: ReplayJob,
    rep: LogReport,
    profile: Any,
    vehicle: Any,
    backend: str,
    track: SmoothTrack | None,
    stop: Callable[[], bool] | None = None,
) -> None:
    li = _inputs(job, profile)
    sinks: list[Any] = []
    try:
        if job.csv is not None:
            sinks.append(CsvWriter(job.csv, smooth=track, background=job.helper_threads))
        if job.mcap is not None:
            meta = {
                "source": str(job.log),
                **profile_metadata(li.profile),
                "vehicle": vehicle.name,
                "backend": backend,
            }
            if track is not None:
                meta["smooth"] = "RTS, float lateral filter"
            sinks.append(RecordingWriter(job.mcap, li.profile, meta, indexed=job.mcap_index, smooth=track))
        res = run_replay(
            li.stream,
            li.profile,
            vehicle,
            backend,
            sinks=tuple(sinks),
            step_times_ns=li.step_times_ns,
            tx_frames=li.tx_frames,
            overlay_enable=li.overlay_enable,
            extra_status=li.extra_status,
            output_frames=job.mcap is not None,
            read_ahead=job.helper_threads,
            learned=job.learned,
            learned_start=li.learned_start,
            stop=stop,
        )
        tc = time.perf_counter()
        for sink in sinks:
            sink.close()  # waits for a writer thread's last blocks
        res.timings["outputs"] += time.perf_counter() - tc
    except OutputError as exc:  # disk full: what was written stays, readable up to its last record
        for sink in sinks:
            sink.abort(keep=True)
        kept = ", ".join(str(s.path) for s in sinks)
        how = " (an MCAP file reads up to its last complete chunk)" if job.mcap is not None else ""
        raise OutputError(f"{exc}; replay stopped, what was written is kept in {kept}{how}") from exc
    except BaseException:
        for sink in sinks:
            sink.abort()
        raise
    finally:
        li.stream.close()
    res.profile, res.profile_origin = li.profile, li.profile_origin
    stats = li.stream.stats
    f = res.frames
    rep.format = li.stream.format
    rep.frames, rep.used, rep.rejected, rep.resync = f.total, f.used, f.rejected, f.resync
    rep.rejected_by_cause = f.rejected_by_cause()
    rep.ignored, rep.tx = f.ignored, f.tx
    rep.other_bus, rep.buses = f.other_bus, {m: b for m, b in f.buses.items() if b}
    rep.steps, rep.valid_steps, rep.segments = res.steps, res.valid_steps, res.segments
    rep.recorded_steps = res.recorded_steps
    rep.skipped = {k: int(getattr(stats, k)) for k in _SKIPPED if getattr(stats, k)}
    rep.profile, rep.profile_origin, rep.backend = li.profile.name, li.profile_origin, res.backend
    rep.timings = {"open": li.read_s, **res.timings}
    rep.learned, rep.learned_origin = res.learned, res.learned_origin
    rep.stopped, rep.last_step_ns = res.stopped, res.last_step_ns
    rep.not_read = describe_skipped(stats, li.stream.end)
    rep.written = _written(job)
    if res.stopped:  # the end of the file was not read: nothing to say about it
        rep.warnings = [stopped_note(rep)]
        return
    notes = (end_note(li.stream), no_valid_note(res), gaps_note(res), late_note(stats, job.reorder_window_ns))
    rep.warnings = [w for w in notes if w]


def _written(job: ReplayJob) -> list[tuple[str, str]]:
    """The files a replay that ended wrote: (what, path)."""
    smooth = job.smooth
    out = []
    if job.csv is not None:
        out.append(("CSV" + (" (with the *_smooth columns)" if smooth else ""), str(job.csv)))
    if job.mcap is not None:
        out.append(("MCAP" + (" (with /lde/smooth)" if smooth else ""), str(job.mcap)))
    if job.learned is not None:
        out.append(("learned state", str(job.learned)))
    return out


def stopped_note(rep: LogReport) -> str:
    """The warning of a replay stopped by a signal: where, and what its outputs hold."""
    t = rep.last_step_ns
    at = "before its first step" if t is None else f"at log time {t / 1e9:.6f} s"
    return (
        f"stopped by a signal {at}: the outputs are closed and hold the {rep.steps} steps replayed so far;"
        " the rest of the log was not replayed"
    )


def run_jobs(
    jobs: Sequence[ReplayJob],
    *,
    progress: bool = True,
    on_report: Callable[[LogReport], None] | None = None,
    stop: Callable[[], bool] | None = None,
) -> list[LogReport]:
    """Every job in this process, one after the other (:func:`lde.replay.fleet_dask.run_jobs_on_dask`
    maps them on a cluster); reports in the order of ``jobs``. ``on_report`` sees each report as
    it ends. ``stop`` (a signal): the running replay ends with its outputs closed, the logs after
    it are not replayed (no report)."""
    bar = progress_bar(progress, len(jobs))
    try:
        out = []
        for job in jobs:
            if stop is not None and stop():
                break
            rep = replay_job(job, stop)
            out.append(rep)
            job_done(bar, rep, on_report)
        return out
    finally:
        if bar is not None:
            bar.close()


def progress_bar(enabled: bool, total: int) -> Any:
    """A tqdm bar over ``total`` logs (None when not ``enabled``)."""
    if not enabled:
        return None
    from tqdm import tqdm  # only with a bar: one log replays without importing it

    return tqdm(total=total, unit="log", desc="lde replay")


def job_done(bar: Any, rep: LogReport, on_report: Callable[[LogReport], None] | None) -> None:
    if bar is not None:
        bar.update(1)
    if on_report is not None:
        on_report(rep)


def summary_table(reports: Iterable[LogReport]) -> str:
    """One line per log (frames, steps, valid share, rejected, seconds, host) and a total. A failed
    log is a row marked ``error``; its error (:attr:`LogReport.error_line`) is said where it
    happened, not again here."""
    reps = list(reports)
    head = ("log", "format", "frames", "steps", "valid %", "rejected", "seconds", "host")
    rows = []
    for r in reps:
        if not r.ok:
            rows.append((r.log.name, "error", "", "", "", "", f"{r.seconds:.2f}", r.host))
            continue
        valid = 100.0 * r.valid_steps / r.steps if r.steps else 0.0
        rows.append(
            (
                r.log.name,
                r.format,
                str(r.frames),
                str(r.steps),
                f"{valid:.1f}",
                str(r.rejected),
                f"{r.seconds:.2f}",
                r.host,
            )
        )
    ok = [r for r in reps if r.ok]
    rows.append(
        (
            f"{len(reps)} logs",
            f"{len(reps) - len(ok)} failed",
            str(sum(r.frames for r in ok)),
            str(sum(r.steps for r in ok)),
            "",
            str(sum(r.rejected for r in ok)),
            f"{sum(r.seconds for r in reps):.2f}",
            "",
        )
    )
    widths = [max(len(head[i]), *(len(row[i]) for row in rows)) for i in range(len(head))]
    lines = ["  ".join(h.ljust(w) for h, w in zip(head, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    for row in rows[:-1]:
        lines.append("  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)))
    lines.append("  ".join("-" * w for w in widths))
    lines.append("  ".join(c.ljust(w) for c, w in zip(rows[-1], widths, strict=True)))
    return "\n".join(lines)
