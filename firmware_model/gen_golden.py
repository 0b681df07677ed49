"""Generate golden vectors for the integer step: ``python -m firmware_model.gen_golden``.

``golden_vectors.json`` holds the constants used (a full tables dict, so the vectors do not go
stale when the tuning changes), a sequence of SI inputs (floats as ``float.hex``, exact) covering
start-up, a gust, faults, non-finite and out-of-range inputs, a hold below min speed and resume,
speed above the model maximum, and the bit-exact expected outputs of the pure-Python reference
(status, X_beta, X_r, X_Fw, X_Mw, T_align_hat, raw) and its final state and saturation counters.
``tests/test_firmware_golden.py`` replays them on the reference and on the numba twin.

Regenerate only when the integer algorithm is changed on purpose (then say so in the commit).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from lde.estimator.paper import EstimatorInputs
from lde.params import load_vehicle
from lde.units import DEG, KMH, STEP_NS

from . import gen_tables as gen
from .step import ReferenceEstimator
from .tables import FixedTables

GOLDEN_PATH = Path(__file__).resolve().parent / "golden_vectors.json"


def golden_inputs(seed: int = 20261121) -> list[tuple[int, EstimatorInputs]]:
    """The input sequence (deterministic)."""
    rng = np.random.default_rng(seed)
    seq: list[tuple[int, EstimatorInputs]] = []
    t0 = 1_700_000_000_000_000_000

    def add(n, speed, steer, yaw, tcol, tas, mdps=True, esc=True, noise=True):
        for _ in range(n):
            k = len(seq)
            nz = rng.normal(size=3) if noise else np.zeros(3)
            seq.append(
                (
                    t0 + k * STEP_NS,
                    EstimatorInputs(
                        float(speed),
                        float(steer + 0.01 * DEG * nz[0]),
                        float(yaw + 0.05 * DEG * nz[1]),
                        float(tcol + 0.05 * nz[2]),
                        float(tas),
                        mdps,
                        esc,
                    ),
                )
            )

    add(10, 20 * KMH, 0.0, 0.0, 0.0, 0.0)  # below min speed: held
    add(270, 100 * KMH, 1 * DEG, 0.2 * DEG, 0.3, 0.9)  # start-up (converged after 1 s: VALID)
    add(60, 100 * KMH, 1 * DEG, 1.5 * DEG, 2.0, 6.0)  # a gust-like torque step
    add(10, 100 * KMH, 1 * DEG, 1.5 * DEG, 2.0, 6.0, mdps=False)  # MDPS fault
    add(10, 100 * KMH, 1 * DEG, 1.5 * DEG, 2.0, 6.0, esc=False)  # ESC fault: held
    add(5, 100 * KMH, float("nan"), 1.5 * DEG, 2.0, 6.0)  # non-finite steering
    add(5, 100 * KMH, 1 * DEG, float("inf"), 2.0, 6.0)  # non-finite yaw rate
    add(5, float("nan"), 1 * DEG, 1.5 * DEG, 2.0, 6.0)  # non-finite speed
    add(30, 300 * KMH, 1 * DEG, 1.5 * DEG, 2.0, 6.0)  # above the model maximum
    add(10, 1000.0, 1 * DEG, 1.5 * DEG, 2.0, 6.0)  # outside the speed format
    add(30, 120 * KMH, 15.9, 15.9, 255.0, 255.0, noise=False)  # extremes inside the formats
    add(10, 120 * KMH, 100.0, -100.0, 1e4, -1e4, noise=False)  # outside the formats
    add(10, 25 * KMH, 0.0, 0.0, 0.0, 0.0)  # hold
    add(60, 60 * KMH, -2 * DEG, -0.5 * DEG, -0.4, -1.2)  # resume (P re-initialised)
    return seq


def _hex(x: float) -> str:
    return float(x).hex()


def generate() -> dict[str, Any]:
    vehicle = load_vehicle("reference")
    tables_dict = json.loads(gen.dumps(gen.generate(vehicle)))
    tb = FixedTables.from_dict(tables_dict)
    ref = ReferenceEstimator(vehicle, tb)
    rows_in, rows_out = [], []
    for t_ns, u in golden_inputs():
        rows_in.append(
            [
                t_ns,
                _hex(u.speed),
                _hex(u.steering_angle),
                _hex(u.yaw_rate),
                _hex(u.column_torque),
                _hex(u.assist_torque),
                int(u.mdps_ok),
                int(u.esc_ok),
            ]
        )
        rows_out.append(list(ref.step_ints(t_ns, u)))
    s = ref.state
    return {
        "tables": tables_dict,
        "inputs": rows_in,
        "expected": rows_out,
        "final_state": {"x": s.x, "P": s.P, "delta": s.delta, "t_align": s.t_align, "sat": s.sat},
    }


def main() -> int:
    GOLDEN_PATH.write_text(json.dumps(generate(), indent=None, separators=(",", ":")) + "\n")
    print(f"wrote {GOLDEN_PATH}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
