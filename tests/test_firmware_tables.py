"""Generated constants: staleness, reproducibility, the Riccati solver and the scheduled
coefficients against the float model."""

from __future__ import annotations

import json
import math
import os
import platform
import re
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from firmware_model import gen_tables as gen
from firmware_model import tables
from firmware_model.qformat import q32
from firmware_model.riccati import solve_dare, steady_state_kf
from firmware_model.tables import FixedTables, tables_for
from lde.estimator.model import discrete_matrices
from lde.params import load_vehicle
from lde.units import KMH


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("reference")


def _fresh(vehicle) -> dict:
    """A fresh generation as the JSON file would hold it."""
    return json.loads(gen.dumps(gen.generate(vehicle)))


def test_shipped_tables_are_not_stale(vehicle):
    """Fails when the vehicle file, the tuning, the model or the generator changed without
    ``python -m firmware_model.gen_tables`` being run.

    Exact: the hash of the generator's inputs and every integer the firmware step uses (raw
    constants, shifts, Q formats, exponents); floats (the Riccati solver's gain table) within
    ``gen.FLOAT_TOL_ULP`` ULP, since LAPACK's last digits differ between CPUs and BLAS builds
    (``test_staleness_check_does_not_depend_on_the_blas_kernel``)."""
    shipped = tables.load_shipped(vehicle.name)
    assert shipped["inputs_sha256"] == gen.inputs_hash(vehicle), (
        "stale: run python -m firmware_model.gen_tables"
    )
    stale = gen.stale_entries(shipped, _fresh(vehicle))
    assert not stale, "stale: run python -m firmware_model.gen_tables:\n" + "\n".join(stale[:20])


def _shift_model(monkeypatch, rel: float) -> None:
    """The float model changes a little (lde.estimator.model is not among the hashed inputs)."""
    real = gen.discrete_matrices

    def shifted(vehicle, vx):
        d = real(vehicle, vx)
        return replace(d, Qd=d.Qd * (1.0 + rel))

    monkeypatch.setattr(gen, "discrete_matrices", shifted)


def _shift_derivation(monkeypatch, rel: float) -> None:
    """The generator derives one coefficient differently (not visible in the input hash)."""
    real = gen.coefficient_polys

    def shifted(*args, **kwargs):
        polys = dict(real(*args, **kwargs))
        c0, c1, c2 = polys["h10"]
        polys["h10"] = (c0 * (1.0 + rel), c1, c2)
        return polys

    monkeypatch.setattr(gen, "coefficient_polys", shifted)


@pytest.mark.parametrize(
    "change",
    ["vehicle mass +1 kg", "tuning q_fw +1 %", "model Qd +1e-6", "derivation h10 +1e-7", "generator version"],
)
def test_staleness_check_fails_when_an_input_changes(vehicle, monkeypatch, change):
    """The shipped file compared with a generation from a changed input: the check must see it.
    The model and derivation changes are below any float noise a test would forgive by accident
    (1e-6 and 1e-7 relative) and leave the input hash as it is: the regenerated values catch them."""
    shipped = tables.load_shipped(vehicle.name)
    v = vehicle
    if change == "vehicle mass +1 kg":
        v = vehicle.with_body(mass=vehicle.body.mass + 1.0)
    elif change == "tuning q_fw +1 %":
        v = replace(vehicle, estimator=replace(vehicle.estimator, q_fw=vehicle.estimator.q_fw * 1.01))
    elif change == "model Qd +1e-6":
        _shift_model(monkeypatch, 1e-6)
    elif change == "derivation h10 +1e-7":
        _shift_derivation(monkeypatch, 1e-7)
    else:
        monkeypatch.setattr(gen, "GENERATOR_VERSION", gen.GENERATOR_VERSION + 1)
    stale = gen.stale_entries(shipped, _fresh(v))
    assert stale, f"{change}: the staleness check did not notice"
    hash_changed = any(e.startswith("/inputs_sha256") for e in stale)
    if change.startswith(("model", "derivation")):
        assert not hash_changed  # caught by the regenerated values alone
        kind = "/ss_table/" if change.startswith("model") else "/coefs/8/terms/0/0"
        assert any(e.startswith(kind) for e in stale), stale[:5]
    else:
        assert hash_changed
    if change.startswith(("vehicle", "tuning", "derivation")):
        # an integer the firmware step uses changed, and is compared exactly
        assert any("/terms/" in e or e.startswith(("/p0_n", "/qd_n", "/r_n")) for e in stale), stale[:5]


