"""Fuzz the whole data path (issue 13 item 6) with seeded random faults on a simulated drive, three ways:

* **engine** (the computation live and replay share): :class:`lde.engine.engine.Engine` fed the faulty
  frames in random pieces - the decoder, the E2E receiver, the grid, the estimator, the overlay
  limiter and the output encoder; :func:`lde.engine.receiver.decode_batch` (the batch decoder) over the
  same frames must count every frame the same way;
* **replay**: the faulty frames written to an MCAP log and replayed as ``lde replay`` does
  (:func:`lde.replay.fleet.replay_job`: the log reader, :func:`lde.replay.replay.run_replay`, the CSV sink);
* **live**: :class:`lde.service.service.Service` stepped every 3.9 ms on python-can's virtual bus (a
  simulated clock), the faulty frames sent on the bus before each step.

For every case (both profiles; the engine on every backend):

* no exception escapes, every output is finite, every step's status is a valid bit map, VALID
  exactly when no fault bit is set;
* the overlay never exceeds its magnitude limit nor its rate limit between consecutive steps. Each
  limit is swept across its boundary (panda safety-test style): the vehicle's ``max_torque`` and
  ``max_rate`` are drawn from values below, at and above what the drive demands, so that the
  output rides exactly on the limit in some cases and stays inside it in others; the bookkeeping
  test checks that both happened;
* the float filter's covariance stays symmetric positive definite (checked after every piece);
* every frame is counted exactly once: per input message received = used + rejected +
  re-synchronising, the frames of its id = received + malformed, and all frames = those + ignored
  ids (the replay summary: frames = used + rejected + re-synchronising + ignored + lde's own; live:
  the same with the frames still pending);
* cutting the frames into pieces anywhere gives the same rows (live one-step calls and replay's
  chunks are the same computation);
* once the faults stop, every step is VALID again within ``RECOVER_STEPS`` steps (the receiver's
  re-sync plus the filter's convergence time, :data:`RECOVER_S`).

The frames per CI run are counted per path and checked (``test_fuzzing_saw_enough_frames``):
``N_CASES`` engine cases and as many replays of ~``DRIVE_S`` s of traffic, ``N_LIVE`` live
cases; > 10^5 frames in all.
"""

from __future__ import annotations

import dataclasses
import math

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lde.can.frames import FrameBatch
from lde.can.profiles import load_profile
from lde.engine.engine import Engine, StepBlock
from lde.engine.receiver import decode_batch
from lde.io import McapWriter
from lde.params import Vehicle, load_vehicle
from lde.replay.fleet import ReplayJob, replay_job
from lde.status import Status
from lde.testing import Bench
from lde.units import STEP_NS, STEP_S
from vcan_sim.run import simulate

DRIVE_S = 20.0
CLEAN_TAIL_S = 4.0  # the last seconds carry no fault: the estimate must recover
N_CASES = 24  # engine cases (each also replayed from a file)
N_LIVE = 12  # live-service cases
#: after the last fault, every step is VALID again within this time: the slowest message's re-sync
#: (a few of its 10 ms frames) plus the filter's convergence time (the reference vehicle's 1 s)
RECOVER_S = 1.5
RECOVER_STEPS = math.ceil(RECOVER_S / STEP_S)
#: the overlay limits swept (the drive demands up to ~3 Nm and ~5 Nm/s; the reference limits are 3, 5)
MAX_TORQUES = (0.05, 0.5, 1.5, 3.0, 4.5, 20.0)  # Nm
MAX_RATES = (0.5, 2.0, 5.0, 50.0)  # Nm/s
#: what the fuzzing saw, per path; checked by test_fuzzing_saw_enough_frames
SEEN: dict[str, int] = {
    "engine": 0,
    "replay": 0,
    "live": 0,
    "torque_limit_hit": 0,
    "torque_limit_inside": 0,
    "rate_limit_hit": 0,
    "rate_limit_inside": 0,
    "recover_steps_max": 0,
}


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle("reference")


