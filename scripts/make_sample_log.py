#!/usr/bin/env python3
"""Generate the sample drive ``tests/data/sample_linear.{log,mcap}`` + ``sample_linear_truth.csv``.

A 20 s straight drive at 100 km/h on the LINEAR 2-DOF bicycle model (written here from the paper's
eqs. (7)-(9), (12) with the SPEC's errata, independently of :mod:`lde.estimator.model`), simulated with
scipy's
exact (zero-order-hold) discretisation on a 0.1 ms grid. From t = 5 s a constant lateral
disturbance acts: Fw = 800 N, Mw = -300 Nm (left positive). The driver holds a small sinusoidal
steering input; sensors add seeded white noise, then the DBC quantises. Frames are encoded with
:func:`lde.can.codec.encode_batch` (E2E Profile 1 counters and CRCs) at their periods (MDPS 3.9 ms,
ESC 10 ms) with up to 100 us of transmit jitter, timestamps in epoch microseconds.

Model, state x = [beta, r] (side slip [rad], yaw rate [rad/s]), ISO 8855 (left positive)::

    alpha_f = delta_f - beta - lf r / vx            (eq. 9, front slip angle)
    alpha_r =         - beta + lr r / vx            (eq. 9, rear slip angle)
    m vx (beta_dot + r) = 2 Cf alpha_f + 2 Cr alpha_r + Fw        (eq. 7)
    Iz r_dot            = 2 lf Cf alpha_f - 2 lr Cr alpha_r + Mw  (eq. 8)
    T_align = 2 K alpha_f = N (T_column + T_assist)               (eqs. 11-12, paper sign)
    a_y = vx (beta_dot + r)                                        (lateral acceleration)

The column torque is split with a constant boost: T_assist = BOOST * T_column.

The plant's parameters (paper Table 2; N = 15; Cf = 62000, Cr = 56000 N/rad per tire, K = 7200
Nm/rad: the reference vehicle's values when the sample was made) are fixed here, independent of
later changes to the shipped vehicle files, and written next to the log as
``sample_linear_vehicle.toml`` (estimator tuning and overlay limits from ``reference``), so that a
replay with ``--vehicle tests/data/sample_linear_vehicle.toml`` runs the estimator on the plant's
own parameters: what remains is the estimator's own error (Euler vs exact discretisation, noise,
quantisation, multi-rate sampling).

Usage: ``python scripts/make_sample_log.py [--out-dir tests/data] [--seed 1] [--duration 20]``.
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np
from scipy import signal

from lde.can.codec import encode_batch, si_to_dbc
from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.io import McapWriter, write_candump
from lde.params import load_vehicle
from lde.units import DEG, KMH, STEP_NS

T0_NS = 1_700_000_000_000_000_000  # log start, epoch ns (2023-11-14 22:13:20 UTC)
SIM_DT_NS = 100_000  # simulation grid [ns]: 0.1 ms divides both frame periods
ESC_PERIOD_NS = 10_000_000
SPEED = 100.0 * KMH  # m/s
FW_TRUE = 800.0  # N, from T_STEP
MW_TRUE = -300.0  # Nm, from T_STEP
T_STEP = 5.0  # s
BOOST = 3.0  # T_assist / T_column
# sensor noise standard deviations (SI), before DBC quantisation
NOISE = {
    "yaw_rate": 0.03 * DEG,  # rad/s
    "column_torque": 0.01,  # Nm
    "assist_torque": 0.02,  # Nm
    "steering_angle": 0.05 * DEG,  # rad
    "lat_accel": 0.05,  # m/s^2
    "speed": 0.05 * KMH,  # m/s
}
JITTER_US = 100  # transmit delay, uniform 0..JITTER_US [us]


def bicycle_ss(vehicle, vx: float) -> signal.StateSpace:
    """Continuous state space, x = [beta, r], u = [delta_f, Fw, Mw], y = [r, alpha_f, a_y]."""
    b = vehicle.body
    m, iz, lf, lr = b.mass, b.yaw_inertia, b.lf, b.lr
    cf, cr = vehicle.tires.cf, vehicle.tires.cr
    # beta_dot = (2Cf alpha_f + 2Cr alpha_r + Fw)/(m vx) - r, with the alphas above
    a = np.array(
        [
            [-2 * (cf + cr) / (m * vx), -1 - 2 * (lf * cf - lr * cr) / (m * vx**2)],
            [-2 * (lf * cf - lr * cr) / iz, -2 * (lf**2 * cf + lr**2 * cr) / (iz * vx)],
        ]
    )
    bm = np.array(
        [
            [2 * cf / (m * vx), 1 / (m * vx), 0.0],
            [2 * lf * cf / iz, 0.0, 1 / iz],
        ]
    )
    # r; alpha_f = delta_f - beta - lf r / vx; a_y = vx (beta_dot + r) = vx (A[0] x + B[0] u) + vx r
    c = np.vstack([[0.0, 1.0], [-1.0, -lf / vx], vx * a[0] + np.array([0.0, vx])])
    d = np.vstack([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], vx * bm[0]])
    return signal.StateSpace(a, bm, c, d)


def simulate(vehicle, duration_s: float, seed: int) -> dict[str, np.ndarray]:
    """Truth on the 0.1 ms grid: time [ns from start], inputs, states and outputs (SI)."""
    n = int(round(duration_s * 1e9 / SIM_DT_NS)) + 1
    t_ns = np.arange(n, dtype=np.int64) * SIM_DT_NS
    t = t_ns * 1e-9
    ratio = vehicle.steering.ratio
    # small steering: two sines at the steering wheel (rad), and its rate
    delta_sw = 1.5 * DEG * np.sin(2 * np.pi * 0.4 * t) + 0.8 * DEG * np.sin(2 * np.pi * 1.1 * t + 0.7)
    delta_sw_rate = 1.5 * DEG * 2 * np.pi * 0.4 * np.cos(
        2 * np.pi * 0.4 * t
    ) + 0.8 * DEG * 2 * np.pi * 1.1 * np.cos(2 * np.pi * 1.1 * t + 0.7)
    on = t >= T_STEP
    fw = np.where(on, FW_TRUE, 0.0)
    mw = np.where(on, MW_TRUE, 0.0)
    u = np.column_stack([delta_sw / ratio, fw, mw])
    dss = bicycle_ss(vehicle, SPEED).to_discrete(SIM_DT_NS * 1e-9, method="zoh")
    _, y, x = signal.dlsim(dss, u)
    t_align = 2 * vehicle.tires.align_rate * y[:, 1]
    return {
        "t_ns": t_ns,
        "steering_angle": delta_sw,
        "steering_rate": delta_sw_rate,
        "Fw": fw,
        "Mw": mw,
        "beta": x[:, 0],
        "yaw_rate": y[:, 0],
        "T_align": t_align,
        "lat_accel": y[:, 2],
        "column_torque": t_align / ratio / (1 + BOOST),
        "assist_torque": t_align / ratio * BOOST / (1 + BOOST),
        "speed": np.full(n, SPEED),
    }


def encode_frames(truth: dict[str, np.ndarray], rng: np.random.Generator) -> FrameBatch:
    """MDPS_Sensors every 3.9 ms and ESC_Motion every 10 ms, sampled from the truth grid with noise."""
    profile = load_profile("lde")
    batches = []
    duration_ns = int(truth["t_ns"][-1])
    for message, period, offset in (("MDPS_Sensors", STEP_NS, 0), ("ESC_Motion", ESC_PERIOD_NS, 2_000_000)):
        t_nom = np.arange(offset, duration_ns + 1, period, dtype=np.int64)
        idx = t_nom // SIM_DT_NS
        names = profile.spec(message).inputs
        si = {}
        for name in names:
            v = truth[name][idx]
            if name in NOISE:
                v = v + rng.normal(0.0, NOISE[name], v.shape)
            si[name] = v
        data = encode_batch(profile, message, si_to_dbc(profile, message, si))
        jitter_ns = rng.integers(0, JITTER_US + 1, t_nom.size) * 1000
        n = t_nom.size
        batches.append(
            FrameBatch(
                t_ns=T0_NS + t_nom + jitter_ns,
                can_id=np.full(n, profile.spec(message).frame_id),
                is_extended=np.zeros(n, bool),
                dlc=np.full(n, profile.spec(message).length),
                data=data,
                is_rx=np.ones(n, bool),
            )
        )
    return FrameBatch.concat(batches)


#: the plant: a vehicle TOML (lde.params schema) written with the sample and loaded to simulate
PLANT_TOML = """\
# Plant of the linear-model sample drive (written by scripts/make_sample_log.py; do not edit).
# Replay tests/data/sample_linear.log with --vehicle tests/data/sample_linear_vehicle.toml.
# Body, steering and tires are the simulated plant's; tuning and overlay limits: the reference.
extends = "reference"
name = "sample_linear"
description = "linear-model sample plant: paper Table 2 body, N = 15, Cf 62000, Cr 56000, K 7200"

