"""Writing a run: candump ``-L`` log, ground-truth CSV, MCAP (frames + ``/truth`` JSON channel).

:class:`SimOutputs` writes whichever of the three are asked for, piece by piece: each
:meth:`SimOutputs.write` appends to the files and :meth:`SimOutputs.sync` pushes what was written to
the OS, so a killed simulator leaves files that read up to their last piece (the candump log and the
CSV up to their last whole line, the MCAP file up to its last chunk, without footer). The pieces do
not change what the text files hold: a run written in pieces gives the bytes of the run written at
once. :class:`Streamer` does that while a :class:`vcan_sim.run.Simulation` runs, with the flush
policy of ``lde run --record``: every :data:`FLUSH_INTERVAL_S` of wall time (live), or after every
piece of the simulation (as fast as possible, deterministic files). :func:`write_outputs` writes a
finished run at once.
"""

from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import IO

import numpy as np

from lde.can.frames import FrameBatch
from lde.can.profiles import Profile
from lde.errors import OutputError
from lde.io import McapWriter
from lde.io.candump import candump_decimals, format_candump_bytes

from .run import SimResult, Simulation
from .truth import TRUTH_COLUMNS, format_truth_rows, truth_csv_names

TRUTH_TOPIC = "/truth"
#: wall time between two flushes of a live run's files [s]: ``lde run --record``'s recorder
#: (``lde.io.recording.Recorder``'s ``flush_interval_s``), so a SIGKILL loses at most about this much
FLUSH_INTERVAL_S = 0.25
#: MCAP chunk bound of a streamed run [bytes, uncompressed]: the recorder's
STREAM_CHUNK_SIZE = 64 * 1024
#: MCAP chunk bound of a run written at once (McapWriter's default: the files of before, byte for byte)
_DEFAULT_CHUNK = 4 << 20


def sim_metadata(scenario: str, seed: int, profile: str | Profile, t0_ns: int) -> dict[str, str]:
    """The MCAP ``lde`` metadata record of a simulated run (a profile file of the user's: its path too,
    :meth:`lde.can.profiles.Profile.metadata`)."""
    return {
        "scenario": scenario,
        "seed": str(seed),
        **(profile.metadata() if isinstance(profile, Profile) else {"profile": profile}),
        "source": "vcan_sim",
        "t0_ns": str(t0_ns),
    }


