#!/usr/bin/env python3
"""Where a first run's compile time goes: one ``lde`` command, each numba compilation timed.

Run it on an empty cache (a fresh ``NUMBA_CACHE_DIR``) to see what a first run after an install
compiles::

    rm -rf /tmp/nb && NUMBA_CACHE_DIR=/tmp/nb python scripts/compile_profile.py \\
        replay tests/data/sample_linear.log --csv /tmp/x.csv -q

It prints the command's wall and CPU seconds, then the compilations (numba's ``numba:compile``
events) with the longest own time first: ``own`` excludes the compilations a kernel's typing set off
(a kernel compiles the kernels it calls), ``incl`` includes them; ``own CPU``: this process's CPU
seconds in it (what a loaded machine changes least). A kernel listed twice was compiled
for two signatures; ``--args`` shows them (``Literal[int](0)`` and the like: a call numba typed
while the caller's types were still partial, see :mod:`lde.engine.loop`). ``--passes NAME,...`` adds
numba's pass times and LLVM time of those kernels.
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from dataclasses import dataclass
from typing import Any

from numba.core import event


@dataclass
class Compile:
    name: str  # the kernel's qualified name
    args: str  # the argument types it was compiled for
    incl_s: float  # wall seconds of the compilation, with the ones it set off
    own_s: float  # without them
    own_cpu: float  # CPU seconds of this process without them (the load does not change it much)
    depth: int  # how many compilations were under way around it


class _Timer(event.Listener):
    def __init__(self) -> None:
        self.stack: list[list[Any]] = []
        self.done: list[Compile] = []
        self.dispatchers: dict[str, Any] = {}

    def on_start(self, ev: event.Event) -> None:
        d = ev.data["dispatcher"]
        self.dispatchers[d.py_func.__qualname__] = d
        now, cpu = time.perf_counter(), time.process_time()
        self.stack.append([d.py_func.__qualname__, str(ev.data["args"]), now, 0.0, cpu, 0.0])

    def on_end(self, ev: event.Event) -> None:
        name, args, t0, inner, c0, inner_cpu = self.stack.pop()
        dt, dc = time.perf_counter() - t0, time.process_time() - c0
        if self.stack:
            self.stack[-1][3] += dt
            self.stack[-1][5] += dc
        self.done.append(Compile(name, args, dt, dt - inner, dc - inner_cpu, len(self.stack)))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--top", type=int, default=25, help="list this many compilations")
    ap.add_argument("--args", action="store_true", help="show the argument types")
    ap.add_argument("--passes", default="", help="comma-separated kernel names: their pass times")
    ap.add_argument("lde_args", nargs=argparse.REMAINDER, help="the lde command line")
    a = ap.parse_args()
    timer = _Timer()
    event.register("numba:compile", timer)
    import lde.cli

    t0 = time.perf_counter()
    rc = lde.cli.main(a.lde_args)
    wall = time.perf_counter() - t0
    ru = resource.getrusage(resource.RUSAGE_SELF)
    rows = sorted(timer.done, key=lambda c: -c.own_s)
    print(
        f"lde {' '.join(a.lde_args)}: rc {rc}, {wall:.1f} s wall, {ru.ru_utime + ru.ru_stime:.1f} s CPU "
        f"(process), {len(rows)} compilations, {sum(c.own_s for c in rows):.1f} s in them "
        f"({sum(c.own_cpu for c in rows):.1f} s CPU)",
        file=sys.stderr,
    )
    for c in rows[: a.top]:
        extra = f" {c.args[-300:]}" if a.args else ""
        print(
            f"  {c.own_s:6.2f} own {c.incl_s:6.2f} incl {c.own_cpu:6.2f} own CPU  "
            f"{'  ' * c.depth}{c.name}{extra}",
            file=sys.stderr,
        )
    for name in filter(None, a.passes.split(",")):
        d = timer.dispatchers.get(name)
        for cres in d.overloads.values() if d is not None else []:
            md = cres.metadata or {}
            timers = md.get("timers", {})
            passes = md.get("pipeline_times", {}).get("nopython", {})
            top = sorted(((v.run, k.split("_", 1)[-1]) for k, v in passes.items()), reverse=True)[:6]
            llvm, total = timers.get("llvm_lock", 0.0), timers.get("compiler_lock", 0.0)
            steps = ", ".join(f"{k} {v:.2f}" for v, k in top)
            print(f"{name}: LLVM {llvm:.2f} s, all {total:.2f} s; {steps}", file=sys.stderr)
    return int(rc)


if __name__ == "__main__":
    sys.exit(main())
