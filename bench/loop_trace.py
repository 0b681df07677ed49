"""The live loop's period error taken apart (``bench/bench_loop.py --trace F.npz``).

On the MDPS-locked grid a step's period error is the time from the trigger frame's kernel receive
stamp to the step's start. Per triggered step this splits it into

* ``wake``: stamp to the return of the receive call that delivered the frame, by how that call
  waited: ``poll`` (the service was polling: the spin around the expected frame) or ``block``
  (blocked in ``select``: the kernel's wake-up of the process);
* ``glue``: that return to the step's start (lde's Python between the frame and the step: the
  frame's bookkeeping, the grid's kernels);

and, from the simulator's own trace (``lde sim --send-trace``), what comes before the stamp:

* ``sender_late``: the simulator's ``sendto`` call minus the frame's scheduled time (its timed sleep's
  wake-up): the grid's input jitter, since the grid follows the frames;
* ``send_to_stamp``: ``sendto`` called to the kernel's stamp on the service's socket;
* ``arrival``: the frame's stamp minus the time the grid expected it (the previous trigger + 3.9 ms):
  the service polls only within ``--spin-us`` of that time, later frames find it blocked.

``run_delay``: the time the service's thread was runnable but not running between two steps
(``/proc/thread-self/schedstat``: another task on its CPU, or the switch to it after a wake-up).

    python bench/loop_trace.py F.npz [F2.npz ...]      # the decomposition of saved traces, as JSON
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

STEP_NS = 3_900_000
MISS_NS = 1_000_000


def _q(a: np.ndarray) -> dict[str, float] | None:
    """p50 / p99 / max [us] (None for no samples)."""
    if a.size == 0:
        return None
    p50, p99 = np.percentile(a, [50, 99])
    return {
        "n": int(a.size),
        "p50": round(p50 / 1e3, 1),
        "p99": round(p99 / 1e3, 1),
        "max": round(a.max() / 1e3, 1),
    }


def decompose(d: dict[str, np.ndarray]) -> dict[str, object]:
    """The decomposition of one run's trace (the arrays ``bench_loop.py --trace`` saves)."""
    a, b = (int(x) for x in d["window"])
    off = int(d["offset_ns"][0])
    t_k = d["step_t"][a:b]
    pe = d["step_pe"][a:b]
    rd = d["step_run_delay"]
    run_delay = (rd[a:b] - rd[a - 1 : b - 1]) if a > 0 else np.diff(rd[a:b], prepend=rd[a])
    start_mono = t_k + pe - off
    recv = d["recv"]
    rx_at = {int(t): i for i, t in enumerate(recv[:, 0])}
    idx = np.array([rx_at.get(int(t), -1) for t in t_k], np.int64)
    trig = idx >= 0
    r = recv[idx[trig]]
    wake = r[:, 2] - (r[:, 0] - off)
    glue = start_mono[trig] - r[:, 2]
    blocked = r[:, 3].astype(bool)
    pe_t = pe[trig]
    out: dict[str, object] = {
        "steps": int(t_k.size),
        "triggered": int(trig.sum()),
        "timeout_steps": int((~trig).sum()),
        "period_error_triggered": _q(pe_t),
        "period_error_timeout": _q(pe[~trig]),
        "wake_poll": _q(wake[~blocked]),
        "wake_block": _q(wake[blocked]),
        "share_blocked": round(float(blocked.mean()), 4) if blocked.size else None,
        "glue": _q(glue),
        "run_delay_per_step": _q(run_delay),
    }
    # arrival against the grid's expectation: the previous step a trigger, this one too
    prev_trig = np.zeros_like(trig)
    prev_trig[1:] = trig[:-1]
    both = trig & prev_trig
    arr = t_k[both] - (t_k[np.flatnonzero(both) - 1] + STEP_NS)
    pol = r[:, 3] == 0
    out["poll_call_with_frame"] = _q(r[pol, 2] - r[pol, 1])
    out["poll_call_start_minus_stamp"] = _q(r[pol, 1] - (r[pol, 0] - off))
    if "empty_poll" in d:
        out["poll_call_empty"] = _q(d["empty_poll"])
    out["arrival_vs_expected"] = _q(np.abs(arr))
    out["arrival_outside_200us"] = int(np.count_nonzero(np.abs(arr) > 200_000))
    # the misses, by what they are made of
    late = pe > MISS_NS
    out["late_steps"] = int(late.sum())
    lt = late[trig]
    out["late_triggered"] = {
        "n": int(lt.sum()),
        "blocked": int((lt & blocked).sum()),
        "polled": int((lt & ~blocked).sum()),
        "wake_gt_1ms": int((lt & (wake > MISS_NS)).sum()),
        "glue_gt_1ms": int((lt & (glue > MISS_NS)).sum()),
        "run_delay_gt_1ms": int((lt & (run_delay[trig] > MISS_NS)).sum()),
    }
    out["late_timeout"] = int(late[~trig].sum())
    # the sender, from the simulator's own trace
    send = d["send"]
    anchor = int(d["anchor_id"][0])
    s = send[send[:, 3] == anchor] if send.size else send
    if s.size:
        due, before = s[:, 0], s[:, 1]
        rx_mono = recv[:, 0] - off
        j = np.searchsorted(before, rx_mono, side="right") - 1
        ok = (j >= 0) & (rx_mono - before[np.maximum(j, 0)] < MISS_NS)
        out["sender_late"] = _q(before - due)
        out["sender_late_gt_200us"] = int(np.count_nonzero(before - due > 200_000))
        out["sender_interval_error"] = _q(np.abs(np.diff(before) - STEP_NS))
        out["send_to_stamp"] = _q(rx_mono[ok] - before[j[ok]])
        # the whole chain for triggered steps: scheduled send time to the step's start
        jt = j[idx[trig]]
        okt = ok[idx[trig]]
        out["due_to_start"] = _q((start_mono[trig] - due[jt])[okt])
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(
        description="The live loop's period error taken apart (JSON, one line per trace)."
    )
    ap.add_argument("traces", nargs="+", metavar="F.npz", help="written by bench_loop.py --trace")
    args = ap.parse_args(argv)
    for path in args.traces:
        try:
            with np.load(path) as z:
                tr = dict(z)
        except (OSError, ValueError) as exc:
            ap.error(f"{path}: not a readable trace ({exc})")
        print(json.dumps({"file": path, **decompose(tr)}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
