"""A profile's inputs decoded from a log: their values in SI, ranges, rates, gaps and integrity.

The inputs are decoded the one way lde decodes a log, by the receiver
(:func:`lde.engine.receiver.decode_batch`): each input message's frames of its bus and its length,
checked by the profile's integrity check, converted by the profile (scale to SI, sign, offset; the
mean or sum of several signals); only the frames the receiver accepts give values. Besides the
estimator's inputs, the per-wheel speeds the checks need are taken from the DBC when it has them:
four signals whose names say wheel and speed and end in FL, FR, RL, RR (``WHL_SPD_FL``,
``WHEEL_SPEED_RR``), in the message of the speed input first.

Integrity per message, as the receiver counts it: checksum failures where the profile's check
verifies one, and counter faults (frames lost, repeated or out of sequence) where the message has a
counter.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from lde.analysis.inspect.checks import WHEELS
from lde.analysis.inspect.resample import Series
from lde.can.codec import SignalCodec
from lde.can.frames import FrameBatch
from lde.can.profiles import Profile, SignalDef
from lde.engine.receiver import Decoded, decode_batch
from lde.units import KMH

__all__ = [
    "InputStats",
    "MessageIntegrity",
    "ProfileInputs",
    "decode_inputs",
    "SI_UNITS",
    "wheel_signals",
]

#: each input's SI unit (torques of an unknown scale are raw counts)
SI_UNITS: Mapping[str, str] = {
    "column_torque": "Nm",
    "assist_torque": "Nm",
    "steering_angle": "rad",
    "steering_rate": "rad/s",
    "yaw_rate": "rad/s",
    "lat_accel": "m/s^2",
    "speed": "m/s",
}
#: a DBC wheel-speed unit -> m/s per unit
_SPEED_UNITS: Mapping[str, float] = {"km/h": KMH, "kph": KMH, "kmh": KMH, "m/s": 1.0, "mph": 0.44704}
_WHEEL_NAME = re.compile(r"(?i)^(?=.*(?:WHE?E?L|WHL))(?=.*(?:SPE?E?D|SPD|VEL)).*?_?(FL|FR|RL|RR)$")


@dataclass(frozen=True)
class InputStats:
    """One input over the log (values in SI, :data:`SI_UNITS`; ``counts`` for an unknown scale).

    Attributes:
        name, message, unit; frames: decoded frames.
        period_ms: median time between them [ms]; max_gap_ms: the longest [ms]; timeout_ms: the
            profile's timeout of the message [ms] (a gap longer than it makes the input stale).
        minimum, p5, median, p95, maximum: the value's distribution (NaN without frames).
    """

    name: str
    message: str
    unit: str
    frames: int
    period_ms: float
    max_gap_ms: float
    timeout_ms: float
    minimum: float
    p5: float
    median: float
    p95: float
    maximum: float

    @property
    def rate_hz(self) -> float:
        return 1000.0 / self.period_ms if self.period_ms > 0 else float("nan")

    @property
    def stale_gaps(self) -> bool:
        """The log has a gap between two frames longer than the timeout."""
        return self.max_gap_ms > self.timeout_ms


@dataclass(frozen=True)
class MessageIntegrity:
    """One input message's frames and their integrity.

    Attributes:
        message, frame_id; check: the profile's integrity check for it.
        frames: frames of the id with the right length; wrong_length: frames with another length.
        used: frames whose values the receiver used.
        checksum_failures: frames whose checksum / CRC is wrong (None: the check verifies none).
        counter_jumps: frames lost, repeated or out of sequence by their counter (None: no counter).
    """

    message: str
    frame_id: int
    check: str
    frames: int
    wrong_length: int
    used: int
    checksum_failures: int | None
    counter_jumps: int | None


@dataclass(frozen=True)
class ProfileInputs:
    """What :func:`decode_inputs` finds.

    Attributes:
        series: input name (and :data:`lde.analysis.inspect.checks.WHEELS` names) -> samples (SI).
        stats: per input; integrity: per input message.
        wheels: the DBC signals taken as wheel speeds, ``MESSAGE.SIGNAL`` in :data:`WHEELS` order.
        speed_is_wheels: the speed input is the mean of those same signals.
        unknown_scale: the torque inputs in raw counts.
    """

    series: Mapping[str, Series]
    stats: tuple[InputStats, ...]
    integrity: tuple[MessageIntegrity, ...]
    wheels: tuple[str, ...]
    speed_is_wheels: bool
    unknown_scale: frozenset[str]


def _frames_of(frames: FrameBatch, spec_id: int, length: int) -> np.ndarray:
    """Rows of ``frames`` (received, 11-bit) with this id and length."""
    return frames.is_rx & ~frames.is_extended & (frames.can_id == spec_id) & (frames.dlc == length)


def _physical(sig: SignalDef, data: np.ndarray) -> np.ndarray:
    """A signal's physical values (DBC unit) in the frames ``data`` (uint8 [n, width])."""
    return SignalCodec.of(sig).decode_batch(data)


