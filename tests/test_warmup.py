"""``lde warmup``: the parts it names are the parts it has, and its default is all of them."""

from __future__ import annotations

import pytest

import lde.warmup
from lde.cli import main
from lde.engine.backends import BACKENDS


def test_every_backend_is_a_part() -> None:
    assert set(BACKENDS) <= set(lde.warmup.PARTS)


def test_default_warms_every_part(monkeypatch: pytest.MonkeyPatch) -> None:
    asked: list[list[str]] = []

    def fake(parts, jobs=1):  # the compiling itself is checked below on one part
        asked.append(list(parts))
        return iter([(p, 0.0) for p in parts])

    monkeypatch.setattr(lde.warmup, "warm_up", fake)
    assert main(["warmup"]) == 0
    assert asked == [list(lde.warmup.PARTS)]
    assert main(["warmup", "--parts", "sim, logio"]) == 0
    assert asked[-1] == ["sim", "logio"]


def test_unknown_part_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["warmup", "--parts", "fixed,lateral"]) == 2
    err = capsys.readouterr().err
    assert f"choose from {', '.join(lde.warmup.PARTS)}" in err and "lateral" in err
    assert "Traceback" not in err


def test_a_part_really_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["warmup", "--parts", "logio"]) == 0
    err = capsys.readouterr().err
    assert "logio:" in err and "lde warmup: done" in err


def test_background_detaches_the_same_command(
    monkeypatch: pytest.MonkeyPatch, tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    started: list[tuple[list[str], dict]] = []

    class FakePopen:
        pid = 4242

        def __init__(self, argv, **kw):
            started.append((argv, kw))

    monkeypatch.setattr("lde.cli.warmup.subprocess.Popen", FakePopen)
    log = tmp_path / "w.log"
    assert main(["warmup", "--parts", "fixed", "--jobs", "2", "--background", "--log", str(log)]) == 0
    ((argv, kw),) = started
    assert argv[1:] == ["-m", "lde", "warmup", "--parts", "fixed", "--jobs", "2"]
    assert kw["start_new_session"] and log.exists()
    assert "pid 4242" in capsys.readouterr().err


def test_background_with_an_unwritable_log_is_a_one_line_error(
    tmp_path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["warmup", "--background", "--log", str(tmp_path / "no" / "such" / "w.log")]) == 2
    err = capsys.readouterr().err
    assert "cannot write it" in err and "Traceback" not in err
