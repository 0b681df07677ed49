"""The zoo: simulated cars the estimator was never fitted to (issue 11, item 1; docs/simulator.md).

Each plant is a full vehicle file ``vcan_sim/zoo/<name>.toml`` with its own ``[sim]`` tables (tires,
steering, sensors, payload, aero, seats) and a one-line ``description``. Every plant differs from
every shipped vehicle file and from vcan_sim's default plant (``tests/sim/test_zoo.py``). The
estimator is given only a plant's spec sheet (mass, yaw inertia, lf, lr, tread, steering ratio:
:mod:`lde.analysis.study.specsheet`); nothing it reads is identified from a plant.

A plant's true linear-equivalent values (per-tire C_f, C_r and K fitted to its truth by
:func:`vcan_sim.identify.identify` over :data:`IDENTIFY_SCENARIOS` x :data:`IDENTIFY_SEEDS`, the
Magic Formula tangents at its static loads, its loaded mass properties, friction, offsets, where its
angle is sensed) are written beside the plants in ``true_values.csv`` for reporting only, and the
identified C_f, C_r, K also into the plant file's ``[tires]`` (the vehicle file format requires the
table; it makes the plant file usable as an oracle estimator file). Regenerate both with::

    python -m vcan_sim.zoo identify --write
"""

from __future__ import annotations

import csv
import re
import tomllib
from dataclasses import asdict, dataclass, fields
from pathlib import Path

import numpy as np

from lde.errors import ConfigError
from lde.params import Vehicle, load_vehicle
from lde.units import DEG

from ..config import sim_params_from_vehicle
from ..identify import identify, static_stiffness
from ..payload import combined, loaded_body, payload_by_name
from ..run import simulate
from ..sensors import angle_below_torsion_bar

ZOO_DIR = Path(__file__).resolve().parent
TRUE_VALUES_CSV = ZOO_DIR / "true_values.csv"
#: the truth the true values are fitted to: the paper's light and heavy lateral load
IDENTIFY_SCENARIOS = ("light_load", "heavy_load")
IDENTIFY_SEEDS = (0, 1)
#: the message that carries the steering angle on each profile (:mod:`vcan_sim.sensors`)
ANGLE_MESSAGE = {"lde": "MDPS_Sensors", "hyundai": "SAS11"}


def plant_names() -> tuple[str, ...]:
    """The zoo's plant names (file stems), sorted."""
    return tuple(sorted(p.stem for p in ZOO_DIR.glob("*.toml")))


def plant_path(name: str) -> Path:
    """The vehicle file of plant ``name``; ConfigError listing the plants otherwise."""
    path = ZOO_DIR / f"{name}.toml"
    if not path.is_file():
        raise ConfigError(f"no zoo plant named {name!r} (plants: {', '.join(plant_names())})")
    return path


def load_plant(name: str) -> Vehicle:
    """Plant ``name`` as a :class:`lde.params.Vehicle` (its ``[sim]`` table is the plant)."""
    return load_vehicle(plant_path(name))


def description(name: str) -> str:
    """The plant's one-line description (the file's top-level ``description``)."""
    with plant_path(name).open("rb") as fh:
        text = tomllib.load(fh).get("description", "")
    if not isinstance(text, str) or not text or "\n" in text:
        raise ConfigError(f"zoo plant {name}: needs a one-line 'description'")
    return text


@dataclass(frozen=True)
class TrueValues:
    """What a zoo plant really is (SI except where the name says; for reporting only).

    cf, cr, k: per-tire bicycle-equivalent C_f, C_r [N/rad] and K [Nm/rad] identified from the
    truth (what the estimator's ``[tires]`` would need); cf_tire, cr_tire: tire-level fits;
    cf_static, cr_static, k_static: Magic Formula tangents at the static loads; mass [kg],
    yaw_inertia [kg m^2], lf, lr [m]: with the plant's own load; payload_kg and cg_shift_m (the
    loaded CG's shift forward of the spec sheet's, negative = back); ratio N; rack_friction_Nm at
    the column; steer_offset_deg, yaw_bias_deg_s (measured minus true); torsion_deg_per_Nm: the
    torsion bar's twist per column torque; angle_lde, angle_hyundai: where that profile's angle is
    sensed ("pinion": below the torsion bar, "wheel": above it, twist included).
    """

    plant: str
    description: str
    cf: float
    cr: float
    k: float
    cf_tire: float
    cr_tire: float
    cf_static: float
    cr_static: float
    k_static: float
    max_alpha_f: float
    mass: float
    yaw_inertia: float
    lf: float
    lr: float
    payload_kg: float
    cg_shift_m: float
    ratio: float
    rack_friction_Nm: float
    steer_offset_deg: float
    yaw_bias_deg_s: float
    torsion_deg_per_Nm: float
    angle_lde: str
    angle_hyundai: str


