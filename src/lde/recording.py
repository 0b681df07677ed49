"""Recording of a live run to MCAP, crash-tolerant, and a reader that recovers an unfinished file.

Channels (documented in ``docs/service.md``; JSON channels have flat numeric fields so that
Foxglove's plot panel can plot every field directly):

==================  ===========================  ==================================================
topic               encoding                     content
==================  ===========================  ==================================================
``/can/rx``         :mod:`lde.logio` CAN schema  every frame the service received (receive time)
``/can/tx``         :mod:`lde.logio` CAN schema  every frame the service sent (send time)
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

Crash tolerance: the hot path only appends to a deque; a writer thread drains it every
``flush_interval_s`` (default 0.25 s), writes small chunks and flushes them to the file
(:meth:`lde.logio.McapWriter.flush` writes the queued messages as chunks). A SIGKILL therefore loses at
most about the last half second. :func:`read_recording` reads a file sequentially and stops cleanly
at a truncated tail, so a file without footer/summary still gives everything up to its last
complete chunk.
"""

from __future__ import annotations

import json
import logging
import os
import struct
import threading
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import can
import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from .engine import StepBlock
from .errors import LogFormatError
from .frames import FrameBatch, seconds_to_ns
from .logio.mcapfile import CAN_PAYLOAD_SIZE, TOPIC_RX, TOPIC_TX, McapWriter
from .logio.textfmt import EXACT, Column, format_rows, time_column
from .profiles import INPUT_NAMES
from .status import DEADLINE_MISS, STATUS_BITS

