"""Recording of a live run to MCAP, crash-tolerant, and a reader that recovers an unfinished file.

Channels (documented in ``docs/guide/mcap.md``; JSON channels have flat numeric fields so that
Foxglove's plot panel can plot every field directly):

==================  ===========================  ==================================================
topic               encoding                     content
==================  ===========================  ==================================================
``/can/rx``         :mod:`lde.io` CAN schema  every frame the service received (receive time)
``/can/tx``         :mod:`lde.io` CAN schema  every frame the service sent (send time)
``/lde/estimate``   JSON (``lde.Estimate``)      one per step (log time = the step time t_k, exact):
                                                 ``Fw`` N, ``Mw`` Nm, ``T_align`` Nm, ``T_overlay`` Nm,
                                                 ``overlay_state``, ``overlay_active``,
                                                 ``overlay_enable``, ``status``
                                                 and its bits as 0/1 fields
``/lde/inputs``     JSON (``lde.Inputs``)        one per step: the sampled inputs in SI
``/lde/diag``       JSON (``lde.Diag``)          one per step: ``period_error_us``, ``step_time_us``,
                                                 ``latency_us``, ``deadline_miss``,
                                                 ``deadline_misses``, ``skipped``, ``e2e_rejects``,
                                                 ``frames_used``
``/lde/events``     JSON (``lde.Events``)        sparse: at the first step and whenever the overlay
                                                 limiter's ``enable`` input changes (``--no-overlay``,
                                                 shutdown ramp-out); log time = that step's t_k.
                                                 Small, so a replay reads it cheaply to reproduce a
                                                 run that ended by a signal exactly.
==================  ===========================  ==================================================

Every message's log time is its own time in the bus time base (ns): receive time, send time, or
the step time t_k (which a replay uses to step on the same grid). Metadata record ``lde``:
profile, vehicle, backend, step period.

Hand-off and crash tolerance: the service hands each step's frames and row to a writer process as
fixed-size records through two pipes (:class:`Recorder`: one non-blocking ``write`` each per step;
the kernel's pipe orders the bytes on any CPU). The writer reads them every 20 ms and every
``flush_interval_s`` (default 0.25 s) writes small chunks and flushes them to the file
(:meth:`lde.io.McapWriter.flush` writes the queued messages as chunks), so the writing never competes
with the service for its interpreter lock. A SIGKILL of the service loses nothing (what it wrote
stays in the pipes: the writer reads it, writes it and closes the file); of both processes at most
about the last flush interval. :func:`read_recording` reads a file sequentially and stops cleanly at a
truncated tail, so a file without footer/summary still gives everything up to its last complete
chunk.
"""

from __future__ import annotations

import contextlib
import fcntl
import logging
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from multiprocessing.connection import Connection
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from lde.can.frames import MAX_DATA, FrameBatch, seconds_to_ns
from lde.can.profiles import INPUT_NAMES
from lde.engine.engine import OUTPUT_MESSAGES, StepBlock
from lde.errors import LogFormatError
from lde.io import TOPIC_RX, TOPIC_TX, McapLog, McapWriter
from lde.io.textfmt import EXACT, Column, format_rows, time_column
from lde.status import DEADLINE_MISS, STATUS_BITS, STATUS_MEANINGS

if TYPE_CHECKING:  # python-can is imported by whoever hands in can.Message objects
    import can

__all__ = [
    "Recorder",
    "frame_record",
    "step_record",
    "Recording",
    "read_recording",
    "ESTIMATE_TOPIC",
    "INPUTS_TOPIC",
    "DIAG_TOPIC",
    "EVENTS_TOPIC",
    "SMOOTH_TOPIC",
    "SmoothTopicWriter",
    "CAN_RX_TOPIC",
    "CAN_TX_TOPIC",
]

log = logging.getLogger(__name__)

CAN_RX_TOPIC = TOPIC_RX
CAN_TX_TOPIC = TOPIC_TX
ESTIMATE_TOPIC = "/lde/estimate"
INPUTS_TOPIC = "/lde/inputs"
DIAG_TOPIC = "/lde/diag"
EVENTS_TOPIC = "/lde/events"
#: ``lde replay --smooth --mcap``: the RTS smoother's outputs, one message per step (log time = t_k)
SMOOTH_TOPIC = "/lde/smooth"
#: ``lde`` metadata key: the learned-state file's text a live run started from (``--learned``), so
#: that a replay of the recording starts from it too (:func:`lde.replay.replay.run_replay`)
LEARNED_START_KEY = "learned_start"

#: estimator input names (SI) recorded on ``/lde/inputs``
INPUT_FIELDS: tuple[str, ...] = INPUT_NAMES


# ---------------------------------------------------------------------- the step topics, once


@dataclass(frozen=True)
class Timing:
    """The live loop's per-step timing columns (``/lde/diag``); a replay has none (null fields).

    All int64 [n]: period error, step time and latency [ns] (latency -1: no input yet), the
    deadline-miss flag (0/1), late steps plus skipped grid points since start, grid points skipped.
    """

    period_error_ns: np.ndarray
    step_time_ns: np.ndarray
    latency_ns: np.ndarray
    deadline_miss: np.ndarray
    deadline_misses: np.ndarray
    skipped: np.ndarray

    @classmethod
    def empty(cls, n: int) -> Timing:
        return cls(*(np.zeros(n, np.int64) for _ in range(6)))

    def head(self, n: int) -> Timing:
        return Timing(*(getattr(self, f.name)[:n] for f in fields(self)))

    @classmethod
    def concat(cls, parts: list[Timing]) -> Timing:
        return cls(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(cls)))


