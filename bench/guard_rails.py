"""Guard rails: two commits of lde measured side by side in one run.

    python bench/guard_rails.py [--base c4b2db1] [--head HEAD] [--repeat 3] [--quick] [--tests]

Each commit is checked out into a temporary worktree (``git worktree add --detach``) and installed
into a fresh venv of its own with ``pip install '.[test]'``, not editable: what a user installs, with
the package data, the ``.pyc`` files compiled at install and numba's cache beside the installed
sources (pip's download cache is reused). Every lde child runs with an ``XDG_CACHE_HOME`` and a
``TMPDIR`` of its commit's own (lde's parsed-profile cache, numba's fallback cache, scratch files),
a shared ``MPLCONFIGDIR`` (matplotlib's font cache, built at setup) and after ``lde warmup``. Then
base and head take turns (base, head, base, head, ...: a change in the machine's load falls on both):

1. ``lde replay`` of one hour: candump to CSV, MCAP to CSV, candump to CSV and MCAP. Wall time, CPU
   time (user + sys of the child, from ``wait4``) and peak RSS; one warm-up run each, then the median
   and min-max of ``--repeat`` runs. The hour is written once by the base's ``bench/traffic.py``, as
   ``bench/run_all.py`` makes it (the lde profile's two input messages at ~100 km/h, E2E protected;
   its MCAP holds the frames only, where ``lde sim --mcap`` adds the truth as JSON: five times the
   size of the candump text). The two commits' CSVs of the hour are compared too.
2. The hot live step without a bus: each commit's own ``bench/bench_service_step.py --json``, p50 and
   p99 of its back-to-back steps; the median over the runs.
3. The first ``lde demo`` on an empty cache: ``NUMBA_CACHE_DIR`` and ``XDG_CACHE_HOME`` fresh and
   empty (numba caches in ``NUMBA_CACHE_DIR`` alone when it is set); then ``lde warmup`` into that
   cache; then ``lde demo`` again. ``--cold-repeat`` rounds, each from an empty cache.
4. The vehicle zoo, as ``lde evaluate --zoo`` runs it: each plant x scenario x profile simulated once
   by the base's ``lde sim`` (seed 0; the warm runs' prior drive with seed 500) and replayed by each
   commit's ``lde replay`` with the plant's spec-sheet vehicle file (written by the base's ``lde
   evaluate --zoo``), for both backends: cold (one ``lde replay LOG... --csv DIR`` per plant x profile
   x backend) and warm (``lde replay PRIOR --learned F`` once, then each drive from a copy of F). The
   CSVs are compared in their shared columns, each difference listed (column, max |diff|, where).
   ``--quick``: 2 plants x 2 scenarios; else every plant and scenario.
5. ``--tests``: each commit's test suite on its worktree's sources (pass/fail counts, time).

Writes ``bench/results/guard_rails.md`` (the table, the machine, the commits, the command, every
difference and failure) and ``guard_rails.json`` (every sample); exit status 1 when a limit is missed
or a command failed. A failing child is reported with the tail of its stderr. On a shared machine
the figures are noisy: read the ratios, both sides having been measured in the same minutes.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path(__file__).resolve().parent / "results"
SIDES = ("base", "head")
PARTS = ("replay", "step", "cold", "zoo", "tests")
#: the zoo evaluation's scenarios (``lde.study.zoo.ZOO_SCENARIOS``), its prior drive and seed offset
ZOO_SCENARIOS: tuple[str, ...] = ("wind_step", "gusty_wind", "bank_transition", "heavy_load", "light_load")
ZOO_SCENARIOS += ("slalom", "curve_800m", "speed_ramp", "rough_driver", "lane_change")
PRIOR_SCENARIO, PRIOR_SEED = "prior_drive", 500
QUICK_PLANTS, QUICK_SCENARIOS = ("angle_above_tb", "loaded_twin"), ("wind_step", "slalom")
ZOO_PROFILES, ZOO_BACKENDS = ("lde", "hyundai"), ("fixed", "float")


def log(msg: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- children
@dataclass
class Run:
    """One child process: exit status, wall [s], CPU (user + sys) [s], peak RSS [MiB], output."""

    argv: list[str]
    rc: int
    wall: float
    cpu: float
    rss_mib: float
    stdout: str
    stderr: str

    def error(self) -> str:
        tail = "\n".join(self.stderr.strip().splitlines()[-12:])
        return f"`{' '.join(self.argv)}` exited with {self.rc}:\n{tail}"


class Failed(Exception):
    """A child that failed (its command and stderr tail)."""


def run(argv: list[str], env: dict[str, str] | None = None, cwd: Path | None = None, timeout=3600.0) -> Run:
    """``argv`` as a child; its own CPU time and peak RSS from ``wait4`` (not the other children's)."""
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        try:
            p = subprocess.Popen(argv, stdout=out, stderr=err, env=env, cwd=cwd)
        except OSError as e:
            return Run(argv, 127, 0.0, 0.0, 0.0, "", str(e))
        timer = threading.Timer(timeout, p.kill)
        timer.start()
        _, status, ru = os.wait4(p.pid, 0)
        timer.cancel()
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        text = [f.read().decode(errors="replace") for f in (out, err)]
    return Run(argv, p.returncode, wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024, *text)


def check(r: Run) -> Run:
    if r.rc != 0:
        raise Failed(r.error())
    return r


@dataclass
class Side:
    """One commit: its worktree, venv and the environment of its lde children."""

    name: str
    ref: str
    sha: str
    subject: str
    tree: Path
    venv: Path
    env: dict[str, str]

    def lde(self, *args: str) -> list[str]:
        return [str(self.venv / "bin" / "lde"), *args]

    def python(self, *args: str) -> list[str]:
        return [str(self.venv / "bin" / "python"), *args]


def git(*args: str) -> str:
    return check(run(["git", "-C", str(ROOT), *args])).stdout.strip()


def prepare(name: str, ref: str, work: Path, mpl: Path) -> Side:
    """Worktree, fresh venv, non-editable install, matplotlib's font cache."""
    sha = git("rev-parse", "--verify", f"{ref}^{{commit}}")
    subject = git("log", "-1", "--format=%s", sha)
    subject = subject if len(subject) <= 72 else subject[:70] + " ..."
    d = work / name
    tree, venv, ready = d / "tree", d / "venv", d / "ready"
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", "NUMBA_CACHE_DIR")}
    env_lde = dict(env, XDG_CACHE_HOME=str(d / "cache"), MPLCONFIGDIR=str(mpl), TMPDIR=str(d / "tmp"))
    side = Side(name, ref, sha, subject, tree, venv, env_lde)
    if ready.is_file() and ready.read_text() == sha:
        log(f"{name}: {ref} = {sha[:9]}: reusing {d} (--work)")
        (d / "tmp").mkdir(exist_ok=True)
        return side
    log(f"{name}: {ref} = {sha[:9]}: worktree, fresh venv, pip install '.[test]' (non-editable)")
    shutil.rmtree(d, ignore_errors=True)
    git("worktree", "prune")
    git("worktree", "add", "--detach", str(tree), sha)
    check(run([sys.executable, "-m", "venv", str(venv)]))
    check(run(side.python("-m", "pip", "install", "-q", ".[test]"), env=env, cwd=tree))
    (d / "cache").mkdir()
    (d / "tmp").mkdir()
    check(run(side.python("-c", "import matplotlib.font_manager"), env=env_lde))
    ready.write_text(sha)
    return side


# ----------------------------------------------------------------------------- rows
def stats(xs: list[float]) -> dict[str, Any]:
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "samples": xs}


