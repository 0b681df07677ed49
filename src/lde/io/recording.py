"""Recording of a live run to MCAP, crash-tolerant, and a reader that recovers an unfinished file.

Channels (documented in ``docs/service.md``; JSON channels have flat numeric fields so that
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

Hand-off and crash tolerance: the hot path stores rows in preallocated rings in shared memory
(:class:`StepRing`); a forked writer process drains them every ``flush_interval_s`` (default 0.25 s),
writes small chunks and flushes them to the file (:meth:`lde.io.McapWriter.flush` writes the
queued messages as chunks), so the writing never competes with the service for its interpreter
lock. A SIGKILL of the service loses nothing (the writer notices and closes the file); of both
processes at most about the last half second. :func:`read_recording` reads a file sequentially and
stops cleanly at a truncated tail, so a file without footer/summary still gives everything up to its last
complete chunk.
"""

from __future__ import annotations

import contextlib
import logging
import mmap
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
from lde.engine.receiver import N_INPUTS
from lde.errors import LogFormatError
from lde.estimator.outputs import N_OUT
from lde.io import TOPIC_RX, TOPIC_TX, McapLog, McapWriter
from lde.io.textfmt import EXACT, Column, format_rows, time_column
from lde.status import DEADLINE_MISS, STATUS_BITS, STATUS_MEANINGS

if TYPE_CHECKING:  # python-can is imported by whoever hands in can.Message objects
    import can