Getter = Callable[[StepBlock, "Timing | None"], Any]


@dataclass(frozen=True)
class TopicField:
    """One flat JSON field of a step topic: name, JSON type, description, decimals, and how its
    column is taken from a :class:`lde.engine.engine.StepBlock` (and the live timing)."""

    name: str
    kind: str  # "integer" | "number"
    description: str
    decimals: int
    get: Getter


@dataclass(frozen=True)
class StepTopic:
    """A per-step JSON channel: one message per step, log time = the step time t_k (exact ns)."""

    topic: str
    title: str
    fields: tuple[TopicField, ...]

    @property
    def properties(self) -> dict[str, dict[str, str]]:
        """JSON-schema properties (the channel's schema)."""
        return {f.name: {"type": f.kind, "description": f.description} for f in self.fields}

    def columns(self, block: StepBlock, timing: Timing | None) -> list[Column]:
        """The text columns of ``block``'s rows."""
        out = []
        for f in self.fields:
            v = f.get(block, timing)
            out.append(v if isinstance(v, Column) else Column(f.name, np.asarray(v), f.decimals))
        return out


def _num(name: str, desc: str, dec: int, get: Getter) -> TopicField:
    return TopicField(name, "number", desc, dec, get)


def _int(name: str, desc: str, get: Getter) -> TopicField:
    return TopicField(name, "integer", desc, 0, get)


def _timing(attr: str, scale: float, missing: float) -> Getter:
    def get(b: StepBlock, tm: Timing | None) -> np.ndarray:
        if tm is None:
            return np.full(len(b), missing)
        v = getattr(tm, attr)
        return v * scale if scale != 1.0 else v

    return get


def _status_bit(i: int) -> Getter:
    return lambda b, _: (b.status >> i) & 1


def _input(i: int) -> Getter:
    return lambda b, _: b.inputs[:, i]


def _latency_us(b: StepBlock, tm: Timing | None) -> np.ndarray:
    if tm is None:
        return np.full(len(b), np.nan)
    return np.where(tm.latency_ns >= 0, tm.latency_ns / 1e3, -1.0)


ESTIMATE = StepTopic(
    ESTIMATE_TOPIC,
    "lde.Estimate",
    (
        _int("t_ns", "the step time t_k [ns], the bus/log time base", lambda b, _: b.t_ns),
        TopicField("t", "number", "the step time [s]", 0, lambda b, _: time_column("t", b.t_ns)),
        _num("Fw", "disturbance force at the CG [N], left positive", EXACT, lambda b, _: b.fw),
        _num("Mw", "disturbance yaw moment [Nm], left positive", EXACT, lambda b, _: b.mw),
        _num(
            "T_align", "aligning torque on the steering axis [Nm], paper sign", EXACT, lambda b, _: b.t_align
        ),
        _num(
            "T_overlay",
            "overlay torque request [Nm] at the column, left positive",
            EXACT,
            lambda b, _: b.t_overlay,
        ),
        _int(
            "overlay_state", "0 off, 1 ramp-in, 2 active, 3 ramp-out, 4 fault", lambda b, _: b.overlay_state
        ),
        _int("overlay_active", "the Active bit sent", lambda b, _: b.overlay_active),
        _int(
            "overlay_enable",
            "the limiter's enable input (0: overlay switched off or ramping out at shutdown)",
            lambda b, _: b.overlay_enable,
        ),
        _int("status", "LDE_Estimate.Status bit map", lambda b, _: b.status),
        _num("beta", "estimated side slip [rad]", EXACT, lambda b, _: b.beta),
        _num("yaw_rate", "estimated yaw rate [rad/s]", EXACT, lambda b, _: b.yaw_rate),
        _num("Fw_wind", "the wind's part of Fw [N] (null: not told apart)", EXACT, lambda b, _: b.fw_wind),
        _num("Mw_wind", "the wind's yaw moment [Nm] (null: not told apart)", EXACT, lambda b, _: b.mw_wind),
        _num("bank_deg", "road bank [deg], left side lower positive", EXACT, lambda b, _: np.degrees(b.bank)),
        _int("learn_state", "0 not learned, 1 learning, 2 learned, 3 no learner", lambda b, _: b.learn_state),
        *(
            _int(name, f"0/1, Status bit{i}: {STATUS_MEANINGS[name]}", _status_bit(i))
            for i, name in enumerate(STATUS_BITS)
        ),
    ),
)
_INPUT_DOC = {
    "column_torque": "Nm, left positive",
    "assist_torque": "Nm, left positive",
    "steering_angle": "rad (steering wheel), left positive",
    "steering_rate": "rad/s (steering wheel), left positive",
    "yaw_rate": "rad/s, left positive",
    "lat_accel": "m/s^2, left positive",
    "speed": "m/s",
}
INPUTS = StepTopic(
    INPUTS_TOPIC,
    "lde.Inputs",
    (
        _int("t_ns", "the step time t_k [ns]", lambda b, _: b.t_ns),
        *(_num(n, _INPUT_DOC[n], EXACT, _input(i)) for i, n in enumerate(INPUT_FIELDS)),
        _int("mdps_ok", "1 if the MDPS inputs are valid (fresh, E2E trusted)", lambda b, _: b.mdps_ok),
        _int("esc_ok", "1 if the ESC inputs are valid (fresh, E2E trusted)", lambda b, _: b.esc_ok),
    ),
)
DIAG = StepTopic(
    DIAG_TOPIC,
    "lde.Diag",
    (
        _num(
            "period_error_us",
            "actual minus nominal step start [us] (live)",
            3,
            _timing("period_error_ns", 1e-3, np.nan),
        ),
        _num(
            "step_time_us",
            "compute time of the step up to the send of its outputs [us] (live)",
            3,
            _timing("step_time_ns", 1e-3, np.nan),
        ),
        _num(
            "latency_us",
            "newest input frame used -> outputs sent [us] (-1: no input yet; live)",
            3,
            _latency_us,
        ),
        _int("deadline_miss", "1 if this step started more than 1 ms late", _timing("deadline_miss", 1.0, 0)),
        _int(
            "deadline_misses",
            "late steps plus skipped grid points since start",
            _timing("deadline_misses", 1.0, 0),
        ),
        _int("skipped", "grid points skipped after overruns since start", _timing("skipped", 1.0, 0)),
        _int("e2e_rejects", "frames rejected (E2E or wrong length) since start", lambda b, _: b.e2e_rejects),
        _int("frames_used", "input frames accepted since the previous step", lambda b, _: b.frames_used),
    ),
)
#: the per-step topics, in the order they are written
STEP_TOPICS: tuple[StepTopic, ...] = (ESTIMATE, INPUTS, DIAG)
EVENTS_PROPS = {
    "overlay_enable": {
        "type": "integer",
        "description": "the limiter's enable input from this step on (0: switched off or ramping out)",
    },
    "deadline_miss": {"type": "integer", "description": "1: this step started more than 1 ms late"},
}
# compatibility names (the schemas as property dicts)
ESTIMATE_PROPS = ESTIMATE.properties
INPUTS_PROPS = INPUTS.properties
DIAG_PROPS = DIAG.properties


