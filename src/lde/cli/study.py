"""``lde study``: parameter sweeps on Dask (issue 6, items 2 and 6), results as CSV + PNG.

Presets (``--preset``):

- ``paper`` — the paper's section-5 study: every Table 1 candidate set (``est1`` .. ``est5``) as the
  estimator's nominal parameters on the heavy and light lateral-load scenarios, for every payload
  case of the simulator (mass, inertia and CG as in Fig. 9) and ``--seeds`` seeds; ranks the sets by
  the eq. (19) error index (Fig. 11) and plots the winner's estimates against truth (Figs. 13-14).
- ``smoke`` — 4 short runs (est1/est3 on heavy/light): checks the whole chain in seconds.

Runs go to a ``LocalCluster(n_workers=--workers, threads_per_worker=1)`` by default or to an existing
scheduler with ``--scheduler tcp://HOST:8786``; ``--workers 0`` runs in this process.
"""

from __future__ import annotations

import argparse
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
        "--preset", choices=("paper", "smoke"), default="paper", help="which sweep (default: paper)"
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
    specs = study.preset_specs(
        args.preset,
        seeds=tuple(range(args.seeds)),
        candidates=args.candidates,
        scenarios=args.scenarios,
        payloads=args.payloads,
        duration=args.duration,
        estimator=args.estimator,
        backend=args.backend,
        sim_options=parse_options(args.sim_option, "--sim-option"),
        est_options=parse_options(args.est_option, "--est-option"),
    )
    print(f"lde study: {len(specs)} runs ({args.preset})", file=sys.stderr)
    results = study.run_specs(specs, cluster_config(args), progress=not args.no_progress)
    out: Path = args.out
    prefix = args.preset
    paths = [study.write_csv(results, out / f"{prefix}_runs.csv")]
    scores = study.rank_candidates(results)
    failed = [r for r in results if not r.ok]
    if scores:
        paths.append(study.write_scores_csv(scores, out / f"{prefix}_scores.csv"))
        paths.append(study.plot_error_index(scores, out / f"{prefix}_error_index.png"))
        print(study.scores_table(scores))
        print(f"\nwinner (smallest mean error index J): {scores[0].candidate}")
    if any(r.trace is not None for r in results):
        paths.append(study.plot_traces(results, out / f"{prefix}_traces.png"))
    for r in failed[:10]:
        print(f"FAILED {r.spec.label}: {r.error}", file=sys.stderr)
    print("wrote " + ", ".join(str(p) for p in paths))
    return 1 if failed else 0
