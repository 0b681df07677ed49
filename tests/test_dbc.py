"""The DBC files and the profiles built from them (SPEC section 3)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cantools
import pytest

from lde.can.profiles import ESC_INPUTS, INPUT_NAMES, MDPS_INPUTS, OUTPUT_MESSAGES, dbc_dir, load_profile
from lde.errors import ConfigError
from lde.units import DEG, KMH

REPO = Path(__file__).resolve().parents[1]

# Message ids of opendbc's hyundai_kia_generic.dbc (commaai/opendbc, commit 00b271f), the real car's
# C-CAN: lde's outputs on the hyundai profile must not use any of them.
OPENDBC_HYUNDAI_IDS = {
    16, 48, 64, 66, 67, 68, 127, 128, 129, 273, 274, 275, 304, 320, 339, 352, 354, 356, 357, 387, 399,
    512, 544, 593, 608, 625, 640, 688, 790, 809, 832, 854, 865, 870, 871, 872, 881, 882, 896, 897, 899,
    900, 902, 903, 905, 906, 908, 909, 910, 911, 912, 913, 914, 915, 916, 1017, 1024, 1040, 1042, 1056,
    1057, 1064, 1065, 1066, 1078, 1136, 1151, 1155, 1156, 1157, 1162, 1168, 1170, 1173, 1186, 1191,
    1265, 1268, 1280, 1281, 1282, 1287, 1290, 1292, 1301, 1307, 1312, 1313, 1314, 1315, 1316, 1317,
    1318, 1319, 1322, 1338, 1342, 1345, 1349, 1350, 1351, 1353, 1355, 1356, 1360, 1362, 1363, 1365,
    1366, 1367, 1369, 1370, 1371, 1378, 1379, 1393, 1395, 1397, 1407, 1411, 1412, 1414, 1415, 1419,
    1425, 1426, 1427, 1430, 1434, 1437, 1440, 1441, 1456, 1472, 1479, 1490, 1491, 1492, 1530, 1531,
    1532, 1535, 1984,
}  # fmt: skip


def _sig(db, msg, name):
    return db.get_message_by_name(msg).get_signal_by_name(name)


def test_dbc_dir_is_the_repo_dbc_folder():
    assert dbc_dir() == REPO / "dbc"


@pytest.mark.parametrize("name", ["lde", "hyundai"])
def test_dbc_loads_strictly_and_outputs_are_profile1(name):
    db = cantools.database.load_file(str(REPO / "dbc" / f"{name}.dbc"), strict=True)
    p = load_profile(name)
    for out in OUTPUT_MESSAGES:
        m = db.get_message_by_name(out)
        assert (_sig(db, out, "CRC").start, _sig(db, out, "CRC").length) == (0, 8)
        assert (_sig(db, out, "Counter").start, _sig(db, out, "Counter").length) == (8, 4)
        assert p.outputs[out].scheme.name == "autosar_e2e_p01"
        assert m.length == 8


def test_lde_dbc_contract_names_and_resolutions():
    db = cantools.database.load_file(str(REPO / "dbc" / "lde.dbc"))
    names = {m.name: {s.name for s in m.signals} for m in db.messages}
    assert names["MDPS_Sensors"] >= {
        "ColumnTorque",
        "AssistTorque",
        "SteeringAngle",
        "SteeringRate",
        "Counter",
        "CRC",
    }
    assert names["ESC_Motion"] >= {"YawRate", "LatAccel", "VehicleSpeed", "Counter", "CRC"}
    assert names["LDE_Estimate"] >= {"LatForce", "YawMoment", "AligningTorque", "Status", "Counter", "CRC"}
    assert names["LDE_Overlay"] >= {"OverlayTorque", "Active", "Counter", "CRC"}
    assert all(not m.is_extended_frame for m in db.messages)
    # input resolution at least (SPEC 3)
    assert _sig(db, "MDPS_Sensors", "ColumnTorque").scale <= 0.001
    assert _sig(db, "MDPS_Sensors", "AssistTorque").scale <= 0.001
    assert _sig(db, "MDPS_Sensors", "SteeringAngle").scale <= 0.1
    assert _sig(db, "ESC_Motion", "YawRate").scale <= 0.01
    # output range and resolution at least
    for msg, sig, rng, res in [
        ("LDE_Estimate", "LatForce", 6000, 1),
        ("LDE_Estimate", "YawMoment", 6000, 1),
        ("LDE_Estimate", "AligningTorque", 400, 0.1),
        ("LDE_Overlay", "OverlayTorque", 8, 0.01),
    ]:
        s = _sig(db, msg, sig)
        assert s.scale <= res and s.minimum <= -rng and s.maximum >= rng, (msg, sig)
        assert s.is_signed
    # no two signals of a message overlap
    for m in db.messages:
        bits = [b for s in m.signals for b in range(s.start, s.start + s.length)]
        assert len(bits) == len(set(bits)) and max(bits) < 8 * m.length, m.name


def test_hyundai_dbc_layout_exactly_as_spec():
    db = cantools.database.load_file(str(REPO / "dbc" / "hyundai.dbc"))
    ids = {m.name: m.frame_id for m in db.messages}
    assert ids["MDPS12"] == 593 and ids["SAS11"] == 688 and ids["ESP12"] == 544 and ids["WHL_SPD11"] == 902
    assert db.get_message_by_name("SAS11").length == 5
    # (message, signal): (start, length, signed, scale, offset) per SPEC section 3
    spec = {
        ("MDPS12", "CR_Mdps_StrColTq"): (0, 11, False, 1, -1024),
        ("MDPS12", "CF_Mdps_MsgCount2"): (16, 8, False, 1, 0),
        ("MDPS12", "CF_Mdps_Chksum2"): (24, 8, False, 1, 0),
        ("MDPS12", "CR_Mdps_StrTq"): (40, 12, False, 0.01, -20.48),
        ("MDPS12", "CR_Mdps_OutTq"): (52, 12, False, 0.1, -204.8),
        ("SAS11", "SAS_Angle"): (0, 16, True, 0.1, 0),
        ("SAS11", "SAS_Speed"): (16, 8, False, 4, 0),
        ("SAS11", "SAS_Stat"): (24, 8, False, 1, 0),
        ("SAS11", "MsgCount"): (32, 4, False, 1, 0),
        ("SAS11", "CheckSum"): (36, 4, False, 1, 0),
        ("ESP12", "LAT_ACCEL"): (0, 11, False, 0.01, -10.23),
        ("ESP12", "LONG_ACCEL"): (13, 11, False, 0.01, -10.23),
        ("ESP12", "YAW_RATE"): (40, 13, False, 0.01, -40.95),
        ("ESP12", "ESP12_Checksum"): (56, 4, False, 1, 0),
        ("ESP12", "ESP12_AliveCounter"): (60, 4, False, 1, 0),
        ("WHL_SPD11", "WHL_SPD_FL"): (0, 14, False, 0.03125, 0),
        ("WHL_SPD11", "WHL_SPD_FR"): (16, 14, False, 0.03125, 0),
        ("WHL_SPD11", "WHL_SPD_RL"): (32, 14, False, 0.03125, 0),
        ("WHL_SPD11", "WHL_SPD_RR"): (48, 14, False, 0.03125, 0),
        ("WHL_SPD11", "WHL_SPD_AliveCounter_LSB"): (14, 2, False, 1, 0),
        ("WHL_SPD11", "WHL_SPD_AliveCounter_MSB"): (30, 2, False, 1, 0),
        ("WHL_SPD11", "WHL_SPD_Checksum_LSB"): (46, 2, False, 1, 0),
        ("WHL_SPD11", "WHL_SPD_Checksum_MSB"): (62, 2, False, 1, 0),
    }
    for (m, s), (start, length, signed, scale, offset) in spec.items():
        sig = _sig(db, m, s)
        assert sig.byte_order == "little_endian", (m, s)
        assert (sig.start, sig.length, sig.is_signed) == (start, length, signed), (m, s)
        assert sig.scale == pytest.approx(scale) and sig.offset == pytest.approx(offset), (m, s)


def test_hyundai_output_ids_do_not_collide_with_the_car():
    p = load_profile("hyundai")
    out_ids = {m.frame_id for m in p.outputs.values()}
    assert not out_ids & OPENDBC_HYUNDAI_IDS
    assert not out_ids & {m.frame_id for m in p.messages.values()}


def test_lde_profile_signal_map_units_and_groups():
    p = load_profile("lde")
    assert set(p.inputs) == set(INPUT_NAMES)
    assert p.inputs["steering_angle"].factor == pytest.approx(DEG)
    assert p.inputs["steering_rate"].factor == pytest.approx(DEG)
    assert p.inputs["yaw_rate"].factor == pytest.approx(DEG)
    assert p.inputs["speed"].factor == pytest.approx(KMH)
    assert p.inputs["column_torque"].factor == 1.0
    assert {p.inputs[i].message for i in MDPS_INPUTS} == {"MDPS_Sensors"}
    assert {p.inputs[i].message for i in ESC_INPUTS} == {"ESC_Motion"}
    mdps = p.messages["MDPS_Sensors"]
    assert mdps.period_ns == 3_900_000 and mdps.timeout_ns == 3 * 3_900_000
    assert p.messages["ESC_Motion"].timeout_ns == 30_000_000
    assert mdps.receiver.max_delta == 2 and mdps.receiver.modulus == 15
    assert p.anchor_message == "MDPS_Sensors"
    assert (p.output_id("LDE_Overlay"), p.output_id("LDE_Estimate"), p.output_id("LDE_Diag")) == (
        0x3D0,
        0x3D1,
        0x3D2,
    )


def test_hyundai_profile_integrity_and_signal_map():
    p = load_profile("hyundai")
    assert p.inputs["column_torque"].signals == ("CR_Mdps_StrTq",)
    assert p.inputs["assist_torque"].signals == ("CR_Mdps_OutTq",)
    assert len(p.inputs["speed"].signals) == 4 and p.inputs["speed"].combine == "mean"
    assert p.messages["WHL_SPD11"].scheme.name == "hyundai_whl_spd11"
    for m in ("MDPS12", "SAS11", "ESP12"):
        assert p.messages[m].scheme.name == "counter"  # checksum not verified
        assert not p.messages[m].scheme.verifies_checksum
    assert p.messages["MDPS12"].scheme.modulus == 256
    assert p.messages["SAS11"].scheme.modulus == 16
    assert p.messages["WHL_SPD11"].scheme.counter_fields == ((14, 2, True), (30, 2, True))
    assert p.messages["ESP12"].timeout_ns == 60_000_000
    assert p.group_messages("mdps") == ("MDPS12", "SAS11")
    assert p.group_messages("esc") == ("ESP12", "WHL_SPD11")
    assert p.angle_above_torsion_bar and not p.steering_rate_signed


def test_unknown_profile_and_a_dbc_given_as_profile_are_config_errors(tmp_path):
    with pytest.raises(ConfigError, match="unknown CAN profile 'volvo'.*shipped name"):
        load_profile("volvo")
    copy = tmp_path / "mycar.dbc"
    shutil.copy(REPO / "dbc" / "lde.dbc", copy)
    with pytest.raises(
        ConfigError, match=r"a DBC is not a profile: write a profile file .*docs/guide/profiles\.md"
    ):
        load_profile(copy)


@pytest.mark.parametrize("name", ["lde", "hyundai", "toyota_rav4_2017"])
def test_shipped_profiles_are_files_beside_their_dbcs_and_the_package_copies_are_equal(name):
    p = load_profile(name)
    assert p.path == REPO / "dbc" / f"{name}.toml" and p.shipped
    assert p.dbc_path.parent == REPO / "dbc"
    for f in (p.path, p.dbc_path):
        assert (REPO / "src" / "lde" / "data" / f.name).read_bytes() == f.read_bytes(), f.name