class SimOutputs:
    """The files of one run, opened now (header lines and records written), appended to piece by piece.

    Args:
        log, truth, mcap: the paths to write (None: not that one).
        profile: the MCAP header's profile; metadata: its ``lde`` record (:func:`sim_metadata`).
        channel: the channel name in the candump lines.
        chunk_size: MCAP chunk bound [bytes, uncompressed] (default: :class:`McapWriter`'s 4 MiB).

    Raises:
        OutputError: a file cannot be created or written (``path: cannot write: reason``); what was
            written before stays readable.
    """

    def __init__(
        self,
        log: str | Path | None = None,
        truth: str | Path | None = None,
        mcap: str | Path | None = None,
        *,
        profile: str = "",
        metadata: Mapping[str, str] | None = None,
        channel: str = "vcan0",
        chunk_size: int | None = None,
    ) -> None:
        self.paths = [Path(p) for p in (log, truth, mcap) if p]
        self.channel = channel
        self._log: IO[bytes] | None = None
        self._csv: IO[bytes] | None = None
        self._mcap: McapWriter | None = None
        self._truth_cid = 0
        self._truth_names: list[str] | None = None
        self._decimals: int | None = None
        self._log_path = Path(log) if log else None
        self._csv_path = Path(truth) if truth else None
        self._closed = False
        self.frames = 0  #: frames written so far
        self.truth_rows = 0  #: truth rows written so far
        try:
            if log:
                self._log = _open(log)
            if truth:
                self._csv = _open(truth)
                # the header now: a file killed before its first row still says what it is
                self._truth_names = truth_csv_names({name: np.zeros(0) for name in TRUTH_COLUMNS})
                self._put(self._csv, truth, (",".join(self._truth_names) + "\n").encode())
            if mcap:
                self._mcap = McapWriter(
                    mcap,
                    profile=profile,
                    metadata=metadata,
                    chunk_size=_DEFAULT_CHUNK if chunk_size is None else int(chunk_size),
                )
                props = {
                    name: {"type": "number", "description": unit} for name, (_, unit) in TRUTH_COLUMNS.items()
                }
                self._truth_cid = self._mcap.add_json_channel(TRUTH_TOPIC, props, title="vcan_sim_truth")
        except BaseException:
            self.abort()
            raise

    @staticmethod
    def _put(fh: IO[bytes], path: str | Path, data: bytes) -> None:
        try:
            fh.write(data)
        except OSError as exc:
            raise OutputError(f"{path}: cannot write: {exc}") from exc

    def write(self, frames: FrameBatch, truth: Mapping[str, np.ndarray], truth_t_ns: np.ndarray) -> None:
        """Append a piece: ``frames`` (after every frame written before, sorted by time) and the truth
        rows at ``truth_t_ns`` [ns] (columns of :data:`vcan_sim.truth.TRUTH_COLUMNS`)."""
        n_truth = int(np.asarray(truth_t_ns).size)
        if self._log is not None and len(frames):
            if self._decimals is None:
                self._decimals = candump_decimals(frames)
            elif self._decimals == 6 and candump_decimals(frames) == 9:
                self._decimals = 9  # a timestamp off the microsecond grid: 9 decimals from here on
            self._put(
                self._log, self._log_path or "", format_candump_bytes(frames, self.channel, self._decimals)
            )
        if self._csv is not None and n_truth:
            self._put(self._csv, self._csv_path or "", format_truth_rows(truth, truth_t_ns).encode())
        if self._mcap is not None:
            self._mcap.write_frames(frames)
            if n_truth:
                self._mcap.write_json_columns(self._truth_cid, truth_t_ns, truth)
        self.frames += len(frames)
        self.truth_rows += n_truth

    def sync(self) -> None:
        """Write what is queued (MCAP chunks) and push every file's buffer to the OS: a SIGKILL after
        this loses nothing written so far (no fsync: a power loss may)."""
        for fh, path in ((self._log, self._log_path), (self._csv, self._csv_path)):
            if fh is not None:
                try:
                    fh.flush()
                except OSError as exc:
                    raise OutputError(f"{path}: cannot write: {exc}") from exc
        if self._mcap is not None:
            self._mcap.sync()

    def close(self) -> None:
        """Write what is queued, the MCAP summary and footer, and close the files (idempotent)."""
        if self._closed:
            return
        try:
            for fh, path in ((self._log, self._log_path), (self._csv, self._csv_path)):
                if fh is not None:
                    try:
                        fh.close()
                    except OSError as exc:
                        raise OutputError(f"{path}: cannot write: {exc}") from exc
            if self._mcap is not None:
                self._mcap.close()
        except BaseException:
            self.abort()
            raise
        self._closed = True

    def abort(self) -> None:
        """Close without the MCAP summary (after a write failed): what was written stays, readable up
        to its last whole line or chunk."""
        if self._closed:
            return
        self._closed = True
        for fh in (self._log, self._csv):
            if fh is not None:
                with contextlib.suppress(OSError):
                    fh.close()
        if self._mcap is not None:
            self._mcap.abort(keep=True)

    def __enter__(self) -> SimOutputs:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def _open(path: str | Path) -> IO[bytes]:
    try:
        return open(path, "wb")  # noqa: SIM115 - closed in SimOutputs.close / abort
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc}") from exc


