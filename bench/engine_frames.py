"""What a frame costs the engine, against a step: one log's frames through ``run_replay`` in process
(no start-up, no CSV, read before timing), three ways, alternating, the engine thread's CPU:

* ``all``: the frames as logged;
* ``no_esc``: without the ESC_Motion frames (the same MDPS-anchored steps, fewer frames; the ESC
  inputs go stale, so the steps are not the same work);
* ``esc_unknown``: the ESC_Motion frames with an id the profile does not know: each is an ignored
  frame (id lookup, the ignored count, the grid's frame hook), so ``esc_unknown - no_esc`` over the
  number of those frames is the cost of a frame's trip through the loop and its call, with no decode.

    PYTHONPATH=TREE/src:TREE python bench/engine_frames.py /tmp/lde-bench-F/hour.mcap [--repeat 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

from lde.can.frames import FrameBatch
from lde.params import load_vehicle
from lde.replay.replay import read_inputs, run_replay

#: an 11-bit id that no shipped profile uses
UNKNOWN_ID = 0x7FE


def variants(pieces: list[FrameBatch], esc_id: int) -> dict[str, list[FrameBatch]]:
    def unknown(p: FrameBatch) -> FrameBatch:
        cid = p.can_id.copy()
        cid[cid == esc_id] = UNKNOWN_ID
        return dataclasses.replace(p, can_id=cid)

    return {
        "all": pieces,
        "no_esc": [p.select(p.can_id != esc_id) for p in pieces],
        "esc_unknown": [unknown(p) for p in pieces],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("log")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    li = read_inputs(args.log, None)
    pieces = list(li.stream)
    esc_id = li.profile.messages["ESC_Motion"].frame_id
    vehicle = load_vehicle("reference")
    vs = variants(pieces, esc_id)
    n_esc = sum(int((p.can_id == esc_id).sum()) for p in pieces)
    res: dict[tuple[str, str], list[float]] = {(k, b): [] for b in ("fixed", "float") for k in vs}
    for r in range(args.repeat + 1):  # the first round warms up (kernel loads)
        for b in ("fixed", "float"):
            for k, v in vs.items():
                c = time.thread_time()
                run_replay(iter(v), li.profile, vehicle, b, output_frames=False, read_ahead=False)
                if r:
                    res[(k, b)].append(time.thread_time() - c)
    print(f"{args.log}: {sum(len(p) for p in pieces)} frames, {n_esc} ESC_Motion; {args.repeat} rounds")
    med = {key: statistics.median(xs) for key, xs in res.items()}
    for (k, b), xs in res.items():
        print(f"{b:5s} {k:12s} engine CPU {med[(k, b)]:.3f} s ({min(xs):.3f}-{max(xs):.3f})")
    for b in ("fixed", "float"):
        us = (med[("esc_unknown", b)] - med[("no_esc", b)]) / max(n_esc, 1) * 1e6
        print(f"{b:5s} an ignored frame's trip through the loop: {us:.3f} us")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