__all__ = [
    "Recorder",
    "Recording",
    "read_recording",
    "iter_records",
    "ESTIMATE_TOPIC",
    "INPUTS_TOPIC",
    "DIAG_TOPIC",
    "EVENTS_TOPIC",
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
#: ``lde`` metadata key: the learned-state file's text a live run started from (``--learned``), so
#: that a replay of the recording starts from it too (:func:`lde.replay.run_replay`)
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
    column is taken from a :class:`lde.engine.StepBlock` (and the live timing)."""

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
        *(_int(name, f"Status bit{i}", _status_bit(i)) for i, name in enumerate(STATUS_BITS)),
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
    """Writes rows of steps (:class:`lde.engine.StepBlock`) as the recording's step topics and the
    sparse ``/lde/events`` channel into an :class:`lde.logio.McapWriter`: the one definition used by
    the live :class:`Recorder` and by :func:`lde.replay.write_recording`.

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


def _write_json_channel(w: McapWriter, cid: int, t: np.ndarray, cols: list[Column]) -> None:
    seps = [("{" if i == 0 else ",") + f'"{c.name}":' for i, c in enumerate(cols)]
    text, off = format_rows(cols, seps, "}", nan_text="null")
    w.write_json_payloads(cid, t, text, off)


def _normal_priority() -> None:
    """Run the calling thread on the normal scheduler: created by a SCHED_FIFO service (``--realtime``)
    it would inherit the loop's real-time priority, and writing files is not real-time work."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):  # not Linux, or not permitted: keep what we have
        pass


def _sync(writer: McapWriter) -> None:
    """Write the queued messages as chunks and push them to the OS (survives a SIGKILL)."""
    writer.flush()
    writer.sync()


class Recorder:
    """Writes a live run to an MCAP file (:class:`lde.logio.McapWriter`) from a background thread.

    Hot-path methods (:meth:`rx`, :meth:`tx`, :meth:`steps`) append to a deque and return.
    Use as a context manager or call :meth:`close` (idempotent; writes the summary/footer).

    Args:
        path: output ``.mcap`` file.
        metadata: strings stored in the ``lde`` metadata record (profile, vehicle, backend...).
        flush_interval_s: the writer thread writes and flushes a chunk this often [s].
        chunk_size: MCAP chunk size bound [bytes, uncompressed] (small: a crash loses little).
        extra_topics: more JSON channels, topic -> {field: JSON-schema property}, written with
            :meth:`json_columns` (the demo's ``/sim/truth``).
    """

    def __init__(
        self,
        path: str | Path,
        metadata: dict[str, str] | None = None,
        flush_interval_s: float = 0.25,
        chunk_size: int = 64 * 1024,
        extra_topics: dict[str, dict[str, dict[str, str]]] | None = None,
    ) -> None:
        self.path = Path(path)
        meta = {k: str(v) for k, v in (metadata or {}).items()}
        self._writer = McapWriter(self.path, chunk_size=chunk_size, buffer_bytes=64 << 20, metadata=meta)
        w = self._writer
        self._steps = StepTopicWriter(w)
        self._ch_extra = {t: w.add_json_channel(t, props) for t, props in (extra_topics or {}).items()}
        _sync(w)
        self._q: deque[tuple[Any, ...]] = deque()
        self._flush_interval = float(flush_interval_s)
        self._stop = threading.Event()
        self._closed = False
        self.failed = False
        self._thread = threading.Thread(target=self._loop, name="lde-recorder", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ hot path
    def rx(self, msg: can.Message) -> None:
        """A received frame (its timestamp is the receive time); its content is copied now."""
        self._q.append(
            (0, seconds_to_ns(msg.timestamp), msg.arbitration_id, msg.is_extended_id, bytes(msg.data))
        )

    def tx(self, msg: can.Message) -> None:
        """A sent frame (its timestamp is the send time); its content is copied now (the sender
        may reuse the message object)."""
        self._q.append(
            (1, seconds_to_ns(msg.timestamp), msg.arbitration_id, msg.is_extended_id, bytes(msg.data))
        )

    def steps(self, block: StepBlock, timing: Timing | None = None) -> None:
        """Rows of steps (the recorder keeps them: pass a block that is not reused)."""
        self._q.append((2, block, timing))

    def json_columns(self, topic: str, t_ns: np.ndarray, columns: dict[str, np.ndarray]) -> None:
        """Many JSON messages at once on an ``extra_topics`` channel (one per element of ``t_ns``)."""
        if topic not in self._ch_extra:
            raise ValueError(f"topic {topic!r} was not declared in extra_topics")
        self._q.append((3, topic, np.asarray(t_ns, np.int64), dict(columns)))

    # ------------------------------------------------------------------ writer thread
    def _loop(self) -> None:
        _normal_priority()
        while not self._stop.wait(self._flush_interval):
            self._drain()

    def _drain(self) -> None:
        q = self._q
        if not q or self.failed:
            q.clear()
            return
        w = self._writer
        try:
            blocks: list[StepBlock] = []
            timings: list[Timing] = []
            while q:
                item = q.popleft()
                kind = item[0]
                if kind < 2:
                    self._write_steps(blocks, timings)
                    _, t_ns, can_id, ext, data = item
                    w.write_frame(t_ns, int(can_id), bool(ext), len(data), data, kind == 0)
                elif kind == 2:
                    blocks.append(item[1])
                    if item[2] is not None:
                        timings.append(item[2])
                else:
                    self._write_steps(blocks, timings)
                    _, topic, t_arr, cols = item
                    w.write_json_columns(self._ch_extra[topic], t_arr, cols)
            self._write_steps(blocks, timings)
            _sync(w)
        except (OSError, ValueError) as exc:  # disk full, closed file: stop recording, keep the loop
            log.error("recording to %s failed, recording stopped: %s", self.path, exc)
            q.clear()
            self.failed = True

    def _write_steps(self, blocks: list[StepBlock], timings: list[Timing]) -> None:
        """The step rows collected so far, as one columnar write (then cleared)."""
        if not blocks:
            return
        block = StepBlock.concat(blocks)
        timing = Timing.concat(timings) if len(timings) == len(blocks) else None
        self._steps.write(block, timing)
        blocks.clear()
        timings.clear()

    # ------------------------------------------------------------------ end
    def close(self) -> None:
        """Write everything queued, the summary and the footer; close the file."""
        if self._closed:
            return
        self._closed = True
        self._stop.set()
        self._thread.join()
        self._drain()
        try:
            self._writer.close()
        except (OSError, ValueError) as exc:
            log.error("closing recording %s failed: %s", self.path, exc)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


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


def iter_records(path: str | Path) -> Iterator[Any]:
    """MCAP records of ``path`` in file order; stops silently at a truncated or corrupt tail."""
    try:
        fh = Path(path).open("rb")  # noqa: SIM115 - closed by the with below (a generator)
    except OSError as exc:
        raise LogFormatError(f"cannot read {path}: {exc}") from exc
    with fh:
        reader = StreamReader(fh, record_size_limit=1 << 28)
        it = reader.records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                return
            except (McapError, struct.error, EOFError, ValueError, MemoryError) as exc:
                log.info("%s: stopped at a truncated/corrupt record (%s)", path, type(exc).__name__)
                return
            yield rec


def _columns(rows: list[tuple[int, dict[str, Any]]]) -> dict[str, np.ndarray]:
    """Per-field columns; ``t_ns`` (int64) is each message's log time."""
    if not rows:
        return {}
    rows = sorted(rows, key=lambda r: r[0])
    out: dict[str, np.ndarray] = {"t_ns": np.array([t for t, _ in rows], np.int64)}
    keys: dict[str, None] = {}
    for _, r in rows:
        for k in r:
            keys.setdefault(k, None)
    for k in keys:
        vals = [r.get(k) for _, r in rows]
        if all(isinstance(v, int) and not isinstance(v, bool) for v in vals):
            out[k] = np.array(vals, dtype=np.int64)
        else:
            out[k] = np.array([np.nan if v is None else v for v in vals], dtype=np.float64)
    return out


def _frames(payloads: list[tuple[int, bytes]]) -> FrameBatch:
    """CAN frames from (log_time, CDR payload) pairs (layout: :mod:`lde.logio.mcapfile`)."""
    good = [(t, p) for t, p in payloads if len(p) == CAN_PAYLOAD_SIZE]
    if not good:
        return FrameBatch.empty()
    n = len(good)
    p = np.frombuffer(b"".join(pl for _, pl in good), np.uint8).reshape(n, CAN_PAYLOAD_SIZE)
    return FrameBatch(
        t_ns=np.array([t for t, _ in good], np.int64),
        can_id=p[:, 4:8].copy().view("<u4").reshape(n),
        is_extended=p[:, 8] != 0,
        dlc=p[:, 10],
        data=p[:, 11:19],
        is_rx=p[:, 9] != 0,
    ).sort()


def read_recording(path: str | Path) -> Recording:
    """Read a recording written by :class:`Recorder`, recovering a file that has no footer.

    Raises :class:`LogFormatError` when the file is not MCAP at all.
    """
    channels: dict[int, str] = {}
    can_rows: dict[str, list[tuple[int, bytes]]] = {CAN_RX_TOPIC: [], CAN_TX_TOPIC: []}
    topics = (ESTIMATE_TOPIC, INPUTS_TOPIC, DIAG_TOPIC)
    rows: dict[str, list[tuple[int, dict[str, Any]]]] = {t: [] for t in topics}
    meta: dict[str, str] = {}
    complete = False
    n = 0
    for rec in iter_records(path):
        n += 1
        if isinstance(rec, Channel):
            channels[rec.id] = rec.topic
        elif isinstance(rec, Message):
            topic = channels.get(rec.channel_id)
            if topic in can_rows:
                can_rows[topic].append((rec.log_time, bytes(rec.data)))
            elif topic in rows:
                try:
                    rows[topic].append((rec.log_time, json.loads(rec.data)))
                except ValueError:
                    continue
        elif isinstance(rec, Metadata) and rec.name == "lde":
            meta = dict(rec.metadata)
        elif isinstance(rec, Schema):
            continue
        elif type(rec).__name__ == "Footer":
            complete = True
    if n == 0:
        raise LogFormatError(f"{path}: not an MCAP file (no readable records)")
    return Recording(
        rx=_frames(can_rows[CAN_RX_TOPIC]),
        tx=_frames(can_rows[CAN_TX_TOPIC]),
        estimate=_columns(rows[ESTIMATE_TOPIC]),
        inputs=_columns(rows[INPUTS_TOPIC]),
        diag=_columns(rows[DIAG_TOPIC]),
        metadata=meta,
        complete=complete,
    )
