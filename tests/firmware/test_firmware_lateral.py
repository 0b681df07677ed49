"""The lateral filter's fixed-point model (firmware_model.lateral, the ``fixed`` backend).

- the step is integer-only (the AST check of the paper model's step, on the lateral kernels);
- the same kernels run interpreted on unbounded Python ints give the same integers as the int64
  compiled run on a drive with extremes (so no int64 intermediate wrapped);
- the function tables (reciprocal, tanh, asin) and the scheduled coefficients against float;
- the coefficient set never saturates anywhere in the learned-parameter box, and the learner's push
  bounds lie inside that box;
- against the float lateral filter (its shadow) within 5 N / 2 Nm at every step on synthetic drives,
  with learning on: the learner's pushes re-quantise the coefficient set (bounded: only on a push,
  only from ``p``), and a learned-state file loaded from outside does too.
"""

from __future__ import annotations

import ast
import inspect
import json
import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from firmware_model import gen_lateral as GL
from firmware_model import lat_coefs as LC
from firmware_model import lateral as FX
from firmware_model.shadow import FW_BOUND_N, MW_BOUND_NM
from firmware_model.tables import lateral_tables_for
from lde.engine.backends import make_backend_state
from lde.engine.backends.fixed import step as lateral_fixed_step
from lde.engine.backends.float import FRESH_A, FRESH_R, FRESH_T
from lde.engine.receiver import (
    I_ASSIST_TORQUE,
    I_COLUMN_TORQUE,
    I_LAT_ACCEL,
    I_SPEED,
    I_STEERING_ANGLE,
    I_YAW_RATE,
    INPUT_NAMES,
)
from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.outputs import N_OUT, O_FW, O_GAIN, O_MW
from lde.params import load_vehicle
from lde.status import DEGRADED, SHADOW_DEVIATION, VALID
from lde.units import KMH

from helpers import TESTS
from helpers.firmware_drives import extreme_drive, lateral_drive

ROOT = TESTS.parent

FAST_PATH = [
    FX.step_kernel,
    FX.reset_kernel,
    FX._set_p0,
    FX._coef,
    FX._cmul,
    FX._update,
    FX._predict,
    FX._friction_sign,
    FX._outputs,
    FX._sat_total,
    FX.shr,
    FX.sat32,
    FX.add64,
    FX.mac,
    FX.msb,
    FX.recip,
    FX.tanh_q,
    FX.isqrt,
    FX._asin_poly,
    FX.asin_q,
]
FORBIDDEN_NAMES = {"float", "math", "np", "numpy", "round"}


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("reference")


@pytest.fixture(scope="module")
def lt(vehicle):
    return lateral_tables_for(vehicle)


@pytest.mark.parametrize("fn", FAST_PATH, ids=lambda f: f.__name__)
def test_fast_step_is_integer_only(fn):
    tree = ast.parse(textwrap.dedent(inspect.getsource(getattr(fn, "py_func", fn))))
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant):
            assert not isinstance(node.value, float), f"float literal {node.value!r}"
        if isinstance(node, ast.BinOp | ast.AugAssign):
            assert not isinstance(node.op, ast.Div), "true division '/'"
        if isinstance(node, ast.Name):
            assert node.id not in FORBIDDEN_NAMES, f"uses {node.id}"


# ----------------------------------------------------------------------------------- drives


def _float_run(p, inputs):
    """The float lateral filter (lde.estimator.lateral) over a drive; Fw, Mw and status per step."""
    x, P = np.zeros(E.NX), np.zeros((E.NX, E.NX))
    fs, ints = np.zeros(E.N_F), np.zeros(E.N_I, np.int64)
    E.reset_kernel(p, x, P, fs, ints)
    h, ph, out = np.zeros(E.NX), np.zeros(E.NX), np.zeros(N_OUT)
    t, speed, steer, yaw, tcol, tas, ay, fr, ftq, fa, mdps, esc = inputs
    n = len(t)
    fw, mw, st = np.zeros(n), np.zeros(n), np.zeros(n, np.int64)
    for k in range(n):
        st[k] = E.step_kernel(
            p, x, P, fs, ints, h, ph, int(t[k]), speed[k], steer[k], yaw[k], tcol[k], tas[k], ay[k],
            bool(fr[k]), bool(ftq[k]), bool(fa[k]), bool(mdps[k]), bool(esc[k]), out,
        )  # fmt: skip
        fw[k], mw[k] = out[O_FW], out[O_MW]
    return fw, mw, st


