"""``lde inspect LOG [--profile NAME|FILE.toml] [--vehicle NAME|FILE.toml] [--json]``.

What a user needs before trusting a new car: which ids and channels the log holds, at which rates;
which shipped (or the given) profile fits it; for the profile, each input's range, rate, staleness
and integrity; and physics checks of its signs and scales, each with pass, fail (and the profile
line to change) or not enough excitation, and the numbers behind it (docs/guide/inspect.md).

Exit status: 0 when the inspection ran (whatever the checks say), 2 on a user error (a missing
file, a bad profile or vehicle file), 3 when the log has none of the profile's input messages
(without ``--profile``: none of any shipped profile's).
"""

from __future__ import annotations

import argparse
import sys

#: the log has none of the profile's input messages
EXIT_NO_INPUTS = 3


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "inspect",
        help="what a log holds, which profile fits it, and physics checks of the profile's signs and scales",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
        epilog=__doc__.split("\n\n")[2] if __doc__ else None,
    )
    p.add_argument("log", metavar="LOG", help="MCAP, candump -L text, ASC, BLF, TRC, CSV, ... (also as .gz)")
    p.add_argument(
        "--profile",
        default=None,
        help="the CAN profile to check (a shipped name or a file); default: the shipped one that fits",
    )
    p.add_argument(
        "--vehicle",
        default=None,
        help="vehicle TOML file or shipped name: its steering ratio, wheelbase, track (default: reference)",
    )
    p.add_argument("--json", action="store_true", help="the report as JSON on stdout (for scripts)")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from lde.analysis.inspect.inspection import inspect_frames
    from lde.analysis.inspect.report import render_json, render_text
    from lde.can.profiles import PROFILE_NAMES, load_profile
    from lde.errors import ConfigError
    from lde.io import read_log
    from lde.params import load_vehicle

    path = Path(args.log)
    if not path.is_file():
        raise ConfigError(f"{path}: no such file")
    vehicle = load_vehicle(args.vehicle or "reference")
    given = load_profile(args.profile) if args.profile is not None else None
    log = read_log(path)
    shipped = [load_profile(name) for name in PROFILE_NAMES]
    insp = inspect_frames(log.frames, vehicle, given=given, shipped=shipped)
    source = f"{path} ({log.format})"
    sys.stdout.write(render_json(insp, source) if args.json else render_text(insp, source))
    if insp.no_input_messages:
        if not args.json:
            which = f"profile {insp.profile}" if insp.profile is not None else "any shipped profile"
            print(f"lde inspect: the log has none of the input messages of {which}", file=sys.stderr)
        return EXIT_NO_INPUTS
    return 0
