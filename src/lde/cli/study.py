"""``lde study``: parameter sweeps on Dask (issue 6, items 2 and 6), results as CSV + PNG.

Presets (``--preset``):

- ``paper`` — the paper's section-5 study: every Table 1 candidate set (``est1`` .. ``est5``) as the
  estimator's nominal parameters on the heavy and light lateral-load scenarios, for every payload
  case of the simulator (mass, inertia and CG as in Fig. 9) and ``--seeds`` seeds; ranks the sets by
  the eq. (19) error index (Fig. 11) and plots the winner's estimates against truth (Figs. 13-14).
- ``smoke`` — 4 short runs (est1/est3 on heavy/light): checks the whole chain in seconds.
- ``ladder`` — what each estimator step buys on the target scenarios (heavy, light, every payload,
  the undisturbed lane change): reference file, Table 1 winner, + Fig. 12 tires (identified on the
  simulator under heavy and light load), + calibration from an undisturbed drive (friction, torsion
  bar, accelerometer tilt, offsets; ``lde.adaptive``), + mass/inertia/CG scheduled on the load.
- ``faults`` — steering friction and sensor offsets in the simulator, uncompensated and learned.
- ``all`` — paper, then Fig. 12, ladder and faults with the paper's winner; ``summary_all.md``.

Runs go to a ``LocalCluster(n_workers=--workers, threads_per_worker=1)`` by default or to an existing
scheduler with ``--scheduler tcp://HOST:8786``; ``--workers 0`` runs in this process.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import sys
from pathlib import Path

from .. import study
from ..errors import ConfigError


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
        choices=("replay", "adaptive"),
        default="replay",
        help="replay: the product pipeline (lde.replay); adaptive: the prototype extensions (lde.adaptive)",
    )
    g.add_argument("--backend", choices=("float", "fixed"), default="float", help="replay backend")
    g.add_argument(
        "--sim-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="simulator option for every run (repeatable), e.g. steering_friction_Nm=0.8",
    )
    g.add_argument(
        "--est-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="prototype estimator option (repeatable), e.g. friction_Nm=0.8",
    )


def cluster_config(args: argparse.Namespace) -> study.ClusterConfig:
    if args.workers < 0:
        raise ConfigError("--workers must be >= 0")
    return study.ClusterConfig(scheduler=args.scheduler, n_workers=args.workers)


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
        help="which sweep (default: paper; all = paper + Fig. 12 + ladder + faults)",
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
    out: Path = args.out
    seeds = tuple(range(args.seeds))
    cluster = cluster_config(args)
    progress = not args.no_progress
    report: list[str] = []
    failed = 0
    winner = args.winner
    if args.preset in ("paper", "smoke", "all"):
        preset = "paper" if args.preset == "all" else args.preset
        specs = study.preset_specs(
            preset,
            seeds=seeds,
            candidates=args.candidates,
            scenarios=args.scenarios,
            payloads=args.payloads,
            duration=args.duration,
            estimator=args.estimator,
            backend=args.backend,
            sim_options=parse_options(args.sim_option, "--sim-option"),
            est_options=parse_options(args.est_option, "--est-option"),
        )
        results = _run(specs, preset, cluster, progress)
        failed += _failures(results)
        study.write_csv(results, out / f"{preset}_runs.csv")
        scores = study.rank_candidates(results)
        if scores:
            study.write_scores_csv(scores, out / f"{preset}_scores.csv")
            study.plot_error_index(scores, out / f"{preset}_error_index.png")
            text = study.scores_table(scores)
            print(text)
            winner = scores[0].candidate
            print(f"\nwinner (smallest mean error index J): {winner}")
            report += [
                f"## {preset}: error index per candidate set ({len(results)} runs)",
                "",
                "```",
                text,
                "```",
                "",
                f"Winner: **{winner}**.",
                "",
            ]
        if any(r.trace is not None for r in results):
            study.plot_traces(results, out / f"{preset}_traces.png")
    if args.preset in ("ladder", "faults", "all"):
        winner = winner or "est3"
        ids = study.identify_tires(seeds=seeds)
        cf, cr, k = study.representative_tires(ids)
        _write_rows([dataclasses.asdict(i) for i in ids], out / "tires_fig12.csv")
        study.plot_tires(ids, out / "tires_fig12.png")
        note = "Fig. 12 on vcan_sim: " + "; ".join(
            f"{i.scenario}: Cf {i.cf:.0f}, Cr {i.cr:.0f}, K {i.k:.0f}" for i in ids
        )
        tire_vehicle = study.write_tire_vehicle(
            (out / "vehicles" / f"{winner}_fig12.toml").resolve(), winner, cf, cr, k, note
        )
        print(note)
        report += ["## Fig. 12: linear-equivalent tires (per tire)", "", note, ""]
        for preset, make in (("ladder", study.ladder_specs), ("faults", study.fault_specs)):
            if args.preset not in (preset, "all"):
                continue
            specs = make(winner, str(tire_vehicle), seeds=seeds, duration=args.duration)
            results = _run(specs, preset, cluster, progress)
            failed += _failures(results)
            study.write_csv(results, out / f"{preset}_runs.csv")
            table = study.pivot_markdown(results)
            print(table)
            report += [f"## {preset}: NRMSE Fw / Mw in % (undisturbed: RMS of the estimate)", "", table, ""]
            if preset == "ladder":
                last = [r for r in results if r.spec.group.startswith("4") and r.trace is not None]
                first = [r for r in results if r.spec.group.startswith("0") and r.trace is not None]
                if last:
                    study.plot_traces(last, out / "ladder_final_traces.png", title="final estimator")
                if first:
                    study.plot_traces(
                        first, out / "ladder_reference_traces.png", title="reference vehicle file"
                    )
    if report:
        (out / f"summary_{args.preset}.md").write_text("\n".join(report) + "\n")
    print(f"results in {out}/")
    return 1 if failed else 0


def _run(specs, name, cluster, progress):
    print(f"lde study: {name}: {len(specs)} runs", file=sys.stderr)
    return study.run_specs(specs, cluster, progress=progress)


def _failures(results) -> int:
    failed = [r for r in results if not r.ok]
    for r in failed[:10]:
        print(f"FAILED {r.spec.label}: {r.error}", file=sys.stderr)
    return len(failed)


def _write_rows(rows: list[dict], path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
