"""Generate the firmware model's constants from the float model: ``python -m firmware_model.gen_tables``.

Nothing in ``tables_<vehicle>.json`` is typed by hand: this script derives every scaling and
constant from :mod:`lde.estimator.model` (the float model) and :mod:`lde.params` (the vehicle file), writes
them with a SHA-256 of its inputs, and ``tests/test_firmware_tables.py`` fails when the file
differs from a fresh generation (stale tables): :func:`stale_entries` compares the input hash and every
integer (raw constants, Q formats, exponents) exactly and the floats within :data:`FLOAT_TOL_ULP`,
because the Riccati solution's last digits depend on the CPU and the BLAS build.

Normalised units (the one idea behind all Q formats)
----------------------------------------------------
Each state ``x_i`` is stored as ``X_i = x_i / sigma_i`` in Q15.16, where ``sigma_i = 2**e_i`` is the
power of two nearest to the steady-state a-priori standard deviation of that state (geometric mean
over the supported speeds, from the DARE below). The covariance is stored normalised the same way,
``Pn_ij = P_ij / (sigma_i sigma_j)`` in Q15.16, so that all four states (whose physical scales span
1e-4 rad to 1e2 N) get the same relative resolution and the same scaled matrices serve the state
and the covariance. Because the sigmas are powers of two, normalising is a change of Q format, not
a multiplication: ``X_Fw`` in Q15.16 is ``Fw`` in Q(15+e).(16-e) N. The aligning-torque
measurement is normalised by ``sigma_T`` (power of two nearest to its noise std), the yaw-rate
measurement by ``sigma_r`` (the state's unit).

Speed-scheduled coefficients
----------------------------
Every entry of the normalised ``Phi``, ``E``, ``H``, ``D`` is a polynomial in ``w = 1/vx``:
``c(w) = c0 + c1 w + c2 w**2`` (:func:`coefficient_polys`; the test checks it against
:func:`lde.estimator.model.discrete_matrices`). The step computes ``w`` with one integer division per step
and evaluates the polynomials: exact scheduling, no interpolation error, no table in RAM. Each
constant gets its own Q format (the most fractional bits that hold it), each coefficient a result
format that holds its range over the supported speeds.

The paper filter's sections (its normalisation, coefficients and steady-state gain table) are
generated too; the lateral filter's section (:mod:`firmware_model.gen_lateral`) is the one the
firmware model runs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import sys
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np

from lde.errors import ConfigError
from lde.estimator.model import discrete_matrices
from lde.params import Vehicle, load_vehicle
from lde.units import KMH, STEP_NS

from . import gen_lateral
from .qformat import QFormat, frac_bits_for
from .riccati import steady_state_kf

#: Bump when the layout or the derivation changes (part of the input hash).
GENERATOR_VERSION = 2  # 2: the lateral filter's section (firmware_model.gen_lateral)
TABLES_DIR = Path(__file__).resolve().parent

# --- fixed choices (documented in docs/firmware.md) ------------------------------------------
F_STATE = 16  #: normalised states, Q15.16
F_COV = 16  #: normalised covariance, Q15.16
F_SPEED = 24  #: speed input, Q7.24 m/s (0..128 m/s)
F_STEER = 27  #: steering-wheel angle input, Q4.27 rad (+-16 rad = +-916 deg)
F_TORQUE = 23  #: column and assist torque inputs, Q8.23 Nm (+-256 Nm)
MODEL_SPEED_MAX = 250.0 * KMH  #: above this the model runs at this speed (status DEGRADED) [m/s]
SS_TABLE_KMH = tuple(range(30, 181, 5))  #: steady-state gain table grid [km/h]

#: Runtime coefficients (normalised), in this order. Names: phiIJ = Phi_n[I, J], eI = E_n[I] per
#: rad of steering-wheel angle, h1J = H_n[1, J] (aligning-torque row), d1 = D_n[1] per rad of
#: steering-wheel angle.
COEF_NAMES = ("phi00", "phi01", "phi02", "phi10", "phi11", "phi13", "e0", "e1", "h10", "h11", "d1")
#: Coefficients of one group share a result format: phi (Phi_n), e (E_n), h (H_n row 1), d (D_n).
COEF_GROUP = {n: ("phi" if n.startswith("phi") else n[0]) for n in COEF_NAMES}
STATE_NAMES = ("beta", "r", "Fw", "Mw")
STATE_UNITS = ("rad", "rad/s", "N", "Nm")


#: binary orders by which a state's normalisation may exceed its steady-state std (to fit P0)
MAX_SIGMA_RAISE = 3


def _pow2_near(x: float) -> int:
    """Exponent e of the power of two nearest to x (in log scale)."""
    return int(round(math.log2(x)))


def steady_state_sweep(vehicle: Vehicle, speeds_ms: np.ndarray) -> dict[str, np.ndarray]:
    """Steady-state filters over ``speeds_ms``: prior/post std devs (n, 4) and gains (n, 4, 2) SI."""
    sd_prior, sd_post, gains = [], [], []
    for v in speeds_ms:
        d = discrete_matrices(vehicle, float(v))
        ss = steady_state_kf(d.Phi, d.H, d.Qd, d.R)
        sd_prior.append(np.sqrt(np.diag(ss.P_prior)))
        sd_post.append(np.sqrt(np.diag(ss.P_post)))
        gains.append(ss.gain)
    return {"sd_prior": np.array(sd_prior), "sd_post": np.array(sd_post), "gain": np.array(gains)}


def normalisation_exponents(vehicle: Vehicle, dt_ns: int = STEP_NS) -> tuple[list[int], int]:
    """(e_i for the 4 states, e_T for T_align): sigma = 2**e (see module docstring).

    sigma_i is the power of two nearest to the steady-state std of state i, raised (a coarser
    LSB, by at most :data:`MAX_SIGMA_RAISE` binary orders) where the initial covariance
    P0_ii + Qd_ii would not fit Q15.16 with 2x headroom: a stiff or heavy vehicle has small
    steady-state stds against the fixed initial std of the tuning. A P0 still out of proportion
    is left to the check in :func:`generate` (a ConfigError).
    """
    speeds = np.array(SS_TABLE_KMH, dtype=np.float64) * KMH
    sd = steady_state_sweep(vehicle, speeds)["sd_prior"]
    geo = np.exp(np.mean(np.log(sd), axis=0))
    est = vehicle.estimator
    dt = dt_ns * 1e-9
    q_cov = QFormat(32, F_COV)
    p0_sd = (est.p0_beta, est.p0_yaw, est.p0_fw, est.p0_mw)
    q_dens = (est.q_beta, est.q_yaw, est.q_fw, est.q_mw)
    e_state = []
    for s, p0, q in zip(geo, p0_sd, q_dens, strict=True):
        e0 = e = _pow2_near(float(s))
        # P0_ii + Qd_ii in normalised units (the check in generate()), 2x headroom
        while e < e0 + MAX_SIGMA_RAISE and not q_cov.fits((p0**2 + q * dt) / math.ldexp(1.0, e) ** 2, 2.0):
            e += 1
        e_state.append(e)
    e_t = _pow2_near(math.sqrt(vehicle.estimator.r_align))
    return e_state, e_t


def coefficient_polys(
    vehicle: Vehicle, e_state: list[int], e_t: int, dt: float
) -> dict[str, tuple[float, float, float]]:
    """(c0, c1, c2) of every runtime coefficient: c(w) = c0 + c1 w + c2 w^2 with w = 1/vx [s/m].

    From lde.estimator.model (Phi = I + A dt, E = B dt) in normalised units X_i = x_i / s_i:
    Phi_n[i, j] = Phi[i, j] s_j / s_i;  E_n[i] = E[i] / (N s_i);  H_n[1, j] = H[1, j] s_j / s_T;
    D_n[1] = D[1] / (N s_T)   (E_n, D_n per rad of steering-wheel angle: delta_f = delta_sw / N).
    """
    b, t = vehicle.body, vehicle.tires
    m, iz, lf, lr, cf, cr, k = b.mass, b.yaw_inertia, b.lf, b.lr, t.cf, t.cr, t.align_rate
    n = vehicle.steering.ratio
    sb, sr, sF, sM = (math.ldexp(1.0, e) for e in e_state)
    sT = math.ldexp(1.0, e_t)
    return {
        # beta+ = (1 - dt 2(Cf+Cr)/(m vx)) beta + dt (-1 - 2(lf Cf - lr Cr)/(m vx^2)) r + dt Fw/(m vx) + ...
        "phi00": (1.0, -dt * 2.0 * (cf + cr) / m, 0.0),
        "phi01": (-dt * sr / sb, 0.0, -dt * 2.0 * (lf * cf - lr * cr) / m * sr / sb),
        "phi02": (0.0, dt / m * sF / sb, 0.0),
        # r+ = -dt 2(lf Cf - lr Cr)/Iz beta + (1 - dt 2(lf^2 Cf + lr^2 Cr)/(Iz vx)) r + dt Mw/Iz + ...
        "phi10": (-dt * 2.0 * (lf * cf - lr * cr) / iz * sb / sr, 0.0, 0.0),
        "phi11": (1.0, -dt * 2.0 * (lf * lf * cf + lr * lr * cr) / iz, 0.0),
        "phi13": (dt / iz * sM / sr, 0.0, 0.0),
        # E = dt [2 Cf/(m vx), 2 lf Cf/Iz], per rad of delta_sw
        "e0": (0.0, dt * 2.0 * cf / m / (n * sb), 0.0),
        "e1": (dt * 2.0 * lf * cf / iz / (n * sr), 0.0, 0.0),
        # T_align = 2K (delta_f - beta - lf r / vx)
        "h10": (-2.0 * k * sb / sT, 0.0, 0.0),
        "h11": (0.0, -2.0 * k * lf * sr / sT, 0.0),
        "d1": (2.0 * k / (n * sT), 0.0, 0.0),
    }


def _const(value: float) -> tuple[int, int]:
    """(raw, n_frac) of a generated constant: int32 with the most fractional bits that hold it."""
    if value == 0.0:
        return 0, 0
    f = frac_bits_for(abs(value), headroom=1.0)
    raw, sat = QFormat(32, f).to_raw(value)
    if sat:  # cannot happen with frac_bits_for; guard against a silent clamp
        raise ConfigError(f"constant {value!r} does not fit Q.{f}")
    return raw, f


def _tuning_inputs(vehicle: Vehicle) -> dict[str, Any]:
    return {
        "body": asdict(vehicle.body),
        "steering": asdict(vehicle.steering),
        "tires": asdict(vehicle.tires),
        "estimator": asdict(vehicle.estimator),
        "learning": asdict(vehicle.learning),  # the accelerometer scale's prior (lateral section)
    }


def inputs_hash(vehicle: Vehicle, dt_ns: int = STEP_NS) -> str:
    """SHA-256 over everything the tables derive from (floats as repr: exact)."""
    payload = {
        "generator_version": GENERATOR_VERSION,
        "dt_ns": dt_ns,
        "vehicle": _tuning_inputs(vehicle),
        "fixed": [F_STATE, F_COV, F_SPEED, F_STEER, F_TORQUE, MODEL_SPEED_MAX, list(SS_TABLE_KMH)],
        "coefs": list(COEF_NAMES),
        "lateral": gen_lateral.fixed_choices(),
    }
    text = json.dumps(payload, sort_keys=True, default=repr)
    return hashlib.sha256(text.encode()).hexdigest()


def generate(vehicle: Vehicle, dt_ns: int = STEP_NS) -> dict[str, Any]:
    """All constants of the firmware model for ``vehicle`` (a JSON-ready dict; see module docstring)."""
    dt = dt_ns * 1e-9
    e_state, e_t = normalisation_exponents(vehicle, dt_ns)
    sig = [math.ldexp(1.0, e) for e in e_state]
    sT = math.ldexp(1.0, e_t)
    est = vehicle.estimator

    v_min = est.min_speed
    v_max = MODEL_SPEED_MAX
    q_speed = QFormat(32, F_SPEED)
    v_min_raw, _ = q_speed.to_raw(v_min)
    v_max_raw, _ = q_speed.to_raw(v_max)
    # w = 1/vx: the largest value at the smallest speed
    f_w = frac_bits_for(1.0 / (v_min_raw * q_speed.lsb), headroom=1.0)

    polys = coefficient_polys(vehicle, e_state, e_t, dt)
    w_grid = np.linspace(1.0 / v_max, 1.0 / (v_min_raw * q_speed.lsb), 257)
    # one result format per coefficient group, so that a row of products accumulates exactly
    group_max: dict[str, float] = {}
    for name in COEF_NAMES:
        c = polys[name]
        vals = c[0] + c[1] * w_grid + c[2] * w_grid**2
        g = COEF_GROUP[name]
        group_max[g] = max(group_max.get(g, 0.0), float(np.max(np.abs(vals))))
    group_frac = {g: frac_bits_for(mx, headroom=1.0) for g, mx in group_max.items()}
    coefs = []
    for name in COEF_NAMES:
        c = polys[name]
        f_c = group_frac[COEF_GROUP[name]]
        terms = []
        for j, cj in enumerate(c):
            raw, f = _const(cj)
            # term j is c_j * w^j: raw Q(f) times Q(f_w) (j >= 1) -> shift right to Q(f_c)
            shift = (f + (f_w if j > 0 else 0) - f_c) if raw != 0 else 0
            terms.append([raw, f, shift])
        coefs.append(
            {"name": name, "group": COEF_GROUP[name], "n_frac": f_c, "terms": terms, "real": list(c)}
        )

    # measurement noise, process noise, initial covariance, in normalised Q15.16
    q_cov = QFormat(32, F_COV)
    r_n = [q_cov.to_raw(est.r_yaw / sig[1] ** 2)[0], q_cov.to_raw(est.r_align / sT**2)[0]]
    q_dens = (est.q_beta, est.q_yaw, est.q_fw, est.q_mw)
    qd_n = [q_cov.to_raw(q * dt / s**2)[0] for q, s in zip(q_dens, sig, strict=True)]
    p0_sd = (est.p0_beta, est.p0_yaw, est.p0_fw, est.p0_mw)
    p0_real = [p**2 / s**2 for p, s in zip(p0_sd, sig, strict=True)]
    for i, p in enumerate(p0_real):
        if not q_cov.fits(p + qd_n[i] * q_cov.lsb, headroom=2.0):
            raise ConfigError(
                f"{vehicle.name}: initial std of {STATE_NAMES[i]} ({p0_sd[i]:.3g}) is {math.sqrt(p):.3g} "
                f"times its steady-state scale: the fixed-point covariance ({q_cov}) has no 2x headroom"
            )
    q_names = ("q_beta", "q_yaw", "q_fw", "q_mw")
    noise = (("r_yaw", r_n[0]), ("r_align", r_n[1]), *zip(q_names, qd_n, strict=True))
    for name, raw in noise:
        if raw < (16 if name.startswith("r_") else 1):
            raise ConfigError(
                f"{vehicle.name}: estimator {name} is too small against the covariance scale for the "
                f"fixed-point formats ({raw} LSB of {q_cov})"
            )
    p0_n = [q_cov.to_raw(p)[0] for p in p0_real]

    # gain format: |Kg_i| <= sqrt(Pn_ii / Rn) for a scalar update; the largest Pn_ii is P0 (+ Qd)
    k_bound = math.sqrt(max(p0_real) * 1.1 / min(r * q_cov.lsb for r in r_n))
    f_gain = frac_bits_for(k_bound, headroom=2.0)

    # T_align = N (T_column + T_assist) / s_T, normalised
    n_over_st = _const(vehicle.steering.ratio / sT)

    # the steady-state gain table (alternative algorithm; SI, float)
    ss_speeds = np.array(SS_TABLE_KMH, dtype=np.float64) * KMH
    sweep = steady_state_sweep(vehicle, ss_speeds)

    physical = []
    for i, e in enumerate(e_state):
        fmt = QFormat(32, F_STATE - e)
        physical.append(
            {
                "state": STATE_NAMES[i],
                "unit": STATE_UNITS[i],
                "sigma_exp": e,
                "q": str(fmt),
                "lsb": fmt.lsb,
                "max": fmt.real_max,
            }
        )

    return {
        "schema": GENERATOR_VERSION,
        "inputs_sha256": inputs_hash(vehicle, dt_ns),
        "vehicle": vehicle.name,
        "dt_ns": dt_ns,
        "formats": {
            "state": F_STATE,
            "cov": F_COV,
            "speed": F_SPEED,
            "steer": F_STEER,
            "torque": F_TORQUE,
            "w": f_w,
            "gain": f_gain,
            "coef_groups": group_frac,
        },
        "sigma_exp": {"state": e_state, "t_align": e_t},
        "state_formats": physical,
        "v_min_raw": v_min_raw,
        "v_max_raw": v_max_raw,
        "coefs": coefs,
        "n_over_st": list(n_over_st),
        "r_n": r_n,
        "qd_n": qd_n,
        "p0_n": p0_n,
        "converge_ns": int(round(est.converge_time * 1e9)),
        "ss_table": {
            "speeds_kmh": list(SS_TABLE_KMH),
            "gain": sweep["gain"].tolist(),
            "sd_prior": sweep["sd_prior"].tolist(),
            "sd_post": sweep["sd_post"].tolist(),
        },
        "lateral": gen_lateral.generate(vehicle, dt_ns),
    }


#: Tolerance of a float entry of a tables file against a fresh generation, in units in the last place
#: (ULP) of the larger of the two magnitudes: 2**24 ULP = 2**-28 (3.7e-9) relative. The float entries
#: (the steady-state gain table and its standard deviations from the Riccati solver, the coefficients'
#: real values, the formats' LSB and range) come out of numpy's LAPACK/BLAS, whose results differ in
#: the last digits between CPUs and BLAS kernels: up to 7.1e4 ULP (about 2**16) between OpenBLAS's
#: SkylakeX, Haswell, Sandybridge, Nehalem and Prescott kernels on this project's reference vehicle.
#: A real change of an input moves them by far more (1 kg of mass: up to 3 % of a gain), and it
#: changes the integer constants, which compare exactly. Only floats get a tolerance.
FLOAT_TOL_ULP = 2**24


def stale_entries(on_disk: Any, fresh: Any, where: str = "") -> list[str]:
    """Where a tables dict (``json.loads`` of a file) differs from a fresh generation; [] if up to date.

    Keys, list lengths, types, strings (the input hash) and integers (the raw constants, shifts,
    Q formats, exponents: what the integer step uses) must be equal; floats within
    :data:`FLOAT_TOL_ULP` ULP. ``fresh`` should itself be a JSON round trip (:func:`dumps`).
    """
    here = where or "<root>"
    if isinstance(fresh, dict):
        if not isinstance(on_disk, dict):
            return [f"{here}: {type(on_disk).__name__} instead of an object"]
        out = [f"{where}/{k}: missing" for k in sorted(fresh.keys() - on_disk.keys())]
        out += [f"{where}/{k}: not generated any more" for k in sorted(on_disk.keys() - fresh.keys())]
        for k in sorted(fresh.keys() & on_disk.keys()):
            out += stale_entries(on_disk[k], fresh[k], f"{where}/{k}")
        return out
    if isinstance(fresh, list):
        if not isinstance(on_disk, list) or len(on_disk) != len(fresh):
            return [f"{here}: {_short(on_disk)} instead of a list of {len(fresh)}"]
        return [
            e
            for i, (a, b) in enumerate(zip(on_disk, fresh, strict=True))
            for e in stale_entries(a, b, f"{where}/{i}")
        ]
    if isinstance(fresh, float) and type(on_disk) is float:
        tol = FLOAT_TOL_ULP * math.ulp(max(abs(on_disk), abs(fresh)))
        if math.isnan(fresh) != math.isnan(on_disk) or abs(on_disk - fresh) > tol:
            return [f"{here}: {on_disk!r} instead of {fresh!r} (tolerance {FLOAT_TOL_ULP} ULP)"]
        return []
    if type(on_disk) is not type(fresh) or on_disk != fresh:
        return [f"{here}: {_short(on_disk)} instead of {_short(fresh)}"]
    return []


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


def tables_path(vehicle_name: str) -> Path:
    return TABLES_DIR / f"tables_{vehicle_name}.json"


def dumps(tables: dict[str, Any]) -> str:
    """The canonical text of a tables file (written by this script; compared by :func:`stale_entries`)."""
    return json.dumps(tables, indent=1, sort_keys=True) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m firmware_model.gen_tables", description=(__doc__ or "").split("\n")[0]
    )
    ap.add_argument("--vehicle", default="reference", help="shipped vehicle name or TOML file")
    ap.add_argument(
        "--out", type=Path, default=None, help="output file (default: firmware_model/tables_<name>.json)"
    )
    ap.add_argument("--check", action="store_true", help="exit 1 if the file on disk is stale")
    args = ap.parse_args(argv)
    vehicle = load_vehicle(args.vehicle)
    text = dumps(generate(vehicle))
    out = args.out or tables_path(vehicle.name)
    if args.check:
        try:
            stale = stale_entries(json.loads(out.read_text()), json.loads(text))
        except (OSError, ValueError) as exc:  # missing, unreadable or not JSON
            print(f"{out}: STALE (run python -m firmware_model.gen_tables): cannot read it: {exc}")
            return 1
        if not stale:
            print(f"{out}: up to date")
            return 0
        print(f"{out}: STALE (run python -m firmware_model.gen_tables): {len(stale)} entries differ")
        for line in stale[:10]:
            print(f"  {line}")
        return 1
    out.write_text(text)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