def test_stale_entries_tolerance_is_in_ulp_for_floats_only():
    x = 354.3135233819351
    ulp = math.ulp(x)
    base = {"gain": [x], "raw": [1348256446], "q": "Q2.29"}
    assert gen.stale_entries(base, base) == []
    assert gen.stale_entries({**base, "gain": [x + 2**20 * ulp]}, base) == []
    assert gen.stale_entries({**base, "gain": [x + 2**26 * ulp]}, base) == [
        f"/gain/0: {x + 2**26 * ulp!r} instead of {x!r} (tolerance {gen.FLOAT_TOL_ULP} ULP)"
    ]
    assert gen.stale_entries({**base, "raw": [1348256447]}, base) == [
        "/raw/0: 1348256447 instead of 1348256446"
    ]
    assert gen.stale_entries({**base, "raw": [1348256446.0]}, base)  # an int must stay an int
    assert gen.stale_entries({**base, "q": "Q3.28"}, base)
    assert gen.stale_entries({"gain": [x]}, base) == ["/q: missing", "/raw: missing"]
    assert gen.stale_entries({**base, "gain": [x, x]}, base)
    assert gen.stale_entries({**base, "old": 1}, base) == ["/old: not generated any more"]


#: OpenBLAS kernels every x86-64 CPU can run (SSE3, SSE4.2): forcing one of them gives another
#: CPU's last digits on this machine
_PORTABLE_CORES = ("Prescott", "Nehalem")
OPENBLAS_CORETYPE_IGNORED = "OPENBLAS_CORETYPE had no effect (no 'Core:' line with OPENBLAS_VERBOSE=2)"


def test_staleness_check_does_not_depend_on_the_blas_kernel(vehicle, tmp_path):
    """The generator under other OpenBLAS kernels (``OPENBLAS_CORETYPE``, as on another CPU): the float
    text differs from the shipped file, the staleness check still passes. Skipped, with the reason,
    where numpy's BLAS is not OpenBLAS with run-time kernel selection."""
    if platform.machine() not in ("x86_64", "AMD64"):
        pytest.skip(f"OPENBLAS_CORETYPE names x86-64 kernels; this is {platform.machine()}")
    shipped_text = gen.tables_path(vehicle.name).read_text()
    shipped = json.loads(shipped_text)
    differed = []
    for core in _PORTABLE_CORES:
        out = tmp_path / f"{core}.json"
        env = {**os.environ, "OPENBLAS_CORETYPE": core, "OPENBLAS_VERBOSE": "2"}
        cmd = [sys.executable, "-m", "firmware_model.gen_tables", "--out", str(out)]
        r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr
        # OpenBLAS names the kernel it runs (Prescott's is called Katmai); other BLAS libraries print nothing
        if re.search(r"Core: \w+", r.stdout + r.stderr) is None:
            pytest.skip(f"numpy's BLAS is not OpenBLAS with run-time kernels: {OPENBLAS_CORETYPE_IGNORED}")
        check = subprocess.run([*cmd, "--check"], env=env, capture_output=True, text=True, timeout=300)
        assert check.returncode == 0, check.stdout + check.stderr
        text = out.read_text()
        assert gen.stale_entries(shipped, json.loads(text)) == []
        if text != shipped_text:
            differed.append(core)
    if not differed:
        pytest.skip(
            f"the kernels {', '.join(_PORTABLE_CORES)} gave the shipped float text on this CPU: nothing shown"
        )


def test_generation_is_reproducible_and_hash_tracks_inputs(vehicle):
    a = gen.dumps(gen.generate(vehicle))
    b = gen.dumps(gen.generate(vehicle))
    assert a == b
    h = gen.inputs_hash(vehicle)
    assert json.loads(a)["inputs_sha256"] == h
    assert gen.inputs_hash(vehicle.with_body(mass=vehicle.body.mass + 1.0)) != h


def test_check_mode_detects_a_stale_file(vehicle, tmp_path):
    out = tmp_path / "t.json"
    assert gen.main(["--out", str(out)]) == 0
    assert gen.main(["--out", str(out), "--check"]) == 0
    out.write_text(out.read_text().replace('"dt_ns": 3900000', '"dt_ns": 3900001'))
    assert gen.main(["--out", str(out), "--check"]) == 1


