"""How much of a live recording a SIGKILL loses (issue 13 item 3: at most 1 s).

Each run starts ``lde sim`` (real time) and ``lde run --record F.mcap`` as two processes on
python-can's ``udp_multicast`` bus (a multicast group and port of their own, ``hop_limit`` 0: on
this host only), waits until the recording holds steps, waits a random 1-3 s more, then SIGKILLs
``lde run``:

* ``--target group``: the service *and* its recorder's writer process (its process group): the
  file keeps what the writer had flushed; the loss is the kill time minus the newest frame and
  step in the file;
* ``--target service``: the service only: the writer sees it gone, writes what the pipes hold and
  closes the file (footer written).

Loss [s] = wall time of the kill (epoch) minus the newest received frame's time (``/can/rx``) and
the newest step time (``/lde/estimate``), both in the bus time base (epoch on ``udp_multicast``).

* ``--target sim``: ``lde sim --log F.log --truth F.csv --mcap F.mcap`` alone (real time, open loop)
  on the bus, SIGKILLed. The files carry simulated timestamps, so the bench listens on the bus
  itself and notes the wall time at which each frame arrived; the n-th frame of a file is the n-th
  frame sent (checked by its id and bytes). Loss of the log / MCAP = kill time minus the arrival
  of its newest frame; of the truth CSV = kill time minus the arrival of the frame at or before its
  newest row, plus the simulated time between the two. Also noted: whether ``lde replay`` of the
  MCAP says "not closed", and whether the CSV's last line was cut.

Prints one line per run and the median / max, and writes them as JSON (``--out``)::

    python bench/bench_sigkill.py --runs 10 --target group --out bench/results/sigkill_group.json
    python bench/bench_sigkill.py --runs 10 --target sim --out bench/results/sigkill_sim.json
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
import threading
import time
from pathlib import Path

import can
import numpy as np

from lde.errors import LogFormatError
from lde.io.recording import read_recording
from lde.testing.bus import private_multicast


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


def _bus_args(kw: dict) -> list[str]:
    """The command-line bus options of ``private_multicast``'s keywords, ``hop_limit`` included (0:
    the datagrams stay on this host; python-can's default 1 also puts each one on the network card)."""
    out = ["--interface", kw["interface"], "--channel", kw["channel"], "--bus-kwarg", f"port={kw['port']}"]
    return out + ["--bus-kwarg", f"hop_limit={kw['hop_limit']}"]


def one_run(tmp: Path, k: int, target: str, rng: random.Random) -> dict:
    kw = private_multicast(rng)
    bus = _bus_args(kw)
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


class _Listener:
    """Every frame on the bus with the wall time [ns, epoch] at which it arrived (a thread)."""

    def __init__(self, bus_args: dict) -> None:
        self.bus = can.Bus(**bus_args)
        self.frames: list[tuple[int, int, bytes]] = []  # (arrival ns, id, data)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self.bus.recv(timeout=0.1)
            if msg is not None:
                self.frames.append((time.time_ns(), msg.arbitration_id, bytes(msg.data)))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(5)
        self.bus.shutdown()


def _arrival(heard: list[tuple[int, int, bytes]], frames, n: int) -> int:
    """Arrival [ns] of the file's ``n``-th frame (1-based): the ``n``-th frame heard, when its id
    and bytes match (else searched among the frames heard, from the newest)."""
    cid, data = int(frames.can_id[n - 1]), bytes(frames.data[n - 1, : frames.dlc[n - 1]])
    if n <= len(heard) and heard[n - 1][1:] == (cid, data):
        return heard[n - 1][0]
    for t, i, d in reversed(heard):
        if (i, d) == (cid, data):
            return t
    raise RuntimeError(f"frame {n} of the file ({cid:#x} {data.hex()}) was never heard on the bus")


