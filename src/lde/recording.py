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
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np
from mcap.exceptions import McapError
from mcap.records import Channel, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from .errors import LogFormatError
from .frames import FrameBatch, seconds_to_ns
from .logio.mcapfile import CAN_PAYLOAD_SIZE, TOPIC_RX, TOPIC_TX, McapWriter
from .profiles import INPUT_NAMES
from .step import Status

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

#: ``Status`` bits (docs/ARCHITECTURE.md) -> flat 0/1 fields of ``/lde/estimate``, bit 0 first
STATUS_BITS: tuple[str, ...] = tuple(str(flag.name).lower() for flag in Status)
#: estimator input names (SI) recorded on ``/lde/inputs``
INPUT_FIELDS: tuple[str, ...] = INPUT_NAMES


def _props(types: dict[str, str], doc: dict[str, str]) -> dict[str, dict[str, str]]:
    return {k: {"type": t, "description": doc.get(k, "")} for k, t in types.items()}


#: ``/lde/estimate`` fields (the step time t_k is the message's log time, exact in ns)
ESTIMATE_PROPS = _props(
    {
        "Fw": "number",
        "Mw": "number",
        "T_align": "number",
        "T_overlay": "number",
        "overlay_state": "integer",
        "overlay_active": "integer",
        "overlay_enable": "integer",
        "status": "integer",
        **{b: "integer" for b in STATUS_BITS},
    },
    {
        "Fw": "disturbance force at the CG [N], left positive",
        "Mw": "disturbance yaw moment [Nm], left positive",
        "T_align": "aligning torque on the steering axis [Nm], paper sign",
        "T_overlay": "overlay torque request sent [Nm] at the column, left positive",
        "overlay_state": "0 off, 1 ramp-in, 2 active, 3 ramp-out, 4 fault",
        "overlay_active": "the Active bit sent",
        "overlay_enable": "0: overlay switched off (--no-overlay) or ramping out at shutdown",
        "status": "LDE_Estimate.Status bit map",
        **{b: f"Status bit{i}" for i, b in enumerate(STATUS_BITS)},
    },
)
INPUTS_PROPS = _props(
    {**{f: "number" for f in INPUT_FIELDS}, "mdps_ok": "integer", "esc_ok": "integer"},
    {
        "column_torque": "Nm, left positive",
        "assist_torque": "Nm, left positive",
        "steering_angle": "rad (steering wheel), left positive",
        "steering_rate": "rad/s (steering wheel), left positive",
        "yaw_rate": "rad/s, left positive",
        "lat_accel": "m/s^2, left positive",
        "speed": "m/s",
        "mdps_ok": "1 if the MDPS input is valid (fresh, E2E ok)",
        "esc_ok": "1 if the ESC input is valid (fresh, E2E ok)",
    },
)
DIAG_PROPS = _props(
    {
        "period_error_us": "number",
        "step_time_us": "number",
        "latency_us": "number",
        "deadline_miss": "integer",
        "deadline_misses": "integer",
        "skipped": "integer",
        "e2e_rejects": "integer",
        "frames_used": "integer",
    },
    {
        "period_error_us": "actual minus nominal step start [us]",
        "step_time_us": "compute time of the step up to the send of its outputs [us]",
        "latency_us": "newest input frame used -> outputs sent [us] (-1: no input yet)",
        "deadline_miss": "1 if this step started more than 1 ms late",
        "deadline_misses": "late steps plus skipped grid points since start",
        "skipped": "grid points skipped after overruns since start",
        "e2e_rejects": "frames rejected by the E2E receiver since start",
        "frames_used": "input frames used in this step",
    },
)


EVENTS_PROPS = _props(
    {"overlay_enable": "integer"},
    {"overlay_enable": "the limiter's enable input from this step on (0: switched off or ramping out)"},
)


def _estimate_record(res: Any) -> dict[str, Any]:
    d: dict[str, Any] = {
        "Fw": res.fw,
        "Mw": res.mw,
        "T_align": res.t_align,
        "T_overlay": res.t_overlay,
        "overlay_state": res.overlay_state,
        "overlay_active": int(res.overlay_active),
        "overlay_enable": int(getattr(res, "overlay_enable", True)),
        "status": res.status,
    }
    for i, name in enumerate(STATUS_BITS):
        d[name] = (res.status >> i) & 1
    return d


