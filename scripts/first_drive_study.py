"""Research harness of the first drive and the light loads (docs/estimator.md, "The first drive").

Not the evaluation (``lde evaluate --zoo --first-drive`` is, through ``lde replay``): the same engine
in process on cached simulations (``$LDE_TUNE_CACHE``, :mod:`tune_zoo`), so that learner and filter
constants can be set per run (``--hook``, as :mod:`tune_zoo`). Sets:

- ``first``: the cold 10-minute ``first_drive``: NRMSE Fw / Mw from minute 2, per minute, RMS Fw per
  minute [N], when the learner reached "learned";
- ``light``: warm (after ``prior_drive``, seed + 500): ``light_crosswind``, ``light_bank``,
  ``straight`` (RMS of the estimate), ``light_crosswind_rough``, and ``light_crosswind`` with the
  rack friction set to 0.4 and 0.8 Nm at the column (prior drive with the same friction);
- ``heavy``: warm, the zoo's standard scenarios (heavy loads must not get worse).

    PYTHONPATH=src:scripts:. python scripts/first_drive_study.py --sets first,light --seeds 0,1 --out F.json
    PYTHONPATH=src:scripts:. python scripts/first_drive_study.py --report F.json [G.json ...]
"""

from __future__ import annotations

import argparse
import json
import math
import pickle
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit
from tune_zoo import CACHE, PRIOR_SEED_OFFSET, make_hook, map_runs, run_engine, spec_vehicle

TUNE = ("indep_twin", "tires_minus25", "suv_slow", "angle_above_tb")
LIGHT = ("light_crosswind", "light_bank", "straight", "light_crosswind_rough")
FRICTIONS = (0.4, 0.8)
KEEP = ("t", "Fw", "Mw", "Mw_ref", "Fy_wind", "Mz_wind", "F_bank", "bank", "vx", "delta_sw", "ay")


def simulated(plant: str, scenario: str, profile: str, seed: int, friction: float | None = None):
    """(frames, truth) of one zoo drive (the rack friction set to ``friction`` Nm), cached."""
    from lde.analysis.study.execute import check_plant, simulate_run
    from lde.analysis.study.spec import SPEC_SHEET, RunSpec, SimOptions

    CACHE.mkdir(parents=True, exist_ok=True)
    tag = "" if friction is None else f"__f{friction:g}"
    path = CACHE / f"{plant}__{scenario}__{profile}__{seed}{tag}.pkl"
    if path.exists():
        with path.open("rb") as fh:
            return pickle.load(fh)
    so = SimOptions() if friction is None else SimOptions(friction_Nm=friction)
    spec = RunSpec(
        scenario=scenario,
        est_vehicle=SPEC_SHEET,
        sim_vehicle=f"zoo:{plant}",
        seed=seed,
        profile=profile,
        sim_options=so,
    )
    sim = simulate_run(spec, scenario, seed)
    try:
        check_plant(sim.truth)
        ok = True
    except Exception:
        ok = False
    truth = {k: np.asarray(sim.truth[k]) for k in KEEP if k in sim.truth}
    truth["ok"] = np.array(ok)
    data = (sim.frames, truth)
    tmp = path.with_suffix(f".{time.time_ns()}.tmp")
    with tmp.open("wb") as fh:
        pickle.dump(data, fh)
    tmp.replace(path)
    return data


def _truth(truth: dict[str, np.ndarray]):
    from lde.analysis import metrics

    return metrics.Truth(
        t=truth["t"], fw=truth["Fw"], mw=truth["Mw"], mw_ref=truth["Mw_ref"], fw_wind=truth["Fy_wind"],
        bank=truth["bank"],
    )  # fmt: skip


SMOOTH: tuple[float, ...] = ()


@njit(cache=True)
def _adaptive_lp(x, dt, tau, c, s0, tau_s):  # pragma: no cover - compiled
    """y follows x with time constant tau / (1 + (d / (c s))^2), d = x - y; s: a robust running RMS
    of d (its square clipped at (3 s)^2, time constant tau_s), starting at s0."""
    y = np.empty_like(x)
    yy = x[0]
    s2 = s0 * s0
    for k in range(x.shape[0]):
        d = x[k] - yy
        s2 += dt / tau_s * (min(d * d, 9.0 * s2) - s2)
        r = d * d / (c * c * s2)
        a = min(1.0, dt * (1.0 + r) / tau)
        yy += a * d
        y[k] = yy
    return y


