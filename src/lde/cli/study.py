"""``lde study``: parameter sweeps of the estimator on simulated drives, on Dask; results as CSV + PNG.

Presets (``--preset``):

- ``paper`` — the paper's section-5 study: its five nominal parameter candidates (``est1`` .. ``est5``)
  as the estimator's parameters on the heavy and light lateral-load scenarios, for every payload
  case of the simulator (mass, yaw inertia and CG) and ``--seeds`` seeds; ranks the sets by the
  paper's error index (RMS error of Fw in N plus that of Mw in Nm per metre) and plots the winner's
  estimates against the truth.
- ``smoke`` — 4 short runs (est1/est3 on heavy/light): checks the whole chain in seconds.
- ``ladder`` — what each estimator step buys on the target scenarios (heavy, light, every payload,
  the undisturbed lane change): reference file, + ``lde calibrate`` (tires and input corrections
  from an undisturbed drive, the product path), the best candidate, + representative tires
  (identified on the simulator under heavy and light load), + ``lde calibrate``, then the prototypes
  of ``lde.analysis.adaptive``: mass/inertia/CG scheduled on the load, lateral acceleration, secant tires.
- ``faults`` — steering friction and sensor offsets in the simulator: the product with the
  reference file as shipped and with the input corrections (and tires) ``lde calibrate`` learns.
- ``all`` — the tire identification, then three candidate sweeps (shipped tires; the identified
  tires; + ``lde calibrate``), the ladder and the faults with their winners; ``summary_all.md``.

The default backend here is ``paper`` (``lde run``, ``replay`` and ``demo`` default to ``fixed``):
the presets reproduce the paper's study, and the tables in docs/design/studies.md were measured
with the paper's float filter. Give ``--backend fixed`` for the product's estimator.

Runs go to a ``LocalCluster(n_workers=--workers, threads_per_worker=1)`` by default or to an existing
scheduler with ``--scheduler tcp://HOST:8786``; ``--workers 0`` runs in this process.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
from pathlib import Path

from lde.analysis import study
from lde.cli import PROFILE_HELP
from lde.cli.replay_in_process import engine
from lde.errors import ConfigError


def add_cluster_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("Dask")
    g.add_argument(
        "--scheduler", metavar="ADDRESS", help="an existing dask.distributed scheduler (tcp://host:8786)"
    )
    g.add_argument(
        "--workers",
        type=int,
        default=2,
        metavar="N",
        help="local cluster worker processes (0: run in-process)",
    )
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def add_run_arguments(p: argparse.ArgumentParser) -> None:
    g = p.add_argument_group("runs")
    g.add_argument(
        "--duration", type=float, metavar="SEC", help="simulated time per run (default: the scenario's)"
    )
    g.add_argument(
        "--estimator",
        choices=("replay", "adaptive", "cli"),
        default="replay",
        help="replay: the product pipeline in process; adaptive: the prototype extensions "
        "(lde.analysis.adaptive); cli: `lde replay` on a written log, as a user runs it",
    )
    g.add_argument(
        "--backend",
        default=None,
        help="replay backend (default here: paper, the paper's float filter, which the tables in "
        "docs/design/studies.md were measured with; lde run, replay and demo default to fixed)",
    )
    g.add_argument(
        "--profile", default=None, help="of the simulated bus: " + PROFILE_HELP + " (default: lde)"
    )
    g.add_argument(
        "--sim-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="simulator option for every run (repeatable), e.g. friction_Nm=0.8",
    )
    g.add_argument(
        "--est-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="estimator option (repeatable), e.g. calibrate=lane_change, steering_friction_Nm=0.35 "
        "(lde.analysis.study.EstOptions)",
    )


def cluster_config(args: argparse.Namespace) -> study.ClusterConfig:
    workers = 2 if args.workers is None else args.workers
    if workers < 0:
        raise ConfigError("--workers must be >= 0")
    return study.ClusterConfig(scheduler=args.scheduler, n_workers=workers)


def sim_options(args: argparse.Namespace) -> study.SimOptions:
    """The typed simulator options of ``--sim-option`` (an unknown name is an error here)."""
    return study.SimOptions.parse(parse_options(args.sim_option, "--sim-option"), strict=True)


def est_options(args: argparse.Namespace) -> study.EstOptions:
    """The typed estimator options of ``--est-option`` (an unknown name is an error here)."""
    return study.EstOptions.parse(parse_options(args.est_option, "--est-option"), strict=True)


def parse_options(items: list[str], flag: str) -> tuple[tuple[str, study.OptionValue], ...]:
    out = []
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key:
            raise ConfigError(f"{flag} {item!r}: expected KEY=VALUE")
        out.append((key, _value(value)))
    return tuple(out)


def _value(v: str) -> study.OptionValue:
    if v.lower() in ("true", "false"):
        return v.lower() == "true"
    for conv in (int, float):
        try:
            return conv(v)
        except ValueError:
            pass
    return v


def _csv_list(s: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in s.split(",") if x.strip())


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "study",
        help="parameter-uncertainty study on Dask (paper section 5): CSV + PNG",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--preset",
        choices=("paper", "smoke", "ladder", "faults", "all"),
        default="paper",
        help="which sweep (default: paper; all = the tire identification + paper + ladder + faults)",
    )
    p.add_argument(
        "--winner", help="candidate set for ladder/faults (default: the paper sweep's winner, else est3)"
    )
    p.add_argument(
        "--seeds", type=int, default=2, metavar="N", help="simulator seeds per load case (paper: 2)"
    )
    p.add_argument(
        "--candidates", type=_csv_list, metavar="A,B,..", help="candidate vehicle files (default: est1..est5)"
    )
    p.add_argument("--scenarios", type=_csv_list, metavar="A,B,..", help="scenarios (default: heavy,light)")
    p.add_argument("--payloads", type=_csv_list, metavar="A,B,..", help="payload cases (default: all)")
    p.add_argument("--out", type=Path, default=Path("results"), help="output directory (default: results/)")
    add_run_arguments(p)
    add_cluster_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.seeds < 1:
        raise ConfigError("--seeds must be >= 1")
    ctx = _Ctx(
        out=args.out,
        seeds=tuple(range(args.seeds)),
        cluster=cluster_config(args),
        progress=not args.no_progress,
    )
    winner = args.winner
    winner_cal = args.winner
    sweep_kw = dict(
        scenarios=args.scenarios,
        payloads=args.payloads,
        duration=args.duration,
        estimator=args.estimator,
        backend=args.backend or "paper",
        profile=args.profile or "lde",
        sim_options=sim_options(args),
        est_options=est_options(args),
    )
    if args.preset in ("paper", "smoke"):
        winner = _sweep(ctx, args.preset, args.candidates, sweep_kw, "Table 1 sets as shipped")
    if args.preset == "all":
        cands = tuple(args.candidates or study.CANDIDATES)
        tire_files = _fig12(ctx, cands)
        _sweep(ctx, "paper", cands, sweep_kw, "Table 1 sets as shipped")
        best = _sweep(
            ctx, "paper_fig12", tuple(tire_files.values()), sweep_kw, "Table 1 sets with the Fig. 12 tires"
        )
        winner = winner or Path(best).stem.removesuffix("_fig12")
        cal_kw = dict(sweep_kw, est_options=study.EstOptions(calibrate="lane_change"))
        winner_cal = _sweep(ctx, "paper_calibrated", cands, cal_kw, "Table 1 sets + lde calibrate")
    if args.preset in ("ladder", "faults", "all"):
        winner = winner or "est3"
        tire_vehicle = _fig12(ctx, (winner,))[winner] if args.preset != "all" else tire_files[winner]
        for preset, make in (("ladder", study.ladder_specs), ("faults", study.fault_specs)):
            if args.preset not in (preset, "all"):
                continue
            extra: dict = {"winner_calibrated": winner_cal} if winner_cal else {}
            extra["curvature"] = ctx.curvature
            specs = make(winner, tire_vehicle, seeds=ctx.seeds, duration=args.duration, **extra)
            results = _run(specs, preset, ctx)
            study.write_csv(results, ctx.out / f"{preset}_runs.csv")
            table = study.pivot_markdown(results)
            print(table)
            ctx.report += [
                f"## {preset}: NRMSE Fw / Mw in % (undisturbed: RMS of the estimate)",
                "",
                table,
                "",
            ]
            if preset == "ladder":
                for prefix, name, title in (
                    ("7", "ladder_final_traces.png", "final estimator (step 7)"),
                    ("0", "ladder_reference_traces.png", "reference vehicle file (step 0)"),
                ):
                    tr = [r for r in results if r.spec.group.startswith(prefix) and r.trace is not None]
                    if tr:
                        study.plot_traces(tr, ctx.out / name, title=title)
    if ctx.report:
        (ctx.out / f"summary_{args.preset}.md").write_text("\n".join(ctx.report) + "\n")
    print(f"results in {ctx.out}/")
    return 1 if ctx.failed else 0


@dataclasses.dataclass
class _Ctx:
    out: Path
    seeds: tuple[int, ...]
    cluster: study.ClusterConfig
    progress: bool
    report: list[str] = dataclasses.field(default_factory=list)
    failed: int = 0
    curvature: tuple[float, float, float] | None = None


def _sweep(ctx: _Ctx, preset: str, candidates, sweep_kw: dict, what: str) -> str:
    """A candidate sweep: CSV, scores, error-index bars and the winner's traces against the truth;
    the winner."""
    base = "smoke" if preset == "smoke" else "paper"
    specs = study.preset_specs(base, seeds=ctx.seeds, candidates=candidates, **sweep_kw)
    results = _run(specs, preset, ctx)
    study.write_csv(results, ctx.out / f"{preset}_runs.csv")
    scores = study.rank_candidates(results)
    if not scores:
        raise ConfigError(f"{preset}: every run failed (see above)")
    study.write_scores_csv(scores, ctx.out / f"{preset}_scores.csv")
    study.plot_error_index(scores, ctx.out / f"{preset}_error_index.png", title=f"Error index: {what}")
    text = study.scores_table(scores)
    winner = scores[0].candidate
    print(text)
    print(f"\nwinner (smallest mean error index J): {winner}")
    n_bad = sum(not r.ok for r in results)
    ctx.report += [
        f"## {preset}: {what} ({len(results)} runs, {n_bad} discarded)",
        "",
        "```",
        text,
        "```",
        "",
        f"Winner: **{Path(winner).stem}**.",
        "",
    ]
    if any(r.trace is not None for r in results):
        study.plot_traces(results, ctx.out / f"{preset}_traces.png")
    return winner


def _fig12(ctx: _Ctx, candidates) -> dict[str, str]:
    """Identify the tires under heavy and light load; write ``vehicles/<cand>_fig12.toml`` per candidate."""
    ids = study.identify_tires(seeds=ctx.seeds)
    cf, cr, k = study.representative_tires(ids)
    _write_rows([dataclasses.asdict(i) for i in ids], ctx.out / "tires_fig12.csv")
    study.plot_tires(ids, ctx.out / "tires_fig12.png")
    note = "Fig. 12 on vcan_sim (per tire): " + "; ".join(
        f"{i.scenario}: Cf {i.cf:.0f} N/rad, Cr {i.cr:.0f} N/rad, K {i.k:.0f} Nm/rad" for i in ids
    )
    note += f"; representative (mean): Cf {cf:.0f}, Cr {cr:.0f}, K {k:.0f}"
    ctx.curvature = study.identify_curvature("heavy_load", ctx.seeds)
    note += (
        "; curvature on heavy_load (secant C = C0 (1 - kappa alpha^2)): kappa_f {:.0f}, kappa_r {:.0f}, "
        "kappa_K {:.0f} 1/rad^2".format(*ctx.curvature)
    )
    print(note)
    ctx.report += ["## Fig. 12: linear-equivalent tires", "", note, ""]
    return {
        c: str(
            study.write_tire_vehicle((ctx.out / "vehicles" / f"{c}_fig12.toml").resolve(), c, cf, cr, k, note)
        )
        for c in candidates
    }


def _run(specs, name: str, ctx: _Ctx):
    print(f"lde study: {name}: {len(specs)} runs", file=sys.stderr)
    results = study.run_specs(specs, ctx.cluster, progress=ctx.progress, engine=engine)
    bad = [r for r in results if not r.ok]
    for r in bad[:10]:
        print(f"FAILED {r.spec.label}: {r.error}", file=sys.stderr)
    # a run in which the simulated driver lost control is discarded, not an lde failure
    ctx.failed += sum("lost control" not in r.error for r in bad)
    return results


def _write_rows(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
