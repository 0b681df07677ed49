"""Spec-sheet vehicle files: what the estimator may know about a car it was not fitted to (issue 11).

A car's spec sheet gives its mass, yaw inertia, CG position (lf, lr), treads and steering ratio. The
spec-sheet vehicle file carries exactly those and ``extends`` the shipped generic defaults
(:data:`GENERIC_BASE`: ``reference.toml``'s generic mid-size-sedan tires, Kalman tuning, overlay
limits, no input corrections) for everything else. Nothing else of the car (its tires, steering
friction, sensor offsets, payload) reaches the estimator: the zoo evaluation (:mod:`lde.analysis.study.zoo`)
gives ``lde replay`` only this file.

For a car that carries a payload the spec sheet is the unloaded car's (the vehicle file's
``[vehicle]``; the simulator's ``[sim.payload]`` is not on it).
"""

from __future__ import annotations

from pathlib import Path

from lde.params import Vehicle, load_vehicle

#: the shipped vehicle file a spec sheet extends (generic defaults for everything not on the sheet)
GENERIC_BASE = "reference"
#: the vehicle-file keys a spec sheet sets: (table, key, attribute path, decimals)
SPEC_SHEET_KEYS: tuple[tuple[str, str, str, int], ...] = (
    ("vehicle", "mass_kg", "body.mass", 1),
    ("vehicle", "yaw_inertia_kgm2", "body.yaw_inertia", 1),
    ("vehicle", "lf_m", "body.lf", 4),
    ("vehicle", "lr_m", "body.lr", 4),
    ("vehicle", "track_front_m", "body.track_front", 4),
    ("vehicle", "track_rear_m", "body.track_rear", 4),
    ("steering", "ratio", "steering.ratio", 3),
)


def _get(vehicle: Vehicle, path: str) -> float:
    obj: object = vehicle
    for part in path.split("."):
        obj = getattr(obj, part)
    return float(obj)  # type: ignore[arg-type]


def spec_sheet_text(vehicle: Vehicle, name: str | None = None, base: str = GENERIC_BASE) -> str:
    """The TOML text of ``vehicle``'s spec-sheet file (see the module docstring)."""
    name = name or f"{vehicle.name}_spec_sheet"
    lines = [
        f"# Spec sheet of {vehicle.name}: mass, yaw inertia, lf, lr, treads, steering ratio.",
        f"# Everything else is the shipped generic default ({base}.toml); nothing here is identified",
        "# from the car (lde.analysis.study.specsheet).",
        f'extends = "{base}"',
        f'name = "{name}"',
        f'description = "spec sheet of {vehicle.name} on the generic {base} defaults"',
    ]
    table = ""
    for tab, key, attr, dec in SPEC_SHEET_KEYS:
        if tab != table:
            lines += ["", f"[{tab}]"]
            table = tab
        lines.append(f"{key} = {_get(vehicle, attr):.{dec}f}")
    return "\n".join(lines) + "\n"


def write_spec_sheet(vehicle: Vehicle, path: str | Path, name: str | None = None) -> Path:
    """Write ``vehicle``'s spec-sheet file to ``path``; returns the path (loadable with ``--vehicle``)."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(spec_sheet_text(vehicle, name))
    return out


def spec_sheet_vehicle(vehicle: Vehicle, tmp_dir: str | Path) -> Vehicle:
    """The spec-sheet file of ``vehicle`` written in ``tmp_dir`` and loaded (as ``lde replay`` would)."""
    return load_vehicle(write_spec_sheet(vehicle, Path(tmp_dir) / f"{vehicle.name}_spec_sheet.toml"))
