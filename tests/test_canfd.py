"""CAN FD frames (up to 64 data bytes) and the bus of each frame, through every reader and writer,
the recording, the receiver, and a profile whose signals sit beyond byte 8."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from lde.can.codec import MessageCodec, encode_frames
from lde.can.e2e import p01_check
from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.engine.receiver import Receiver, decode_batch
from lde.io import McapWriter, read_log, read_mcap, write_candump
from lde.io.candump import format_candump_bytes, parse_candump_bytes
from lde.io.recording import StepRing
from lde.units import DEG, KMH

T0 = 1_700_000_000_000_000_000
FD_LENGTHS = (12, 16, 20, 24, 32, 48, 64)


def fd_frames(n: int, seed: int = 0, buses: tuple[str, ...] = ("can0", "can1")) -> FrameBatch:
    """Classic and CAN FD frames on several buses, microsecond timestamps, zero padded."""
    rng = np.random.default_rng(seed)
    t = T0 + np.sort(rng.integers(0, 10 * 10**9, n)) // 1000 * 1000
    ext = rng.random(n) < 0.2
    cid = np.where(ext, rng.integers(0, 1 << 29, n), rng.integers(0, 0x800, n))
    dlc = np.where(rng.random(n) < 0.5, rng.integers(0, 9, n), rng.choice(FD_LENGTHS, n))
    data = rng.integers(0, 256, (n, 64)).astype(np.uint8)
    data[np.arange(64)[None, :] >= dlc[:, None]] = 0
    return FrameBatch(
        t_ns=t,
        can_id=cid,
        is_extended=ext,
        dlc=dlc,
        data=data,
        is_rx=rng.random(n) < 0.7,
        channel=rng.integers(0, len(buses), n),
        channels=buses,
    )


def assert_same_frames(a: FrameBatch, b: FrameBatch, rx: bool = True) -> None:
    assert len(a) == len(b)
    for name in ("t_ns", "can_id", "is_extended", "dlc") + (("is_rx",) if rx else ()):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    w = max(a.width, b.width)
    np.testing.assert_array_equal(a.widened(w).data, b.widened(w).data, err_msg="data")
    assert a.channel_names().tolist() == b.channel_names().tolist()


def test_a_batch_is_as_wide_as_its_longest_frame():
    f = fd_frames(300, seed=1)
    classic = FrameBatch.from_messages(f.select(f.dlc <= 8).to_messages())
    assert classic.width == 8
    assert f.width == 64
    both = FrameBatch.concat([classic, f], sort=False)
    assert both.width == 64 and set(both.channels) == {"can0", "can1"}
    assert both.channel_names().tolist() == classic.channel_names().tolist() + f.channel_names().tolist()
    again = FrameBatch.from_messages(f.to_messages(), sort=False)
    assert_same_frames(again, f)


def test_candump_keeps_fd_bytes_and_interface_names(tmp_path: Path):
    frames = fd_frames(2000, seed=2)
    path = tmp_path / "fd.log"
    write_candump(path, frames)
    text = path.read_text()
    assert "##0" in text and " can1 " in text
    assert_same_frames(read_log(path).frames, frames.sort())
    # python-can's candump reader agrees on every frame (its independent parser)
    msgs = list(can.LogReader(str(path)))
    assert [len(m.data) for m in msgs] == frames.sort().dlc.tolist()
    assert [m.channel for m in msgs] == frames.sort().channel_names().tolist()


def test_candump_without_interface_column_is_the_unnamed_bus():
    p = parse_candump_bytes(b"(1.000000) 123#0102\n(1.000001) 124##0" + b"AB" * 20 + b"\n")
    assert p.frames.channels == ("",) and p.frames.dlc.tolist() == [2, 20]
    assert format_candump_bytes(p.frames, "vcan7").decode().startswith("(1.000000) vcan7 123#0102")


@pytest.mark.parametrize("library", [False, True])
def test_mcap_keeps_fd_bytes_and_buses(tmp_path: Path, library: bool):
    frames = fd_frames(3000, seed=3)
    path = tmp_path / "fd.mcap"
    with McapWriter(path) as w:
        w.write_frames(frames)
    data = read_mcap(path, force_library=library)
    assert_same_frames(data.frames, frames)
    assert {"/can/can0/rx", "/can/can1/fd/rx", "/can/can0/fd/tx"} <= set(data.topics)
    rx_only = read_mcap(path, skip_tx=True, force_library=library)
    assert_same_frames(rx_only.frames, frames.select(frames.is_rx))


def test_mcap_fd_schema_decodes_with_the_ros2_cdr_decoder(tmp_path: Path):
    pytest.importorskip(
        "mcap_ros2", reason="mcap-ros2-support (the reference ROS 2 CDR decoder) not installed"
    )
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    frames = fd_frames(300, seed=4)
    fd = frames.select(frames.dlc > 8)
    path = tmp_path / "ros.mcap"
    with McapWriter(path) as w:
        w.write_frames(fd)
    got = []
    with path.open("rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for _s, ch, message, ros in reader.iter_decoded_messages():
            got.append((message.log_time, ros.id, ros.dlc, bytes(ros.data), ch.metadata.get("bus")))
    got.sort(key=lambda g: g[0])
    assert [g[0] for g in got] == fd.t_ns.tolist()
    assert [g[1] for g in got] == fd.can_id.tolist()
    assert [g[3] for g in got] == [fd.data[i, : fd.dlc[i]].tobytes() for i in range(len(fd))]
    assert [g[4] for g in got] == fd.channel_names().tolist()


@pytest.mark.parametrize("suffix", [".blf", ".asc", ".mcap"])
def test_python_can_logs_keep_fd_bytes_and_channels(tmp_path: Path, suffix: str):
    frames = fd_frames(400, seed=5, buses=("1", "2"))
    path = tmp_path / f"x{suffix}"
    with can.Logger(str(path)) as logger:
        for m in frames.to_messages():
            m.channel = int(m.channel) if suffix != ".mcap" else m.channel
            logger.on_message_received(m)
    got = read_log(path).frames
    if suffix == ".mcap":  # lde's own file: every column, the timestamps exact
        assert_same_frames(got, frames)
    np.testing.assert_array_equal(got.dlc, frames.dlc)
    np.testing.assert_array_equal(got.widened(64).data, frames.data)
    assert got.channel_names().tolist() == frames.channel_names().tolist()


def test_recorder_ring_keeps_fd_bytes():
    frames = fd_frames(200, seed=6, buses=("",))
    ring = StepRing(frames=256, steps=16, frame_bytes=64)
    try:
        for i in range(len(frames)):
            word = int.from_bytes(frames.data[i, : frames.dlc[i]].tobytes(), "little")
            ring.put_frame(
                int(frames.t_ns[i]),
                int(frames.can_id[i]),
                bool(frames.is_extended[i]),
                int(frames.dlc[i]),
                word,
                True,
            )
        got = ring.take_frames()
    finally:
        ring.close()
    np.testing.assert_array_equal(got.dlc, frames.dlc)
    np.testing.assert_array_equal(got.widened(64).data, frames.data)


# ------------------------------------------------------------------------- a CAN FD profile

FD_DBC = """VERSION ""

