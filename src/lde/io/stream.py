"""Frames in time order from a reader that produces them in file order, in bounded memory.

A log is read piece by piece (a block of candump text, a batch of python-can messages, an MCAP
chunk). Lines of a text log can be slightly out of time order (candump on several interfaces, a
logger with several threads): :class:`Reorder` holds back the frames of the last
``window_ns`` of log time and releases the others stably sorted, exactly as a sort of the whole
file would order them, as long as no frame is more than ``window_ns`` behind a frame before it in
the file. A frame later than that (a log joined from two files out of order) can no longer be put
in its place: it is skipped and counted (``late``), never silently reordered.

:func:`split` cuts a batch into pieces of at most ``n`` frames (views, no copies).
:class:`ReadAhead` reads the pieces in a thread, a bounded number ahead of their consumer (the
parsers and decompressors release the GIL, so that a replay reads while its engine runs).
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable, Iterator
from typing import Generic, TypeVar

import numpy as np

from lde.can.frames import FrameBatch

__all__ = ["Reorder", "ReadAhead", "split", "view", "CHUNK_FRAMES", "REORDER_WINDOW_NS"]

#: frames per piece handed to a replay: bounds its memory, whatever the log's length (64k frames,
#: ~46k steps of rows: ~30 MB of a replay's peak RSS, ~190 MB of which is numba and its kernels)
CHUNK_FRAMES = 1 << 16
#: how far (log time) a frame may lag behind a frame before it in the file and still be reordered
REORDER_WINDOW_NS = 10_000_000_000


def view(f: FrameBatch, a: int, b: int) -> FrameBatch:
    """Rows ``a:b`` of ``f`` as views (no copy)."""
    return f.rows(a, b)


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


T = TypeVar("T")
_END = object()


class ReadAhead(Generic[T]):
    """The items of ``items`` (an iterable of pieces, e.g. a :class:`lde.io.LogStream`) produced
    in a thread of their own, at most ``depth`` ahead of the consumer: the producer reads the next
    piece only when the consumer has taken one (memory: ``depth`` pieces more than reading them in
    line). The order is unchanged; an exception of the producer is
    raised to the consumer where it happened (after the pieces before it). Close it (or use it as a
    context manager) when the consumer stops early: the producer is stopped, its iterator closed in
    its own thread (files closed) and joined."""

    def __init__(self, items: Iterable[T], depth: int = 1, name: str = "lde-read") -> None:
        self._q: queue.Queue[tuple[object, BaseException | None]] = queue.Queue()
        self._ask = threading.Semaphore(depth)  # pieces the producer may read before one is taken
        self._stop = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=self._run, args=(items,), name=name, daemon=True)
        self._thread.start()

    def _wait_turn(self) -> bool:
        while not self._stop.is_set():
            if self._ask.acquire(timeout=0.05):
                return not self._stop.is_set()
        return False

    def _run(self, items: Iterable[T]) -> None:
        it = iter(items)
        try:
            while self._wait_turn():
                x = next(it, _END)
                self._q.put((x, None))
                if x is _END:
                    return
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            self._q.put((_END, exc))
        finally:
            close = getattr(it, "close", None)
            if close is not None:
                close()

    def __iter__(self) -> Iterator[T]:
        return self

    def __next__(self) -> T:
        if self._done:
            raise StopIteration
        x, exc = self._q.get()
        self._ask.release()
        if x is _END:
            self._done = True
            self._thread.join()
            if exc is not None:
                raise exc
            raise StopIteration
        return x  # type: ignore[return-value]

    def close(self) -> None:
        """Stop the producer (after the piece it is on) and wait for it."""
        self._stop.set()  # a producer waiting for its turn sees it within 50 ms
        self._thread.join()
        self._done = True
        while not self._q.empty():
            self._q.get_nowait()

    def __enter__(self) -> ReadAhead[T]:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
