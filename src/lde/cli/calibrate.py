"""``lde calibrate LOG``: identify C_f, C_r, K (and steering friction, offsets) from a drive.

LOG is any log ``lde replay`` reads (MCAP, candump ``-L``, python-can formats) of a drive *without
significant disturbance* (still air, flat road) with transient steering: a few lane changes or a
slalom at 60-120 km/h. Body parameters (mass, yaw inertia, CG, steering ratio) come from
``--vehicle`` (default: reference); the result is a vehicle file that ``extends`` it and overrides
``[tires]`` with effective values for the estimator step as it is (the torsion-bar twist folded
in), for ``lde run/replay --vehicle FILE``; the full calibration (tire values with the torsion bar
modelled, friction, offsets, accelerometer scale) is written as comments. Method: ``lde.calibrate``
(least squares on the bicycle-model equations; friction and offsets as extra regressors).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ..adaptive import drive_from_grid, grid_from_frames
from ..calibrate import calibrate, write_vehicle
from ..logio import read_log
from ..params import load_vehicle


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="identify Cf, Cr, K from an undisturbed drive and write a vehicle file",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("log", type=Path, help="CAN log of a drive without disturbance")
    p.add_argument("--vehicle", default=None, help="base vehicle file or shipped name (default: reference)")
    p.add_argument("--profile", default="lde", help="CAN profile: lde, hyundai or a .dbc path")
    p.add_argument(
        "-o",
        "--out",
        type=Path,
        default=Path("calibrated.toml"),
        help="vehicle file to write (calibrated.toml)",
    )
    p.add_argument("--name", default="calibrated", help="name inside the written vehicle file")
    p.add_argument(
        "--torsion",
        choices=("auto", "yes", "no"),
        default="auto",
        help="identify the torsion-bar twist in the steering angle (auto: not on profile lde, whose "
        "angle is the MDPS's pinion angle; yes on profiles that carry the steering-wheel angle)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    base = load_vehicle(args.vehicle)
    log = read_log(args.log)
    grid = grid_from_frames(log.frames, args.profile)
    drive = drive_from_grid(grid)
    torsion = args.torsion == "yes" or (args.torsion == "auto" and str(args.profile) != "lde")
    full = calibrate(drive, base, identify_torsion=torsion)
    # the file is for the estimator step as it is: no torsion model, so fit effective values
    cal = calibrate(drive, base, identify_torsion=False)
    out = write_vehicle(cal, base, args.out, name=args.name, log=str(args.log), full=full)
    print("full calibration:        " + full.summary())
    print("effective (vehicle file): " + cal.summary())
    print(f"wrote {out}")
    return 0
