"""Live bus faults on a real SocketCAN vcan0 (issue 13 item 1): ``lde run`` faces, one after the
other in one run, an input message that stops, the interface going down and up, error frames, a
flood of foreign frames and a sender that restarts its counter.

Marked ``vcan``: runs inside user-mode Linux (tests/test_uml.py). The inputs come from a light sender
(tests/uml/fault_sender.py: frames encoded beforehand by lde's codec, one ``send`` per frame at
SCHED_FIFO 90) rather than ``lde sim``: on UML's one emulated CPU the simulator's step takes 1-2 ms
of every 3.9 ms beside the service's 1-2 ms, and the closed-loop test skips its judgement there for
the service's pace (docs/guide/bus.md, "User-mode Linux"); the sender's CPU is printed. The inputs are steady
(100 km/h, the driver holding 0.8 Nm against a disturbance), so the overlay is engaged before every
fault.

Checked for each fault, on the service's recording (step times, ``T_overlay``, overlay state,
``/lde/diag``), on the bus (candump at SCHED_FIFO 99, filtered to the profile's ids) and on the
service's log:

* every overlay request within the torque and rate limits, step by step; the ``LDE_Overlay`` frames
  on the bus exactly those the recording says were sent;
* where the fault takes an input away (the message stops, the interface is down), the overlay ramps
  to zero at its rate limit (monotonic, within ``|T| / max_rate`` plus the input's timeout);
* the service resumes by itself: outputs on the bus right after the interface is up again, the
  overlay engaged again before the next fault;
* its log has a line when the fault starts and one when it clears;
* the loop keeps stepping: steps and deadline misses per fault window (from ``/lde/diag``) are
  printed; the pace is judged (>= 90 % of the grid points in every window) only when the guest kept it
  without faults, else that judgement skips with the figures.
"""

from __future__ import annotations

import json
import re
import shutil
import struct
import subprocess
import sys
import time
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import can
import numpy as np
import pytest
from uml_bounds import Budget, run_bounded, stop_process

from lde.can.e2e import p01_check
from lde.can.profiles import load_profile
from lde.estimator.overlay import OverlayTiming
from lde.io.recording import read_recording
from lde.params import load_vehicle
from lde.testing import InputFeeder
from lde.units import DEG, KMH, STEP_NS

pytestmark = [pytest.mark.vcan, pytest.mark.slow]

CHANNEL = "vcan0"
LDE = [sys.executable, "-m", "lde"]
SENDER = Path(__file__).with_name("fault_sender.py")
REC = struct.Struct("<qBIB8s")
K_FRAME, K_DOWN, K_UP, K_FLOOD, K_FLOOD_END, K_MARK = range(6)
CAN_ERR_FLAG = 0x20000000
#: the error frame sent: protocol violation and bus error (linux/can/error.h classes)
ERROR_ID = CAN_ERR_FLAG | 0x08 | 0x80
S = 10**9


@dataclass(frozen=True)
class Fault:
    """One fault of the schedule: from ``start_s`` to ``end_s`` after the sender's start."""

    name: str
    start_s: float
    end_s: float
    takes_inputs: bool  # the inputs stop (the overlay must ramp out)
    start_log: str  # a regular expression the service's log must match at the start ...
    clear_log: str  # ... and at the clear


FAULTS = (
    Fault(
        "input stops",
        8.0,
        9.5,
        True,
        r"no input: MDPS_Sensors \(0x2A0\) none for",
        r"MDPS_Sensors .* arrives again",
    ),
    Fault(
        "link down", 14.0, 15.5, True, r"CAN send failing: .*Network is down", r"CAN send failing: cleared"
    ),
    Fault("error frames", 20.0, 21.5, False, r"error frames on .*: \d+ in", r"error frames on .*: cleared"),
    Fault(
        "flood",
        26.0,
        29.0,
        False,
        r"foreign frames flood .*: \d+ foreign frames/s",
        r"foreign frames flood .*cleared",
    ),
    Fault(
        "counter restart",
        34.0,
        34.1,
        True,  # the receiver re-synchronises: the MDPS input is untrusted for a few steps
        r"E2E MDPS_Sensors \(0x2A0\): \d+ frames rejected \(wrong sequence",
        r"E2E MDPS_Sensors \(0x2A0\): cleared",
    ),
)
DURATION_S = 40.0
ERROR_EVERY_NS = 4_000_000  # an error frame every 4 ms during the error-frame fault

