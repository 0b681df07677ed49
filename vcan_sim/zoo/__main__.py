"""``python -m vcan_sim.zoo [list | identify [--write] [--plant NAME] | table]``.

- ``list``: the plants with their one-line descriptions.
- ``identify``: fit every plant's true values (:func:`vcan_sim.zoo.identify_plant`) and print them;
  ``--write`` also writes ``true_values.csv`` and each plant file's ``[tires]``.
- ``table``: the markdown table of ``true_values.csv`` (docs/design/simulator.md).
"""

from __future__ import annotations

import argparse
import sys
import time

from . import (
    TRUE_VALUES_CSV,
    description,
    identify_plant,
    markdown_table,
    plant_names,
    read_true_values,
    write_plant_tires,
    write_true_values,
)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m vcan_sim.zoo", description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", help="plants and their descriptions")
    ident = sub.add_parser("identify", help="fit the plants' true values")
    ident.add_argument("--write", action="store_true", help="write true_values.csv and the plants' [tires]")
    ident.add_argument("--plant", action="append", help="only this plant (repeatable; no --write then)")
    sub.add_parser("table", help="markdown table of true_values.csv")
    args = p.parse_args(argv)
    if args.cmd == "list":
        for name in plant_names():
            print(f"{name:16s} {description(name)}")
        return 0
    if args.cmd == "table":
        print(markdown_table(read_true_values()))
        return 0
    names = tuple(args.plant or plant_names())
    if args.write and args.plant:
        p.error("--write rewrites every plant: do not combine it with --plant")
    values = []
    for name in names:
        t0 = time.perf_counter()
        v = identify_plant(name)
        values.append(v)
        print(
            f"{name:16s} Cf {v.cf:7.0f} Cr {v.cr:7.0f} K {v.k:6.0f}  (static {v.cf_static:.0f} / "
            f"{v.cr_static:.0f} / {v.k_static:.0f})  m {v.mass:.0f} lf {v.lf:.3f}  "
            f"[{time.perf_counter() - t0:.1f} s]",
            file=sys.stderr,
        )
    if args.write:
        for v in values:
            write_plant_tires(v.plant, v.cf, v.cr, v.k)
        write_true_values(values)
        print(f"wrote {TRUE_VALUES_CSV} and the plants' [tires]", file=sys.stderr)
    print(markdown_table({v.plant: v for v in values}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
