"""Which profile fits a log: how many of its input messages arrive, with their length, on one bus.

A profile fits when every input message arrives with the length its DBC gives, all on one channel
(or each on the channel the profile names for it). The score of a profile is the number of its
input messages found so on its best channel; a profile that does not fit says why (a message
missing, present with another length, or present only on another channel).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

from lde.analysis.inspect.survey import LogSurvey

__all__ = ["Wanted", "MessageMatch", "ProfileMatch", "match_profile", "rank"]


class Wanted(NamedTuple):
    """An input message a profile needs: its name, 11-bit id, length [bytes] and, when the profile
    names it, its channel."""

    message: str
    frame_id: int
    length: int
    channel: str | None = None


@dataclass(frozen=True)
class MessageMatch:
    """Where one wanted message arrives.

    Attributes:
        wanted: the message.
        channels: the channels where its id arrives with its length.
        other_lengths: (channel, the lengths seen) where its id arrives with other lengths only.
    """

    wanted: Wanted
    channels: tuple[str, ...]
    other_lengths: tuple[tuple[str, tuple[int, ...]], ...] = ()

    def on(self, channel: str) -> bool:
        return channel in self.channels and (self.wanted.channel in (None, channel))


@dataclass(frozen=True)
class ProfileMatch:
    """How a profile fits a log.

    Attributes:
        profile: its name; origin: ``shipped`` or ``given``.
        messages: one :class:`MessageMatch` per input message.
        channel: the channel that carries most of them (None when none arrives).
    """

    profile: str
    origin: str
    messages: tuple[MessageMatch, ...]
    channel: str | None

    @property
    def present(self) -> int:
        """Input messages found with their length on :attr:`channel`."""
        return 0 if self.channel is None else sum(m.on(self.channel) for m in self.messages)

    @property
    def required(self) -> int:
        return len(self.messages)

    @property
    def fits(self) -> bool:
        return self.required > 0 and self.present == self.required

    @property
    def score(self) -> float:
        return self.present / self.required if self.required else 0.0

    def why(self) -> str:
        """What is missing, one clause per message (empty when it fits)."""
        out = []
        for m in self.messages:
            w = m.wanted
            name = f"{w.message} (0x{w.frame_id:X}, {w.length} B)"
            if self.channel is not None and m.on(self.channel):
                continue
            if m.channels:
                out.append(f"{name} only on {', '.join(repr(c) for c in m.channels)}")
            elif m.other_lengths:
                seen = "; ".join(
                    f"{', '.join(str(x) for x in lens)} B on {c!r}" for c, lens in m.other_lengths
                )
                out.append(f"{name} arrives with another length ({seen})")
            else:
                out.append(f"{name} missing")
        return "; ".join(out)


def match_profile(
    survey: LogSurvey, profile: str, wanted: Sequence[Wanted], origin: str = "shipped"
) -> ProfileMatch:
    """How the input messages ``wanted`` of ``profile`` arrive in the surveyed log."""
    found = []
    for w in wanted:
        stats = survey.on(w.frame_id)
        good = tuple(s.channel for s in stats if w.length in s.lengths)
        other = tuple((s.channel, s.lengths) for s in stats if w.length not in s.lengths)
        found.append(MessageMatch(w, good, other))
    counts: dict[str, int] = {}
    for m in found:
        for c in m.channels:
            if m.on(c):
                counts[c] = counts.get(c, 0) + 1
    channel = max(sorted(counts), key=lambda c: counts[c]) if counts else None
    return ProfileMatch(profile, origin, tuple(found), channel)


def rank(matches: Sequence[ProfileMatch]) -> list[ProfileMatch]:
    """Best fit first: by score, then the given profile before shipped ones, then by name."""
    return sorted(matches, key=lambda m: (-m.score, m.origin != "given", m.profile))
