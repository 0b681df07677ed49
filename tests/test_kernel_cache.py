"""lde.cli.kernels: the ``lde`` command's kernels live in a directory keyed by lde's sources (a cached
kernel never outlives a change to a file it calls into), ``import lde`` changes nothing, and the
compile notice appears when numba really compiles, with this machine's last measured time."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

from numba import njit

from lde.cli import kernels

SAMPLE = Path(__file__).parent / "data" / "sample_linear.log"

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


def _write_pkg(root: Path, v: int) -> Path:
    pkg = root / "kpkg"
    pkg.mkdir(exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "caller.py").write_text(textwrap.dedent(CALLER))
    (pkg / "callee.py").write_text(textwrap.dedent(CALLEE.format(v=v)))
    return pkg


def _run(root: Path, cache: Path) -> int:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache), PYTHONPATH=str(root))
    code = "from kpkg.caller import run; print(run())"
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300, check=True
    )
    return int(out.stdout.strip().splitlines()[-1])


def _bump(f: Path, text: str) -> None:
    st = f.stat()
    f.write_text(text)
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 2_000_000_000))  # a coarse clock still sees it


def test_a_changed_callee_gets_a_new_kernel_directory(tmp_path):
    """numba's cache checks a caller against its own file only: in the same directory the caller
    keeps the old callee (the numba behaviour this exists for); the directory keyed by the sources
    changes with the callee, and there the caller is compiled with the new one."""
    pkg = _write_pkg(tmp_path, 1)
    base = tmp_path / "cache"
    before = kernels.kernel_dir(base, [pkg])
    assert _run(tmp_path, before) == 10
    _bump(pkg / "callee.py", textwrap.dedent(CALLEE.format(v=2)))
    after = kernels.kernel_dir(base, [pkg])
    assert after != before and after.parent == before.parent
    assert _run(tmp_path, before) == 10  # stale: what a cache not keyed by the sources would run
    assert _run(tmp_path, after) == 20
    assert kernels.prune_other_kernel_dirs(after) == [before] and not before.exists()


def test_an_lde_started_by_lde_uses_the_same_kernel_directory(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    d = kernels.kernel_dir()
    assert d.parent == tmp_path / "mine"
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(d))  # what the parent `lde` hands its children
    assert kernels.kernel_dir() == d


def test_import_lde_neither_imports_numba_nor_sets_its_cache():
    code = "import os, sys, lde, lde.cli; print('numba' in sys.modules, os.environ.get('NUMBA_CACHE_DIR'))"
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "None"]


def test_the_lde_command_compiles_once_into_its_sources_directory_and_says_so_only_then(tmp_path):
    """A first ``lde replay`` on an empty cache says that it compiles (once, on stderr), compiles into
    the directory of lde's sources below the user's NUMBA_CACHE_DIR and stores its compile time; the
    second run loads everything (no notice); a third on an emptied cache names the time measured."""
    base = tmp_path / "cache"
    env = dict(os.environ, NUMBA_CACHE_DIR=str(base))
    csv = tmp_path / "o.csv"
    argv = [sys.executable, "-m", "lde", "replay", str(SAMPLE), "--backend", "paper", "--csv", str(csv)]

    def lde() -> str:
        r = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, r.stderr
        return r.stderr

    first = lde()
    assert first.count("lde: compiling the numba kernels") == 1, first
    assert "once per install or upgrade" in first
    d = kernels.kernel_dir(base)
    assert f"cached in {d}" in first
    assert list(d.rglob("*.nbi")), "the kernels went elsewhere"
    second = lde()
    assert "compiling" not in second, second
    times = (base / "compile-times.json").read_text()
    assert '"replay paper"' in times
    for f in d.rglob("*.nb*"):
        f.unlink()
    third = lde()
    assert "here last time" in third, third


def test_the_notice_appears_at_a_real_compilation_and_stores_its_time(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    said: list[str] = []

    @njit
    def twice(x):  # not cached: compiled at its first call
        return 2 * x

    with kernels.compile_notice("test key", write=said.append):
        assert twice(21) == 42
        assert twice(4) == 8  # the same types: no second compilation, no second notice
    assert len(said) == 1 and "once per install or upgrade" in said[0]
    took = kernels.last_compile_s("test key")
    assert took is not None and took >= 0.0
    with kernels.compile_notice("test key", write=said.append):
        assert twice(2) == 4  # compiled already: nothing said
    assert len(said) == 1
    assert "here last time" in kernels.notice_text("test key")