def row(
    metric: str, unit: str, samples: dict[str, list[float]], errors: dict[str, str], limit: str = ""
) -> dict:
    """A table row: per side stats (or its error), the ratio head/base and the limit's verdict.
    ``limit``: ``<= 1.5x`` (ratio), ``< 5`` (the head's median, in ``unit``) or empty."""
    r: dict[str, Any] = {"metric": metric, "unit": unit, "limit": limit, "ok": None, "ratio": None}
    for s in SIDES:
        r[s] = {"error": errors[s]} if s in errors else stats(samples[s]) if samples.get(s) else None
    b, h = r["base"], r["head"]
    if b and h and "median" in b and "median" in h:
        r["ratio"] = h["median"] / b["median"] if b["median"] else None
        if limit.startswith("<= ") and r["ratio"] is not None:
            r["ok"] = r["ratio"] <= float(limit[3:-1])
        elif limit.startswith("< "):
            r["ok"] = h["median"] < float(limit[2:])
    elif limit:
        r["ok"] = False
    return r


def turns(sides: dict[str, Side], job: Callable[[Side], Run], repeat: int, warm_up: bool = True) -> tuple:
    """``job`` for base and head in turns (one warm-up each first): the runs and the errors by side."""
    runs: dict[str, list[Run]] = {s: [] for s in SIDES}
    errors: dict[str, str] = {}
    for k in range(repeat + warm_up):
        for s in SIDES:
            if s in errors:
                continue
            r = job(sides[s])
            if r.rc != 0:
                errors[s] = r.error()
            elif k >= warm_up:
                runs[s].append(r)
    return runs, errors


