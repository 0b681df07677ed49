"""Bad input never ends in a traceback: a clear one-line error (exit 2) or a counted rejection.

Covers broken files (missing, empty, a directory, garbage, truncated candump and MCAP), odd candump
lines (odd hex length, too long, CAN FD, error and remote frames, 29-bit ids), odd traffic (out of
order, duplicated, wrong CRC, counter jumps, mid-drive start, only ESC frames, unknown ids only, low
speed, a long silence, two time bases in one log), bad vehicle files and bad ``lde sim`` options,
and fuzzes the candump parser and :func:`lde.engine.receiver.decode_batch` with hypothesis.

Most checks call :func:`lde.cli.main` in-process (the same code path as the ``lde`` command, without
the start-up cost of a subprocess); ``tests/test_cli_contract.py`` runs the real command.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lde.can.e2e import protect_frame
from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.cli import main
from lde.engine.grid import MAX_GAP_NS, build_grid
from lde.engine.receiver import Receiver, decode_batch
from lde.errors import LogFormatError
from lde.estimator.paper import Status
from lde.io import read_log, write_candump
from lde.io.candump import format_candump, parse_candump_bytes
from lde.params import load_vehicle
from lde.replay.replay import replay
from lde.units import STEP_NS

MDPS_ID = 0x2A0
ESC_ID = 0x2A8
SEC = 1_000_000_000
FUZZ = settings(
    max_examples=150,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def profile():
    return load_profile("lde")


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("reference")


@pytest.fixture(scope="module")
def drive():
    """6 s of crosswind at 120 km/h (the wind ramps up over the first 2 s), lde profile."""
    from vcan_sim.run import simulate

    return simulate("steady_wind", seed=1, duration=6.0).frames


@pytest.fixture(scope="module")
def drive_log(drive, tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("robust") / "drive.log"
    write_candump(p, drive)
    return p


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    rc = main(list(argv))
    out, err = capsys.readouterr()
    return rc, out, err


def assert_one_line_error(rc: int, err: str, *words: str) -> None:
    assert rc == 2, err
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("lde: error: "), err
    for w in words:
        assert w in lines[0], (w, err)


def csv_rows(path: Path) -> tuple[list[str], np.ndarray]:
    text = path.read_text().splitlines()
    header = text[0].split(",")
    if len(text) == 1:
        return header, np.zeros((0, len(header)))
    return header, np.genfromtxt(path, delimiter=",", skip_header=1, ndmin=2)


# ----------------------------------------------------------------------------- broken files
def test_missing_empty_directory_and_garbage_files_are_one_line_errors(tmp_path, capsys):
    rng = np.random.default_rng(5)
    garbage = rng.integers(0, 256, 3000, dtype=np.uint8).tobytes()
    (tmp_path / "empty.log").write_bytes(b"")
    (tmp_path / "dir.log").mkdir()
    cases = {
        "missing.log": "no such file",
        "empty.log": "empty",
        "dir.log": "dir.log",
        "garbage.log": "candump",
        "garbage.mcap": "MCAP",
        "garbage.blf": "garbage.blf",
        "garbage.asc": "garbage.asc",
        "garbage.bin": "unknown log format",
        "text.log": "candump",
    }
    for name in ("garbage.log", "garbage.mcap", "garbage.blf", "garbage.asc", "garbage.bin"):
        (tmp_path / name).write_bytes(garbage)
    (tmp_path / "text.log").write_text("hello world\nthis is not CAN\n")
    for name, word in cases.items():
        rc, _, err = run_cli(capsys, "replay", "-q", str(tmp_path / name))
        assert_one_line_error(rc, err, word)


def test_mcap_cut_inside_the_frame_chunk_is_an_error_and_after_it_still_replays(tmp_path, capsys):
    """A cut inside the chunk holding the frames leaves no frame: one-line error. A cut after that
    chunk (inside the truth chunk) still replays every frame and counts the cut."""
    from mcap_util import chunk_spans

    from vcan_sim.output import write_outputs
    from vcan_sim.run import simulate

    src = tmp_path / "sim.mcap"
    write_outputs(simulate("straight", seed=2, duration=2.0), mcap=src)
    raw = src.read_bytes()
    chunks = chunk_spans(src)
    first = chunks[0]
    cut_in = tmp_path / "cut_in.mcap"
    cut_in.write_bytes(raw[: first.chunk_start_offset + first.chunk_length // 2])
    rc, _, err = run_cli(capsys, "replay", "-q", str(cut_in))
    assert_one_line_error(rc, err, "cut_in.mcap")
    full = read_log(src)
    replayed = 0
    for c in chunks[1:]:
        cut_after = tmp_path / "cut_after.mcap"
        cut_after.write_bytes(raw[: c.chunk_start_offset + c.chunk_length // 2])
        log = read_log(cut_after)
        assert log.stats.truncated_last_line == 1
        if len(log.frames) == len(full.frames):  # this chunk held no CAN frames
            rc, _, err = run_cli(capsys, "replay", str(cut_after), "--csv", str(tmp_path / "c.csv"))
            assert rc == 0, err
            assert "the cut last record (bytes " in err and "line" not in err.split("not read:")[1]
            replayed += 1
    assert replayed >= 1


def test_candump_odd_lines_are_counted_not_fatal(drive_log, tmp_path, profile, vehicle):
    lines = drive_log.read_text().splitlines(keepends=True)
    t_mid = lines[300][1:18]
    extra = [
        f"({t_mid}) vcan0 2A0#D60040FFDFFF070\n",  # odd number of hex digits
        f"({t_mid}) vcan0 2A0#D60040FFDFFF07000102\n",  # 10 data bytes on classic CAN
        f"({t_mid}) vcan0 2A0##1D60040FFDFFF07000102030405\n",  # CAN FD, 14 bytes: wrong length
        f"({t_mid}) vcan0 20000080#0000000000000000\n",  # error frame
        f"({t_mid}) vcan0 2A0#R\n",  # remote frame
        f"({t_mid}) vcan0 000002A0#D60040FFDFFF0700\n",  # 29-bit id equal to MDPS's number
        f"({t_mid}) vcan0 12345678#0011\n",  # unknown 29-bit id
        "(oops) vcan0 2A0#00\n",
        "\n",
    ]
    bad = tmp_path / "odd.log"
    bad.write_text("".join(lines[:300] + extra + lines[300:])[:-12])  # last line cut off too
    log = read_log(bad)
    s = log.stats
    assert (s.malformed_lines, s.error_frames, s.remote_frames, s.truncated_last_line) == (3, 1, 1, 1)
    assert s.first_malformed_line == 301
    res = replay(log.frames, profile, vehicle, "float")
    assert res.frames.ignored == 2
    assert res.frames.messages["MDPS_Sensors"].malformed == 1  # the FD frame
    ref = replay(read_log(drive_log).frames, profile, vehicle, "float")
    n = len(res)
    assert n in (len(ref), len(ref) - 1)  # the cut last line may end the grid one step early
    # the odd frames change nothing: no odd frame was accepted
    np.testing.assert_array_equal(res.fw, ref.fw[:n])


def test_candump_lines_out_of_order_duplicated_or_with_crlf_read_as_the_sorted_frames(drive_log, tmp_path):
    lines = drive_log.read_text().splitlines()
    rng = np.random.default_rng(8)
    p = tmp_path / "messy.log"
    messy = [lines[i] for i in rng.permutation(len(lines))] + lines[:50]
    p.write_bytes("".join(line + "\r\n" for line in messy).encode())
    got = read_log(p).frames
    ref = read_log(drive_log).frames
    assert len(got) == len(ref) + 50 and got.is_sorted()
    keep = np.ones(len(got), bool)
    _, first = np.unique(np.column_stack([got.t_ns, got.can_id]), axis=0, return_index=True)
    keep[:] = False
    keep[first] = True
    np.testing.assert_array_equal(got.select(keep).t_ns, ref.t_ns)


def test_out_of_order_and_duplicated_frames(drive, profile, vehicle):
    ref = replay(drive, profile, vehicle, "float")
    rng = np.random.default_rng(3)
    shuffled = drive.take(rng.permutation(len(drive)))
    res = replay(shuffled, profile, vehicle, "float")  # frames are sorted by time first
    np.testing.assert_array_equal(res.fw, ref.fw)
    doubled = FrameBatch.concat([drive, drive])  # every frame twice: the copies are REPEATED
    res = replay(doubled, profile, vehicle, "float")
    np.testing.assert_array_equal(res.fw, ref.fw)
    m = res.frames.messages["MDPS_Sensors"]
    assert m.repeated == ref.frames.messages["MDPS_Sensors"].received
    assert res.frames.used == ref.frames.used


def _status_at(res, t_ns: int) -> int:
    return int(res.status[np.searchsorted(res.t_ns, t_ns)])


def test_wrong_crc_and_counter_jump_are_rejected_then_trusted_again(drive, profile, vehicle):
    fb = drive.take(np.arange(len(drive)))
    mdps = np.flatnonzero(fb.can_id == MDPS_ID)
    i_crc = mdps[700]
    fb.data[i_crc, 3] ^= 0x40  # payload changed, CRC not: WRONGCRC
    spec = profile.messages["MDPS_Sensors"]
    for i in mdps[900:]:  # the counter jumps by 6 > MaxDeltaCounter 2, then runs on
        buf = bytearray(fb.data[i].tobytes())
        protect_frame(spec.scheme, MDPS_ID, buf, ((buf[1] & 0x0F) + 5) % 15)
        fb.data[i] = np.frombuffer(bytes(buf), np.uint8)
    res = replay(fb, profile, vehicle, "float")
    m = res.frames.messages["MDPS_Sensors"]
    assert m.wrong_crc == 1 and m.wrong_sequence == 1
    t_crc, t_jump = int(drive.t_ns[i_crc]), int(drive.t_ns[mdps[900]])
    assert _status_at(res, t_crc) & Status.MDPS_FAULT
    assert _status_at(res, t_jump) & Status.MDPS_FAULT
    assert res.status[-1] & Status.VALID  # trusted again after the sync frames


def test_log_starting_mid_drive(drive, profile, vehicle):
    """The first frames' counters are anywhere in 0..14: the receiver starts on them."""
    t_cut = int(drive.t_ns[0]) + 2 * SEC + 1_234_567
    part = drive.select(drive.t_ns >= t_cut)
    counters = part.data[part.can_id == MDPS_ID, 1] & 0x0F
    assert counters[0] != 0
    res = replay(part, profile, vehicle, "float")
    assert res.t_ns[0] >= t_cut and res.frames.rejected == 0
    assert res.status[-1] & Status.VALID