# ----------------------------------------------------------------------------------- no wrap


_INTERPRETED = """
import json, sys
import numpy as np
sys.path[:0] = {paths!r}
from firmware_model import lateral as FX
from firmware_model.tables import lateral_tables_for
from lde.estimator import lateral as E
from lde.params import load_vehicle
sys.path.insert(0, {tests!r})
from helpers.firmware_drives import extreme_drive
v = load_vehicle("reference")
res = FX.run_drive(lateral_tables_for(v), E.params_vector(v), extreme_drive(v), python_ints=True)
print(json.dumps({{k: np.asarray(a).astype(object).tolist() for k, a in res.items()}}))
"""


def test_interpreted_python_ints_equal_compiled_int64(vehicle, lt):
    """With numba disabled the kernels run on Python ints (no wrap-around possible); the compiled
    int64 run gives the same integers at every step: no intermediate wrapped, every saturation is
    the explicit one."""
    p = E.params_vector(vehicle)
    compiled = FX.run_drive(lt, p, extreme_drive(vehicle))
    env = dict(os.environ, NUMBA_DISABLE_JIT="1")
    code = _INTERPRETED.format(paths=[str(ROOT / "src"), str(ROOT)], tests=str(TESTS))
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    interp = json.loads(proc.stdout)
    for key, a in compiled.items():
        got = np.asarray(interp[key], dtype=object)
        assert got.shape == a.shape, key
        bad = np.flatnonzero(got.ravel() != a.astype(object).ravel())
        assert bad.size == 0, f"{key}: first difference at flat index {bad[:5]}"
    sat = compiled["sat"]
    assert sat[FX.S_IN_SPEED] > 0 and sat[FX.S_IN_TORQUE] > 0  # the drive did reach the limits
    assert compiled["iout"].min() >= -(2**31) and compiled["iout"].max() < 2**31


# ----------------------------------------------------------------------------------- functions


def test_reciprocal_is_accurate(lt):
    tv, ft = FX.tables_vectors(lt)
    rng = np.random.default_rng(1)
    for a in [1, 2, 3, 7, 2**30 - 1, 2**30, 2**31 - 1, 2**40 + 12345, 2**61, *rng.integers(1, 2**62, 500)]:
        m, n = FX.recip(tv, ft, int(a))
        assert 2**29 <= m <= 2**30
        rel = m * 2.0 ** -(30 + n) * int(a) - 1.0
        assert abs(rel) < 4e-9, (a, rel)


def test_tanh_and_asin_tables_are_accurate(lt):
    tv, ft = FX.tables_vectors(lt)
    fu, fz = lt.formats["u"], lt.formats["z"]
    for u in np.linspace(-9.0, 9.0, 2001):
        got = FX.tanh_q(tv, ft, int(round(u * 2**fu))) * 2.0**-fz
        assert abs(got - math.tanh(u)) < 2e-4, u
    for x in np.linspace(-1.0, 1.0, 2001):
        got = FX.asin_q(tv, ft, int(round(x * 2**fz))) * 2.0**-fz
        assert abs(got - math.asin(x)) < 2e-5, x


# ----------------------------------------------------------------------------------- coefficients


def _w_raw(tv, ft, speed):
    m, n = FX.recip(tv, ft, int(round(speed * 2 ** tv[FX.T_F_SPEED])))
    w = FX.shr(m, tv[FX.T_RECIP_FRAC] + n - tv[FX.T_F_W] - tv[FX.T_F_SPEED])
    return w, FX.shr(w * w, tv[FX.T_F_W])