@pytest.mark.parametrize("kmh", [30, 75, 130, 180])
def test_sda_matches_scipy(vehicle, kmh):
    d = discrete_matrices(vehicle, kmh * KMH)
    ours = solve_dare(d.Phi.T, d.H.T, d.Qd, d.R)
    ref = solve_discrete_are(d.Phi.T, d.H.T, d.Qd, d.R)
    np.testing.assert_allclose(ours, ref, rtol=1e-8, atol=1e-12 * np.abs(ref).max())
    ss = steady_state_kf(d.Phi, d.H, d.Qd, d.R)
    # a fixed point of the filter Riccati recursion
    P = ss.P_prior
    S = d.H @ P @ d.H.T + d.R
    Pn = d.Phi @ (P - P @ d.H.T @ np.linalg.solve(S, d.H @ P)) @ d.Phi.T + d.Qd
    np.testing.assert_allclose(Pn, P, rtol=1e-8, atol=1e-12 * np.abs(P).max())


@pytest.mark.parametrize("kmh", [30, 47.5, 100, 180, 250])
def test_coefficient_polynomials_equal_the_float_model(vehicle, kmh):
    """c0 + c1 w + c2 w^2 (normalised) reproduces lde.estimator.model's Phi, E, H, D at any speed."""
    tb = tables_for(vehicle)
    e, et = list(tb.sigma_exp), tb.sigma_t_exp
    s = [math.ldexp(1.0, k) for k in e]
    sT = math.ldexp(1.0, et)
    N = vehicle.steering.ratio
    v = kmh * KMH
    d = discrete_matrices(vehicle, v)
    polys = gen.coefficient_polys(vehicle, e, et, tb.dt_ns * 1e-9)
    val = {k: c[0] + c[1] / v + c[2] / v**2 for k, c in polys.items()}
    for name, (i, j) in {
        "phi00": (0, 0),
        "phi01": (0, 1),
        "phi02": (0, 2),
        "phi10": (1, 0),
        "phi11": (1, 1),
        "phi13": (1, 3),
    }.items():
        assert val[name] == pytest.approx(d.Phi[i, j] * s[j] / s[i], rel=1e-12)
    # the structural zeros and ones the step relies on
    assert d.Phi[0, 3] == d.Phi[1, 2] == 0.0
    np.testing.assert_array_equal(d.Phi[2:], np.eye(4)[2:])
    np.testing.assert_array_equal(d.H[0], [0, 1, 0, 0])
    assert d.H[1, 2] == d.H[1, 3] == d.D[0] == 0.0
    assert val["e0"] == pytest.approx(d.E[0] / (N * s[0]), rel=1e-12)
    assert val["e1"] == pytest.approx(d.E[1] / (N * s[1]), rel=1e-12)
    assert val["h10"] == pytest.approx(d.H[1, 0] * s[0] / sT, rel=1e-12)
    assert val["h11"] == pytest.approx(d.H[1, 1] * s[1] / sT, rel=1e-12)
    assert val["d1"] == pytest.approx(d.D[1] / (N * sT), rel=1e-12)


def test_formats_hold_their_ranges(vehicle):
    tb = tables_for(vehicle)
    q = q32(tb.f_cov)
    # P0 with 2x headroom; the normalised noise entries within 5 % (the per-step process noise
    # of beta and r is the smallest constant: docs/firmware.md gives its effect on the gains)
    for p0 in tb.p0_n:
        assert 2 * p0 <= q.raw_max
    for r in (*tb.r_n, *tb.qd_n):
        assert r >= 10
    # the supported physical ranges fit the state formats (Fw, Mw +-6000, yaw rate +-2 rad/s)
    assert q32(tb.f_state).real_max * 2.0 ** tb.sigma_exp[2] >= 6000.0
    assert q32(tb.f_state).real_max * 2.0 ** tb.sigma_exp[3] >= 6000.0
    assert q32(tb.yaw_input_frac()).real_max >= 2.0
    # w = 1/v at the minimum speed fits int32, and 1 << (f_speed + f_w) fits int64
    assert round(2 ** (tb.f_speed + tb.f_w) / tb.v_min_raw) < 2**31
    assert tb.f_speed + tb.f_w <= 62


def test_tables_for_another_vehicle_are_generated_in_memory(vehicle):
    other = vehicle.with_body(mass=1800.0)
    tb = tables_for(other)
    assert isinstance(tb, FixedTables)
    assert tb.inputs_sha256 == gen.inputs_hash(other) != tables_for(vehicle).inputs_sha256


def test_generator_rejects_a_tuning_outside_the_formats(vehicle):
    from lde.errors import ConfigError

    huge_p0 = replace(vehicle, estimator=replace(vehicle.estimator, p0_fw=1e6))
    with pytest.raises(ConfigError, match="headroom"):
        gen.generate(huge_p0)
    tiny_q = replace(vehicle, estimator=replace(vehicle.estimator, q_beta=1e-16))
    with pytest.raises(ConfigError, match="q_beta"):
        gen.generate(tiny_q)