class StepTopicWriter:
    """Writes rows of steps (:class:`lde.engine.engine.StepBlock`) as the recording's step topics and the
    sparse ``/lde/events`` channel into an :class:`lde.io.McapWriter`: the one definition used by
    the live :class:`Recorder` and by :func:`lde.replay.replay.write_recording`.

    ``/lde/events`` gets a message at the first step, whenever the overlay enable input changes, and
    at every step with a deadline miss (so that a replay reproduces the status bits exactly).
    """

    def __init__(self, writer: McapWriter) -> None:
        self.writer = writer
        self._ids = [writer.add_json_channel(t.topic, t.properties, title=t.title) for t in STEP_TOPICS]
        self._events = writer.add_json_channel(EVENTS_TOPIC, EVENTS_PROPS, title="lde.Events")
        self._last_enable: int | None = None

    def write(self, block: StepBlock, timing: Timing | None = None) -> None:
        n = len(block)
        if n == 0:
            return
        t = block.t_ns
        for cid, topic in zip(self._ids, STEP_TOPICS, strict=True):
            _write_json_channel(self.writer, cid, t, topic.columns(block, timing))
        en = block.overlay_enable.astype(np.int64)
        prev = np.concatenate([[-1 if self._last_enable is None else self._last_enable], en[:-1]])
        miss = (block.status.astype(np.int64) & DEADLINE_MISS) != 0
        ev = np.flatnonzero((en != prev) | miss)
        if ev.size:
            cols = [Column("overlay_enable", en[ev]), Column("deadline_miss", miss[ev].astype(np.int64))]
            _write_json_channel(self.writer, self._events, t[ev], cols)
        self._last_enable = int(en[-1])


class SmoothTopicWriter:
    """The ``/lde/smooth`` channel (:data:`SMOOTH_TOPIC`): the smoother's columns per step
    (``fields``: name and description of each, :data:`lde.replay.smoother.SMOOTHED`)."""

    def __init__(self, writer: McapWriter, fields: tuple[tuple[str, str], ...]) -> None:
        self.writer = writer
        props = {name: {"type": "number", "description": desc} for name, desc in fields}
        self._id = writer.add_json_channel(SMOOTH_TOPIC, props, title="lde.Smooth")

    def write(self, t_ns: np.ndarray, columns: list[Column]) -> None:
        _write_json_channel(self.writer, self._id, t_ns, columns)


def _write_json_channel(w: McapWriter, cid: int, t: np.ndarray, cols: list[Column]) -> None:
    seps = [("{" if i == 0 else ",") + f'"{c.name}":' for i, c in enumerate(cols)]
    text, off = format_rows(cols, seps, "}", nan_text="null")
    w.write_json_payloads(cid, t, text, off)