def one_sim_run(tmp: Path, k: int, rng: random.Random) -> dict:
    from lde.io import read_log, read_mcap
    from lde.replay.fleet import ReplayJob, replay_job
    from vcan_sim.truth import read_truth_csv

    kw = private_multicast(rng)
    bus = _bus_args(kw)
    log, csv, mcap = (tmp / f"sim_{k}.{ext}" for ext in ("log", "csv", "mcap"))
    listener = _Listener(kw)
    cmd = [sys.executable, "-m", "lde", "sim", *bus, "--scenario", "heavy_load", "--duration", "120"]
    cmd += ["--open-loop", "--log", str(log), "--truth", str(csv), "--mcap", str(mcap)]
    sim = subprocess.Popen(cmd, stderr=subprocess.DEVNULL, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    try:
        deadline = time.monotonic() + 120
        while len(listener.frames) < 200 and time.monotonic() < deadline and sim.poll() is None:
            time.sleep(0.1)
        if len(listener.frames) < 200:
            raise RuntimeError("the simulator sent no 200 frames within 120 s")
        time.sleep(rng.uniform(1.0, 3.0))
        t_kill = time.time_ns()
        sim.send_signal(signal.SIGKILL)
        sim.wait(10)
    finally:
        if sim.poll() is None:
            sim.kill()
            sim.wait()
        time.sleep(0.2)
        listener.close()
    heard = listener.frames
    fl = read_log(log).frames
    fm = read_mcap(mcap, json_topics="/truth")
    truth = read_truth_csv(csv)
    lost_log = (t_kill - _arrival(heard, fl, len(fl))) / 1e9
    lost_mcap = (t_kill - _arrival(heard, fm.frames, len(fm.frames))) / 1e9
    t_truth = int(round(truth.columns["t"][-1] * 1e9))
    i = int(np.searchsorted(fl.t_ns, t_truth, side="right"))  # frames at or before the last row
    lost_truth = (t_kill - _arrival(heard, fl, i) - (t_truth - int(fl.t_ns[i - 1]))) / 1e9
    rep = replay_job(ReplayJob(mcap, profile="lde", use_recorded_steps=False))
    return {
        "run": k,
        "target": "sim",
        "frames_heard": len(heard),
        "log_frames": len(fl),
        "mcap_frames": len(fm.frames),
        "truth_rows": len(truth),
        "truth_cut": truth.cut,
        "replay_says_not_closed": any("not closed" in w for w in rep.warnings),
        "lost_log_s": lost_log,
        "lost_mcap_s": lost_mcap,
        "lost_truth_s": lost_truth,
        "bytes": [p.stat().st_size for p in (log, csv, mcap)],
    }


def _sim_runs(args: argparse.Namespace, rng: random.Random) -> list[dict]:
    rows = []
    with tempfile.TemporaryDirectory(prefix="lde-sigkill-sim-") as d:
        for k in range(args.runs):
            row = one_sim_run(Path(d), k, rng)
            rows.append(row)
            print(
                f"run {k}: lost {row['lost_log_s']:.3f} s of the log, {row['lost_mcap_s']:.3f} s of the "
                f"MCAP, {row['lost_truth_s']:.3f} s of the truth ({row['log_frames']} frames, "
                f"{row['truth_rows']} rows, replay says not closed: {row['replay_says_not_closed']}, "
                f"CSV cut: {row['truth_cut']})",
                flush=True,
            )
    return rows


def _sim_summary(args: argparse.Namespace, rows: list[dict], load0: tuple[float, ...]) -> dict:
    out: dict = {
        "command": " ".join(["python", *sys.argv]),
        "target": "sim",
        "busy": args.busy,
        "runs": args.runs,
    }
    for key in ("lost_log_s", "lost_mcap_s", "lost_truth_s"):
        v = np.array([r[key] for r in rows])
        out[f"{key}_median"], out[f"{key}_max"] = float(np.median(v)), float(v.max())
    out["replay_says_not_closed"] = sum(r["replay_says_not_closed"] for r in rows)
    out["truth_cut"] = sum(r["truth_cut"] for r in rows)
    out["load_avg_before_after"] = [*load0, *os.getloadavg()]
    out["machine"] = f"{platform.machine()}, {os.cpu_count()} cpus, python {platform.python_version()}"
    out["rows"] = rows
    print(
        "sim: lost median / max [s]: log {lost_log_s_median:.3f} / {lost_log_s_max:.3f}, MCAP "
        "{lost_mcap_s_median:.3f} / {lost_mcap_s_max:.3f}, truth {lost_truth_s_median:.3f} / "
        "{lost_truth_s_max:.3f}; replay said not closed {replay_says_not_closed}/{runs}".format(**out)
    )
    return out


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
    ap.add_argument("--target", choices=("group", "service", "sim"), default="group")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    ap.add_argument("--busy", type=int, default=0, metavar="N", help="N busy-loop processes meanwhile (load)")
    args = ap.parse_args()
    rng = random.Random(args.seed)
    load0 = os.getloadavg()
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        rows = _sim_runs(args, rng) if args.target == "sim" else _runs(args, rng)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    if args.target == "sim":
        out = _sim_summary(args, rows, load0)
        if args.out is not None:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps(out, indent=1) + "\n")
        return 0
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
