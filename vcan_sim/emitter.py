"""Frames at their periods: the profile's input messages, encoded through the DBC with counters and
CRCs (:func:`lde.can.codec.encode_frames`), and the pump that puts them on a python-can bus.

Schedule: every input message of the profile is sent at its DBC period (``lde``: MDPS_Sensors every
3.9 ms, ESC_Motion every 10 ms; ``hyundai``: MDPS12, SAS11 every 10 ms, ESP12, WHL_SPD11 every 20 ms),
the anchor (MDPS torque) message from the simulation start, the others offset by a fixed phase
(``PHASE_NS`` times their position) as on a real bus where ECUs are not synchronised. A frame at
time t samples the plant at the last sub-step at or before t (see :mod:`vcan_sim.sensors`).
Counters start at 0 and run on per message (Profile 1: 0..14).
"""

from __future__ import annotations

import gc
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import numpy as np

from lde.can.busio import drain
from lde.can.codec import MessageCodec, MessageEncoder, encode_frames, si_to_dbc
from lde.can.frames import FrameBatch, data_width, ns_to_seconds
from lde.can.profiles import Profile
from lde.clock import MonotonicClock
from lde.units import STEP_NS

from .config import SensorParams
from .faults import Fault, apply_faults, hit_mask
from .plant import O_VW1, O_VW2, O_VW3, O_VW4
from .sensors import SensorNoise, angle_below_torsion_bar, measure

log = logging.getLogger(__name__)

#: phase offset between the input messages' schedules [ns] (message i starts at i * PHASE_NS)
PHASE_NS = 1_300_000


@dataclass
class MessageStream:
    """The whole run's schedule of one input message.

    Attributes: name; inputs (estimator inputs it carries); t_rel_ns (frame times from the simulation
    start); sample (plant sub-step index of each frame); noise (pre-drawn); unsigned (signals whose
    DBC range starts at 0: the magnitude is sent); sent (frames emitted so far).
    """

    name: str
    inputs: tuple[str, ...]
    t_rel_ns: np.ndarray
    sample: np.ndarray
    noise: SensorNoise
    unsigned: frozenset[str] = frozenset()
    modulus: int = 15
    sent: int = 0
    encoder: MessageEncoder | None = None  # scalar path for the few frames of one live step
    fault_hits: list[tuple[Fault, np.ndarray]] = field(default_factory=list)
    checksum_fields: tuple[tuple[int, int, bool], ...] = ()
    last_data: np.ndarray | None = None  # data of the last frame sent (REPEAT faults)


def build_streams(
    profile: Profile,
    duration_ns: int,
    h_ns: int,
    sp: SensorParams,
    rng: np.random.Generator,
    faults: tuple[Fault, ...] = (),
) -> list[MessageStream]:
    """Schedules of the profile's input messages (anchor message first), with their injected faults."""
    names = [profile.anchor_message] + [m for m in profile.messages if m != profile.anchor_message]
    streams = []
    for i, name in enumerate(names):
        spec = profile.messages[name]
        t = np.arange(i * PHASE_NS, duration_ns, spec.period_ns, dtype=np.int64)
        codec = MessageCodec(profile, name)
        unsigned = frozenset(
            inp
            for inp in spec.inputs
            if all(
                not codec.signals[s].signed and (codec.signals[s].minimum or 0.0) >= 0.0
                for s in profile.inputs[inp].signals
            )
        )
        streams.append(
            MessageStream(
                name=name,
                inputs=spec.inputs,
                t_rel_ns=t,
                sample=t // h_ns,
                noise=SensorNoise.draw(spec.inputs, t.size, sp, rng),
                unsigned=unsigned,
                modulus=spec.scheme.modulus,
                encoder=MessageEncoder(profile, name),
                fault_hits=[(f, hit_mask(f, t)) for f in faults if name in f.messages(profile)],
                checksum_fields=spec.scheme.checksum_fields,
            )
        )
    return streams