NS_ :

BS_:

BU_: EPS ESC LDE

BO_ 320 STEER_FD: 64 EPS
 SG_ CRC : 0|8@1+ (1,0) [0|255] "" LDE
 SG_ Counter : 8|4@1+ (1,0) [0|14] "" LDE
 SG_ Torque : 100|16@1- (0.001,0) [-32.768|32.767] "Nm" LDE
 SG_ Assist : 207|16@0- (0.001,0) [-32.768|32.767] "Nm" LDE
 SG_ Angle : 400|16@1- (0.1,0) [-3276.8|3276.7] "deg" LDE
 SG_ Rate : 495|12@0- (2,0) [-4096|4094] "deg/s" LDE

BO_ 336 MOTION_FD: 32 ESC
 SG_ Yaw : 130|16@1- (0.01,0) [-327.68|327.67] "deg/s" LDE
 SG_ Lat : 170|12@1- (0.01,0) [-20.48|20.47] "m/s^2" LDE
 SG_ Speed : 247|16@0+ (0.01,0) [0|655.35] "km/h" LDE

BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;
BA_DEF_DEF_ "GenMsgCycleTime" 0;
BA_ "GenMsgCycleTime" BO_ 320 4;
BA_ "GenMsgCycleTime" BO_ 336 10;
"""

FD_PROFILE = """
dbc = "fd.dbc"
[inputs.column_torque]
message = "STEER_FD"
signal = "Torque"
scale = "Nm"
[inputs.assist_torque]
message = "STEER_FD"
signal = "Assist"
scale = "Nm"
[inputs.steering_angle]
message = "STEER_FD"
signal = "Angle"
scale = "deg"
[inputs.steering_rate]
message = "STEER_FD"
signal = "Rate"
scale = "deg/s"
[inputs.yaw_rate]
message = "MOTION_FD"
signal = "Yaw"
scale = "deg/s"
[inputs.lat_accel]
message = "MOTION_FD"
signal = "Lat"
scale = "m/s^2"
[inputs.speed]
message = "MOTION_FD"
signal = "Speed"
scale = "km/h"
[messages.STEER_FD]
integrity = "autosar_e2e_p01"
counter = "Counter"
checksum = "CRC"
[messages.MOTION_FD]
integrity = "none"
"""


@pytest.fixture
def fd_profile(tmp_path: Path):
    (tmp_path / "fd.dbc").write_text(FD_DBC)
    (tmp_path / "fd.toml").write_text(FD_PROFILE)
    return load_profile(tmp_path / "fd.toml")


def test_fd_profile_decodes_signals_beyond_byte_8_in_a_log_and_live(fd_profile, tmp_path: Path):
    p = fd_profile
    assert p.messages["STEER_FD"].length == 64 and p.messages["MOTION_FD"].length == 32
    n = 50
    t = T0 + np.arange(n, dtype=np.int64) * 4_000_000
    torque = np.linspace(-3.0, 3.0, n)
    angle = np.linspace(-10.0, 20.0, n)
    steer = encode_frames(
        p, "STEER_FD", t, {"Torque": torque, "Assist": -torque, "Angle": angle, "Rate": 100.0}
    )
    assert steer.width == 64 and all(p01_check(0x140, steer.data[i].tobytes()) for i in range(n))
    motion = encode_frames(p, "MOTION_FD", t + 1000, {"Yaw": 1.5, "Lat": -0.75, "Speed": 72.0})
    log = tmp_path / "fd.log"
    write_candump(log, FrameBatch.concat([steer, motion]), channel="can2")
    d = decode_batch(p, read_log(log).frames)
    assert d.messages["STEER_FD"].stats.used == n - 2 and d.messages["STEER_FD"].stats.wrong_crc == 0
    np.testing.assert_allclose(d.inputs["column_torque"].value, torque[2:], atol=0.0005)
    np.testing.assert_allclose(d.inputs["assist_torque"].value, -torque[2:], atol=0.0005)
    np.testing.assert_allclose(d.inputs["steering_angle"].value, angle[2:] * DEG, atol=0.05 * DEG)
    np.testing.assert_allclose(d.inputs["steering_rate"].value, 100.0 * DEG)
    np.testing.assert_allclose(d.inputs["speed"].value, 72.0 * KMH)
    np.testing.assert_allclose(d.inputs["yaw_rate"].value, 1.5 * DEG)
    # the live receiver, frame by frame from python-can messages
    rx = Receiver(p)
    for m in FrameBatch.concat([steer, motion]).to_messages():
        rx.feed(int(round(m.timestamp * 1e9)), m.arbitration_id, bytes(m.data))
    s = rx.sample(int(t[-1]) + 2000)
    assert s.mdps_ok and s.esc_ok
    assert s.column_torque == pytest.approx(3.0, abs=0.0005) and s.lat_accel == pytest.approx(-0.75)
    # a frame cut to 8 bytes is malformed, never decoded
    short = rx.feed(int(t[-1]) + 3000, 0x140, steer.data[0, :8].tobytes())
    assert short.malformed


def test_fd_codec_round_trip(fd_profile):
    c = MessageCodec(fd_profile, "STEER_FD")
    raw = encode_frames(fd_profile, "STEER_FD", np.zeros(1, np.int64), {"Angle": -123.4, "Rate": -512.0})
    dec = c.decode(raw.data[0].tobytes())
    assert dec["Angle"] == pytest.approx(-123.4) and dec["Rate"] == -512.0 and dec["Torque"] == 0.0


def test_the_live_service_steps_on_fd_frames_records_them_and_the_recording_replays(fd_profile, tmp_path):
    """An FD profile live: the service takes 64- and 32-byte frames from python-can's virtual bus, its
    inputs are decoded, its recorder keeps every byte, and the recording replays to the live
    estimates."""
    import itertools

    from lde.can.codec import MessageEncoder
    from lde.clock import SimulatedClock
    from lde.io.recording import Recorder, read_recording
    from lde.params import load_vehicle
    from lde.replay.replay import replay_log
    from lde.service.service import Service
    from lde.units import STEP_NS

    ch = f"lde-test-canfd-{next(itertools.count())}-{id(tmp_path)}"
    feed = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    vehicle = load_vehicle("reference")
    clock = SimulatedClock(T0)
    try:
        svc = Service(bus, fd_profile, vehicle, clock, backend="float")
        assert svc.rx_width == 64
        rec = svc.recorder = Recorder(tmp_path / "fd.mcap", frame_bytes=svc.rx_width)
        steer, motion = MessageEncoder(fd_profile, "STEER_FD"), MessageEncoder(fd_profile, "MOTION_FD")
        t_motion = T0 - 2_000_000
        fw = []
        for k in range(600):
            t_k = T0 + k * STEP_NS
            feed.send(steer.message({"Torque": 0.8, "Assist": 1.2, "Angle": 0.5, "Rate": 0.0}, t_k - 300_000))
            while t_motion <= t_k:
                feed.send(motion.message({"Yaw": 0.0, "Lat": 0.0, "Speed": 100.0}, t_motion))
                t_motion += 10_000_000
            clock.sleep_until(t_k)
            fw.append(svc.step_once(t_k).fw)
        s = svc.receiver.sample(T0 + 599 * STEP_NS)
        assert s.mdps_ok and s.esc_ok
        assert s.column_torque == pytest.approx(0.8) and s.speed == pytest.approx(100.0 * KMH)
        rec.close()
    finally:
        feed.shutdown()
        bus.shutdown()
    got = read_recording(tmp_path / "fd.mcap")
    steer_rx = got.rx.select(got.rx.can_id == 0x140)
    assert len(steer_rx) == 600 and (steer_rx.dlc == 64).all() and steer_rx.width == 64
    assert all(p01_check(0x140, steer_rx.data[i].tobytes()) for i in range(len(steer_rx)))
    _, res = replay_log(tmp_path / "fd.mcap", fd_profile, vehicle, "float")
    np.testing.assert_array_equal(res.fw, fw)
    assert np.isfinite(fw[-1]) and fw[-1] != 0.0
