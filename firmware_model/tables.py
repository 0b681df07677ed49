"""The generated constants as a typed, immutable object (loaded from ``tables_<vehicle>.json``).

The shipped file is for the reference vehicle; for any other vehicle the same generator
(:func:`firmware_model.gen_tables.generate`) runs in memory, so every backend always uses
constants derived from the vehicle it is given. :func:`tables_for` caches by the input hash.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from lde.params import Vehicle
from lde.units import STEP_NS

from . import gen_tables as gen

# coefficient slots (the order of gen_tables.COEF_NAMES)
C_PHI00, C_PHI01, C_PHI02, C_PHI10, C_PHI11, C_PHI13, C_E0, C_E1, C_H10, C_H11, C_D1 = range(11)
N_COEF = 11


@dataclass(frozen=True)
class FixedTables:
    """Everything the integer step needs, as plain ints (see :mod:`firmware_model.gen_tables`).

    Attributes:
        f_state, f_cov, f_speed, f_steer, f_torque, f_w, f_gain: fractional bits of the
            normalised state, normalised covariance, speed [m/s], steering-wheel angle [rad],
            torques [Nm], w = 1/vx [s/m] and the Kalman gain (normalised).
        f_phi, f_e, f_h, f_d: fractional bits of the coefficient groups Phi_n, E_n, H_n, D_n.
        sigma_exp: e_i with sigma_i = 2**e_i for beta, r, Fw, Mw; sigma_t_exp: e_T for T_align.
        coef_terms: per coefficient three (raw, shift) pairs: c = sum_j (raw_j * w^j) >> shift_j.
        v_min_raw, v_max_raw: hold below / clamp above this speed (Q f_speed).
        n_over_st: (raw, n_frac) of N / sigma_T.
        r_n, qd_n, p0_n: normalised R diagonal (2), Qd diagonal (4), P0 diagonal (4), Q f_cov.
        converge_ns: time after a (re)start with both measurements before VALID [ns].
        dt_ns: the model period [ns].
        inputs_sha256: hash of the generator inputs.
    """

    f_state: int
    f_cov: int
    f_speed: int
    f_steer: int
    f_torque: int
    f_w: int
    f_gain: int
    f_phi: int
    f_e: int
    f_h: int
    f_d: int
    sigma_exp: tuple[int, int, int, int]
    sigma_t_exp: int
    coef_terms: tuple[tuple[tuple[int, int], ...], ...]
    v_min_raw: int
    v_max_raw: int
    n_over_st: tuple[int, int]
    r_n: tuple[int, int]
    qd_n: tuple[int, int, int, int]
    p0_n: tuple[int, int, int, int]
    converge_ns: int
    dt_ns: int
    inputs_sha256: str
    raw: Any = field(default=None, compare=False, repr=False)  # the source dict (ss table, docs)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> FixedTables:
        f = d["formats"]
        g = f["coef_groups"]
        names = [c["name"] for c in d["coefs"]]
        if tuple(names) != gen.COEF_NAMES:
            raise ValueError(f"tables list coefficients {names}, expected {gen.COEF_NAMES}")
        terms = tuple(tuple((int(t[0]), int(t[2])) for t in c["terms"]) for c in d["coefs"])
        return cls(
            f_state=f["state"],
            f_cov=f["cov"],
            f_speed=f["speed"],
            f_steer=f["steer"],
            f_torque=f["torque"],
            f_w=f["w"],
            f_gain=f["gain"],
            f_phi=g["phi"],
            f_e=g["e"],
            f_h=g["h"],
            f_d=g["d"],
            sigma_exp=tuple(d["sigma_exp"]["state"]),
            sigma_t_exp=d["sigma_exp"]["t_align"],
            coef_terms=terms,
            v_min_raw=d["v_min_raw"],
            v_max_raw=d["v_max_raw"],
            n_over_st=tuple(d["n_over_st"]),
            r_n=tuple(d["r_n"]),
            qd_n=tuple(d["qd_n"]),
            p0_n=tuple(d["p0_n"]),
            converge_ns=d["converge_ns"],
            dt_ns=d["dt_ns"],
            inputs_sha256=d["inputs_sha256"],
            raw=d,
        )

    # --- boundary scalings (float only here and in the input/output conversion) ---------------
    def state_lsb(self, i: int) -> float:
        """Physical value of one raw unit of state i (rad, rad/s, N, Nm)."""
        return math.ldexp(1.0, self.sigma_exp[i] - self.f_state)

    def t_align_lsb(self) -> float:
        return math.ldexp(1.0, self.sigma_t_exp - self.f_state)

    def yaw_input_frac(self) -> int:
        """Fractional bits of the yaw-rate input: the normalised state r's format in rad/s."""
        return self.f_state - self.sigma_exp[1]

    def coef_array(self) -> np.ndarray:
        """(N_COEF, 3, 2) int64: (raw, shift) of every term (for the numba twin)."""
        return np.array(self.coef_terms, dtype=np.int64)


