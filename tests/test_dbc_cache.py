"""The parsed-profile cache (lde.can.profiles.load_profile): keyed by the profile file's and the DBC's
bytes, never serving a changed file; a corrupt, foreign or unwritable cache falls back to parsing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lde.can.codec import MessageCodec
from lde.can.profiles import OUTPUT_MESSAGES, dbc_dir, load_profile, profile_cache_dir
from lde.engine.receiver import RxTables
from lde.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def cache(tmp_path, monkeypatch) -> Path:
    d = tmp_path / "cache"
    monkeypatch.setenv("LDE_PROFILE_CACHE", str(d))
    return d


def _entries(d: Path) -> list[Path]:
    return sorted(d.glob("*.pickle")) if d.is_dir() else []


def _same(a, b) -> None:
    """Two profiles give the same receiver tables, specs and output layouts."""
    assert dict(a.messages) == dict(b.messages)
    assert dict(a.outputs) == dict(b.outputs)
    assert dict(a.inputs) == dict(b.inputs)
    assert dict(a.signals) == dict(b.signals)
    ta, tb = RxTables.of(a).kernel_args(), RxTables.of(b).kernel_args()
    for x, y in zip(ta, tb, strict=True):
        np.testing.assert_array_equal(x, y)
    for name in OUTPUT_MESSAGES:
        ca, cb = MessageCodec(a, name), MessageCodec(b, name)
        assert ca.signals == cb.signals and ca.integrity == cb.integrity
        for x, y in zip(ca.layout.kernel_args(), cb.layout.kernel_args(), strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("name", ["lde", "hyundai"])
def test_cached_profile_equals_parsed(cache, monkeypatch, name):
    first = load_profile(name)  # parses, writes the entry
    assert len(_entries(cache)) == 1
    cached = load_profile(name)
    assert cached._db is None  # served from the cache: cantools did not parse
    monkeypatch.setenv("LDE_PROFILE_CACHE", "off")
    parsed = load_profile(name)
    assert parsed._db is not None
    _same(first, cached)
    _same(parsed, cached)
    # the database is still there when asked for
    assert cached.db.get_message_by_name("LDE_Estimate").frame_id == parsed.outputs["LDE_Estimate"].frame_id


def _variant(tmp_path: Path, scale_from: str, scale_to: str) -> Path:
    """A copy of lde.dbc with one change, and a copy of lde.toml that reads it (the DBC's path)."""
    text = (dbc_dir() / "lde.dbc").read_text(encoding="cp1252")
    assert scale_from in text
    p = tmp_path / "car.dbc"
    p.write_text(text.replace(scale_from, scale_to, 1), encoding="cp1252")
    toml = (dbc_dir() / "lde.toml").read_text().replace('dbc = "lde.dbc"', 'dbc = "car.dbc"')
    (tmp_path / "car.toml").write_text(toml.replace('name = "lde"', 'name = "car"'))
    return p


def _profile_of(dbc: Path) -> Path:
    return dbc.with_suffix(".toml")


def test_changed_dbc_is_never_served_from_the_cache(cache, tmp_path):
    """The same path, the same size and mtime, another content: parsed again."""
    src = (dbc_dir() / "lde.dbc").read_text(encoding="cp1252")
    line = next(ln for ln in src.splitlines() if "SG_ ColumnTorque" in ln)
    scale = line.split("(")[1].split(",")[0]
    other = scale[:-1] + ("2" if scale[-1] != "2" else "3")  # same length: same file size
    p = _variant(tmp_path, line, line.replace(f"({scale},", f"({other},"))
    st = p.stat()
    a = load_profile(_profile_of(p))
    p.write_text(src, encoding="cp1252")  # back to the shipped scale
    os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert p.stat().st_size == st.st_size
    b = load_profile(_profile_of(p))
    assert b._db is not None  # a miss: parsed
    sa = {s.name: s for s in a.signals["MDPS_Sensors"]}["ColumnTorque"]
    sb = {s.name: s for s in b.signals["MDPS_Sensors"]}["ColumnTorque"]
    assert sa.scale == pytest.approx(float(other)) and sb.scale == pytest.approx(float(scale))
    assert len(_entries(cache)) == 2


def test_db_of_a_dbc_changed_after_loading_is_an_error(cache, tmp_path):
    p = _variant(tmp_path, "LDE", "LDE")
    load_profile(_profile_of(p))
    prof = load_profile(_profile_of(p))  # from the cache: no database yet
    p.write_text(p.read_text(encoding="cp1252") + "\n", encoding="cp1252")
    with pytest.raises(ConfigError, match="changed since"):
        prof.db  # noqa: B018


@pytest.mark.parametrize(
    "garbage",
    [b"", b"\x80\x05not a pickle", b"\x80\x04K\x01.", None],
    ids=["empty", "corrupt", "other", "cut"],
)
def test_corrupt_cache_entry_falls_back_to_parsing(cache, garbage):
    ref = load_profile("lde")
    (entry,) = _entries(cache)
    data = entry.read_bytes()
    entry.write_bytes(data[: len(data) // 2] if garbage is None else garbage)
    p = load_profile("lde")
    assert p._db is not None  # parsed
    _same(ref, p)
    assert load_profile("lde")._db is None  # the entry was written again


def test_incomplete_entry_falls_back_to_parsing(cache):
    import pickle

    load_profile("lde")
    (entry,) = _entries(cache)
    parts = pickle.loads(entry.read_bytes())
    del parts["signals"]
    entry.write_bytes(pickle.dumps(parts))
    p = load_profile("lde")
    assert p._db is not None and "LDE_Estimate" in p.signals


def test_entry_of_another_dbc_is_not_used(cache, tmp_path):
    """An entry copied under another key (or a hash collision of the file name) is refused."""
    load_profile("lde")
    load_profile("hyundai")
    a, b = _entries(cache)
    a.write_bytes(b.read_bytes())
    b.write_bytes(a.read_bytes())
    for name in ("lde", "hyundai"):
        assert load_profile(name).name == name
        assert load_profile(name, max_delta=3)._db is not None  # other receiver parameters: another key


def test_unwritable_cache_parses_every_time(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a directory")
    monkeypatch.setenv("LDE_PROFILE_CACHE", str(blocker / "profiles"))
    p = load_profile("lde")
    assert p._db is not None
    assert load_profile("lde")._db is not None
    assert not list(tmp_path.glob("**/*.tmp"))


def test_cache_dir_default_and_off(monkeypatch, tmp_path):
    monkeypatch.delenv("LDE_PROFILE_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert profile_cache_dir() == tmp_path / "lde" / "profiles"
    monkeypatch.setenv("LDE_PROFILE_CACHE", "off")
    assert profile_cache_dir() is None


def test_replay_with_a_warm_cache_imports_neither_cantools_nor_python_can(tmp_path):
    env = dict(os.environ, LDE_PROFILE_CACHE=str(tmp_path / "c"), PYTHONPATH=os.pathsep.join(sys.path))
    code = (
        "import sys, runpy\n"
        "sys.argv = ['lde', 'replay', sys.argv[1], '--csv', sys.argv[2], '-q']\n"
        "try:\n    runpy.run_module('lde', run_name='__main__')\nexcept SystemExit as e:\n    rc = e.code\n"
        "print(rc, 'cantools' in sys.modules, 'can' in sys.modules)\n"
    )
    log = str(REPO / "tests" / "data" / "sample_linear.log")
    outs = []
    for k in range(2):
        r = subprocess.run(
            [sys.executable, "-c", code, log, str(tmp_path / f"{k}.csv")],
            env=env,
            capture_output=True,
            text=True,
        )
        outs.append(r.stdout.split())
    assert outs[0][0] == "0" and outs[0][1] == "True"  # a miss parses with cantools
    assert outs[1] == ["0", "False", "False"]  # a hit needs neither
    assert (tmp_path / "0.csv").read_bytes() == (tmp_path / "1.csv").read_bytes()


def test_changed_profile_file_is_never_served_from_the_cache(cache, tmp_path):
    """The DBC unchanged, the profile file changed: read again (the sign it says is the new one)."""
    p = _variant(tmp_path, "LDE", "LDE")
    toml = _profile_of(p)
    a = load_profile(toml)
    text = toml.read_text()
    toml.write_text(
        text.replace('signal = "YawRate"\nscale = "deg/s"', 'signal = "YawRate"\nscale = "deg/s"\nsign = -1')
    )
    b = load_profile(toml)
    assert b._db is not None  # a miss: parsed
    assert a.inputs["yaw_rate"].sign == 1.0 and b.inputs["yaw_rate"].sign == -1.0