def _inputs_record(inputs: Any) -> dict[str, Any]:
    d: dict[str, Any] = {}
    for f in INPUT_FIELDS:
        v = getattr(inputs, f, None)
        d[f] = float(v) if v is not None else None
    d["mdps_ok"] = int(bool(getattr(inputs, "mdps_ok", 0)))
    d["esc_ok"] = int(bool(getattr(inputs, "esc_ok", 0)))
    return d


def _diag_record(res: Any, skipped: int, e2e_rejects: int) -> dict[str, Any]:
    tm = res.timing
    return {
        "period_error_us": tm.period_error_ns / 1e3,
        "step_time_us": tm.step_time_ns / 1e3,
        "latency_us": tm.latency_ns / 1e3 if tm.latency_ns >= 0 else -1.0,
        "deadline_miss": int(tm.deadline_miss),
        "deadline_misses": tm.deadline_misses,
        "skipped": skipped,
        "e2e_rejects": e2e_rejects,
        "frames_used": res.frames_used,
    }


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
    sync = getattr(writer, "sync", None)
    if sync is not None:
        sync()
    else:  # lde.logio's McapWriter.flush() writes the chunks but does not flush the file object
        fh = getattr(writer, "_f", None)
        if fh is not None:
            fh.flush()


class Recorder:
    """Writes a live run to an MCAP file (:class:`lde.logio.McapWriter`) from a background thread.

    Hot-path methods (:meth:`rx`, :meth:`tx`, :meth:`step`) append to a deque and return.
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
        self._ch_est = w.add_json_channel(ESTIMATE_TOPIC, ESTIMATE_PROPS, title="lde.Estimate")
        self._ch_in = w.add_json_channel(INPUTS_TOPIC, INPUTS_PROPS, title="lde.Inputs")
        self._ch_diag = w.add_json_channel(DIAG_TOPIC, DIAG_PROPS, title="lde.Diag")
        self._ch_events = w.add_json_channel(EVENTS_TOPIC, EVENTS_PROPS, title="lde.Events")
        self._last_enable: int | None = None
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
        """A received frame (its timestamp is the receive time)."""
        self._q.append((0, msg))

    def tx(self, msg: can.Message) -> None:
        """A sent frame (its timestamp is the send time)."""
        self._q.append((1, msg))

    def step(self, res: Any, inputs: Any, e2e_rejects: int = 0, skipped: int = 0) -> None:
        """One step's result (:class:`lde.service.StepResult`), its sampled inputs and counters."""
        self._q.append((2, res, inputs, e2e_rejects, skipped))

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
            while q:
                item = q.popleft()
                kind = item[0]
                if kind < 2:
                    msg = item[1]
                    data = bytes(msg.data)
                    w.write_frame(
                        seconds_to_ns(msg.timestamp),
                        int(msg.arbitration_id),
                        bool(msg.is_extended_id),
                        len(data),
                        data,
                        kind == 0,
                    )
                elif kind == 3:
                    _, topic, t_arr, cols = item
                    w.write_json_columns(self._ch_extra[topic], t_arr, cols)
                else:
                    _, res, inputs, rejects, skipped = item
                    t = res.t_ns
                    rec = _estimate_record(res)
                    w.write_json(self._ch_est, t, rec)
                    if rec["overlay_enable"] != self._last_enable:
                        self._last_enable = rec["overlay_enable"]
                        w.write_json(self._ch_events, t, {"overlay_enable": self._last_enable})
                    w.write_json(self._ch_in, t, _inputs_record(inputs))
                    if res.timing is not None:
                        w.write_json(self._ch_diag, t, _diag_record(res, skipped, rejects))
            _sync(w)
        except (OSError, ValueError) as exc:  # disk full, closed file: stop recording, keep the loop
            log.error("recording to %s failed, recording stopped: %s", self.path, exc)
            q.clear()
            self.failed = True

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
