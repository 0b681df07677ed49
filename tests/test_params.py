"""Vehicle parameter files: loading, SI conversion, inheritance and validation."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from lde.errors import ConfigError
from lde.params import load_vehicle, shipped_vehicles
from lde.units import DEG, KMH

TABLE1 = {  # paper Table 1 (Est 2's lr corrected, SPEC erratum 6)
    "est1": (1500.0, 2800.0, 1.07, 1.725),
    "est2": (1600.0, 2850.0, 1.12, 1.675),
    "est3": (1700.0, 2900.0, 1.17, 1.625),
    "est4": (1800.0, 2950.0, 1.22, 1.575),
    "est5": (1900.0, 3000.0, 1.27, 1.525),
}


def test_reference_vehicle_is_table_2_in_si() -> None:
    v = load_vehicle()
    assert v.name == "reference"
    b = v.body
    assert (b.mass, b.yaw_inertia, b.lf, b.lr, b.track_front) == (1466.0, 2744.0, 1.071, 1.724, 1.587)
    assert v.steering.ratio == 15.0
    assert 6750.0 <= v.tires.align_rate <= 7640.0
    assert v.overlay.min_speed == pytest.approx(60.0 * KMH)
    assert v.overlay.max_steering_angle == pytest.approx(15.0 * DEG)
    assert v.estimator.min_speed == pytest.approx(30.0 * KMH)
    # std devs in the file are stored as variances
    assert v.estimator.r_yaw == pytest.approx((0.1 * DEG) ** 2)
    assert v.estimator.r_align == pytest.approx(10.0**2)


@pytest.mark.parametrize("name", sorted(TABLE1))
def test_table1_candidates_extend_the_reference(name: str) -> None:
    v, ref = load_vehicle(name), load_vehicle("reference")
    m, iz, lf, lr = TABLE1[name]
    assert (v.body.mass, v.body.yaw_inertia, v.body.lf, v.body.lr) == (m, iz, lf, lr)
    assert v.body.wheelbase == pytest.approx(2.795)
    assert v.tires == ref.tires and v.steering == ref.steering and v.overlay == ref.overlay


def test_shipped_names() -> None:
    assert set(TABLE1) | {"reference"} <= set(shipped_vehicles())


def _write(tmp_path: Path, text: str, name: str = "car.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_custom_file_overrides_only_what_it_names(tmp_path: Path) -> None:
    p = _write(
        tmp_path,
        'extends = "reference"\nname = "mine"\n[tires]\ncf_N_per_rad = 70000.0\n'
        "[overlay]\nmax_torque_Nm = 2.0\nhold_off_s = 0.5\n",
    )
    v = load_vehicle(p)
    assert v.name == "mine" and v.tires.cf == 70000.0 and v.overlay.max_torque == 2.0
    assert v.overlay.hold_off == 0.5
    assert v.tires.cr == load_vehicle().tires.cr


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ('extends = "reference"\nname = "x"\n[vehicle]\nmass_kg = -5.0\n', "mass_kg"),
        ('extends = "reference"\nname = "x"\n[vehicle]\nmas_kg = 1500.0\n', "unknown key"),
        ('extends = "reference"\nname = "x"\n[tires]\ncf_N_per_rad = "soft"\n', "must be a number"),
        ('extends = "reference"\nname = "x"\n[overlay]\nhold_off_s = -1.0\n', "hold_off_s"),
        ('extends = "reference"\nname = "x"\n[vehicle]\nlf_m = nan\n', "finite"),
        ('name = "x"\n[vehicle]\nmass_kg = 1500.0\n', "missing"),
        ('extends = "reference"\nname = "x"\n[wheels]\nn = 4\n', "unknown table"),
        ("this is not toml", "not valid TOML"),
    ],
)
def test_bad_files_name_the_problem(tmp_path: Path, text: str, needle: str) -> None:
    with pytest.raises(ConfigError, match=needle):
        load_vehicle(_write(tmp_path, text))


def test_extends_cycle_is_an_error(tmp_path: Path) -> None:
    _write(tmp_path, 'extends = "b.toml"\nname = "a"\n', "a.toml")
    _write(tmp_path, 'extends = "a.toml"\nname = "b"\n', "b.toml")
    with pytest.raises(ConfigError, match="cycle"):
        load_vehicle(tmp_path / "a.toml")


def test_unknown_shipped_name_lists_the_shipped_ones() -> None:
    with pytest.raises(ConfigError, match="reference"):
        load_vehicle("no_such_car")


def test_with_body_revalidates() -> None:
    v = load_vehicle()
    assert v.with_body(mass=1700.0).body.mass == 1700.0
    with pytest.raises(ConfigError):
        v.with_body(mass=math.inf)