def test_scheduled_coefficients_match_the_float_polynomials(vehicle, lt):
    """Integer coefficients (coefficient set + w by the reciprocal) against the float polynomials
    at 30-460 km/h, for the vehicle's parameters and every corner of the parameter box: within
    8 LSB of their group's format plus 1e-7 relative."""
    tv, ft = FX.tables_vectors(lt)
    ex = [int(tv[s]) for s in FX.T_EX]
    groups = (tv[FX.T_F_PHI], tv[FX.T_F_E], tv[FX.T_F_H], tv[FX.T_F_D])
    p0 = E.params_vector(vehicle)
    for p in [p0, *GL.param_corners(p0)]:
        cs = np.zeros(FX.N_CS, np.int64)
        FX.coef_set_kernel(p, tv, cs)
        assert cs[FX.CS_NSAT] == 0
        polys = LC.polys(p, ex)
        for kmh in (30, 45, 80, 120, 180, 250, 460):
            w, w2 = _w_raw(tv, ft, kmh * KMH)
            sat = np.zeros(FX.N_SAT, np.int64)
            want = LC.evaluate(polys, 1.0 / (kmh * KMH))[:, 0]
            for k in range(LC.N_K):
                fg = groups[LC.COEF_GROUP[k]]
                got = FX._coef(cs, sat, k, w, w2) * 2.0**-fg
                assert abs(got - want[k]) <= 8 * 2.0**-fg + 1e-7 * abs(want[k]), (LC.COEF_NAMES[k], kmh, p)
            assert not sat.any()


def test_coefficient_polynomials_are_the_float_step(vehicle):
    """The polynomials (unnormalised) reproduce the float step's Phi rows and measurement rows."""
    p = E.params_vector(vehicle)
    m, iz, lf, lr, n, dt = (p[i] for i in (E.P_M, E.P_IZ, E.P_LF, E.P_LR, E.P_N, E.P_DT))
    cf, cr, k, s = p[E.P_CF], p[E.P_CR], p[E.P_K], p[E.P_S]
    for vx in (9.0, 27.0, 50.0):
        phi, h, _ = GL.physical_model(p, vx)
        assert phi[0, 0] == pytest.approx(1.0 - dt * 2.0 * (cf + cr) / (m * vx), rel=1e-12)
        assert phi[0, 1] == pytest.approx(-dt - dt * 2.0 * (lf * cf - lr * cr) / (m * vx * vx), rel=1e-12)
        assert phi[0, 2] == phi[0, 4] == pytest.approx(dt / (m * vx), rel=1e-12)
        assert phi[1, 1] == pytest.approx(
            1.0 - dt * 2.0 * (lf * lf * cf + lr * lr * cr) / (iz * vx), rel=1e-12
        )
        assert phi[1, 3] == pytest.approx(dt / iz, rel=1e-12)
        assert h[1, 1] == pytest.approx(-2.0 * k * lf / vx, rel=1e-12)
        assert h[2, 0] == pytest.approx(-2.0 * s * (cf + cr) / m, rel=1e-12)
        assert h[2, 2] == pytest.approx(1.0 / m, rel=1e-12)
        c = LC.evaluate(LC.polys(p, np.zeros(LC.N_EX, np.int64)), 1.0 / vx)[:, 0]
        assert c[LC.K_E0] * n == pytest.approx(dt * 2.0 * cf / (m * vx), rel=1e-12)
        assert c[LC.K_DA] * n == pytest.approx(2.0 * s * cf / m, rel=1e-12)


def test_learner_bounds_lie_inside_the_parameter_box(vehicle):
    """What the learner can push (its clamps) and what a learned-state file may hold (its
    plausibility check) is inside the box the coefficient formats were sized for."""
    assert GL.PARAM_BOX is Ln.PLAUSIBLE
    p = E.params_vector(vehicle)
    lp = Ln.learner_params(vehicle, False)
    rng = np.random.default_rng(0)
    for trial in range(200):
        q = p.copy()
        ls = Ln.init_state(q, lp, friction_prior=0.3)
        # absurd regression coefficients: the push's clamps must hold
        ls[Ln.LS_T3 : Ln.LS_T3 + Ln.N3] = rng.normal(0.0, 10.0 ** rng.uniform(-6, 6), Ln.N3)
        ls[Ln.LS_T1] = 10.0 ** rng.uniform(-9, 3)
        ls[Ln.LS_T2] = 10.0 ** rng.uniform(-3, 9)
        ls[Ln.LS_N] = 1e9 if trial % 2 else 0.0
        for _ in range(50):  # rate-limited: many pushes reach the clamps
            Ln.push(lp, ls, q)
        for name, (lo, hi) in GL.PARAM_BOX.items():
            v = q[{"cf": E.P_CF, "cr": E.P_CR, "k": E.P_K, "s": E.P_S}[name]]
            assert lo <= v <= hi, (name, v)