def _integrity(profile: Profile, decoded: Decoded) -> tuple[MessageIntegrity, ...]:
    out = []
    for name, spec in profile.messages.items():
        st = decoded.messages[name].stats
        sch = spec.scheme
        out.append(
            MessageIntegrity(
                message=name,
                frame_id=spec.frame_id,
                check=sch.name,
                frames=st.received,
                wrong_length=st.malformed,
                used=st.used,
                checksum_failures=st.wrong_crc if sch.verifies_checksum else None,
                counter_jumps=st.lost + st.repeated + st.wrong_sequence if sch.has_counter else None,
            )
        )
    return tuple(out)


def _stats(name: str, message: str, unit: str, s: Series) -> InputStats:
    v = s.values[np.isfinite(s.values)]
    d = np.diff(np.sort(s.t_ns)) * 1e-6
    q = np.percentile(v, (0, 5, 50, 95, 100)) if v.size else np.full(5, np.nan)
    return InputStats(
        name=name,
        message=message,
        unit=unit,
        frames=int(s.t_ns.size),
        period_ms=float(np.median(d)) if d.size else float("nan"),
        max_gap_ms=float(d.max()) if d.size else float("nan"),
        timeout_ms=s.timeout_ns * 1e-6,
        minimum=float(q[0]),
        p5=float(q[1]),
        median=float(q[2]),
        p95=float(q[3]),
        maximum=float(q[4]),
    )


def wheel_signals(profile: Profile) -> tuple[tuple[str, SignalDef, float], ...]:
    """The DBC's per-wheel speeds, in :data:`WHEELS` order: (message, signal, m/s per DBC unit)
    each; empty unless all four are found in one message (the speed input's message first)."""
    db = profile.db
    speed = profile.inputs.get("speed")
    names = [speed.message] if speed is not None else []
    names += [m.name for m in db.messages if m.name not in names]
    for mname in names:
        msg = db.get_message_by_name(mname)
        found: dict[str, tuple[str, SignalDef, float]] = {}
        for sig in msg.signals:
            m = _WHEEL_NAME.match(sig.name)
            if m is None:
                continue
            if speed is not None and mname == speed.message and sig.name in speed.signals:
                k = abs(speed.to_si)  # the profile's own unit for these signals
            else:
                unit = str(sig.unit or "").strip().lower()
                if unit not in _SPEED_UNITS:
                    continue
                k = _SPEED_UNITS[unit]
            found.setdefault(f"wheel_{m.group(1).lower()}", (mname, SignalDef.from_cantools(sig), k))
        if len(found) == 4:
            return tuple(found[w] for w in WHEELS)
    return ()


def decode_inputs(frames: FrameBatch, profile: Profile) -> ProfileInputs:
    """The profile's inputs (and the DBC's wheel speeds) in ``frames`` (module doc)."""
    decoded = decode_batch(profile, frames)
    used = decoded.used_profile or profile  # with the timeouts observed where its DBC gives none
    series: dict[str, Series] = {}
    stats = []
    for name, im in profile.inputs.items():
        got = decoded.inputs[name]
        s = Series(got.t_ns, got.value, int(used.messages[im.message].timeout_ns))
        series[name] = s
        unit = "counts" if im.unknown_scale else SI_UNITS[name]
        stats.append(_stats(name, im.message, unit, s))
    wheels = wheel_signals(profile)
    kept = decoded.frames if decoded.frames is not None else frames
    for w, (mname, sig, k) in zip(WHEELS, wheels, strict=False):
        msg = profile.db.get_message_by_name(mname)
        good = _frames_of(kept, int(msg.frame_id), int(msg.length))
        wspec = used.messages.get(mname)
        timeout = int(wspec.timeout_ns) if wspec is not None else _observed_timeout(kept.t_ns[good])
        series[w] = Series(kept.t_ns[good], k * _physical(sig, kept.data[good]), timeout)
    speed = profile.inputs.get("speed")
    speed_is_wheels = bool(
        wheels and speed is not None and sorted(speed.signals) == sorted(s.name for _, s, _ in wheels)
    )
    return ProfileInputs(
        series=series,
        stats=tuple(stats),
        integrity=_integrity(profile, decoded),
        wheels=tuple(f"{m}.{s.name}" for m, s, _ in wheels),
        speed_is_wheels=speed_is_wheels,
        unknown_scale=profile.unknown_scale,
    )


def _observed_timeout(t_ns: np.ndarray) -> int:
    """Three median periods (the default timeout, SPEC section 3) of a message the profile does not
    time: a wheel-speed message that is not an input, or a DBC without cycle times."""
    d = np.diff(np.sort(t_ns))
    return int(3 * np.median(d)) if d.size else 0
