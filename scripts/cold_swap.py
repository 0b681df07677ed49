"""Where the cold error comes from (docs/design/studies.md, "The zoo: cars the estimator was not fitted to").

Replays cold zoo runs (the spec-sheet vehicle file only) with the plant's true parameters swapped
into the filter one at a time (Cf, Cr, K, the torsion twist in the profile's angle; from
``vcan_sim/zoo/true_values.csv``, for this diagnosis only), with one measurement switched off
(its variance made huge), or with filter constants set (``--hook`` as in ``scripts/tune_zoo.py``).
Learning is off in every variant (``L_ENABLE=0``) so that the filter alone is measured. Per run it
splits the Mw and Fw error into steady driving and manoeuvres (steering-wheel rate, 1 s RMS, above
``--man-rate`` deg/s) and reports each part's bias (mean error) and share of the squared error.

    PYTHONPATH=src:. python scripts/cold_swap.py --plants indep_twin,tires_minus25 --jobs 2
"""

from __future__ import annotations

import argparse
import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from tune_zoo import map_runs, run_engine, score, simulated, spec_vehicle

TRUE_CSV = Path(__file__).resolve().parents[1] / "vcan_sim" / "zoo" / "true_values.csv"
BIG = 1e12  # a measurement variance that switches the measurement off

VARIANTS = ("spec", "Cf", "Cr", "K", "twist", "tires", "all", "no_align", "no_ay")


def true_values(plant: str) -> dict[str, str]:
    with TRUE_CSV.open() as fh:
        for row in csv.DictReader(fh):
            if row["plant"] == plant:
                return row
    raise SystemExit(f"cold_swap: no plant {plant!r} in {TRUE_CSV}")


def make_hook(plant: str, profile: str, variant: str, extra: str):
    from tune_zoo import make_hook as tz_hook

    from lde.estimator import lateral as E
    from lde.estimator import learner as Ln

    tv = true_values(plant)
    twist = math.radians(float(tv["torsion_deg_per_Nm"])) if tv[f"angle_{profile}"] == "wheel" else 0.0
    sets: list[tuple[int, float]] = []
    if variant in ("Cf", "tires", "all"):
        sets.append((E.P_CF, float(tv["cf"])))
    if variant in ("Cr", "tires", "all"):
        sets.append((E.P_CR, float(tv["cr"])))
    if variant in ("K", "tires", "all"):
        sets.append((E.P_K, float(tv["k"])))
    if variant in ("twist", "all"):
        sets.append((E.P_CTB, twist))
    if variant == "no_align":
        sets.append((E.P_RT, BIG))
    if variant == "no_ay":
        sets.append((E.P_RA, BIG))
    base = tz_hook(extra)

    def hook(p: np.ndarray, lp: np.ndarray) -> None:
        if base is not None:
            base(p, lp)
        lp[Ln.L_ENABLE] = 0.0
        for i, v in sets:
            p[i] = v

    return hook


def split(block: Any, truth: dict[str, np.ndarray], man_rate: float) -> dict[str, float]:
    """Bias and share of the squared error of Fw and Mw in steady driving and in manoeuvres."""
    from lde.analysis import metrics
    from lde.status import VALID

    t = block.t_ns * 1e-9
    valid = (block.status & int(VALID)) != 0
    if not valid.any():
        return {}
    sel = valid & (t >= t[valid][0] + metrics.SETTLE_S)
    tt = truth["t"]
    dsw = truth["delta_sw"]
    rate = np.gradient(dsw, tt)
    dt = float(np.median(np.diff(tt)))
    n = max(1, int(round(1.0 / dt)))
    rms = np.sqrt(np.convolve(rate**2, np.ones(n) / n, mode="same"))
    man = np.interp(t[sel], tt, rms) > math.radians(man_rate)
    out: dict[str, float] = {"man_frac": float(man.mean())}
    for name, est, key in (("fw", block.fw, "Fw"), ("mw", block.mw, "Mw")):
        e = est[sel] - np.interp(t[sel], tt, truth[key])
        tot = float(np.sum(e**2)) or 1.0
        slow = np.convolve(e, np.ones(512) / 512, mode="same")  # 2 s moving average
        out[f"{name}_slow_share"] = float(np.sum(slow**2)) / tot
        for part, m in (("steady", ~man), ("man", man)):
            out[f"{name}_{part}_bias"] = abs(float(e[m].mean())) if m.any() else math.nan
            out[f"{name}_{part}_share"] = float(np.sum(e[m] ** 2)) / tot
    return out


