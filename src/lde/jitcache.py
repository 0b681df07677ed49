"""Where numba keeps lde's compiled kernels and whether the data path's are there.

lde's kernels are numba functions cached on disk (``cache=True``). numba (0.59+) looks for a
function's cache next to its source in ``__pycache__`` when that directory is writable, else in
the user's cache directory (``~/.cache/numba/<dir>_<sha1 of the source directory>``), or only in
``$NUMBA_CACHE_DIR/<dir>_<sha1>`` when that is set; an entry is valid for the same source content,
Python, numba and CPU. A first run after a fresh install (or an upgrade) compiles them: 25-35 s of
CPU per backend (``bench/run_all.py --cold`` measures it; docs/startup.md has the breakdown).
:func:`is_warm` tells, before numba is even imported, whether the data path's loop is cached, so
that the CLI can say what is happening at once (:mod:`lde.cli.jit`); ``lde warmup`` compiles
everything ahead of time (:mod:`lde.warmup`).
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path

__all__ = ["cache_dirs", "is_warm", "notice", "NOTICE"]

NOTICE = (
    "lde: compiling the numba kernels of the data path (first run after an install or an upgrade: "
    "25-35 s of CPU per backend, once; cached in {where}; `lde warmup --background` does it ahead of time)"
)


def _subpath(src_dir: Path) -> str:
    """numba's cache subdirectory for sources in ``src_dir`` (``<name>_<sha1 of the path>``)."""
    d = os.path.abspath(src_dir)
    return "_".join([os.path.split(d)[-1], hashlib.sha1(d.encode()).hexdigest()])


def cache_dirs() -> list[Path]:
    """Where numba keeps (or would keep) the kernels of ``lde`` itself, in numba's order."""
    pkg = Path(__file__).resolve().parent
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return [Path(env) / _subpath(pkg)]
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return [pkg / "__pycache__", Path(xdg) / "numba" / _subpath(pkg)]


#: the compiled data-path loops, one per backend (:data:`lde.backends.BACKENDS`, named by
#: :func:`lde.pipeline.make_loop`): fixed, float (lateral), paper-fixed, paper
LOOPS = ("run_lateral_fixed", "run_lateral", "run_paper_fixed", "run_paper")


def is_warm(loops: tuple[str, ...] = LOOPS) -> bool:
    """True when a compiled data-path loop (:mod:`lde.pipeline`, any of ``loops``) is cached for
    this Python. A stale entry (another numba, changed sources) still counts as warm here: the
    compile notice then comes with the first compilation (:func:`lde.cli.jit.announce_compiles`)."""
    tag = f"py{sys.version_info[0]}{sys.version_info[1]}"
    for d in cache_dirs():
        for loop in loops:
            if d.is_dir() and next(d.glob(f"pipeline.{loop}-*.{tag}.nbi"), None) is not None:
                return True
    return False


def notice() -> str:
    """:data:`NOTICE` with this installation's cache directories."""
    return NOTICE.format(where=" or ".join(str(d) for d in cache_dirs()))
