"""Frames in time order from a reader that produces them in file order, in bounded memory.

A log is read piece by piece (a block of candump text, a batch of python-can messages, an MCAP
chunk). Lines of a text log can be slightly out of time order (candump on several interfaces, a
logger with several threads): :class:`Reorder` holds back the frames of the last
``window_ns`` of log time and releases the others stably sorted, exactly as a sort of the whole
file would order them, as long as no frame is more than ``window_ns`` behind a frame before it in
the file. A frame later than that (a log joined from two files out of order) can no longer be put
in its place: it is skipped and counted (``late``), never silently reordered.

:func:`split` cuts a batch into pieces of at most ``n`` frames (views, no copies).
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from ..frames import FrameBatch

__all__ = ["Reorder", "split", "view", "CHUNK_FRAMES", "REORDER_WINDOW_NS"]

#: frames per piece handed to a replay: bounds its memory, whatever the log's length (64k frames,
#: ~46k steps of rows: ~30 MB of a replay's peak RSS, ~190 MB of which is numba and its kernels)
CHUNK_FRAMES = 1 << 16
#: how far (log time) a frame may lag behind a frame before it in the file and still be reordered
REORDER_WINDOW_NS = 10_000_000_000


def view(f: FrameBatch, a: int, b: int) -> FrameBatch:
    """Rows ``a:b`` of ``f`` as views (no copy)."""
    return FrameBatch(
        t_ns=f.t_ns[a:b],
        can_id=f.can_id[a:b],
        is_extended=f.is_extended[a:b],
        dlc=f.dlc[a:b],
        data=f.data[a:b],
        is_rx=f.is_rx[a:b],
    )


def split(f: FrameBatch, n: int) -> Iterator[FrameBatch]:
    """``f`` in pieces of at most ``n`` frames (views); nothing for an empty batch."""
    for a in range(0, len(f), n):
        yield view(f, a, min(a + n, len(f)))


class Reorder:
    """Stable time order over a stream of batches in file order, within a bounded window.

    ``push(batch)`` returns the frames that are final: every frame at or before ``max time seen -
    window_ns``; :meth:`finish` returns the rest. ``window_ns`` None holds everything until
    :meth:`finish` (a sort of the whole log). A pushed frame earlier than a frame already released
    is counted in :attr:`late` and dropped.
    """

    def __init__(self, window_ns: int | None = REORDER_WINDOW_NS) -> None:
        self.window_ns = window_ns
        self.late = 0
        self._pending = FrameBatch.empty()
        self._released: int | None = None  # time of the last frame released
        self._max: int | None = None

    def push(self, batch: FrameBatch) -> FrameBatch:
        if len(batch) == 0:
            return FrameBatch.empty()
        if self._released is not None:
            late = batch.t_ns < self._released
            k = int(np.count_nonzero(late))
            if k:
                self.late += k
                batch = batch.select(~late)
                if len(batch) == 0:
                    return FrameBatch.empty()
        p = self._pending
        if len(p) == 0:
            merged = batch.sort()
        elif batch.is_sorted() and batch.t_ns[0] >= p.t_ns[-1]:
            merged = FrameBatch.concat([p, batch], sort=False)
        else:
            merged = FrameBatch.concat([p, batch])  # stable: pending frames came first in the file
        hi = int(batch.t_ns.max())
        self._max = hi if self._max is None else max(self._max, hi)
        if self.window_ns is None:
            self._pending = merged
            return FrameBatch.empty()
        cut = int(np.searchsorted(merged.t_ns, self._max - self.window_ns, side="right"))
        return self._release(merged, cut)

    def finish(self) -> FrameBatch:
        return self._release(self._pending, len(self._pending))

    def _release(self, merged: FrameBatch, cut: int) -> FrameBatch:
        out = view(merged, 0, cut)
        self._pending = view(merged, cut, len(merged))
        if cut:
            self._released = int(out.t_ns[-1])
        return out