def load_shipped(vehicle_name: str = "reference") -> dict[str, Any]:
    """The tables file shipped in the package for ``vehicle_name``."""
    return json.loads(gen.tables_path(vehicle_name).read_text())


_CACHE: dict[str, FixedTables] = {}


def tables_for(vehicle: Vehicle, dt_ns: int = STEP_NS) -> FixedTables:
    """The constants for ``vehicle``: the shipped file when its input hash matches, else generated
    in memory by the same generator (cached by the input hash)."""
    key = gen.inputs_hash(vehicle, dt_ns)
    if key not in _CACHE:
        path = gen.tables_path(vehicle.name)
        d = json.loads(path.read_text()) if path.exists() else {}
        if d.get("inputs_sha256") != key:
            d = json.loads(gen.dumps(gen.generate(vehicle, dt_ns)))
        _CACHE[key] = FixedTables.from_dict(d)
    return _CACHE[key]


# --------------------------------------------------------------------------- the lateral filter


@dataclass(frozen=True)
class LateralTables:
    """The lateral fixed-point model's offline constants (:mod:`firmware_model.gen_lateral`): the
    formats and exponents, the function tables. The coefficient values are not here: the slow task
    quantises them from the parameter vector (:func:`firmware_model.lateral.coef_set_kernel`).

    Attributes:
        formats: fractional bits by name (state, cov, speed, steer, torque, rate, z, u, w, gain).
        coef_groups: fractional bits of the groups phi, e, h, d.
        sigma_exp: exponents of the five states; sigma_t_exp, sigma_a_exp: of the scaled aligning
            torque and lateral acceleration.
        recip_bits, recip_frac, recip_seeds; tanh_u_exp, tanh_seg_bits, tanh_table; asin_coefs,
        asin_half_pi: the function tables (ints).
    """

    formats: dict[str, int]
    coef_groups: dict[str, int]
    sigma_exp: tuple[int, ...]
    sigma_t_exp: int
    sigma_a_exp: int
    recip_bits: int
    recip_frac: int
    recip_seeds: tuple[int, ...]
    tanh_u_exp: int
    tanh_seg_bits: int
    tanh_table: tuple[int, ...]
    asin_coefs: tuple[int, ...]
    asin_half_pi: int
    raw: Any = field(default=None, compare=False, repr=False)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> LateralTables:
        f = d["formats"]
        return cls(
            formats={k: int(v) for k, v in f.items() if k != "coef_groups"},
            coef_groups={k: int(v) for k, v in f["coef_groups"].items()},
            sigma_exp=tuple(int(e) for e in d["sigma_exp"]["state"]),
            sigma_t_exp=int(d["sigma_exp"]["t_align"]),
            sigma_a_exp=int(d["sigma_exp"]["lat_accel"]),
            recip_bits=int(d["recip"]["bits"]),
            recip_frac=int(d["recip"]["frac"]),
            recip_seeds=tuple(int(v) for v in d["recip"]["seeds"]),
            tanh_u_exp=int(d["tanh"]["u_exp"]),
            tanh_seg_bits=int(d["tanh"]["seg_bits"]),
            tanh_table=tuple(int(v) for v in d["tanh"]["table"]),
            asin_coefs=tuple(int(v) for v in d["asin"]["coefs"]),
            asin_half_pi=int(d["asin"]["half_pi"]),
            raw=d,
        )

    def state_lsb(self, i: int) -> float:
        """Physical value of one raw unit of lateral state i (rad, rad/s, N, Nm, N)."""
        return math.ldexp(1.0, self.sigma_exp[i] - self.formats["state"])

    def t_align_lsb(self) -> float:
        return math.ldexp(1.0, self.sigma_t_exp - self.formats["state"])


def lateral_tables_for(vehicle: Vehicle, dt_ns: int = STEP_NS) -> LateralTables:
    """The lateral section of :func:`tables_for` (the same file, or generated in memory)."""
    tb = tables_for(vehicle, dt_ns)
    key = tb.inputs_sha256
    if key not in _LAT_CACHE:
        _LAT_CACHE[key] = LateralTables.from_dict(tb.raw["lateral"])
    return _LAT_CACHE[key]


_LAT_CACHE: dict[str, LateralTables] = {}