# ----------------------------------------------------------------------------- 1. replay
def bench_replay(sides: dict[str, Side], work: Path, repeat: int) -> tuple[list[dict], dict]:
    base, hour = sides["base"], work / "hour"
    log("the hour: base's bench/traffic.py --hours 1 (as bench/run_all.py makes it; candump and MCAP)")
    gen = base.python(
        str(base.tree / "bench" / "traffic.py"), "--hours", "1", "--out", str(hour), "--name", "hour"
    )
    check(run(gen, env=base.env, cwd=work))
    variants = {  # label: the log, and whether an MCAP recording is written too
        "candump -> CSV": ("hour.log", False),
        "MCAP -> CSV": ("hour.mcap", False),
        "candump -> CSV + MCAP": ("hour.log", True),
    }
    rows, csvs = [], {}
    for i, (label, (src, mcap)) in enumerate(variants.items()):

        def job(side: Side, src=src, mcap=mcap, i=i) -> Run:
            out = work / side.name / "replay"
            out.mkdir(exist_ok=True)
            argv = side.lde("replay", str(hour / src), "--csv", str(out / f"hour{i}.csv"), "-q")
            return run(argv + (["--mcap", str(out / "hour.mcap")] if mcap else []), side.env, out)

        log(f"replay of the hour, {label}: {repeat} x base/head after a warm-up each")
        runs, errors = turns(sides, job, repeat)
        for m, name, unit, lim in (
            ("wall", "wall", "s", "<= 1.5x"),
            ("cpu", "CPU", "s", "<= 1.5x"),
            ("rss_mib", "peak RSS", "MiB", "<= 1.1x"),
        ):
            samples = {s: [getattr(r, m) for r in runs[s]] for s in SIDES}
            rows.append(row(f"replay 1 h, {label}: {name}", unit, samples, errors, lim))
        a, b = (work / s / "replay" / f"hour{i}.csv" for s in SIDES)
        ok = not errors and a.is_file() and b.is_file()
        csvs[f"replay 1 h, {label}"] = compare_csv(a, b) if ok else {"error": "a replay failed (see below)"}
    return rows, csvs


# ----------------------------------------------------------------------------- 2. live step
def bench_step(sides: dict[str, Side], repeat: int) -> list[dict]:
    def job(side: Side) -> Run:
        return run(side.python(str(side.tree / "bench" / "bench_service_step.py"), "--json"), env=side.env)

    log(f"live step without a bus (bench/bench_service_step.py --json): {repeat} x base/head after a warm-up")
    runs, errors = turns(sides, job, repeat)
    samples: dict[str, dict[str, list[float]]] = {"p50": {}, "p99": {}}
    for s in SIDES:
        for r in runs[s]:
            try:
                hot = json.loads(r.stdout.strip().splitlines()[-1])["hot"]
                for q in samples:
                    samples[q].setdefault(s, []).append(float(hot[f"step_cost_{q}_us"]))
            except (ValueError, KeyError, IndexError, TypeError):
                errors[s] = f"unexpected output of bench_service_step.py: {r.stdout[-300:]!r}"
    return [row(f"live step, hot, {q}", "us", samples[q], errors, "<= 1.5x") for q in samples]