#: bounds [s] (each also capped by what is left of the guest's budget)
SERVICE_START_S = 180.0
SENDER_S = DURATION_S * 4 + 30
SERVICE_STOP_S = 120.0
#: the overlay must be engaged again this soon after a fault clears (before the next one starts)
RESUME_S = 4.4
#: ``lde run --flood-rate``: this bus carries no other traffic; the guest's flood reaches ~400-3000
#: foreign frames/s (measured), below the default 2000/s meant for car buses shared with other ECUs
FLOOD_RATE_HZ = 300.0
#: input gaps (kernel times of MDPS frames further apart than the timeout) this close before a
#: judgement window make the overlay legitimately disengaged there (the estimator reconverges)
GAP_REACH_S = 3.0


class _Collect:
    """A stand-in bus for the feeder: keeps the encoded frames."""

    def __init__(self) -> None:
        self.frames: list[tuple[int, int, bytes]] = []

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.frames.append((round(msg.timestamp * 1e9), msg.arbitration_id, bytes(msg.data)))


def _schedule(path: Path) -> list[str]:
    """Write the sender's schedule; returns the names of its action and mark records, in order."""
    profile = load_profile("lde")
    f = {x.name: x for x in FAULTS}
    stop = f["input stops"]

    def silent(message: str, t: int) -> bool:
        return message == "MDPS_Sensors" and stop.start_s * S <= t < stop.end_s * S

    bus = _Collect()
    feeder = InputFeeder(
        bus,  # type: ignore[arg-type]
        profile,
        {"MDPS_Sensors": 0, "ESC_Motion": 1_000_000},
        silent=silent,
        speed=100 * KMH,
        column_torque=0.8,
        assist_torque=1.2,
        steering_angle=0.5 * DEG,
    )
    restart = f["counter restart"]
    feeder.send_until(int(restart.start_s * S))
    enc = feeder.encoders["MDPS_Sensors"]
    # a jump the receiver cannot take for a loss: the next counter is not 0 (repeated) nor 14 (delta 1)
    while enc.counter in (14, 0):
        feeder.send_until(feeder.next_ns["MDPS_Sensors"])
    restart_ns = feeder.next_ns["MDPS_Sensors"]
    enc.counter = 0
    feeder.send_until(int(DURATION_S * S))
    recs: list[tuple[int, int, int, int, bytes]] = [
        (t, K_FRAME, cid, len(d), d.ljust(8, b"\0")) for t, cid, d in bus.frames
    ]
    marks: list[tuple[int, int, str]] = [
        (int(stop.start_s * S), K_MARK, "input stops start"),
        (int(stop.end_s * S), K_MARK, "input stops end"),
        (int(f["link down"].start_s * S), K_DOWN, "link down start"),
        (int(f["link down"].end_s * S), K_UP, "link down end"),
        (int(f["error frames"].start_s * S), K_MARK, "error frames start"),
        (int(f["error frames"].end_s * S), K_MARK, "error frames end"),
        (int(f["flood"].start_s * S), K_FLOOD, "flood start"),
        (int(f["flood"].end_s * S), K_FLOOD_END, "flood end"),
        (restart_ns - 1, K_MARK, "counter restart start"),
        (restart_ns + int(0.1 * S), K_MARK, "counter restart end"),
    ]
    err = f["error frames"]
    for t in range(int(err.start_s * S), int(err.end_s * S), ERROR_EVERY_NS):
        recs.append((t, K_FRAME, ERROR_ID, 8, bytes(8)))
    recs += [(t, k, 0, 0, bytes(8)) for t, k, _ in marks]
    order = sorted(range(len(recs)), key=lambda i: (recs[i][0], recs[i][1] == K_FRAME))
    with path.open("wb") as fh:
        for i in order:
            fh.write(REC.pack(*recs[i]))
    names = {(t, k): n for t, k, n in marks}
    return [names[(recs[i][0], recs[i][1])] for i in order if recs[i][1] != K_FRAME]