def test_long_silence_makes_inputs_stale_then_recovers(drive, profile, vehicle):
    t0 = int(drive.t_ns[0])
    gap = (drive.t_ns >= t0 + 2 * SEC) & (drive.t_ns < t0 + 4 * SEC)
    res = replay(drive.select(~gap), profile, vehicle, "fixed")
    t = res.t_ns - t0
    assert np.all(np.diff(res.t_ns) == STEP_NS)  # stepped through the silence
    before = (t > 1.5 * SEC) & (t < 2 * SEC)
    inside = (t > 2.1 * SEC) & (t < 4 * SEC)
    after = t > 5.5 * SEC  # trusted again at once, VALID after the convergence time
    assert res.grid.mdps_ok[before].all() and res.status[before][-1] & Status.VALID
    assert not res.grid.mdps_ok[inside].any() and not res.grid.esc_ok[inside].any()
    assert not np.any(res.status[inside] & Status.VALID)
    assert np.all(res.status[inside] & Status.MDPS_FAULT)
    assert np.all(res.t_overlay[t > 3 * SEC][: np.count_nonzero(inside & (t > 3 * SEC))] == 0.0)
    assert np.all(res.status[after] & Status.VALID) and res.grid.mdps_ok[after].all()


def test_two_time_bases_in_one_log_replay_each_part(drive, profile, vehicle, tmp_path, capsys):
    """First part with timestamps relative to 0, the rest in epoch seconds (two logs joined):
    two grid segments instead of 4e11 steps across the jump; ``t`` keeps each part's base."""
    t0 = int(drive.t_ns[0])
    split = t0 + 3 * SEC
    early = drive.select(drive.t_ns < split)
    early.t_ns = early.t_ns - t0
    mixed = FrameBatch.concat([early, drive.select(drive.t_ns >= split)])
    res = replay(mixed, profile, vehicle, "float")
    jumps = np.flatnonzero(np.diff(res.t_ns) != STEP_NS)
    assert jumps.size == 1
    assert res.t_ns[0] < 1 * SEC and res.t_ns[jumps[0] + 1] >= split
    assert len(res) < 2 * 6 * SEC // STEP_NS
    assert res.status[jumps[0]] & Status.VALID and res.status[-1] & Status.VALID
    # and through the command, from a candump log with both bases
    p = tmp_path / "mixed.log"
    write_candump(p, mixed)
    rc, _, err = run_cli(capsys, "replay", str(p), "--csv", str(tmp_path / "m.csv"))
    assert rc == 0, err
    header, rows = csv_rows(tmp_path / "m.csv")
    assert rows.shape[0] == len(res) and rows[0, 0] < 1.0 and rows[-1, 0] > 1.6e9


