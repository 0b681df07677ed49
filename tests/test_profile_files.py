"""Profile files (docs/guide/profiles.md): the shipped ones, every way a file can be wrong (one clear line
that names the file and the key), absent inputs, torques of unknown scale, observed timeouts, and the
bus a message is read from."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

from lde.can.channels import ChannelSelect
from lde.can.codec import encode_frames
from lde.can.frames import FrameBatch
from lde.can.profiles import PROFILE_NAMES, load_profile, observe_timeouts
from lde.cli import PROFILE_CHOICES, main
from lde.engine.receiver import Receiver, RxTables, decode_batch
from lde.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
DBC = REPO / "dbc"


def _copy(tmp_path: Path, name: str, edit=None, dbc_edit=None) -> Path:
    """A shipped profile and its DBC copied to ``tmp_path``, the profile's text changed by ``edit``
    (a function of the text), the DBC's by ``dbc_edit``."""
    src = DBC / f"{name}.toml"
    text = src.read_text()
    dbc = re.search(r'^dbc = "(.+)"', text, re.M).group(1)
    dbc_text = (DBC / dbc).read_text(encoding="cp1252")
    (tmp_path / dbc).write_text(dbc_edit(dbc_text) if dbc_edit else dbc_text, encoding="cp1252")
    out = tmp_path / f"my_{name}.toml"
    out.write_text(edit(text) if edit else text)
    return out


def _sub(old: str, new: str):
    def f(text: str) -> str:
        assert old in text, old
        return text.replace(old, new, 1)

    return f


def test_shipped_names_are_the_cli_choices_and_lde_comes_first():
    assert PROFILE_NAMES == PROFILE_CHOICES
    assert PROFILE_NAMES[0] == "lde"


def test_a_copied_profile_file_loads_like_the_shipped_one(tmp_path):
    p = load_profile(_copy(tmp_path, "hyundai"))
    ref = load_profile("hyundai")
    assert p.name == "hyundai" and not p.shipped and ref.shipped
    assert dict(p.inputs) == dict(ref.inputs)
    assert dict(p.messages) == dict(ref.messages) and dict(p.outputs) == dict(ref.outputs)
    for a, b in zip(RxTables.of(p).kernel_args(), RxTables.of(ref).kernel_args(), strict=True):
        np.testing.assert_array_equal(a, b)
    assert p.metadata() == {"profile": "hyundai", "profile_file": str(p.path.resolve())}
    assert ref.metadata() == {"profile": "hyundai"}


