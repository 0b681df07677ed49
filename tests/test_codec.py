"""Signal bit layout and encoding with automatic counters and CRCs (lde.can.codec)."""

from __future__ import annotations

import cantools
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lde.can.codec import (
    EncodeError,
    MessageCodec,
    MessageEncoder,
    MessageLayout,
    SignalCodec,
    decode_frame,
    encode_batch,
    encode_frames,
    si_to_dbc,
)
from lde.can.e2e import INTEGRITY, IntegrityScheme, check_frame, p01_check, read_counter
from lde.can.profiles import load_profile
from lde.units import DEG, KMH


@pytest.fixture(scope="module")
def lde():
    return load_profile("lde")


@pytest.fixture(scope="module")
def hyundai():
    return load_profile("hyundai")


def random_values(codec: MessageCodec, rng: np.random.Generator, n: int) -> dict[str, np.ndarray]:
    """Random physical values inside each value signal's DBC range."""
    out = {}
    for name in codec.values:
        s = codec.signals[name]
        lo = s.minimum if s.minimum is not None else s.raw_min * s.scale + s.offset
        hi = s.maximum if s.maximum is not None else s.raw_max * s.scale + s.offset
        out[name] = rng.uniform(lo, hi, n)
    return out


ALL = [
    ("lde", "MDPS_Sensors"),
    ("lde", "ESC_Motion"),
    ("lde", "LDE_Overlay"),
    ("lde", "LDE_Estimate"),
    ("lde", "LDE_Diag"),
    ("hyundai", "MDPS12"),
    ("hyundai", "SAS11"),
    ("hyundai", "ESP12"),
    ("hyundai", "WHL_SPD11"),
    ("hyundai", "LDE_Estimate"),
    ("hyundai", "LDE_Overlay"),
]


@pytest.mark.parametrize("pname,mname", ALL)
def test_encode_then_cantools_decode_within_resolution_and_integrity_ok(pname, mname):
    p = load_profile(pname)
    enc = MessageEncoder(p, mname, counter_start=3)
    codec = enc.codec
    rng = np.random.default_rng(ALL.index((pname, mname)))
    vals = random_values(codec, rng, 40)
    spec = p.spec(mname)
    for i in range(40):
        row = {k: float(v[i]) for k, v in vals.items()}
        data = enc.encode(row)
        assert len(data) == spec.length
        dec = p.db.decode_message(spec.frame_id, data, decode_choices=False)
        for k, v in row.items():
            assert dec[k] == pytest.approx(v, abs=codec.signals[k].scale / 2 + 1e-9), (mname, k)
        assert check_frame(spec.scheme, spec.frame_id, data)
        assert read_counter(spec.scheme, data) == (3 + i) % spec.scheme.modulus


@pytest.mark.parametrize("pname,mname", ALL)
def test_encode_batch_is_bit_identical_to_the_scalar_encoder(pname, mname):
    p = load_profile(pname)
    codec = MessageCodec(p, mname)
    rng = np.random.default_rng(5)
    n = 37
    vals = random_values(codec, rng, n)
    # include out-of-range values (saturated identically in both paths)
    first = codec.values[0]
    vals[first][:3] = [1e9, -1e9, 0.0]
    batch = encode_batch(p, mname, vals, counter_start=2)
    enc = MessageEncoder(p, mname, counter_start=2)
    length = p.spec(mname).length
    for i in range(n):
        one = enc.encode({k: float(v[i]) for k, v in vals.items()})
        assert batch[i, :length].tobytes() == one, (mname, i)
        assert not batch[i, length:].any()


def test_counters_are_automatic_and_wrap_0_to_14(lde):
    enc = MessageEncoder(lde, "LDE_Overlay", counter_start=13)
    counters = [enc.encode({"OverlayTorque": 0.5})[1] & 0x0F for _ in range(4)]
    assert counters == [13, 14, 0, 1]
    data = encode_batch(lde, "LDE_Overlay", {"OverlayTorque": np.zeros(20)}, counter_start=10)
    assert list(data[:, 1] & 0x0F) == [(10 + i) % 15 for i in range(20)]
    assert all(p01_check(0x3D0, row.tobytes()) for row in data)