def identify_plant(
    name: str, scenarios: tuple[str, ...] = IDENTIFY_SCENARIOS, seeds: tuple[int, ...] = IDENTIFY_SEEDS
) -> TrueValues:
    """Fit the plant's true linear-equivalent values to its truth (``scenarios`` x ``seeds`` pooled)."""

    vehicle = load_plant(name)
    sp = sim_params_from_vehicle(vehicle)
    runs = [simulate(sc, vehicle, seed=s) for sc in scenarios for s in seeds]
    cols = ("vx", "alpha_f", "alpha_r", "Fy_front", "Fy_rear", "Mz_tires", "T_align")
    pooled = {c: np.concatenate([r.truth[c] for r in runs]) for c in cols}
    body = loaded_body(vehicle, sp, combined(sp, payload_by_name("none")))
    le = identify(pooled, body.lf, body.lr)
    cf_s, cr_s, k_s = static_stiffness(vehicle, sp)

    def where(profile: str) -> str:
        return "pinion" if angle_below_torsion_bar(sp.sensors, ANGLE_MESSAGE[profile]) else "wheel"

    return TrueValues(
        plant=name,
        description=description(name),
        cf=le.cf,
        cr=le.cr,
        k=le.k,
        cf_tire=le.cf_tire,
        cr_tire=le.cr_tire,
        cf_static=cf_s,
        cr_static=cr_s,
        k_static=k_s,
        max_alpha_f=le.max_alpha_f,
        mass=body.mass,
        yaw_inertia=body.yaw_inertia,
        lf=body.lf,
        lr=body.lr,
        payload_kg=sum(m for _, m in sp.payload),
        cg_shift_m=body.dx_ref,
        ratio=vehicle.steering.ratio,
        rack_friction_Nm=sp.steering.rack_coulomb,
        steer_offset_deg=sp.sensors.steering_angle_bias / DEG,
        yaw_bias_deg_s=sp.sensors.yaw_rate_bias / DEG,
        torsion_deg_per_Nm=1.0 / (sp.steering.torsion_stiffness * DEG),
        angle_lde=where("lde"),
        angle_hyundai=where("hyundai"),
    )


#: decimals of the CSV columns (the rest are text or printed as is)
_DECIMALS = {
    "cf": 0,
    "cr": 0,
    "k": 0,
    "cf_tire": 0,
    "cr_tire": 0,
    "cf_static": 0,
    "cr_static": 0,
    "k_static": 0,
    "max_alpha_f": 4,
    "mass": 1,
    "yaw_inertia": 0,
    "lf": 3,
    "lr": 3,
    "payload_kg": 1,
    "cg_shift_m": 3,
    "ratio": 2,
    "rack_friction_Nm": 2,
    "steer_offset_deg": 2,
    "yaw_bias_deg_s": 3,
    "torsion_deg_per_Nm": 3,
}


def write_true_values(values: list[TrueValues], path: Path = TRUE_VALUES_CSV) -> Path:
    """``true_values.csv``: one row per plant (:class:`TrueValues` fields as columns)."""
    with path.open("w", newline="") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow([f.name for f in fields(TrueValues)])
        for v in values:
            row = []
            for key, val in asdict(v).items():
                if key in _DECIMALS:  # rounded first: no "-0.000" for a CG shift of -1e-16 m
                    d = _DECIMALS[key]
                    row.append(f"{round(val, d) + 0.0:.{d}f}")
                else:
                    row.append(val)
            w.writerow(row)
    return path


def read_true_values(path: Path = TRUE_VALUES_CSV) -> dict[str, TrueValues]:
    """The written true values by plant name."""
    out = {}
    with path.open(newline="") as fh:
        for row in csv.DictReader(fh):
            kw: dict[str, object] = {}
            for f in fields(TrueValues):
                kw[f.name] = float(row[f.name]) if f.name in _DECIMALS else row[f.name]
            out[row["plant"]] = TrueValues(**kw)  # type: ignore[arg-type]
    return out


_TIRE_KEYS = ("cf_N_per_rad", "cr_N_per_rad", "align_rate_Nm_per_rad")


def write_plant_tires(name: str, cf: float, cr: float, k: float) -> None:
    """Put the identified C_f, C_r, K into the plant file's ``[tires]`` (the three keys only)."""
    path = plant_path(name)
    text = path.read_text()
    for key, val in zip(_TIRE_KEYS, (cf, cr, k), strict=True):
        text, n = re.subn(rf"(?m)^{key} = [0-9.eE+-]+", f"{key} = {val:.0f}.0", text)
        if n != 1:
            raise ConfigError(f"{path}: expected one '{key} = ...' line in [tires]")
    path.write_text(text)


def markdown_table(values: dict[str, TrueValues]) -> str:
    """One line per plant: what it is and its true values (docs/simulator.md)."""
    lines = [
        "| plant | description | m [kg] | Iz [kg m^2] | lf [m] | N | C_f / C_r [kN/rad] (static) "
        "| K [Nm/rad] (static) | friction [Nm] | offset [deg] / bias [deg/s] | angle lde / hyundai |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for v in values.values():
        lines.append(
            f"| {v.plant} | {v.description} | {v.mass:.0f} | {v.yaw_inertia:.0f} | {v.lf:.3f} | "
            f"{v.ratio:g} | {v.cf / 1e3:.1f} / {v.cr / 1e3:.1f} ({v.cf_static / 1e3:.1f} / "
            f"{v.cr_static / 1e3:.1f}) | {v.k:.0f} ({v.k_static:.0f}) | {v.rack_friction_Nm:g} | "
            f"{v.steer_offset_deg:g} / {v.yaw_bias_deg_s:g} | {v.angle_lde} / {v.angle_hyundai} |"
        )
    return "\n".join(lines)