# ----------------------------------------------------------------------------- 3. first run
def bench_cold(sides: dict[str, Side], work: Path, repeat: int) -> list[dict]:
    """``lde demo`` on an empty cache, ``lde warmup``, ``lde demo``: ``repeat`` rounds, base and head
    in turns in each phase."""
    samples: dict[str, dict[str, list[float]]] = {
        k + cpu: {s: [] for s in SIDES} for k in ("first", "warmup", "again") for cpu in ("", " CPU")
    }
    errors: dict[str, str] = {}
    for k in range(repeat):
        envs, dirs = {}, {}
        for s in SIDES:
            d = work / s / f"cold{k}"
            for sub in ("numba", "xdg", "cwd"):
                (d / sub).mkdir(parents=True)
            envs[s] = dict(sides[s].env, NUMBA_CACHE_DIR=str(d / "numba"), XDG_CACHE_HOME=str(d / "xdg"))
            dirs[s] = d / "cwd"
        for phase, args in (("first", ("demo",)), ("warmup", ("warmup",)), ("again", ("demo",))):
            for s in SIDES:
                if s in errors:
                    continue
                log(f"round {k + 1}/{repeat}: {s}: lde {' '.join(args)} ({phase})")
                r = run(sides[s].lde(*args), env=envs[s], cwd=dirs[s])
                if r.rc != 0:
                    errors[s] = r.error()
                    continue
                samples[phase][s].append(r.wall)
                samples[f"{phase} CPU"][s].append(r.cpu)
        for s in SIDES:
            shutil.rmtree(work / s / f"cold{k}", ignore_errors=True)
    return [
        row("first lde demo, empty cache: wall", "s", samples["first"], errors, "<= 1.5x"),
        row("first lde demo, empty cache: CPU", "s", samples["first CPU"], errors),
        row("lde warmup after it: wall", "s", samples["warmup"], errors),
        row("lde warmup after it: CPU", "s", samples["warmup CPU"], errors),
        row("lde demo after lde warmup: wall", "s", samples["again"], errors, "< 5"),
        row("lde demo after lde warmup: CPU", "s", samples["again CPU"], errors),
    ]


# ----------------------------------------------------------------------------- 4. the zoo
def compare_csv(a: Path, b: Path) -> dict[str, Any]:
    """Two replay CSVs in their shared columns: identical, or per differing column its max |diff|
    (numbers; else the count of differing cells) and where (row, ``t``)."""
    if a.read_bytes() == b.read_bytes():
        return {"identical": True, "rows": sum(1 for _ in a.open()) - 1}
    with a.open(newline="") as fa, b.open(newline="") as fb:
        ra, rb = csv.reader(fa), csv.reader(fb)
        ha, hb = next(ra), next(rb)
        shared = [c for c in ha if c in hb]
        ia, ib = [ha.index(c) for c in shared], [hb.index(c) for c in shared]
        worst: dict[str, list] = {}  # column -> [max |diff| or count, row, t]
        n = 0
        for n, (x, y) in enumerate(zip(ra, rb, strict=False), 1):
            for c, i, j in zip(shared, ia, ib, strict=True):
                if x[i] == y[j]:
                    continue
                try:
                    d = abs(float(x[i]) - float(y[j]))
                except ValueError:
                    d = float("nan")
                w = worst.setdefault(c, [0.0, 0, "", 0])
                w[3] += 1
                if d != d or d > w[0]:
                    w[:3] = [d, n, x[0]]
        rows_a, rows_b = n + sum(1 for _ in ra), n + sum(1 for _ in rb)
    return {
        "identical": not worst and rows_a == rows_b,
        "rows": [rows_a, rows_b],
        "only_base": [c for c in ha if c not in hb],
        "only_head": [c for c in hb if c not in ha],
        "diffs": [
            {"column": c, "max_abs_diff": w[0], "row": w[1], "t": w[2], "cells": w[3]}
            for c, w in worst.items()
        ],
    }


