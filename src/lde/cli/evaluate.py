"""``lde evaluate``: accuracy of the estimator on simulator scenarios (issues 6 and 11).

For every (scenario, payload, seed) the simulator produces CAN frames and truth, the estimator runs
over the frames, and the table reports, after a 2 s settling window: NRMSE of Fw and of Mw (about the
actual CG, as in the paper) with the Mw figure about the unloaded reference CG beside it; for a
bank-only scenario the Mw error is normalised by 1 m x max|Fw|; for a disturbance-free scenario the
figures are the RMS of the estimate in N and Nm (``lde.metrics``).

``lde evaluate --zoo``: the estimator on cars it was never fitted to (``vcan_sim/zoo``). For every
plant x scenario x profile x backend: simulate (seeded), write the candump log, run
``lde replay LOG --profile P --backend B --vehicle SPEC_SHEET --csv OUT`` in process with only the
plant's spec sheet (mass, yaw inertia, lf, lr, tread, ratio on the generic defaults), score the CSV.
Writes OUT/zoo_runs.csv (every run), OUT/zoo_table.csv and OUT/zoo_table.md (a row per plant x
profile x backend, a summary line per target) and OUT/spec_sheets/. ``--warm`` first replays an
earlier drive of the same car with ``--learned`` (needs ``lde replay --learned``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from .. import study
from ..errors import ConfigError
from ..study import zoo
from ..study.engine import load_sim_vehicle
from ..study.specsheet import write_spec_sheet
from ..study.tables import write_rows
from . import BACKEND_CHOICES
from .engine import engine
from .study import add_cluster_arguments, add_run_arguments, cluster_config, est_options, sim_options


def _csv_list(s: str) -> tuple[str, ...]:
    return tuple(x.strip() for x in s.split(",") if x.strip())


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="accuracy table (NRMSE of Fw, Mw) of the estimator on simulator scenarios or the zoo",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--scenario",
        action="append",
        metavar="NAME",
        help="scenario (repeatable; default: the accuracy set, see lde.study.EVALUATE_SCENARIOS)",
    )
    p.add_argument("--scenarios", type=_csv_list, metavar="A,B,..", help="scenarios as a comma list")
    p.add_argument(
        "--payload",
        action="append",
        metavar="NAME",
        help="payload case (repeatable; default: the scenario's own)",
    )
    p.add_argument("--all-payloads", action="store_true", help="every payload case of the simulator")
    p.add_argument(
        "--vehicle", default=None, help="estimator vehicle file or shipped name (default: reference)"
    )
    p.add_argument(
        "--sim-vehicle",
        default="reference",
        help="simulated vehicle: shipped name, TOML path or zoo:PLANT (default: reference)",
    )
    p.add_argument("--seed", type=int, default=0, help="simulator seed")
    p.add_argument("--csv", type=Path, help="write the table as CSV")
    p.add_argument("--plot", type=Path, help="write estimates against truth as PNG")
    z = p.add_argument_group("zoo (cars the estimator was not fitted to)")
    z.add_argument("--zoo", action="store_true", help="evaluate on the zoo plants through `lde replay`")
    z.add_argument("--plants", type=_csv_list, metavar="A,B,..", help="zoo plants (default: all)")
    z.add_argument(
        "--profiles", type=_csv_list, metavar="A,B", help="profiles (default: --profile, else lde,hyundai)"
    )
    z.add_argument(
        "--backends", type=_csv_list, metavar="A,B", help="backends (default: --backend, else fixed,float)"
    )
    z.add_argument(
        "--warm",
        action="store_true",
        help="warm: `lde replay PRIOR --learned S` on an earlier drive of the same car first",
    )
    z.add_argument("--out", type=Path, default=Path("results/zoo"), help="output directory (results/zoo)")
    z.add_argument("--keep-logs", action="store_true", help="keep every run's log, truth, spec sheet, CSV")
    add_run_arguments(p)
    add_cluster_arguments(p)
    p.set_defaults(func=run, workers=None)


def _scenarios(args: argparse.Namespace) -> tuple[str, ...] | None:
    names = tuple(args.scenario or ()) + tuple(args.scenarios or ())
    return names or None


def run(args: argparse.Namespace) -> int:
    if args.zoo:
        return run_zoo(args)
    if args.workers is None:
        args.workers = 0
    if args.plants or args.profiles or args.backends or args.warm or args.keep_logs:
        raise ConfigError("--plants, --profiles, --backends, --warm and --keep-logs need --zoo")
    payloads = study.all_payloads() if args.all_payloads else tuple(args.payload or ("",))
    specs = study.evaluation_specs(
        scenarios=_scenarios(args) or study.EVALUATE_SCENARIOS,
        payloads=payloads,
        est_vehicle=args.vehicle or "reference",
        sim_vehicle=args.sim_vehicle,
        seed=args.seed,
        duration=args.duration,
        estimator=args.estimator,
        backend=args.backend or "paper",
        profile=args.profile or "lde",
        sim_options=sim_options(args),
        est_options=est_options(args),
        trace=args.plot is not None,
    )
    results = study.run_specs(specs, cluster_config(args), progress=not args.no_progress, engine=engine)
    print(study.table(results))
    if args.csv:
        study.write_csv(results, args.csv)
    if args.plot and any(r.trace is not None for r in results):
        study.plot_traces(results, args.plot)
    return 0 if all(r.ok for r in results) else 1


def run_zoo(args: argparse.Namespace) -> int:
    """``lde evaluate --zoo``: see the module docstring."""

    for flag, given in (
        ("--vehicle", args.vehicle),
        ("--payload/--all-payloads", args.payload or args.all_payloads),
        ("--sim-option", args.sim_option),
        ("--est-option", args.est_option),
        ("--plot", args.plot),
        ("--csv", args.csv),
    ):
        if given:
            raise ConfigError(
                f"{flag} does not apply to --zoo (the estimator gets only each plant's spec sheet; "
                "outputs go to --out)"
            )
    if args.sim_vehicle != "reference" or args.estimator != "replay":
        raise ConfigError("--sim-vehicle/--estimator do not apply to --zoo (use --plants)")
    if args.workers is None:
        args.workers = 2
    mode = zoo.Mode.WARM if args.warm else zoo.Mode.COLD
    profiles = args.profiles or ((args.profile,) if args.profile else zoo.PROFILES)
    backends = args.backends or ((args.backend,) if args.backend else zoo.BACKENDS)
    for b in backends:
        if b not in BACKEND_CHOICES:
            raise ConfigError(f"unknown backend {b!r} ({', '.join(BACKEND_CHOICES)})")
    out: Path = args.out
    specs = zoo.zoo_specs(
        plant_list=args.plants,
        scenarios=_scenarios(args) or zoo.ZOO_SCENARIOS,
        profiles=profiles,
        backends=backends,
        seed=args.seed,
        mode=mode,
        duration=args.duration,
        work_dir=str((out / "runs").resolve()) if args.keep_logs else "",
    )

    for plant in dict.fromkeys(s.group for s in specs):
        write_spec_sheet(load_sim_vehicle(f"zoo:{plant}"), out / "spec_sheets" / f"{plant}.toml")
    n_plants, n_scen = len({s.group for s in specs}), len({s.scenario for s in specs})
    print(
        f"lde evaluate --zoo ({mode.value}): {len(specs)} runs = {n_plants} plants x {n_scen} scenarios x "
        f"{len(profiles)} profiles x {len(backends)} backends",
        file=sys.stderr,
    )
    t0 = time.perf_counter()
    results = study.run_specs(
        specs, cluster_config(args), progress=not args.no_progress, desc="lde zoo", engine=engine
    )
    wall = time.perf_counter() - t0
    study.write_csv(results, out / "zoo_runs.csv")
    write_rows(zoo.plant_table_rows(results), out / "zoo_table.csv")
    summary = zoo.summary_lines(results)
    md = [f"# Zoo evaluation ({mode.value})", "", f"`{_command(args)}`: {len(results)} runs in {wall:.0f} s."]
    md += ["", _LEGEND, ""]
    md += [f"- {line}" for line in summary] + [""]
    for b in backends:
        md += [f"## backend {b}", "", zoo.plant_table_markdown(results, backend=b), ""]
    (out / "zoo_table.md").write_text("\n".join(md))
    print("\n".join(summary))
    print()
    print(zoo.plant_table_markdown(results, backend=backends[0]))
    print(f"\n{len(results)} runs in {wall:.0f} s; tables in {out}/zoo_table.{{md,csv}}", file=sys.stderr)
    for r in results:
        if not r.ok:
            print(f"FAILED {r.spec.label}: {r.error}", file=sys.stderr)
    return 0 if all(r.ok for r in results) else 1


_LEGEND = (
    "Cells: NRMSE Fw / Mw in % after 2 s (Mw about the spec sheet's CG; payload plants: about the true "
    "CG in brackets); disturbance-free drives: RMS of the estimate in N / Nm. **Bold**: target missed."
)


def _command(args: argparse.Namespace) -> str:
    """The evaluate command line that reproduces this zoo run (for the table's header)."""
    parts = ["lde evaluate --zoo"]
    if args.warm:
        parts.append("--warm")
    for flag, val in (
        ("--plants", args.plants),
        ("--scenarios", _scenarios(args)),
        ("--profiles", args.profiles),
        ("--backends", args.backends),
    ):
        if val:
            parts.append(f"{flag} {','.join(val)}")
    if args.profile:
        parts.append(f"--profile {args.profile}")
    if args.backend:
        parts.append(f"--backend {args.backend}")
    if args.seed:
        parts.append(f"--seed {args.seed}")
    if args.duration:
        parts.append(f"--duration {args.duration:g}")
    parts.append(f"--out {args.out}")
    return " ".join(parts)