@dataclass
class Run:
    tmp: Path
    dump: Path
    rec_path: Path
    service_rc: int | None
    service_out: str
    sender: dict
    times: dict[str, float]  # epoch seconds of each fault's start and end (the sender's)
    speed: str
    problems: list[str] = field(default_factory=list)

    def skip_if_incomplete(self, what: str) -> None:
        if self.problems:
            pytest.skip(f"{what}: {'; '.join(self.problems)}{self.speed}")


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory, budget: Budget, guest_speed: str) -> Run:
    """candump, ``lde run --grid fixed --realtime --record``, then the sender with its faults; SIGTERM."""
    for tool in ("candump", "cangen", "chrt", "ip"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} not installed (can-utils, util-linux, iproute2)")
    budget.require(90.0 + DURATION_S, "live bus faults on vcan0", guest_speed)
    tmp = tmp_path_factory.mktemp("faults")
    sched = tmp / "schedule.bin"
    names = _schedule(sched)
    dump, rec_path, service_log = tmp / "dump.log", tmp / "service.mcap", tmp / "service.out"
    problems: list[str] = []
    ids = ",".join(f"{i:X}:7FF" for i in (0x2A0, 0x2A8, 0x3D0, 0x3D1, 0x3D2, 0x3D3))
    sender: dict = {}
    with dump.open("w") as fh, service_log.open("w") as service_fh:
        # the observer sees only the profile's ids (a flood must not starve it), survives the link down
        candump = subprocess.Popen(
            ["chrt", "-f", "99", "candump", "-D", "-L", "-r", str(16 << 20), f"{CHANNEL},{ids}"], stdout=fh
        )
        service = subprocess.Popen(
            [
                *LDE,
                "run",
                "-i",
                "socketcan",
                "-c",
                CHANNEL,
                "--backend",
                "fixed",
                # the fixed grid: the bookkeeping below (every 3.9 ms lattice point run or counted) needs
                # a lattice; the default MDPS-locked grid moves with the frames a fault stops (its skip
                # rule is checked on the host, tests/service/test_service.py, and in the closed-loop UML test)
                "--grid",
                "fixed",
                "--realtime",
                "--spin-us",
                "0",
            ]
            + ["--record", str(rec_path), "--log-period", "5", "--flood-rate", str(FLOOD_RATE_HZ)],
            stdout=service_fh,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
        )
        try:
            t0 = time.monotonic()
            limit = budget.bound(SERVICE_START_S)
            while time.monotonic() - t0 < limit and service.poll() is None:
                if rec_path.exists() and rec_path.stat().st_size > 4096:
                    break
                time.sleep(0.5)
            if service.poll() is None and rec_path.exists() and rec_path.stat().st_size > 4096:
                bound = budget.bound(SENDER_S)
                cmd = [
                    sys.executable,
                    str(SENDER),
                    str(sched),
                    CHANNEL,
                    str(tmp / "sender.json"),
                    "--rt-priority",
                    "90",
                ]
                rc, wall, out = run_bounded(cmd, tmp / "sender.out", bound)
                print(f"sender: exit {rc} in {wall:.0f} s: {out[-1500:]}")
                if rc is None:
                    problems.append(f"the sender did not finish its {DURATION_S:.0f} s in {bound:.0f} s")
                else:
                    assert rc == 0, out
                    sender = json.loads((tmp / "sender.json").read_text())
                time.sleep(1.0)
            elif service.poll() is None:
                problems.append(f"lde run was not stepping {limit:.0f} s after its start")
        finally:
            stop = stop_process(service, budget.bound(SERVICE_STOP_S, reserve_s=10.0))
            stop_process(candump, 30.0)
            subprocess.run(["ip", "link", "set", CHANNEL, "up"], check=False)  # whatever happened
    if stop:
        problems.append(f"lde run {stop}")
    out = service_log.read_text(errors="replace")
    print(out[-6000:])
    times = {}
    for (_, t), name in zip(sender.get("events", []), names, strict=False):
        times[name] = float(t)
    return Run(tmp, dump, rec_path, service.returncode, out, sender, times, guest_speed, problems)


def _bus(run: Run) -> dict[int, list[tuple[float, bytes]]]:
    frames: dict[int, list[tuple[float, bytes]]] = defaultdict(list)
    for m in can.CanutilsLogReader(str(run.dump)):
        frames[m.arbitration_id].append((m.timestamp, bytes(m.data)))
    return frames


def _rec(run: Run):
    if not run.rec_path.exists():
        pytest.skip(f"lde run wrote no recording: {'; '.join(run.problems) or run.service_out[-300:]}")
    rec = read_recording(run.rec_path)
    if not run.times:
        pytest.skip(f"the sender did not run: {'; '.join(run.problems)}{run.speed}")
    return rec