def zoo_logs(base: Side, work: Path, plants: list[str], scenarios: tuple[str, ...]) -> dict[str, Path]:
    """The drives (and prior drives) simulated once by the base's ``lde sim``; the plants' spec sheets
    from the base's ``lde evaluate --zoo`` (it writes them first; one 1-second run per plant after)."""
    d = work / "zoo"
    log(f"zoo: spec sheets of {len(plants)} plants (base's lde evaluate --zoo --duration 1)")
    argv = [
        "evaluate",
        "--zoo",
        "--plants",
        ",".join(plants),
        "--scenarios",
        scenarios[0],
        "--profiles",
        "lde",
    ]
    argv += ["--backends", "float", "--modes", "cold", "--duration", "1", "--workers", "0", "--no-progress"]
    r = run(base.lde(*argv, "--out", str(d / "evaluate")), env=base.env, cwd=work)
    if any(not (d / "evaluate" / "spec_sheets" / f"{p}.toml").is_file() for p in plants):
        raise Failed(r.error())  # (its 1-second runs may fail: only the sheets are used)
    logs = {}
    for plant in plants:
        car = str(base.tree / "vcan_sim" / "zoo" / f"{plant}.toml")
        for prof in ZOO_PROFILES:
            for sc, seed in [(x, 0) for x in scenarios] + [(PRIOR_SCENARIO, PRIOR_SEED)]:
                p = d / "logs" / plant / prof / f"{sc}-s{seed}.log"
                p.parent.mkdir(parents=True, exist_ok=True)
                argv = ["sim", "--scenario", sc, "--vehicle", car, "--profile", prof, "--seed", str(seed)]
                check(run(base.lde(*argv, "--log", str(p)), env=base.env, cwd=work))
                logs[f"{plant}/{prof}/{sc}"] = p
        log(f"zoo: simulated {plant} ({len(logs)} logs)")
    return logs


def zoo_replays(side: Side, out: Path, drives: dict[str, Path], prior: Path, common: list[str]) -> dict:
    """One plant x profile x backend with ``side``'s ``lde replay``: the cold runs in one command (one
    CSV per drive), the prior drive once with ``--learned``, then each warm run from a copy of what it
    learned. Returns the CSV path, or the failed command's error, per ``"SCENARIO cold|warm"``."""
    res: dict[str, Path | str] = {}
    cold = run(
        side.lde("replay", *map(str, drives.values()), *common, "--csv", str(out / "cold")), side.env, out
    )
    for sc, log_ in drives.items():
        csv_ = out / "cold" / f"{log_.stem}.csv"
        res[f"{sc} cold"] = csv_ if cold.rc == 0 and csv_.is_file() else cold.error()
    learned = out / "prior.learned"
    r = run(side.lde("replay", str(prior), *common, "--learned", str(learned)), side.env, out)
    for sc, log_ in drives.items():
        if r.rc == 0:
            shutil.copyfile(learned, out / f"{sc}.learned")
            csv_ = out / f"{sc}-warm.csv"
            argv = [str(log_), *common, "--learned", str(out / f"{sc}.learned"), "--csv", str(csv_)]
            w = run(side.lde("replay", *argv), side.env, out)
        res[f"{sc} warm"] = csv_ if r.rc == 0 and w.rc == 0 else (r if r.rc else w).error()
    return res


