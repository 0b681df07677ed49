"""The ``lde`` command. One module per subcommand, each with ``add_parser(sub)`` and ``run(args) -> int``.

Errors a user can fix (:class:`lde.errors.LdeError`) end as one ``lde: error: ...`` line and exit
status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from collections.abc import Sequence

from ..errors import LdeError

#: subcommand name -> module below lde.cli. A module that does not exist yet is skipped.
SUBCOMMANDS = ("demo", "run", "sim", "replay", "evaluate", "study", "calibrate")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("lde")
    except PackageNotFoundError:  # a source tree that was not installed
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lde",
        description="Lateral disturbance estimator for MDPS cars: CAN service, replay, simulator, studies.",
    )
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv: debug)")
    parser.add_argument("--version", action="version", version=f"lde {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            mod = importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"{__name__}.{name}":
                continue
            raise
        mod.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING - 10 * min(args.verbose, 2)
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except LdeError as exc:
        print(f"lde: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
