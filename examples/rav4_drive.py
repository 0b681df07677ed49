"""The figure and the numbers of docs/guide/rav4.md: lde on a real car's 60 s drive.

Replays the RAV4 log (tests/data/real/rav4_2017_highway.log.gz) with the shipped
``toyota_rav4_2017`` profile and vehicle file, decodes its inputs the way the replay does, and draws
the inputs and the estimates over the drive into one PNG; prints what the replay learned and the
share of valid steps. Run from the repository::

    python examples/rav4_drive.py                       # writes docs/img/rav4_drive.png
    python examples/rav4_drive.py LOG -o out.png --backend fixed

Rows of the figure (time in s from the log's first frame): speed; steering-wheel angle and yaw rate;
lateral acceleration against speed x yaw rate; the two EPS torques in raw counts; the disturbance
force Fw and its wind part; the bank angle; the learner's state and where the estimate is valid.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lde.can.profiles import load_profile
from lde.cli import main as lde_main
from lde.engine.receiver import decode_batch
from lde.io import read_log
from lde.params import load_vehicle
from lde.units import DEG, KMH

REPO = Path(__file__).resolve().parents[1]
LOG = REPO / "tests" / "data" / "real" / "rav4_2017_highway.log.gz"
NAME = "toyota_rav4_2017"
LEARN_STATES = ("not learned", "learning", "learned", "does not learn")


def replay(log: Path, backend: str) -> tuple[np.ndarray, dict]:
    """``lde replay`` of ``log`` as a user runs it: the CSV rows and the learned state."""
    with tempfile.TemporaryDirectory() as tmp:
        csv, learned = Path(tmp) / "rav4.csv", Path(tmp) / "rav4.json"
        argv = ["replay", str(log), "--profile", NAME, "--vehicle", NAME, "--backend", backend]
        rc = lde_main([*argv, "--learned", str(learned), "--csv", str(csv), "-q"])
        if rc != 0:
            raise SystemExit(f"lde replay exited {rc}")
        return np.genfromtxt(csv, delimiter=",", names=True), json.loads(learned.read_text())


def draw(log: Path, rows: np.ndarray, out: Path, backend: str) -> None:
    """The figure (module doc) into ``out``."""
    decoded = decode_batch(load_profile(NAME), read_log(log).frames)
    t0 = decoded.t_first_ns or 0

    def series(name: str) -> tuple[np.ndarray, np.ndarray]:
        s = decoded.inputs[name]
        return (s.t_ns - t0) * 1e-9, s.value

    t = rows["t"] - t0 * 1e-9
    valid = rows["valid"] == 1
    fig = Figure(figsize=(10, 13), layout="constrained")
    ax = fig.subplots(7, 1, sharex=True)
    ax[0].plot(t, rows["speed"] / KMH, color="k")
    ax[0].axhline(load_vehicle(NAME).estimator.min_speed / KMH, color="grey", ls=":", label="model's minimum")
    ax[0].set_ylabel("speed [km/h]")
    ax[0].legend(loc="lower right")
    ts, sa = series("steering_angle")
    ax[1].plot(ts, sa / DEG, label="steering-wheel angle [deg]")
    ty, yr = series("yaw_rate")
    ax[1].plot(ty, 10 * yr / DEG, label="yaw rate x 10 [deg/s]")
    ax[1].legend(loc="lower right")
    ax[1].set_ylabel("left +")
    ta, ay = series("lat_accel")
    ax[2].plot(ta, ay, lw=0.6, label="lateral acceleration")
    tv, v = series("speed")
    ax[2].plot(ty, np.interp(ty, tv, v) * yr, lw=1.0, label="speed x yaw rate (measured)")
    ax[2].set_ylabel("[m/s^2], left +")
    ax[2].legend(loc="lower right")
    for name, label in (("column_torque", "driver (STEER_TORQUE_DRIVER)"), ("assist_torque", "EPS motor")):
        tt, v = series(name)
        ax[3].plot(tt, v, lw=0.7, label=label)
    ax[3].set_ylabel("torque [counts]")
    ax[3].legend(loc="lower right")
    fw = np.where(valid, rows["Fw"], np.nan)
    ax[4].plot(t, fw * 1e-3, label="Fw")
    ax[4].plot(t, np.where(valid, rows["Fw_wind"], np.nan) * 1e-3, lw=0.8, label="wind part")
    ax[4].set_ylabel("[kN, counts as Nm]")
    ax[4].legend(loc="lower right")
    ax[5].plot(t, np.where(valid, rows["bank_deg"], np.nan), color="tab:brown")
    ax[5].set_ylabel("bank [deg]")
    ax[6].step(t, rows["learn_state"], where="post", label="learner state")
    ax[6].fill_between(
        t, 0, 3, where=valid, color="tab:green", alpha=0.2, step="post", label="estimate valid"
    )
    ax[6].set_yticks(range(4), LEARN_STATES)
    ax[6].set_ylim(-0.3, 3.3)
    ax[6].legend(loc="lower right")
    ax[6].set_xlabel("time [s]")
    fig.suptitle(f"Toyota RAV4 2017, 60 s of comma2k19 (lane-keeping engaged); lde replay, backend {backend}")
    fig.savefig(out, dpi=80)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", nargs="?", default=str(LOG), help="the RAV4 log (default: the test data's)")
    ap.add_argument("-o", "--out", default=str(REPO / "docs" / "img" / "rav4_drive.png"), help="the PNG")
    ap.add_argument("--backend", default="float", help="the estimator backend (default: float)")
    args = ap.parse_args(argv)
    log = Path(args.log)
    rows, learned = replay(log, args.backend)
    draw(log, rows, Path(args.out), args.backend)
    above = rows["speed"] >= load_vehicle(NAME).estimator.min_speed
    print(f"wrote {args.out}")
    share = np.mean(rows["valid"][above] == 1)
    print(f"valid: {share:.1%} of the {np.count_nonzero(above)} steps above the minimum speed")
    print(f"learner: {learned['state']} after {learned['seconds']:.1f} s of learning time")
    print("learned: " + ", ".join(f"{k} {v:.6g}" for k, v in learned["params"].items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
