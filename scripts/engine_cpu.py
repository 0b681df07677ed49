#!/usr/bin/env python3
"""CPU of the data path alone over a log (warm kernels, no start-up, no CSV), per step.

    python scripts/engine_cpu.py LOG [BACKEND] [RUNS]

Reads the whole log, then runs ``Engine(lde profile, reference vehicle, BACKEND,
).feed(frames, final=True)`` RUNS + 1 times and prints the median, fastest and
slowest CPU seconds (``time.process_time``) of the last RUNS (the first loads or compiles the
kernels). Compare two trees in one session, alternating, each with its own ``NUMBA_CACHE_DIR``.
"""

from __future__ import annotations

import statistics
import sys
import time

from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.engine.engine import Engine
from lde.io import open_log
from lde.params import load_vehicle


def main(argv: list[str]) -> int:
    if not argv:
        print(__doc__.split("\n\n")[1].strip(), file=sys.stderr)
        return 2
    path = argv[0]
    backend = argv[1] if len(argv) > 1 else "fixed"
    runs = int(argv[2]) if len(argv) > 2 else 3
    with open_log(path) as stream:
        frames = FrameBatch.concat(list(stream))
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    cpu = []
    steps = 0
    for k in range(runs + 1):
        engine = Engine(profile, vehicle, backend)
        t0 = time.process_time()
        steps = len(engine.feed(frames, final=True))
        if k:
            cpu.append(time.process_time() - t0)
    med = statistics.median(cpu)
    per_step_us = med / max(steps, 1) * 1e6
    print(
        f"{backend}: {steps} steps, {len(frames)} frames; engine CPU median {med:.3f} s "
        f"(fastest {min(cpu):.3f}, slowest {max(cpu):.3f}, {runs} runs) = {per_step_us:.3f} us/step"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
