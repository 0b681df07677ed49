#!/usr/bin/env python3
"""CPU seconds of one group of the cold start's split (:mod:`lde.coldstart`), compiled alone.

Run it on an empty cache, one process, e.g. the fixed helper's firmware step::

    rm -rf /tmp/nb && NUMBA_CACHE_DIR=/tmp/nb python scripts/compile_group_cpu.py fx-step [--counted]

Prints the group's CPU seconds (``time.process_time``), its compilations, the longest ones (own CPU,
without the compilations they set off) and numba's LLVM time. ``--counted``: every kernel compiled
with numba's reference counting (:data:`lde.refcount.NO_REFCOUNT` emptied before the kernels'
modules are imported), to compare the uncounted form's compile cost.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> int:
    ap = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    ap.add_argument("group", help="a group of lde.coldstart (fx-step, learner, loop-out, ...)")
    ap.add_argument("--counted", action="store_true", help="compile with reference counting")
    a = ap.parse_args()
    from lde import refcount

    if a.counted:
        refcount.NO_REFCOUNT.clear()
    from compile_profile import _Timer
    from numba.core import event

    from lde import coldstart as C

    if a.group not in C._GROUPS:
        print(f"no group {a.group!r}: one of {', '.join(C._GROUPS)}", file=sys.stderr)
        return 2
    timer = _Timer()
    event.register("numba:compile", timer)
    c0 = time.process_time()
    C._GROUPS[a.group]()
    cpu = time.process_time() - c0
    rows = sorted(timer.done, key=lambda c: -c.own_cpu)
    llvm = sum(
        (cres.metadata or {}).get("timers", {}).get("llvm_lock", 0.0)
        for d in timer.dispatchers.values()
        for cres in d.overloads.values()
    )
    print(
        f"{a.group} ({'counted' if a.counted else 'as shipped'}): {cpu:.2f} s CPU, {len(rows)} compilations, "
        f"LLVM {llvm:.2f} s (wall); longest: " + ", ".join(f"{c.name} {c.own_cpu:.2f}" for c in rows[:6])
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
