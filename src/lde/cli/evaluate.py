"""``lde evaluate``: accuracy of the estimator on simulator scenarios.

For every (scenario, payload, seed) the simulator produces CAN frames and truth, the estimator runs
over the frames, and the table reports, after a 2 s settling window: NRMSE of Fw and of Mw (about the
actual CG, as in the paper) with the Mw figure about the unloaded reference CG beside it; for a
bank-only scenario the Mw error is normalised by 1 m x max|Fw|; for a disturbance-free scenario the
figures are the RMS of the estimate in N and Nm (``lde.analysis.metrics``). The default backend here is
``paper`` (``lde run``, ``replay`` and ``demo`` default to ``fixed``): the accuracy tables in
docs/design/studies.md were measured with the paper's float filter; give ``--backend fixed`` for the
product's estimator. ``--zoo`` runs ``fixed`` and ``float`` unless ``--backends`` says otherwise.

``lde evaluate --zoo``: the estimator on cars it was never fitted to (``vcan_sim/zoo``). For every
plant x scenario x profile x backend: simulate (seeded), write the candump log, run
``lde replay LOG --profile P --backend B --vehicle SPEC_SHEET --csv OUT`` in process with only the
plant's spec sheet (mass, yaw inertia, lf, lr, tread, ratio on the generic defaults), score the CSV.
Writes OUT/zoo_runs.csv (every run), OUT/zoo_table.csv and OUT/zoo_table.md (a row per plant x
profile x backend x mode, a summary line per target, wind force, bank angle, payload about both CGs)
and OUT/spec_sheets/. ``--modes cold,warm`` (the default): cold runs with the spec sheet only; warm
first replays an earlier drive of the same car with ``--learned S`` and then the run with it
(``--prior A,B``: which drives, each its own mode ``warm after NAME``; default ``prior_drive``). A
payload plant also runs with the spec sheet plus the load (``PLANT + load`` rows).
``--first-drive``: instead of the scenario table, each plant's first drive (ten minutes of motorway
driving, cold, scored from minute 2 on and per minute, and when the learner reports "learned") and
warm light loads (2 m/s crosswind, 1 deg bank, no disturbance, the crosswind with 0.4 and 0.8 Nm of
rack friction and with a rough driver), each beside its target; ``--backends`` defaults to
``fixed`` there, ``--duration`` shortens the first drive only. Writes OUT/first_drive.md and
OUT/first_drive.csv (every run, every minute).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lde.analysis import study
from lde.analysis.study import firstdrive, zoo, zooreport
from lde.analysis.study.execute import load_sim_vehicle
from lde.analysis.study.specsheet import write_spec_sheet
from lde.analysis.study.tables import write_rows
from lde.cli.replay_in_process import engine
from lde.cli.study import add_cluster_arguments, add_run_arguments, cluster_config, est_options, sim_options
from lde.errors import ConfigError


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
        help="scenario (repeatable; default: the accuracy set, see lde.analysis.study.EVALUATE_SCENARIOS)",
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
        "--modes",
        type=_csv_list,
        metavar="cold,warm",
        help="cold: `lde replay LOG` with the spec sheet; warm: `lde replay PRIOR --learned S` on an "
        "earlier drive of the same car first (default: cold,warm)",
    )
    z.add_argument("--warm", action="store_true", help="warm only (= --modes warm)")
    z.add_argument(
        "--prior",
        type=_csv_list,
        metavar="A,B",
        help="warm: the earlier drive(s) of the same car to learn on, each reported apart "
        f"(scenario names, another seed than the scored drive; default {zoo.PRIOR_SCENARIO})",
    )
    z.add_argument(
        "--first-drive",
        action="store_true",
        help="first drives (10 min, cold, per minute, time to learned) and warm light loads, with targets",
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
    if (
        args.plants
        or args.profiles
        or args.backends
        or args.warm
        or args.modes
        or args.prior
        or args.keep_logs
    ):
        raise ConfigError(
            "--plants, --profiles, --backends, --modes, --warm, --prior and --keep-logs need --zoo"
        )
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
    if args.first_drive:
        return run_first_drive(args)
    modes = _modes(args)
    priors = tuple(args.prior or (zoo.PRIOR_SCENARIO,))
    if args.prior and zoo.Mode.WARM not in modes:
        raise ConfigError("--prior applies to warm runs: add warm to --modes")
    profiles = args.profiles or ((args.profile,) if args.profile else zoo.PROFILES)
    backends = args.backends or ((args.backend,) if args.backend else zoo.BACKENDS)
    from lde.engine.backends import get_backend

    for b in backends:
        get_backend(b)  # ConfigError for an unknown or removed name
    out: Path = args.out
    specs = zoo.zoo_specs(
        plant_list=args.plants,
        scenarios=_scenarios(args) or zoo.ZOO_SCENARIOS,
        profiles=profiles,
        backends=backends,
        seed=args.seed,
        modes=modes,
        priors=priors,
        duration=args.duration,
        work_dir=str((out / "runs").resolve()) if args.keep_logs else "",
    )

    for plant in dict.fromkeys(s.group for s in specs):
        write_spec_sheet(load_sim_vehicle(f"zoo:{plant}"), out / "spec_sheets" / f"{plant}.toml")
    n_plants, n_scen = len({s.group for s in specs}), len({s.scenario for s in specs})
    n_load = sum(s.est_vehicle == study.SPEC_SHEET_LOADED for s in specs)
    print(
        f"lde evaluate --zoo ({','.join(m.value for m in modes)}): {len(specs)} runs = {len(modes)} modes x "
        f"{n_plants} plants x {n_scen} scenarios x {len(profiles)} profiles x {len(backends)} backends"
        + (f" (+ {n_load} payload runs with the load in the vehicle file)" if n_load else ""),
        file=sys.stderr,
    )
    load_before = zooreport.load_average()
    t0 = time.perf_counter()
    results = study.run_specs(
        specs, cluster_config(args), progress=not args.no_progress, desc="lde zoo", engine=engine
    )
    wall = time.perf_counter() - t0
    info = zooreport.RunInfo(
        command=_command(args),
        runs=len(results),
        wall_s=wall,
        workers=args.workers,
        machine=zooreport.machine_description(),
        load_before=load_before,
        load_after=zooreport.load_average(),
        date=zooreport.now(),
    )
    study.write_csv(results, out / "zoo_runs.csv")
    write_rows(zoo.plant_table_rows(results), out / "zoo_table.csv")
    doc = zooreport.doc_block(results, info)
    (out / "zoo_table.md").write_text(f"# Zoo evaluation\n\n{doc}\n")
    print("\n".join(zooreport.summary_block(results)))
    print()
    print(zoo.plant_table_markdown(results, backend=backends[0]))
    print(f"\n{len(results)} runs in {wall:.0f} s; tables in {out}/zoo_table.{{md,csv}}", file=sys.stderr)
    for r in results:
        if not r.ok:
            print(f"FAILED {r.spec.label}: {r.error}", file=sys.stderr)
    return 0 if all(r.ok for r in results) else 1


def run_first_drive(args: argparse.Namespace) -> int:
    """``lde evaluate --zoo --first-drive``: see the module docstring."""
    for flag, given in (
        ("--scenarios/--scenario", _scenarios(args)),
        ("--modes/--warm", args.modes or args.warm),
        ("--prior", args.prior),
    ):
        if given:
            raise ConfigError(f"{flag} does not apply to --first-drive (its drives and modes are fixed)")
    profiles = args.profiles or ((args.profile,) if args.profile else zoo.PROFILES)
    backends = args.backends or ((args.backend,) if args.backend else ("fixed",))
    from lde.engine.backends import get_backend

    for b in backends:
        get_backend(b)  # ConfigError for an unknown or removed name
    out: Path = args.out
    specs = firstdrive.specs(
        plant_list=args.plants,
        profiles=profiles,
        backends=backends,
        seed=args.seed,
        first_drive_s=args.duration,
        work_dir=str((out / "runs").resolve()) if args.keep_logs else "",
    )
    print(f"lde evaluate --zoo --first-drive: {len(specs)} runs", file=sys.stderr)
    t0 = time.perf_counter()
    results = study.run_specs(
        specs, cluster_config(args), progress=not args.no_progress, desc="lde first drives", engine=engine
    )
    wall = time.perf_counter() - t0
    table = firstdrive.rows(results)
    out.mkdir(parents=True, exist_ok=True)
    write_rows(table, out / "first_drive.csv")
    text = (
        f"# First drives and light loads\n\n`{_command(args)} --first-drive` (seed {args.seed}; "
        f"{len(results)} runs in {wall:.0f} s)\n\n{firstdrive.summary_markdown(table)}\n\n"
        f"Per minute (NRMSE Fw / Mw %, RMS Fw error):\n\n{firstdrive.minutes_markdown(table)}\n"
    )
    (out / "first_drive.md").write_text(text)
    print(firstdrive.summary_markdown(table))
    print(f"\n{len(results)} runs in {wall:.0f} s; tables in {out}/first_drive.{{md,csv}}", file=sys.stderr)
    for r in results:
        if not r.ok:
            print(f"FAILED {r.spec.label}: {r.error}", file=sys.stderr)
    return 0 if all(r.ok for r in results) else 1


def _modes(args: argparse.Namespace) -> tuple[zoo.Mode, ...]:
    if args.warm and args.modes:
        raise ConfigError("--warm is --modes warm: give one of them")
    names = ("warm",) if args.warm else args.modes or ("cold", "warm")
    known = {m.value: m for m in zoo.Mode}
    bad = [n for n in names if n not in known]
    if bad:
        raise ConfigError(f"unknown mode(s) {', '.join(bad)} (modes: cold, warm)")
    return tuple(known[n] for n in dict.fromkeys(names))


def _command(args: argparse.Namespace) -> str:
    """The evaluate command line that reproduces this zoo run (for the table's header)."""
    parts = ["lde evaluate --zoo"]
    if args.warm:
        parts.append("--warm")
    if args.modes:
        parts.append(f"--modes {','.join(args.modes)}")
    for flag, val in (
        ("--plants", args.plants),
        ("--scenarios", _scenarios(args)),
        ("--profiles", args.profiles),
        ("--backends", args.backends),
        ("--prior", args.prior),
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
    if args.workers != 2:
        parts.append(f"--workers {args.workers}")
    parts.append(f"--out {args.out}")
    return " ".join(parts)
