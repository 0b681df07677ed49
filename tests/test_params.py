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


@pytest.mark.parametrize(
    "table,text,key",
    [
        ("vehicle", "lf_m = 5.9\nlr_m = 5.9", "wheelbase 11.8 m outside 1.5..5"),  # the 11.8 m
        ("vehicle", "lf_m = 0.3\nlr_m = 2.5", "lf_m 0.3 is 0.11 of the wheelbase"),
        ("vehicle", "yaw_inertia_kgm2 = 9000.0", "yaw_inertia_kgm2 9000 is 3.32 x mass lf lr"),
        ("vehicle", "yaw_inertia_kgm2 = 900.0", "yaw_inertia_kgm2 900 is 0.33 x mass lf lr"),
        ("vehicle", "track_rear_m = 3.1", "track_rear_m 3.1 outside 0.9..2.2"),
        ("vehicle", "mass_kg = 40000.0", "mass_kg 40000 outside 300..8000"),
        ("steering", "ratio = 3.0", "ratio 3 outside 8..30"),
        ("tires", "cf_N_per_rad = 5000.0", "cf_N_per_rad 5000 is 1.1 x the static tire load"),
        ("tires", "cr_N_per_rad = 400000.0", "cr_N_per_rad 400000"),
        ("tires", "align_rate_Nm_per_rad = 40000.0", "trail 0.645 m, outside 0.02..0.3"),
    ],
)
def test_implausible_vehicles_are_one_line_errors_naming_key_and_range(tmp_path, table, text, key):
    f = tmp_path / "bad.toml"
    f.write_text(f'extends = "reference"\nname = "bad"\n[{table}]\n{text}\n')
    with pytest.raises(ConfigError) as exc:
        load_vehicle(f)
    msg = str(exc.value)
    assert key in msg and f"[{table}]" in msg and str(f) in msg and "\n" not in msg, msg


def test_each_plausibility_range_holds_at_its_boundary(tmp_path):
    """The shipped ranges accept their own boundaries (a check that is off by one rejects them)."""
    from lde.params import RATIO_RANGE, WHEELBASE_RANGE_M

    for lo_hi in (RATIO_RANGE[0], RATIO_RANGE[1]):
        f = tmp_path / "r.toml"
        f.write_text(f'extends = "reference"\nname = "r"\n[steering]\nratio = {lo_hi}\n')
        assert load_vehicle(f).steering.ratio == lo_hi
    f = tmp_path / "w.toml"
    # wheelbase exactly 5.0 m with the reference's axle shares and a matching yaw inertia
    f.write_text(
        'extends = "reference"\nname = "w"\n[vehicle]\nlf_m = 2.0\nlr_m = 3.0\nyaw_inertia_kgm2 = 8796.0\n'
    )
    assert load_vehicle(f).body.wheelbase == WHEELBASE_RANGE_M[1]


def test_defaults_used_are_stated(tmp_path):
    f = tmp_path / "min.toml"
    f.write_text(
        'name = "min"\n[vehicle]\nmass_kg = 1600.0\nyaw_inertia_kgm2 = 2900.0\nlf_m = 1.15\nlr_m = 1.65\n'
        "track_front_m = 1.6\ntrack_rear_m = 1.6\n[steering]\nratio = 14.5\n"
        "[tires]\ncf_N_per_rad = 60000.0\ncr_N_per_rad = 55000.0\nalign_rate_Nm_per_rad = 7000.0\n"
        "[overlay]\nmax_torque_Nm = 2.0\n"
    )
    v = load_vehicle(f)
    note = v.defaults_note()
    assert "[estimator] all 19 keys" in note and "[corrections] all 6 keys" in note
    assert "[overlay] max_rate_Nm_per_s" in note and "max_torque_Nm" not in note
    assert load_vehicle("reference").defaults == ()  # the shipped file states every key
    spec = tmp_path / "spec.toml"  # a spec sheet: no tires, generic ones from the axle loads
    spec.write_text(f.read_text().split("[tires]")[0])
    s = load_vehicle(spec)
    assert "[tires] generic from the axle loads" in s.defaults_note()
    assert s.tires.cf == pytest.approx(13.98 * 1600.0 * 9.80665 * 1.65 / 5.6, rel=1e-3)