def test_caller_may_not_pass_counter_or_crc_and_unknown_names_raise(lde):
    enc = MessageEncoder(lde, "LDE_Estimate")
    with pytest.raises(EncodeError, match="filled by the encoder"):
        enc.encode({"LatForce": 1.0, "Counter": 3})
    with pytest.raises(EncodeError, match="filled by the encoder"):
        encode_batch(lde, "LDE_Estimate", {"CRC": np.zeros(2)})
    with pytest.raises(EncodeError, match="unknown signals"):
        enc.encode({"LatForc": 1.0})


def test_nan_raises_and_out_of_range_saturates(lde):
    enc = MessageEncoder(lde, "LDE_Overlay")
    with pytest.raises(EncodeError, match="NaN"):
        enc.encode({"OverlayTorque": float("nan")})
    with pytest.raises(EncodeError, match="NaN"):
        encode_batch(lde, "LDE_Overlay", {"OverlayTorque": np.array([0.0, np.nan])})
    hi = decode_frame(lde, "LDE_Overlay", enc.encode({"OverlayTorque": 50.0}))
    lo = decode_frame(lde, "LDE_Overlay", enc.encode({"OverlayTorque": -50.0}))
    assert hi["OverlayTorque"] == pytest.approx(10.23)
    assert lo["OverlayTorque"] == pytest.approx(-10.24)
    inf = decode_frame(
        lde, "LDE_Estimate", MessageEncoder(lde, "LDE_Estimate").encode({"LatForce": float("inf")})
    )
    assert inf["LatForce"] == 8191


def test_missing_signals_default_to_physical_zero(hyundai):
    enc = MessageEncoder(hyundai, "MDPS12")
    dec = decode_frame(hyundai, "MDPS12", enc.encode({"CR_Mdps_StrTq": 1.5}))
    assert dec["CR_Mdps_StrTq"] == pytest.approx(1.5)
    assert dec["CR_Mdps_OutTq"] == pytest.approx(0.0)
    assert dec["CR_Mdps_StrColTq"] == pytest.approx(0.0)


def test_message_has_timestamp_and_id(lde):
    m = MessageEncoder(lde, "LDE_Estimate").message({"LatForce": -120.0}, t_ns=1_700_000_000_123_456_000)
    assert m.arbitration_id == 0x3D1 and not m.is_extended_id and m.dlc == 8
    assert m.timestamp == pytest.approx(1_700_000_000.123456, abs=1e-6)
    assert lde.db.decode_message(0x3D1, m.data)["LatForce"] == -120


def test_si_to_dbc_converts_units_and_signs(lde, hyundai):
    d = si_to_dbc(lde, "MDPS_Sensors", {"steering_angle": 0.1, "column_torque": -1.5, "steering_rate": -1.0})
    assert d["SteeringAngle"] == pytest.approx(0.1 / DEG)
    assert d["SteeringRate"] == pytest.approx(-1.0 / DEG)
    assert d["ColumnTorque"] == -1.5
    e = si_to_dbc(lde, "ESC_Motion", {"speed": 25.0, "yaw_rate": np.array([0.01, -0.02])})
    assert e["VehicleSpeed"] == pytest.approx(90.0)
    assert np.allclose(e["YawRate"], np.array([0.01, -0.02]) / DEG)
    w = si_to_dbc(hyundai, "WHL_SPD11", {"speed": 20.0})
    assert set(w) == {"WHL_SPD_FL", "WHL_SPD_FR", "WHL_SPD_RL", "WHL_SPD_RR"}
    assert all(v == pytest.approx(20.0 / KMH) for v in w.values())
    with pytest.raises(EncodeError, match="not carried"):
        si_to_dbc(lde, "ESC_Motion", {"column_torque": 1.0})


def test_encode_frames_builds_a_frame_batch(hyundai):
    t = np.arange(5, dtype=np.int64) * 20_000_000
    fb = encode_frames(hyundai, "SAS11", t, {"SAS_Angle": 12.3})
    assert len(fb) == 5 and (fb.dlc == 5).all() and (fb.can_id == 688).all() and not fb.is_extended.any()
    assert list(fb.data[:, 4] & 0x0F) == [0, 1, 2, 3, 4]
    assert hyundai.db.decode_message(688, fb.data[2, :5].tobytes())["SAS_Angle"] == pytest.approx(12.3)


