"""Which bus each input message is read from, in a log that holds several (the RAV4 log has
``can0`` and ``can1``; a car's buses may carry the same id with other contents).

:class:`ChannelSelect` keeps, of a log's frames, those of each input message on its bus and every
frame of the other ids (the receiver ignores and counts those). A message's bus is decided at its
first frames:

* the profile names it (``channel`` of ``[messages.NAME]``, else the top-level ``channel``): that bus;
  a log of one bus (whatever its name, or none: a candump without interface column) is taken as that
  bus; a log of several buses that has the message only on other buses is an error that names them;
* the profile names none: the one bus that carries the message; several is an error that names them
  and the key to set.

Frames of an input message on another bus than its own are dropped and counted (:attr:`dropped`).
Live, a bus is one channel: the service reads every frame it is given.
"""

from __future__ import annotations

import numpy as np

from lde.can.frames import FrameBatch
from lde.can.profiles import Profile
from lde.errors import ConfigError

__all__ = ["ChannelSelect"]

_NO_MSG = -1


class ChannelSelect:
    """The frames of each input message on its bus (module doc); call it on a log's pieces in order.

    Attributes:
        chosen: message name -> the bus name its frames are read from (once seen).
        dropped: frames of input messages on other buses, dropped so far.
    """

    def __init__(self, profile: Profile, source: str = "the log") -> None:
        self.profile = profile
        self.source = source
        specs = list(profile.messages.values())
        self._names = [s.name for s in specs]
        self._ids = np.array([s.frame_id for s in specs], np.int64)
        self._want = [s.channel for s in specs]
        self._row = np.full(0x800, _NO_MSG, np.int64)
        for k, s in enumerate(specs):
            self._row[s.frame_id] = k
        self.chosen: dict[str, str] = {}
        self.dropped = 0

    def _decide(self, k: int, carriers: list[str], buses: list[str]) -> str:
        name, fid, want = self._names[k], int(self._ids[k]), self._want[k]
        where = f"{name} (0x{fid:X})"
        if want is not None:
            if want in carriers:
                return want
            if len(buses) == 1:
                return buses[0]  # a log of one bus is that bus
            raise ConfigError(
                f"{self.profile.path or self.profile.name}: [messages.{name}] channel = {want!r}, but "
                f"{self.source} has {where} on {', '.join(repr(c) for c in carriers)} only"
            )
        if len(carriers) == 1:
            return carriers[0]
        raise ConfigError(
            f"{self.source}: {where} is on channels {', '.join(repr(c) for c in carriers)}: name the one "
            f'to read in the profile ([messages.{name}] channel = "{carriers[0]}", or channel = ... at '
            "its top)"
        )

    def __call__(self, frames: FrameBatch) -> FrameBatch:
        """``frames`` without the input messages' frames of other buses (the same object when it
        keeps them all)."""
        n = len(frames)
        if n == 0:
            return frames
        std = ~frames.is_extended & (frames.can_id < 0x800)
        row = np.where(std, self._row[frames.can_id & 0x7FF], _NO_MSG)
        is_in = row >= 0
        single = len(frames.channels) == 1
        buses: list[str] | None = None
        for k in np.unique(row[is_in]).tolist():
            name = self._names[k]
            if name in self.chosen:
                continue
            if single:
                carriers = buses = [frames.channels[0]]
            else:
                idx = np.unique(frames.channel[row == k])
                carriers = [frames.channels[i] for i in idx.tolist()]
                if buses is None:
                    buses = [frames.channels[i] for i in np.unique(frames.channel).tolist()]
            self.chosen[name] = self._decide(k, carriers, buses)
        if single:
            only = frames.channels[0]
            if all(self.chosen.get(self._names[k], only) == only for k in np.unique(row[is_in]).tolist()):
                return frames
        want = np.full(len(self._names), -1, np.int64)
        for k, name in enumerate(self._names):
            c = self.chosen.get(name)
            if c is not None and c in frames.channels:
                want[k] = frames.channels.index(c)
        keep = ~is_in | (frames.channel.astype(np.int64) == want[np.maximum(row, 0)])
        dropped = n - int(np.count_nonzero(keep))
        if dropped == 0:
            return frames
        self.dropped += dropped
        return frames.select(keep)
