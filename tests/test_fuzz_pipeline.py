"""Fuzz the whole data path (issue 13 item 6): the decoder, the E2E receiver, the grid, the estimator,
the overlay limiter and the output encoder, through :class:`lde.engine.Engine` (live and replay run
the same loop), with seeded random faults on a simulated drive.

For every case, on every backend (fixed, float, paper-fixed, paper) and both profiles:

* no exception escapes, every output is finite, every step's status is a valid bit map;
* the overlay never exceeds its magnitude limit nor its rate limit between consecutive steps;
* the float filter's covariance stays symmetric positive definite;
* per input message, received = used + rejected + re-synchronising frames (every frame counted once);
* cutting the frames into chunks anywhere gives the same rows (the live loop's one-step calls and
  replay's chunks are the same computation);
* once the faults stop, the estimate is VALID again within the receiver's re-sync plus the filter's
  convergence time.

The frames per CI run: ``N_CASES`` cases of ~``DRIVE_S`` s of traffic (MDPS every 3.9 ms, ESC every
10 ms on profile lde; more messages on hyundai), > 10^5 frames in all (checked below).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lde.engine import Engine, StepBlock
from lde.frames import FrameBatch
from lde.params import load_vehicle
from lde.profiles import load_profile
from lde.status import Status
from lde.units import STEP_NS, STEP_S
from vcan_sim.run import simulate

DRIVE_S = 20.0
CLEAN_TAIL_S = 4.0  # the last seconds carry no fault: the estimate must recover
N_CASES = 24
_SEEN = {"frames": 0}


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
        "backend": draw(st.sampled_from(["float", "fixed", "paper", "paper-fixed"])),
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
    }


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
    e = Engine(profile, vehicle, backend)
    edges = sorted({0, len(frames), *(c % (len(frames) + 1) for c in cuts)})
    blocks = [e.feed(frames.take(np.arange(a, b))) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    blocks.append(e.finish())
    return StepBlock.concat(blocks), e


@settings(max_examples=N_CASES, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(f=faults())
def test_the_pipeline_survives_faults_and_keeps_its_promises(f, vehicle):
    profile = load_profile(f["pname"])
    frames = _apply(_drive(f["pname"]), f)
    _SEEN["frames"] += len(frames)
    b, e = _run(profile, vehicle, f["backend"], frames, f["cuts"])
    assert len(b) > 1000
    # finite outputs, valid status words
    for col in (b.fw, b.mw, b.t_align, b.t_overlay):
        assert np.all(np.isfinite(col))
    assert np.all(b.status <= 0xFF)
    valid = (b.status & Status.VALID) != 0
    faults = (
        b.status & (Status.MDPS_FAULT | Status.ESC_FAULT | Status.LOW_SPEED | Status.NOT_CONVERGED)
    ) != 0
    np.testing.assert_array_equal(valid, ~faults)  # VALID exactly when no fault bit
    # overlay limits: magnitude and rate (dt from the step times, clamped as the limiter does)
    lim = vehicle.overlay
    assert np.all(np.abs(b.t_overlay) <= lim.max_torque)
    dt = np.minimum(np.diff(b.t_ns) * 1e-9, 0.05)
    assert np.all(np.abs(np.diff(b.t_overlay)) <= lim.max_rate * dt + 1e-12)
    # every received frame counted once
    for name, s in e.stats().items():
        assert s.received == s.used + s.rejected + s.resync, (name, s)
    # the float filter's covariance: symmetric positive definite
    if f["backend"] in ("float", "paper"):
        P = e.est.state[2] if f["backend"] == "float" else e.est.state[1]  # lateral: (p, x, P, ...)
        np.testing.assert_allclose(P, P.T, rtol=0, atol=1e-9 * np.abs(P).max())
        assert np.all(np.linalg.eigvalsh(P) > 0)
    # recovery: VALID again once the faults have stopped (re-sync: a few frames of the slowest
    # message; then the filter's convergence time)
    t_clean = int(frames.t_ns[0]) + int((DRIVE_S - CLEAN_TAIL_S) * 1e9)
    recover_s = vehicle.estimator.converge_time + 0.5
    late = b.t_ns >= t_clean + int(recover_s * 1e9)
    assert late.any() and np.all(valid[late]), "not VALID after the faults stopped"
    # the same rows in one piece: cutting the frames anywhere changes nothing
    whole, _ = _run(profile, vehicle, f["backend"], frames, [])
    for col in ("t_ns", "status", "est", "t_overlay", "overlay_state", "frames"):
        np.testing.assert_array_equal(getattr(b, col), getattr(whole, col), err_msg=col)


def test_fuzzing_saw_enough_frames():
    """More than 10^5 fuzzed frames per run (issue 13); runs after the fuzz test in file order."""
    if _SEEN["frames"] == 0:
        pytest.skip("the fuzz test did not run in this session (selected alone)")
    assert _SEEN["frames"] > 100_000, _SEEN["frames"]


def test_step_period_constant_matches():
    assert pytest.approx(STEP_S) == STEP_NS * 1e-9