def bench_zoo(sides: dict[str, Side], work: Path, quick: bool) -> dict[str, Any]:
    plants = sorted(p.stem for p in (sides["base"].tree / "vcan_sim" / "zoo").glob("*.toml"))
    plants = [p for p in plants if p in QUICK_PLANTS] if quick else plants
    scenarios = QUICK_SCENARIOS if quick else ZOO_SCENARIOS
    logs = zoo_logs(sides["base"], work, plants, scenarios)
    results: dict[str, Any] = {}
    for plant in plants:
        sheet = work / "zoo" / "evaluate" / "spec_sheets" / f"{plant}.toml"
        for prof in ZOO_PROFILES:
            drives = {sc: logs[f"{plant}/{prof}/{sc}"] for sc in scenarios}
            prior = logs[f"{plant}/{prof}/{PRIOR_SCENARIO}"]
            for be in ZOO_BACKENDS:
                common = ["--profile", prof, "--backend", be, "--vehicle", str(sheet), "-q"]
                res = {}
                for s in SIDES:
                    out = work / s / "zoo" / f"{plant}_{prof}_{be}"
                    out.mkdir(parents=True)
                    res[s] = zoo_replays(sides[s], out, drives, prior, common)
                for run_ in res["base"]:
                    a, b = res["base"][run_], res["head"][run_]
                    err = [(s, x) for s, x in (("base", a), ("head", b)) if isinstance(x, str)]
                    key = f"{plant} {prof} {be} {run_}"
                    results[key] = {"side": err[0][0], "error": err[0][1]} if err else compare_csv(a, b)
                same = sum(v.get("identical") is True for v in results.values())
                log(f"zoo: {plant} {prof} {be}: {same} of {len(results)} identical so far")
    return results


# ----------------------------------------------------------------------------- 5. tests
def bench_tests(sides: dict[str, Side]) -> list[dict]:
    """Each commit's test suite, importing its sources from the worktree (``PYTHONPATH=src:.``, as an
    editable install does: some tests check the source layout, e.g. that the DBCs come from ``dbc/``)."""
    out = []
    for s in SIDES:
        side = sides[s]
        log(f"{s}: the test suite (pytest -q on the worktree's sources)")
        env = dict(side.env, PYTHONPATH=f"{side.tree / 'src'}{os.pathsep}{side.tree}")
        r = run(
            side.python("-m", "pytest", "-q", "-p", "no:cacheprovider"), env=env, cwd=side.tree, timeout=7200
        )
        last = (r.stdout.strip().splitlines() or [""])[-1]
        out.append({"side": s, "rc": r.rc, "summary": last.strip("= "), "wall": r.wall})
    return out


# ----------------------------------------------------------------------------- report
def machine() -> dict[str, Any]:
    cpu = ""
    with contextlib.suppress(OSError, StopIteration), open("/proc/cpuinfo") as fh:
        cpu = next(ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name"))
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "platform": platform.platform(),
    }


def _cell(v: dict | None, unit: str) -> str:
    if v is None:
        return "-"
    if "error" in v:
        return "failed"
    f = "{:.0f}" if unit == "MiB" or v["median"] >= 100 else "{:.3g}"
    return f"{f.format(v['median'])} [{f.format(v['min'])}-{f.format(v['max'])}]"


