"""Identify the overlay loop's return ratio (docs/design/overlay.md, "Why the law is band-limited").

The loop is estimator -> law -> MDPS -> steering -> the estimator's inputs. It is opened at the
overlay: the simulator runs a scenario with a scripted overlay (a mean plus a multisine), the log
is replayed through a backend, and at each excited frequency

    H(f) = (demand_hat - demand_true)(f) / T_overlay(f)

with ``demand = -K (lr Fw + Mw) / (N Cf L)`` (the law before its low-pass; ``demand_true`` from the
simulator's true Fw, Mw). The closed loop returns T_ov = L T_ov with
``L = H LP(tau) exp(-j w 3.9 ms)``: positive feedback, unstable where L reaches +1. The script
prints |H|, its phase, and per law time constant the largest |L| and the smallest distance |1 - L|
(the modulus margin). Also printed: the column torque the aligning torque does not balance
(``T_col + T_ast - T_align / N``, the simulator's truth) per Nm of overlay.

    PYTHONPATH=src:. python scripts/overlay_loop.py --backend fixed [--scenario light_load] [--seed 2]
"""

from __future__ import annotations

import argparse

import numpy as np

from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.estimator.overlay import feedforward_gain
from lde.params import load_vehicle
from lde.replay.replay import replay
from lde.units import STEP_S
from vcan_sim.run import Simulation

FREQS = np.array([0.25, 0.5, 0.75, 1.0, 1.25, 1.5, 1.75, 2.0, 2.25, 2.5, 3.0, 3.5, 4.0, 5.0, 6.0, 8.0])
TAUS = (0.0, 0.1, 0.2, 0.3, 0.5)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--backend", default="fixed")
    ap.add_argument("--scenario", default="light_load")
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--mean", type=float, default=1.0, help="mean overlay [Nm]")
    ap.add_argument("--amp", type=float, default=0.06, help="amplitude of each sine [Nm]")
    a = ap.parse_args()
    veh, prof = load_vehicle("reference"), load_profile("lde")
    sim = Simulation(a.scenario, veh, prof, seed=a.seed, duration=44.0)
    phase = np.random.default_rng(0).uniform(0.0, 2.0 * np.pi, FREQS.size)
    frames, k = [], 0
    while not sim.done:
        t = k * STEP_S
        ramp = min(1.0, t / 2.0)
        frames.append(sim.step(ramp * (a.mean + a.amp * np.sum(np.sin(2 * np.pi * FREQS * t + phase)))))
        k += 1
    truth, tt = sim.truth()
    res = replay(FrameBatch.concat(frames, sort=True), prof, veh, a.backend)
    t = (res.t_ns - sim.t0_ns) * 1e-9
    ttr = (tt - sim.t0_ns) * 1e-9

    def at(col: np.ndarray) -> np.ndarray:
        return np.interp(t, ttr, col)

    g, lr, n = feedforward_gain(veh), veh.body.lr, veh.steering.ratio
    err = -g * (lr * res.fw + res.mw) + g * (lr * at(truth["Fw"]) + at(truth["Mw"]))
    tov = at(truth["T_overlay"])
    unbalanced = at(truth["T_column"] + truth["T_assist"] - truth["T_align"] / n)
    m = (t >= 4.0) & (t < 44.0)  # 40 s: every frequency an integer number of periods

    def tf(y: np.ndarray) -> np.ndarray:
        e = np.exp(-2j * np.pi * np.outer(FREQS, t[m]))
        return (e @ y[m]) / (e @ tov[m])

    h, u = tf(err), tf(unbalanced)
    print(f"backend {a.backend}, scenario {a.scenario}, seed {a.seed}")
    print("   f [Hz]   |H|  phase [deg]   unbalanced column torque per Nm of overlay")
    for f, hv, uv in zip(FREQS, h, u, strict=True):
        print(f"  {f:6.2f} {abs(hv):6.2f} {np.degrees(np.angle(hv)):8.0f}      {abs(uv):.2f}")
    for tau in TAUS:
        loop = h / (1.0 + 2j * np.pi * FREQS * tau) * np.exp(-2j * np.pi * FREQS * STEP_S)
        big, margin = np.abs(loop).max(), np.abs(1 - loop).min()
        print(f"  law tau {tau:.1f} s: max |L| {big:.2f}, min |1 - L| {margin:.2f}")


if __name__ == "__main__":
    main()
