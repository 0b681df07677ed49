"""Where the ``lde`` command keeps its compiled kernels, and the notice while it compiles them.

lde's data path is numba functions cached on disk (``cache=True``). numba checks a cached function
against its own source file only: a kernel that calls a function of another file keeps the old
callee after that file changes (numba's documented limitation for cached functions that call
other functions), and lde's kernels call across files (the loop, the backends, the firmware model,
the learner). So the ``lde`` command, before numba is imported, points numba's documented
``NUMBA_CACHE_DIR`` at a directory named after a digest of the sources of every package with lde
kernels (and of the Python version and numba's installation): a changed source is a new directory,
compiled afresh, never a stale mix (:func:`use_kernel_cache`). The base directory is
``$NUMBA_CACHE_DIR`` when the user set one, else the user's cache directory (``$XDG_CACHE_HOME/lde``
or ``~/.cache/lde``).
``lde warmup`` compiles into it ahead of time and removes the directories of other sources.

Code that imports lde as a library (the pytest plugin, a notebook) uses numba's default cache and
keeps numba's own rule: nothing here runs at ``import lde``.

:func:`compile_notice` says so on stderr when numba really compiles (numba reports each
compilation, not a load from its cache, through its documented ``numba.core.event`` API), with the
compile time this machine measured the last time it compiled the same command's kernels.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import shutil
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = [
    "KERNEL_PACKAGES",
    "base_dir",
    "compile_notice",
    "kernel_dir",
    "prune_other_kernel_dirs",
    "sources_digest",
    "use_kernel_cache",
]

#: the packages whose numba kernels call each other across files
KERNEL_PACKAGES = ("lde", "firmware_model", "vcan_sim")
_PREFIX = "kernels-"
_TIMES = "compile-times.json"


def base_dir() -> Path:
    """Where the kernel directories live: the user's ``NUMBA_CACHE_DIR``, else the user cache dir.
    A ``NUMBA_CACHE_DIR`` that is a kernel directory already (set by the ``lde`` process that
    started this one) stands for its parent."""
    user = os.environ.get("NUMBA_CACHE_DIR")
    if user:
        p = Path(user)
        return p.parent if p.name.startswith(_PREFIX) else p
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "lde"


def _package_dirs(names: tuple[str, ...]) -> list[Path]:
    """The installed directories of the packages ``names`` (found without importing them)."""
    out: list[Path] = []
    for name in names:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            continue
        if spec is not None and spec.submodule_search_locations:
            out.extend(Path(p) for p in spec.submodule_search_locations)
    return out


def sources_digest(packages: list[Path] | None = None) -> str:
    """A digest of every ``.py`` file below ``packages`` (default: :data:`KERNEL_PACKAGES`): their
    paths relative to the package and their contents, plus the Python version and numba's
    installation (its path and the time it was installed: another numba is another directory)."""
    pkgs = _package_dirs(KERNEL_PACKAGES) if packages is None else packages
    h = hashlib.sha1()
    try:
        spec = importlib.util.find_spec("numba")
        origin = spec.origin if spec is not None else None
        if origin:
            h.update(f"numba {origin} {os.stat(origin).st_mtime_ns}\n".encode())
    except (ImportError, ValueError, OSError):
        pass
    h.update(f"python {sys.version_info[0]}.{sys.version_info[1]}\n".encode())
    for pkg in sorted(pkgs):
        for path in _sources(pkg):
            h.update(f"{pkg.name}/{os.path.relpath(path, pkg)}\0".encode())
            with open(path, "rb") as fh:
                h.update(hashlib.sha1(fh.read()).digest())
    return h.hexdigest()[:16]


def _sources(pkg: Path) -> list[str]:
    """The ``.py`` files below ``pkg``, sorted (``__pycache__`` not entered)."""
    out: list[str] = []
    for root, dirs, names in os.walk(pkg):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        out.extend(os.path.join(root, f) for f in names if f.endswith(".py"))
    return sorted(out)


def kernel_dir(base: Path | None = None, packages: list[Path] | None = None) -> Path:
    """The kernel directory of these sources below ``base`` (default :func:`base_dir`)."""
    return (base_dir() if base is None else base) / f"{_PREFIX}{sources_digest(packages)}"


def use_kernel_cache() -> Path | None:
    """Point ``NUMBA_CACHE_DIR`` at :func:`kernel_dir` (for this process and the ones it starts).
    Only before numba is imported (numba reads the setting at import): returns the directory, or
    None when numba was imported already (nothing is changed then)."""
    if "numba" in sys.modules:
        return None
    d = kernel_dir()
    os.environ["NUMBA_CACHE_DIR"] = str(d)
    return d


def prune_other_kernel_dirs(keep: Path) -> list[Path]:
    """Remove the kernel directories beside ``keep`` (other sources'); returns those removed."""
    gone: list[Path] = []
    try:
        siblings = [p for p in keep.parent.iterdir() if p.name.startswith(_PREFIX) and p != keep]
    except OSError:
        return gone
    for p in siblings:
        shutil.rmtree(p, ignore_errors=True)
        gone.append(p)
    return gone


def _times_file() -> Path:
    return base_dir() / _TIMES


def last_compile_s(key: str) -> float | None:
    """The seconds this machine spent compiling the kernels of ``key`` the last time it did."""
    try:
        got = json.loads(_times_file().read_text()).get(key)
    except (OSError, ValueError, AttributeError):
        return None
    return float(got) if isinstance(got, int | float) and got > 0 else None


def _store_compile_s(key: str, seconds: float) -> None:
    f = _times_file()
    try:
        times = json.loads(f.read_text())
        if not isinstance(times, dict):
            times = {}
    except (OSError, ValueError):
        times = {}
    times[key] = round(seconds, 2)
    try:
        f.parent.mkdir(parents=True, exist_ok=True)
        tmp = f.with_name(f"{f.name}.{os.getpid()}")
        tmp.write_text(json.dumps(times, indent=1, sort_keys=True))
        os.replace(tmp, f)
    except OSError:
        pass  # a cache that cannot be written: no figure next time


def notice_text(key: str) -> str:
    """The notice for ``key`` (with the last measured compile time when there is one)."""
    last = last_compile_s(key)
    if last is None:
        took = "once per install or upgrade"
    else:
        took = f"about {last:.0f} s here last time" if last >= 1.0 else "under a second here last time"
    where = os.environ.get("NUMBA_CACHE_DIR") or "numba's cache"
    return (
        f"lde: compiling the numba kernels of this run ({took}; cached in {where}; "
        "`lde warmup` does it ahead)"
    )


@contextmanager
def compile_notice(
    key: str, quiet: bool = False, write: Callable[[str], None] | None = None
) -> Iterator[None]:
    """Within the block: at numba's first compilation print the notice (unless ``quiet``); at the
    end, when something was compiled, store the seconds spent compiling under ``key``."""
    from numba.core import event

    out = write or (lambda s: print(s, file=sys.stderr, flush=True))
    lock = threading.Lock()
    depth: dict[int, int] = {}  # thread -> nesting of compilations (a kernel compiles its callees)
    started: dict[int, float] = {}
    total = [0.0]
    said = [quiet]

    class _Listener(event.Listener):
        def on_start(self, ev: event.Event) -> None:
            tid = threading.get_ident()
            with lock:
                if not said[0]:
                    said[0] = True
                    out(notice_text(key))
                depth[tid] = depth.get(tid, 0) + 1
                if depth[tid] == 1:
                    started[tid] = time.perf_counter()

        def on_end(self, ev: event.Event) -> None:
            tid = threading.get_ident()
            with lock:
                depth[tid] = depth.get(tid, 1) - 1
                if depth[tid] == 0 and tid in started:
                    total[0] += time.perf_counter() - started.pop(tid)

    listener = _Listener()
    event.register("numba:compile", listener)
    try:
        yield
    finally:
        event.unregister("numba:compile", listener)
        if total[0] > 0.0:
            _store_compile_s(key, total[0])
