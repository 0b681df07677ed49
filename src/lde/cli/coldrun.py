"""A live command's first run on a cold kernel cache (``lde run``, ``lde demo``), as ``lde replay``'s.

:func:`begin`, called before the heavy imports: when the data path's kernels are not cached
(:func:`lde.jitcache.is_warm`) it prints the compile notice at once and starts the helper process
of :mod:`lde.coldstart`; :func:`compile_ahead`, called once the options are checked: this process
compiles its share of the split while the helper compiles the other (docs/startup.md), so that the
service's engine then finds its kernels compiled. A warm cache: neither does anything.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from typing import Any

__all__ = ["ColdStart", "begin", "compile_ahead"]


@dataclass
class ColdStart:
    """What :func:`begin` found and started."""

    cold: bool  # the data path's loop was not cached: the notice was printed
    backend: str | None  # the backend with a split (``fixed``, ``float``), None for one without
    helper: Any = None  # the helper (lde.coldstart), None when not started


def begin(backend: str | None) -> ColdStart:
    """The notice on stderr and the helper for ``--backend`` as given, when the cache is cold; in
    either case numba's BLAS check answered from disk (:func:`lde.lazyblas.defer_blas_import`, as
    ``lde replay``: 0.15-0.45 s of importing ``scipy.linalg`` saved)."""
    from lde.jitcache import is_warm, notice
    from lde.lazyblas import defer_blas_import

    if is_warm():
        defer_blas_import()
        return ColdStart(False, None)
    print(notice(), file=sys.stderr, flush=True)
    from lde.coldstart import EARLY_NAMES, start_helper

    name = EARLY_NAMES.get(backend)
    cs = ColdStart(True, name, None if name is None else start_helper(backend, live=True))
    defer_blas_import()  # after the helper's start: it does its own
    return cs


def compile_ahead(cs: ColdStart) -> None:
    """This process's share of the split (nothing when the cache was warm or the backend has none)."""
    if cs.cold and cs.backend is not None:
        from lde.coldstart import compile_split

        compile_split(cs.backend, cs.helper, logs=[])  # no log: the candump parser is not needed