# ----------------------------------------------------------------------------------- vs float


def _inp_row(inputs, k):
    t, speed, steer, yaw, tcol, tas, ay, fr, ftq, fa, mdps, esc = inputs
    row = np.zeros(len(INPUT_NAMES))
    row[I_SPEED], row[I_STEERING_ANGLE], row[I_YAW_RATE] = speed[k], steer[k], yaw[k]
    row[I_COLUMN_TORQUE], row[I_ASSIST_TORQUE], row[I_LAT_ACCEL] = tcol[k], tas[k], ay[k]
    fresh = (FRESH_R if fr[k] else 0) | (FRESH_T if ftq[k] else 0) | (FRESH_A if fa[k] else 0)
    return int(t[k]), row, fresh, bool(mdps[k]), bool(esc[k])


def _run_backend(st, inputs):
    n = len(inputs[0])
    out = np.full(N_OUT, np.nan)
    fw, mw, gain = np.zeros(n), np.zeros(n), np.zeros(n)
    status = np.zeros(n, np.int64)
    for k in range(n):
        t, row, fresh, mdps, esc = _inp_row(inputs, k)
        status[k] = lateral_fixed_step(st.params, st.state, t, row, fresh, mdps, esc, out)
        fw[k], mw[k], gain[k] = out[O_FW], out[O_MW], out[O_GAIN]
    return fw, mw, status, gain


@pytest.mark.parametrize("kind", ["sweep", "gusts", "steer", "faults"])
def test_fixed_step_within_bound_of_float_filter(vehicle, lt, kind):
    """The integer step alone (no learner) against the float lateral filter: 5 N / 2 Nm at every
    step, the same status bits (except DEGRADED from a saturation, which must not occur here)."""
    inputs = lateral_drive(vehicle, kind)
    p = E.params_vector(vehicle)
    res = FX.run_drive(lt, p, inputs)
    fw_f, mw_f, st_f = _float_run(p, inputs)
    si = np.array([FX.to_si(lt, row) for row in res["iout"]])
    dfw = np.abs(si[:, 5] - fw_f)
    dmw = np.abs(si[:, 3] - mw_f)
    assert dfw.max() <= FW_BOUND_N, f"max |dFw| {dfw.max():.3f} N at {dfw.argmax()}"
    assert dmw.max() <= MW_BOUND_NM, f"max |dMw| {dmw.max():.3f} Nm at {dmw.argmax()}"
    assert not res["sat"].any(), dict(zip(FX.SAT_NAMES, res["sat"].tolist(), strict=True))
    np.testing.assert_array_equal(res["status"], st_f)


@pytest.mark.parametrize("column, assist", [(1.0, 2.7), (0.4, 1.0), (0.4, 2.7)])
def test_fixed_step_carries_the_torque_factors_of_unknown_scale(vehicle, lt, column, assist):
    """Torques read in other units than Nm (``column``, ``assist`` units per Nm) with the factors back
    to Nm in the parameter vector (what the learner pushes for a torque of unknown scale): the
    integer step within 5 N / 2 Nm of the float step at every step, and both within the same bounds
    of the drive read in Nm."""
    inputs = list(lateral_drive(vehicle, "gusts"))
    p_nm = E.params_vector(vehicle)
    fw_nm, mw_nm, _ = _float_run(p_nm, inputs)
    inputs[4] = inputs[4] * column
    inputs[5] = inputs[5] * assist
    p = p_nm.copy()
    p[E.P_KC], p[E.P_KA] = 1.0 / column, 1.0 / assist
    res = FX.run_drive(lt, p, tuple(inputs))
    fw_f, mw_f, st_f = _float_run(p, tuple(inputs))
    si = np.array([FX.to_si(lt, row) for row in res["iout"]])
    assert np.abs(si[:, 5] - fw_f).max() <= FW_BOUND_N and np.abs(si[:, 3] - mw_f).max() <= MW_BOUND_NM
    assert np.abs(fw_f - fw_nm).max() <= FW_BOUND_N and np.abs(mw_f - mw_nm).max() <= MW_BOUND_NM
    assert not res["sat"].any(), dict(zip(FX.SAT_NAMES, res["sat"].tolist(), strict=True))
    np.testing.assert_array_equal(res["status"], st_f)


