"""How much of a live recording a SIGKILL loses (issue 13 item 3: at most 1 s).

Each run starts ``lde sim`` (real time) and ``lde run --record F.mcap`` as two processes on
python-can's ``udp_multicast`` bus (a multicast group and port of their own), waits until the
recording holds steps, waits a random 1-3 s more, then SIGKILLs ``lde run``:

* ``--target group``: the service *and* its recorder's writer process (its process group): the
  file keeps what the writer had flushed; the loss is the kill time minus the newest frame and
  step in the file;
* ``--target service``: the service only: the writer sees it gone, writes what the rings hold and
  closes the file (footer written).

Loss [s] = wall time of the kill (epoch) minus the newest received frame's time (``/can/rx``) and
the newest step time (``/lde/estimate``), both in the bus time base (epoch on ``udp_multicast``).
Prints one line per run and the median / max, and writes them as JSON (``--out``)::

    python bench/bench_sigkill.py --runs 10 --target group --out bench/results/sigkill_group.json
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lde.errors import LogFormatError
from lde.recording import read_recording


def _wait_steps(path: Path, n: int, timeout: float) -> bool:
    """Until the recording holds ``n`` steps and ``n`` received frames (under load the simulator
    may start sending seconds after the service steps)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        time.sleep(0.2)
        try:
            r = read_recording(path)
            if len(r.step_times_ns) >= n and len(r.rx) >= n:
                return True
        except (FileNotFoundError, LogFormatError):
            continue
    return False


def one_run(tmp: Path, k: int, target: str, rng: random.Random) -> dict:
    port = rng.randint(40000, 60000)
    channel = f"239.74.{rng.randint(1, 254)}.{rng.randint(1, 254)}"
    bus = ["--interface", "udp_multicast", "--channel", channel, "--bus-kwarg", f"port={port}"]
    path = tmp / f"killed_{k}.mcap"
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    sim = subprocess.Popen(
        [sys.executable, "-m", "lde", "sim", *bus, "--scenario", "heavy_load", "--duration", "120"],
        stderr=subprocess.DEVNULL,
        env=env,
    )
    run = subprocess.Popen(
        [sys.executable, "-m", "lde", "run", *bus, "--backend", "float", "--record", str(path)],
        stderr=subprocess.DEVNULL,
        env=env,
        start_new_session=True,  # its own process group: the service and its writer
    )
    try:
        if not _wait_steps(path, 200, 120.0):
            raise RuntimeError("the recording got no steps and frames within 120 s")
        time.sleep(rng.uniform(1.0, 3.0))
        t_kill = time.time_ns()
        if target == "group":
            os.killpg(run.pid, signal.SIGKILL)
        else:
            run.send_signal(signal.SIGKILL)
        run.wait(10)
        if target == "service":  # the writer outlives the service, closes the file
            deadline = time.monotonic() + 20
            while not read_recording(path).complete and time.monotonic() < deadline:
                time.sleep(0.1)
    finally:
        for p in (run, sim):
            if p.poll() is None:
                p.kill()
                p.wait()
        if run.poll() is not None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(run.pid, signal.SIGKILL)  # a writer still alive
    r = read_recording(path)
    last_rx = int(r.rx.t_ns.max()) if len(r.rx) else 0
    last_step = int(r.step_times_ns[-1]) if len(r.step_times_ns) else 0
    return {
        "run": k,
        "target": target,
        "complete": bool(r.complete),
        "steps": len(r.step_times_ns),
        "rx_frames": len(r.rx),
        "lost_rx_s": (t_kill - last_rx) / 1e9,
        "lost_steps_s": (t_kill - last_step) / 1e9,
        "bytes": path.stat().st_size,
    }


def _runs(args: argparse.Namespace, rng: random.Random) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="lde-sigkill-") as d:
        for k in range(args.runs):
            row = one_run(Path(d), k, args.target, rng)
            rows.append(row)
            print(
                f"run {k}: complete {row['complete']}, {row['steps']} steps, lost {row['lost_rx_s']:.3f} s of"
                f" frames, {row['lost_steps_s']:.3f} s of steps",
                flush=True,
            )
    return rows


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--target", choices=("group", "service"), default="group")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--busy", type=int, default=0, metavar="N", help="N busy-loop processes meanwhile (load)")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    load0 = os.getloadavg()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        rows = _runs(args, rng)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    lost = np.array([r["lost_rx_s"] for r in rows])
    lost_steps = np.array([r["lost_steps_s"] for r in rows])
    summary = {
        "command": " ".join(["python", *sys.argv]),
        "target": args.target,
        "busy": args.busy,
        "runs": args.runs,
        "lost_rx_s_median": float(np.median(lost)),
        "lost_rx_s_max": float(lost.max()),
        "lost_steps_s_median": float(np.median(lost_steps)),
        "lost_steps_s_max": float(lost_steps.max()),
        "complete": sum(r["complete"] for r in rows),
        "load_avg_before_after": [*load0, *os.getloadavg()],
        "machine": f"{platform.machine()}, {os.cpu_count()} cpus, python {platform.python_version()}",
        "rows": rows,
    }
    med, top = summary["lost_rx_s_median"], summary["lost_rx_s_max"]
    print(
        f"{args.target}: lost frames median {med:.3f} s, max {top:.3f} s;"
        f" steps median {float(np.median(lost_steps)):.3f} s, max {float(lost_steps.max()):.3f} s;"
        f" {summary['complete']}/{args.runs} files closed"
    )
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(summary, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