def test_service_runs_through_all_faults_and_ends_cleanly(run: Run) -> None:
    run.skip_if_incomplete("the processes could not end on their own")
    assert run.service_rc == 0, run.service_out[-3000:]  # no traceback, SIGTERM -> exit 0
    assert "Traceback" not in run.service_out
    assert read_recording(run.rec_path).complete
    s = run.sender
    assert s["failed"] > 0, "the sender's frames should fail while the interface is down"
    assert s["error_frames"] == int(1.5 * S / ERROR_EVERY_NS)


def test_overlay_within_limits_and_the_bus_carries_what_was_recorded(run: Run) -> None:
    rec = _rec(run)
    lim = load_vehicle("reference").overlay
    t = rec.step_times_ns.astype(np.int64)
    tq = np.asarray(rec.estimate["T_overlay"], dtype=np.float64)
    assert np.max(np.abs(tq)) <= lim.max_torque
    dt = np.minimum(np.diff(t) * 1e-9, OverlayTiming().dt_max)
    excess = np.abs(np.diff(tq)) - lim.max_rate * dt
    assert np.max(excess, initial=0.0) <= 1e-9, f"rate limit exceeded by {np.max(excess):.3g} Nm"
    # the LDE_Overlay frames on the bus are exactly the ones the recording says went out, valid E2E
    fid = load_profile("lde").output_id("LDE_Overlay")
    on_bus = [d for _, d in _bus(run)[fid]]
    sel = rec.tx.can_id == fid
    sent = [bytes(d[:n]) for d, n in zip(rec.tx.data[sel], rec.tx.dlc[sel], strict=True)]
    assert all(p01_check(fid, d) for d in on_bus)
    assert on_bus == sent[: len(on_bus)] and len(sent) - len(on_bus) <= 2  # the last ones: SIGTERM


def _window(run: Run, fault: Fault) -> tuple[int, int]:
    """The fault's start and end [ns, epoch: the bus time base], as the sender did them."""
    return int(run.times[f"{fault.name} start"] * S), int(run.times[f"{fault.name} end"] * S)


