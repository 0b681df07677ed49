"""Frames -> estimator inputs in SI: the vectorised batch decoder and the live receiver.

Both paths apply the same rules to the same frames, in time order:

1. select by id: only 11-bit frames whose id is one of the profile's input messages (unknown ids and
   29-bit frames are ignored, also a 29-bit frame whose number equals a known 11-bit id);
2. a frame whose length (dlc) differs from the message's DBC length is *malformed*: counted, never
   raised, and not passed to the E2E receiver;
3. the E2E receiver (:func:`lde.e2e.receive_frame`, one state per message) gives each frame a status,
   an ``accepted`` flag (its values are used) and the message's ``trusted`` flag after the frame;
4. accepted frames are decoded: ``SI = factor * mean(DBC values of the input's signals)``
   (:class:`lde.profiles.InputMap`) with the same numpy expressions in both paths, so the values
   are bit-identical.

Sampling at a time ``t`` (live :meth:`Receiver.sample`, batch :func:`lde.grid.build_grid`)::

    value[i](t)  = value of the latest accepted frame with t_frame <= t   (NaN before the first)
    valid[i](t)  = such a frame exists and t - t_frame <= timeout of its message
    trusted_m(t) = 'trusted' after the latest frame of message m with t_frame <= t (False before any)
    mdps_ok(t)   = all MDPS-group inputs valid and all their messages trusted; esc_ok likewise

Stale values are held (``valid`` says they are stale); the estimator decides what to do with them.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .codec import SignalCodec, words_le
from .e2e import S_ACCEPTED as _S_ACCEPTED
from .e2e import S_TRUSTED as _S_TRUSTED
from .e2e import (
    E2EStatus,
    ReceiverStats,
    check_batch,
    check_frame,
    new_state,
    read_counter,
    read_counter_batch,
    receive_batch,
    receive_frame,
)
from .frames import FrameBatch
from .profiles import ESC_INPUTS, GROUPS, INPUT_NAMES, MDPS_INPUTS, MessageSpec, Profile

__all__ = [
    "SignalSeries",
    "MessageDecode",
    "Decoded",
    "decode_batch",
    "FrameStatus",
    "InputSample",
    "Receiver",
]


# ------------------------------------------------------------------------------ decoding core


class _InputDecoder:
    """Compiled decoder of one estimator input: signal codecs + SI factor."""

    def __init__(self, profile: Profile, name: str) -> None:
        im = profile.inputs[name]
        msg = profile.db.get_message_by_name(im.message)
        self.name = name
        self.codecs = tuple(SignalCodec.from_cantools(msg.get_signal_by_name(s)) for s in im.signals)
        self.factor = float(im.factor)
        self.needs_be = any(not c.little_endian for c in self.codecs)

    def decode(self, w_le: np.ndarray, w_be: np.ndarray | None) -> np.ndarray:
        """SI values of frames given as little-endian words (big-endian words for Motorola)."""
        v = self.codecs[0].decode_batch(w_le, w_be)
        for c in self.codecs[1:]:
            v = v + c.decode_batch(w_le, w_be)
        if len(self.codecs) > 1:
            v = v / len(self.codecs)
        return v * self.factor


class _MessageDecoder:
    def __init__(self, profile: Profile, spec: MessageSpec) -> None:
        self.spec = spec
        self.cfg = spec.receiver.as_array()
        self.inputs = tuple(_InputDecoder(profile, n) for n in spec.inputs)
        self.needs_be = any(d.needs_be for d in self.inputs)

    def decode_words(self, w_le: np.ndarray) -> dict[str, np.ndarray]:
        w_be = w_le.byteswap() if self.needs_be else None
        return {d.name: d.decode(w_le, w_be) for d in self.inputs}


# ------------------------------------------------------------------------------ batch decoding


@dataclass
class SignalSeries:
    """Accepted samples of one estimator input: times [ns] and SI values."""

    t_ns: np.ndarray  # int64 [m]
    value: np.ndarray  # float64 [m]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])


@dataclass
class MessageDecode:
    """Receiver results of one input message over a batch (frames of the right length, in order)."""

    name: str
    frame_id: int
    timeout_ns: int
    t_ns: np.ndarray  # int64 [k], frames passed to the receiver
    status: np.ndarray  # uint8 [k], E2EStatus values
    accepted: np.ndarray  # bool [k], values used
    trusted: np.ndarray  # bool [k], message trusted after this frame
    stats: ReceiverStats
    malformed_t_ns: np.ndarray  # int64, times of frames with a wrong length

    def status_counts(self) -> dict[E2EStatus, int]:
        """Frames per E2E status."""
        vals, counts = np.unique(self.status, return_counts=True)
        return {E2EStatus(int(v)): int(c) for v, c in zip(vals, counts, strict=True)}


@dataclass
class Decoded:
    """Result of :func:`decode_batch`."""

    profile: str
    inputs: dict[str, SignalSeries]
    messages: dict[str, MessageDecode]
    n_frames: int  # frames in the batch
    n_ignored: int  # unknown ids and 29-bit frames
    t_first_ns: int | None  # first / last frame time of the whole batch
    t_last_ns: int | None

    @property
    def stats(self) -> dict[str, ReceiverStats]:
        return {k: m.stats for k, m in self.messages.items()}


def decode_batch(profile: Profile, frames: FrameBatch) -> Decoded:
    """Decode a batch of frames (any order; stably sorted by time first) -> :class:`Decoded`."""
    frames = frames.sort()
    n = len(frames)
    std = ~frames.is_extended
    inputs: dict[str, SignalSeries] = {}
    messages: dict[str, MessageDecode] = {}
    n_known = 0
    for spec in profile.messages.values():
        dec = _MessageDecoder(profile, spec)
        idx = np.flatnonzero((frames.can_id == spec.frame_id) & std)
        n_known += idx.size
        good = frames.dlc[idx] == spec.length
        bad_idx = idx[~good]
        idx = idx[good]
        t = frames.t_ns[idx]
        data = frames.data[idx]
        k = idx.size
        check_ok = check_batch(spec.scheme, spec.frame_id, data, spec.length)
        counters = read_counter_batch(spec.scheme, data)
        state = new_state()
        status = np.empty(k, dtype=np.uint8)
        accepted = np.empty(k, dtype=np.bool_)
        trusted = np.empty(k, dtype=np.bool_)
        receive_batch(state, dec.cfg, t, counters, check_ok, status, accepted, trusted)
        acc = np.flatnonzero(accepted)
        t_acc = t[acc]
        values = dec.decode_words(words_le(data[acc]))
        for name, v in values.items():
            inputs[name] = SignalSeries(t_acc, v)
        messages[spec.name] = MessageDecode(
            name=spec.name,
            frame_id=spec.frame_id,
            timeout_ns=spec.timeout_ns,
            t_ns=t,
            status=status,
            accepted=accepted,
            trusted=trusted,
            stats=ReceiverStats.from_state(state, malformed=int(bad_idx.size)),
            malformed_t_ns=frames.t_ns[bad_idx],
        )
    return Decoded(
        profile=profile.name,
        inputs={name: inputs[name] for name in INPUT_NAMES},
        messages=messages,
        n_frames=n,
        n_ignored=n - n_known,
        t_first_ns=int(frames.t_ns[0]) if n else None,
        t_last_ns=int(frames.t_ns[-1]) if n else None,
    )


# ------------------------------------------------------------------------------ live receiver


@dataclass(frozen=True)
class FrameStatus:
    """What the live receiver did with one frame.

    ``message`` is None for an ignored frame (unknown id / 29-bit); ``malformed`` for a wrong length;
    otherwise ``status`` is the E2E status and ``accepted`` says whether its values are used.
    """

    message: str | None
    status: E2EStatus | None = None
    accepted: bool = False
    malformed: bool = False

    @property
    def ignored(self) -> bool:
        return self.message is None


_IGNORED = FrameStatus(None)


@dataclass(frozen=True)
class InputSample:
    """The estimator inputs at one step time (SI, ISO 8855 signs; NaN before the first sample).

    ``valid[name]``: a value exists and is not older than its message's timeout. ``mdps_ok`` /
    ``esc_ok``: every input of the group valid and its messages trusted by the E2E receiver.
    ``age_ns[name]``: ``t_ns`` minus the time of the sample used (-1 if none).
    """

    t_ns: int
    column_torque: float  # Nm
    assist_torque: float  # Nm, total motor torque referred to the column
    steering_angle: float  # rad, steering wheel
    steering_rate: float  # rad/s, steering wheel
    yaw_rate: float  # rad/s
    lat_accel: float  # m/s^2
    speed: float  # m/s
    valid: Mapping[str, bool] = field(default_factory=dict)
    age_ns: Mapping[str, int] = field(default_factory=dict)
    mdps_ok: bool = False
    esc_ok: bool = False

    def value(self, name: str) -> float:
        return float(getattr(self, name))


@dataclass
class _LiveMessage:
    dec: _MessageDecoder
    state: np.ndarray
    frames: deque  # (t_ns, trusted_after) of recent frames passed to the receiver
    samples: deque  # (t_ns, {input: SI value}) of recent accepted frames
    malformed: int = 0


class Receiver:
    """Live receiver: ``feed`` frames in time order, ``sample`` the inputs at step times.

    Same semantics as :func:`decode_batch` + :func:`lde.grid.build_grid` (module docstring). It keeps
    the last ``history`` frames and accepted samples per message, so ``sample(t)`` may look back past
    frames newer than ``t`` that were already fed (the live loop normally feeds only frames <= t).
    """

    def __init__(self, profile: Profile, history: int = 8) -> None:
        self.profile = profile
        self._by_id: dict[int, _LiveMessage] = {}
        self._by_name: dict[str, _LiveMessage] = {}
        for spec in profile.messages.values():
            lm = _LiveMessage(
                dec=_MessageDecoder(profile, spec),
                state=new_state(),
                frames=deque(maxlen=history),
                samples=deque(maxlen=history),
            )
            self._by_id[spec.frame_id] = lm
            self._by_name[spec.name] = lm
        self._input_msg = {name: self._by_name[profile.inputs[name].message] for name in INPUT_NAMES}
        self._group_msgs = {g: tuple(self._by_name[m] for m in profile.group_messages(g)) for g in GROUPS}
        self.n_ignored = 0

    def reset(self) -> None:
        for lm in self._by_name.values():
            lm.state = new_state()
            lm.frames.clear()
            lm.samples.clear()
            lm.malformed = 0
        self.n_ignored = 0

    def feed(
        self,
        t_ns: int,
        can_id: int,
        data: bytes | bytearray,
        dlc: int | None = None,
        is_extended: bool = False,
    ) -> FrameStatus:
        """Process one received frame (time ``t_ns`` [ns]); never raises for a bad frame."""
        lm = None if is_extended else self._by_id.get(int(can_id))
        if lm is None:
            self.n_ignored += 1
            return _IGNORED
        spec = lm.dec.spec
        raw = bytes(data)
        length = len(raw) if dlc is None else int(dlc)
        if length != spec.length or len(raw) < spec.length:
            lm.malformed += 1
            return FrameStatus(spec.name, malformed=True)
        raw8 = raw[:8].ljust(8, b"\x00")[: spec.length].ljust(8, b"\x00")
        ok = check_frame(spec.scheme, spec.frame_id, raw8[: spec.length])
        counter = read_counter(spec.scheme, raw8)
        t = int(t_ns)
        st = E2EStatus(int(receive_frame(lm.state, lm.dec.cfg, np.int64(t), np.int64(counter), ok)))
        accepted = bool(lm.state[_S_ACCEPTED])
        lm.frames.append((t, bool(lm.state[_S_TRUSTED])))
        if accepted:
            w = np.array([int.from_bytes(raw8, "little")], dtype=np.uint64)
            vals = lm.dec.decode_words(w)
            lm.samples.append((t, {k: float(v[0]) for k, v in vals.items()}))
        return FrameStatus(spec.name, st, accepted)

    def sample(self, t_ns: int) -> InputSample:
        """Inputs at time ``t_ns`` (sample-and-hold, staleness, trust; module docstring)."""
        t = int(t_ns)
        values: dict[str, float] = {}
        valid: dict[str, bool] = {}
        age: dict[str, int] = {}
        latest: dict[int, tuple[int, dict[str, float]] | None] = {}
        for name in INPUT_NAMES:
            lm = self._input_msg[name]
            key = id(lm)
            if key not in latest:
                latest[key] = next((s for s in reversed(lm.samples) if s[0] <= t), None)
            s = latest[key]
            if s is None:
                values[name], valid[name], age[name] = math.nan, False, -1
            else:
                values[name] = s[1][name]
                age[name] = t - s[0]
                valid[name] = age[name] <= lm.dec.spec.timeout_ns
        ok = {}
        for g, names in (("mdps", MDPS_INPUTS), ("esc", ESC_INPUTS)):
            ok[g] = all(valid[n] for n in names) and all(
                self._trusted_at(lm, t) for lm in self._group_msgs[g]
            )
        return InputSample(
            t_ns=t,
            **values,
            valid=valid,
            age_ns=age,
            mdps_ok=ok["mdps"],
            esc_ok=ok["esc"],
        )

    @staticmethod
    def _trusted_at(lm: _LiveMessage, t: int) -> bool:
        for tf, trusted in reversed(lm.frames):
            if tf <= t:
                return trusted
        return False

    # ---------------------------------------------------------------- counters
    @property
    def stats(self) -> dict[str, ReceiverStats]:
        """Per-message counts (same meaning as :attr:`Decoded.stats`)."""
        return {
            n: ReceiverStats.from_state(lm.state, malformed=lm.malformed) for n, lm in self._by_name.items()
        }

    @property
    def e2e_rejects(self) -> int:
        """Frames rejected since start: E2E (repeated, wrong sequence, wrong CRC) plus malformed."""
        return sum(s.rejected + s.malformed for s in self.stats.values())

    def trusted(self, message: str) -> bool:
        """Current trust of an input message."""
        return bool(self._by_name[message].state[_S_TRUSTED])

    def timed_out(self, t_ns: int) -> dict[str, bool]:
        """Per input message: no accepted frame within its timeout before ``t_ns`` (E2E NONEWDATA)."""
        out = {}
        for name, lm in self._by_name.items():
            s = next((x for x in reversed(lm.samples) if x[0] <= int(t_ns)), None)
            out[name] = s is None or int(t_ns) - s[0] > lm.dec.spec.timeout_ns
        return out
