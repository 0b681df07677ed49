"""Benchmark and accuracy report of the fixed-point firmware model (issue 5's closing note).

Measured, never invented. Three parts, all in one run:

1. The Q-format table (from the generated constants of the vehicle).
2. Per simulator scenario (``vcan_sim``, seed 0, the replay pipeline ``lde.replay.replay.replay`` with
   ``backend="paper-fixed"`` and ``"paper"``): worst |dFw| [N] and |dMw| [Nm] of fixed vs float at any
   step, and the same for the steady-state-gain alternative (float, ``firmware_model.float_ref``)
   vs the float filter, over all steps and after the first second.
3. Per-step cost of both backends on the same inputs: the scenario grids concatenated (time
   shifted to one monotonic clock) and repeated to at least ``--steps`` steps;
   - batch: ``run_batch`` over all steps, ``--repeat`` times after a warm-up; per-step cost =
     time / steps, median over the repeats;
   - live: ``step(t_ns, inputs)`` per call, each call timed with ``perf_counter_ns``, median over
     all steps (>= 100k);
   for the float filter (``lde.estimator.paper``), the fixed model without shadow and the fixed model with
   its float shadow (the default of ``--backend fixed``); plus the pure-Python reference on
   ``--ref-steps`` steps.

    python bench/bench_firmware.py                   # full report (about a minute)
    python bench/bench_firmware.py --steps 100000 --repeat 5 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from firmware_model.fast import FixedEstimator
from firmware_model.fast import run_batch as fixed_run_batch
from firmware_model.float_ref import run_batch_steady_state
from firmware_model.step import ReferenceEstimator
from firmware_model.tables import tables_for
from lde.estimator.paper import Estimator, EstimatorInputs
from lde.estimator.paper import run_batch as float_run_batch
from lde.params import load_vehicle
from lde.units import STEP_NS

FIELDS = (
    "t_ns",
    "speed",
    "steering_angle",
    "yaw_rate",
    "column_torque",
    "assist_torque",
    "mdps_ok",
    "esc_ok",
)


def qformat_rows(vehicle) -> list[tuple[str, str, str, str, str]]:
    """(variable, unit, Q format, LSB, range) of every stored variable and constant group."""
    from firmware_model.qformat import q32

    tb = tables_for(vehicle)
    rows = []
    names = ("beta", "r (yaw rate)", "Fw", "Mw")
    units = ("rad", "rad/s", "N", "Nm")
    for i, e in enumerate(tb.sigma_exp):
        q = q32(tb.f_state - e)
        rows.append(
            (
                f"state {names[i]} (X = x / 2^{e}, Q15.16)",
                units[i],
                str(q),
                f"{q.lsb:.3g}",
                f"+-{q.real_max:.4g}",
            )
        )
    qt = q32(tb.f_state - tb.sigma_t_exp)
    rows.append(
        (
            f"T_align measurement / output (/ 2^{tb.sigma_t_exp})",
            "Nm",
            str(qt),
            f"{qt.lsb:.3g}",
            f"+-{qt.real_max:.4g}",
        )
    )
    qy = q32(tb.yaw_input_frac())
    rows.append(
        ("yaw-rate input (= state r's format)", "rad/s", str(qy), f"{qy.lsb:.3g}", f"+-{qy.real_max:.4g}")
    )
    for label, unit, f in (
        ("speed input", "m/s", tb.f_speed),
        ("steering-wheel angle input", "rad", tb.f_steer),
        ("column / assist torque input", "Nm", tb.f_torque),
        ("w = 1/vx", "s/m", tb.f_w),
    ):
        q = q32(f)
        rows.append((label, unit, str(q), f"{q.lsb:.3g}", f"+-{q.real_max:.4g}"))
    q = q32(tb.f_cov)
    rows.append(("covariance Pn_ij = P_ij / (s_i s_j)", "-", str(q), f"{q.lsb:.3g}", f"+-{q.real_max:.4g}"))
    q = q32(tb.f_gain)
    rows.append(("Kalman gain (normalised)", "-", str(q), f"{q.lsb:.3g}", f"+-{q.real_max:.4g}"))
    for label, f in (
        ("Phi_n coefficients", tb.f_phi),
        ("E_n (per rad steering wheel)", tb.f_e),
        ("H_n aligning-torque row", tb.f_h),
        ("D_n (per rad steering wheel)", tb.f_d),
    ):
        q = q32(f)
        rows.append((label, "-", str(q), f"{q.lsb:.3g}", f"+-{q.real_max:.4g}"))
    rows.append(("innovations, ph = Pn h^T, T = Phi_n Pn", "-", "Q15.16", f"{2**-16:.3g}", "+-32768"))
    rows.append(("accumulators (sums of int32 x int32 products)", "-", "int64", "-", "saturating"))
    return rows


def scenario_grids(vehicle, names):
    from lde.can.profiles import load_profile
    from lde.replay.replay import replay
    from vcan_sim.run import simulate

    profile = load_profile("lde")
    out = []
    for name in names:
        sim = simulate(name, vehicle, "lde", seed=0)
        fx = replay(sim.frames, profile, vehicle, "paper-fixed")
        fl = replay(sim.frames, profile, vehicle, "paper")
        out.append((name, fx, fl))
    return out


def accuracy_rows(vehicle, runs):
    rows = []
    n1 = int(round(1.0e9 / STEP_NS))
    for name, fx, fl in runs:
        g = fl.grid
        ss = run_batch_steady_state(*(getattr(g, f) for f in FIELDS), vehicle)
        dfw, dmw = np.abs(fx.fw - fl.fw), np.abs(fx.mw - fl.mw)
        sfw, smw = np.abs(ss.fw - fl.fw), np.abs(ss.mw - fl.mw)
        rows.append(
            dict(
                scenario=name,
                steps=len(fx),
                fixed_dfw_max=float(dfw.max()),
                fixed_dmw_max=float(dmw.max()),
                fixed_dfw_rms=float(np.sqrt(np.mean(dfw**2))),
                shadow_flags=int(np.count_nonzero(fx.status & 64)),
                ss_dfw_max=float(sfw.max()),
                ss_dmw_max=float(smw.max()),
                ss_dfw_max_after_1s=float(sfw[n1:].max()),
                ss_dmw_max_after_1s=float(smw[n1:].max()),
                ss_steps_over_bound=int(np.count_nonzero((sfw > 5.0) | (smw > 2.0))),
            )
        )
    return rows


def concat_inputs(runs, min_steps: int) -> dict[str, np.ndarray]:
    parts: dict[str, list[np.ndarray]] = {f: [] for f in FIELDS}
    total, t_next = 0, 1_700_000_000_000_000_000
    while total < min_steps:
        for _, _, fl in runs:
            g = fl.grid
            for f in FIELDS[1:]:
                parts[f].append(np.asarray(getattr(g, f)))
            n = len(g)
            parts["t_ns"].append(t_next + np.arange(n, dtype=np.int64) * STEP_NS)
            t_next += n * STEP_NS
            total += n
    return {f: np.concatenate(v) for f, v in parts.items()}


def bench_batch(vehicle, inp, repeat: int) -> dict[str, dict]:
    n = len(inp["t_ns"])
    cases = {
        "float (lde.estimator.paper.run_batch)": lambda: float_run_batch(*(inp[f] for f in FIELDS), vehicle),
        "fixed, no shadow": lambda: fixed_run_batch(*(inp[f] for f in FIELDS), vehicle, shadow=False),
        "fixed + float shadow (default)": lambda: fixed_run_batch(*(inp[f] for f in FIELDS), vehicle),
    }
    out = {}
    for name, fn in cases.items():
        fn()  # warm-up (numba compile or cache load)
        ts = []
        for _ in range(repeat):
            t0 = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t0)
        per = [t / n * 1e9 for t in ts]
        out[name] = dict(
            steps=n,
            ns_per_step_median=statistics.median(per),
            ns_per_step_min=min(per),
            ns_per_step_max=max(per),
            hour_s=statistics.median(per) * 923_077 * 1e-9,
        )
    return out


def bench_live(vehicle, inp, ref_steps: int) -> dict[str, dict]:
    n = len(inp["t_ns"])
    rows = [
        EstimatorInputs(
            float(inp["speed"][k]),
            float(inp["steering_angle"][k]),
            float(inp["yaw_rate"][k]),
            float(inp["column_torque"][k]),
            float(inp["assist_torque"][k]),
            bool(inp["mdps_ok"][k]),
            bool(inp["esc_ok"][k]),
        )
        for k in range(n)
    ]
    t = [int(x) for x in inp["t_ns"]]
    cases = {
        "float (lde.estimator.paper.Estimator.step)": (Estimator(vehicle), n),
        "fixed, no shadow (FixedEstimator.step)": (FixedEstimator(vehicle, shadow=False), n),
        "fixed + float shadow (default)": (FixedEstimator(vehicle), n),
        "pure-Python integer reference": (ReferenceEstimator(vehicle), min(ref_steps, n)),
    }
    out = {}
    for name, (est, m) in cases.items():
        for k in range(50):  # warm-up
            est.step(t[k], rows[k])
        est.reset()
        dts = np.empty(m, dtype=np.int64)
        pc = time.perf_counter_ns
        for k in range(m):
            t0 = pc()
            est.step(t[k], rows[k])
            dts[k] = pc() - t0
        out[name] = dict(
            steps=m,
            ns_median=float(np.median(dts)),
            ns_p90=float(np.percentile(dts, 90)),
            ns_p99=float(np.percentile(dts, 99)),
        )
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    ap.add_argument("--vehicle", default="reference")
    ap.add_argument("--steps", type=int, default=100_000, help="at least this many steps for the cost")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--ref-steps", type=int, default=10_000, help="steps for the pure-Python reference")
    ap.add_argument("--json", default=None)
    args = ap.parse_args(argv)
    vehicle = load_vehicle(args.vehicle)
    from vcan_sim.scenarios import scenario_list

    names = [n for n, _ in scenario_list()]
    report: dict = dict(
        machine=dict(
            python=platform.python_version(),
            cpu=platform.processor() or platform.machine(),
            cpus=os.cpu_count(),
        )
    )
    print("Q formats (int32 storage; signed QI.F: I integer bits, F fractional bits)")
    for row in qformat_rows(vehicle):
        print(f"  {row[0]:55s} {row[1]:6s} {row[2]:8s} lsb {row[3]:>9s}  range {row[4]}")
    print("\nscenarios (seed 0): fixed vs float, and steady-state gains (float) vs float")
    t0 = time.perf_counter()
    runs = scenario_grids(vehicle, names)
    acc = accuracy_rows(vehicle, runs)
    report["accuracy"] = acc
    print(
        f"  {'scenario':16s} {'steps':>6s} {'fix dFw N':>10s} {'fix dMw Nm':>10s} {'shadow':>6s} "
        f"{'ss dFw N':>9s} {'ss dMw Nm':>9s} {'ss dFw>1s':>9s} {'ss dMw>1s':>9s} {'ss over':>7s}"
    )
    for r in acc:
        print(
            f"  {r['scenario']:16s} {r['steps']:6d} {r['fixed_dfw_max']:10.3f} "
            f"{r['fixed_dmw_max']:10.3f} "
            f"{r['shadow_flags']:6d} {r['ss_dfw_max']:9.1f} {r['ss_dmw_max']:9.1f} "
            f"{r['ss_dfw_max_after_1s']:9.2f} {r['ss_dmw_max_after_1s']:9.2f} "
            f"{r['ss_steps_over_bound']:7d}"
        )
    print(f"  (simulation + replays {time.perf_counter() - t0:.1f} s)")
    inp = concat_inputs(runs, args.steps)
    print(f"\nper-step cost, {len(inp['t_ns'])} steps (scenario grids concatenated), same run")
    batch = bench_batch(vehicle, inp, args.repeat)
    report["batch"] = batch
    for name, r in batch.items():
        print(
            f"  batch {name:34s} median {r['ns_per_step_median']:7.0f} ns/step "
            f"(min {r['ns_per_step_min']:.0f}, max {r['ns_per_step_max']:.0f}); "
            f"one hour of steps {r['hour_s']:.2f} s"
        )
    live = bench_live(vehicle, inp, args.ref_steps)
    report["live"] = live
    for name, r in live.items():
        print(
            f"  live  {name:40s} median {r['ns_median']:8.0f} ns/call  p90 {r['ns_p90']:.0f}  "
            f"p99 {r['ns_p99']:.0f}  ({r['steps']} steps)"
        )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=1)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