def emit_range(
    profile: Profile,
    stream: MessageStream,
    k0: int,
    k1: int,
    out_ring: np.ndarray,
    delay: int,
    sp: SensorParams,
    t0_ns: int,
) -> FrameBatch | None:
    """Encode the frames of ``stream`` whose samples lie in sub-steps [k0, k1); advance ``stream.sent``.

    ``out_ring`` holds plant output rows indexed ``k % len(out_ring)`` (it must still hold k0 - delay).
    """
    a = stream.sent
    b = int(np.searchsorted(stream.sample, k1, side="left"))
    if b <= a:
        return None
    idx = stream.sample[a:b]
    if idx[0] < k0 - delay:
        raise RuntimeError("emitter fell behind the plant's output ring")
    r = out_ring.shape[0]
    rows = out_ring[idx % r]
    rows_d = out_ring[np.maximum(idx - delay, 0) % r]
    si = measure(
        stream.inputs,
        rows,
        rows_d,
        stream.noise,
        slice(a, b),
        sp,
        angle_below_torsion_bar(sp, stream.name),
    )
    for name in stream.unsigned:
        si[name] = np.abs(si[name])
    cols = si_to_dbc(profile, stream.name, si)
    if "speed" in stream.inputs:
        _wheel_speeds(profile, cols, rows, stream.noise.values["speed"][a:b])
    t_abs = t0_ns + stream.t_rel_ns[a:b]
    if b - a <= _SCALAR_MAX and stream.encoder is not None:
        frames = _encode_scalar(stream, cols, t_abs, a)
    else:
        arrays = {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}
        frames = encode_frames(profile, stream.name, t_abs, arrays, counter_start=_counter(a, stream.modulus))
    frames, stream.last_data = apply_faults(
        frames, stream.fault_hits, a, stream.checksum_fields, stream.last_data
    )
    stream.sent = b
    return frames


#: wheel-speed signal suffix -> plant output (FL, FR, RL, RR)
_WHEELS = {"_FL": O_VW1, "_FR": O_VW2, "_RL": O_VW3, "_RR": O_VW4}


def _wheel_speeds(profile: Profile, cols: dict, rows: np.ndarray, noise: np.ndarray) -> None:
    """A speed input carried by four wheel-speed signals (hyundai WHL_SPD11) gets each wheel's own
    speed (outer wheels faster in a turn; their mean is the vehicle speed), same noise on all four."""
    im = profile.inputs["speed"]
    if len(im.signals) != 4:
        return
    for sig in im.signals:
        col = next((o for suffix, o in _WHEELS.items() if sig.upper().endswith(suffix)), None)
        if col is not None:
            cols[sig] = im.to_dbc(np.abs(rows[:, col] + noise))


_SCALAR_MAX = 3  # up to this many frames: one MessageEncoder.encode each (cheaper than a batch)


def _encode_scalar(stream: MessageStream, cols: dict, t_abs: np.ndarray, first: int) -> FrameBatch:
    """The same bytes as :func:`encode_frames`, frame by frame (the live step path)."""
    enc = stream.encoder
    assert enc is not None  # emit_range only calls this with an encoder
    n = t_abs.shape[0]
    data = np.zeros((n, data_width(enc.codec.length)), np.uint8)
    for i in range(n):
        enc.counter = _counter(first + i, stream.modulus)
        raw = enc.encode({k: float(np.asarray(v).reshape(-1)[i]) for k, v in cols.items()})
        data[i, : len(raw)] = np.frombuffer(raw, np.uint8)
    length = enc.codec.length
    return FrameBatch(
        t_ns=t_abs,
        can_id=np.full(n, enc.frame_id, np.uint32),
        is_extended=np.zeros(n, bool),
        dlc=np.full(n, length, np.uint8),
        data=data,
        is_rx=np.ones(n, bool),
    )


def _counter(n_sent: int, modulus: int) -> int:
    # encode_frames counts (start + i) % modulus: Profile 1's modulus 15 already skips 15
    return n_sent % modulus


# ------------------------------------------------------------------------------ bus pump