def _background_priority() -> None:
    """Run the calling process as background work, on any CPU: forked from a SCHED_FIFO service
    (``--realtime``, ``--cpu``) the writer would inherit the loop's real-time priority and its CPU.
    Under a real-time service it takes SCHED_FIFO 1 (below the loop, above normal tasks: it must
    flush every ``flush_interval_s`` for the crash guarantee, and a starved writer drops steps);
    otherwise SCHED_BATCH (where allowed): the normal-priority service then goes first when it wakes
    up, while the writer keeps its fair share of the CPU."""
    try:
        if os.sched_getscheduler(0) in (os.SCHED_FIFO, os.SCHED_RR):
            # a real-time service: the writer goes at the lowest real-time priority, below the loop
            # but above every normal task. At SCHED_BATCH it got what a real-time service and
            # simulator left on one CPU (user-mode Linux in CI: the ring filled, 2338 steps dropped);
            # it sleeps between its drains, so it takes only what writing needs
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        elif hasattr(os, "SCHED_BATCH"):
            os.sched_setscheduler(0, os.SCHED_BATCH, os.sched_param(0))
    except (AttributeError, OSError):  # not Linux, or not permitted: keep what we have
        pass
    with contextlib.suppress(AttributeError, OSError, ValueError):
        os.sched_setaffinity(0, range(os.cpu_count() or 1))


def _sync(writer: McapWriter) -> None:
    """Write the queued messages as chunks and push them to the OS (survives a SIGKILL)."""
    writer.flush()
    writer.sync()


# ---------------------------------------------------------------------- the hand-off to the writer

#: a frame whose data is this wide or narrower fits a classic frame record (:func:`frame_record`)
CLASSIC_BYTES = 8
#: POSIX's least ``PIPE_BUF``: writes of at most this many bytes to a pipe are atomic (Linux: 4096,
#: asked of each pipe: :func:`_pipe`)
_POSIX_PIPE_BUF = 512
#: the pipes' capacity asked for [bytes] (Linux ``F_SETPIPE_SZ``; unprivileged at most
#: ``/proc/sys/fs/pipe-max-size``, 1 MiB by default): about 8 s of lde's traffic
_PIPE_BYTES = (1 << 20, 1 << 18)
#: the writer reads the pipes this often [s]: it never wakes per step, and never lets a pipe fill
_READ_S = 0.02
#: a period error no live step has: "this row has no timing" (a replay's rows through Recorder.steps)
_NO_TIMING = np.iinfo(np.int64).min
#: the recorder's writer process must have opened the file within this time [s]
_START_TIMEOUT_S = 120.0


def frame_record(width: int = CLASSIC_BYTES) -> np.dtype:
    """One frame as the service hands it to the recorder's writer (little-endian, packed): ``t_ns``
    int64 its receive or send time [ns], ``can_id`` uint32, ``dlc`` uint8, ``flags`` uint8 (bit 0:
    received, bit 1: 29-bit id), two pad bytes, then ``data``: ``width`` bytes (the first ``dlc``
    hold the frame's data, the rest zero). 24 bytes for a classic frame."""
    return np.dtype(
        {
            "names": ["t_ns", "can_id", "dlc", "flags", "data"],
            "formats": ["<i8", "<u4", "u1", "u1", ("u1", (width,))],
            "offsets": [0, 8, 12, 13, 16],
            "itemsize": 16 + width,
        }
    )


_FLAG_RX, _FLAG_EXT = 1, 2


def step_record(n_outputs: int = len(OUTPUT_MESSAGES)) -> np.dtype:
    """One step as the service hands it to the recorder's writer: the columns of one
    :class:`lde.engine.engine.StepBlock` row (each at its natural alignment), then ``timing``: 6 int64
    (period error, step time, latency [ns], miss 0/1, misses, skipped; period error
    ``_NO_TIMING``: the row has no timing), the record's last 48 bytes."""
    like = StepBlock.empty(1, n_outputs)
    names, formats, offsets = [], [], []
    off = 0
    for f in fields(StepBlock):
        a = getattr(like, f.name)
        align = a.dtype.alignment
        off = (off + align - 1) // align * align
        names.append(f.name)
        formats.append((a.dtype, a.shape[1:]))
        offsets.append(off)
        off += a.nbytes
    off = (off + 7) // 8 * 8
    names.append("timing")
    formats.append(("<i8", (6,)))
    offsets.append(off)
    return np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": off + 48})


def _frames_of(rec: np.ndarray) -> FrameBatch:
    """Frame records as a :class:`lde.can.frames.FrameBatch` (copies)."""
    flags = rec["flags"]
    return FrameBatch(
        t_ns=rec["t_ns"].copy(),
        can_id=rec["can_id"].copy(),
        is_extended=(flags & _FLAG_EXT) != 0,
        dlc=rec["dlc"].copy(),
        data=np.ascontiguousarray(rec["data"]),
        is_rx=(flags & _FLAG_RX) != 0,
    )


def _steps_of(rec: np.ndarray) -> tuple[StepBlock, Timing | None]:
    """Step records as a :class:`lde.engine.engine.StepBlock` and their timing (None when a row has
    none), copies."""
    block = StepBlock(**{f.name: np.ascontiguousarray(rec[f.name]) for f in fields(StepBlock)})
    tm = rec["timing"]
    timing = None
    if len(rec) and not np.any(tm[:, 0] == _NO_TIMING):
        timing = Timing(*(tm[:, k].copy() for k in range(6)))
    return block, timing


