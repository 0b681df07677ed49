"""Loud when blind: say which required input message is missing, and what arrived instead.

A service on the wrong channel or with the wrong ``--profile`` steps on, sends an invalid estimate
every 3.9 ms and otherwise looks healthy. :class:`InputWatch` is told every frame the service
receives (its id and time) and, once per step, the step time; it returns the lines to log:

* a **warning** when an input message of the profile has not arrived for ``WARN_TIMEOUTS`` of its
  timeouts (from the start, or since its last frame), naming the message, its id, where the
  service listens and the profile, plus the ids that did arrive and the shipped profile they fit;
  repeated every ``repeat_ns`` while it lasts (a slow rate: a log, not a flood);
* an **info** line when a reported message arrives again (with how long it was missing).

:func:`describe_ids` and :func:`profile_fit` do the same for a log (``lde replay``'s summary). Pure
logic: times are passed in [ns], nothing here reads a clock or a bus.
"""

from __future__ import annotations

import functools
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from lde.can.profiles import PROFILE_NAMES, Profile, load_profile

__all__ = ["WARN_TIMEOUTS", "REPEAT_NS", "InputWatch", "ProfileFit", "describe_ids", "profile_fit"]

#: a required input message missing for this many of its message timeouts is reported
WARN_TIMEOUTS = 10
#: while it stays missing, the warning is repeated this often [ns]
REPEAT_NS = 30 * 10**9
#: the most frequent ids listed in a warning
MAX_IDS = 8


@dataclass(frozen=True)
class ProfileFit:
    """How well a set of received ids fits a shipped profile's input messages."""

    profile: str
    present: tuple[str, ...]  # its input messages whose id arrived
    required: int  # its number of input messages

    @property
    def complete(self) -> bool:
        return len(self.present) == self.required


@functools.cache
def _input_ids(name: str) -> dict[int, str]:
    return {spec.frame_id: msg for msg, spec in load_profile(name).messages.items()}


def profile_fit(ids: set[int] | frozenset[int]) -> list[ProfileFit]:
    """The shipped profiles ranked by how many of their input messages ``ids`` contains (best first;
    profiles with none left out)."""
    fits = []
    for name in PROFILE_NAMES:
        want = _input_ids(name)
        present = tuple(sorted(msg for fid, msg in want.items() if fid in ids))
        if present:
            fits.append(ProfileFit(name, present, len(want)))
    fits.sort(key=lambda f: (-len(f.present) / f.required, f.profile))
    return fits


def describe_ids(counts: Counter[int] | dict[int, int], profile: Profile) -> str:
    """'ids that arrived: 0x251 x512, ...; they fit profile hyundai (4 of its 4 input messages)', or
    'no frame arrived at all'."""
    if not counts:
        return "no frame arrived at all"
    top = sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))[:MAX_IDS]
    more = len(counts) - len(top)
    text = "ids that arrived: " + ", ".join(f"0x{fid:X} x{n}" for fid, n in top)
    if more > 0:
        text += f" and {more} more"
    own = sorted({spec.frame_id for spec in profile.messages.values()})
    fits = [f for f in profile_fit(frozenset(counts)) if f.profile != profile.name]
    came = [f"0x{fid:X}" for fid in own if fid in counts]
    if came and len(came) < len(own):
        text += f"; of this profile's ({profile.name}) inputs only {', '.join(came)} arrived"
    elif came:  # every input came before: what is missing now stopped or comes late
        text += f"; all of this profile's ({profile.name}) inputs arrived before: they stopped or come late"
    elif fits:
        f = fits[0]
        text += (
            f"; they fit profile {f.profile} ({len(f.present)} of its {f.required} input messages:"
            f" {', '.join(f.present)})"
        )
    else:
        text += f"; none of them is an input of a shipped profile ({', '.join(PROFILE_NAMES)})"
    return text


