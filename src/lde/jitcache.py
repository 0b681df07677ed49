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

__all__ = ["cache_dirs", "drop_stale", "is_warm", "notice", "NOTICE"]

NOTICE = (
    "lde: compiling the numba kernels of the data path (first run after an install or an upgrade: "
    "25-35 s of CPU per backend, once; cached in {where}; `lde warmup --background` does it ahead of time)"
)


#: the packages whose numba kernels call each other across files (a data-path loop inlines the
#: firmware model's step, the learner, the codec ...)
KERNEL_PACKAGES = ("lde", "firmware_model", "vcan_sim")
STAMP_NAME = "lde-sources.stamp"


def _subpath(src_dir: Path) -> str:
    """numba's cache subdirectory for sources in ``src_dir`` (``<name>_<sha1 of the path>``)."""
    d = os.path.abspath(src_dir)
    return "_".join([os.path.split(d)[-1], hashlib.sha1(d.encode()).hexdigest()])


def cache_dirs() -> list[Path]:
    """Where numba keeps (or would keep) the kernels of ``lde`` itself, in numba's order."""
    return _dir_cache_dirs(Path(__file__).resolve().parent / "engine")


def _dir_cache_dirs(src_dir: Path) -> list[Path]:
    """Where numba keeps (or would keep) the kernels of the sources in ``src_dir``."""
    env = os.environ.get("NUMBA_CACHE_DIR")
    if env:
        return [Path(env) / _subpath(src_dir)]
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return [src_dir / "__pycache__", Path(xdg) / "numba" / _subpath(src_dir)]


def _package_dirs(names: tuple[str, ...]) -> list[Path]:
    """The installed directories of the packages ``names`` (found without importing them)."""
    import importlib.util

    out: list[Path] = []
    for name in names:
        try:
            spec = importlib.util.find_spec(name)
        except (ImportError, ValueError):
            continue
        if spec is not None and spec.submodule_search_locations:
            out.extend(Path(p) for p in spec.submodule_search_locations)
    return out


def _source_dirs(pkg: Path) -> list[Path]:
    """``pkg`` and its subdirectories that hold ``.py`` files (``__pycache__`` not entered)."""
    out: list[Path] = []
    for root, dirs, files in os.walk(pkg):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        if any(f.endswith(".py") for f in files):
            out.append(Path(root))
    return out


def _sources(packages: list[Path]) -> list[tuple[str, os.stat_result]]:
    out: list[tuple[str, os.stat_result]] = []
    for pkg in sorted(packages):
        for src in sorted(_source_dirs(pkg)):
            with os.scandir(src) as it:
                for e in sorted(it, key=lambda e: e.name):
                    if e.name.endswith(".py") and e.is_file():
                        out.append((e.path, e.stat()))
    return out