@dataclass
class PumpStats:
    """What :func:`pump` did.

    Attributes:
        sent, send_errors: frames the bus took / refused (a refused frame is counted, never retried).
        received, overlay_used: frames read from the bus (closed loop) / accepted as overlay requests.
        steps: simulation steps (3.9 ms each); stale_overlay_steps: closed-loop steps that found no new
            overlay frame since the previous step and ran on the last request (the receiver ramps it
            out after the message timeout).
        rx_full_steps: closed-loop steps that took in :data:`MAX_RX_PER_STEP` frames and left the
            rest queued for the next step (a bus busier than the loop's traffic).
        max_late_s, late_frames: the largest lateness [s] of a frame against its schedule, and the
            frames sent more than :data:`LATE_S` after their time.
        slips, slipped_s: how often the schedule was moved later because the simulator fell more than
            :data:`MAX_LAG_S` behind, and by how much in all [s] (its traffic then ends that much later).
        wall_s, cpu_s, sim_s: wall-clock time from the first frame to the end (slips included), CPU
            time, simulated time [s].
    """

    sent: int = 0
    received: int = 0
    overlay_used: int = 0
    send_errors: int = 0
    steps: int = 0
    stale_overlay_steps: int = 0
    rx_full_steps: int = 0
    max_late_s: float = 0.0
    late_frames: int = 0
    slips: int = 0
    slipped_s: float = 0.0
    wall_s: float = 0.0
    cpu_s: float = 0.0
    sim_s: float = 0.0
    frames: list[FrameBatch] = field(default_factory=list)


#: a frame sent later than this after its time counts as late [s] (1 ms: a quarter MDPS period)
LATE_S = 1e-3
#: behind schedule by more than this, the simulator moves its schedule instead of sending a burst to
#: catch up [s]: three MDPS periods, the receiver's input timeout, past which the frames are stale anyway
MAX_LAG_S = 3 * STEP_NS * 1e-9
#: closed loop: at most this many received frames are taken in per step, so that a flood cannot hold
#: up the simulator's own sends; the rest stay queued for the next step (counted: ``rx_full_steps``)
MAX_RX_PER_STEP = 64


def to_messages(frames: FrameBatch, channel: str | None = None) -> list[can.Message]:
    """python-can messages with the frames' (simulated) timestamps."""
    return [
        can.Message(
            timestamp=ns_to_seconds(int(frames.t_ns[i])),
            arbitration_id=int(frames.can_id[i]),
            is_extended_id=bool(frames.is_extended[i]),
            dlc=int(frames.dlc[i]),
            data=bytes(frames.data[i, : frames.dlc[i]]),
            is_fd=int(frames.dlc[i]) > 8,
            channel=channel,
        )
        for i in range(len(frames))
    ]


