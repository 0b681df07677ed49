"""Service steps as the recorder receives them, made up from a seeded generator: what the recording
tests write and read back (a step's result, its inputs, the row handed to the recorder, frames
received before and sent after each step)."""

from __future__ import annotations

from types import SimpleNamespace

import can
import numpy as np

from lde.can.profiles import INPUT_NAMES
from lde.engine.engine import StepBlock
from lde.io.recording import Recorder, Timing
from lde.service.diagnostics import StepTiming
from lde.service.service import StepResult
from lde.units import STEP_NS

T0 = 1_700_000_000_000_000_000  # ns, an epoch-like time base


def step_result(k: int, rng: np.random.Generator) -> StepResult:
    return StepResult(
        t_ns=T0 + k * STEP_NS,
        fw=float(rng.normal(0, 500)),
        mw=float(rng.normal(0, 300)),
        t_align=float(rng.normal(0, 10)),
        t_overlay=float(rng.uniform(-3, 3)),
        overlay_state=int(k % 5),
        overlay_active=bool(k % 2),
        status=int(rng.integers(0, 256)),
        frames_used=int(k % 3),
        timing=StepTiming(int(rng.integers(-100, 2_000_000)), 150_000, 300_000, False, k // 10),
    )


def step_inputs(rng: np.random.Generator) -> SimpleNamespace:
    return SimpleNamespace(
        column_torque=float(rng.normal()),
        assist_torque=float(rng.normal()),
        steering_angle=0.01,
        steering_rate=0.0,
        yaw_rate=0.001,
        lat_accel=0.1,
        speed=27.0,
        mdps_ok=True,
        esc_ok=False,
    )


def step_row(res: StepResult, inputs: SimpleNamespace, e2e_rejects: int) -> tuple[StepBlock, Timing]:
    """One step as the service hands it to the recorder (a StepBlock row and its timing)."""
    b = StepBlock.empty(1)
    b.t_ns[0] = res.t_ns
    b.status[0] = res.status
    b.est[0] = [res.fw, res.mw, res.t_align, 0.001, 0.002, res.fw - 100.0, res.mw, 0.01, 1, 0.002]
    b.t_overlay[0] = res.t_overlay
    b.overlay_state[0] = res.overlay_state
    b.overlay_enable[0] = True
    b.inputs[0] = [getattr(inputs, n) for n in INPUT_NAMES]
    b.ages[0] = 0
    b.valid_mask[0] = 0
    b.ok[0] = (inputs.mdps_ok, inputs.esc_ok)
    b.frames_used[0] = res.frames_used
    b.e2e_rejects[0] = e2e_rejects
    tm = res.timing
    assert tm is not None
    values = (
        tm.period_error_ns,
        tm.step_time_ns,
        tm.latency_ns,
        int(tm.deadline_miss),
        tm.deadline_misses,
        0,
    )
    timing = Timing(*(np.array([v]) for v in values))
    return b, timing


def record_steps(rec: Recorder, n: int, seed: int = 1) -> list[StepResult]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        t = T0 + k * STEP_NS
        rx = can.Message(timestamp=(t - 500_000) / 1e9, arbitration_id=0x2A0, data=bytes([k % 256] * 8))
        tx = can.Message(timestamp=(t + 200_000) / 1e9, arbitration_id=0x3D1, data=bytes(range(8)))
        rec.rx(rx)
        res = step_result(k, rng)
        rec.steps(*step_row(res, step_inputs(rng), e2e_rejects=k // 100))
        rec.tx(tx)
        out.append(res)
    return out