def markdown(r: dict[str, Any]) -> str:
    m, c = r["machine"], r["commits"]
    lb, la = ("/".join(f"{x:.1f}" for x in r[k]) for k in ("load_before", "load_after"))
    lines = [
        "# Guard rails: base and head side by side",
        "",
        f"Command: `{r['command']}`  ",
        f"Base: `{c['base']['ref']}` = {c['base']['sha'][:9]} ({c['base']['subject']})  ",
        f"Head: `{c['head']['ref']}` = {c['head']['sha'][:9]} ({c['head']['subject']})  ",
        f"Machine: {m['cpu']}, {m['cores']} cores (shared), Python {m['python']}; load average "
        f"{lb} before, {la} after; {r['date']}.  ",
        f"Medians [min-max] of {r['repeat']} runs each after a warm-up"
        + (
            f" (first demo: {r['cold_repeat']} rounds, no warm-up)"
            if any("demo" in x["metric"] for x in r["rows"])
            else ""
        )
        + ", base and head in turns; CPU = user + sys of the child. Ratio = head / base.",
        "",
        "| metric | base | head | ratio | limit | ok? |",
        "|---|---|---|---|---|---|",
    ]
    for x in r["rows"]:
        ratio = "-" if x["ratio"] is None else f"{x['ratio']:.2f}"
        ok = {None: "", True: "yes", False: "**NO**"}[x["ok"]]
        lim = x["limit"] + (
            f" {x['unit']}" if x["limit"].startswith("<") and not x["limit"].endswith("x") else ""
        )
        lines.append(
            f"| {x['metric']} [{x['unit']}] | {_cell(x['base'], x['unit'])} | {_cell(x['head'], x['unit'])} "
            f"| {ratio} | {lim} | {ok} |"
        )
    csvs = {**r.get("hour_csvs", {}), **r.get("zoo", {})}
    if csvs:
        same = sum(v.get("identical") is True for v in csvs.values())
        lines.append(
            f"| CSVs identical in their shared columns ({len(csvs)} replays) | | | | all | "
            f"{'yes' if same == len(csvs) else f'**NO**: {same} of {len(csvs)}'} |"
        )
    for t in r.get("tests", []):
        ok = "yes" if t["rc"] == 0 else "**NO**"
        lines.append(f"| tests, {t['side']}: {t['summary']} ({t['wall']:.0f} s) | | | | all pass | {ok} |")
    cols: dict[str, int] = {}  # the columns one side's CSVs lack, with how many CSVs
    for v in csvs.values():
        for s in SIDES if v.get("identical") is True else ():
            if v.get(f"only_{s}"):
                k = f"only in {s}: {', '.join(v[f'only_{s}'])}"
                cols[k] = cols.get(k, 0) + 1
    lines += ["", *(f"Columns {k} ({n} CSVs, otherwise identical)." for k, n in cols.items())] if cols else []
    diffs = [(k, v) for k, v in csvs.items() if v.get("identical") is not True]
    if diffs:
        lines += [
            "",
            "## CSV differences",
            "",
            "Per shared column: max |diff|, the row and t [s] where it is largest, how many cells differ.",
            "",
        ]
        failed: dict[str, list[str]] = {}
        for k, v in diffs:
            if "error" in v:
                failed.setdefault(f"{v.get('side', '')}: {v['error'].splitlines()[-1]}", []).append(k)
                continue
            parts = [
                f"{d['column']} {d['max_abs_diff']:.3g} at row {d['row']} (t {d['t']}; {d['cells']} cells)"
                for d in v["diffs"]
            ]
            extra = [f"rows {v['rows'][0]} vs {v['rows'][1]}"] if v["rows"][0] != v["rows"][1] else []
            extra += [f"only in base: {', '.join(v['only_base'])}"] if v["only_base"] else []
            extra += [f"only in head: {', '.join(v['only_head'])}"] if v["only_head"] else []
            lines.append(f"- {k}: " + "; ".join(parts + extra))
        for err, keys in failed.items():
            lines.append(f"- **failed** ({len(keys)} runs, e.g. {keys[0]}): {err}")
    fails: dict[str, str] = {}  # error -> the first row (or step) it failed
    for x in r["rows"]:
        for s in SIDES:
            if x[s] and "error" in x[s]:
                fails.setdefault(x[s]["error"], f"{x['metric']} ({s})")
    fails.update({v: k for k, v in r.get("failures", {}).items()})
    fails.update({r["error"]: "stopped"} if "error" in r else {})
    if fails:
        lines += ["", "## Failures", ""]
        for err, what in fails.items():
            lines += [f"{what}:", "", "```", err, "```", ""]
    return "\n".join(lines).rstrip() + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default="c4b2db1", help="the commit before the change (default c4b2db1)")
    ap.add_argument("--head", default="HEAD", help="the commit to check (default HEAD)")
    ap.add_argument(
        "--repeat", type=int, default=3, help="measured runs per side after a warm-up (default 3)"
    )
    ap.add_argument(
        "--cold-repeat", type=int, default=3, help="rounds of the first-demo measurement (default 3)"
    )
    ap.add_argument("--quick", action="store_true", help="the zoo: 2 plants x 2 scenarios (else all)")
    ap.add_argument("--tests", action="store_true", help="run each commit's test suite too")
    ap.add_argument("--only", default=",".join(PARTS[:-1]), help=f"comma-separated, of {','.join(PARTS)}")
    ap.add_argument(
        "--work",
        type=Path,
        help="work directory, kept afterwards; a later run with the same DIR reuses its worktrees and venvs "
        "of the same commits (not fresh: for iterating on this script; default: a temporary directory)",
    )
    ap.add_argument("--out", type=Path, default=RESULTS, help="where guard_rails.md/.json go")
    args = ap.parse_args(argv)
    parts = set(args.only.split(",")) | ({"tests"} if args.tests else set())
    if parts - set(PARTS) or args.repeat < 1 or args.cold_repeat < 1:
        ap.error(f"--only takes {','.join(PARTS)}; --repeat and --cold-repeat at least 1")
    work = args.work or Path(tempfile.mkdtemp(prefix="lde-guard-"))
    work.mkdir(parents=True, exist_ok=True)
    r: dict[str, Any] = {
        "command": " ".join(["python", "bench/guard_rails.py", *(sys.argv[1:] if argv is None else argv)]),
        "machine": machine(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "load_before": os.getloadavg(),
        "repeat": args.repeat,
        "cold_repeat": args.cold_repeat,
        "commits": {
            s: {"ref": ref, "sha": "", "subject": ""}
            for s, ref in zip(SIDES, (args.base, args.head), strict=True)
        },
        "rows": [],
    }
    sides: dict[str, Side] = {}
    runs = work / "run"  # this invocation's logs and outputs
    shutil.rmtree(runs, ignore_errors=True)
    try:
        for s in SIDES:
            sides[s] = prepare(s, r["commits"][s]["ref"], work, work / "mpl")
            r["commits"][s].update(sha=sides[s].sha, subject=sides[s].subject)
            (runs / s).mkdir(parents=True)
        for side in sides.values():  # not fatal: each measurement then reports its own failure
            w = run(side.lde("warmup"), env=side.env)
            log(f"{side.name}: lde warmup: {w.wall:.0f} s" + (f", FAILED: {w.error()}" if w.rc else ""))
            if w.rc:
                r.setdefault("failures", {})[f"lde warmup after install ({side.name})"] = w.error()
        if "replay" in parts:
            rows, r["hour_csvs"] = bench_replay(sides, runs, args.repeat)
            r["rows"] += rows
        if "step" in parts:
            r["rows"] += bench_step(sides, args.repeat)
        if "cold" in parts:
            r["rows"] += bench_cold(sides, runs, args.cold_repeat)
        if "zoo" in parts:
            r["zoo"] = bench_zoo(sides, runs, args.quick)
        if "tests" in parts:
            r["tests"] = bench_tests(sides)
    except Failed as e:
        r["error"] = str(e)
        log(f"stopped: {e}")
    finally:
        r["load_after"] = os.getloadavg()
        if args.work is None:
            for side in sides.values():
                run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(side.tree)])
            shutil.rmtree(work, ignore_errors=True)
            run(["git", "-C", str(ROOT), "worktree", "prune"])
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "guard_rails.json").write_text(json.dumps(r, indent=1) + "\n")
    text = markdown(r)
    (args.out / "guard_rails.md").write_text(text)
    print(text)
    csvs = {**r.get("hour_csvs", {}), **r.get("zoo", {})}.values()
    bad = any(x["ok"] is False for x in r["rows"]) or any(c.get("identical") is not True for c in csvs)
    return 1 if bad or "error" in r or r.get("failures") or any(t["rc"] for t in r.get("tests", [])) else 0


if __name__ == "__main__":
    sys.exit(main())