def test_silence_longer_than_the_gap_limit_starts_a_new_segment(drive, profile):
    t0 = int(drive.t_ns[0])
    late = drive.take(np.arange(len(drive)))
    late.t_ns = late.t_ns + (late.t_ns >= t0 + 3 * SEC) * (MAX_GAP_NS + 7 * SEC)
    g = build_grid(decode_batch(profile, late), profile)
    assert len(g) < 6 * SEC // STEP_NS + 2
    seg2 = g.t_ns[np.flatnonzero(np.diff(g.t_ns) > STEP_NS)[0] + 1]
    mdps_t = late.t_ns[late.can_id == MDPS_ID]
    assert seg2 in mdps_t  # the new segment is anchored at an MDPS frame


def test_absurd_timestamp_does_not_allocate_a_huge_grid(drive, profile, vehicle):
    """One frame far in the future (a corrupt timestamp): no 10^11-step grid, no MemoryError."""
    fb = drive.take(np.arange(200))
    far = fb.take(np.flatnonzero(fb.can_id == MDPS_ID)[-3:])
    far.t_ns = far.t_ns + 10**9 * SEC
    res = replay(FrameBatch.concat([fb, far]), profile, vehicle, "float")
    assert len(res) < 200


def test_a_grid_beyond_max_steps_is_a_clear_error():
    from lde.engine.grid import MAX_STEPS, segmented_step_times

    every = np.arange(MAX_STEPS // (MAX_GAP_NS // STEP_NS) + 2, dtype=np.int64) * MAX_GAP_NS
    with pytest.raises(LogFormatError, match="estimator steps"):
        segmented_step_times(every, every, int(every[-1]))


def test_only_esc_frames_or_unknown_ids_give_an_empty_csv_with_a_note(drive, tmp_path, capsys):
    esc_only = tmp_path / "esc_only.log"
    write_candump(esc_only, drive.select(drive.can_id == ESC_ID))
    unknown = tmp_path / "unknown.log"
    other = drive.take(np.arange(len(drive)))
    other.can_id = other.can_id + 0x100
    write_candump(unknown, other)
    for p in (esc_only, unknown):
        out = tmp_path / f"{p.stem}.csv"
        rc, _, err = run_cli(capsys, "replay", str(p), "--csv", str(out))
        assert rc == 3 and "no estimator step" in err, err  # 3: replayed, nothing usable
        header, rows = csv_rows(out)
        assert header[:4] == ["t", "Fw", "Mw", "T_overlay"] and rows.shape[0] == 0


def test_low_speed_log_gives_no_overlay_and_finite_estimates(profile, vehicle):
    from vcan_sim.run import simulate

    slow = simulate("steady_wind", seed=4, duration=3.0, speed_kmh=20.0).frames
    res = replay(slow, profile, vehicle, "fixed")
    known = res.grid.esc_ok  # the speed is known (before: ESC_FAULT)
    assert known[-1] and np.all(res.status[known] & Status.LOW_SPEED)
    assert not np.any(res.status & Status.VALID)
    assert np.all(res.t_overlay == 0.0) and np.isfinite(res.fw).all() and np.isfinite(res.mw).all()


def test_candump_timestamp_beyond_int64_is_malformed():
    # both exceed int64 ns (9223372036.854775807 s): reject (malformed), never wrap around
    p = parse_candump_bytes(b"(99999999999.000000) vcan0 2A0#00\n(19999999999.5) vcan0 2A0#00\n")
    assert len(p.frames) == 0 and p.malformed_lines == 2


# ----------------------------------------------------------------------------- options and files
def test_bad_vehicle_files_are_one_line_errors(drive_log, tmp_path, capsys):
    files = {
        "neg.toml": ('extends = "reference"\n[vehicle]\nmass_kg = -5.0\n', "mass_kg"),
        "type.toml": ('extends = "reference"\n[vehicle]\nmass_kg = "heavy"\n', "must be a number"),
        "unknown.toml": ('extends = "reference"\n[vehicle]\nmas_kg = 1500\n', "mas_kg"),
        "missing.toml": ('name = "x"\n[vehicle]\nmass_kg = 1500\n', "missing"),
        "a.toml": ('extends = "b.toml"\n', "cycle"),
        "b.toml": ('extends = "a.toml"\n', "cycle"),
        "self.toml": ('extends = "self.toml"\n', "cycle"),
        "badparent.toml": ('extends = "nothere"\n', "nothere"),
        "syntax.toml": ('extends = "reference"\n[vehicle\n', "TOML"),
        "nan.toml": ('extends = "reference"\n[vehicle]\nmass_kg = nan\n', "finite"),
        "table.toml": ('extends = "reference"\nvehicle = 3\n', "table"),
        "sim_gain.toml": ('extends = "reference"\n[sim]\nspeed_gain_per_s = -5.0\n', "speed_gain_per_s"),
    }
    for name, (text, _) in files.items():
        (tmp_path / name).write_text(text)
    for name, (_, word) in files.items():
        if name.startswith("sim_"):  # [sim] is the simulator's: lde sim checks it
            sim = ("sim", "--scenario", "straight", "--duration", "0.2", "--log", str(tmp_path / "s.log"))
            rc, _, err = run_cli(capsys, *sim, "--vehicle", str(tmp_path / name))
        else:
            rc, _, err = run_cli(capsys, "replay", "-q", str(drive_log), "--vehicle", str(tmp_path / name))
        assert_one_line_error(rc, err, word)
    for arg, word in (("nosuch", "nosuch"), (str(tmp_path / "none.toml"), "not found"), (str(tmp_path), "")):
        rc, _, err = run_cli(capsys, "replay", "-q", str(drive_log), "--vehicle", arg)
        assert_one_line_error(rc, err, word)


def test_a_complete_vehicle_file_needs_no_name_and_no_optional_tables(tmp_path):
    p = tmp_path / "my_car.toml"
    p.write_text(
        "[vehicle]\nmass_kg = 1600.0\nyaw_inertia_kgm2 = 2900.0\nlf_m = 1.15\nlr_m = 1.65\n"
        "track_front_m = 1.6\ntrack_rear_m = 1.6\n[steering]\nratio = 14.5\n"
        "[tires]\ncf_N_per_rad = 60000.0\ncr_N_per_rad = 55000.0\nalign_rate_Nm_per_rad = 7000.0\n"
    )
    v = load_vehicle(p)
    assert v.name == "my_car" and v.body.mass == 1600.0 and v.overlay.max_torque > 0


@pytest.mark.parametrize(
    "body",
    [
        "mass_kg = 3000.0\nyaw_inertia_kgm2 = 7000.0\nlf_m = 1.6\nlr_m = 1.9\n[tires]\n"
        "cf_N_per_rad = 90000.0\ncr_N_per_rad = 90000.0\nalign_rate_Nm_per_rad = 12000.0\n",  # a van
        # stiff tires (absolute values, what the fixed-point scaling sees) on a heavy sedan: on the
        # reference body they would be 50 x the rear tire load per rad, which validation rejects
        "mass_kg = 2600.0\nyaw_inertia_kgm2 = 4800.0\n"
        "[tires]\ncf_N_per_rad = 150000.0\ncr_N_per_rad = 140000.0\n",
    ],
)
def test_fixed_backend_takes_heavy_or_stiff_vehicles(body, drive, profile, tmp_path):
    """Their steady-state covariance is small against the tuning's P0: the fixed-point scaling
    adapts (was: ConfigError 'no 2x headroom', so the default backend refused the vehicle)."""
    p = tmp_path / "car.toml"
    p.write_text(f'extends = "reference"\n[vehicle]\n{body}')
    v = load_vehicle(p)
    assert v.name == "car"  # not the parent's name
    fixed = replay(drive, profile, v, "fixed")
    ref = replay(drive, profile, v, "float")
    assert np.all(fixed.status[-200:] & Status.VALID)
    np.testing.assert_allclose(fixed.fw, ref.fw, atol=0.01 * np.abs(ref.fw).max() + 1.0)
    np.testing.assert_allclose(fixed.mw, ref.mw, atol=0.01 * np.abs(ref.mw).max() + 1.0)


def test_extends_prefers_the_file_beside_the_child(tmp_path, monkeypatch):
    (tmp_path / "sub").mkdir()
    (tmp_path / "base.toml").write_text('extends = "reference"\n[vehicle]\nmass_kg = 1500.0\n')
    (tmp_path / "sub" / "base.toml").write_text('extends = "reference"\n[vehicle]\nmass_kg = 1700.0\n')
    (tmp_path / "sub" / "child.toml").write_text('extends = "base.toml"\n')
    monkeypatch.chdir(tmp_path)
    v = load_vehicle("sub/child.toml")
    assert v.body.mass == 1700.0 and v.name == "child"


def test_bad_sim_options_are_one_line_errors(tmp_path, capsys):
    log = str(tmp_path / "x.log")
    cases = [
        (["--scenario", "nosuch", "--log", log], "nosuch"),
        (["--scenario", "straight", "--duration", "-1", "--log", log], "duration"),
        (["--scenario", "straight", "--duration", "nan", "--log", log], "duration"),
        (["--scenario", "straight", "--seed", "-5", "--log", log], "seed"),
        (["--scenario", "straight", "--t0", "1e12", "--log", log], "t0"),
        (["--scenario", "straight", "--t0", "nan", "--log", log], "t0"),
        (["--scenario", "straight", "--speed", "0", "--log", log], "speed"),
        (["--scenario", "straight", "--profile", "nosuch", "--log", log], "profile"),
        (["--scenario", "straight", "--fault", "bogus", "--log", log], "fault"),
        (["--scenario", "straight", "--duration", "0.5", "--log", str(tmp_path / "no" / "x.log")], "x.log"),
        (["--scenario", "straight", "--duration", "0.5", "--truth", str(tmp_path / "no" / "t.csv")], "t.csv"),
        (
            ["--scenario", "straight", "--duration", "0.5", "--mcap", str(tmp_path / "no" / "m.mcap")],
            "m.mcap",
        ),
        (["--scenario", "straight", "--log", log, "--log-channel", "can 0"], "--log-channel"),
        (["--scenario", "straight", "--log", log, "--truth", str(tmp_path)], "directory"),
        (["--scenario", "straight"], "nothing to do"),
        ([], "--scenario"),
    ]
    for argv, word in cases:
        rc, _, err = run_cli(capsys, "sim", *argv)
        assert_one_line_error(rc, err, word)


def test_unwritable_replay_outputs_are_one_line_errors(drive_log, tmp_path, capsys):
    for opt, name in (("--csv", "r.csv"), ("--mcap", "r.mcap")):
        rc, _, err = run_cli(capsys, "replay", "-q", str(drive_log), opt, str(tmp_path / "no" / name))
        assert_one_line_error(rc, err, name)
    bad_dbc = tmp_path / "bad.dbc"
    bad_dbc.write_text("garbage\n")
    for prof in ("nosuch", str(bad_dbc)):
        rc, _, err = run_cli(capsys, "replay", "-q", str(drive_log), "--profile", prof)
        assert_one_line_error(rc, err)


# ----------------------------------------------------------------------------- fuzzing
_HEX = "0123456789abcdefABCDEF"
_TOKENS = st.one_of(
    st.text(st.sampled_from(_HEX), max_size=20),
    st.sampled_from(
        ["#", "##", "R", " ", "(", ")", ".", "T", "_", "\r", "\t", "vcan0", "2A0", "-", "9" * 11]
    ),
)
_LINES = st.lists(_TOKENS, max_size=12).map("".join)


@FUZZ
@given(st.binary(max_size=400))
def test_candump_parser_never_raises_on_random_bytes(raw):
    p = parse_candump_bytes(raw)
    f = p.frames
    n_blank_or_frames = len(f) + p.error_frames + p.remote_frames + p.malformed_lines + p.truncated_last_line
    assert n_blank_or_frames <= p.lines + 1
    assert np.all(f.dlc <= 64) and np.all(f.can_id[~f.is_extended] <= 0x7FF)
    assert np.all(f.can_id <= 0x1FFFFFFF)


@FUZZ
@given(st.lists(_LINES, max_size=6), st.booleans())
def test_candump_parser_round_trips_what_it_accepts(lines, newline):
    p = parse_candump_bytes(("\n".join(lines) + ("\n" if newline else "")).encode())
    f = p.frames
    f = f.select(f.dlc <= 8)  # FD frames keep only their first 8 bytes
    q = parse_candump_bytes(format_candump(f).encode()).frames
    for col in ("t_ns", "can_id", "is_extended", "dlc", "data", "is_rx"):
        np.testing.assert_array_equal(getattr(q, col), getattr(f, col))


@st.composite
def _frame_batches(draw):
    name = draw(st.sampled_from(["lde", "hyundai"]))
    prof = load_profile(name)
    ids = [m.frame_id for m in prof.messages.values()] + [0x123, 0x7FF, 0]
    n = draw(st.integers(0, 50))
    steps = draw(st.lists(st.integers(-5_000_000, 40_000_000), min_size=n, max_size=n))
    t = 1_700_000_000 * SEC + np.cumsum(np.array(steps, np.int64))
    fb = FrameBatch(
        t_ns=t,
        can_id=np.array(draw(st.lists(st.sampled_from(ids), min_size=n, max_size=n)), np.uint32),
        is_extended=np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), bool) & (n % 3 == 0),
        dlc=np.array(
            draw(st.lists(st.sampled_from([0, 5, 8, 8, 8, 12, 64]), min_size=n, max_size=n)), np.uint8
        ),
        data=np.frombuffer(draw(st.binary(min_size=8 * n, max_size=8 * n)), np.uint8).reshape(n, 8),
        is_rx=np.ones(n, bool),
    )
    return prof, fb


