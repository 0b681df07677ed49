"""The benchmark suite (issue 12 item 9): every figure beside its anchor, measured in the same run.

    python bench/run_all.py                    # ~5 min: anchors, replay (1 h), MCAP size, warm start
    python bench/run_all.py --ten-hours        # + peak RSS of a 10-hour log (generated once, ~2 min)
    python bench/run_all.py --cold             # + a first run on an empty numba cache (minutes)
    python bench/run_all.py --fleet 100        # + 100 logs one after the other vs --jobs 2
    python bench/run_all.py --readme README.md # and put the table into the README between markers

Writes ``bench/results/report.json`` (every sample) and ``bench/results/report.md`` (the table:
medians with min-max, the machine, the load average before and after, the command). Timings are
medians of ``--repeat`` runs after one warm-up; CPU time (``process_time`` in process, user+sys of
a child process) is given beside wall time because the machine may be shared. The anchors:

=====================================  ================================================================
lde                                    anchor
=====================================  ================================================================
float / fixed estimator step           filterpy ``KalmanFilter`` predict + update (same model matrices)
receiver: E2E + decode to SI           cantools ``Database.decode_message``
output encoder (counters, CRC)         cantools ``Database.encode_message``
compiled Profile 1 CRC check           ``autosar-e2e``'s ``e2e.p01.e2e_p01_check`` (why lde has its own)
candump reader (``lde.io``)         python-can ``CanutilsLogReader``
MCAP reader (``lde.io``)            the ``mcap`` library's ``iter_messages``
replay of 1 h to CSV                   a straightforward replay: cantools decode + a numpy Kalman step
                                       per frame (run on 2 min of the log, scaled to the hour)
=====================================  ================================================================
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import platform
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from traffic import write_logs

import lde
from lde.can.codec import encode_batch
from lde.can.e2e import P01_SCHEME, check_batch
from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.engine.grid import build_grid
from lde.engine.receiver import decode_batch
from lde.estimator import model
from lde.estimator.paper import run_batch as float_run_batch
from lde.io import McapWriter, open_log, read_log
from lde.kalman_reference import FilterpyReference
from lde.params import load_vehicle
from lde.replay.replay import CsvWriter, read_inputs, run_replay

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "data" / "sample_linear.log"
MARK_BEGIN = "<!-- bench/run_all.py: begin -->"
MARK_END = "<!-- bench/run_all.py: end -->"


# ----------------------------------------------------------------------------- measuring
def stats(xs: list[float]) -> dict[str, Any]:
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "n": len(xs), "samples": xs}


def timed(fn: Callable[[], Any], repeat: int, clock: Callable[[], float] = time.process_time) -> dict:
    """``fn`` once to warm up, then ``repeat`` times: CPU seconds (``clock``) and wall seconds."""
    fn()
    cpu, wall = [], []
    for _ in range(repeat):
        c, w = clock(), time.perf_counter()
        fn()
        cpu.append(clock() - c)
        wall.append(time.perf_counter() - w)
    return {"cpu": stats(cpu), "wall": stats(wall)}


_WRAP = (
    "import json, resource, subprocess, sys, time\n"
    "t = time.perf_counter(); r = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
    "w = time.perf_counter() - t; u = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
    "print(json.dumps([r.returncode, w, u.ru_utime + u.ru_stime, u.ru_maxrss, r.stderr[-2000:]]))\n"
)


def child_env(**extra: str) -> dict[str, str]:
    """The children's environment: this one with Python's bytecode cache on (an installed package
    has its ``.pyc`` files; ``PYTHONDONTWRITEBYTECODE`` would make every start compile lde's sources
    again, about 0.17 s here), plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env.update(extra)
    return env


def run_child(argv: list[str], env: dict[str, str] | None = None) -> dict[str, Any]:
    """Wall, CPU (user + sys) and peak RSS [MiB] of one child process."""
    env = child_env() if env is None else env
    out = subprocess.run([sys.executable, "-c", _WRAP, *argv], capture_output=True, text=True, env=env)
    rc, wall, cpu, rss_kib, err = json.loads(out.stdout)
    if rc != 0:
        raise RuntimeError(f"{' '.join(argv)} failed ({rc}): {err}")
    return {"wall": wall, "cpu": cpu, "rss_mib": rss_kib / 1024}