def pump(
    sim,
    bus: can.BusABC,
    *,
    realtime: bool = True,
    closed_loop: bool = True,
    receiver=None,
    keep_frames: bool = False,
    stop: Callable[[], bool] | None = None,
    after_step: Callable[[], None] | None = None,
    spin_s: float = 0.0,
    send_trace: list[tuple[int, int, int, int]] | None = None,
) -> PumpStats:
    """Run ``sim`` (a :class:`vcan_sim.run.Simulation`) to its end, sending its frames on ``bus``.

    ``realtime``: each frame goes out when the wall clock reaches its simulated time; else as fast as
    possible with the simulated timestamps. ``closed_loop``: frames received from the bus go to
    ``receiver`` (a :class:`vcan_sim.closed_loop.OverlayReceiver`) and its request drives the overlay
    torque.

    In real time the pump never waits for another process, so that it may run at a real-time
    priority on a CPU it shares with the service it feeds (user-mode Linux): it sleeps until the
    next frame's time (a timed sleep: no frame wakes it), then takes in the overlay frames that have
    arrived (non-blocking) and steps with the newest request; a step that finds none runs on the
    last request (counted: ``stale_overlay_steps``). Sends do not wait either (``timeout=0``: a full
    queue is a counted send error). Behind schedule it sends at once; more than :data:`MAX_LAG_S`
    behind (after a stall) it moves the rest of its schedule later (``slips``) instead of sending a
    burst of stale frames. ``stop`` is asked before each step (True ends the run); ``after_step`` is
    called once a step's frames are sent, before the wait for the next one (the streaming writer's
    flush goes there: into the time the pump would sleep).

    ``spin_s`` [s] (real time): sleep until this long before a frame's time, then busy-wait to it: a
    timed sleep alone wakes 50-150 us late on this project's VM, and a service whose grid follows the
    MDPS frames takes that jitter as its input. Only where the simulator has a CPU of its own (it
    spins up to ``spin_s`` per frame). ``send_trace``: a list to which each frame's (scheduled time,
    time before its send, time after it, CAN id) is appended, ``time.monotonic_ns`` [ns] (the
    benchmark's decomposition of the live loop's period error, ``bench/bench_loop.py --trace``).
    """
    st = PumpStats()
    clock = MonotonicClock(spin_ns=round(spin_s * 1e9))  # sleep, then spin the last spin_s
    # what exists now (modules, DBC objects, the schedules) leaves the collector's view: a full
    # collection during the run then scans only what the run allocates (a full scan of everything
    # takes tens of ms on a slow CPU, longer than the MDPS frame's timeout)
    gc.collect()
    gc.freeze()
    cpu0 = time.process_time()
    sim0 = sim.t_ns
    wall0: float | None = None  # the schedule's origin: set at the first frame, moved by slips
    wall_first = 0.0  # when the first frame went out
    listen = closed_loop and receiver is not None
    send_timeout = 0.0 if realtime else None  # real time: never block in send

    def take_arrived() -> None:
        n = 0
        for msg in drain(bus, MAX_RX_PER_STEP):
            n += 1
            if receiver.on_message(msg, sim.t_ns) is not None:
                st.overlay_used += 1
        st.received += n
        st.rx_full_steps += n == MAX_RX_PER_STEP

    while not sim.done:
        if stop is not None and stop():
            break
        req = None
        if listen:
            used = st.overlay_used
            take_arrived()
            if st.steps > 0 and st.overlay_used == used:
                st.stale_overlay_steps += 1
            req = receiver.request(sim.t_ns)
        frames = sim.step(req)
        st.steps += 1
        if keep_frames:
            st.frames.append(frames)
        for msg in to_messages(frames):
            t_rel = (int(round(msg.timestamp * 1e9)) - sim0) * 1e-9
            if wall0 is None:
                wall_first = time.monotonic()
                wall0 = wall_first - t_rel
            if realtime:
                now = time.monotonic()
                due = wall0 + t_rel
                wait = due - now
                if wait > 0:
                    clock.sleep_until(round(due * 1e9))  # a timed sleep: no frame on the bus wakes it
                elif -wait > MAX_LAG_S:  # move the schedule: no burst of stale frames
                    st.slips += 1
                    st.slipped_s += -wait
                    wall0 += -wait
                else:
                    st.max_late_s = max(st.max_late_s, -wait)
                    st.late_frames += -wait > LATE_S
            t_before = time.monotonic_ns() if send_trace is not None else 0
            try:
                bus.send(msg, timeout=send_timeout)
                st.sent += 1
            except can.CanError as exc:
                st.send_errors += 1
                if st.send_errors == 1 or st.send_errors % 1000 == 0:
                    log.warning("send failed (%d so far): %s", st.send_errors, exc)
            if send_trace is not None and wall0 is not None:
                t_due = int(round((wall0 + t_rel) * 1e9))
                send_trace.append((t_due, t_before, time.monotonic_ns(), msg.arbitration_id))
        if after_step is not None:
            after_step()
        if realtime and wall0 is not None and len(frames) == 0:  # a silent step (faults): keep the pace
            wait = wall0 + (sim.t_ns - sim0) * 1e-9 - time.monotonic()
            if wait > 0:
                time.sleep(wait)
    st.wall_s = time.monotonic() - wall_first if wall0 is not None else 0.0
    st.cpu_s = time.process_time() - cpu0
    st.sim_s = (sim.t_ns - sim0) * 1e-9
    return st