class Streamer:
    """Writes what a running :class:`Simulation` produces to its :class:`SimOutputs`.

    Live, :meth:`poll` runs after every step. Every ``write_every`` steps it formats the new frames
    and truth rows into the writers' buffers (about 0.3 ms for 8 steps here, in the time the pump
    would sleep), and every ``interval_s`` of wall time it pushes them to the OS
    (:meth:`SimOutputs.sync`: the MCAP chunks are built and compressed then, about 1.3 ms). All at
    once, 0.25 s of truth took 8 ms to format, two MDPS periods: frames would go out late; step by
    step, the per-column overhead of the JSON and CSV formatting took 0.25 ms of every 3.9 ms step.
    :meth:`flush` writes and syncs everything new at once (the offline pieces, the end).
    """

    def __init__(
        self,
        sim: Simulation,
        outputs: SimOutputs,
        interval_s: float = FLUSH_INTERVAL_S,
        clock: Callable[[], float] = time.monotonic,
        write_every: int = 8,
    ) -> None:
        self.sim = sim
        self.outputs = outputs
        self.interval_s = float(interval_s)
        self.write_every = max(1, int(write_every))
        self._clock = clock
        self._due = clock() + self.interval_s
        self._polls = 0
        self.syncs = 0

    def poll(self) -> None:
        """After a step: write the new steps every ``write_every`` calls; sync (after writing them)
        when ``interval_s`` has passed since the last sync."""
        self._polls += 1
        if self._clock() >= self._due:
            self.flush()
        elif self._polls % self.write_every == 0:
            self.outputs.write(*self.sim.drain_new())

    def flush(self) -> None:
        """Write everything new and sync now."""
        self.outputs.write(*self.sim.drain_new())
        self._sync()

    def _sync(self) -> None:
        self.outputs.sync()
        self.syncs += 1
        self._due = self._clock() + self.interval_s


def open_outputs(
    sim: Simulation,
    log: str | Path | None = None,
    truth: str | Path | None = None,
    mcap: str | Path | None = None,
    channel: str = "vcan0",
    chunk_size: int | None = STREAM_CHUNK_SIZE,
) -> SimOutputs:
    """:class:`SimOutputs` for a run of ``sim`` that is about to start (streamed: small chunks)."""
    return SimOutputs(
        log,
        truth,
        mcap,
        profile=sim.profile.name,
        metadata=sim_metadata(sim.scenario.name, sim.seed, sim.profile, sim.t0_ns),
        channel=channel,
        chunk_size=chunk_size,
    )


def warm_up() -> None:
    """Write one frame and one truth row to throwaway writers, so that the writers' compiled kernels
    are loaded (numba's cache) before a live run, not at its first flush (a late frame)."""
    one = FrameBatch(
        np.full(1, 1_000_000_000, np.int64),
        np.zeros(1, np.uint32),
        np.zeros(1, bool),
        np.full(1, 8, np.uint8),
        np.zeros((1, 8), np.uint8),
        np.ones(1, bool),
    )
    truth = {name: np.zeros(1) for name in TRUTH_COLUMNS}
    with SimOutputs(os.devnull, os.devnull, os.devnull) as out:
        out.write(one, truth, one.t_ns)
        out.sync()


def write_mcap(path: str | Path, res: SimResult) -> None:
    """MCAP: the frames on ``/can/rx`` and one JSON truth record per 3.9 ms step on ``/truth``."""
    write_outputs(res, mcap=path)


def write_outputs(
    res: SimResult,
    log: str | Path | None = None,
    truth: str | Path | None = None,
    mcap: str | Path | None = None,
    channel: str = "vcan0",
) -> list[Path]:
    """Write whichever outputs are given, at once; the paths written."""
    out = SimOutputs(
        log,
        truth,
        mcap,
        profile=res.profile,
        metadata=sim_metadata(res.scenario.name, res.seed, res.profile, res.t0_ns),
        channel=channel,
    )
    with out:
        out.write(res.frames, res.truth, res.truth_t_ns)
    return out.paths