_DRIVES: dict[str, FrameBatch] = {}


def _drive(pname: str) -> FrameBatch:
    if pname not in _DRIVES:
        sim = simulate("gusty_wind", "reference", pname, seed=3, duration=DRIVE_S)
        _DRIVES[pname] = sim.frames.sort()
    return _DRIVES[pname]


@st.composite
def faults(draw: st.DrawFn) -> dict:
    return {
        "pname": draw(st.sampled_from(["lde", "hyundai"])),
        "backend": draw(st.sampled_from(["float", "fixed", "paper"])),
        "seed": draw(st.integers(0, 2**31 - 1)),
        "p_drop": draw(st.floats(0.0, 0.3)),
        "p_corrupt": draw(st.floats(0.0, 0.2)),
        "p_dup": draw(st.floats(0.0, 0.1)),
        "p_garbage": draw(st.floats(0.0, 0.2)),  # random payload (invalid CRC on lde; may pass on hyundai)
        "p_dlc": draw(st.floats(0.0, 0.05)),
        "n_foreign": draw(st.integers(0, 3000)),
        "jitter_us": draw(st.integers(0, 5000)),
        "gap_s": draw(st.sampled_from([0.0, 0.05, 0.5, 2.0])),
        "cuts": draw(st.lists(st.integers(0, 10**6), min_size=0, max_size=6)),
        "max_torque": draw(st.sampled_from(MAX_TORQUES)),
        "max_rate": draw(st.sampled_from(MAX_RATES)),
    }


def _limited(vehicle: Vehicle, f: dict) -> Vehicle:
    """``vehicle`` with the case's overlay limits."""
    o = dataclasses.replace(vehicle.overlay, max_torque=f["max_torque"], max_rate=f["max_rate"])
    return dataclasses.replace(vehicle, overlay=o)


def _apply(fb: FrameBatch, f: dict) -> FrameBatch:
    """The drive with the faults applied before ``DRIVE_S - CLEAN_TAIL_S`` (time-sorted again)."""
    rng = np.random.default_rng(f["seed"])
    n = len(fb)
    t0 = int(fb.t_ns[0])
    faulty = fb.t_ns < t0 + int((DRIVE_S - CLEAN_TAIL_S) * 1e9)
    keep = ~(faulty & (rng.random(n) < f["p_drop"]))
    if f["gap_s"] > 0:  # a silence of every input in the middle of the faulty part
        g0 = t0 + int(2e9)
        keep &= ~((fb.t_ns >= g0) & (fb.t_ns < g0 + int(f["gap_s"] * 1e9)))
    out = fb.take(np.flatnonzero(keep))
    m = len(out)
    faulty = out.t_ns < t0 + int((DRIVE_S - CLEAN_TAIL_S) * 1e9)
    data = out.data.copy()
    bad = faulty & (rng.random(m) < f["p_corrupt"])
    data[bad, rng.integers(0, 8, m)[bad]] ^= rng.integers(1, 256, m, dtype=np.uint8)[bad]
    garbage = faulty & (rng.random(m) < f["p_garbage"])
    data[garbage] = rng.integers(0, 256, (int(garbage.sum()), 8), dtype=np.uint8)
    dlc = out.dlc.copy()
    wrong = faulty & (rng.random(m) < f["p_dlc"])
    dlc[wrong] = rng.choice(np.array([0, 3, 7, 12, 64], np.uint8), int(wrong.sum()))
    t = out.t_ns.copy()
    if f["jitter_us"]:
        t[faulty] += rng.integers(-f["jitter_us"], f["jitter_us"] + 1, int(faulty.sum())) * 1000
    parts = [FrameBatch(t, out.can_id, out.is_extended, dlc, data, out.is_rx)]
    dup = faulty & (rng.random(m) < f["p_dup"])
    if dup.any():
        parts.append(
            FrameBatch(t[dup], out.can_id[dup], out.is_extended[dup], dlc[dup], data[dup], out.is_rx[dup])
        )
    k = f["n_foreign"]
    if k:  # other ECUs' frames all the time (ids of the profile's inputs only as 29-bit ones)
        ids = rng.integers(0, 0x800, k).astype(np.uint32)
        ids[np.isin(ids, np.unique(fb.can_id))] += 0x800  # an input id's number: a 29-bit id
        parts.append(
            FrameBatch(
                t0 + rng.integers(0, int(DRIVE_S * 1e9), k),
                ids,
                (rng.random(k) < 0.2) | (ids >= 0x800),
                rng.integers(0, 9, k).astype(np.uint8),
                rng.integers(0, 256, (k, 8), dtype=np.uint8),
                np.ones(k, np.bool_),
            )
        )
    return FrameBatch.concat(parts).sort()


