"""Bus faults injected into the simulator's frames (to test the receiver's E2E handling).

A :class:`Fault` names a kind, the messages it hits (a message name, or a group ``"mdps"`` /
``"esc"`` of the profile), a time window [t, t + duration) relative to the simulation start, and
``every``: the n-th frames inside the window that are hit (1 = all). Kinds (:class:`FaultKind`):

* ``DROP``: the frame is not sent (a counter gap: OKSOMELOST, or WRONGSEQUENCE if the gap is
  larger than MaxDeltaCounter);
* ``SILENCE``: alias of DROP with every = 1 (the ECU is quiet: timeouts, NONEWDATA);
* ``CORRUPT``: the checksum/CRC field is inverted (WRONGCRC where the scheme verifies it);
* ``REPEAT``: the previous frame is sent again, counter and all (REPEATED).

Faults are applied after encoding, per frame index, so the fast path and the step path stay
identical; the truth is unaffected (the plant does not know about the bus).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from lde.can.bitfield import field_pos, get_bits, put_bits
from lde.can.frames import FrameBatch
from lde.can.profiles import GROUPS, Profile
from lde.errors import ConfigError


class FaultKind(Enum):
    DROP = "drop"
    SILENCE = "silence"
    CORRUPT = "corrupt"
    REPEAT = "repeat"


@dataclass(frozen=True)
class Fault:
    """One injected fault. t, duration [s] from the simulation start; every >= 1."""

    kind: FaultKind
    target: str
    t: float
    duration: float
    every: int = 1

    def messages(self, profile: Profile) -> tuple[str, ...]:
        """The profile's message names this fault hits."""
        if self.target in GROUPS:
            return profile.group_messages(self.target)
        if self.target in profile.messages:
            return (self.target,)
        raise ConfigError(
            f"fault target {self.target!r} is neither a group {list(GROUPS)} nor an input "
            f"message of profile {profile.name!r} ({list(profile.messages)})"
        )


def parse_fault(text: str) -> Fault:
    """``KIND:TARGET:START:DURATION[:EVERY]`` (the ``lde sim --fault`` syntax) -> :class:`Fault`."""
    parts = text.split(":")
    if len(parts) not in (4, 5):
        raise ConfigError(f"--fault {text!r}: expected KIND:TARGET:START:DURATION[:EVERY]")
    try:
        kind = FaultKind(parts[0].lower())
    except ValueError:
        raise ConfigError(f"--fault {text!r}: kind must be one of {[k.value for k in FaultKind]}") from None
    try:
        start, dur = float(parts[2]), float(parts[3])
        every = int(parts[4]) if len(parts) == 5 else 1
    except ValueError:
        raise ConfigError(f"--fault {text!r}: START, DURATION must be numbers and EVERY an integer") from None
    if start < 0 or dur <= 0 or every < 1:
        raise ConfigError(f"--fault {text!r}: need START >= 0, DURATION > 0, EVERY >= 1")
    return Fault(kind, parts[1], start, dur, every)


def hit_mask(fault: Fault, t_rel_ns: np.ndarray) -> np.ndarray:
    """Frames (by their times since the start) that ``fault`` hits."""
    t0 = int(round(fault.t * 1e9))
    t1 = t0 + int(round(fault.duration * 1e9))
    inside = (t_rel_ns >= t0) & (t_rel_ns < t1)
    if fault.kind is FaultKind.SILENCE or fault.every <= 1:
        return inside
    idx = np.cumsum(inside) - 1
    return inside & (idx % fault.every == fault.every - 1)


def apply_faults(
    frames: FrameBatch,
    hits: list[tuple[Fault, np.ndarray]],
    first: int,
    checksum_fields: tuple[tuple[int, int, bool], ...],
    prev: np.ndarray | None,
) -> tuple[FrameBatch, np.ndarray | None]:
    """Apply the faults of one message to its frames ``first, first + 1, ...`` of the run.

    ``hits``: (fault, hit mask over all the message's frames of the run); ``prev``: the data of the
    last frame sent before ``first`` (for REPEAT). Returns the frames to send and the new ``prev``.
    """
    n = len(frames)
    if n == 0:
        return frames, prev
    last = frames.data[-1].copy()
    if not hits:
        return frames, last
    data = frames.data.copy()
    keep = np.ones(n, dtype=bool)
    for i in range(n):
        for f, mask in hits:
            if not mask[first + i]:
                continue
            if f.kind in (FaultKind.DROP, FaultKind.SILENCE):
                keep[i] = False
            elif f.kind is FaultKind.CORRUPT:  # every bit of the checksum (else of byte 0) flipped
                for start, length, little_endian in checksum_fields or ((0, 8, True),):
                    pos = field_pos(start, length, little_endian)
                    v = int(get_bits(data[i], pos, length, little_endian))
                    put_bits(data[i], pos, length, little_endian, ~v & ((1 << length) - 1))
            elif f.kind is FaultKind.REPEAT and prev is not None:
                data[i] = prev
        if keep[i]:
            prev = data[i].copy()
    out = FrameBatch(
        frames.t_ns,
        frames.can_id,
        frames.is_extended,
        frames.dlc,
        data,
        frames.is_rx,
        frames.channel,
        frames.channels,
    )
    return out.select(keep), prev