[vehicle]
mass_kg = 1466.0
yaw_inertia_kgm2 = 2744.0
lf_m = 1.071
lr_m = 1.724
track_front_m = 1.587
track_rear_m = 1.587

[steering]
ratio = 15.0

[tires]
cf_N_per_rad = 62000.0
cr_N_per_rad = 56000.0
align_rate_Nm_per_rad = 7200.0
"""

TRUTH_COLUMNS = ("t", "Fw", "Mw", "beta", "yaw_rate", "T_align", "steering_angle", "speed")


def write_truth_csv(path: Path, truth: dict[str, np.ndarray], every_ns: int = ESC_PERIOD_NS) -> None:
    """Truth every ``every_ns`` with ``t`` in seconds in the log's time base (SI units, ISO signs)."""
    idx = np.arange(0, truth["t_ns"].size, every_ns // SIM_DT_NS)
    t_abs = T0_NS + truth["t_ns"][idx]
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(TRUTH_COLUMNS)
        for k, i in enumerate(idx.tolist()):
            s, ns = divmod(int(t_abs[k]), 1_000_000_000)
            w.writerow(
                [f"{s}.{ns // 1000:06d}"]
                + [
                    f"{truth[c][i]:.9g}"
                    for c in ("Fw", "Mw", "beta", "yaw_rate", "T_align", "steering_angle", "speed")
                ]
            )


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out-dir", type=Path, default=Path(__file__).resolve().parents[1] / "tests" / "data")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--duration", type=float, default=20.0, help="seconds")
    ap.add_argument("--name", default="sample_linear")
    args = ap.parse_args(argv)
    out = args.out_dir
    out.mkdir(parents=True, exist_ok=True)
    vehicle_path = out / f"{args.name}_vehicle.toml"
    vehicle_path.write_text(PLANT_TOML)
    vehicle = load_vehicle(vehicle_path)
    rng = np.random.default_rng(args.seed)
    truth = simulate(vehicle, args.duration, args.seed)
    frames = encode_frames(truth, rng)
    write_candump(out / f"{args.name}.log", frames, channel="vcan0")
    write_truth_csv(out / f"{args.name}_truth.csv", truth)
    with McapWriter(out / f"{args.name}.mcap") as w:
        w.write_frames(frames)
        ch = w.add_json_channel(
            "/sim/truth",
            {
                "Fw": {"type": "number", "description": "true disturbance force [N], left positive"},
                "Mw": {"type": "number", "description": "true disturbance yaw moment [Nm], left positive"},
                "beta": {"type": "number", "description": "side slip [rad]"},
                "yaw_rate": {"type": "number", "description": "yaw rate [rad/s]"},
                "T_align": {"type": "number", "description": "aligning torque [Nm], paper sign"},
            },
        )
        idx = np.arange(0, truth["t_ns"].size, ESC_PERIOD_NS // SIM_DT_NS)
        w.write_json_columns(
            ch,
            T0_NS + truth["t_ns"][idx],
            {k: truth[k][idx] for k in ("Fw", "Mw", "beta", "yaw_rate", "T_align")},
        )
    sizes = {p.name: p.stat().st_size for p in sorted(out.glob(f"{args.name}*"))}
    print(
        f"{len(frames)} frames, {args.duration:g} s -> "
        + ", ".join(f"{k} {v / 1e3:.0f} kB" for k, v in sizes.items())
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