MOTOROLA_DBC = """VERSION ""

NS_ :

BS_:

BU_: A

BO_ 291 Mixed: 8 A
 SG_ BeSigned : 7|12@0- (0.5,-3) [-1027|1020.5] "" A
 SG_ BeUnsigned : 27|9@0+ (1,0) [0|511] "" A
 SG_ BeCross : 45|14@0+ (0.01,0) [0|163.83] "" A
 SG_ LeSigned : 56|8@1- (1,0) [-128|127] "" A
"""


FD_DBC = """VERSION ""

NS_ :

BS_:

BU_: A

BO_ 1234 Wide: 64 A
 SG_ LeLow : 0|12@1+ (1,0) [0|4095] "" A
 SG_ LeAcross : 60|16@1- (0.1,0) [-3276.8|3276.7] "" A
 SG_ LeHigh : 300|20@1+ (1,0) [0|1048575] "" A
 SG_ LeLast : 504|8@1+ (1,0) [0|255] "" A
 SG_ Le64 : 131|64@1+ (1,0) [0|0] "" A
 SG_ BeHigh : 207|16@0- (0.01,0) [-327.68|327.67] "" A
 SG_ BeCross : 389|14@0+ (1,0) [0|16383] "" A
 SG_ BeLast : 503|8@0+ (1,0) [0|255] "" A
"""


def _raws(codecs, n, rng):
    """Random raw values over each signal's full bit range."""
    out = {}
    for name, c in codecs.items():
        if c.length == 64:
            out[name] = rng.integers(0, np.iinfo(np.uint64).max, n, dtype=np.uint64, endpoint=True)
        else:
            out[name] = rng.integers(c.raw_min, c.raw_max + 1, n)
    return out


@pytest.mark.parametrize(("dbc", "name", "length"), [(MOTOROLA_DBC, "Mixed", 8), (FD_DBC, "Wide", 64)])
def test_signal_codec_bit_layout_matches_cantools_intel_and_motorola(dbc, name, length):
    """Raw values packed by cantools (the oracle) are unpacked by lde's codec and the other way
    round, Intel and Motorola, in a classic frame and in a 64-byte CAN FD frame (signals past byte 8,
    across byte boundaries, a 64-bit field off a byte boundary)."""
    db = cantools.database.load_string(dbc, database_format="dbc")
    msg = db.get_message_by_name(name)
    codecs = {s.name: SignalCodec.from_cantools(s) for s in msg.signals}
    rng = np.random.default_rng(11)
    n = 200
    raws = _raws(codecs, n, rng)
    data = np.zeros((n, length), np.uint8)
    for i in range(n):
        row = {k: int(v[i]) for k, v in raws.items()}
        data[i] = np.frombuffer(msg.encode(row, scaling=False, strict=False), np.uint8)
    for k, c in codecs.items():
        got = c.raw_batch(data)
        assert np.array_equal(got.view(np.uint64) if c.length == 64 else got, raws[k]), k
        assert np.allclose(c.decode_batch(data), raws[k] * c.scale + c.offset)
    # lde's packer -> cantools
    codec_list = list(codecs.values())
    lay = MessageLayout.of(
        msg.frame_id, length, IntegrityScheme.of(INTEGRITY["none"], (), ()), codec_list, frozenset()
    )
    for i in range(20):
        # float64 holds raw values up to 2**53 exactly: a 64-bit field's are cut to that here
        want = {
            c.name: int(raws[c.name][i]) % (1 << 52) if c.length == 64 else int(raws[c.name][i])
            for c in codec_list
        }
        phys = np.array([want[c.name] * c.scale + c.offset for c in codec_list])
        ref = msg.decode(lay.encode(phys, 0), scaling=False)
        for c in codec_list:
            assert ref[c.name] == want[c.name], c.name


@settings(derandomize=True, max_examples=200, deadline=None)
@given(
    torque=st.floats(-20.0, 20.0, allow_nan=False),
    angle=st.floats(-500.0, 500.0, allow_nan=False),
    rate=st.floats(-600.0, 600.0, allow_nan=False),
)
def test_property_round_trip_is_saturated_rounding(torque, angle, rate):
    p = load_profile("lde")
    c = MessageCodec(p, "MDPS_Sensors")
    vals = {"ColumnTorque": torque, "SteeringAngle": angle, "SteeringRate": rate}
    dec = c.decode(MessageEncoder(p, "MDPS_Sensors").encode(vals))
    for k, v in vals.items():
        s = c.signals[k]
        expected = min(max(v, s.minimum), s.maximum)
        assert abs(dec[k] - expected) <= s.scale / 2 + 1e-9, k