def test_learning_requantises_the_coefficient_set(vehicle):
    """The fixed backend with its learner (fast learning: a short test drive) and its inline
    float shadow: every push re-derives the coefficient set from p and nothing else (the set at
    the end equals a fresh quantisation of the final p), the shadow stays within bound throughout,
    and the overlay gain follows the learned parameters."""
    st = make_backend_state("fixed", vehicle)
    lp = st.params.lp
    lp[Ln.L_MIN_SAMPLES] = 200.0  # learn from a short drive
    cs0 = st.state.cs.copy()
    p = st.state.p
    p0 = p.copy()
    inputs = lateral_drive(vehicle, "steer", duration_s=30.0)
    fw, mw, status, gain = _run_backend(st, inputs)
    sh = st.state.shadow_counts
    assert sh[0] == 0 and sh[1] <= FW_BOUND_N and sh[2] <= MW_BOUND_NM, sh
    assert not np.any(status & SHADOW_DEVIATION)
    assert not np.any(status & DEGRADED)
    assert np.any(status & VALID)
    assert not np.array_equal(p, p0), "the learner pushed nothing: the test drive is too short"
    cs = st.state.cs
    assert not np.array_equal(cs, cs0)
    fresh = np.zeros(FX.N_CS, np.int64)
    FX.coef_set_kernel(p, st.params.tv, fresh)
    np.testing.assert_array_equal(cs, fresh)
    want = p[E.P_K] / (p[E.P_N] * p[E.P_CF] * (p[E.P_LF] + p[E.P_LR]))
    assert gain[-1] == pytest.approx(want, rel=1e-12)


def test_parameters_changed_from_outside_requantise(vehicle):
    """A learned-state file writes p from outside the step: ``params_changed`` re-derives the
    coefficient set (the engine calls it after loading), and the fixed step follows the float
    shadow on the new tires within bound."""
    st = make_backend_state("fixed", vehicle)
    p = st.state.p
    cs0 = st.state.cs.copy()
    p[E.P_CF] *= 1.6
    p[E.P_CR] *= 0.7
    p[E.P_K] *= 1.3
    p[E.P_S] = 1.2
    st.params_changed()
    cs = st.state.cs
    assert not np.array_equal(cs, cs0) and cs[FX.CS_NSAT] == 0
    st.params.lp[Ln.L_ENABLE] = 0.0  # keep the new tires: the learner does not push
    fw, mw, status, gain = _run_backend(st, lateral_drive(vehicle, "gusts", duration_s=8.0))
    sh = st.state.shadow_counts
    assert sh[0] == 0 and sh[1] <= FW_BOUND_N and sh[2] <= MW_BOUND_NM, sh
    assert gain[-1] == pytest.approx(p[E.P_K] / (p[E.P_N] * p[E.P_CF] * (p[E.P_LF] + p[E.P_LR])))


def test_fixed_step_degrades_never_wraps_on_extremes(vehicle, lt):
    """Extreme inputs: counted, the step DEGRADED (or a fault bit), the states stay in int32."""
    res = FX.run_drive(lt, E.params_vector(vehicle), extreme_drive(vehicle))
    assert res["sat"].sum() > 0
    iout = res["iout"]
    assert iout.min() >= -(2**31) and iout.max() < 2**31
    valid = (res["status"] & VALID) != 0
    assert not np.any(valid & ((res["status"] & DEGRADED) != 0))


def test_lateral_tables_formats(lt):
    """The generated formats: the states share one scale for F_wind and F_bank (their sum is the
    output), the gain and coefficient formats are in range, every Q format is an int32 one."""
    assert lt.sigma_exp[LC.X_FA] == lt.sigma_exp[LC.X_FB]
    for f in (*lt.formats.values(), *lt.coef_groups.values()):
        assert -8 <= f <= 40
    assert len(lt.recip_seeds) == 1 << lt.recip_bits