@njit(cache=True)
def _one_euro(xs, dt, fmin, beta, fd):  # pragma: no cover - compiled
    """One-euro filter over the columns of xs (n, k) with one cutoff from the derivative of their
    sum: cutoff = fmin + beta |d sum/dt| (the derivative low-passed at fd Hz)."""
    n, k = xs.shape
    y = np.empty_like(xs)
    yy = xs[0].copy()
    prev = 0.0
    for j in range(k):
        prev += xs[0, j]
    dd = 0.0
    ad = 1.0 / (1.0 + 1.0 / (2.0 * np.pi * fd * dt))
    for i in range(n):
        tot = 0.0
        for j in range(k):
            tot += xs[i, j]
        d = (tot - prev) / dt
        prev = tot
        dd += ad * (d - dd)
        fc = fmin + beta * abs(dd)
        a = 1.0 / (1.0 + 1.0 / (2.0 * np.pi * fc * dt))
        for j in range(k):
            yy[j] += a * (xs[i, j] - yy[j])
            y[i, j] = yy[j]
    return y


@njit(cache=True)
def _tracker(x, dt, sigma, qj, k):  # pragma: no cover - compiled
    """Level + slope Kalman tracker of the filter's output x (noise sigma, jerk-free random walk of
    the slope with density qj); an innovation beyond k sqrt(S) opens the level's variance to it."""
    n = x.shape[0]
    y = np.empty_like(x)
    lv, sl = x[0], 0.0
    p00, p01, p11 = sigma * sigma, 0.0, 0.0
    r = sigma * sigma
    for i in range(n):
        # predict
        lv += sl * dt
        p00 += dt * (2.0 * p01 + dt * p11) + qj * dt**3 / 3.0
        p01 += dt * p11 + qj * dt * dt / 2.0
        p11 += qj * dt
        e = x[i] - lv
        s = p00 + r
        if e * e > k * k * s:
            p00 += e * e
            p11 += (e / 0.2) ** 2
            s = p00 + r
        k0 = p00 / s
        k1 = p01 / s
        lv += k0 * e
        sl += k1 * e
        p11 -= k1 * p01
        p01 -= k0 * p01 * 0.0 + k1 * p00
        p00 -= k0 * p00
        y[i] = lv
    return y


def smoothed(block: Any) -> tuple[np.ndarray, np.ndarray]:
    """(Fw, Mw) of a block through the prototype output filter (SMOOTH = fmin, betaF, betaM, fd)."""
    if not SMOOTH:
        return np.asarray(block.fw), np.asarray(block.mw)
    sf, sm, qf, qm, k = SMOOTH
    dt = 0.0039
    f = _tracker(np.asarray(block.fw, np.float64), dt, sf, qf, k)
    m = _tracker(np.asarray(block.mw, np.float64), dt, sm, qm, k)
    return f, m


def score_short(block: Any, truth: dict[str, np.ndarray], scenario: str) -> dict[str, float]:
    from lde.analysis import metrics
    from lde.analysis.study.execute import scenario_kind
    from lde.status import VALID

    t = block.t_ns * 1e-9
    valid = (block.status & int(VALID)) != 0
    fw, mw = smoothed(block)
    acc = metrics.accuracy(t, fw, mw, _truth(truth), valid=valid, kind=scenario_kind(scenario))
    f, m = metrics.target_figures(acc)
    return {"fw": f, "mw": m, "undist": float(acc.kind is metrics.Kind.UNDISTURBED), "rms_fw": acc.rms_fw}


def score_long(block: Any, truth: dict[str, np.ndarray]) -> dict[str, Any]:
    from lde.analysis import metrics
    from lde.status import VALID

    t = block.t_ns * 1e-9
    valid = (block.status & int(VALID)) != 0
    fw, mw = smoothed(block)
    ld = metrics.long_drive(
        t, fw, mw, _truth(truth), valid=valid, learn_state=np.asarray(block.learn_state)
    )
    f, m = metrics.target_figures(ld.scored)
    out: dict[str, Any] = {"fw": f, "mw": m, "undist": 0.0, "learned_s": ld.learned_s}
    out["min_fw"] = [metrics.target_figures(w)[0] if w else math.nan for w in ld.windows]
    out["min_mw"] = [metrics.target_figures(w)[1] if w else math.nan for w in ld.windows]
    out["min_rms_fw"] = [w.rms_fw if w else math.nan for w in ld.windows]
    out["min_rms_mw"] = [w.rms_mw_ref if w else math.nan for w in ld.windows]
    out["min_max_fw"] = [w.scale_fw if w else math.nan for w in ld.windows]
    return out


