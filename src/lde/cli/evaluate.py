"""``lde evaluate``: accuracy of the estimator on simulator scenarios (issue 6, item 1).

For every (scenario, payload, seed) the simulator produces CAN frames and truth, the estimator runs
over the frames, and the table reports, after a 2 s settling window: NRMSE of Fw and of Mw (about the
actual CG, as in the paper) with the Mw figure about the unloaded reference CG beside it; for a
bank-only scenario the Mw error is normalised by 1 m x max|Fw|; for a disturbance-free scenario the
figures are the RMS of the estimate in N and Nm (``lde.metrics``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from .. import study
from .study import add_cluster_arguments, add_run_arguments, cluster_config, parse_options


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate",
        help="accuracy table (NRMSE of Fw, Mw) of the estimator on simulator scenarios",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--scenario",
        action="append",
        metavar="NAME",
        help="scenario (repeatable; default: the accuracy set, see lde.study.EVALUATE_SCENARIOS)",
    )
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
    p.add_argument("--sim-vehicle", default="reference", help="simulated vehicle (default: reference)")
    p.add_argument("--seed", type=int, default=0, help="simulator seed")
    p.add_argument("--csv", type=Path, help="write the table as CSV")
    p.add_argument("--plot", type=Path, help="write estimates against truth as PNG")
    add_run_arguments(p)
    add_cluster_arguments(p)
    p.set_defaults(func=run, workers=0)


def run(args: argparse.Namespace) -> int:
    payloads = study.all_payloads() if args.all_payloads else tuple(args.payload or ("",))
    specs = study.evaluation_specs(
        scenarios=tuple(args.scenario or study.EVALUATE_SCENARIOS),
        payloads=payloads,
        est_vehicle=args.vehicle or "reference",
        sim_vehicle=args.sim_vehicle,
        seed=args.seed,
        duration=args.duration,
        estimator=args.estimator,
        backend=args.backend,
        profile=args.profile,
        sim_options=parse_options(args.sim_option, "--sim-option"),
        est_options=parse_options(args.est_option, "--est-option"),
        trace=args.plot is not None,
    )
    results = study.run_specs(specs, cluster_config(args), progress=not args.no_progress)
    print(study.table(results))
    if args.csv:
        study.write_csv(results, args.csv)
    if args.plot and any(r.trace is not None for r in results):
        study.plot_traces(results, args.plot)
    return 0 if all(r.ok for r in results) else 1