@FUZZ
@given(case=_frame_batches())
def test_decode_batch_and_replay_never_raise_and_match_the_live_receiver(case, vehicle):
    prof, fb = case
    d = decode_batch(prof, fb)
    g = build_grid(d, prof)
    assert len(g) <= (int(fb.t_ns.max() - fb.t_ns.min()) // STEP_NS + 1 if len(fb) else 0)
    live = Receiver(prof)
    s = fb.sort()
    for i in range(len(s)):
        dlc = int(s.dlc[i])
        live.feed(
            int(s.t_ns[i]), int(s.can_id[i]), s.data[i, : min(dlc, 8)].tobytes(), dlc, bool(s.is_extended[i])
        )
    assert live.stats == d.stats
    for m in d.messages.values():
        assert m.stats.used == int(m.accepted.sum()) <= m.stats.received
    res = replay(fb, prof, vehicle, "fixed")
    assert len(res) == len(g)
    assert np.all(np.abs(res.t_overlay) <= vehicle.overlay.max_torque + 1e-9)


def test_read_log_of_a_log_with_no_data_frames_is_an_error(tmp_path):
    p = tmp_path / "only_errors.log"
    p.write_text("(1700000000.000000) vcan0 20000080#0000000000000000\n(1700000000.1) vcan0 2A0#R\n")
    with pytest.raises(LogFormatError, match="no CAN data frames"):
        read_log(p)


def test_bad_run_duration_is_a_one_line_error(capsys):
    """``lde run --duration`` must be positive and finite (checked before the bus is opened)."""
    for bad in ("-1", "0", "nan", "inf"):
        rc, _, err = run_cli(capsys, "run", "-i", "virtual", "-c", "lde-dur-test", "--duration", bad)
        assert_one_line_error(rc, err, "--duration")


def test_a_time_jump_is_reported_with_where_and_how_long(drive, tmp_path, capsys):
    """A 5 s silence in the middle of a log (a paused logger): the summary names it (issue 13 item 4)."""
    jumped = drive.take(np.arange(len(drive)))
    half = jumped.t_ns >= jumped.t_ns[len(jumped) // 2]
    jumped.t_ns = jumped.t_ns + np.where(half, 5_000_000_000, 0)
    p = tmp_path / "jump.log"
    write_candump(p, jumped)
    rc, _, err = run_cli(capsys, "replay", str(p), "--csv", str(tmp_path / "j.csv"))
    assert rc == 0, err
    t_before = int(jumped.t_ns[~half].max())
    assert "1 time jump in the received frames (silences > 1 s; longest 5.0" in err, err
    assert f"after log time {t_before / 1e9:.6f} s" in err
    plain = tmp_path / "plain.log"
    write_candump(plain, drive)
    rc, _, err = run_cli(capsys, "replay", str(plain), "--csv", str(tmp_path / "n.csv"))
    assert rc == 0 and "time jump" not in err, err