def learned_summary(info: dict[str, Any]) -> dict[str, float]:
    from lde.estimator import lateral as E
    from lde.estimator import learner as Ln

    p, ls = info["p"], info["learner"]
    return {
        "Cf": p[E.P_CF], "Cr": p[E.P_CR], "K": p[E.P_K], "s": p[E.P_S], "Tf": p[E.P_TFRIC],
        "ctb": math.degrees(p[E.P_CTB]), "st": ls[Ln.LS_STATE], "n3": ls[Ln.LS_N + 1],
    }  # fmt: skip


def one(args: tuple) -> list[dict[str, Any]]:
    global SMOOTH
    plant, profile, seed, sets, hook_name, smooth = args
    SMOOTH = smooth
    hook = make_hook(hook_name)
    vehicle = spec_vehicle(plant)
    rows: list[dict[str, Any]] = []
    base = {"plant": plant, "profile": profile, "seed": seed}
    if "first" in sets:
        frames, truth = simulated(plant, "first_drive", profile, seed)
        if bool(truth["ok"]):
            block, info = run_engine(frames, profile, vehicle, None, None, hook)
            rows.append({**base, "set": "first", "scenario": "first_drive", **score_long(block, truth)}
                        | learned_summary(info))  # fmt: skip
        else:
            rows.append({**base, "set": "first", "scenario": "first_drive", "lost": 1.0})
    runs: list[tuple[str, str, float | None]] = []
    if "light" in sets:
        runs += [("light", sc, None) for sc in LIGHT]
        runs += [("friction", "light_crosswind", f) for f in FRICTIONS]
    if "heavy" in sets:
        from lde.analysis.study.zoo import ZOO_SCENARIOS

        runs += [("heavy", sc, None) for sc in ZOO_SCENARIOS]
    learned: dict[float | None, Path] = {}
    for set_name, sc, fr in runs:
        if fr not in learned:
            pf, _ = simulated(plant, "prior_drive", profile, seed + PRIOR_SEED_OFFSET, fr)
            learned[fr] = Path(tempfile.mkdtemp(prefix="lde-fd-")) / "learned.json"
            run_engine(pf, profile, vehicle, None, learned[fr], hook)
        frames, truth = simulated(plant, sc, profile, seed, fr)
        row = {**base, "set": set_name, "scenario": sc, "friction": fr}
        if not bool(truth["ok"]):
            rows.append({**row, "lost": 1.0})
            continue
        block, info = run_engine(frames, profile, vehicle, learned[fr], None, hook)
        rows.append({**row, **score_short(block, truth, sc)} | learned_summary(info))
    return rows


# ------------------------------------------------------------------------------------- report


def _m(xs: Sequence[float]) -> float:
    v = [x for x in xs if math.isfinite(x)]
    return float(np.mean(v)) if v else math.nan


def _rng(xs: Sequence[float], pct: bool = True) -> str:
    v = [x for x in xs if math.isfinite(x)]
    if not v:
        return "-"
    k = 100.0 if pct else 1.0
    return f"{k * min(v):.1f}-{k * max(v):.1f}"


