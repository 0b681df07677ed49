"""``lde replay --smooth`` on one hour of traffic (923 k steps): the causal replay before (main's
``src``, exported with ``git archive``) and after this change, the smoothed replay (wall, CPU, peak
RSS of the whole command), and the backward pass alone against filterpy's ``rts_smoother`` on the
same trace (filterpy without the input term: speed only; it holds every step's F, Q, x, P in memory).

    PYTHONPATH=src:. python bench/bench_smoother.py --hours 1 --repeat 3 [--base-ref main] [--out F.json]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from run_all import child_stats, lde_cmd  # noqa: E402
from traffic import write_logs  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def filterpy_vs_numba(log: Path, limit: int | None) -> dict:
    from filterpy.kalman import KalmanFilter

    from lde.can.profiles import load_profile
    from lde.io import open_log
    from lde.params import load_vehicle
    from lde.replay import smoother as S

    spill = S.TraceSpill()
    try:
        eng = S.TracingEngine(load_profile("lde"), load_vehicle("reference"), spill)
        with open_log(log) as stream:
            for piece in stream:
                eng.feed(piece)
        eng.finish()
        spill.finish()
        tr = spill.read(0, spill.n)
    finally:
        spill.remove()
    n = len(tr) if limit is None else min(limit, len(tr))
    tr = tr[:n]
    ox, op, of = np.empty((n, 5)), np.empty((n, 5)), np.empty((n, 5))
    S.rts_backward(tr[:10], np.zeros(5), np.zeros((5, 5)), np.zeros(1, np.int64), ox, op, of)  # compiled
    t0 = time.perf_counter()
    S.rts_backward(tr, np.zeros(5), np.zeros((5, 5)), np.zeros(1, np.int64), ox, op, of)
    t_numba = time.perf_counter() - t0
    # filterpy's inputs: filtered x, P and Fs[k+1] = Phi_k, Qs (the input term left out)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    Fs = np.tile(np.eye(5), (n, 1, 1))
    f = tr[:, S.T_F : S.T_F + 7]
    Fs[1:, 0, 0], Fs[1:, 0, 1], Fs[1:, 0, 2], Fs[1:, 0, 4] = f[:-1, 0], f[:-1, 1], f[:-1, 2], f[:-1, 3]
    Fs[1:, 1, 0], Fs[1:, 1, 1], Fs[1:, 1, 3] = f[:-1, 4], f[:-1, 5], f[:-1, 6]
    held = np.flatnonzero(tr[:-1, S.T_PROP] == 0.0) + 1
    Fs[held] = np.eye(5)  # a held step: no transition
    Qs = np.zeros((n, 5, 5))
    Qs[:, range(5), range(5)] = tr[:, S.T_Q : S.T_Q + 5]
    Ps = np.zeros((n, 5, 5))
    iu = np.triu_indices(5)
    Ps[:, iu[0], iu[1]] = tr[:, S.T_P : S.T_P + 15]
    Ps = Ps + np.triu(Ps, 1).transpose(0, 2, 1) + np.eye(5) * 1e-9  # any SPD values: timing only
    Xs = of.reshape(n, 5, 1).copy()
    t0 = time.perf_counter()
    KalmanFilter(dim_x=5, dim_z=1).rts_smoother(Xs, Ps, Fs, Qs)
    t_fp = time.perf_counter() - t0
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "steps": n,
        "numba_backward_s": t_numba,
        "filterpy_rts_smoother_s": t_fp,
        "filterpy_extra_peak_rss_mib": (rss1 - rss0) / 1024,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--base-ref", default="main", help="git ref of the causal replay 'before'")
    ap.add_argument("--filterpy-steps", type=int, default=None, help="filterpy on the first N steps only")
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="lde-bench-smooth-"))
    log = write_logs(tmp, a.hours, formats=("log",))["log"]
    base = tmp / "base"
    base.mkdir()
    arch = subprocess.run(
        ["git", "-C", str(ROOT), "archive", a.base_ref, "src", "dbc", "firmware_model", "vcan_sim"],
        capture_output=True,
        check=True,
    )
    subprocess.run(["tar", "-x", "-C", str(base)], input=arch.stdout, check=True)
    env_base = dict(os.environ, PYTHONPATH=f"{base / 'src'}:{base}")
    env_new = dict(os.environ, PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    csv = str(tmp / "o.csv")
    r: dict = {"hours": a.hours, "load_before": os.getloadavg()[0]}
    cmd = lde_cmd("replay", str(log), "--backend", "float", "--csv", csv, "-q")
    # interleaved: before / after / smoothed, each a median of `repeat`
    r["causal_before"] = child_stats(cmd, a.repeat, env_base)
    r["causal_after"] = child_stats(cmd, a.repeat, env_new)
    r["smooth_float"] = child_stats([*cmd, "--smooth"], a.repeat, env_new)
    r["smooth_fixed"] = child_stats(
        lde_cmd("replay", str(log), "--csv", csv, "-q", "--smooth"), a.repeat, env_new
    )
    if a.out:
        a.out.write_text(json.dumps(r, indent=1))
    r["backward"] = filterpy_vs_numba(log, a.filterpy_steps)
    r["load_after"] = os.getloadavg()[0]
    text = json.dumps(r, indent=1)
    print(text)
    if a.out:
        a.out.write_text(text)
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