def _run(profile, vehicle, backend: str, frames: FrameBatch, cuts: list[int]) -> tuple[StepBlock, Engine]:
    """The engine over ``frames`` cut at ``cuts``; the float filters' covariance checked after each piece."""
    e = Engine(profile, vehicle, backend)
    edges = sorted({0, len(frames), *(c % (len(frames) + 1) for c in cuts)})
    blocks = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        blocks.append(e.feed(frames.take(np.arange(a, b))))
        _check_covariance(e, backend)
    blocks.append(e.finish())
    _check_covariance(e, backend)
    return StepBlock.concat(blocks), e


def _check_covariance(e: Engine, backend: str) -> None:
    """The float filters' covariance: symmetric positive definite (the fixed-point ones are
    checked against their float shadow within 5 N / 2 Nm at every step, SHADOW_DEVIATION)."""
    if backend not in ("float", "paper"):
        return
    P = e.est.state.filter.P if backend == "float" else e.est.state.P
    np.testing.assert_allclose(P, P.T, rtol=0, atol=1e-9 * np.abs(P).max())
    assert np.all(np.linalg.eigvalsh(P) > 0)


def _check_rows(
    t_ns: np.ndarray,
    status: np.ndarray,
    outputs: list[np.ndarray],
    t_overlay: np.ndarray,
    vehicle: Vehicle,
    t_clean: int,
    count_limits: bool = False,
    tol: float = 0.0,
) -> None:
    """Finite outputs, valid status words, the overlay within its limits, recovery after the faults.
    ``tol`` [Nm]: the rounding of rows read back from a CSV (4 decimals), else 0."""
    for col in outputs:
        assert np.all(np.isfinite(col))
    assert np.all(np.isfinite(t_overlay))
    assert np.all(status <= 0xFF)
    valid = (status & Status.VALID) != 0
    fault_bits = Status.MDPS_FAULT | Status.ESC_FAULT | Status.LOW_SPEED | Status.NOT_CONVERGED
    np.testing.assert_array_equal(valid, (status & fault_bits) == 0)  # VALID exactly when no fault bit
    # overlay limits: magnitude and rate (dt from the step times, clamped as the limiter does); the
    # tolerance is the last bits of a double, not a margin
    lim = vehicle.overlay
    peak = float(np.max(np.abs(t_overlay))) if len(t_overlay) else 0.0
    assert peak <= lim.max_torque + tol, (peak, lim.max_torque)
    dt = np.minimum(np.diff(t_ns) * 1e-9, 0.05)
    allowed = lim.max_rate * dt
    slope = np.abs(np.diff(t_overlay))
    ok = slope <= allowed * (1 + 1e-12) + 1e-15 + 2 * tol
    assert np.all(ok), float(np.max(slope / np.maximum(allowed, 1e-300)))
    if count_limits:  # the boundary: the output rode exactly on the limit, or stayed inside it
        SEEN["torque_limit_hit" if peak == lim.max_torque else "torque_limit_inside"] += 1
        # rate: steps on the limit (ramps, a demand moving faster) and steps that followed the
        # demand inside it (a slope above zero, below half the limit)
        SEEN["rate_limit_hit"] += int(np.any(slope >= allowed * (1 - 1e-9)))
        SEEN["rate_limit_inside"] += int(np.any((slope > 0) & (slope < 0.5 * allowed)))
    # recovery: VALID at every step from RECOVER_STEPS after the last fault on
    after = np.flatnonzero(t_ns >= t_clean)
    assert len(after) > RECOVER_STEPS + 100
    invalid = np.flatnonzero(~valid[after])
    took = int(invalid[-1]) + 1 if len(invalid) else 0
    SEEN["recover_steps_max"] = max(SEEN["recover_steps_max"], took)
    assert took <= RECOVER_STEPS, f"VALID again only {took} steps after the faults stopped"


