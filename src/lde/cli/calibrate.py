"""``lde calibrate LOG``: identify C_f, C_r, K (and steering friction, offsets) from a drive.

LOG is any log ``lde replay`` reads (MCAP, candump ``-L``, python-can formats, also as .gz) of a drive
*without significant disturbance* (still air, flat road) with transient steering: a few lane changes
or a slalom at 60-120 km/h. Body parameters (mass, yaw inertia, CG, steering ratio) come from
``--vehicle`` (default: reference); the result (``--toml``, default calibrated.toml) is a vehicle file
that ``extends`` it and overrides ``[tires]`` and ``[corrections]`` (steering friction, torsion-bar
twist, steering-angle offset, yaw-rate bias, torque offset: removed from the inputs before the step,
``lde.estimator.conditioning``), for ``lde run/replay --vehicle FILE``. ``--no-corrections`` writes only
effective ``[tires]`` for the paper's filter. Method: ``lde.analysis.calibrate`` (least squares on the
single-track model's equations with Fw = Mw = 0; friction and offsets as extra regressors): the
identification uses no estimator backend, so there is no ``--backend`` option.

The command then replays the drive with the base and with the calibrated file and prints the RMS
of both estimates (the drive has no disturbance: lower is better). That check always runs the
paper's float filter (backend ``paper``, where ``lde run``, ``replay`` and ``demo`` default to
``fixed``): it uses the file's tires and corrections as written and learns nothing while it runs, so
the two figures compare the files alone (the lateral filter's online learner would adapt the tires
itself). To see the product's estimator on the calibrated file, run ``lde replay LOG --vehicle
calibrated.toml``.
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
    p.add_argument(
        "log", metavar="LOG", type=Path, help="CAN log of a drive without disturbance (formats as lde replay)"
    )
    p.add_argument("--vehicle", default=None, help="base vehicle file or shipped name (default: reference)")
    p.add_argument(
        "--profile",
        default=None,
        help=PROFILE_HELP + " (default: the one an lde recording names, else lde)",
    )
    p.add_argument(
        "--toml",
        type=Path,
        default=Path("calibrated.toml"),
        metavar="OUT.toml",
        help="the vehicle file to write (default: calibrated.toml)",
    )
    # the earlier spelling, still accepted (--out names a directory in lde study and lde evaluate)
    p.add_argument("-o", "--out", dest="toml", type=Path, default=argparse.SUPPRESS, help=argparse.SUPPRESS)
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
    from lde.replay.replay import recorded_profile, replay
    from lde.status import VALID

    base = load_vehicle(args.vehicle)
    log = read_log(args.log)
    profile = load_profile(args.profile or recorded_profile(log) or "lde")
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
        args.toml,
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
        r = replay(log.frames, profile, vehicle, "paper")  # no online learning: the files alone (help)
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
