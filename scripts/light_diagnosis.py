"""Where the light-load error comes from, with the truth at hand (docs/estimator.md, "Light loads").

Warm runs (after the plant's ``prior_drive``, seed + 500, learned on the same plant variant) of a
light scenario, replayed through the float lateral backend step by step on the input grid, with
the inputs or the filter replaced one at a time by what the truth says:

- ``base``: the grid as decoded from the frames (what ``lde replay`` runs; checked to reproduce it);
- ``oracle``: the plant's true Cf, Cr, K, friction and twist (``vcan_sim/zoo/true_values.csv``) in
  the filter, learning off;
- ``torque``: the torque sensors' truth (no noise, no quantisation; the rack's friction, inertia
  and damping still in it);
- ``align``: the measured torque replaced by the tires' true aligning torque (``T_align / N``; no
  rack dynamics, no friction, no quantisation; the filter's friction set to 0);
- ``angle``: the true pinion angle (no noise, no twist, no quantisation);
- ``ideal``: ``oracle`` + ``align`` + ``angle`` + the yaw rate's truth;

and plant variants (``--plant-mod``, simulated apart, prior drive too): ``nofric`` (rack friction
0), ``norack`` (rack inertia and damping a tenth), ``calm`` (the driver's torque noise a tenth),
``nonoise`` (every sensor noise 0).

Each line: RMS Fw error [N], NRMSE Fw / Mw [%], and the error's low-passed part (2 s moving average,
the bias) and the rest (fast) [N].

    PYTHONPATH=src:scripts:. python scripts/light_diagnosis.py --plants indep_twin --scenario light_crosswind
"""

from __future__ import annotations

import argparse
import math
import pickle
import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numba import njit
from tune_zoo import CACHE, PRIOR_SEED_OFFSET, map_runs, spec_vehicle

from lde.engine.backends import lateral_step
from lde.estimator.paper import N_OUT, O_BANK, O_FW, O_FW_WIND, O_LEARN, O_MW

PLANT_MODS = ("nofric", "norack", "calm", "nonoise")
GRID_MODS = ("base", "oracle", "torque", "align", "angle", "ideal")


def sim_params(plant: str, mod: str) -> Any:
    from lde.analysis.study.execute import load_sim_vehicle
    from vcan_sim.config import sim_params_from_vehicle

    sp = sim_params_from_vehicle(load_sim_vehicle(f"zoo:{plant}"))
    if mod == "nofric":
        sp = replace(sp, steering=replace(sp.steering, rack_coulomb=0.0))
    elif mod == "norack":
        st = sp.steering
        sp = replace(sp, steering=replace(st, rack_inertia=st.rack_inertia / 10, rack_damping=st.rack_damping / 10))
    elif mod == "calm":
        sp = replace(sp, driver=replace(sp.driver, noise_torque=sp.driver.noise_torque / 10))
    elif mod == "nonoise":
        s = sp.sensors
        sp = replace(
            sp,
            sensors=replace(
                s, column_torque_noise=0.0, assist_torque_noise=0.0, steering_angle_noise=0.0,
                steering_rate_noise=0.0, yaw_rate_noise=0.0, lat_accel_noise=0.0, speed_noise=0.0,
            ),
        )  # fmt: skip
    elif mod:
        raise SystemExit(f"unknown plant mod {mod}")
    return sp


def simulated(plant: str, scenario: str, profile: str, seed: int, mod: str = ""):
    from lde.analysis.study.execute import load_sim_vehicle
    from vcan_sim.run import simulate

    CACHE.mkdir(parents=True, exist_ok=True)
    path = CACHE / f"diag__{plant}__{scenario}__{profile}__{seed}__{mod}.pkl"
    if path.exists():
        with path.open("rb") as fh:
            return pickle.load(fh)
    sim = simulate(scenario, load_sim_vehicle(f"zoo:{plant}"), profile=profile, seed=seed,
                   sim_params=sim_params(plant, mod))  # fmt: skip
    data = (sim.frames, {k: np.asarray(v) for k, v in sim.truth.items()})
    tmp = path.with_suffix(f".{time.time_ns()}.tmp")
    with tmp.open("wb") as fh:
        pickle.dump(data, fh)
    tmp.replace(path)
    return data


