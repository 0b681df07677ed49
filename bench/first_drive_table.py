"""One table of ``lde evaluate --zoo --first-drive`` runs made by several commands (plant batches,
seeds): the summary per case and profile for the tuning plants and for the held-out plants, each
figure beside its target, and the first drives minute by minute.

    lde evaluate --zoo --first-drive --plants indep_twin,compact_quick,suv_slow --seed 0 --out OUT/s0_a
    ...
    python bench/first_drive_table.py OUT/*/first_drive.csv > bench/results/first_drive/first_drive.md

The rows of every CSV given are joined (``--csv FILE`` writes them as one CSV too).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from lde.analysis.study import firstdrive
from lde.analysis.study.tables import write_rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csvs", nargs="+", type=Path, help="first_drive.csv files")
    ap.add_argument("--csv", type=Path, help="write the joined rows here")
    a = ap.parse_args()
    rows = [r for p in a.csvs for r in firstdrive.read_rows(p)]
    rows.sort(
        key=lambda r: (
            r["plant"] not in firstdrive.TUNING_PLANTS,
            r["plant"],
            r["profile"] != "lde",
            r["seed"],
        )
    )
    if a.csv:
        write_rows(rows, a.csv)
    seeds = sorted({r["seed"] for r in rows})
    tuning = [r for r in rows if r["plant"] in firstdrive.TUNING_PLANTS]
    held = [r for r in rows if r["plant"] not in firstdrive.TUNING_PLANTS]
    print(
        f"Seeds {', '.join(map(str, seeds))}; {len(rows)} runs; each cell: the span over plants and seeds "
        "(Fw / Mw).\n"
    )
    for name, part in (("Tuning plants", tuning), ("Held-out plants", held)):
        plants = sorted({r["plant"] for r in part})
        print(f"**{name}** ({', '.join(plants)}):\n")
        print(firstdrive.summary_markdown(part) + "\n")
    print("**First drives, minute by minute** (NRMSE Fw / Mw %, RMS Fw error):\n")
    print(firstdrive.minutes_markdown([r for r in rows if r["case"] == "first"]))


if __name__ == "__main__":
    main()