BAD = {
    "missing DBC": (
        _sub('dbc = "hyundai.dbc"', 'dbc = "nowhere.dbc"'),
        r"my_hyundai\.toml: dbc .*nowhere\.dbc cannot be read",
    ),
    "unknown message": (
        _sub('message = "ESP12"\nsignal = "YAW_RATE"', 'message = "ESP13"\nsignal = "YAW_RATE"'),
        r"my_hyundai\.toml: \[inputs\.yaw_rate\] message 'ESP13' not in hyundai\.dbc \(messages: .*ESP12",
    ),
    "unknown signal": (
        _sub('signal = "YAW_RATE"', 'signal = "YAW_RAT"'),
        r"my_hyundai\.toml: \[inputs\.yaw_rate\] signal 'YAW_RAT' not in message 'ESP12' \(signals: "
        r"LAT_ACCEL, LONG_ACCEL, YAW_RATE, ESP12_Checksum, ESP12_AliveCounter\)",
    ),
    "a unit of another quantity": (
        _sub('signal = "YAW_RATE"\nscale = "deg/s"', 'signal = "YAW_RATE"\nscale = "km/h"'),
        r"\[inputs\.yaw_rate\] scale 'km/h' is a unit of speed, not angular rate \(for yaw_rate: deg/s, "
        r"rad/s or a number\)",
    ),
    "a unit lde does not know": (
        _sub('signal = "YAW_RATE"\nscale = "deg/s"', 'signal = "YAW_RATE"\nscale = "furlong"'),
        r"\[inputs\.yaw_rate\] scale 'furlong' is not a unit lde knows",
    ),
    "a negative scale": (
        _sub('signal = "YAW_RATE"\nscale = "deg/s"', 'signal = "YAW_RATE"\nscale = -0.01'),
        r"\[inputs\.yaw_rate\] scale must be a positive number .*the sign is 'sign'",
    ),
    "a sign that is not +-1": (
        _sub('signal = "YAW_RATE"\nscale = "deg/s"', 'signal = "YAW_RATE"\nscale = "deg/s"\nsign = 2'),
        r"\[inputs\.yaw_rate\] sign must be \+1 or -1, got 2",
    ),
    "unknown integrity": (
        _sub('integrity = "counter"\ncounter = "MsgCount"', 'integrity = "crc32"\ncounter = "MsgCount"'),
        r"\[messages\.SAS11\] unknown integrity 'crc32' \(one of: none, counter, autosar_e2e_p01, "
        r"toyota_checksum, hyundai_whl_spd11\)",
    ),
    "integrity without its counter": (
        _sub('integrity = "counter"\ncounter = "MsgCount"', 'integrity = "counter"'),
        r"\[messages\.SAS11\] integrity 'counter' needs its counter signal",
    ),
    "output id of a car message": (
        _sub("LDE_Overlay = 0x3D0", "LDE_Overlay = 0x251"),
        r"\[outputs\] LDE_Overlay id 0x251 collides with message 'MDPS12' \(0x251\) of hyundai\.dbc",
    ),
    "two outputs on one id": (
        _sub("LDE_Estimate = 0x3D1", "LDE_Estimate = 0x3D0"),
        r"\[outputs\] LDE_Estimate and LDE_Overlay share the id 0x3D0",
    ),
    "unknown top-level key": (
        _sub('dbc = "hyundai.dbc"', 'dbc = "hyundai.dbc"\ndbcs = "x"'),
        r"my_hyundai\.toml: unknown top-level key 'dbcs' \(known: ",
    ),
    "unknown input key": (
        _sub('signal = "YAW_RATE"', 'signal = "YAW_RATE"\nunit = "deg/s"'),
        r"\[inputs\.yaw_rate\] unknown key 'unit'",
    ),
    "an input missing": (
        lambda t: t.replace(
            '[inputs.lat_accel]\nmessage = "ESP12"\nsignal = "LAT_ACCEL"\nscale = "m/s^2"\n', ""
        ),
        r"\[inputs\.lat_accel\] missing: declare its message, signal and scale \(or absent = true",
    ),
    "an input lde needs declared absent": (
        _sub(
            '[inputs.yaw_rate]\nmessage = "ESP12"\nsignal = "YAW_RATE"\nscale = "deg/s"',
            "[inputs.yaw_rate]\nabsent = true",
        ),
        r"\[inputs\.yaw_rate\] yaw_rate cannot be absent: lde needs it",
    ),
    "unknown scale of a non-torque": (
        _sub('signal = "YAW_RATE"\nscale = "deg/s"', 'signal = "YAW_RATE"\nscale = "unknown"'),
        r"\[inputs\.yaw_rate\] scale 'unknown' is allowed only for assist_torque and column_torque",
    ),
    "a message without its integrity table": (
        lambda t: t.replace(
            '[messages.ESP12]\nintegrity = "counter"\n'
            'counter = "ESP12_AliveCounter"\nchecksum = "ESP12_Checksum"\n',
            "",
        ),
        r"\[messages\.ESP12\] missing: every input message names its integrity check",
    ),
    "not TOML": (lambda t: t + "\n[[[ nonsense\n", r"my_hyundai\.toml: not a TOML profile file"),
    "one message feeding both groups": (
        _sub(
            '[inputs.yaw_rate]\nmessage = "ESP12"\nsignal = "YAW_RATE"',
            '[inputs.yaw_rate]\nmessage = "SAS11"\nsignal = "SAS_Angle"',
        ),
        r"\[messages\.SAS11\] SAS11 feeds inputs of both groups \(steering_angle, steering_rate, yaw_rate\)",
    ),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_profile_file_is_one_line_naming_the_key(tmp_path, case):
    edit, pattern = BAD[case]
    path = _copy(tmp_path, "hyundai", edit)
    with pytest.raises(ConfigError) as exc:
        load_profile(path)
    msg = str(exc.value)
    assert "\n" not in msg and re.search(pattern, msg), msg


def test_profile_integrity_positions_are_checked(tmp_path):
    lde = _copy(
        tmp_path,
        "lde",
        _sub('counter = "Counter"\nchecksum = "CRC"', 'counter = "CRC"\nchecksum = "Counter"'),
    )
    with pytest.raises(
        ConfigError, match=r"\[messages\.MDPS_Sensors\] autosar_e2e_p01 needs the CRC at 0\|8@1"
    ):
        load_profile(lde)
    rav = _copy(tmp_path, "toyota_rav4_2017", _sub('checksum = "CHECKSUM"', 'checksum = "STEER_OVERRIDE"'))
    with pytest.raises(ConfigError, match=r"toyota_checksum needs its checksum in the last byte \(byte 7\)"):
        load_profile(rav)


def test_the_cli_says_what_is_wrong_with_a_profile_file_in_one_line(tmp_path, capsys):
    path = _copy(tmp_path, "hyundai", BAD["unknown signal"][0])
    rc = main(["replay", str(REPO / "tests" / "data" / "sample_linear.log"), "--profile", str(path), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert err[0].startswith(f"lde: error: {path}: [inputs.yaw_rate] signal 'YAW_RAT' not in message 'ESP12'")
    rc = main(
        [
            "replay",
            str(REPO / "tests" / "data" / "sample_linear.log"),
            "--profile",
            str(DBC / "lde.dbc"),
            "-q",
        ]
    )
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "a DBC is not a profile: write a profile file" in err[0]


# --------------------------------------------------------------------------- absent, unknown


def _lde_frames(profile, n: int = 40):
    """n MDPS_Sensors frames (3.9 ms) and the ESC_Motion frames between them, lde layout."""
    t_m = 1_000_000_000 + np.arange(n, dtype=np.int64) * 3_900_000
    t_e = 1_000_000_000 + np.arange(n * 39 // 100, dtype=np.int64) * 10_000_000 + 1000
    m = encode_frames(
        profile, "MDPS_Sensors", t_m, {"ColumnTorque": 1.5, "AssistTorque": 4.0, "SteeringAngle": 2.0}
    )
    e = encode_frames(profile, "ESC_Motion", t_e, {"YawRate": 1.0, "LatAccel": 0.5, "VehicleSpeed": 90.0})
    return FrameBatch.concat([m, e])


def test_an_absent_input_is_never_valid_and_does_not_hold_its_group_back(tmp_path):
    path = _copy(
        tmp_path,
        "lde",
        _sub(
            '[inputs.lat_accel]\nmessage = "ESC_Motion"\nsignal = "LatAccel"\nscale = "m/s^2"',
            "[inputs.lat_accel]\nabsent = true",
        ),
    )
    p = load_profile(path)
    assert p.absent == {"lat_accel"} and "lat_accel" not in p.inputs
    frames = _lde_frames(p)
    rx = Receiver(p)
    for i in range(len(frames)):
        rx.feed(int(frames.t_ns[i]), int(frames.can_id[i]), frames.data[i, :8].tobytes())
    s = rx.sample(int(frames.t_ns[-1]))
    assert s.esc_ok and s.mdps_ok and s.valid["yaw_rate"] and not s.valid["lat_accel"]
    assert np.isnan(s.lat_accel) and s.age_ns["lat_accel"] == -1
    # the same frames with lat_accel present: the same other inputs
    ref = Receiver(load_profile("lde"))
    for i in range(len(frames)):
        ref.feed(int(frames.t_ns[i]), int(frames.can_id[i]), frames.data[i, :8].tobytes())
    r = ref.sample(int(frames.t_ns[-1]))
    assert r.lat_accel == pytest.approx(0.5) and r.yaw_rate == s.yaw_rate and r.speed == s.speed


def test_a_torque_of_unknown_scale_enters_as_its_dbc_value_and_is_flagged(tmp_path):
    path = _copy(
        tmp_path,
        "lde",
        _sub('signal = "AssistTorque"\nscale = "Nm"', 'signal = "AssistTorque"\nscale = "unknown"'),
    )
    p = load_profile(path)
    assert p.unknown_scale == {"assist_torque"} and not p.torque_scales_known
    assert load_profile("lde").torque_scales_known
    assert p.inputs["assist_torque"].to_si == 1.0 and p.inputs["assist_torque"].unknown_scale
    rav = load_profile("toyota_rav4_2017")
    assert rav.unknown_scale == {"column_torque", "assist_torque"}


def test_sign_offset_and_sum_apply_as_documented(tmp_path):
    path = _copy(
        tmp_path,
        "lde",
        _sub(
            'signal = "YawRate"\nscale = "deg/s"',
            'signal = "YawRate"\nscale = "deg/s"\nsign = -1\noffset = 0.25',
        ),
    )
    p = load_profile(path)
    frames = _lde_frames(p)
    d = decode_batch(p, frames)
    # si = sign * scale * (value + offset): -(1.0 + 0.25) deg/s
    np.testing.assert_allclose(d.inputs["yaw_rate"].value, -1.25 * np.pi / 180.0)


def test_timeouts_come_from_the_observed_rate_when_the_dbc_has_no_cycle_time(tmp_path):
    path = _copy(
        tmp_path,
        "toyota_rav4_2017",
        dbc_edit=lambda t: "\n".join(ln for ln in t.splitlines() if "GenMsgCycleTime" not in ln) + "\n",
    )
    p = load_profile(path)
    assert not p.timeouts_known and p.messages["KINEMATICS"].receiver is None
    with pytest.raises(
        ConfigError, match=r"no timeout for .*set timeout_ms in \[messages\.STEER_TORQUE_SENSOR\]"
    ):
        RxTables.of(p)
    t = 1_000_000_000 + np.arange(20, dtype=np.int64) * 12_000_000
    frames = FrameBatch.concat(
        [
            encode_frames(p, "KINEMATICS", t, {}),
            encode_frames(p, "STEER_ANGLE_SENSOR", t, {}),
            encode_frames(p, "WHEEL_SPEEDS", t, {}),
            encode_frames(p, "STEER_TORQUE_SENSOR", t[::2], {}),
        ]
    )
    q = observe_timeouts(p, frames)
    assert q.messages["KINEMATICS"].timeout_ns == 3 * 12_000_000
    assert q.messages["STEER_TORQUE_SENSOR"].timeout_ns == 3 * 24_000_000
    with pytest.raises(
        ConfigError, match=r"\[messages\.WHEEL_SPEEDS\] its DBC gives no cycle time .* set timeout_ms"
    ):
        observe_timeouts(p, frames.select(frames.can_id != 0xAA))
    # a timeout_ms in the file needs no log
    given = _copy(
        tmp_path,
        "toyota_rav4_2017",
        _sub(
            '[messages.KINEMATICS]\nintegrity = "none"',
            '[messages.KINEMATICS]\nintegrity = "none"\ntimeout_ms = 50',
        ),
        dbc_edit=lambda t: "\n".join(ln for ln in t.splitlines() if "GenMsgCycleTime" not in ln) + "\n",
    )
    assert load_profile(given).messages["KINEMATICS"].timeout_ns == 50_000_000


# --------------------------------------------------------------------------- channels


def _two_buses(profile, same_id_on_both: bool) -> FrameBatch:
    frames = _lde_frames(profile)
    other = frames.select(frames.can_id == 0x2A8)  # the ESC frames, again on can1 (with junk bytes)
    if not same_id_on_both:  # can1 carries other ids only
        other.can_id = np.full(len(other), 0x123, np.uint32)
    a = FrameBatch(frames.t_ns, frames.can_id, frames.is_extended, frames.dlc, frames.data, frames.is_rx,
                   np.zeros(len(frames)), ("can0",))  # fmt: skip
    junk = np.full_like(other.data, 0xFF)
    b = FrameBatch(other.t_ns + 500, other.can_id, other.is_extended, other.dlc, junk, other.is_rx,
                   np.zeros(len(other)), ("can1",))  # fmt: skip
    return FrameBatch.concat([a, b])


def test_the_bus_of_each_message_is_the_one_that_carries_it_or_the_one_named(tmp_path):
    p = load_profile("lde")
    sel = ChannelSelect(p)
    only0 = sel(_two_buses(p, same_id_on_both=False))
    assert sel.chosen == {"MDPS_Sensors": "can0", "ESC_Motion": "can0"} and sel.dropped == 0
    assert len(only0) == len(_two_buses(p, same_id_on_both=False))
    with pytest.raises(
        ConfigError, match=r"ESC_Motion \(0x2A8\) is on channels 'can0', 'can1': name the one"
    ):
        ChannelSelect(p)(_two_buses(p, same_id_on_both=True))
    named = load_profile(_copy(tmp_path, "lde", _sub('name = "lde"', 'name = "lde"\nchannel = "can0"')))
    sel = ChannelSelect(named)
    both = _two_buses(named, same_id_on_both=True)
    kept = sel(both)
    assert sel.dropped == int(np.count_nonzero(both.channel == 1)) > 0
    assert kept.channel_names().tolist() == ["can0"] * len(kept)
    d = decode_batch(named, both)
    assert d.messages["ESC_Motion"].stats.wrong_crc == 0 and d.other_bus > 0
    wrong = load_profile(_copy(tmp_path, "lde", _sub('name = "lde"', 'name = "lde"\nchannel = "can7"')))
    with pytest.raises(
        ConfigError, match=r"channel = 'can7', but the log has MDPS_Sensors \(0x2A0\) on 'can0' only"
    ):
        ChannelSelect(wrong)(_two_buses(wrong, same_id_on_both=False))
    # a log of one bus, unnamed or of another name, is the bus the profile names
    plain = _lde_frames(wrong)
    assert ChannelSelect(wrong)(plain) is plain
    one = FrameBatch(plain.t_ns, plain.can_id, plain.is_extended, plain.dlc, plain.data, plain.is_rx,
                     np.zeros(len(plain)), ("vcan0",))  # fmt: skip
    sel = ChannelSelect(wrong)
    assert sel(one) is one and sel.chosen["MDPS_Sensors"] == "vcan0"


def test_profile_files_need_no_python(tmp_path):
    """A user's own car: a profile file beside a DBC, loaded by path, with no lde code touched."""
    shutil.copy(DBC / "hyundai.dbc", tmp_path / "car.dbc")
    text = (DBC / "hyundai.toml").read_text().replace('dbc = "hyundai.dbc"', 'dbc = "car.dbc"')
    (tmp_path / "mycar.toml").write_text(text.replace('name = "hyundai"', 'name = "mycar"'))
    p = load_profile(tmp_path / "mycar.toml")
    assert p.name == "mycar" and p.dbc_path == tmp_path / "car.dbc"


def test_the_overlay_stays_off_while_a_torque_scale_is_unknown(tmp_path):
    """The same drive through lde's profile and through a copy that calls the assist torque's scale
    unknown (its DBC unit happens to be Nm, so the estimates are the same): the overlay engages on
    the first and never on the second."""
    from lde.params import load_vehicle
    from lde.replay.replay import replay_log

    log = REPO / "tests" / "data" / "c4b2db1" / "lde.log.gz"
    unknown = load_profile(
        _copy(
            tmp_path,
            "lde",
            _sub('signal = "AssistTorque"\nscale = "Nm"', 'signal = "AssistTorque"\nscale = "unknown"'),
        )
    )
    vehicle = load_vehicle("reference")
    _, known = replay_log(log, load_profile("lde"), vehicle, "float")
    _, off = replay_log(log, unknown, vehicle, "float")
    np.testing.assert_array_equal(off.fw, known.fw)
    assert np.count_nonzero(known.t_overlay) > 100 and known.block.overlay_enable.all()
    assert not off.t_overlay.any() and not off.overlay_state.any() and not off.block.overlay_enable.any()


def test_without_lateral_acceleration_the_estimate_runs_on_yaw_rate_and_torque(tmp_path):
    """lat_accel declared absent on a drive that has it: the ESC group stays usable, the estimate
    becomes valid, and Fw differs from the full profile's (the accelerometer's update is gone) but
    stays in the same range."""
    from lde.params import load_vehicle
    from lde.replay.replay import replay_log

    log = REPO / "tests" / "data" / "c4b2db1" / "lde.log.gz"
    absent = load_profile(
        _copy(
            tmp_path,
            "lde",
            _sub(
                '[inputs.lat_accel]\nmessage = "ESC_Motion"\nsignal = "LatAccel"\nscale = "m/s^2"',
                "[inputs.lat_accel]\nabsent = true",
            ),
        )
    )
    vehicle = load_vehicle("reference")
    _, full = replay_log(log, load_profile("lde"), vehicle, "float")
    _, without = replay_log(log, absent, vehicle, "float")
    valid = (without.status & 1) != 0
    assert valid.mean() > 0.5 and ((full.status & 1) != 0).mean() > 0.5
    assert np.isnan(without.block.inputs[:, 5]).all()  # lat_accel: never a value
    assert not np.array_equal(without.fw, full.fw)
    assert np.abs(without.fw[valid]).max() < 3 * np.abs(full.fw).max()