@dataclass
class InputWatch:
    """Per-message arrival watch for a live service (module docstring).

    Args:
        profile: the profile the service decodes.
        where: where it listens, for the warning ("socketcan channel 'vcan0'").
        warn_timeouts: a message is missing after this many of its timeouts.
        repeat_ns: repeat period of the warning while a message stays missing [ns].
    """

    profile: Profile
    where: str
    warn_timeouts: int = WARN_TIMEOUTS
    repeat_ns: int = REPEAT_NS
    ids: Counter[int] = field(default_factory=Counter)  # every id received, with its count
    _last: dict[str, int] = field(default_factory=dict)  # message -> time of its last frame [ns]
    _start_ns: int | None = None
    _missing_since: dict[str, int] = field(default_factory=dict)  # reported messages -> since [ns]
    _next_warn_ns: int = 0
    warnings: int = 0  # warnings given so far

    def __post_init__(self) -> None:
        self._by_id = {spec.frame_id: name for name, spec in self.profile.messages.items()}
        self._after = {
            name: self.warn_timeouts * spec.timeout_ns for name, spec in self.profile.messages.items()
        }

    def saw(self, can_id: int, t_ns: int) -> None:
        """One received frame (any id) at ``t_ns`` [ns]."""
        self.ids[can_id] += 1
        name = self._by_id.get(can_id)
        if name is not None and t_ns > self._last.get(name, -1):
            self._last[name] = t_ns

    def saw_many(self, can_ids: np.ndarray, t_ns: np.ndarray) -> None:
        """Received frames as columns (ids uint32, times int64 [ns])."""
        if len(can_ids) == 0:
            return
        uniq, counts = np.unique(can_ids, return_counts=True)
        for fid, n in zip(uniq.tolist(), counts.tolist(), strict=True):
            self.ids[fid] += n
            name = self._by_id.get(fid)
            if name is not None:
                t = int(t_ns[can_ids == fid].max())
                if t > self._last.get(name, -1):
                    self._last[name] = t

    def missing(self, t_ns: int) -> dict[str, int]:
        """Input messages missing at ``t_ns``: name -> the time since which [ns] (their last frame,
        or the watch's start when none came). A message that never came is missing once every
        input's warning time has passed since the start (the longest): a silent bus gets one
        warning naming every input, not one per input as each one's time passes."""
        if self._start_ns is None:
            self._start_ns = t_ns
        start = self._start_ns
        started = t_ns - start >= max(self._after.values(), default=0)
        out = {}
        for name, after in self._after.items():
            last = self._last.get(name)
            if last is None:
                if started:
                    out[name] = start
            elif t_ns - last >= after:
                out[name] = last
        return out

    def late(self, t_ns: int) -> list[str]:
        """Input messages without a frame within their message timeout at ``t_ns`` [ns] (none came
        yet included): what the estimator lacks now (the status line)."""
        return [
            name
            for name, spec in self.profile.messages.items()
            if t_ns - self._last.get(name, -(1 << 62)) > spec.timeout_ns
        ]

    def check(self, t_ns: int) -> list[tuple[str, str]]:
        """Lines to log at step time ``t_ns`` [ns] as (level, text), level "warning" or "info"."""
        now = self.missing(t_ns)
        lines: list[tuple[str, str]] = []
        for name in sorted(set(self._missing_since) - set(now)):
            gone_s = (self._last.get(name, t_ns) - self._missing_since.pop(name)) * 1e-9
            lines.append(("info", f"input {self._label(name)} arrives again (missing for {gone_s:.1f} s)"))
        new = [n for n in now if n not in self._missing_since]
        for n in new:
            self._missing_since[n] = now[n]
        if now and (new or t_ns >= self._next_warn_ns):
            self._next_warn_ns = t_ns + self.repeat_ns
            self.warnings += 1
            parts = []
            for name in sorted(now):
                gap_s = (t_ns - now[name]) * 1e-9
                seen = "never received" if name not in self._last else f"none for {gap_s:.1f} s"
                parts.append(f"{self._label(name)} {seen}")
            lines.append(
                (
                    "warning",
                    f"no input: {'; '.join(parts)} on {self.where} with profile {self.profile.name};"
                    f" {describe_ids(self.ids, self.profile)}; the estimate stays invalid and the"
                    f" overlay off until it arrives",
                )
            )
        return lines

    def _label(self, name: str) -> str:
        return f"{name} (0x{self.profile.messages[name].frame_id:X})"
