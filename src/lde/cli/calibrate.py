"""``lde calibrate LOG``: identify C_f, C_r, K (and steering friction, offsets) from a drive.

LOG is any log ``lde replay`` reads (MCAP, candump ``-L``, python-can formats) of a drive *without
significant disturbance* (still air, flat road) with transient steering: a few lane changes or a
slalom at 60-120 km/h. Body parameters (mass, yaw inertia, CG, steering ratio) come from
``--vehicle`` (default: reference); the result is a vehicle file that ``extends`` it and overrides
``[tires]`` and ``[corrections]`` (steering friction, torsion-bar twist, steering-angle offset,
yaw-rate bias, torque offset: removed from the inputs before the step, ``lde.estimator.conditioning``), for
``lde run/replay --vehicle FILE``. ``--no-corrections`` writes only effective ``[tires]`` for the
paper's step. The command replays the drive with the base and the calibrated file and prints the
RMS of both estimates (the drive has no disturbance: lower is better). Method: ``lde.analysis.calibrate``
(least squares on the bicycle-model equations; friction and offsets as extra regressors).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lde.analysis.adaptive import drive_from_grid, grid_from_frames
from lde.analysis.calibrate import calibrate, write_vehicle
from lde.cli import PROFILE_HELP
from lde.errors import ConfigError
from lde.io import read_log
from lde.params import load_vehicle


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate",
        help="identify Cf, Cr, K from an undisturbed drive and write a vehicle file",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("log", type=Path, help="CAN log of a drive without disturbance")
    p.add_argument("--vehicle", default=None, help="base vehicle file or shipped name (default: reference)")
    p.add_argument("--profile", default="lde", help=PROFILE_HELP + " (default: lde)")
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
        help="identify the torsion-bar twist in the steering angle (auto: on profiles whose angle sensor "
        "sits above the torsion bar, angle_above_torsion_bar; not on lde's, the MDPS's pinion angle)",
    )
    p.add_argument(
        "--keep-tires",
        action="store_true",
        help="write only [corrections]; keep the base vehicle's [tires] (when they are known better than a "
        "lane change can tell, e.g. identified over the whole lateral-acceleration range)",
    )
    p.add_argument(
        "--no-corrections",
        dest="corrections",
        action="store_false",
        help="write only [tires], effective values for the paper's step (no [corrections] table)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from lde.can.profiles import load_profile
    from lde.params import load_vehicle as _load
    from lde.replay.replay import replay
    from lde.status import VALID

    base = load_vehicle(args.vehicle)
    profile = load_profile(args.profile)
    log = read_log(args.log)
    grid = grid_from_frames(log.frames, profile)
    drive = drive_from_grid(grid)
    if args.corrections:
        torsion = args.torsion == "yes" or (args.torsion == "auto" and profile.angle_above_torsion_bar)
        if not profile.steering_rate_signed:
            print(
                f"note: profile {profile.name} carries the steering rate without its sign: "
                "friction not identified"
            )
        cal = calibrate(drive, base, identify_torsion=torsion, identify_friction=profile.steering_rate_signed)
    else:
        # tires only, for the paper's step: no torsion model, so fit effective values
        cal = calibrate(drive, base, identify_torsion=False)
    if args.keep_tires and not args.corrections:
        raise ConfigError("--keep-tires with --no-corrections would write nothing")
    out = write_vehicle(
        cal,
        base,
        args.out,
        name=args.name,
        log=str(args.log),
        corrections=args.corrections,
        tires=not args.keep_tires,
    )
    print("calibration: " + cal.summary())
    print("identified (95 % intervals: Newey-West over the drive plus the fit's systematic term; a")
    print("correction is written only when its interval excludes zero):")
    for line in cal.report_lines():
        print("  " + line)
    print(f"wrote {out}")

    # self-check on the same drive: it has no disturbance, so the estimate should be ~0
    def rms(vehicle):  # (RMS Fw [N], RMS Mw [Nm]) over the valid steps
        r = replay(log.frames, profile, vehicle, "paper")  # the filter the corrections feed
        ok = (r.status & VALID) != 0
        if not ok.any():
            return float("nan"), float("nan")
        return float(np.sqrt(np.mean(r.fw[ok] ** 2))), float(np.sqrt(np.mean(r.mw[ok] ** 2)))

    b, c = rms(base), rms(_load(out))
    print(
        f"estimate on this (undisturbed) drive, RMS Fw / Mw: {base.name} {b[0]:.0f} N / {b[1]:.1f} Nm -> "
        f"calibrated {c[0]:.0f} N / {c[1]:.1f} Nm"
    )
    return 0