@njit(cache=False)  # not cached: numba would not see a change of the lde kernels it inlines
def run_grid(bp, bs, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """The lateral backend step over a grid: inp (n, 7), fresh (n,) bit masks; out (n, N_OUT)."""
    st = np.zeros(t_ns.shape[0], np.int64)
    o = np.zeros(N_OUT)
    for k in range(t_ns.shape[0]):
        for j in range(N_OUT):
            o[j] = 0.0
        st[k] = lateral_step(bp, bs, t_ns[k], inp[k], fresh[k], mdps_ok[k], esc_ok[k], o)
        for j in range(N_OUT):
            out[k, j] = o[j]
    return st


def engine_for(plant: str, profile: str, learned: Path | None) -> Any:
    from lde.can.profiles import load_profile
    from lde.engine.engine import Engine

    eng = Engine(load_profile(profile), spec_vehicle(plant), "lateral", encode_outputs=False)
    if learned is not None:
        eng.load_learned(learned)
    return eng


def grid_arrays(frames: Any, profile: str) -> tuple[Any, np.ndarray, np.ndarray]:
    from lde.analysis.adaptive import grid_from_frames
    from lde.can.profiles import INPUT_NAMES

    g = grid_from_frames(frames.sort(), profile)
    inp = np.column_stack([g.values(n) for n in INPUT_NAMES]).astype(np.float64)
    fresh = np.zeros(len(g), np.int64)
    prev = np.concatenate([[np.iinfo(np.int64).min // 2], g.t_ns[:-1]])
    for i, n in enumerate(INPUT_NAMES):
        a = g.age_ns[n]
        new = (a >= 0) & (g.t_ns - a > prev)  # a sample since the previous step (lde.engine.loop)
        fresh |= new.astype(np.int64) << i
    return g, inp, fresh


def true_values(plant: str) -> Any:
    from vcan_sim.zoo import read_true_values

    return read_true_values()[plant]


def apply_grid_mod(mod: str, plant: str, profile: str, eng: Any, g: Any, inp: np.ndarray, truth: dict) -> np.ndarray:
    from lde.estimator import lateral as E
    from lde.estimator import learner as Ln

    inp = inp.copy()
    t = g.t_ns * 1e-9
    tt = truth["t"]

    def at(col: str) -> np.ndarray:
        return np.interp(t, tt, truth[col])

    p, lp = eng.est.info["p"], eng.est.info["lp"]
    tv = true_values(plant)
    if mod in ("oracle", "ideal"):
        p[E.P_CF], p[E.P_CR], p[E.P_K] = tv.cf, tv.cr, tv.k
        p[E.P_TFRIC] = tv.rack_friction_Nm
        above = (tv.angle_hyundai if profile == "hyundai" else tv.angle_lde) == "wheel"
        p[E.P_CTB] = math.radians(tv.torsion_deg_per_Nm) if above else 0.0
        p[E.P_DSW] = math.radians(tv.steer_offset_deg)
        p[E.P_BR] = math.radians(tv.yaw_bias_deg_s)
        lp[Ln.L_ENABLE] = 0.0
    if mod == "torque":
        inp[:, 0] = at("T_column")
        inp[:, 1] = at("T_assist")
    if mod in ("align", "ideal"):
        inp[:, 0] = at("T_align") / p[E.P_N]
        inp[:, 1] = 0.0
        p[E.P_TFRIC] = 0.0
        lp[Ln.L_ENABLE] = 0.0 if mod == "ideal" else lp[Ln.L_ENABLE]
    if mod in ("angle", "ideal"):
        inp[:, 2] = at("theta_p") + p[E.P_CTB] * inp[:, 0] + p[E.P_DSW]  # the filter takes its twist out
    if mod == "ideal":
        inp[:, 4] = at("r") + p[E.P_BR]
    if mod.startswith("anglelp"):  # the measured angle through a causal 2nd-order low-pass (Hz)
        inp[:, 2] = _lp2(inp[:, 2], 0.0039, float(mod[7:]))
    if mod == "angleq":  # the true angle quantised to the DBC's 0.1 deg (no sensor noise)
        lsb = math.radians(0.1)
        inp[:, 2] = np.round((at("theta_p" if profile == "lde" else "delta_sw")) / lsb) * lsb
    eng.est.params_changed()
    return inp


def _lp2(x: np.ndarray, dt: float, fc: float) -> np.ndarray:
    """Critically damped 2nd-order low-pass (semi-implicit Euler), starting at x[0]."""
    w = 2.0 * math.pi * fc
    fin = np.flatnonzero(np.isfinite(x))
    y, yd = float(x[fin[0]]), 0.0
    out = np.full_like(x, np.nan)
    for k in range(int(fin[0]), x.shape[0]):
        ydd = w * w * (x[k] - y) - 2.0 * w * yd
        yd += dt * ydd
        y += dt * yd
        out[k] = y
    return out


def errors(t: np.ndarray, fw: np.ndarray, mw: np.ndarray, valid: np.ndarray, truth: dict) -> dict[str, float]:
    from lde.analysis import metrics

    tr = metrics.Truth(t=truth["t"], fw=truth["Fw"], mw=truth["Mw"], mw_ref=truth["Mw_ref"])
    acc = metrics.accuracy(t, fw, mw, tr, valid=valid)
    keep = valid & (t >= t[0] + metrics.SETTLE_S)
    e = fw[keep] - np.interp(t[keep], truth["t"], truth["Fw"])
    n = int(round(2.0 / 0.0039))
    lowp = np.convolve(e, np.ones(n) / n, mode="same")
    return {
        "rms": acc.rms_fw,
        "fw": acc.nrmse_fw if math.isfinite(acc.nrmse_fw) else math.nan,
        "mw": acc.nrmse_mw if math.isfinite(acc.nrmse_mw) else acc.rms_mw,
        "bias": float(np.sqrt(np.mean(lowp**2))),
        "fast": float(np.sqrt(np.mean((e - lowp) ** 2))),
        "mean": float(np.mean(e)),
    }


def one(args: tuple) -> list[dict[str, Any]]:
    plant, profile, scenario, seed, plant_mod, grid_mods = args
    pf, _ = simulated(plant, "prior_drive", profile, seed + PRIOR_SEED_OFFSET, plant_mod)
    learned = Path(tempfile.mkdtemp(prefix="lde-diag-")) / "learned.json"
    eng = engine_for(plant, profile, None)
    eng.feed(pf.sort(), final=True)
    eng.save_learned(learned, 1.0)
    frames, truth = simulated(plant, scenario, profile, seed, plant_mod)
    rows = []
    # the product's run (frames through the engine) for the check of the grid runner
    eng = engine_for(plant, profile, learned)
    blk = eng.feed(frames.sort(), final=True)
    from lde.status import VALID

    ref_t = blk.t_ns * 1e-9
    for gm in grid_mods:
        eng = engine_for(plant, profile, learned)
        g, inp, fresh = grid_arrays(frames, profile)
        inp = apply_grid_mod(gm, plant, profile, eng, g, inp, truth)
        out = np.zeros((len(g), N_OUT))
        st = run_grid(eng.est.params, eng.est.state, g.t_ns, inp, fresh, g.mdps_ok, g.esc_ok, out)
        t = g.t_ns * 1e-9
        valid = (st & int(VALID)) != 0
        r = {"plant": plant, "profile": profile, "scenario": scenario, "seed": seed, "plant_mod": plant_mod,
             "grid_mod": gm, **errors(t, out[:, O_FW], out[:, O_MW], valid, truth)}  # fmt: skip
        if gm == "base":
            n = min(len(t), len(ref_t))
            r["check"] = float(np.max(np.abs(out[:n, O_FW] - blk.fw[:n])))
        rows.append(r)
    _ = (O_BANK, O_FW_WIND, O_LEARN)
    return rows


def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--plants", default="indep_twin,tires_minus25,suv_slow,angle_above_tb")
    ap.add_argument("--profiles", default="lde,hyundai")
    ap.add_argument("--scenario", default="light_crosswind")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--plant-mods", default="")
    ap.add_argument("--grid-mods", default=",".join(GRID_MODS))
    ap.add_argument("--jobs", type=int, default=2)
    a = ap.parse_args(argv)
    pmods = [""] + [m for m in a.plant_mods.split(",") if m]
    tasks = [
        (pl, pr, a.scenario, int(s), pm, tuple(a.grid_mods.split(",")))
        for s in a.seeds.split(",")
        for pl in a.plants.split(",")
        for pr in a.profiles.split(",")
        for pm in pmods
    ]
    rows = map_runs(one, tasks, a.jobs)
    for r in rows:
        chk = f" (grid check {r['check']:.2g} N)" if "check" in r else ""
        print(f"{r['plant'][:14]:14s} {r['profile'][:3]} s{r['seed']} {r['plant_mod'] or '-':8s} {r['grid_mod']:7s} "
              f"RMS {r['rms']:5.1f} N  NRMSE {100 * r['fw']:5.1f} / {100 * r['mw']:5.1f} %  bias {r['bias']:5.1f} N  "
              f"fast {r['fast']:5.1f} N  mean {r['mean']:6.1f} N{chk}")  # fmt: skip


if __name__ == "__main__":
    main()