def one(args: tuple) -> list[dict[str, Any]]:
    plant, profile, scenarios, seed, variants, extra, man_rate = args
    vehicle = spec_vehicle(plant)
    rows = []
    for sc in scenarios:
        frames, truth = simulated(plant, sc, profile, seed)
        if not bool(truth["ok"]):
            continue
        for v in variants:
            block, _ = run_engine(frames, profile, vehicle, None, None, make_hook(plant, profile, v, extra))
            r = {"plant": plant, "profile": profile, "scenario": sc, "variant": v}
            r.update(score(block, truth, sc))
            r.update(split(block, truth, man_rate))
            rows.append(r)
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    from lde.analysis.study.zoo import ZOO_SCENARIOS, plants

    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default=",".join(plants()))
    ap.add_argument("--profiles", default="lde,hyundai")
    ap.add_argument("--scenarios", default=",".join(s for s in ZOO_SCENARIOS if s != "lane_change"))
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--hook", default="", help="filter constants for every variant (tune_zoo --hook)")
    ap.add_argument("--man-rate", type=float, default=5.0, help="manoeuvre: steering-wheel rate RMS [deg/s]")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--out", default="")
    a = ap.parse_args(argv)
    variants = a.variants.split(",")
    tasks = [
        (pl, pr, a.scenarios.split(","), a.seed, variants, a.hook, a.man_rate)
        for pl in a.plants.split(",")
        for pr in a.profiles.split(",")
    ]
    rows = map_runs(one, tasks, a.jobs)
    report(rows, variants)
    if a.out:
        import json

        Path(a.out).write_text(json.dumps(rows, default=float))


def report(rows: list[dict[str, Any]], variants: list[str]) -> None:
    keys = list(dict.fromkeys((r["plant"], r["profile"]) for r in rows))
    print("mean NRMSE Fw / Mw % over the disturbed scenarios, learning off")
    print("plant/profile | " + " | ".join(variants))
    for k in keys:
        cells = []
        for v in variants:
            rs = [r for r in rows if (r["plant"], r["profile"]) == k and r["variant"] == v]
            cells.append(
                f"{100 * np.mean([r['fw'] for r in rs]):.1f}/{100 * np.mean([r['mw'] for r in rs]):.1f}"
            )
        print(f"{k[0]}/{k[1]} | " + " | ".join(cells))
    print(
        "all | "
        + " | ".join(
            f"{100 * np.mean([r['fw'] for r in rows if r['variant'] == v]):.1f}/"
            f"{100 * np.mean([r['mw'] for r in rows if r['variant'] == v]):.1f}"
            for v in variants
        )
    )
    spec = [r for r in rows if r["variant"] == variants[0] and "mw_man_share" in r]
    if not spec:
        return
    print(
        f"\n{variants[0]}: share of the squared error in manoeuvres (time share), "
        "|bias| steady / manoeuvre, share of the 2 s mean"
    )

    def mean(rs: list[dict[str, Any]], key: str, scale: float = 1.0) -> float:
        return scale * float(np.nanmean([r[key] for r in rs]))

    for k in keys:
        rs = [r for r in spec if (r["plant"], r["profile"]) == k]
        parts = [f"{k[0]}/{k[1]}: time {mean(rs, 'man_frac', 100):.0f} %"]
        for q, unit in (("mw", "Nm"), ("fw", "N")):
            parts.append(
                f"{q} {mean(rs, q + '_man_share', 100):.0f} %, bias {mean(rs, q + '_steady_bias'):.0f} / "
                f"{mean(rs, q + '_man_bias'):.0f} {unit}, slow {mean(rs, q + '_slow_share', 100):.0f} %"
            )
        print("; ".join(parts))


if __name__ == "__main__":
    main()
