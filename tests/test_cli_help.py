"""Every ``--help`` is written for a user: no development history (issue or item numbers, figure
and table numbers), no unexplained aliases, the default backend stated where it differs, and the
same argument names for the same things."""

from __future__ import annotations

import re

import pytest

from lde.cli import SUBCOMMANDS, build_parser, main

#: what a help text must not contain: references to the development's notes or to numbered
#: figures / tables a user does not have
HISTORY = re.compile(
    r"\bissues?\s*#?\d|\bitems?\s+\d|(?-i:\bFig)|\bTable\s+\d|\bsteps?\s+\d+-\d+\b|"
    r"\b(first|second|third|fourth|fifth) pass\b",
    re.IGNORECASE,
)


def _help(capsys, *argv: str) -> str:
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--help"])
    assert exc.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("command", ["", *SUBCOMMANDS])
def test_no_development_history_in_any_help(capsys, command):
    text = _help(capsys, *([command] if command else []))
    assert len(text) > 200, text
    found = [m.group(0) for m in HISTORY.finditer(text)]
    assert not found, f"lde {command} --help mentions {found}"


def test_the_history_pattern_catches_what_it_must():
    for bad in ("(issues 6 and 11)", "issue 6, items 2 and 6", "PNG plot (Figs. 13-14 style)", "Table 1"):
        assert HISTORY.search(bad), bad
    for fine in ("the figures are RMS errors", "the paper's section-5 study", "steps of 3.9 ms"):
        assert not HISTORY.search(fine), fine


@pytest.mark.parametrize("command", ["run", "replay", "demo", "study", "evaluate"])
def test_the_help_offers_the_backends_and_no_removed_name(capsys, command):
    """The names are checked against the registry when the command runs (a removed one is an error
    naming its replacement: tests/test_backends.py); the help names the three backends only."""
    text = " ".join(_help(capsys, command).split())
    if command in ("run", "replay", "demo"):
        assert "fixed (default)" in text and "float:" in text and "paper:" in text
    assert "paper-fixed" not in text and "lateral:" not in text and ",lateral" not in text


def test_every_backend_default_is_the_same_or_said_with_its_reason(capsys):
    for command in ("run", "replay", "demo"):
        assert "fixed (default)" in _help(capsys, command)
    for command in ("study", "evaluate"):
        text = " ".join(_help(capsys, command).split())
        assert "default here: paper" in text and "default to fixed" in text
        assert "docs/design/studies.md" in text
    text = " ".join(_help(capsys, "calibrate").split())
    assert "no --backend option" in text.replace("``", "")
    assert "paper's float filter" in text and "learns nothing" in text


def test_calibrate_takes_the_same_argument_names_and_the_old_spelling(capsys, tmp_path):
    text = _help(capsys, "calibrate")
    usage = " ".join(text.split("\n\n")[0].split())
    assert usage.endswith(" LOG") and "--toml OUT.toml" in usage and "--profile PROFILE" in usage
    assert "-o" not in usage and "--out" not in usage
    parser = build_parser(["calibrate"])
    for spelling in (["--toml", "a.toml"], ["-o", "a.toml"], ["--out", "a.toml"]):
        args = parser.parse_args(["calibrate", "drive.log", *spelling])
        assert str(args.toml) == "a.toml" and str(args.log) == "drive.log"
    assert str(parser.parse_args(["calibrate", "drive.log"]).toml) == "calibrated.toml"
    assert parser.parse_args(["calibrate", "drive.log"]).profile is None  # as replay: the recording's
