"""Where the `fixed` backend's engine time goes: its kernels alone on a log's real inputs.

    python bench/bench_lateral_kernels.py LOG [--minutes 10] [--repeat 5]

Replays the first ``--minutes`` of LOG with the ``float`` backend to get every step's sampled inputs,
fresh flags and group validity, then times, per step (CPU, median of ``--repeat`` after a warm-up):
the boundary (``firmware_model.lateral.quantise_kernel``), the integer lateral step after it
(``step_kernel``), and the float lateral step (``lde.estimator.lateral.step_kernel``, the fixed backend's
shadow). The kernels run outside the data-path loop (no receiver, learner, overlay): what each costs,
not the loop's total.
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
from numba import njit

from firmware_model import lateral as FX
from firmware_model.tables import lateral_tables_for
from lde.can.profiles import load_profile
from lde.engine.engine import Engine
from lde.engine.receiver import (
    I_ASSIST_TORQUE,
    I_COLUMN_TORQUE,
    I_LAT_ACCEL,
    I_SPEED,
    I_STEERING_ANGLE,
    I_YAW_RATE,
)
from lde.estimator import lateral as E
from lde.io import read_log
from lde.params import load_vehicle
from lde.units import STEP_NS

FR = 1 << I_YAW_RATE
FT = (1 << I_COLUMN_TORQUE) | (1 << I_ASSIST_TORQUE)
FA = 1 << I_LAT_ACCEL


@njit(cache=True)
def _integer(p, tv, ft, t, inp, fresh, ok, step):  # pragma: no cover - compiled
    cs = np.zeros(FX.N_CS, np.int64)
    FX.coef_set_kernel(p, tv, cs)
    x, P = np.zeros(5, np.int64), np.zeros(25, np.int64)
    aux, sat = np.zeros(FX.N_AUX, np.int64), np.zeros(FX.N_SAT, np.int64)
    FX.reset_kernel(cs, x, P, aux, sat)
    ws, iout = np.zeros((4, 16), np.int64), np.zeros(FX.N_IO, np.int64)
    acc = 0
    for k in range(t.shape[0]):
        u = inp[k]
        v, s, y, c, a, q, fl = FX.quantise_kernel(
            tv,
            u[I_SPEED],
            u[I_STEERING_ANGLE],
            u[I_YAW_RATE],
            u[I_COLUMN_TORQUE],
            u[I_ASSIST_TORQUE],
            u[I_LAT_ACCEL],
        )
        if not step:
            acc += v + s + fl
            continue
        f = fresh[k]
        acc += FX.step_kernel(
            tv, ft, cs, x, P, aux, sat, ws, t[k], v, s, y, c, a, q, fl,
            (f & FR) != 0, (f & FT) == FT, (f & FA) != 0, ok[k, 0], ok[k, 1], iout,
        )  # fmt: skip
    return acc


@njit(cache=True)
def _float(p, t, inp, fresh, ok):  # pragma: no cover - compiled
    x, P = np.zeros(E.NX), np.zeros((E.NX, E.NX))
    fs, ints = np.zeros(E.N_F), np.zeros(E.N_I, np.int64)
    E.reset_kernel(p, x, P, fs, ints)
    h, ph, out = np.zeros(E.NX), np.zeros(E.NX), np.zeros(16)
    acc = 0
    for k in range(t.shape[0]):
        u, f = inp[k], fresh[k]
        acc += E.step_kernel(
            p, x, P, fs, ints, h, ph, t[k], u[I_SPEED], u[I_STEERING_ANGLE], u[I_YAW_RATE],
            u[I_COLUMN_TORQUE], u[I_ASSIST_TORQUE], u[I_LAT_ACCEL], (f & FR) != 0, (f & FT) == FT,
            (f & FA) != 0, ok[k, 0], ok[k, 1], out,
        )  # fmt: skip
    return acc


def measure(log: Path, minutes: float = 10.0, repeat: int = 5) -> dict:
    """ns per step (median, min, max of ``repeat`` after a warm-up, CPU) of the boundary, the boundary
    and the integer step, and the float step, over the first ``minutes`` of ``log``."""
    vehicle = load_vehicle("reference")
    frames = read_log(log).frames
    frames = frames.select(frames.t_ns < frames.t_ns[0] + int(minutes * 60e9))
    blk = Engine(load_profile("lde"), vehicle, "float", encode_outputs=False).feed(frames, final=True)
    t, inp, ok, ages = blk.t_ns, np.ascontiguousarray(blk.inputs), blk.ok.copy(), blk.ages
    prev = np.concatenate([[np.iinfo(np.int64).min], t[:-1]])
    fresh_bits = (ages >= 0) & ((t[:, None] - ages) > prev[:, None])  # as lde.engine.loop computes it
    fresh = (fresh_bits * (1 << np.arange(ages.shape[1]))).sum(axis=1).astype(np.int64)
    p = E.params_vector(vehicle, STEP_NS * 1e-9)
    tv, ft = FX.tables_vectors(lateral_tables_for(vehicle, STEP_NS))
    n = len(t)

    def per_step(fn) -> tuple[float, float, float]:
        fn()
        xs = []
        for _ in range(repeat):
            c = time.process_time()
            fn()
            xs.append((time.process_time() - c) / n * 1e9)
        return statistics.median(xs), min(xs), max(xs)

    return {
        "steps": n,
        "quantise_ns": per_step(lambda: _integer(p, tv, ft, t, inp, fresh, ok, False)),
        "integer_ns": per_step(lambda: _integer(p, tv, ft, t, inp, fresh, ok, True)),
        "float_ns": per_step(lambda: _float(p.copy(), t, inp, fresh, ok)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("log", type=Path)
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    r = measure(args.log, args.minutes, args.repeat)
    q, i, f = r["quantise_ns"], r["integer_ns"], r["float_ns"]
    head = f"{r['steps']} steps of {args.log} ({args.minutes:g} min)"
    print(f"{head}; ns per step, median (min-max) of {args.repeat}:")
    print(f"  boundary (quantise)          {q[0]:6.0f} ({q[1]:.0f}-{q[2]:.0f})")
    print(f"  boundary + integer step      {i[0]:6.0f} ({i[1]:.0f}-{i[2]:.0f})")
    print(f"  float step (the shadow)      {f[0]:6.0f} ({f[1]:.0f}-{f[2]:.0f})")


if __name__ == "__main__":
    main()