def report(rows: list[dict[str, Any]]) -> None:
    ok = [r for r in rows if not r.get("lost")]
    lost = [r for r in rows if r.get("lost")]
    for group, sel in (("tuning", lambda r: r["plant"] in TUNE), ("held out", lambda r: r["plant"] not in TUNE)):
        rs = [r for r in ok if sel(r)]
        if not rs:
            continue
        print(f"== {group} plants ({', '.join(sorted({r['plant'] for r in rs}))})")
        for prof in ("lde", "hyundai"):
            pr = [r for r in rs if r["profile"] == prof]
            fd = [r for r in pr if r["set"] == "first"]
            if fd:
                lmax = [r["learned_s"] for r in fd]
                worst_min_f = [max(x for x in r["min_fw"][1:] if math.isfinite(x)) for r in fd]
                worst_min_m = [max(x for x in r["min_mw"][1:] if math.isfinite(x)) for r in fd]
                print(
                    f"  {prof:7s} first drive: min2+ Fw {_rng([r['fw'] for r in fd])} % (mean "
                    f"{100 * _m([r['fw'] for r in fd]):.2f}), Mw {_rng([r['mw'] for r in fd])} % (mean "
                    f"{100 * _m([r['mw'] for r in fd]):.2f}); worst minute 2-10 Fw {_rng(worst_min_f)} %, "
                    f"Mw {_rng(worst_min_m)} %; learned at {_rng(lmax, False)} s "
                    f"(never: {sum(not math.isfinite(x) for x in lmax)}/{len(lmax)})"
                )
            for sc in LIGHT:
                li = [r for r in pr if r["set"] == "light" and r["scenario"] == sc]
                if li:
                    if li[0]["undist"]:
                        print(f"  {prof:7s} {sc:22s} RMS {_rng([r['fw'] for r in li], False)} N / "
                              f"{_rng([r['mw'] for r in li], False)} Nm")  # fmt: skip
                    else:
                        print(f"  {prof:7s} {sc:22s} Fw {_rng([r['fw'] for r in li])} % (mean "
                              f"{100 * _m([r['fw'] for r in li]):.2f}) / Mw {_rng([r['mw'] for r in li])} % "
                              f"(mean {100 * _m([r['mw'] for r in li]):.2f})")  # fmt: skip
            for fr in FRICTIONS:
                li = [r for r in pr if r["set"] == "friction" and r["friction"] == fr]
                if li:
                    print(f"  {prof:7s} friction {fr:g} Nm, light wind Fw {_rng([r['fw'] for r in li])} % "
                          f"(mean {100 * _m([r['fw'] for r in li]):.2f}) / Mw {_rng([r['mw'] for r in li])} %")  # fmt: skip
            hv = [r for r in pr if r["set"] == "heavy" and not r["undist"]]
            if hv:
                print(f"  {prof:7s} heavy (zoo, warm): mean Fw {100 * _m([r['fw'] for r in hv]):.2f} / Mw "
                      f"{100 * _m([r['mw'] for r in hv]):.2f} %, <=5 %: "
                      f"{sum(max(r['fw'], r['mw']) <= 0.05 for r in hv)}/{len(hv)}")  # fmt: skip
    if lost:
        print(f"lost (the simulated driver lost control): {len(lost)}: "
              + ", ".join(f"{r['plant']}/{r['profile']}/{r['scenario']}/s{r['seed']}" for r in lost[:8]))  # fmt: skip


def per_minute(rows: list[dict[str, Any]]) -> None:
    """Per plant x profile x seed: minute-by-minute NRMSE Fw / Mw %, RMS Fw [N], learned at."""
    for r in rows:
        if r.get("set") != "first" or r.get("lost"):
            continue
        f = " ".join(f"{100 * x:4.1f}" for x in r["min_fw"])
        m = " ".join(f"{100 * x:4.1f}" for x in r["min_mw"])
        n = " ".join(f"{x:4.0f}" for x in r["min_rms_fw"])
        print(f"{r['plant'][:14]:14s} {r['profile'][:3]} s{r['seed']} learned {r['learned_s']:5.0f} s | "
              f"Fw% {f} | Mw% {m} | RMS N {n}")  # fmt: skip


def main(argv: Sequence[str] | None = None) -> None:
    from lde.analysis.study.zoo import plants

    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default=",".join(plants()))
    ap.add_argument("--profiles", default="lde,hyundai")
    ap.add_argument("--seeds", default="0,1")
    ap.add_argument("--sets", default="first,light")
    ap.add_argument("--hook", default="")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--smooth", default="", help="prototype output filter: tau,c,sF,sM,tau_s")
    ap.add_argument("--out", default="")
    ap.add_argument("--report", nargs="*", help="print the report of --out files instead of running")
    ap.add_argument("--minutes", action="store_true", help="also the per-minute lines")
    a = ap.parse_args(argv)
    if a.report:
        for path in a.report:
            rows = json.loads(Path(path).read_text())
            print(f"# {path}")
            report(rows)
            if a.minutes:
                per_minute(rows)
        return
    sets = tuple(a.sets.split(","))
    tasks = [
        (pl, pr, int(s), sets, a.hook, tuple(float(v) for v in a.smooth.split(",")) if a.smooth else ())
        for s in a.seeds.split(",")
        for pl in a.plants.split(",")
        for pr in a.profiles.split(",")
    ]
    t0 = time.time()
    rows = map_runs(one, tasks, a.jobs)
    report(rows)
    if a.minutes:
        per_minute(rows)
    print(f"{len(rows)} runs in {time.time() - t0:.0f} s")
    if a.out:
        Path(a.out).write_text(json.dumps(rows, default=float))


if __name__ == "__main__":
    main()
