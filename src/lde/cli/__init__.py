"""The ``lde`` command. One module per subcommand, each with ``add_parser(sub)`` and ``run(args) -> int``.

Errors a user can fix (:class:`lde.errors.LdeError`) end as one ``lde: error: ...`` line and exit
status 2, never a traceback.

Start-up: when the command line names a subcommand, only that subcommand's module is imported (the
others get a bare placeholder parser), so ``lde replay`` does not pay for the service, the
calibrator or the study's imports. ``lde``, ``lde --help`` and an unknown command import them all
(the help lists every subcommand). A module's ``add_parser`` should stay cheap: heavy imports belong
inside its ``run`` (the one place where lde imports inside functions: measured with
``python -X importtime``, ``import lde.cli`` takes 8 ms, ``lde.replay.replay`` 0.76 s,
``lde.service.service`` 1.0 s,
``lde.analysis.study`` with dask 1-2 s; ``tests/test_replay.py`` checks that ``--help`` stays light).

Exit: the ``lde`` process (:func:`main` called without ``argv``) freezes the garbage collector's
objects before it returns, so that Python's final collections do not walk the ~140k objects that
numba, its registries and the kernels left behind (none of which needs a finaliser; lde closes its
outputs itself). That took 0.3-1.5 s after a replay had ended, depending on the machine's load
(docs/service.md, "Replay speed").
"""

from __future__ import annotations

import argparse
import gc
import importlib
import logging
import sys
from collections.abc import Sequence

from lde.errors import LdeError

#: the help of every --backend option (the names are checked against lde.engine.backends' registry when
#: the command runs, which keeps building the parser light; tests/test_backends.py checks that this text
#: names every registered backend)
BACKEND_HELP = (
    "estimator: fixed (default): the lateral filter in fixed point (the firmware model) with its float "
    "shadow check; float: the lateral filter in float; paper: the paper's 4-state filter in float"
)

#: the shipped CAN profiles (lde.can.profiles.PROFILE_NAMES: kept here so that building the parser
#: stays light; tests/test_profile_files.py holds them equal)
PROFILE_CHOICES = ("lde", "hyundai", "toyota_rav4_2017")
#: the help of every --profile option
PROFILE_HELP = (
    f"CAN profile: a shipped one ({', '.join(PROFILE_CHOICES)}) or a profile file (.toml; its format: "
    "docs/guide/profiles.md)"
)

#: subcommand name -> module below lde.cli. A module that does not exist yet is skipped.
SUBCOMMANDS = ("demo", "run", "sim", "replay", "inspect", "evaluate", "study", "calibrate", "warmup")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lde")
    except PackageNotFoundError:  # a source tree that was not installed
        return "unknown"


class _VersionAction(argparse.Action):
    """``--version``, with the version looked up only when asked: ``importlib.metadata`` took
    10-25 ms of every ``lde`` start-up when the parser was built with the version in it."""

    def __init__(self, option_strings: Sequence[str], dest: str = argparse.SUPPRESS, help: str | None = None):
        super().__init__(option_strings, dest=dest, default=argparse.SUPPRESS, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(f"lde {_version()}")
        parser.exit()


def _command_in(argv: Sequence[str]) -> str | None:
    """The subcommand named on the command line (the first word that is not a top-level option),
    when it is one of :data:`SUBCOMMANDS`; ``""`` for ``--version`` (no subcommand needed); else
    None."""
    for a in argv:
        if a == "--version":
            return ""
        if a == "--":
            return None
        if not a.startswith("-"):
            return a if a in SUBCOMMANDS else None
    return None


def build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``lde`` parser. With ``argv`` naming a subcommand, only that subcommand's module is
    imported; the others are placeholders (never shown: argparse prints one subcommand's help)."""
    parser = argparse.ArgumentParser(
        prog="lde",
        description="Lateral disturbance estimator for MDPS cars: CAN service, replay, simulator, studies.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    parser.add_argument("--version", action=_VersionAction, help="show lde's version and exit")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    only = _command_in(argv) if argv is not None else None
    for name in SUBCOMMANDS:
        if only is not None and name != only:
            sub.add_parser(name)
            continue
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue
            raise
        mod.add_parser(sub)
    return parser


def _notice_key(args: argparse.Namespace) -> str:
    """What a run compiles, as the key of its measured compile time (lde.cli.kernels)."""
    parts = [str(args.command), str(getattr(args, "backend", None) or "")]
    if getattr(args, "smooth", False):
        parts.append("--smooth")
    return " ".join(p for p in parts if p)


def main(argv: Sequence[str] | None = None) -> int:
    whole_process = argv is None  # the `lde` command: the process ends when this returns
    if whole_process:
        from lde.cli.kernels import use_kernel_cache

        use_kernel_cache()  # before numba is imported: kernels keyed by lde's sources
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        if args.command == "warmup":  # says what it compiles itself
            return int(args.func(args) or 0)
        from lde.cli.kernels import compile_notice

        with compile_notice(_notice_key(args), quiet=bool(getattr(args, "quiet", False))):
            return int(args.func(args) or 0)
    except LdeError as exc:
        print(f"lde: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    finally:
        if whole_process:
            gc.freeze()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
