"""``lde demo``: simulator + live service on python-can's virtual bus, closed loop, faster than real time.

Runs a scenario (default: the paper's heavy lateral load) with the overlay and without it, prints the
estimation error against the simulator's truth and the driver's holding torque and lateral drift with
and without the overlay, and writes an MCAP recording (open it in Foxglove) and a PNG plot.
"""

from __future__ import annotations

import argparse
import sys

from lde.cli import BACKEND_HELP, PROFILE_HELP


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "demo",
        help="closed-loop demo: simulator + service on a virtual bus (summary, MCAP, plot)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--scenario", default=None, help="simulator scenario (default heavy_load; lde sim --list)")
    p.add_argument("--seed", type=int, default=1, help="seed of wind, driver and sensor noise")
    p.add_argument("--duration", type=float, metavar="SEC", help="simulated seconds (default: scenario)")
    p.add_argument("--vehicle", default=None, help="vehicle TOML file or shipped name (default: reference)")
    p.add_argument("--profile", default="lde", help=PROFILE_HELP + " (default: lde)")
    p.add_argument("--backend", default="fixed", help=BACKEND_HELP)
    p.add_argument("--mcap", default="lde_demo.mcap", metavar="FILE", help="recording of the overlay run")
    p.add_argument(
        "--plot",
        default="lde_demo.png",
        metavar="FILE",
        help="PNG plot: Fw and Mw against the truth, the driver's torque and the drift with and without "
        "the overlay, the overlay torque and the speed",
    )
    p.add_argument("--no-mcap", action="store_true", help="do not write the recording")
    p.add_argument("--no-plot", action="store_true", help="do not write the plot")
    p.add_argument(
        "--full-off-run",
        action="store_true",
        help="run the no-overlay case through the service loop too (default: the simulator's fast path, "
        "identical plant trajectory)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from lde.demo import DEFAULT_SCENARIO, run_demo
    from lde.params import load_vehicle

    vehicle = load_vehicle(args.vehicle)
    if args.duration is not None and args.duration <= 0:
        from lde.errors import ConfigError

        raise ConfigError(f"--duration must be > 0, got {args.duration}")
    summary, _on, _off = run_demo(
        args.scenario or DEFAULT_SCENARIO,
        seed=args.seed,
        duration=args.duration,
        vehicle=vehicle,
        backend=args.backend,
        profile=args.profile,
        mcap=None if args.no_mcap else args.mcap,
        png=None if args.no_plot else args.plot,
        full_off_run=args.full_off_run,
    )
    print(summary.text())
    sys.stdout.flush()
    return 0