def _check_counts(stats: dict, ignored: int, frames: FrameBatch, profile, pending: int = 0) -> None:
    """Every frame counted exactly once (module doc); ``pending``: frames taken from the bus and not
    yet fed to a step (live)."""
    total = 0
    for name, s in stats.items():
        assert s.received == s.used + s.rejected + s.resync, (name, s)
        mine = (frames.can_id == profile.messages[name].frame_id) & ~frames.is_extended
        n = int(np.count_nonzero(mine))
        assert n - pending <= s.received + s.malformed <= n, (name, n, s)
        total += s.received + s.malformed
    assert total + ignored + pending == len(frames), (total, ignored, pending, len(frames))


@settings(
    max_examples=N_CASES,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(f=faults())
def test_the_pipeline_survives_faults_and_keeps_its_promises(f, vehicle, tmp_path_factory):
    profile = load_profile(f["pname"])
    frames = _apply(_drive(f["pname"]), f)
    veh = _limited(vehicle, f)
    b, e = _run(profile, veh, f["backend"], frames, f["cuts"])
    SEEN["engine"] += len(frames)
    assert len(b) > 1000
    t_clean = int(frames.t_ns[0]) + int((DRIVE_S - CLEAN_TAIL_S) * 1e9)
    _check_rows(
        b.t_ns,
        b.status,
        [b.fw, b.mw, b.t_align, b.beta, b.yaw_rate],
        b.t_overlay,
        veh,
        t_clean,
        count_limits=True,
    )
    # every frame counted once, per message exactly as the batch decoder counts it
    _check_counts(e.stats(), e.n_ignored, frames, profile)
    assert decode_batch(profile, frames).stats == e.stats()
    # the same rows in one piece: cutting the frames anywhere changes nothing
    whole, _ = _run(profile, veh, f["backend"], frames, [])
    for col in ("t_ns", "status", "est", "t_overlay", "overlay_state", "frames"):
        np.testing.assert_array_equal(getattr(b, col), getattr(whole, col), err_msg=col)
    # the same frames from a file, as lde replay reads it (reference limits: a vehicle by name)
    path = tmp_path_factory.mktemp("fuzz") / "faulty.mcap"
    with McapWriter(path) as w:
        w.write_frames(frames)
    csv = path.with_suffix(".csv")
    rep = replay_job(ReplayJob(path, csv=csv, profile=f["pname"], backend=f["backend"]))
    assert rep.ok, rep.error
    SEEN["replay"] += rep.frames
    assert rep.frames == len(frames)
    assert rep.frames == rep.used + rep.rejected + rep.resync + rep.ignored + rep.tx
    rows = np.genfromtxt(csv, delimiter=",", names=True)
    t_rows = np.round(rows["t"] * 1e9).astype(np.int64)
    assert len(rows) == rep.steps
    status = rows["status"].astype(np.int64)
    outs = [rows["Fw"], rows["Mw"], rows["T_align"]]
    _check_rows(t_rows, status, outs, rows["T_overlay"], vehicle, t_clean, tol=0.5e-4)


@st.composite
def live_faults(draw: st.DrawFn) -> dict:
    f = draw(faults())
    f["cuts"] = []
    f["backend"] = draw(st.sampled_from(["fixed", "float"]))
    return f


@settings(
    max_examples=N_LIVE,
    deadline=None,
    derandomize=True,
    database=None,
    suppress_health_check=[HealthCheck.too_slow],
)
@given(f=live_faults())
def test_the_live_step_survives_faults_and_keeps_its_promises(f, vehicle):
    """The service's step (``lde run``'s loop body) on a virtual bus, the faulty frames sent before
    each step."""
    profile = load_profile(f["pname"])
    frames = _apply(_drive(f["pname"]), f)
    veh = _limited(vehicle, f)
    t0 = int(frames.t_ns[0])
    bench = Bench(profile=profile, capture=False, start_ns=t0, label="fuzz-live")
    try:
        bus = bench.bus("feeder", preserve_timestamps=True)
        svc = bench.service(backend=f["backend"], vehicle=veh).service
        msgs = []
        for i in range(len(frames)):
            dlc = int(frames.dlc[i])
            data = bytes(frames.data[i, : min(dlc, 8)]).ljust(dlc, b"\0")
            msgs.append(
                can.Message(
                    timestamp=int(frames.t_ns[i]) / 1e9,
                    arbitration_id=int(frames.can_id[i]),
                    is_extended_id=bool(frames.is_extended[i]),
                    is_fd=dlc > 8,
                    data=data,
                )
            )
        t_ns, status, fw, mw, tov = [], [], [], [], []
        j = 0
        n_steps = int((int(frames.t_ns[-1]) - t0) // STEP_NS)
        for k in range(1, n_steps + 1):
            t_k = t0 + k * STEP_NS
            while j < len(frames) and frames.t_ns[j] <= t_k:
                bus.send(msgs[j])
                j += 1
            bench.clock.sleep_until(t_k)
            r = svc.step_once(t_k)
            t_ns.append(r.t_ns)
            status.append(r.status)
            fw.append(r.fw)
            mw.append(r.mw)
            tov.append(r.t_overlay)
        SEEN["live"] += j
        svc._drain()  # frames on the bus not yet taken by a step: pending, not lost
        pending = len(svc.pending_times())
        # the service drops frames of other ids before its engine (``foreign``), the engine ignores
        # 29-bit ones with an input's number
        ignored = svc.engine.n_ignored + svc.foreign
        _check_counts(svc.engine.stats(), ignored, frames.take(np.arange(j)), profile, pending)
    finally:
        bench.close()
    t_clean = t0 + int((DRIVE_S - CLEAN_TAIL_S) * 1e9)
    _check_rows(
        np.array(t_ns),
        np.array(status),
        [np.array(fw), np.array(mw)],
        np.array(tov),
        veh,
        t_clean,
        count_limits=True,
    )


def test_fuzzing_saw_enough_frames():
    """> 10^5 fuzzed frames per run across the paths, each overlay limit met at its boundary and
    stayed inside it in some cases (runs after the fuzz tests in file order)."""
    if SEEN["engine"] == 0 or SEEN["live"] == 0:
        pytest.skip("the fuzz tests did not run in this session (selected alone)")
    print(f"fuzz bookkeeping: {SEEN}")
    assert SEEN["engine"] + SEEN["replay"] + SEEN["live"] > 100_000, SEEN
    assert min(SEEN["engine"], SEEN["replay"]) > 100_000 and SEEN["live"] > 60_000, SEEN
    for limit in ("torque", "rate"):
        assert SEEN[f"{limit}_limit_hit"] >= 3 and SEEN[f"{limit}_limit_inside"] >= 3, SEEN
    assert SEEN["recover_steps_max"] <= RECOVER_STEPS


def test_step_period_constant_matches():
    assert pytest.approx(STEP_S) == STEP_NS * 1e-9