def sources_stamp(packages: list[Path]) -> str:
    """One digest of every ``.py`` file below ``packages``: path, size and mtime (the fields numba's
    own index compares for a kernel's file). Fast; another view of the same files (user-mode
    Linux's hostfs) may see other mtimes, hence :func:`sources_digest` behind it."""
    h = hashlib.sha1()
    for path, st in _sources(packages):
        h.update(f"{path}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
    return h.hexdigest()


def sources_digest(packages: list[Path]) -> str:
    """One digest of the content of every ``.py`` file below ``packages`` (about 20 ms; read only
    when :func:`sources_stamp` differs from the cache's)."""
    h = hashlib.sha1()
    for path, _ in _sources(packages):
        h.update(path.encode() + b"\0")
        with open(path, "rb") as f:
            h.update(hashlib.sha1(f.read()).digest())
    return h.hexdigest()


def drop_stale(packages: list[Path] | None = None) -> int:
    """Delete the cached kernels of ``packages`` (default: :data:`KERNEL_PACKAGES`) when any of
    their sources changed since the cache was written; returns how many files were removed.

    numba checks a cached kernel only against its own source file, so a kernel that calls (and
    inlines) a function of another file keeps the old callee after that file changes: a replay
    would silently run yesterday's learner (numba PRs #8396 and #9563, which would track such
    dependencies, were not merged). lde's kernels call across files, so one stamp over all their
    sources decides for all of them, in every cache directory numba would use: when the files'
    mtimes differ from the stamp's, their content decides (a touched but unchanged tree, or the
    same tree seen through another file system, keeps its kernels). A directory that cannot be
    written is left alone (numba then uses the next)."""
    pkgs = _package_dirs(KERNEL_PACKAGES) if packages is None else packages
    stamp = sources_stamp(pkgs)
    digest: list[str] = []  # computed once, only if some directory needs it
    removed = 0
    for pkg in pkgs:
        for src in _source_dirs(pkg):
            dirs = _dir_cache_dirs(src)
            for cache in dirs:
                removed += _drop_dir(cache, stamp, pkgs, digest)
            _stamp_new(dirs, stamp, pkgs, digest)
    return removed


def _stamp_new(dirs: list[Path], stamp: str, pkgs: list[Path], digest: list[str]) -> None:
    """Create the directory numba will write these sources' kernels to (the first of ``dirs`` that
    exists writable or can be made, as numba picks it) with this stamp, when it does not exist yet.

    Without it, the kernels a first run compiles land in a directory without a stamp, and the next
    run's :func:`drop_stale` takes them for stale and deletes them all: the second run after an install
    was as cold as the first (measured: 23 kernels compiled again, docs/startup.md)."""
    for cache in dirs:
        if cache.is_dir():
            if os.access(cache, os.W_OK):
                return  # _drop_dir stamped it (or it holds this stamp)
            continue
        try:
            cache.mkdir(parents=True)
            _write_stamp(cache, stamp, pkgs, digest)
            return
        except FileExistsError:  # made by another process just now (the cold start's helper)
            _drop_dir(cache, stamp, pkgs, digest)
            return
        except OSError:
            continue


def _drop_dir(cache: Path, stamp: str, pkgs: list[Path], digest: list[str]) -> int:
    if not cache.is_dir():
        return 0
    mark = cache / STAMP_NAME
    try:
        old = mark.read_text().split()
    except OSError:
        old = []
    if old[:1] == [stamp]:
        return 0
    if not digest:
        digest.append(sources_digest(pkgs))
    removed = 0
    try:
        if old[1:2] != digest:
            for f in [*cache.glob("*.nbi"), *cache.glob("*.nbc")]:
                f.unlink(missing_ok=True)
                removed += 1
        _write_stamp(cache, stamp, pkgs, digest)
    except OSError:
        pass
    return removed


def _write_stamp(cache: Path, stamp: str, pkgs: list[Path], digest: list[str]) -> None:
    """``cache``'s stamp file (the sources' stamp and content digest), replaced atomically;
    ``digest`` is computed once per :func:`drop_stale` (an empty list: not yet). OSError as the
    file system gives it."""
    if not digest:
        digest.append(sources_digest(pkgs))
    tmp = cache / f"{STAMP_NAME}.{os.getpid()}"
    tmp.write_text(f"{stamp} {digest[0]}")
    os.replace(tmp, cache / STAMP_NAME)


#: the compiled data-path loops, one per backend (:data:`lde.engine.backends.BACKENDS`, named by
#: :func:`lde.engine.loop.make_loop`): fixed, float (lateral), paper-fixed, paper
LOOPS = ("run_lateral_fixed", "run_lateral", "run_paper_fixed", "run_paper")


def is_warm(loops: tuple[str, ...] = LOOPS) -> bool:
    """True when a compiled data-path loop (:mod:`lde.engine.loop`, any of ``loops``) is cached for
    this Python. A stale entry (another numba, changed sources) still counts as warm here: the
    compile notice then comes with the first compilation (:func:`lde.cli.jit.announce_compiles`)."""
    tag = f"py{sys.version_info[0]}{sys.version_info[1]}"
    for d in cache_dirs():
        for loop in loops:
            if d.is_dir() and next(d.glob(f"loop.{loop}-*.{tag}.nbi"), None) is not None:
                return True
    return False


def notice() -> str:
    """:data:`NOTICE` with this installation's cache directories."""
    return NOTICE.format(where=" or ".join(str(d) for d in cache_dirs()))
