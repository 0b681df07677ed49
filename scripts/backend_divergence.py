"""Why the fixed and float backends' Mw move apart where both learn (docs/firmware_lateral.md, "Fixed
vs float while the learners learn").

Diagnosis only, not the evaluation. Simulates one zoo run as ``lde evaluate --zoo`` does (spec sheet
only: the cold run), samples its inputs once through the data path (``lde.replay.replay``), then steps both
lateral backends per step from Python on the same sampled inputs (``lateral_fixed_step``,
``lde.engine.backends.float.step``: the same rows as the replay, checked) and prints

- the backends' largest Mw / Fw difference and the fixed backend's shadow maxima (its float step on
  the fixed learner's parameters: the integer step's own agreement);
- a trace: the Mw and F_wind differences, the learner's band-passed wind change ``e2`` (the input of
  ``L_WIND_Q``) and its difference, Cf, Cr, K as fixed/float - 1, the excited-sample counters;
- the variants: ``L_WIND_Q`` 0 in both learners, and the float backend whose learner reads the fixed
  filter's wind estimate (F_wind, M_wind) instead of its own (by hand: ``lde.estimator.lateral.step_kernel``
  then ``lde.estimator.learner.learner_step``, which reproduces the float step exactly when fed its own).

    PYTHONPATH=src:. python scripts/backend_divergence.py --plant suv_slow --scenario heavy_load
"""

from __future__ import annotations

import argparse
import tempfile

import numpy as np

from firmware_model.tables import lateral_tables_for
from lde.analysis.study.execute import load_sim_vehicle, simulate_run
from lde.analysis.study.spec import SPEC_SHEET, RunSpec
from lde.analysis.study.specsheet import spec_sheet_vehicle
from lde.can.profiles import load_profile
from lde.engine import backends as B
from lde.engine.backends import fixed as fixed_backend
from lde.engine.backends import float as float_backend
from lde.engine.receiver import (
    I_ASSIST_TORQUE,
    I_COLUMN_TORQUE,
    I_LAT_ACCEL,
    I_SPEED,
    I_STEERING_ANGLE,
    I_YAW_RATE,
)
from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.outputs import N_OUT, O_FW, O_FW_WIND, O_MW, O_MW_WIND
from lde.params import Vehicle
from lde.replay.replay import replay
from lde.status import VALID
from lde.units import STEP_NS


def fresh_masks(block) -> np.ndarray:
    """The inputs that brought a new sample since the previous step (``lde.engine.loop.sample_inputs``)."""
    t, ages = block.t_ns, block.ages
    prev = np.concatenate([[np.iinfo(np.int64).min], t[:-1]])
    new = (ages >= 0) & ((t[:, None] - ages) > prev[:, None])
    return (new * (1 << np.arange(ages.shape[1]))).sum(axis=1)


def step_backend(name: str, vehicle: Vehicle, block, fresh, torsion: bool, wind_q: float | None) -> dict:
    """One backend per step; per step its outputs, p and learner state."""
    st = B.make_backend_state(name, vehicle, angle_above_torsion_bar=torsion)
    if wind_q is not None:
        st.params.lp[Ln.L_WIND_Q] = wind_q
    fn = fixed_backend.step if name == "fixed" else float_backend.step
    p, ls = st.state.p, st.state.ls
    n = len(block)
    out = np.empty(N_OUT)
    rec = {"out": np.empty((n, N_OUT)), "p": np.empty((n, p.size)), "ls": np.empty((n, ls.size))}
    for k in range(n):
        out[:] = np.nan
        okm, oke = bool(block.ok[k, 0]), bool(block.ok[k, 1])
        fn(st.params, st.state, int(block.t_ns[k]), block.inputs[k], int(fresh[k]), okm, oke, out)
        rec["out"][k], rec["p"][k], rec["ls"][k] = out, p, ls
    rec["shadow"] = getattr(st.state, "shadow_counts", None)
    return rec


def float_fed(vehicle: Vehicle, block, fresh, torsion: bool, wind: np.ndarray | None) -> np.ndarray:
    """The float backend by hand; its learner reads ``wind`` (n, 2: F_wind, M_wind) instead of its own
    filter's wind estimate when given. Returns Mw per step."""
    st = B.make_backend_state("float", vehicle, angle_above_torsion_bar=torsion)
    p, x, P, fs, ints, h, ph, ls, lws = st.state
    lp = st.params[0]
    out = np.empty(N_OUT)
    mw = np.empty(len(block))
    for k in range(len(block)):
        u, f = block.inputs[k], int(fresh[k])
        okm, oke = bool(block.ok[k, 0]), bool(block.ok[k, 1])
        out[:] = np.nan
        status = E.step_kernel(
            p, x, P, fs, ints, h, ph, int(block.t_ns[k]), u[I_SPEED], u[I_STEERING_ANGLE], u[I_YAW_RATE],
            u[I_COLUMN_TORQUE], u[I_ASSIST_TORQUE], u[I_LAT_ACCEL], (f & B.FRESH_R) != 0,
            (f & B.FRESH_T) == B.FRESH_T, (f & B.FRESH_A) != 0, okm, oke, out,
        )  # fmt: skip
        seen = out.copy()
        if wind is not None:
            seen[O_FW_WIND], seen[O_MW_WIND] = wind[k]
        Ln.learner_step(
            lp, ls, lws, p, seen, u[I_SPEED], u[I_STEERING_ANGLE], u[I_YAW_RATE], u[I_COLUMN_TORQUE],
            u[I_ASSIST_TORQUE], u[I_LAT_ACCEL], fs[E.F_ZFRIC], okm and oke and (status & VALID) != 0,
        )  # fmt: skip
        E.wind_moment_output(p, out)
        mw[k] = out[O_MW]
    return mw


