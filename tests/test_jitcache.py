"""lde.jitcache.drop_stale: a cached kernel never outlives a change to a file it calls into."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from lde.jitcache import STAMP_NAME, drop_stale, sources_digest, sources_stamp

CALLEE = """
from numba import njit

@njit(cache=True)
def value():
    return {v}
"""
CALLER = """
from numba import njit
from .callee import value

@njit(cache=True)
def run():
    return value() * 10
"""
RUN = """
import sys
sys.path.insert(0, {root!r})
from lde.jitcache import drop_stale
if {drop}:
    drop_stale([__import__("pathlib").Path({pkg!r})])
from kpkg.caller import run
print(run())
"""


def _write_pkg(root: Path, v: int) -> Path:
    pkg = root / "kpkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "caller.py").write_text(textwrap.dedent(CALLER))
    (pkg / "callee.py").write_text(textwrap.dedent(CALLEE.format(v=v)))
    return pkg


def _run(root: Path, pkg: Path, cache: Path, drop: bool) -> int:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    code = RUN.format(root=str(root), pkg=str(pkg), drop=drop)
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300, check=True
    )
    return int(out.stdout.strip().splitlines()[-1])


def _bump(f: Path, text: str) -> None:
    st = f.stat()
    f.write_text(text)
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 2_000_000_000))  # a coarse clock still sees it


@pytest.mark.parametrize("drop", [False, True])
def test_a_callers_cached_kernel_follows_a_changed_callee_only_with_drop_stale(tmp_path, drop):
    """numba's cache checks only the caller's own file: without drop_stale the caller keeps the old
    callee (this documents the numba behaviour the function exists for); with it, the new one."""
    pkg = _write_pkg(tmp_path, 1)
    cache = tmp_path / "cache"
    assert _run(tmp_path, pkg, cache, drop) == 10
    _bump(pkg / "callee.py", textwrap.dedent(CALLEE.format(v=2)))
    assert _run(tmp_path, pkg, cache, drop) == (20 if drop else 10)


def test_drop_stale_keeps_a_cache_whose_sources_did_not_change(tmp_path, monkeypatch):
    pkg = _write_pkg(tmp_path, 1)
    cache_root = tmp_path / "cache"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache_root))
    from lde.jitcache import _dir_cache_dirs

    (cdir,) = _dir_cache_dirs(pkg)
    cdir.mkdir(parents=True)
    for name in ("caller.run-5.py311.nbi", "caller.run-5.py311.1.nbc"):
        (cdir / name).write_bytes(b"x")
    assert drop_stale([pkg]) == 2  # no stamp yet: whatever is there may be stale
    assert (cdir / STAMP_NAME).read_text() == f"{sources_stamp([pkg])} {sources_digest([pkg])}"
    (cdir / "caller.run-5.py311.nbi").write_bytes(b"x")
    assert drop_stale([pkg]) == 0 and (cdir / "caller.run-5.py311.nbi").exists()
    # touched, same content (a checkout; the tree seen through user-mode Linux's hostfs): kept
    _bump(pkg / "callee.py", (pkg / "callee.py").read_text())
    assert drop_stale([pkg]) == 0 and (cdir / "caller.run-5.py311.nbi").exists()
    assert (cdir / STAMP_NAME).read_text().split()[0] == sources_stamp([pkg])
    _bump(pkg / "callee.py", textwrap.dedent(CALLEE.format(v=3)))
    assert drop_stale([pkg]) == 1 and not (cdir / "caller.run-5.py311.nbi").exists()


def test_drop_stale_leaves_an_unwritable_cache_alone(tmp_path, monkeypatch):
    if os.geteuid() == 0:
        pytest.skip("root writes anywhere")
    pkg = _write_pkg(tmp_path, 1)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "cache"))
    from lde.jitcache import _dir_cache_dirs

    (cdir,) = _dir_cache_dirs(pkg)
    cdir.mkdir(parents=True)
    (cdir / "x.nbi").write_bytes(b"x")
    cdir.chmod(0o500)
    try:
        assert drop_stale([pkg]) == 0
    finally:
        cdir.chmod(0o700)


def test_a_first_runs_kernels_survive_the_second_runs_drop_stale(tmp_path, monkeypatch):
    """A first run on an empty cache directory: numba makes the directory and writes the kernels
    there after drop_stale ran. The second run must load them, not take them for stale (it did:
    the second run after an install compiled everything again)."""
    pkg = _write_pkg(tmp_path, 1)
    cache = tmp_path / "cache"
    assert _run(tmp_path, pkg, cache, True) == 10
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(cache))
    from lde.jitcache import _dir_cache_dirs

    (cdir,) = _dir_cache_dirs(pkg)

    def files() -> dict[str, tuple[int, int]]:
        return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns) for p in cdir.glob("*.nb[ic]")}

    first = files()
    assert len(first) == 4 and (cdir / STAMP_NAME).exists()  # caller and callee: index and data each
    assert _run(tmp_path, pkg, cache, True) == 10
    assert files() == first  # the same files: loaded, not deleted and written again
