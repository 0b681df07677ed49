"""``lde warmup``: the parts it names are the parts it has, and its default is all of them."""

from __future__ import annotations

import pytest

import lde.warmup
from lde.cli import main
from lde.cli.warmup import PART_NAMES


def test_the_cli_names_every_part_and_only_those() -> None:
    assert PART_NAMES == lde.warmup.PARTS


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
    assert "choose from fixed, float, paper-fixed, paper, logio, sim, smooth" in err
    assert "Traceback" not in err


def test_a_part_really_runs(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["warmup", "--parts", "logio"]) == 0
    err = capsys.readouterr().err
    assert "logio:" in err and "lde warmup: done" in err