def _pipe() -> tuple[int, int, int]:
    """A pipe: (read end, write end, ``PIPE_BUF``); its write end never blocks; as large as allowed.
    A write of at most ``PIPE_BUF`` bytes to it is atomic: whole, or not at all when the pipe is full."""
    r, w = os.pipe()
    try:
        atomic = int(os.fpathconf(w, "PC_PIPE_BUF"))
    except (OSError, ValueError):
        atomic = _POSIX_PIPE_BUF
    os.set_blocking(w, False)
    setsize: int = getattr(fcntl, "F_SETPIPE_SZ", -1)  # Linux only
    for size in _PIPE_BYTES if setsize >= 0 else ():
        try:
            fcntl.fcntl(w, setsize, size)
            break
        except OSError:  # above this system's limit for unprivileged users: try less
            continue
    return r, w, atomic


class _RecordReader:
    """The writer's end of one pipe of fixed-size records: :meth:`read` takes what has arrived
    (never blocks), :meth:`take` hands out the whole records read so far."""

    def __init__(self, fd: int, dtype: np.dtype) -> None:
        self.fd = fd
        self.dtype = dtype
        self.buf = bytearray()
        self.eof = False
        os.set_blocking(fd, False)

    def read(self) -> None:
        while not self.eof:
            try:
                got = os.read(self.fd, 1 << 20)
            except BlockingIOError:
                return
            if not got:
                self.eof = True
            self.buf += got

    def take(self) -> np.ndarray:
        n = len(self.buf) // self.dtype.itemsize
        k = n * self.dtype.itemsize
        rec = np.frombuffer(bytes(self.buf[:k]), self.dtype)
        del self.buf[:k]
        return rec


class _WriterProcess:
    """The recorder's writer process. Forked when this process has no other thread (``lde run``: fast,
    and no lock can be held by a thread that the child would not have); otherwise a fresh interpreter
    (``python -m lde.io.recording``), because a fork would inherit locks that other threads hold (numba's
    compiler lock, say) and could hang on them. ``keep``: the descriptors the writer reads (its end of
    the connection, then the two pipes' read ends); ``drop``: the service's ends, closed in a forked
    child (a pipe whose write end only the service holds reads as ended once the service is gone)."""

    def __init__(self, keep: tuple[int, int, int], drop: tuple[int, ...]) -> None:
        self.pid = 0
        self.popen: subprocess.Popen | None = None
        if hasattr(os, "fork") and threading.active_count() == 1:
            pid = os.fork()
            if pid == 0:  # the child: never returns
                code = 1
                try:
                    for fd in drop:
                        os.close(fd)
                    _writer_main(*keep)
                    code = 0
                finally:
                    os._exit(code)
            self.pid = pid
        else:
            cmd = [sys.executable, "-m", "lde.io.recording", *map(str, keep)]
            self.popen = subprocess.Popen(cmd, pass_fds=keep, stdin=subprocess.DEVNULL, close_fds=True)

    def wait(self, timeout: float | None = None) -> None:
        """Wait for the end of the process (``subprocess.TimeoutExpired`` after ``timeout``)."""
        if self.popen is not None:
            self.popen.wait(timeout)
            return
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            done, _ = os.waitpid(self.pid, 0 if deadline is None else os.WNOHANG)
            if done:
                return
            if deadline is not None and time.monotonic() > deadline:
                raise subprocess.TimeoutExpired(f"lde recorder writer {self.pid}", timeout or 0.0)
            time.sleep(0.01)

    def kill(self) -> None:
        if self.popen is not None:
            self.popen.kill()
        else:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)


