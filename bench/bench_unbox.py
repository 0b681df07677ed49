"""What moving the backend's parameter and state tuples (23 arrays for ``fixed``) into a StructRef could
save on the live engine call: a compiled function that takes them as tuples against one that takes
nothing, both called through their resolved overloads as the service calls the engine (no type
dispatch); back to back ("hot") and after a 0.5 ms sleep each (as the live step after the idle period).

    taskset -c 1 python bench/bench_unbox.py      # one JSON line, microseconds
"""

from __future__ import annotations

import json
import os
import time

import numpy as np
from numba import njit

from lde.can.profiles import load_profile
from lde.engine.engine import Engine
from lde.params import load_vehicle


@njit
def _with_tuples(bp, bs):  # pragma: no cover - compiled
    return bs[2][0]


@njit
def _without():  # pragma: no cover - compiled
    return 0


def main() -> None:
    eng = Engine(load_profile("lde"), load_vehicle("reference"), "fixed", explicit=True)
    bp, bs = eng.est.params, eng.est.state
    _with_tuples(bp, bs)
    _without()
    with_tuples = _with_tuples.overloads[tuple(_with_tuples.typeof_pyval(x) for x in (bp, bs))].entry_point
    without = _without.overloads[()].entry_point
    pc = time.perf_counter_ns
    out: dict[str, object] = {
        "arrays": sum(isinstance(a, np.ndarray) for a in (*bp, *bs)),
        "load_avg": os.getloadavg()[0],
    }
    for name, f, args in (("tuples", with_tuples, (bp, bs)), ("none", without, ())):
        hot, cold = np.zeros(20000, np.int64), np.zeros(2000, np.int64)
        for k in range(hot.size):
            t = pc()
            f(*args)
            hot[k] = pc() - t
        for k in range(cold.size):
            time.sleep(0.0005)
            t = pc()
            f(*args)
            cold[k] = pc() - t
        out[name] = {
            "hot_p50_us": round(float(np.median(hot)) / 1e3, 2),
            "after_sleep_p50_us": round(float(np.median(cold)) / 1e3, 2),
        }
    print(json.dumps(out))


if __name__ == "__main__":
    main()