def child_stats(argv: list[str], repeat: int, env: dict[str, str] | None = None) -> dict[str, Any]:
    run_child(argv, env)  # warm-up (page cache, numba cache)
    runs = [run_child(argv, env) for _ in range(repeat)]
    return {k: stats([r[k] for r in runs]) for k in ("wall", "cpu", "rss_mib")}


def lde_cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "lde", *args]


# ----------------------------------------------------------------------------- anchors
def bench_kalman(vehicle, grid, repeat: int) -> dict:
    """Per step: the paper's float step over the hour's grid vs filterpy predict + update."""
    n = len(grid)
    args = (grid.t_ns, grid.speed, grid.steering_angle, grid.yaw_rate, grid.column_torque, grid.assist_torque)
    ok = (grid.mdps_ok, grid.esc_ok)
    flt = timed(lambda: float_run_batch(*args, *ok, vehicle), repeat)
    m = 5000
    d = model.discrete_matrices(vehicle, 27.8)
    x0 = np.zeros(4)
    p0 = np.eye(4)
    z = np.array([0.01, 3.0])

    def filterpy_steps() -> None:
        ref = FilterpyReference(x0, p0)
        for _ in range(m):
            ref.predict(d.Phi, d.E, 0.001, d.Qd)
            ref.update(z, d.H, d.D, 0.001, d.R)

    fp = timed(filterpy_steps, max(2, repeat // 2))
    return {
        "float_us_per_step": _per(flt["cpu"], n, 1e6),
        "filterpy_us_per_step": _per(fp["cpu"], m, 1e6),
        "steps": n,
    }


def bench_lateral(log: Path, repeat: int) -> dict:
    """The `fixed` backend's own step: the boundary + the integer lateral step
    (:mod:`firmware_model.lateral`) and its float shadow (:func:`lde.estimator.lateral.step_kernel`) alone,
    per step, on the first 10 minutes of the hour's inputs (``bench/bench_lateral_kernels.py``)."""
    from bench_lateral_kernels import measure

    r = measure(log, 10.0, repeat)
    return {
        k.replace("_ns", "_us"): {"median": v[0] / 1e3, "min": v[1] / 1e3, "max": v[2] / 1e3}
        if k.endswith("_ns")
        else v
        for k, v in r.items()
    }


def _per(s: dict, n: int, scale: float) -> dict:
    return {
        k: (v * scale / n if k in ("median", "min", "max") else v) for k, v in s.items() if k != "samples"
    }


def bench_codec(profile, frames: FrameBatch, repeat: int) -> dict:
    """Per frame: lde's receiver (E2E + decode, over the hour) vs cantools decode; lde's batch
    encoder vs cantools encode; lde's compiled CRC check vs autosar-e2e's."""
    import cantools
    import e2e.p01 as p01

    db = cantools.database.load_file(str(profile.dbc_path))
    n = len(frames)
    dec = timed(lambda: decode_batch(profile, frames), repeat)
    sub = frames[:20000]
    ids = sub.can_id.tolist()
    datas = [bytes(sub.data[i, : sub.dlc[i]]) for i in range(len(sub))]

    def ct_decode() -> None:
        for i, dd in zip(ids, datas, strict=True):
            db.decode_message(i, dd)

    ctd = timed(ct_decode, max(2, repeat // 2))
    est = {"LatForce": np.linspace(-500, 500, n), "YawMoment": np.linspace(-50, 50, n), "Status": 1}
    enc = timed(lambda: encode_batch(profile, "LDE_Estimate", est), repeat)
    msg = db.get_message_by_name("LDE_Estimate")
    sig = {s.name: 0 for s in msg.signals}
    vals = [dict(sig, LatForce=float(v), YawMoment=float(v) / 10) for v in np.linspace(-500, 500, 20000)]

    def ct_encode() -> None:
        for v in vals:
            db.encode_message("LDE_Estimate", v)

    cte = timed(ct_encode, max(2, repeat // 2))
    mdps = frames.select(frames.can_id == profile.spec("MDPS_Sensors").frame_id)
    data_id = profile.spec("MDPS_Sensors").frame_id
    chk = timed(lambda: check_batch(P01_SCHEME, data_id, mdps.data), repeat)
    bufs = [bytearray(mdps.data[i].tobytes()) for i in range(20000)]

    def ae_check() -> None:
        for b in bufs:
            p01.e2e_p01_check(b, data_id)

    aec = timed(ae_check, max(2, repeat // 2))
    return {
        "lde_decode_us_per_frame": _per(dec["cpu"], n, 1e6),
        "cantools_decode_us_per_frame": _per(ctd["cpu"], len(ids), 1e6),
        "lde_encode_us_per_frame": _per(enc["cpu"], n, 1e6),
        "cantools_encode_us_per_frame": _per(cte["cpu"], len(vals), 1e6),
        "lde_crc_check_us_per_frame": _per(chk["cpu"], len(mdps), 1e6),
        "autosar_e2e_check_us_per_frame": _per(aec["cpu"], len(bufs), 1e6),
    }


def bench_readers(log: Path, mcap: Path, repeat: int, tmp: Path) -> dict:
    """Per frame: lde's streamed readers over the hour vs python-can's CanutilsLogReader and the
    mcap library's iter_messages (over a 6-minute slice of the same files: they take minutes)."""
    import can
    from mcap.reader import make_reader

    def lde_read(p: Path) -> Callable[[], int]:
        def go() -> int:
            with open_log(p) as s:
                return sum(len(x) for x in s)

        return go

    n = lde_read(log)()
    cd = timed(lde_read(log), repeat)
    mc = timed(lde_read(mcap), repeat)
    frames = read_log(log).frames
    part = frames[: len(frames) // 10]
    slog = tmp / "slice.log"
    smcap = tmp / "slice.mcap"
    from lde.io import write_candump

    write_candump(slog, part)
    with McapWriter(smcap) as w:
        w.write_frames(part)

    def pycan() -> None:
        for _ in can.CanutilsLogReader(str(slog)):
            pass

    def mcap_lib() -> None:
        with smcap.open("rb") as fh:
            for _ in make_reader(fh).iter_messages():
                pass

    pc = timed(pycan, max(2, repeat // 2))
    ml = timed(mcap_lib, max(2, repeat // 2))
    return {
        "lde_candump_us_per_frame": _per(cd["cpu"], n, 1e6),
        "python_can_candump_us_per_frame": _per(pc["cpu"], len(part), 1e6),
        "lde_mcap_us_per_frame": _per(mc["cpu"], n, 1e6),
        "mcap_library_us_per_frame": _per(ml["cpu"], len(part), 1e6),
        "frames": n,
    }


def naive_replay(frames: FrameBatch, profile, vehicle, out: Path) -> int:
    """A straightforward replay: cantools decode of every frame, the latest values held, and on
    every MDPS frame a numpy Kalman predict + update on the model at that speed; CSV rows with the
    csv module. Returns the rows."""
    import cantools

    db = cantools.database.load_file(str(profile.dbc_path))
    mdps_id = profile.spec("MDPS_Sensors").frame_id
    esc_id = profile.spec("ESC_Motion").frame_id
    x = np.zeros(4)
    P = np.eye(4) * 1e3
    latest: dict[str, float] = {}
    rows = 0
    with out.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["t", "Fw", "Mw"])
        for i in range(len(frames)):
            cid = int(frames.can_id[i])
            if cid not in (mdps_id, esc_id):
                continue
            latest.update(db.decode_message(cid, bytes(frames.data[i, : frames.dlc[i]])))
            if cid != mdps_id or "VehicleSpeed" not in latest:
                continue
            vx = max(float(latest["VehicleSpeed"]) / 3.6, 10.0)
            d = model.discrete_matrices(vehicle, vx)
            delta = np.deg2rad(float(latest["SteeringAngle"])) / vehicle.steering.ratio
            z = np.array(
                [
                    np.deg2rad(float(latest["YawRate"])),
                    vehicle.steering.ratio * (float(latest["ColumnTorque"]) + float(latest["AssistTorque"])),
                ]
            )
            # x = Phi x + E u; P = Phi P Phi' + Qd
            x = d.Phi @ x + d.E * delta
            P = d.Phi @ P @ d.Phi.T + d.Qd
            # K = P H' (H P H' + R)^-1; x += K (z - H x - D u); P = (I - K H) P
            S = d.H @ P @ d.H.T + d.R
            K = P @ d.H.T @ np.linalg.inv(S)
            x = x + K @ (z - d.H @ x - d.D * delta)
            P = (np.eye(4) - K @ d.H) @ P
            w.writerow([f"{frames.t_ns[i] / 1e9:.6f}", f"{x[2]:.3f}", f"{x[3]:.3f}"])
            rows += 1
    return rows


def bench_replay_inproc(log: Path, mcap: Path, vehicle, profile, repeat: int, tmp: Path) -> dict:
    """In process (warm, no start-up): the hour through read -> engine -> CSV, CPU per stage (each
    stage's own thread CPU; the CSV written inline here, ``lde replay`` writes it from a thread
    beside the engine; the pieces are read one ahead in a thread, as ``lde replay`` reads them)."""
    out: dict[str, Any] = {}
    for label, path in (("candump", log), ("mcap", mcap)):
        for backend in ("fixed", "float"):
            samples: dict[str, list[float]] = {"total": [], "read": [], "engine": [], "csv": [], "wall": []}
            for k in range(repeat + 1):
                c0, w0 = time.process_time(), time.perf_counter()
                li = read_inputs(path, None)
                csvw = CsvWriter(tmp / "inproc.csv", background=False)  # its CPU counted apart
                read_cpu = [0.0]
                csv_cpu = [0.0]

                # per-thread CPU: run_replay reads the pieces in a thread of their own
                def pieces(s=li.stream, acc=read_cpu):
                    it = iter(s)
                    while True:
                        c = time.thread_time()
                        x = next(it, None)
                        acc[0] += time.thread_time() - c
                        if x is None:
                            return
                        yield x

                def sink(fr, b, w=csvw, acc=csv_cpu):
                    c = time.thread_time()
                    w(fr, b)
                    acc[0] += time.thread_time() - c

                run_replay(
                    pieces(),
                    li.profile,
                    vehicle,
                    backend,
                    sinks=(sink,),
                    output_frames=False,
                    read_ahead=True,  # as lde replay reads it
                )
                csvw.close()
                li.stream.close()
                total = time.process_time() - c0
                if k:
                    samples["total"].append(total)
                    samples["read"].append(read_cpu[0])
                    samples["csv"].append(csv_cpu[0])
                    samples["engine"].append(total - read_cpu[0] - csv_cpu[0])
                    samples["wall"].append(time.perf_counter() - w0)
            out[f"{label}_{backend}"] = {k: stats(v) for k, v in samples.items()}
    # the straightforward replay: 2 minutes of the log, scaled to the hour
    frames = read_log(log).frames
    part = frames.select(frames.t_ns < frames.t_ns[0] + 120 * 10**9)
    c0 = time.process_time()
    rows = naive_replay(part, profile, vehicle, tmp / "naive.csv")
    cpu = time.process_time() - c0
    out["naive_per_hour_cpu_s"] = cpu * len(frames) / len(part)
    out["naive_rows"] = rows
    return out


def bench_replay_cli(paths: dict[str, Path], repeat: int, tmp: Path) -> dict:
    """The command, end to end (start-up included): wall, CPU and peak RSS. The four variants take
    turns (one run each per round, after a warm-up of each), so that a change in the machine's load
    during the runs falls on all of them alike."""
    argvs = {
        f"{label}_{backend}": lde_cmd(
            "replay", str(path), "--backend", backend, "--csv", str(tmp / "cli.csv"), "-q"
        )
        for label, path in paths.items()
        for backend in ("fixed", "float")
    }
    for argv in argvs.values():
        run_child(argv)  # warm-up (page cache, numba cache)
    runs: dict[str, list[dict[str, Any]]] = {k: [] for k in argvs}
    for _ in range(repeat):
        for k, argv in argvs.items():
            runs[k].append(run_child(argv))
    return {k: {m: stats([r[m] for r in rs]) for m in ("wall", "cpu", "rss_mib")} for k, rs in runs.items()}


#: a warm start in phases (one child process): the imports of ``lde replay``, numba's first load
#: of a cached kernel (numba's registries and their BLAS check), the rest of the command (the other
#: kernels' loads, profile and vehicle, the replay of the sample log, the CSV)
_PHASES = (
    "import json, sys, time\n"
    "t0 = time.perf_counter()\n"
    "import lde.cli, lde.cli.replay, lde.replay.fleet, lde.replay.replay\n"
    "t1 = time.perf_counter()\n"
    "from lde.io.candump import parse_candump_bytes\n"
    "parse_candump_bytes(b'(1.000000) can0 2A0#0000000000000000\\n')\n"
    "t2 = time.perf_counter()\n"
    "rc = lde.cli.main(sys.argv[1:])\n"
    "t3 = time.perf_counter()\n"
    "print(json.dumps({'imports': t1 - t0, 'numba_first_load': t2 - t1, 'rest': t3 - t2, 'rc': rc}))\n"
)


def startup_phases(argv: list[str], repeat: int) -> dict[str, Any]:
    """:data:`_PHASES` ``repeat`` times (after a warm-up), and the bare interpreter's start."""
    runs = []
    for k in range(repeat + 1):
        out = subprocess.run(
            [sys.executable, "-c", _PHASES, *argv], capture_output=True, text=True, env=child_env()
        )
        r = json.loads(out.stdout.strip().splitlines()[-1])
        if r["rc"] != 0:
            raise RuntimeError(f"start-up phases: {' '.join(argv)} failed: {out.stderr[-500:]}")
        if k:
            runs.append(r)
    bare = [run_child([sys.executable, "-c", "pass"])["wall"] for _ in range(repeat)]
    res = {k: stats([r[k] for r in runs]) for k in ("imports", "numba_first_load", "rest")}
    res["python"] = stats(bare)
    return res


def bench_startup(repeat: int, cold: bool, tmp: Path) -> dict:
    """Warm: the command on the 20-second sample log (start-up + a few ms of replay), and the same in
    phases. Cold: the same on an empty numba cache: when the notice came and how long until the CSV
    was written."""
    args = ["replay", str(SAMPLE), "--csv", str(tmp / "s.csv"), "-q"]
    argv = lde_cmd(*args)
    out: dict[str, Any] = {"warm": child_stats(argv, repeat), "phases": startup_phases(args, repeat)}
    if cold:
        cache = tmp / "numba-cold"
        env = child_env(NUMBA_CACHE_DIR=str(cache), PYTHONDONTWRITEBYTECODE="1")
        _children_cpu()  # the baseline: the CPU of the children before this one (reaped already)
        t0 = time.perf_counter()
        proc = subprocess.Popen(
            lde_cmd("replay", str(SAMPLE), "--csv", str(tmp / "c.csv")),
            env=env,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert proc.stderr is not None
        first = proc.stderr.readline()
        t_notice = time.perf_counter() - t0
        proc.communicate()
        out["cold"] = {
            "notice_s": t_notice,
            "first_line": first.strip(),
            "result_s": time.perf_counter() - t0,
            "cpu_s": _children_cpu(),
        }
        shutil.rmtree(cache, ignore_errors=True)
    return out


_last_children = [0.0]


def _children_cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    total = u.ru_utime + u.ru_stime
    delta, _last_children[0] = total - _last_children[0], total
    return delta


def bench_sizes(log: Path, mcap: Path, tmp: Path) -> dict:
    frames = read_log(mcap).frames
    idx = tmp / "indexed.mcap"
    lz4 = tmp / "lz4.mcap"
    with McapWriter(idx, indexed=True) as w:
        w.write_frames(frames)
    with McapWriter(lz4, compression="lz4") as w:
        w.write_frames(frames)
    c = log.stat().st_size
    return {
        "candump_bytes": c,
        "compact_zstd_ratio": mcap.stat().st_size / c,
        "compact_lz4_ratio": lz4.stat().st_size / c,
        "indexed_zstd_ratio": idx.stat().st_size / c,
    }


def bench_fleet(n_logs: int, minutes: float, tmp: Path, repeat: int) -> dict:
    """``n_logs`` logs of ``minutes`` each: one ``lde replay LOG...`` after the other vs ``--jobs 2``."""
    d = tmp / "fleet"
    if not d.is_dir() or len(list(d.glob("*.log"))) != n_logs:
        shutil.rmtree(d, ignore_errors=True)
        write_logs(d, minutes / 60.0, seed=7, name="log000", formats=("log",))
        src = d / "log000.log"
        for i in range(1, n_logs):
            shutil.copyfile(src, d / f"log{i:03d}.log")
    logs = sorted(str(p) for p in d.glob("*.log"))
    seq = lde_cmd("replay", *logs, "--csv", str(tmp / "fleet_seq"), "-q")
    par = lde_cmd("replay", *logs, "--csv", str(tmp / "fleet_par"), "-q", "--jobs", "2")
    runs: dict[str, list[dict]] = {"sequential": [], "jobs2": []}
    for _ in range(repeat):
        runs["sequential"].append(run_child(seq))
        runs["jobs2"].append(run_child(par))
    out = {k: {m: stats([r[m] for r in v]) for m in ("wall", "cpu")} for k, v in runs.items()}
    out["speedup"] = out["sequential"]["wall"]["median"] / out["jobs2"]["wall"]["median"]
    out["logs"], out["minutes_each"] = n_logs, minutes
    return out


def bench_rss_scaling(one: dict[str, Path], ten: dict[str, Path], tmp: Path, repeat: int) -> dict:
    out = {}
    for label in one:
        for hours, paths in (("1h", one), ("10h", ten)):
            argv = lde_cmd("replay", str(paths[label]), "--csv", str(tmp / "rss.csv"), "-q")
            out[f"{label}_{hours}"] = child_stats(argv, repeat)
    return out


# ----------------------------------------------------------------------------- report
def machine() -> dict:
    cpu = ""
    with contextlib.suppress(OSError, StopIteration), open("/proc/cpuinfo") as fh:
        cpu = next(ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name"))
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "cpu": cpu,
        "cpus": os.cpu_count(),
        "lde": lde.__version__,
        "numpy": np.__version__,
        "numba": __import__("numba").__version__,
    }


def _ms(s: dict, scale: float = 1e3) -> str:
    return f"{s['median'] * scale:.0f} ({s['min'] * scale:.0f}-{s['max'] * scale:.0f})"


def _us(s: dict) -> str:
    return f"{s['median']:.3g} ({s['min']:.3g}-{s['max']:.3g})"


def table(r: dict) -> str:
    m = r["machine"]
    h = f"{r['hours']:g} h"
    lines = [
        f"Measured with `{r['command']}` on {m['cpus']} cores ({m['cpu']}), Python {m['python']}, "
        f"numba {m['numba']}; load average {r['load_before'][0]:.1f} before, {r['load_after'][0]:.1f} "
        f"after; {r['date']}. Medians with min-max; CPU = user + sys time.",
        "",
        "| what | lde | anchor | anchor is | lde faster by |",
        "|---|---|---|---|---|",
    ]

    def row(what: str, ours: dict, anchor: dict, name: str, unit: str) -> None:
        ratio = anchor["median"] / ours["median"] if ours["median"] else float("inf")
        lines.append(f"| {what} [{unit}] | {_us(ours)} | {_us(anchor)} | {name} | {ratio:.0f}x |")

    fp = "filterpy KalmanFilter predict+update"
    if "kalman" in r:
        k = r["kalman"]
        row("float estimator step", k["float_us_per_step"], k["filterpy_us_per_step"], fp, "us/step")
        if "lateral" in r:  # the default backend's steps, on the hour's real inputs
            la = r["lateral"]
            row(
                "lateral float step (`float`; `fixed`'s shadow)",
                la["float_us"],
                k["filterpy_us_per_step"],
                fp,
                "us/step",
            )
            row(
                "lateral integer step + boundary (`fixed`)",
                la["integer_us"],
                k["filterpy_us_per_step"],
                fp,
                "us/step",
            )
    for what, ours, anchor, name in (
        ("receiver: E2E check + decode to SI", "lde_decode", "cantools_decode", "cantools decode_message"),
        ("output encoder (counter, CRC)", "lde_encode", "cantools_encode", "cantools encode_message"),
        ("Profile 1 CRC check", "lde_crc_check", "autosar_e2e_check", "autosar-e2e e2e_p01_check"),
    ):
        if "codec" in r:
            c = r["codec"]
            row(what, c[f"{ours}_us_per_frame"], c[f"{anchor}_us_per_frame"], name, "us/frame")
    for what, ours, anchor, name in (
        ("candump reader", "lde_candump", "python_can_candump", "python-can CanutilsLogReader"),
        ("MCAP reader", "lde_mcap", "mcap_library", "mcap iter_messages"),
    ):
        if "readers" in r:
            d = r["readers"]
            row(what, d[f"{ours}_us_per_frame"], d[f"{anchor}_us_per_frame"], name, "us/frame")
    anchor = "cantools decode + numpy Kalman step per frame (2 min, scaled)"
    for key in ("candump_fixed", "mcap_fixed", "candump_float", "mcap_float"):
        if "inproc" not in r:
            break
        ip = r["inproc"]
        naive = ip["naive_per_hour_cpu_s"]
        s = ip[key]
        fmt, backend = key.split("_")
        parts = ", ".join(f"{n} {s[n]['median']:.2f}" for n in ("read", "engine", "csv"))
        ours = f"{s['total']['median']:.2f} ({parts}; wall {s['wall']['median']:.2f})"
        ratio = naive / s["total"]["median"]
        what = f"replay {h} in process, {fmt}, {backend} [s CPU]"
        lines.append(f"| {what} | {ours} | {naive:.0f} | {anchor} | {ratio:.0f}x |")
    lines += [
        "",
        "| the command `lde replay LOG --csv OUT` (start-up included) "
        "| wall [s] | CPU [s] | peak RSS [MiB] | target |",
        "|---|---|---|---|---|",
    ]
    targets = {"candump": "<= 2 s, <= 250 MiB", "mcap": "<= 1 s, <= 250 MiB"}

    def cli_row(what: str, s: dict, target: str) -> None:
        w = s["wall"]
        lines.append(
            f"| {what} | {w['median']:.2f} ({w['min']:.2f}-{w['max']:.2f}) | {s['cpu']['median']:.2f} | "
            f"{s['rss_mib']['median']:.0f} | {target} |"
        )

    for key, s in r.get("cli", {}).items():
        fmt, backend = key.split("_")
        cli_row(f"{h} {fmt}, {backend} backend", s, targets.get(fmt, ""))
    for key, s in r.get("rss", {}).items():
        cli_row(f"{key.replace('_', ' ')} (fixed backend)", s, "RSS flat: 10 h within 10 % of 1 h")
    st = r.get("startup", {})
    if "warm" in st:
        cli_row("warm start: the command on a 20 s log", st["warm"], "< 2 s to the first step")
    if "cold" in st:
        cs = st["cold"]
        lines.append(
            f"| cold start (empty numba cache): notice after {cs['notice_s']:.2f} s, CSV after | "
            f"{cs['result_s']:.1f} | {cs['cpu_s']:.1f} | | notice < 1 s, result < 15 s |"
        )
    if "phases" in st:
        ph = st["phases"]
        lines += [
            "",
            "Warm start in phases (wall, medians with min-max, one child process each): interpreter "
            f"{_ms(ph['python'])} ms, imports of `lde replay` {_ms(ph['imports'])} ms, numba's first "
            f"load of a cached kernel (its registries; numba's BLAS check without scipy.linalg) "
            f"{_ms(ph['numba_first_load'])} ms, the rest of the command (other kernels' loads, profile, "
            f"vehicle, the 20 s replay, CSV) {_ms(ph['rest'])} ms. Children run with Python's bytecode "
            "cache on, as an installed package.",
        ]
    if "sizes" in r:
        sz = r["sizes"]
        lines += [
            "",
            f"MCAP size / candump text of the same {h} ({sz['candump_bytes'] / 1e6:.0f} MB): compact zstd "
            f"{sz['compact_zstd_ratio']:.1%}, compact lz4 {sz['compact_lz4_ratio']:.1%}, indexed zstd "
            f"{sz['indexed_zstd_ratio']:.1%} (target <= 40 %).",
        ]
    if "fleet" in r:
        f = r["fleet"]
        lines.append(
            f"Fleet: {f['logs']} logs of {f['minutes_each']:g} min: one after the other "
            f"{f['sequential']['wall']['median']:.1f} s, `--jobs 2` {f['jobs2']['wall']['median']:.1f} s: "
            f"speed-up {f['speedup']:.2f}x (target >= 1.7x)."
        )
    return "\n".join(lines)


def update_readme(path: Path, text: str) -> None:
    s = path.read_text()
    if MARK_BEGIN not in s or MARK_END not in s:
        raise SystemExit(f"{path}: no {MARK_BEGIN} ... {MARK_END} markers")
    a, b = s.index(MARK_BEGIN) + len(MARK_BEGIN), s.index(MARK_END)
    path.write_text(s[:a] + "\n" + text + "\n" + s[b:])


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--data", type=Path, default=Path(tempfile.gettempdir()) / "lde-bench", help="log cache")
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results")
    ap.add_argument("--readme", type=Path, default=None)
    ap.add_argument("--ten-hours", action="store_true", help="peak RSS of a 10-hour log too")
    ap.add_argument("--cold", action="store_true", help="a first run on an empty numba cache too")
    ap.add_argument("--fleet", type=int, default=0, metavar="N", help="N logs: sequential vs --jobs 2")
    ap.add_argument("--fleet-minutes", type=float, default=10.0)
    ap.add_argument(
        "--only",
        default=None,
        metavar="PARTS",
        help="comma-separated subset while iterating: kalman, codec, readers, inproc, cli, startup, "
        "sizes (and rss / fleet with their options); not for the README",
    )
    args = ap.parse_args()
    r: dict[str, Any] = {
        "command": " ".join(["python", "bench/run_all.py", *sys.argv[1:]]),
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "load_before": os.getloadavg(),
    }
    print(json.dumps(r["machine"]), file=sys.stderr)
    args.data.mkdir(parents=True, exist_ok=True)
    one = _logs(args.data, args.hours, "hour")
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    rep = args.repeat
    r["hours"] = args.hours
    with tempfile.TemporaryDirectory(prefix="lde-bench-") as td:
        tmp = Path(td)
        frames = read_log(one["mcap"]).frames
        grid = build_grid(decode_batch(profile, frames), profile)
        steps = [
            ("kalman", lambda: bench_kalman(vehicle, grid, rep)),
            ("lateral", lambda: bench_lateral(one["log"], rep)),
            ("codec", lambda: bench_codec(profile, frames, rep)),
            ("readers", lambda: bench_readers(one["log"], one["mcap"], rep, tmp)),
            (
                "inproc",
                lambda: bench_replay_inproc(one["log"], one["mcap"], vehicle, profile, rep, tmp),
            ),
            ("cli", lambda: bench_replay_cli({"candump": one["log"], "mcap": one["mcap"]}, rep, tmp)),
            ("startup", lambda: bench_startup(rep, args.cold, tmp)),
            ("sizes", lambda: bench_sizes(one["log"], one["mcap"], tmp)),
        ]
        if args.ten_hours:
            ten = _logs(args.data, 10 * args.hours, "hour10")
            steps.append(("rss", lambda: bench_rss_scaling(one, ten, tmp, max(3, rep // 2))))
        if args.fleet:
            steps.append(
                (
                    "fleet",
                    lambda: bench_fleet(args.fleet, args.fleet_minutes, args.data, max(1, rep // 3)),
                )
            )
        if args.only:
            want = set(args.only.split(","))
            unknown = want - {name for name, _ in steps}
            if unknown:
                raise SystemExit(f"--only: unknown part(s) {', '.join(sorted(unknown))}")
            if args.readme is not None:
                raise SystemExit("--only with --readme: the README table is written from a full run")
            steps = [(name, fn) for name, fn in steps if name in want]
        for name, fn in steps:
            t0 = time.perf_counter()
            r[name] = fn()
            print(f"{name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
    r["load_after"] = os.getloadavg()
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "report.json").write_text(json.dumps(r, indent=1, default=float))
    text = table(r)
    (args.out / "report.md").write_text(text + "\n")
    print(text)
    if args.readme is not None:
        update_readme(args.readme, text)
    return 0


def _logs(d: Path, hours: float, name: str) -> dict[str, Path]:
    paths = {"log": d / f"{name}.log", "mcap": d / f"{name}.mcap"}
    if not all(p.exists() for p in paths.values()):
        t0 = time.perf_counter()
        write_logs(d, hours, seed=1, name=name)
        print(f"generated {name}: {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    return paths


if __name__ == "__main__":
    sys.exit(main())