class Recorder:
    """Writes a live run to an MCAP file (:class:`lde.io.McapWriter`) from a writer *process*.

    The service hands each step's frames and row to the writer as fixed-size records
    (:func:`frame_record`, :func:`step_record`) through two pipes (:meth:`put`: one ``write`` each,
    from buffers the step's compiled hand-off filled). The kernel's pipe is the synchronisation: a
    record is complete in the writer's ``read`` once the service's ``write`` has returned, on any CPU,
    with no memory ordering of lde's own. The service's ends never block: a batch of records up to
    ``PIPE_BUF`` bytes is written whole or not at all, and a full pipe drops the batch and counts it
    (:attr:`dropped`). The writer process (:class:`_WriterProcess`: forked, or a fresh interpreter
    when other threads run) reads the pipes every 20 ms, and every ``flush_interval_s`` writes small
    chunks and pushes them to the OS. The writing (JSON formatting, MCAP records, compression) thus
    never holds the service's interpreter lock.

    When the service dies (SIGKILL included) what it wrote stays in the pipes: the writer sees its end
    of the connection close, reads the rest, writes it and closes the file with its summary. If both
    are killed, at most about the last flush interval is lost.

    Use as a context manager or call :meth:`close` (idempotent; writes the summary/footer).

    Args:
        path: output ``.mcap`` file.
        metadata: strings stored in the ``lde`` metadata record (profile, vehicle, backend...).
        flush_interval_s: the writer writes and flushes a chunk this often [s].
        chunk_size: MCAP chunk size bound [bytes, uncompressed] (small: a crash loses little).
        extra_topics: more JSON channels, topic -> {field: JSON-schema property}, written with
            :meth:`json_columns` (the demo's ``/sim/truth``).
        n_outputs: output frames per step row (``StepBlock.frames``).
        frame_bytes: data bytes kept per frame: 8 (a classic bus), up to 64 (a profile with CAN FD
            input messages; the service's ``rx_width``).
    """

    def __init__(
        self,
        path: str | Path,
        metadata: dict[str, str] | None = None,
        flush_interval_s: float = 0.25,
        chunk_size: int = 64 * 1024,
        extra_topics: dict[str, dict[str, dict[str, str]]] | None = None,
        n_outputs: int = len(OUTPUT_MESSAGES),
        frame_bytes: int = CLASSIC_BYTES,
    ) -> None:
        if not CLASSIC_BYTES <= frame_bytes <= MAX_DATA:
            raise ValueError(f"frame_bytes must lie in {CLASSIC_BYTES}..{MAX_DATA}, got {frame_bytes}")
        self.path = Path(path)
        meta = {k: str(v) for k, v in (metadata or {}).items()}
        try:  # a path that cannot be written is an error now, not in the writer (which opens it again)
            self.path.open("wb").close()
        except OSError as exc:
            raise LogFormatError(f"{path}: cannot write: {exc}") from exc
        self.n_outputs = int(n_outputs)
        #: the records' layouts (the service's compiled hand-off fills buffers of these)
        self.frame_bytes = int(frame_bytes)
        self.frame_dtype = frame_record(self.frame_bytes)
        self.step_dtype = step_record(self.n_outputs)
        self._extra_topics = dict(extra_topics or {})
        self._closed = False
        self._failed = False
        self._dropped = [0, 0]
        mine, theirs = socket.socketpair()
        fr_r, self._frame_fd, atomic = _pipe()
        st_r, self._step_fd, _ = _pipe()
        sizes = (self.frame_dtype.itemsize, self.step_dtype.itemsize)
        if max(sizes) > atomic:  # (lde's records: 24-80 and about 330 bytes; POSIX's least: 512)
            for fd in (fr_r, self._frame_fd, st_r, self._step_fd):
                os.close(fd)
            mine.close()
            theirs.close()
            raise LogFormatError(f"{path}: records of {max(sizes)} bytes exceed this system's PIPE_BUF")
        #: bytes of one batch: whole records, written whole or not at all
        self._batch = tuple(atomic // n * n for n in sizes)
        mine_fd = mine.fileno()
        try:
            self._proc = _WriterProcess(
                (theirs.fileno(), fr_r, st_r), (mine_fd, self._frame_fd, self._step_fd)
            )
        except OSError as exc:
            mine.close()
            self._close_fds()
            raise LogFormatError(f"{path}: cannot start the recorder's writer process: {exc}") from exc
        finally:
            theirs.close()
            os.close(fr_r)
            os.close(st_r)
        self._conn = Connection(mine.detach())
        self._conn.send(
            (self.path, meta, float(flush_interval_s), int(chunk_size), self._extra_topics,
             self.n_outputs, self.frame_bytes)
        )  # fmt: skip
        # the writer has the file open with its header written when this returns (or says why not)
        ok = self._conn.poll(_START_TIMEOUT_S) and self._reply()
        if not ok or ok[0] != "ready":
            self._proc.kill()
            self._proc.wait()
            self._conn.close()
            self._close_fds()
            self._closed = True
            why = ok[1] if ok else f"the writer process did not start within {_START_TIMEOUT_S:.0f} s"
            raise LogFormatError(f"{path}: cannot record: {why}")

    def _close_fds(self) -> None:
        for fd in (self._frame_fd, self._step_fd):
            with contextlib.suppress(OSError):
                os.close(fd)

    def _reply(self) -> tuple[Any, ...]:
        """The writer's next answer; a note that it failed, which it sends unasked, is taken on the way."""
        try:
            while True:
                r = self._conn.recv()
                if r[0] != "failed":
                    return r
                self._failed = True
        except (EOFError, OSError) as exc:
            return ("error", f"{self.path}: the recorder's writer process ended ({exc or 'EOF'})")

    @property
    def failed(self) -> bool:
        """The writer could not write (disk full, ...) or is gone: recording stopped, the service goes on."""
        if not self._closed and not self._failed:
            try:
                while self._conn.poll(0):
                    if self._conn.recv()[0] == "failed":
                        self._failed = True
            except (EOFError, OSError):
                self._failed = True
        return self._failed

    @property
    def dropped(self) -> tuple[int, int]:
        """(frames, steps) dropped because the writer did not keep up (a pipe was full) or was gone."""
        return self._dropped[0], self._dropped[1]

    # ------------------------------------------------------------------ hot path
    def put(self, frames: memoryview | bytes, step: memoryview | bytes) -> None:
        """One step's frame records (:attr:`frame_dtype`, any number) and its step record
        (:attr:`step_dtype`), as bytes: written to the pipes now, never blocking."""
        if len(frames):
            self._write(self._frame_fd, frames, 0)
        self._write(self._step_fd, step, 1)

    def _write(self, fd: int, buf: memoryview | bytes, kind: int) -> None:
        """Records (``kind`` 0: frames, 1: steps) to their pipe in batches of at most ``PIPE_BUF``
        bytes: POSIX writes such a batch to a non-blocking pipe whole, or not at all when it is full,
        so the writer never reads part of a record."""
        size = self.step_dtype.itemsize if kind else self.frame_dtype.itemsize
        batch = self._batch[kind]
        for at in range(0, len(buf), batch):
            part = buf[at : at + batch]
            try:
                os.write(fd, part)
            except BlockingIOError:  # the pipe is full: the writer did not keep up
                self._dropped[kind] += len(part) // size
            except OSError:  # the writer is gone (EPIPE): recording stopped
                self._dropped[kind] += len(part) // size
                self._failed = True

    def frame(self, t_ns: int, can_id: int, is_extended: bool, dlc: int, word: int, is_rx: bool) -> None:
        """A received (``is_rx``) or sent frame at ``t_ns`` [ns]; ``word``: its data bytes as a
        little-endian integer (the first :attr:`frame_bytes` are kept)."""
        rec = np.zeros(1, self.frame_dtype)
        rec["t_ns"] = t_ns
        rec["can_id"] = can_id
        rec["dlc"] = dlc
        rec["flags"] = (_FLAG_RX if is_rx else 0) | (_FLAG_EXT if is_extended else 0)
        width = self.frame_bytes
        rec["data"][0] = np.frombuffer((word & ((1 << 8 * width) - 1)).to_bytes(width, "little"), np.uint8)
        self._write(self._frame_fd, rec.tobytes(), 0)

    def step(
        self, block: StepBlock, row: int = 0, timing: tuple[int, int, int, int, int, int] | None = None
    ) -> None:
        """One step's row of ``block`` (copied now) and its live timing (period error, step time,
        latency [ns], miss 0/1, misses, skipped; None: no timing)."""
        rec = np.zeros(1, self.step_dtype)
        for f in fields(StepBlock):
            rec[f.name][0] = getattr(block, f.name)[row]
        if timing is None:
            rec["timing"][0, 0] = _NO_TIMING
        else:
            rec["timing"][0] = timing
        self._write(self._step_fd, rec.tobytes(), 1)

    def rx(self, msg: can.Message) -> None:
        """A received frame (its timestamp is the receive time); its content is copied now."""
        self.frame(
            seconds_to_ns(msg.timestamp),
            msg.arbitration_id,
            msg.is_extended_id,
            msg.dlc,
            _word(msg.data),
            True,
        )

    def tx(self, msg: can.Message) -> None:
        """A sent frame (its timestamp is the send time); its content is copied now (the sender
        may reuse the message object)."""
        self.frame(
            seconds_to_ns(msg.timestamp),
            msg.arbitration_id,
            msg.is_extended_id,
            msg.dlc,
            _word(msg.data),
            False,
        )

    def steps(self, block: StepBlock, timing: Timing | None = None) -> None:
        """Rows of steps (copied now)."""
        rec = np.zeros(len(block), self.step_dtype)
        for f in fields(StepBlock):
            rec[f.name] = getattr(block, f.name)
        if timing is None:
            rec["timing"][:, 0] = _NO_TIMING
        else:
            for k, f in enumerate(fields(Timing)):
                rec["timing"][:, k] = getattr(timing, f.name)
        self._write(self._step_fd, rec.tobytes(), 1)

    def json_columns(self, topic: str, t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        """Many JSON messages at once on an ``extra_topics`` channel (one per element of ``t_ns``);
        not for the hot path (the columns go to the writer through its connection)."""
        if topic not in self._extra_topics:
            raise ValueError(f"topic {topic!r} was not declared in extra_topics")
        self._conn.send(
            ("json", topic, np.asarray(t_ns, np.int64), {k: np.asarray(v) for k, v in columns.items()})
        )

    # ------------------------------------------------------------------ writer control
    def _drain(self) -> None:
        """Have the writer write and flush everything handed over so far (returns when it has)."""
        if self._closed:
            return
        self._conn.send(("flush",))
        self._reply()

    def close(self) -> None:
        """Write everything handed over, the summary and the footer; close the file; end the writer."""
        if self._closed:
            return
        try:
            self._conn.send(("close",))
            r = self._reply()
            if r[0] == "error":
                log.error("%s", r[1])
            self._failed = self._failed or r[0] != "closed"
        except (BrokenPipeError, OSError) as exc:
            self._failed = True
            log.error("recording to %s: the writer process is gone (%s)", self.path, exc)
        self._closed = True
        try:
            self._proc.wait(30.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - a hung writer must not hang the exit
            self._proc.kill()
            self._proc.wait()
        self._conn.close()
        self._close_fds()
        if any(self._dropped):
            log.warning(
                "recording %s: the writer fell behind, dropped %d frames and %d steps",
                self.path,
                *self._dropped,
            )

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _word(data: bytes | bytearray) -> int:
    return int.from_bytes(bytes(data), "little")


def _warm_up(n_outputs: int) -> None:
    """Write one step and one frame to a throwaway writer, so that the compiled formatters are loaded
    (numba's cache: seconds in a fresh process on a busy machine) before the first flush is due."""
    w = McapWriter(os.devnull, metadata={"warm": "up"})
    block = StepBlock.empty(1, n_outputs)
    for f in fields(StepBlock):
        getattr(block, f.name)[...] = 0
    StepTopicWriter(w).write(block, Timing.empty(1))
    one = (np.zeros(1, np.uint32), np.zeros(1, np.bool_), np.zeros(1, np.uint8), np.zeros((1, 8), np.uint8))
    w.write_frames(FrameBatch(block.t_ns, *one, np.ones(1, np.bool_)))
    w.flush()


def _writer_main(conn_fd: int, frame_fd: int, step_fd: int) -> None:
    """The writer process (``python -m lde.io.recording CONN_FD FRAME_FD STEP_FD``): read the pipes
    every :data:`_READ_S`, write and flush every flush interval, until told to close or until the
    service is gone (its end of the connection closes); then the rest of the pipes, and close the file."""
    # Ctrl-C reaches the whole process group, a service manager's SIGTERM maybe too: the writer
    # ends when the service tells it to (or is gone), after writing what the pipes hold
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _background_priority()
    conn: Connection | None = Connection(conn_fd)
    assert conn is not None
    path, meta, flush_interval, chunk_size, extra_topics, n_out, width = conn.recv()
    frames_in = _RecordReader(frame_fd, frame_record(width))
    steps_in = _RecordReader(step_fd, step_record(n_out))
    try:
        w = McapWriter(path, chunk_size=chunk_size, buffer_bytes=64 << 20, metadata=meta)
        steps = StepTopicWriter(w)
        extra = {t: w.add_json_channel(t, props) for t, props in extra_topics.items()}
        _sync(w)
        _warm_up(n_out)
    except (LogFormatError, OSError, ValueError) as exc:
        conn.send(("error", str(exc)))
        return
    conn.send(("ready",))
    failed = False

    def write_out() -> None:
        """Everything read so far into the file, flushed to the OS."""
        nonlocal failed
        frames_in.read()
        steps_in.read()
        fb = _frames_of(frames_in.take())
        block, timing = _steps_of(steps_in.take())
        if failed:
            return
        try:
            if len(fb):
                w.write_frames(fb)
            if len(block):
                steps.write(block, timing)
            _sync(w)
        except (OSError, ValueError) as exc:  # disk full, closed file: stop recording, keep reading
            log.error("recording to %s failed, recording stopped: %s", path, exc)
            failed = True
            if conn is not None:
                with contextlib.suppress(OSError):
                    conn.send(("failed", str(exc)))

    next_flush = time.monotonic() + flush_interval
    while True:
        cmd: tuple[Any, ...] | None = None
        try:
            if conn is None:
                raise EOFError
            if conn.poll(max(0.0, min(_READ_S, next_flush - time.monotonic()))):
                cmd = conn.recv()
        except (EOFError, OSError):  # the service is gone: write what it left, then close
            cmd = ("close",)
            conn = None
        if cmd is None:
            frames_in.read()
            steps_in.read()
            if time.monotonic() >= next_flush:
                write_out()
                next_flush = time.monotonic() + flush_interval
        elif cmd[0] == "flush":
            write_out()
            if conn is not None:
                conn.send(("flushed",))
        elif cmd[0] == "json":
            if not failed:
                w.write_json_columns(extra[cmd[1]], cmd[2], cmd[3])
        elif cmd[0] == "close":
            write_out()
            reply: tuple[Any, ...] = ("closed",)
            if not failed:
                try:
                    w.close()
                except (OSError, ValueError) as exc:
                    reply = ("error", f"closing recording {path} failed: {exc}")
            if conn is not None:
                conn.send(reply)
            return


# ---------------------------------------------------------------------- reading back


@dataclass
class Recording:
    """A recording read back (possibly recovered from a file without footer).

    Attributes:
        rx, tx: received / sent frames (``is_rx`` True / False).
        estimate, inputs, diag: per-step columns (numpy arrays) keyed by JSON field.
        metadata: the ``lde`` metadata record.
        complete: the file had its footer (closed cleanly).
    """

    rx: FrameBatch
    tx: FrameBatch
    estimate: dict[str, np.ndarray] = field(default_factory=dict)
    inputs: dict[str, np.ndarray] = field(default_factory=dict)
    diag: dict[str, np.ndarray] = field(default_factory=dict)
    metadata: dict[str, str] = field(default_factory=dict)
    complete: bool = False

    @property
    def step_times_ns(self) -> np.ndarray:
        """The recorded step times t_k [ns] (int64)."""
        return self.estimate.get("t_ns", np.zeros(0, np.int64))


def read_recording(path: str | Path) -> Recording:
    """Read a recording written by :class:`Recorder` (or any lde MCAP file) with the logio reader
    (:class:`lde.io.McapLog`), recovering a file that has no footer: everything up to its last
    complete chunk.

    Raises:
        LogFormatError: not an MCAP file, or cut before its first complete chunk.
    """
    with McapLog(path) as m:
        frames = FrameBatch.concat(list(m.iter_frames()), sort=False)
        cols = {t: m.json(t) for t in (ESTIMATE_TOPIC, INPUTS_TOPIC, DIAG_TOPIC) if t in m.topics}
        return Recording(
            rx=frames.select(frames.is_rx),
            tx=frames.select(~frames.is_rx),
            estimate=cols.get(ESTIMATE_TOPIC, {}),
            inputs=cols.get(INPUTS_TOPIC, {}),
            diag=cols.get(DIAG_TOPIC, {}),
            metadata=dict(m.metadata.get("lde", {})),
            complete=m.complete,
        )


if __name__ == "__main__":  # the recorder's writer process (Recorder starts it)
    _writer_main(int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]))