__all__ = [
    "Recorder",
    "StepRing",
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


# ring control slots (int64): heads are written by the service only, tails by the writer only
_F_HEAD, _F_TAIL, _S_HEAD, _S_TAIL, _F_DROPPED, _S_DROPPED, _FAILED = range(7)
_N_CTL = 8


class StepRing:
    """Preallocated single-producer / single-consumer rings of received/sent frames and step rows in
    memory shared with the recorder's writer process (an anonymous ``memfd`` mapped ``MAP_SHARED`` by
    both; ``fd`` attaches to an existing one).

    The producer (the service's loop) stores a row's values, then advances the ring's head; the
    consumer (the writer) reads the head, then the rows before it, then advances the tail. On x86
    stores become visible in program order, so a row is complete before its head is seen. A full ring
    drops the new row and counts it (never blocks the loop). Capacities are powers of two.

    Args:
        frames: frame slots (default 65536: 35 s of lde traffic at 4.5 frames per step, 64 B each).
        steps: step slots (default 16384: 64 s of steps, about 300 B each).
        n_outputs: output frames per step row (``StepBlock.frames``).
        frame_bytes: data bytes kept per frame: 8 (a classic bus), up to 64 (a profile with CAN FD
            input messages: bytes 8.. are kept in ``f_more``).
    """

    ctl: np.ndarray
    f_t: np.ndarray
    f_word: np.ndarray
    f_more: np.ndarray | None
    f_id: np.ndarray
    f_ext: np.ndarray
    f_dlc: np.ndarray
    f_rx: np.ndarray
    t_ns: np.ndarray
    status: np.ndarray
    est: np.ndarray
    t_overlay: np.ndarray
    overlay_state: np.ndarray
    overlay_enable: np.ndarray
    inputs: np.ndarray
    ages: np.ndarray
    valid_mask: np.ndarray
    ok: np.ndarray
    frames_used: np.ndarray
    e2e_rejects: np.ndarray
    frames: np.ndarray
    timing: np.ndarray

    def __init__(
        self,
        frames: int = 1 << 16,
        steps: int = 1 << 14,
        n_outputs: int = len(OUTPUT_MESSAGES),
        fd: int | None = None,
        frame_bytes: int = 8,
    ) -> None:
        for n in (frames, steps):
            if n <= 0 or n & (n - 1):
                raise ValueError(f"ring capacities must be powers of two, got {n}")
        if not 8 <= frame_bytes <= MAX_DATA:
            raise ValueError(f"frame_bytes must lie in 8..{MAX_DATA}, got {frame_bytes}")
        self.nf, self.ns = int(frames), int(steps)
        self.frame_bytes = int(frame_bytes)
        f, s = self.nf, self.ns
        spec: list[tuple[str, Any, tuple[int, ...]]] = [
            ("ctl", np.int64, (_N_CTL,)),
            ("f_t", np.int64, (f,)),
            ("f_word", np.uint64, (f,)),
            ("f_id", np.uint32, (f,)),
            ("f_ext", np.bool_, (f,)),
            ("f_dlc", np.uint8, (f,)),
            ("f_rx", np.bool_, (f,)),
            ("t_ns", np.int64, (s,)),
            ("status", np.uint8, (s,)),
            ("est", np.float64, (s, N_OUT)),
            ("t_overlay", np.float64, (s,)),
            ("overlay_state", np.uint8, (s,)),
            ("overlay_enable", np.bool_, (s,)),
            ("inputs", np.float64, (s, N_INPUTS)),
            ("ages", np.int64, (s, N_INPUTS)),
            ("valid_mask", np.int64, (s,)),
            ("ok", np.bool_, (s, 2)),
            ("frames_used", np.int64, (s,)),
            ("e2e_rejects", np.int64, (s,)),
            ("frames", np.uint8, (s, n_outputs, 8)),
            ("timing", np.int64, (s, 6)),
        ]
        if frame_bytes > 8:
            spec.append(("f_more", np.uint8, (f, frame_bytes - 8)))
        size = 0
        offs = []
        for _, dt, shape in spec:
            size = (size + 63) & ~63
            offs.append(size)
            size += int(np.dtype(dt).itemsize * np.prod(shape))
        if fd is None:  # an anonymous file in memory; the writer process maps it through its descriptor
            fd = os.memfd_create("lde-recorder-ring", 0)
            os.ftruncate(fd, size)
        self.fd = fd
        self.n_outputs = int(n_outputs)
        self._mm = mmap.mmap(fd, size, flags=mmap.MAP_SHARED)
        for (name, dt, shape), off in zip(spec, offs, strict=True):
            a = np.frombuffer(self._mm, dtype=dt, count=int(np.prod(shape)), offset=off).reshape(shape)
            setattr(self, name, a)
        if frame_bytes == 8:
            self.f_more = None
        #: byte offset of each column in the shared memory (:meth:`memory`)
        self.offsets = {name: off for (name, _, _), off in zip(spec, offs, strict=True)}
        self._fh = 0  # producer's copies of its heads
        self._sh = 0
        self._f_tail_seen = 0
        self._s_tail_seen = 0

    # ------------------------------------------------------------------ producer (hot path)
    def put_frame(self, t_ns: int, can_id: int, is_extended: bool, dlc: int, word: int, is_rx: bool) -> None:
        """One frame; ``word``: its data bytes as a little-endian integer (the first ``frame_bytes``
        are kept)."""
        h = self._fh
        if h - self._f_tail_seen >= self.nf:
            self._f_tail_seen = int(self.ctl[_F_TAIL])
            if h - self._f_tail_seen >= self.nf:
                self.ctl[_F_DROPPED] += 1
                return
        i = h & (self.nf - 1)
        self.f_t[i] = t_ns
        self.f_word[i] = word & _WORD
        if self.f_more is not None:
            self.f_more[i] = np.frombuffer((word >> 64).to_bytes(self.frame_bytes, "little"), np.uint8)[
                : self.frame_bytes - 8
            ]
        self.f_id[i] = can_id
        self.f_ext[i] = is_extended
        self.f_dlc[i] = dlc
        self.f_rx[i] = is_rx
        self._fh = h + 1
        self.ctl[_F_HEAD] = h + 1

    def put_step(
        self, block: StepBlock, row: int, timing: tuple[int, int, int, int, int, int] | None
    ) -> None:
        """Row ``row`` of ``block`` and its live timing (period error, step time, latency [ns], miss
        0/1, misses, skipped; None: no timing)."""
        h = self._sh
        if h - self._s_tail_seen >= self.ns:
            self._s_tail_seen = int(self.ctl[_S_TAIL])
            if h - self._s_tail_seen >= self.ns:
                self.ctl[_S_DROPPED] += 1
                return
        i = h & (self.ns - 1)
        self.t_ns[i] = block.t_ns[row]
        self.status[i] = block.status[row]
        self.est[i] = block.est[row]
        self.t_overlay[i] = block.t_overlay[row]
        self.overlay_state[i] = block.overlay_state[row]
        self.overlay_enable[i] = block.overlay_enable[row]
        self.inputs[i] = block.inputs[row]
        self.ages[i] = block.ages[row]
        self.valid_mask[i] = block.valid_mask[row]
        self.ok[i] = block.ok[row]
        self.frames_used[i] = block.frames_used[row]
        self.e2e_rejects[i] = block.e2e_rejects[row]
        self.frames[i] = block.frames[row]
        if timing is None:
            self.timing[i, 0] = _NO_TIMING
        else:
            self.timing[i] = timing
        self._sh = h + 1
        self.ctl[_S_HEAD] = h + 1

    def memory(self) -> np.ndarray:
        """The rings' shared memory as one uint8 array (the columns are views of it at
        :attr:`offsets`), for a compiled producer (:mod:`lde.service.handoff`)."""
        return np.frombuffer(self._mm, np.uint8)

    def published(self, frame_head: int, step_head: int) -> None:
        """A compiled producer stored rows up to these heads: make them visible to the writer."""
        self._fh = frame_head
        self.ctl[_F_HEAD] = frame_head
        self._sh = step_head
        self.ctl[_S_HEAD] = step_head

    # ------------------------------------------------------------------ consumer (writer)
    def take_frames(self) -> FrameBatch:
        """The frames written since the last call (copies), and frees their slots."""
        tail, head = int(self.ctl[_F_TAIL]), int(self.ctl[_F_HEAD])
        idx = np.arange(tail, head) & (self.nf - 1)
        data = self.f_word[idx].astype("<u8").view(np.uint8).reshape(-1, 8)
        if self.f_more is not None:  # bytes past a frame's length may be an older frame's: zeros
            data = np.concatenate([data, self.f_more[idx]], axis=1)
            data[np.arange(data.shape[1]) >= self.f_dlc[idx][:, None]] = 0
        fb = FrameBatch(
            t_ns=self.f_t[idx],
            can_id=self.f_id[idx],
            is_extended=self.f_ext[idx],
            dlc=self.f_dlc[idx],
            data=data,
            is_rx=self.f_rx[idx],
        )
        self.ctl[_F_TAIL] = head
        return fb

    def take_steps(self) -> tuple[StepBlock, Timing | None]:
        """The step rows written since the last call (copies) and their timing (None when a row has
        none), and frees their slots."""
        tail, head = int(self.ctl[_S_TAIL]), int(self.ctl[_S_HEAD])
        idx = np.arange(tail, head) & (self.ns - 1)
        block = StepBlock(**{f.name: getattr(self, f.name)[idx] for f in fields(StepBlock)})
        tm = self.timing[idx]
        self.ctl[_S_TAIL] = head
        timing = None
        if len(idx) and not np.any(tm[:, 0] == _NO_TIMING):
            timing = Timing(*(tm[:, k].copy() for k in range(6)))
        return block, timing

    @property
    def dropped(self) -> tuple[int, int]:
        """(frames, steps) dropped because the ring was full."""
        return int(self.ctl[_F_DROPPED]), int(self.ctl[_S_DROPPED])

    def close(self) -> None:
        for name in list(vars(self)):
            if isinstance(getattr(self, name), np.ndarray):
                setattr(self, name, None)
        with contextlib.suppress(BufferError):  # a view still alive: the mapping goes with the process
            self._mm.close()
        with contextlib.suppress(OSError):
            os.close(self.fd)


#: the recorder's writer process must have opened the file within this time [s]
_START_TIMEOUT_S = 120.0
#: a period error no live step has: "this row has no timing" (a replay's rows through Recorder.steps)
_NO_TIMING = np.iinfo(np.int64).min


def _word(data: bytes | bytearray) -> int:
    return int.from_bytes(bytes(data), "little")


#: a data word's 64 bits
_WORD = (1 << 64) - 1


class _WriterProcess:
    """The recorder's writer process. Forked when this process has no other thread (``lde run``: fast,
    and no lock can be held by a thread that the child would not have); otherwise a fresh interpreter
    (``python -m lde.io.recording``), because a fork would inherit locks that other threads hold (numba's
    compiler lock, say) and could hang on them."""

    def __init__(self, ring_fd: int, mine: socket.socket, theirs: socket.socket) -> None:
        self.pid = 0
        self.popen: subprocess.Popen | None = None
        if hasattr(os, "fork") and threading.active_count() == 1:
            pid = os.fork()
            if pid == 0:  # the child: never returns
                code = 1
                try:
                    mine.close()
                    _writer_main(ring_fd, theirs.detach())
                    code = 0
                finally:
                    os._exit(code)
            self.pid = pid
        else:
            cmd = [sys.executable, "-m", "lde.io.recording", str(ring_fd), str(theirs.fileno())]
            self.popen = subprocess.Popen(
                cmd, pass_fds=(ring_fd, theirs.fileno()), stdin=subprocess.DEVNULL, close_fds=True
            )

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

    The service's hot path stores each received/sent frame and each step's row in a preallocated
    ring in shared memory (:class:`StepRing`: a few array stores, no allocation, no lock); a writer
    process (:class:`_WriterProcess`: forked, or a fresh interpreter when other threads run) runs as
    background work, drains the rings every
    ``flush_interval_s``, writes small chunks and pushes them to the OS. The writing (JSON formatting,
    MCAP records, compression) thus never holds the service's interpreter lock. When the service dies
    (SIGKILL included), the writer sees its end of the connection close, writes what the rings hold
    and closes the file with its summary; if both are killed, at most about the last half second is
    lost.

    Use as a context manager or call :meth:`close` (idempotent; writes the summary/footer).

    Args:
        path: output ``.mcap`` file.
        metadata: strings stored in the ``lde`` metadata record (profile, vehicle, backend...).
        flush_interval_s: the writer writes and flushes a chunk this often [s].
        chunk_size: MCAP chunk size bound [bytes, uncompressed] (small: a crash loses little).
        extra_topics: more JSON channels, topic -> {field: JSON-schema property}, written with
            :meth:`json_columns` (the demo's ``/sim/truth``).
        ring_frames, ring_steps: ring capacities (powers of two; :class:`StepRing`).
        frame_bytes: data bytes kept per frame (:class:`StepRing`; the service's ``rx_width``).
    """

    def __init__(
        self,
        path: str | Path,
        metadata: dict[str, str] | None = None,
        flush_interval_s: float = 0.25,
        chunk_size: int = 64 * 1024,
        extra_topics: dict[str, dict[str, dict[str, str]]] | None = None,
        ring_frames: int = 1 << 16,
        ring_steps: int = 1 << 14,
        frame_bytes: int = 8,
    ) -> None:
        self.path = Path(path)
        meta = {k: str(v) for k, v in (metadata or {}).items()}
        try:  # a path that cannot be written is an error now, not in the writer (which opens it again)
            self.path.open("wb").close()
        except OSError as exc:
            raise LogFormatError(f"{path}: cannot write: {exc}") from exc
        self.ring = StepRing(ring_frames, ring_steps, frame_bytes=frame_bytes)
        self._extra_topics = dict(extra_topics or {})
        self._closed = False
        mine, theirs = socket.socketpair()
        try:
            self._proc = _WriterProcess(self.ring.fd, mine, theirs)
        except OSError as exc:
            mine.close()
            self.ring.close()
            raise LogFormatError(f"{path}: cannot start the recorder's writer process: {exc}") from exc
        finally:
            theirs.close()
        self._conn = Connection(mine.detach())
        self._conn.send(
            (self.path, meta, float(flush_interval_s), int(chunk_size), self._extra_topics,
             self.ring.nf, self.ring.ns, self.ring.n_outputs, self.ring.frame_bytes)
        )  # fmt: skip
        # the writer has the file open with its header written when this returns (or says why not)
        ok = self._conn.poll(_START_TIMEOUT_S) and self._reply()
        if not ok or ok[0] != "ready":
            self._proc.kill()
            self._proc.wait()
            self._conn.close()
            self.ring.close()
            self._closed = True
            why = ok[1] if ok else f"the writer process did not start within {_START_TIMEOUT_S:.0f} s"
            raise LogFormatError(f"{path}: cannot record: {why}")

    def _reply(self) -> tuple[Any, ...]:
        try:
            return self._conn.recv()
        except (EOFError, OSError) as exc:
            return ("error", f"{self.path}: the recorder's writer process ended ({exc or 'EOF'})")

    @property
    def failed(self) -> bool:
        """The writer could not write (disk full, ...): recording stopped, the service goes on."""
        return bool(self.ring.ctl[_FAILED]) if not self._closed else self._failed_at_close

    _failed_at_close = False
    _dropped_at_close = (0, 0)

    @property
    def dropped(self) -> tuple[int, int]:
        """(frames, steps) dropped because the writer did not keep up (the rings were full)."""
        return self.ring.dropped if not self._closed else self._dropped_at_close

    # ------------------------------------------------------------------ hot path
    def frame(self, t_ns: int, can_id: int, is_extended: bool, dlc: int, word: int, is_rx: bool) -> None:
        """A received (``is_rx``) or sent frame at ``t_ns`` [ns]; ``word``: its data bytes as a
        little-endian integer."""
        self.ring.put_frame(t_ns, can_id, is_extended, dlc, word, is_rx)

    def step(
        self, block: StepBlock, row: int = 0, timing: tuple[int, int, int, int, int, int] | None = None
    ) -> None:
        """One step's row of ``block`` (copied now) and its timing (:meth:`StepRing.put_step`)."""
        self.ring.put_step(block, row, timing)

    def rx(self, msg: can.Message) -> None:
        """A received frame (its timestamp is the receive time); its content is copied now."""
        self.ring.put_frame(
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
        self.ring.put_frame(
            seconds_to_ns(msg.timestamp),
            msg.arbitration_id,
            msg.is_extended_id,
            msg.dlc,
            _word(msg.data),
            False,
        )

    def steps(self, block: StepBlock, timing: Timing | None = None) -> None:
        """Rows of steps (copied now)."""
        for i in range(len(block)):
            tm = None
            if timing is not None:
                tm = tuple(int(getattr(timing, f.name)[i]) for f in fields(Timing))
            self.ring.put_step(block, i, tm)  # type: ignore[arg-type]

    def json_columns(self, topic: str, t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        """Many JSON messages at once on an ``extra_topics`` channel (one per element of ``t_ns``);
        not for the hot path (the columns go to the writer through a pipe)."""
        if topic not in self._extra_topics:
            raise ValueError(f"topic {topic!r} was not declared in extra_topics")
        self._conn.send(
            ("json", topic, np.asarray(t_ns, np.int64), {k: np.asarray(v) for k, v in columns.items()})
        )

    # ------------------------------------------------------------------ writer control
    def _drain(self) -> None:
        """Have the writer write and flush everything stored so far (returns when it has)."""
        if self._closed:
            return
        self._conn.send(("flush",))
        self._reply()

    def close(self) -> None:
        """Write everything stored, the summary and the footer; close the file; end the writer."""
        if self._closed:
            return
        try:
            self._conn.send(("close",))
            r = self._reply()
            if r[0] == "error":
                log.error("%s", r[1])
            self._failed_at_close = bool(self.ring.ctl[_FAILED]) or r[0] != "closed"
        except (BrokenPipeError, OSError) as exc:
            self._failed_at_close = True
            log.error("recording to %s: the writer process is gone (%s)", self.path, exc)
        self._closed = True
        try:
            self._proc.wait(30.0)
        except subprocess.TimeoutExpired:  # pragma: no cover - a hung writer must not hang the exit
            self._proc.kill()
            self._proc.wait()
        self._conn.close()
        self._dropped_at_close = dropped = self.ring.dropped
        if any(dropped):
            log.warning("recording %s: ring full, dropped %d frames and %d steps", self.path, *dropped)
        self.ring.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


def _writer_main(ring_fd: int, conn_fd: int) -> None:
    """The writer process (``python -m lde.io.recording RING_FD CONN_FD``): drain the rings every flush
    interval until told to close or until the service is gone (its end of the connection closes),
    then close the file."""
    # Ctrl-C reaches the whole process group, a service manager's SIGTERM maybe too: the writer
    # ends when the service tells it to (or is gone), after writing what the rings hold
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    _background_priority()
    conn: Connection | None = Connection(conn_fd)
    assert conn is not None
    path, meta, flush_interval, chunk_size, extra_topics, nf, ns, n_out, width = conn.recv()
    ring = StepRing(nf, ns, n_out, fd=ring_fd, frame_bytes=width)
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

    def drain() -> None:
        nonlocal failed
        fb = ring.take_frames()
        block, timing = ring.take_steps()
        if failed:
            return
        try:
            if len(fb):
                w.write_frames(fb)
            if len(block):
                steps.write(block, timing)
            _sync(w)
        except (OSError, ValueError) as exc:  # disk full, closed file: stop recording, keep draining
            log.error("recording to %s failed, recording stopped: %s", path, exc)
            failed = True
            ring.ctl[_FAILED] = 1

    while True:
        try:
            if conn is None:
                raise EOFError
            if not conn.poll(flush_interval):
                drain()
                continue
            cmd = conn.recv()
        except (EOFError, OSError):  # the service is gone: write what it left, then close
            cmd = ("close",)
            conn = None
        if cmd[0] == "flush":
            drain()
            if conn is not None:
                conn.send(("flushed",))
        elif cmd[0] == "json":
            if not failed:
                w.write_json_columns(extra[cmd[1]], cmd[2], cmd[3])
        elif cmd[0] == "close":
            drain()
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
    _writer_main(int(sys.argv[1]), int(sys.argv[2]))