def _input_gaps(run: Run) -> list[tuple[int, int]]:
    """MDPS_Sensors gaps on the bus longer than its timeout that no scheduled fault explains
    (the guest stalled): (start, end) [ns]."""
    spec = load_profile("lde").messages["MDPS_Sensors"]
    ts = np.array([t for t, _ in _bus(run)[spec.frame_id]])
    idx = np.nonzero(np.diff(ts) > spec.timeout_ns * 1e-9)[0]
    out = []
    for i in idx:
        a, b = int(ts[i] * S), int(ts[i + 1] * S)
        if not any(fa - S // 2 <= b and a <= fb + S // 2 for fa, fb in (_window(run, f) for f in FAULTS)):
            out.append((a, b))
    return out


def _disturbed(gaps: list[tuple[int, int]], a: int, b: int) -> int:
    """Stall gaps that end within GAP_REACH_S before or inside [a, b]."""
    return sum(1 for ga, gb in gaps if a - int(GAP_REACH_S * S) <= gb and ga <= b)


def _stale_episodes(rec, run: Run, a: int, b: int, keep: Fault | None = None) -> int:
    """Episodes of steps in [a - GAP_REACH_S, b] with an input not ok (stale or re-synchronising) that
    no scheduled fault explains: the guest held a frame up (a gap on the bus, or a frame that reached
    the service's socket after its step). Each one restarts the estimator's convergence."""
    t = rec.step_times_ns.astype(np.int64)
    bad = ~(np.asarray(rec.inputs["mdps_ok"]).astype(bool) & np.asarray(rec.inputs["esc_ok"]).astype(bool))
    sel = (t >= a - int(GAP_REACH_S * S)) & (t <= b)
    for fa, fb in (_window(run, f) for f in FAULTS if f is not keep):
        sel &= ~((t >= fa) & (t < fb + S // 5))  # the fault itself and the re-sync after it
    starts = np.nonzero(bad & sel & ~np.r_[False, bad[:-1]])[0]
    return int(starts.size)


def test_every_ramp_out_runs_at_the_rate_limit_to_zero(run: Run) -> None:
    """Every disengagement in the recording (the scheduled faults and the guest's stalls alike):
    while the limiter ramps out (RAMP_OUT, FAULT, or OFF with a torque left), each step moves the
    request toward zero by exactly ``max_rate * min(dt, dt_max)`` (or to zero), never away."""
    rec = _rec(run)
    lim = load_vehicle("reference").overlay
    t = rec.step_times_ns.astype(np.int64)
    tq = np.asarray(rec.estimate["T_overlay"], dtype=np.float64)
    state = np.asarray(rec.estimate["overlay_state"]).astype(int)
    dt = np.minimum(np.diff(t) * 1e-9, OverlayTiming().dt_max)
    bad, episodes, steps = [], 0, 0
    for i in range(1, len(t)):
        if state[i] in (3, 4) or (state[i] == 0 and tq[i - 1] != 0.0):
            if tq[i - 1] == 0.0:
                continue
            episodes += state[i - 1] in (1, 2)
            steps += 1
            want = max(0.0, abs(tq[i - 1]) - lim.max_rate * dt[i - 1])
            if abs(abs(tq[i]) - want) > 1e-9 or tq[i] * tq[i - 1] < 0:
                bad.append((i, tq[i - 1], tq[i], want))
    print(f"ramp-outs in the recording: {episodes} disengagements, {steps} ramp steps, all at the rate limit")
    assert episodes >= 2, "the scheduled faults should make the overlay ramp out"
    assert not bad, f"ramp-out steps off the rate limit (step, before, after, expected): {bad[:5]}"


def test_each_fault_ramps_out_resumes_and_is_said(run: Run) -> None:
    """Per fault: log lines at start and clear (always); the link: outputs stop and come back at
    once; where the fault takes the inputs away, the overlay ramps to zero in time; the overlay is
    engaged again before the next fault. The two overlay judgements need the overlay engaged before
    the fault and no stall of the guest (an input gap) around it: otherwise they skip with the
    figures. Prints the per-fault figures."""
    rec = _rec(run)
    lim = load_vehicle("reference").overlay
    t = rec.step_times_ns.astype(np.int64)
    tq = np.asarray(rec.estimate["T_overlay"], dtype=np.float64)
    active = np.isin(np.asarray(rec.estimate["overlay_state"]).astype(int), (1, 2))
    misses = np.asarray(rec.diag["deadline_misses"], dtype=np.int64)
    skipped = np.asarray(rec.diag["skipped"], dtype=np.int64)
    out_t = np.array([ts for ts, _ in _bus(run)[load_profile("lde").output_id("LDE_Overlay")]])
    timeout_s = load_profile("lde").messages["MDPS_Sensors"].timeout_ns * 1e-9
    gaps = _input_gaps(run)
    rows, failures, unjudged = [], [], []
    for k, f in enumerate(FAULTS):
        a, b = _window(run, f)
        nxt = _window(run, FAULTS[k + 1])[0] if k + 1 < len(FAULTS) else int(t[-1])
        before = np.nonzero(t < a)[0]
        i0 = int(before[-1]) if before.size else 0
        engaged = bool(active[i0]) and abs(tq[i0]) > 0.05
        row: dict[str, object] = {"T before": f"{tq[i0]:.2f} Nm" if engaged else "not engaged"}
        w = (t >= a) & (t < b + S // 2)
        row["steps run"] = f"{np.count_nonzero(w)} of {(b + S / 2 - a) / STEP_NS:.0f}"
        row["misses"] = int(misses[w][-1] - misses[i0]) if np.any(w) else 0
        row["skipped"] = int(skipped[w][-1] - skipped[i0]) if np.any(w) else 0
        stalls = _disturbed(gaps, a, b) + _stale_episodes(rec, run, a, a)
        row["stalls before"] = stalls
        if f.takes_inputs:
            zero = np.nonzero((t >= a) & (tq == 0.0))[0]
            if not engaged:
                unjudged.append(f"{f.name}: overlay not engaged at the start ({stalls} stalls before)")
                if not stalls:
                    failures.append(
                        f"{f.name}: the overlay was not engaged before it, with no stall to explain it"
                    )
            elif not zero.size:
                failures.append(f"{f.name}: the overlay never reached zero")
            else:
                ramp_s = (t[zero[0]] - a) * 1e-9
                row["ramp to 0"] = f"{ramp_s * 1e3:.0f} ms in {zero[0] - i0} steps"
                # the ramp at the rate limit after the input's detection (its timeout and a step or
                # two, during which a ramp-in may still rise), plus any stall during the ramp beyond
                # dt_max (the limiter clamps a step's dt)
                detect_s = timeout_s + 3 * STEP_NS * 1e-9
                gap = np.diff(t[i0 : zero[0] + 1]) * 1e-9
                stalled = float(np.sum(np.maximum(0.0, gap - OverlayTiming().dt_max)))
                peak = abs(tq[i0]) + lim.max_rate * detect_s
                allowed = peak / lim.max_rate + detect_s + stalled
                off = np.nonzero(~active & (t >= a))[0]
                j0 = int(off[0]) if off.size else zero[0]
                problems = []
                if ramp_s > allowed:
                    problems.append(f"reached 0 after {ramp_s:.3f} s (allowed {allowed:.3f} s)")
                if np.any(np.diff(np.abs(tq[j0 : zero[0] + 1])) > 1e-12):
                    problems.append("the ramp-out was not monotonic")
                if np.any(np.abs(tq[i0 : zero[0] + 1]) > peak + 1e-9):
                    problems.append("the request rose beyond the detection time")
                if problems and stalls:  # the guest stalled around it: the input came and went
                    unjudged.append(f"{f.name}: {'; '.join(problems)} with {stalls} stalls before it")
                else:
                    failures += [f"{f.name}: {x}" for x in problems]
        back = np.nonzero(active & (t >= b) & (t < nxt))[0]
        if f.takes_inputs or not np.all(active[(t >= a) & (t < b)]):
            row["overlay back after"] = f"{(t[back[0]] - b) * 1e-9:.2f} s" if back.size else "no"
            if not back.size or (t[back[0]] - b) * 1e-9 > RESUME_S:
                if _disturbed(gaps, b, nxt) or _stale_episodes(rec, run, b + int(GAP_REACH_S * S), nxt):
                    unjudged.append(
                        f"{f.name}: overlay not back within {RESUME_S} s, stall gaps after the clear"
                    )
                else:
                    failures.append(f"{f.name}: the overlay was not engaged again within {RESUME_S} s")
        else:
            row["overlay"] = "stayed engaged"
        if not f.takes_inputs and engaged and not np.all(active[(t >= a) & (t < b)]):
            # allowed only where the inputs failed at the service's steps meanwhile (the flood's
            # delivery in the kernel, or a stall, delayed input frames past their timeout)
            late = _stale_episodes(rec, run, a + int(GAP_REACH_S * S), b, keep=f)
            row["input faults during"] = late
            if not late:
                failures.append(f"{f.name}: the overlay disengaged although the inputs stayed ok")
        if f.name == "link down":
            after = out_t[out_t >= b * 1e-9]
            inside = np.count_nonzero((out_t > a * 1e-9 + 0.05) & (out_t < b * 1e-9 - 0.05))
            row["first output after up"] = f"{(after[0] - b * 1e-9) * 1e3:.1f} ms" if after.size else "none"
            if not after.size or inside or after[0] - b * 1e-9 > 0.5:
                failures.append(
                    f"{f.name}: {inside} outputs while down, first after up {row['first output after up']}"
                )
        if not re.search(f.start_log, run.service_out):
            failures.append(f"{f.name}: no log line for its start ({f.start_log!r})")
        if not re.search(f.clear_log, run.service_out):
            failures.append(f"{f.name}: no log line for its clear ({f.clear_log!r})")
        rows.append((f.name, row))
    for name, row in rows:
        print(f"fault {name}:", "; ".join(f"{k} {v}" for k, v in row.items()))
    s = run.sender
    print(
        f"sender: {s['sent']} frames sent, {s['failed']} failed, {s['error_frames']} error frames, late p50"
        f" {s['late_ms_p50']:.2f} / p99 {s['late_ms_p99']:.2f} / max {s['late_ms_max']:.1f} ms,"
        f" {s['slips']} slips ({s['slipped_ms']:.0f} ms), CPU {s['cpu_s']:.1f} s in {s['wall_s']:.1f} s;"
        f" stall gaps of MDPS_Sensors outside the faults: {len(gaps)}; flood: {_flood(run)}"
    )
    assert not failures, "; ".join(failures)
    if unjudged:
        pytest.skip(f"overlay judgement skipped where the guest stalled: {'; '.join(unjudged)}{run.speed}")


def _flood(run: Run) -> str:
    fr = run.sender.get("flood_rx_packets", [])
    if len(fr) != 2:
        return "not measured"
    span = run.times["flood end"] - run.times["flood start"]
    m = re.search(r"foreign frames that reached the service (\d+)", run.service_out)
    return (
        f"{(fr[1] - fr[0]) / span:.0f} frames/s on {CHANNEL} (all ids) for {span:.1f} s, foreign frames"
        f" that reached the service: {m.group(1) if m else '?'}"
    )


def test_kernel_filters_keep_the_flood_out_of_python(run: Run) -> None:
    _rec(run)
    m = re.search(r"foreign frames that reached the service (\d+)", run.service_out)
    assert m, run.service_out[-2000:]
    assert int(m.group(1)) == 0
    fr = run.sender["flood_rx_packets"]
    assert fr[1] - fr[0] > 1000, f"the flood put only {fr[1] - fr[0]} frames on the bus"


def test_every_grid_point_is_run_or_counted_as_missed(run: Run) -> None:
    """The fixed grid keeps its period through every fault: each step time is a grid point, and
    every grid point not run is counted as skipped (``/lde/diag``), so the misses add up."""
    rec = _rec(run)
    t = rec.step_times_ns.astype(np.int64)
    skipped = np.asarray(rec.diag["skipped"], dtype=np.int64)
    assert np.all((t - t[0]) % STEP_NS == 0), "a step off the 3.9 ms grid"
    k = (t - t[0]) // STEP_NS
    not_run = int(k[-1] + 1 - len(t))
    assert not_run == int(skipped[-1] - skipped[0]), (not_run, int(skipped[-1] - skipped[0]))
    print(f"grid: {k[-1] + 1} points, {len(t)} run, {not_run} skipped and counted")


#: below this share of its grid points in a fault window (no stall of the guest seen) the loop is
#: judged stopped by the fault: a failure; between it and 90 % the judgement skips with the figures
HALTED_PACE = 0.5


def test_the_loop_keeps_its_pace_through_the_faults(run: Run) -> None:
    """Timing judgement: in every fault window (plus 0.5 s) the service ran >= 90 % of its grid
    points. Judged only when it kept that pace in the 5 s before the first fault; a window below
    :data:`HALTED_PACE` without a stall of the guest fails (the fault stopped the loop), any other
    window below 90 % skips with the figures (on UML's one CPU the flood's frames are delivered by
    ksoftirqd at SCHED_FIFO 99, above the service: that time is the service's)."""
    rec = _rec(run)
    t = rec.step_times_ns.astype(np.int64)
    a0 = _window(run, FAULTS[0])[0]
    base_pace = np.count_nonzero((t >= a0 - 5 * S) & (t < a0)) / (5 * S / STEP_NS)
    paces = {}
    for f in FAULTS:
        a, b = _window(run, f)
        paces[f.name] = np.count_nonzero((t >= a) & (t < b + S // 2)) / ((b + S / 2 - a) / STEP_NS)
    text = ", ".join(f"{k} {100 * v:.0f} %" for k, v in paces.items())
    print(f"service pace: before the faults {100 * base_pace:.0f} %; {text}")
    gaps = _input_gaps(run)
    slow = {k: f"{100 * v:.0f} %" for k, v in paces.items() if v < 0.9}
    # a slow window is explained by a stall of the guest (input gaps around it) or by the flood's
    # delivery above the service; any other is a failure
    unexplained = [
        k
        for k in slow
        if k != "flood" and not _disturbed(gaps, *_window(run, next(f for f in FAULTS if f.name == k)))
    ]
    # a fault that stops or blocks the loop shows as a pace far below the guest's own; a few per cent
    # under 90 % without a detected stall is UML's noise on a loaded host (seen in CI: link down 89 %
    # with a base pace of 90 %+), judged with the figures, not failed
    stopped = [k for k in unexplained if paces[k] < HALTED_PACE]
    if base_pace >= 0.9:
        assert not stopped, (
            f"the loop nearly stopped (pace below {100 * HALTED_PACE:.0f} %) without a stall of the guest"
            f" during {stopped}: {text}"
        )
    if base_pace < 0.9 or slow:
        pytest.skip(
            f"service pace below 90 % of the grid points (before the faults {100 * base_pace:.0f} %;"
            f" during {slow}, with stalls of the guest or the flood); every grid point not run was"
            f" counted (previous test){run.speed}"
        )
