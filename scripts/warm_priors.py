"""Warm accuracy after different prior drives (docs/design/studies.md, "Warm after other earlier drives").

Reads ``scripts/tune_zoo.py --warm --prior NAME --out FILE`` outputs (one per prior) and prints,
per prior: met / mean Fw / Mw on the tuning and the held-out plants (:mod:`zoo_sets`), and per
plant x profile what the prior drive left in the filter (Cf, Cr, K, twist) against
``vcan_sim/zoo/true_values.csv`` (diagnosis only: nothing here is an input) with the learner's state.

    PYTHONPATH=src:. python scripts/warm_priors.py /tmp/wp/warm_prior_drive.json /tmp/wp/warm_slalom.json
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

from zoo_sets import TUNE, line


def true_twist(tv: object, profile: str) -> float:
    """The twist [deg/Nm] in the profile's angle: the torsion bar's where the angle is the wheel's."""
    where = getattr(tv, f"angle_{profile}")
    return float(tv.torsion_deg_per_Nm) if where == "wheel" else 0.0


def learned_table(rows: list[dict]) -> list[str]:
    """Per plant x profile: learned Cf, Cr [kN/rad], K [Nm/rad], twist [deg/Nm] (true in brackets)
    and the learner state at the end of the prior drive (0 prior only, 1 learning, 2 learned)."""
    from vcan_sim.zoo import read_true_values

    tvs = read_true_values()
    out = [
        "| plant | profile | Cf kN/rad | Cr kN/rad | K Nm/rad | twist deg/Nm | state |",
        "|---|---|---|---|---|---|---|",
    ]
    seen = set()
    for r in rows:
        key = (r["plant"], r["profile"])
        if key in seen or "Cf" not in r:
            continue
        seen.add(key)
        tv = tvs[r["plant"]]
        out.append(
            f"| {r['plant']} | {r['profile']} | {r['Cf'] / 1e3:.1f} ({tv.cf / 1e3:.1f}) "
            f"| {r['Cr'] / 1e3:.1f} ({tv.cr / 1e3:.1f}) | {r['K']:.0f} ({tv.k:.0f}) "
            f"| {r['ctb']:.2f} ({true_twist(tv, r['profile']):.2f}) | {r['st']:.0f} |"
        )
    return out


def errors(rows: list[dict]) -> str:
    """Mean |relative error| of the learned Cf, Cr, K over plant x profile pairs."""
    from vcan_sim.zoo import read_true_values

    tvs = read_true_values()
    pairs = {(r["plant"], r["profile"]): r for r in rows if "Cf" in r}
    e = {"Cf": [], "Cr": [], "K": []}
    for (plant, _), r in pairs.items():
        tv = tvs[plant]
        for k, t in (("Cf", tv.cf), ("Cr", tv.cr), ("K", tv.k)):
            e[k].append(abs(r[k] / t - 1))
    return ", ".join(f"{k} {100 * sum(v) / len(v):.1f} %" for k, v in e.items() if v)


def main(argv: Sequence[str] | None = None) -> None:
    for path in argv if argv is not None else sys.argv[1:]:
        rows = json.loads(Path(path).read_text())
        tune = [r for r in rows if r["plant"] in TUNE]
        held = [r for r in rows if r["plant"] not in TUNE]
        print(f"## {path}\n  tune:     {line(tune)}\n  held out: {line(held)}\n  all:      {line(rows)}")
        if any("Cf" in r for r in rows) and any(r.get("warm") for r in rows):
            print(f"  mean |learned / true - 1|: {errors(rows)}")
            print("\n".join(learned_table(rows)))
        print()


if __name__ == "__main__":
    main()
