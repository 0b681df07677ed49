"""The CLI's notice while numba compiles lde's kernels (a first run after an install or upgrade).

:func:`announce_compiles` prints :data:`lde.jitcache.NOTICE` once on stderr: at once when the cache
looks cold (:func:`lde.jitcache.is_warm`, called before the heavy imports so that the notice comes
within a second), else at the first compilation numba reports (a stale cache). Importing this
module imports numba: a subcommand's ``run`` imports it after the cheap check.
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from numba.core import event

from lde.jitcache import notice

__all__ = ["announce_compiles"]


@contextmanager
def announce_compiles(already_said: bool, write: Callable[[str], None] | None = None) -> Iterator[None]:
    """Within the block, print the compile notice at the first compilation, unless ``already_said``."""
    out = write or (lambda s: print(s, file=sys.stderr, flush=True))
    said = [already_said]
    lock = threading.Lock()

    class _Listener(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            with lock:
                if not said[0]:
                    said[0] = True
                    out(notice())

        def on_end(self, ev: event.Event) -> None:
            pass

    listener = _Listener()
    event.register("numba:compile", listener)
    try:
        yield
    finally:
        event.unregister("numba:compile", listener)
