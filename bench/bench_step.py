"""Benchmark of the float estimator step: ``run_batch`` throughput and ``Estimator.step`` per call.

Measured, not invented: one hour of steps on the 3.9 ms grid (923,077 steps) of synthetic inputs
(100 km/h with speed changes every step so the model is re-scheduled each time, steering sines,
noisy yaw rate and torques, a few MDPS/ESC faults and a low-speed stretch so every branch runs)
through :func:`lde.estimator.paper.run_batch`, ``--repeat`` times after one warm-up (numba compilation or
cache load). Then ``--calls`` single :meth:`lde.estimator.paper.Estimator.step` calls, each timed with
``perf_counter_ns``, ``--repeat`` times. Prints medians with min/max (batch) and p10/p50/p90/p99
(per call), and the CPU time of the batch runs (``process_time``: on a shared machine the wall
time also counts waiting for a core; see the load average). Target (task brief): an hour of
steps in well under 1 s.

    python bench/bench_step.py                      # 1 hour, 7 repeats, 20000 live calls
    python bench/bench_step.py --hours 0.1 --repeat 3 --json out.json
    python bench/bench_step.py --tuning             # the docs/design/model.md table (no timing)
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time

import numpy as np

from lde.estimator import kalman, model
from lde.estimator.paper import Estimator, EstimatorInputs, run_batch
from lde.params import load_vehicle
from lde.units import DEG, KMH, STEP_NS, STEP_S

T0 = 1_700_000_000_000_000_000  # ns


def make_inputs(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    ts = np.arange(n) * STEP_S
    speed = 100.0 * KMH + 5.0 * np.sin(2 * np.pi * ts / 60.0) + rng.normal(0.0, 0.01, n)
    speed[n // 3 : n // 3 + 2000] = 20.0 * KMH  # a low-speed stretch
    mdps_ok = np.ones(n, dtype=bool)
    esc_ok = np.ones(n, dtype=bool)
    mdps_ok[rng.integers(0, n, max(1, n // 10000))] = False
    esc_ok[rng.integers(0, n, max(1, n // 10000))] = False
    return dict(
        t_ns=T0 + np.arange(n, dtype=np.int64) * STEP_NS,
        speed=speed,
        steering_angle=20.0 * DEG * np.sin(2 * np.pi * 0.2 * ts),
        yaw_rate=rng.normal(0.0, 0.002, n),
        column_torque=rng.normal(0.5, 0.2, n),
        assist_torque=rng.normal(2.0, 0.5, n),
        mdps_ok=mdps_ok,
        esc_ok=esc_ok,
    )


def bench_batch(vehicle, inputs, repeat: int) -> dict:
    t0 = time.perf_counter()
    run_batch(vehicle=vehicle, **{k: v[:100] for k, v in inputs.items()})
    warm = time.perf_counter() - t0
    n = len(inputs["t_ns"])
    times, cpu = [], []
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        run_batch(vehicle=vehicle, **inputs)
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    med = statistics.median(times)
    return {
        "cpu_median_s": statistics.median(cpu),
        "cpu_min_s": min(cpu),
        "steps": n,
        "warmup_s": warm,
        "median_s": med,
        "min_s": min(times),
        "max_s": max(times),
        "steps_per_s": n / med,
        "ns_per_step": 1e9 * med / n,
    }


def bench_live(vehicle, inputs, calls: int, repeat: int) -> dict:
    keys = ("speed", "steering_angle", "yaw_rate", "column_torque", "assist_torque", "mdps_ok", "esc_ok")
    rows = [EstimatorInputs(*(inputs[k][i].item() for k in keys)) for i in range(calls)]
    t_ns = [int(t) for t in inputs["t_ns"][:calls]]
    est = Estimator(vehicle)
    est.step(t_ns[0], rows[0])  # warm-up
    per_call = []
    medians = []
    for _ in range(repeat):
        est.reset()
        d = np.empty(calls, dtype=np.int64)
        for i in range(calls):
            a = time.perf_counter_ns()
            est.step(t_ns[i], rows[i])
            d[i] = time.perf_counter_ns() - a
        medians.append(float(np.median(d)))
        per_call.append(d)
    allc = np.concatenate(per_call) / 1e3
    return {
        "calls": calls,
        "repeats": repeat,
        "median_us": float(np.median(allc)),
        "p10_us": float(np.percentile(allc, 10)),
        "p90_us": float(np.percentile(allc, 90)),
        "p99_us": float(np.percentile(allc, 99)),
        "median_of_repeats_us": [m / 1e3 for m in medians],
    }


def settling_time(vehicle, vx: float, fw: float, mw: float, level: float) -> float:
    """Time [s] after a step of (fw, mw) until the estimate stays within (1 - level) of it.

    Noise-free straight driving (delta_f = 0) from the Euler model, the estimator converged on
    zero disturbance for 3 s first; the measured T_align goes in as column torque.
    """
    d = model.discrete_matrices(vehicle, vx)
    n0 = n1 = round(3.0 / STEP_S)
    n = n0 + n1
    x = np.zeros(4)
    z = np.empty((n, 2))
    for k in range(n):
        if k == n0:
            x[2], x[3] = fw, mw
        z[k] = d.H @ x
        x = d.Phi @ x
    ones = np.ones(n, dtype=bool)
    res = run_batch(
        np.arange(n, dtype=np.int64) * STEP_NS,
        np.full(n, vx),
        np.zeros(n),
        z[:, 0],
        z[:, 1] / vehicle.steering.ratio,
        np.zeros(n),
        ones,
        ones,
        vehicle,
    )
    est, truth = (res.fw, fw) if fw else (res.mw, mw)
    late = np.flatnonzero(np.abs(est[n0:] - truth) > (1.0 - level) * abs(truth))
    return float((late[-1] + 1) * STEP_S) if late.size else 0.0


def tuning_table(vehicle, speeds_kmh=(60.0, 100.0, 160.0)) -> str:
    """Markdown table: steady-state Kalman gain, closed-loop time constants (eigenvalues of
    (I - Kg H) Phi), a-posteriori std and measured step settling times per speed."""
    lines = [
        "| speed [km/h] | tau [s], slowest first | Kg Fw row [N/(rad/s), N/Nm] | Kg Mw row [Nm/(rad/s), -] "
        "| std Fw [N] | std Mw [Nm] | 1000 N step 95 % / 98 % [s] | 500 Nm step 95 % [s] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kmh in speeds_kmh:
        vx = kmh * KMH
        d = model.discrete_matrices(vehicle, vx)
        kg, p_post = kalman.steady_state_gain(d.Phi, d.H, d.Qd, d.R)
        tau = kalman.closed_loop_time_constants(d.Phi, d.H, kg, STEP_S)
        f95 = settling_time(vehicle, vx, 1000.0, 0.0, 0.95)
        f98 = settling_time(vehicle, vx, 1000.0, 0.0, 0.98)
        m95 = settling_time(vehicle, vx, 0.0, 500.0, 0.95)
        lines.append(
            f"| {kmh:g} | {', '.join(f'{t:.3f}' for t in tau)} | {kg[2, 0]:.3g}, {kg[2, 1]:.3g} "
            f"| {kg[3, 0]:.3g}, {kg[3, 1]:.3g} | {np.sqrt(p_post[2, 2]):.0f} | {np.sqrt(p_post[3, 3]):.0f} "
            f"| {f95:.2f} / {f98:.2f} | {m95:.2f} |"
        )
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--hours", type=float, default=1.0, help="hours of 3.9 ms steps (default 1)")
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--calls", type=int, default=20000, help="live Estimator.step calls per repeat")
    ap.add_argument("--vehicle", default="reference")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="also write the results to this JSON file")
    ap.add_argument("--tuning", action="store_true", help="print the docs/design/model.md table and stop")
    args = ap.parse_args()

    vehicle = load_vehicle(args.vehicle)
    if args.tuning:
        print(tuning_table(vehicle))
        return 0
    n = round(args.hours * 3600.0 / STEP_S)
    inputs = make_inputs(n, args.seed)
    batch = bench_batch(vehicle, inputs, args.repeat)
    live = bench_live(vehicle, inputs, min(args.calls, n), args.repeat)
    cpu = platform.processor() or platform.machine()
    print(f"machine: {cpu}, {os.cpu_count()} cpus, python {platform.python_version()}")
    print(
        f"run_batch: {batch['steps']} steps ({args.hours:g} h) median {batch['median_s'] * 1e3:.1f} ms "
        f"(min {batch['min_s'] * 1e3:.1f}, max {batch['max_s'] * 1e3:.1f}; {args.repeat} repeats), "
        f"{batch['steps_per_s'] / 1e6:.2f} M steps/s, {batch['ns_per_step']:.0f} ns/step "
        f"(warm-up {batch['warmup_s']:.2f} s)"
    )
    print(
        f"run_batch CPU time (process_time; robust on a shared machine): median "
        f"{batch['cpu_median_s'] * 1e3:.1f} ms, min {batch['cpu_min_s'] * 1e3:.1f} ms"
    )
    print(
        f"Estimator.step: median {live['median_us']:.2f} us/call (p10 {live['p10_us']:.2f}, "
        f"p90 {live['p90_us']:.2f}, p99 {live['p99_us']:.2f}; {live['calls']} calls x {live['repeats']}), "
        f"medians of repeats {', '.join(f'{m:.2f}' for m in live['median_of_repeats_us'])} us"
    )
    if args.json:
        with open(args.json, "w") as fh:
            json.dump({"run_batch": batch, "estimator_step": live, "hours": args.hours}, fh, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