def summary(label: str, a: np.ndarray, b: np.ndarray, t: np.ndarray) -> str:
    d = a - b
    return (
        f"{label}: max |dMw| {np.nanmax(np.abs(d)):.4f} Nm, RMS dMw after 2 s "
        f"{np.sqrt(np.nanmean(d[t > 2.0] ** 2)):.4f} Nm"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--plant", default="suv_slow")
    ap.add_argument("--scenario", default="heavy_load")
    ap.add_argument("--profile", default="lde")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--every", type=float, default=1.0, help="trace period [s]")
    a = ap.parse_args()
    plant = f"zoo:{a.plant}"
    profile = load_profile(a.profile)
    torsion = profile.angle_above_torsion_bar
    vehicle = spec_sheet_vehicle(load_sim_vehicle(plant), tempfile.mkdtemp(prefix="lde-div-"))
    spec = RunSpec(
        scenario=a.scenario, est_vehicle=SPEC_SHEET, sim_vehicle=plant, seed=a.seed, profile=a.profile
    )
    frames = simulate_run(spec, a.scenario, a.seed).frames
    res = {b: replay(frames, profile, vehicle, b, output_frames=False) for b in ("fixed", "float")}
    block = res["fixed"].block
    t = (block.t_ns - block.t_ns[0]) / 1e9
    fresh = fresh_masks(block)
    fx = step_backend("fixed", vehicle, block, fresh, torsion, None)
    fl = step_backend("float", vehicle, block, fresh, torsion, None)
    for name, rec in (("fixed", fx), ("float", fl)):
        same = np.array_equal(rec["out"][:, O_MW], res[name].mw, equal_nan=True)
        print(f"per-step {name} == replay {name}: {same}")
    print(f"{a.plant}, {a.scenario}, {a.profile}, seed {a.seed}, spec sheet only; {len(t)} steps")
    print(summary("backends fixed - float", fx["out"][:, O_MW], fl["out"][:, O_MW], t))
    dfw = np.nanmax(np.abs(fx["out"][:, O_FW] - fl["out"][:, O_FW]))
    sh = fx["shadow"]
    print(f"  max |dFw| {dfw:.4f} N; fixed's shadow (same p): {sh[1]:.4f} N, {sh[2]:.4f} Nm")
    lx, lf = fx["ls"], fl["ls"]
    gates = (Ln.LS_N, Ln.LS_N + 1, Ln.LS_N + 2, Ln.LS_STATE)
    same_gates = all(np.array_equal(lx[:, i], lf[:, i]) for i in gates)
    print(f"  learners' excited-sample counters and learned state equal at every step: {same_gates}")
    for nm, i in (("Cf", E.P_CF), ("Cr", E.P_CR), ("K", E.P_K), ("s", E.P_S)):
        r = np.abs(fx["p"][:, i] / fl["p"][:, i] - 1.0)
        print(f"  {nm}: max |fixed/float - 1| {r.max():.1e} (t {t[r.argmax()]:.1f} s)")
    bp = Ln.LS_BP
    e2x, e2f = lx[:, bp + 2] - lx[:, bp + 3], lf[:, bp + 2] - lf[:, bp + 3]
    print()
    print("| t [s] | dMw [Nm] | dF_wind [N] | e2 float [N] | de2 [N] | Cf | Cr | K (fixed/float - 1) | n |")
    print("|---|---|---|---|---|---|---|---|---|")
    ox, of = fx["out"], fl["out"]
    for ts in np.arange(0.0, t[-1], a.every):
        k = int(np.searchsorted(t, ts))

        def rel(i: int, k: int = k) -> float:
            return float(fx["p"][k, i] / fl["p"][k, i] - 1.0)

        print(
            f"| {t[k]:.1f} | {ox[k, O_MW] - of[k, O_MW]:+.3f} | {ox[k, O_FW_WIND] - of[k, O_FW_WIND]:+.3f} | "
            f"{e2f[k]:.0f} | {e2x[k] - e2f[k]:+.3f} | {rel(E.P_CF):+.1e} | {rel(E.P_CR):+.1e} | "
            f"{rel(E.P_K):+.1e} | {lx[k, Ln.LS_N]:.0f} / {lf[k, Ln.LS_N]:.0f} |"
        )
    print()
    q0x = step_backend("fixed", vehicle, block, fresh, torsion, 0.0)
    q0f = step_backend("float", vehicle, block, fresh, torsion, 0.0)
    print(summary("L_WIND_Q 0 in both learners", q0x["out"][:, O_MW], q0f["out"][:, O_MW], t))
    fed = float_fed(vehicle, block, fresh, torsion, ox[:, [O_FW_WIND, O_MW_WIND]])
    print(summary("float backend, its learner fed the fixed filter's wind, vs float", fed, of[:, O_MW], t))
    print(summary("  the same vs the fixed backend", fed, ox[:, O_MW], t))
    lt = lateral_tables_for(vehicle, STEP_NS)
    lsb = np.array([lt.state_lsb(2), lt.state_lsb(3)])  # the integer filter's F_wind [N], M_wind [Nm] LSB
    rounded = np.round(of[:, [O_FW_WIND, O_MW_WIND]] / lsb) * lsb
    own = float_fed(vehicle, block, fresh, torsion, rounded)
    what = f"its learner's own wind estimate rounded to the integer LSB ({lsb[0]} N, {lsb[1]} Nm)"
    print(summary(f"float backend, {what}, vs float", own, of[:, O_MW], t))


if __name__ == "__main__":
    main()
