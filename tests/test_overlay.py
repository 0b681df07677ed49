"""Overlay law and limiter (lde.estimator.overlay, SPEC section 5).

The limit tests follow openpilot's safety tests (opendbc/safety/tests/common.py): a reusable mixin
sweeps every limit at its boundary, and concrete classes run it on vehicles with different limits.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lde.errors import ConfigError
from lde.estimator.overlay import (
    OverlayLimiter,
    OverlayState,
    OverlayTiming,
    feedforward_torque,
    run_batch_overlay,
)
from lde.estimator.paper import Status
from lde.params import OverlayLimits, load_vehicle, shipped_vehicles
from lde.units import DEG, KMH, STEP_NS

T0 = 1_700_000_000_000_000_000  # ns, an epoch-like start time
VALID = int(Status.VALID)
TIMING = OverlayTiming()
TOL = 1e-9  # Nm, float tolerance on limits


# --- the law ------------------------------------------------------------------------------------


def _straight_line_state(vehicle, fw: float, mw: float) -> tuple[float, float]:
    """Independent derivation: eqs 7-9 with r = 0 and beta_dot = r_dot = 0, unknowns [beta, delta_f].

    0 = 2 Cf (delta_f - beta) + 2 Cr (-beta) + Fw
    0 = 2 lf Cf (delta_f - beta) - 2 lr Cr (-beta) + Mw
    """
    b, t = vehicle.body, vehicle.tires
    a = np.array(
        [
            [-2 * t.cf - 2 * t.cr, 2 * t.cf],
            [-2 * b.lf * t.cf + 2 * b.lr * t.cr, 2 * b.lf * t.cf],
        ]
    )
    beta, delta_f = np.linalg.solve(a, [-fw, -mw])
    return float(beta), float(delta_f)


@pytest.mark.parametrize("name", shipped_vehicles())
def test_law_equals_straight_line_holding_torque(name):
    v = load_vehicle(name)
    rng = np.random.default_rng(7)
    for fw, mw in rng.uniform(-3000, 3000, size=(50, 2)):
        beta, delta_f = _straight_line_state(v, fw, mw)
        t_align = 2 * v.tires.align_rate * (delta_f - beta)  # eq 12, paper sign
        assert feedforward_torque(v, fw, mw) == pytest.approx(t_align / v.steering.ratio, rel=1e-9, abs=1e-12)


def test_law_sign_left_force_needs_right_torque():
    v = load_vehicle("reference")
    assert feedforward_torque(v, 1000.0, 0.0) < 0  # pushed left -> hold by steering right
    assert feedforward_torque(v, 0.0, 1000.0) < 0  # yawed left -> steer right
    assert feedforward_torque(v, -1000.0, 0.0) > 0
    # a pure force at the rear axle's moment-free point: lr Fw + Mw = 0 -> no front-axle force
    assert feedforward_torque(v, 1000.0, -v.body.lr * 1000.0) == pytest.approx(0.0, abs=1e-12)


def test_law_matches_model_straight_line_hold():
    model = pytest.importorskip("lde.estimator.model")
    v = load_vehicle("reference")
    for fw, mw in [(800.0, -300.0), (-1500.0, 2000.0), (0.0, 500.0)]:
        ss = model.straight_line_hold(v, fw, mw)
        assert feedforward_torque(v, fw, mw) == pytest.approx(ss.t_align / v.steering.ratio, rel=1e-12)


def _closed_loop_matrices(v, vx: float):
    """Linear 2-DOF car (eqs 7-9) + a steering wheel with the aligning torque (eq 12) on it.

    State [beta, r, delta_sw, delta_sw_dot]; column torque balance (driver torque 0, no boost):
    J dd_sw = T_overlay - T_align / N - c d_sw,  T_align = 2K alpha_f,  delta_f = delta_sw / N.
    Returns (A, b_fw, b_mw, b_tov) of x_dot = A x + b_fw Fw + b_mw Mw + b_tov T_overlay.
    """
    b, t = v.body, v.tires
    m, iz, lf, lr = b.mass, b.yaw_inertia, b.lf, b.lr
    cf, cr, k, n = t.cf, t.cr, t.align_rate, v.steering.ratio
    j, c = 0.05, 0.5  # kg m^2, Nm s/rad: steering wheel inertia and damping
    # alpha_f = d_sw/N - beta - lf r/vx ; alpha_r = -beta + lr r/vx
    af = np.array([-1.0, -lf / vx, 1.0 / n, 0.0])
    ar = np.array([-1.0, lr / vx, 0.0, 0.0])
    a = np.zeros((4, 4))
    a[0] = (2 * cf * af + 2 * cr * ar) / (m * vx)
    a[0, 1] -= 1.0
    a[1] = (2 * lf * cf * af - 2 * lr * cr * ar) / iz
    a[2, 3] = 1.0
    a[3] = -(2 * k * af / n) / j
    a[3, 3] -= c / j
    e = np.eye(4)
    return a, e[0] / (m * vx), e[1] / iz, e[3] / j


@pytest.mark.parametrize("vx_kmh", [60.0, 100.0, 160.0])
def test_law_holds_linear_model_straight(vx_kmh):
    v = load_vehicle("reference")
    vx = vx_kmh * KMH
    a, b_fw, b_mw, b_tov = _closed_loop_matrices(v, vx)
    fw, mw = 900.0, -350.0
    t_ov = feedforward_torque(v, fw, mw)
    # equilibrium with the overlay: x = -A^-1 (b_fw Fw + b_mw Mw + b_tov T_ov)
    x_ov = np.linalg.solve(a, -(b_fw * fw + b_mw * mw + b_tov * t_ov))
    x_free = np.linalg.solve(a, -(b_fw * fw + b_mw * mw))
    assert abs(x_ov[1]) < 1e-12  # r = 0: held straight with zero driver torque
    assert abs(x_free[1]) > 1e-3  # without it the car yaws away
    # and the equilibrium is reached (the closed loop is stable): simulate 20 s
    dt = 1e-3
    x = np.zeros(4)
    phi = np.eye(4) + a * dt
    u = (b_fw * fw + b_mw * mw + b_tov * t_ov) * dt
    for _ in range(20_000):
        x = phi @ x + u
    assert abs(x[1]) < 1e-6


def _lateral_filter_on_constant_inputs(v, vx: float, t_col: float, seconds: float = 20.0):
    """The lateral filter (lde.estimator.lateral, float) on a straight drive whose only non-zero input is
    the column torque: (Fw, Mw) at the end."""
    from lde.estimator import lateral as E
    from lde.estimator.outputs import N_OUT, O_FW, O_MW

    p = E.params_vector(v)
    x, P = np.zeros(E.NX), np.zeros((E.NX, E.NX))
    fs, ints = np.zeros(E.N_F), np.zeros(E.N_I, np.int64)
    h, ph, out = np.zeros(E.NX), np.zeros(E.NX), np.zeros(N_OUT)
    E.reset_kernel(p, x, P, fs, ints)
    for k in range(int(seconds / (STEP_NS * 1e-9))):
        E.step_kernel(
            p, x, P, fs, ints, h, ph, T0 + k * STEP_NS, vx, 0.0, 0.0, t_col, 0.0, 0.0,
            True, True, True, True, True, out,
        )  # fmt: skip
    return out[O_FW], out[O_MW]


@pytest.mark.parametrize("vx_kmh", [60.0, 100.0, 160.0])
@pytest.mark.parametrize("dt_col", [0.3, -0.5])
def test_unbalanced_column_torque_returns_to_the_law_with_gain_plus_one(vx_kmh, dt_col):
    """The closed loop's structural gain (docs/overlay.md, "Closed loop"): a column torque that the
    aligning torque does not balance (steering friction, inertia, the overlay itself before the rack
    has moved) is read by the filter as a front-tire force, and the law turns it back into overlay
    torque of the same size and sign: T_ov = +dT (K/(N Cf L) * L * Cf/K * N = 1). A law with the wrong
    sign gives -dT, a wrong size (no N, no L, K/Cf inverted) another ratio: this is what makes the
    law's band limit necessary and what its margin is computed against."""
    v = load_vehicle("reference")
    fw, mw = _lateral_filter_on_constant_inputs(v, vx_kmh * KMH, dt_col)
    assert feedforward_torque(v, fw, mw) == pytest.approx(dt_col, rel=0.02)
    lim = OverlayLimiter(v)  # the kernel's law (after its low-pass has settled on the constant estimate)
    for k in range(1000):
        out = lim.step_values(T0 + k * STEP_NS, fw, mw, VALID, vx_kmh * KMH, 0.0, 0.0)
    assert out.demand == pytest.approx(dt_col, rel=0.02)


def _law_step_response(tau: float, n: int) -> np.ndarray:
    v = load_vehicle("reference")
    limits = dataclasses.replace(v.overlay, law_time=tau, max_torque=10.0, max_rate=1e6)
    v = dataclasses.replace(v, overlay=limits)
    lim = OverlayLimiter(v)
    out = []
    for k in range(n):
        fw = 0.0 if k < 10 else 500.0
        out.append(lim.step_values(T0 + k * STEP_NS, fw, 0.0, VALID, 100 * KMH, 0.0, 0.0).demand)
    return np.array(out)


def test_law_low_pass_time_constant_and_zero_is_the_plain_law():
    v = load_vehicle("reference")
    target = feedforward_torque(v, 500.0, 0.0)
    plain = _law_step_response(0.0, 400)
    np.testing.assert_array_equal(plain[10:], target)
    lp = _law_step_response(0.3, 400)
    assert np.all(lp[:10] == 0.0)
    # backward Euler of a 0.3 s first-order lag: 1 - (tau / (tau + dt))^k after k steps
    dt = STEP_NS * 1e-9
    k = np.arange(1, 391)
    np.testing.assert_allclose(lp[10:], target * (1.0 - (0.3 / (0.3 + dt)) ** k), rtol=1e-12, atol=1e-12)
    i63 = 10 + int(np.argmax(np.abs(lp[10:]) >= 0.632 * abs(target)))
    assert abs((i63 - 9) * dt - 0.3) < 2 * dt


def test_law_low_pass_restarts_on_an_unusable_estimate():
    """While the estimate is not ready the filter follows it, so engaging starts from the estimate
    of that moment, not from a lag through a start-up transient; a NaN never enters the filter."""
    v = load_vehicle("reference")
    lim = OverlayLimiter(v)
    nc = VALID | int(Status.NOT_CONVERGED)
    for k in range(5):
        lim.step_values(T0 + k * STEP_NS, 800.0 * k, 0.0, nc, 100 * KMH, 0.0, 0.0)
    out = lim.step_values(T0 + 5 * STEP_NS, 4000.0, 0.0, nc, 100 * KMH, 0.0, 0.0)
    assert out.demand == pytest.approx(feedforward_torque(v, 4000.0, 0.0))
    lim.step_values(T0 + 6 * STEP_NS, math.nan, 0.0, VALID, 100 * KMH, 0.0, 0.0)
    out = lim.step_values(T0 + 7 * STEP_NS, 4000.0, 0.0, VALID, 100 * KMH, 0.0, 0.0)
    assert math.isfinite(out.demand)


def test_law_time_constant_is_read_and_checked():
    assert load_vehicle("reference").overlay.law_time == 0.3
    assert OverlayLimits().law_time == 0.3


# --- helpers for the limiter --------------------------------------------------------------------


@dataclasses.dataclass
class Inputs:
    fw: float = 0.0
    mw: float = 0.0
    status: int = VALID
    speed: float = 100.0 * KMH
    steer: float = 0.0
    col: float = 0.0
    enable: bool = True

    def args(self):
        return (self.fw, self.mw, self.status, self.speed, self.steer, self.col, self.enable)


def _saturating_fw(v, sign: float = 1.0) -> float:
    """A force whose law output is beyond max_torque (sign of the torque: -sign)."""
    g = -feedforward_torque(v, 1.0, 0.0)
    return sign * 2.0 * v.overlay.max_torque / g


def _run(lim: OverlayLimiter, inp: Inputs, n: int, k0: int, dt_ns: int = STEP_NS):
    out = []
    for k in range(k0, k0 + n):
        out.append(lim.step_values(T0 + k * dt_ns, *inp.args()))
    return out


def _engage(v, sign: float = 1.0) -> tuple[OverlayLimiter, int]:
    """A limiter ACTIVE at the torque limit; returns (limiter, next step index)."""
    lim = OverlayLimiter(v)
    need = TIMING.rearm_delay + v.overlay.max_torque / v.overlay.max_rate
    n = int(need * 1e9 / STEP_NS) + 20
    out = _run(lim, Inputs(fw=_saturating_fw(v, sign)), n, 0)
    assert out[-1].state == OverlayState.ACTIVE
    assert abs(out[-1].torque) == pytest.approx(v.overlay.max_torque)
    return lim, n


# --- fault classes: every one must ramp to zero, rate limited -----------------------------------


def _dir(v, i: Inputs) -> float:
    """Direction of the law's demand for these inputs (+1 left, -1 right, 0 none)."""
    d = feedforward_torque(v, i.fw, i.mw)
    return float(np.sign(d)) if math.isfinite(d) else 0.0


def _vehicle_fault_classes(v):
    o = v.overlay
    return {
        "mdps_fault": lambda i: dataclasses.replace(i, status=VALID | int(Status.MDPS_FAULT)),
        "esc_fault": lambda i: dataclasses.replace(i, status=VALID | int(Status.ESC_FAULT)),
        "shadow_deviation": lambda i: dataclasses.replace(i, status=VALID | int(Status.SHADOW_DEVIATION)),
        "not_valid": lambda i: dataclasses.replace(i, status=0),
        "not_converged": lambda i: dataclasses.replace(i, status=VALID | int(Status.NOT_CONVERGED)),
        "low_speed_bit": lambda i: dataclasses.replace(i, status=VALID | int(Status.LOW_SPEED)),
        "below_min_speed": lambda i: dataclasses.replace(i, speed=o.min_speed * 0.9),
        "above_max_speed": lambda i: dataclasses.replace(i, speed=o.max_speed * 1.1),
        "steering_left": lambda i: dataclasses.replace(i, steer=o.max_steering_angle * 1.1),
        "steering_right": lambda i: dataclasses.replace(i, steer=-o.max_steering_angle * 1.1),
        "override_against": lambda i: dataclasses.replace(
            i, col=-(_dir(v, i) or 1.0) * o.driver_override_torque * 1.1
        ),
        "override_beyond": lambda i: dataclasses.replace(
            i,
            col=(_dir(v, i) or 1.0)
            * (abs(feedforward_torque(v, i.fw, i.mw)) + o.driver_override_torque * 1.1),
        ),
        "disabled": lambda i: dataclasses.replace(i, enable=False),
        "nan_fw": lambda i: dataclasses.replace(i, fw=math.nan),
        "nan_mw": lambda i: dataclasses.replace(i, mw=math.inf),
        "nan_speed": lambda i: dataclasses.replace(i, speed=math.nan),
        "nan_steer": lambda i: dataclasses.replace(i, steer=math.nan),
        "nan_column_torque": lambda i: dataclasses.replace(i, col=-math.inf),
    }


FAULT_CLASSES = sorted(_vehicle_fault_classes(load_vehicle("reference")))


class OverlaySafetyMixin:
    """Reusable limit sweeps; a concrete class sets ``vehicle`` (limits from its vehicle file)."""

    vehicle = None

    # each fault class ramps out, monotonically, rate limited, within max_torque/max_rate + 1 step
    @pytest.mark.parametrize("fault", FAULT_CLASSES)
    @pytest.mark.parametrize("sign", [1.0, -1.0])
    def test_fault_ramps_to_zero(self, fault, sign):
        v = self.vehicle
        o = v.overlay
        lim, k = _engage(v, sign)
        prev = lim.torque
        bad = _vehicle_fault_classes(v)[fault](Inputs(fw=_saturating_fw(v, sign)))
        n_max = math.ceil(o.max_torque / o.max_rate * 1e9 / STEP_NS) + 1
        reached = None
        for j, out in enumerate(_run(lim, bad, n_max + 50, k)):
            assert abs(out.torque - prev) <= o.max_rate * STEP_NS * 1e-9 + TOL  # never a step
            assert abs(out.torque) <= abs(prev) + TOL  # only toward zero
            assert not out.active
            assert out.state in (OverlayState.RAMP_OUT, OverlayState.OFF, OverlayState.FAULT)
            prev = out.torque
            if out.torque == 0.0 and reached is None:
                reached = j + 1
        assert reached is not None and reached <= n_max

    # magnitude limit at the boundary: a demand just inside passes, beyond it is clipped
    def test_max_torque_boundary(self):
        v = self.vehicle
        o = v.overlay
        g = -feedforward_torque(v, 1.0, 0.0)
        for demand, expect in [
            (o.max_torque * 0.999, o.max_torque * 0.999),
            (o.max_torque * 1.5, o.max_torque),
        ]:
            for sign in (1.0, -1.0):
                lim = OverlayLimiter(v)
                out = _run(lim, Inputs(fw=-sign * demand / g), 2000, 0)
                assert out[-1].state == OverlayState.ACTIVE
                assert out[-1].torque == pytest.approx(sign * expect, rel=1e-9)
                assert max(abs(x.torque) for x in out) <= o.max_torque + TOL

    # rate limit: the ramp-in slope is exactly max_rate
    def test_rate_limit_boundary(self):
        v = self.vehicle
        o = v.overlay
        lim = OverlayLimiter(v)
        out = _run(lim, Inputs(fw=_saturating_fw(v)), 2000, 0)
        steps = np.diff([0.0] + [x.torque for x in out])
        assert np.max(np.abs(steps)) == pytest.approx(o.max_rate * STEP_NS * 1e-9, rel=1e-9)
        assert np.all(np.abs(steps) <= o.max_rate * STEP_NS * 1e-9 + TOL)

    def _engages(self, **changes) -> bool:
        v = self.vehicle
        lim = OverlayLimiter(v)
        inp = dataclasses.replace(Inputs(fw=_saturating_fw(v)), **changes)
        out = _run(lim, inp, int(1e9 / STEP_NS), 0)
        return any(x.active for x in out)

    def test_speed_window_boundaries(self):
        o = self.vehicle.overlay
        eps = 1e-6
        assert self._engages(speed=o.min_speed)
        assert self._engages(speed=o.min_speed + eps)
        assert not self._engages(speed=o.min_speed - eps)
        assert self._engages(speed=o.max_speed)
        assert not self._engages(speed=o.max_speed + eps)

    def test_steering_window_boundaries(self):
        o = self.vehicle.overlay
        eps = 1e-9
        for sign in (1.0, -1.0):
            assert self._engages(steer=sign * o.max_steering_angle)
            assert not self._engages(steer=sign * (o.max_steering_angle + eps))

    def test_driver_override_boundaries(self):
        """The driver may hold from 0 to the whole holding torque along the demand's direction:
        override when more than driver_override_torque outside that band."""
        v = self.vehicle
        thr = v.overlay.driver_override_torque
        eps = 1e-9
        for sign in (1.0, -1.0):
            fw = _saturating_fw(v, sign)
            s = float(np.sign(feedforward_torque(v, fw, 0.0)))
            hold = abs(feedforward_torque(v, fw, 0.0))
            # against the overlay
            assert self._engages(fw=fw, col=-s * thr)
            assert not self._engages(fw=fw, col=-s * (thr + eps))
            # with it: up to the whole holding torque plus the threshold
            assert self._engages(fw=fw, col=s * hold)
            assert self._engages(fw=fw, col=s * (hold + thr))
            assert not self._engages(fw=fw, col=s * (hold + thr + 1e-6))
        # no demand: the plain threshold both ways
        for sign in (1.0, -1.0):
            assert self._engages(fw=0.0, col=sign * thr)
            assert not self._engages(fw=0.0, col=sign * (thr + eps))

    def test_each_status_bit(self):
        for bit in Status:
            blocks = bit in (
                Status.MDPS_FAULT,
                Status.ESC_FAULT,
                Status.SHADOW_DEVIATION,
                Status.NOT_CONVERGED,
                Status.LOW_SPEED,
            )
            assert self._engages(status=VALID | int(bit)) is not blocks, bit
        assert not self._engages(status=0)


class TestReferenceLimits(OverlaySafetyMixin):
    vehicle = load_vehicle("reference")


class TestOtherLimits(OverlaySafetyMixin):
    """Different limits in the vehicle file change every boundary."""

    vehicle = dataclasses.replace(
        load_vehicle("est3"),
        overlay=OverlayLimits(
            max_torque=1.5,
            max_rate=12.0,
            min_speed=40.0 * KMH,
            max_speed=130.0 * KMH,
            max_steering_angle=8.0 * DEG,
            driver_override_torque=1.2,
        ),
    )


# --- hold-off, FAULT state, time handling -------------------------------------------------------


@pytest.mark.parametrize("pulse_steps", [1, 5, 100])
def test_override_hold_off_before_re_engaging(pulse_steps):
    v = load_vehicle("reference")
    o = v.overlay
    lim, k = _engage(v)
    good = Inputs(fw=_saturating_fw(v))
    over = dataclasses.replace(good, col=o.driver_override_torque * 2)
    _run(lim, over, pulse_steps, k)
    t_last_override = T0 + (k + pulse_steps - 1) * STEP_NS
    k += pulse_steps
    n = int((TIMING.hold_off + TIMING.rearm_delay + 0.5) * 1e9 / STEP_NS)
    first_active = None
    for j, out in enumerate(_run(lim, good, n, k)):
        if out.active:
            first_active = T0 + (k + j) * STEP_NS
            break
    assert first_active is not None  # it does come back
    assert first_active - t_last_override >= TIMING.hold_off * 1e9
    assert first_active - t_last_override <= (TIMING.hold_off + TIMING.rearm_delay) * 1e9 + 2 * STEP_NS


def test_persistent_input_fault_enters_and_leaves_fault_state():
    v = load_vehicle("reference")
    lim, k = _engage(v)
    bad = Inputs(fw=_saturating_fw(v), status=VALID | int(Status.MDPS_FAULT))
    out = _run(lim, bad, int(TIMING.fault_persist * 1e9 / STEP_NS) + 2, k)
    k += len(out)
    assert out[0].state == OverlayState.RAMP_OUT
    assert out[-1].state == OverlayState.FAULT
    out = _run(lim, bad, 200, k)
    k += len(out)
    assert out[-1].state == OverlayState.FAULT and out[-1].torque == 0.0
    # clear: stays FAULT for fault_recover, then OFF, then re-engages after the rearm delay
    good = Inputs(fw=_saturating_fw(v))
    n_rec = int(TIMING.fault_recover * 1e9 / STEP_NS)
    out = _run(lim, good, n_rec - 1, k)
    k += len(out)
    assert all(x.state == OverlayState.FAULT for x in out)
    out = _run(lim, good, int((TIMING.rearm_delay + 0.1) * 1e9 / STEP_NS), k)
    assert any(x.state == OverlayState.OFF for x in out)
    assert out[-1].active


def test_short_fault_does_not_enter_fault_state():
    v = load_vehicle("reference")
    lim, k = _engage(v)
    bad = Inputs(fw=_saturating_fw(v), status=VALID | int(Status.ESC_FAULT))
    out = _run(lim, bad, int(TIMING.fault_persist * 1e9 / STEP_NS) - 2, k)
    assert all(x.state == OverlayState.RAMP_OUT for x in out)


def test_time_gap_and_backwards_time_never_allow_a_step():
    v = load_vehicle("reference")
    o = v.overlay
    lim = OverlayLimiter(v)
    inp = Inputs(fw=_saturating_fw(v))
    _run(lim, inp, int(TIMING.rearm_delay * 1e9 / STEP_NS) + 2, 0)
    t1 = lim.torque
    t = T0 + 10_000_000_000
    lim.step_values(t, *inp.args())  # 10 s gap: at most max_rate * dt_max
    assert abs(lim.torque - t1) <= o.max_rate * TIMING.dt_max + TOL
    t2 = lim.torque
    lim.step_values(t - 1_000_000_000, *inp.args())  # backwards: no change
    lim.step_values(t, *inp.args())  # repeated: no change
    assert lim.torque == t2


def test_first_call_outputs_zero_and_is_off():
    v = load_vehicle("reference")
    out = OverlayLimiter(v).step_values(T0, _saturating_fw(v), 0.0, VALID, 100 * KMH, 0.0, 0.0)
    assert out.torque == 0.0 and out.state == OverlayState.OFF and not out.active


def test_limiter_needs_the_vehicle():
    with pytest.raises(ConfigError, match="whole Vehicle"):
        OverlayLimiter(load_vehicle("reference").overlay)


def test_timing_validation():
    with pytest.raises(ConfigError):
        OverlayTiming(hold_off=-1.0)
    with pytest.raises(ConfigError):
        OverlayTiming(dt_max=0.0)


def test_step_with_estimate_and_inputs_objects():
    """The service's call: ``step(t, est, inputs, enable)``; a stale input group ramps out."""
    v = load_vehicle("reference")
    lim, k = _engage(v)

    @dataclasses.dataclass
    class Est:
        fw: float
        mw: float
        status: int

    @dataclasses.dataclass
    class Smp:
        speed: float
        steering_angle: float
        column_torque: float
        mdps_ok: bool = True
        esc_ok: bool = True

    est = Est(_saturating_fw(v), 0.0, VALID)
    out = lim.step(T0 + k * STEP_NS, est, Smp(100 * KMH, 0.0, 0.0))
    assert out.state == OverlayState.ACTIVE
    out = lim.step(T0 + (k + 1) * STEP_NS, est, Smp(100 * KMH, 0.0, 0.0, mdps_ok=False))
    assert out.state == OverlayState.RAMP_OUT
    assert abs(out.torque) < v.overlay.max_torque


# --- batch == live, and the global properties ---------------------------------------------------


def _random_sequence(rng: np.random.Generator, n: int, v):
    o = v.overlay
    dt = rng.choice([STEP_NS, STEP_NS, STEP_NS, 2 * STEP_NS, 0, 80_000_000, -STEP_NS], size=n)
    t = T0 + np.cumsum(dt)
    # piecewise-constant segments so that the machine visits every state
    seg = np.repeat(np.arange(n // 50 + 1), 50)[:n]
    m = seg.max() + 1
    fw = rng.normal(0, 3000, m)[seg] + rng.normal(0, 100, n)
    mw = rng.normal(0, 2000, m)[seg]
    status = rng.choice([VALID] * 8 + [0, 2 | VALID, 4 | VALID, 8, 32 | VALID, 64 | VALID, 16], size=m)[seg]
    speed = rng.uniform(o.min_speed * 0.8, o.max_speed * 1.1, m)[seg]
    steer = rng.normal(0, o.max_steering_angle * 0.7, m)[seg]
    col = rng.normal(0, o.driver_override_torque * 0.6, m)[seg]
    enable = rng.random(m)[seg] > 0.05
    nan = rng.random(n) < 0.002
    speed[nan] = np.nan
    return t, fw, mw, status, speed, steer, col, enable


def test_batch_equals_live_lockstep():
    v = load_vehicle("reference")
    rng = np.random.default_rng(2024)
    t, fw, mw, status, speed, steer, col, enable = _random_sequence(rng, 20_000, v)
    tb, ab, sb = run_batch_overlay(t, fw, mw, status, speed, steer, col, v, enable=enable)
    lim = OverlayLimiter(v)
    tl = np.empty_like(tb)
    sl = np.empty_like(sb)
    al = np.empty_like(ab)
    for k in range(len(t)):
        out = lim.step_values(
            int(t[k]), fw[k], mw[k], int(status[k]), speed[k], steer[k], col[k], bool(enable[k])
        )
        tl[k], sl[k], al[k] = out.torque, int(out.state), out.active
    np.testing.assert_array_equal(tb, tl)  # bit for bit
    np.testing.assert_array_equal(sb, sl)
    np.testing.assert_array_equal(ab, al)
    assert set(np.unique(sb)) == {int(s) for s in OverlayState}  # every state visited


def _check_limits(v, t, tq):
    o = v.overlay
    assert np.all(np.abs(tq) <= o.max_torque + TOL)
    dt = np.clip(np.diff(t.astype(np.int64)) * 1e-9, 0.0, TIMING.dt_max)
    assert np.all(np.abs(np.diff(tq)) <= o.max_rate * dt + TOL)
    assert abs(tq[0]) == 0.0


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(2, 3000))
def test_property_limits_hold_for_random_sequences(seed, n):
    v = load_vehicle("reference")
    seq = _random_sequence(np.random.default_rng(seed), n, v)
    tq, active, state = run_batch_overlay(*seq[:7], v, enable=seq[7])
    _check_limits(v, seq[0], tq)
    assert np.all(active == np.isin(state, [OverlayState.RAMP_IN, OverlayState.ACTIVE]))


step_st = st.tuples(
    st.sampled_from([0, STEP_NS, STEP_NS, 3 * STEP_NS, 200_000_000, -STEP_NS]),
    st.floats(-1e4, 1e4, allow_nan=False),
    st.floats(-1e4, 1e4, allow_nan=False),
    st.sampled_from([VALID, VALID, 0, VALID | 2, VALID | 4, VALID | 32]),
    st.floats(0.0, 70.0),
    st.floats(-0.5, 0.5),
    st.floats(-5.0, 5.0),
    st.booleans(),
)


@settings(max_examples=150, deadline=None)
@given(steps=st.lists(step_st, min_size=2, max_size=400))
def test_property_limits_hold_for_arbitrary_steps(steps):
    v = load_vehicle("reference")
    cols = list(zip(*steps, strict=True))
    t = T0 + np.cumsum(np.array(cols[0], dtype=np.int64))
    tq, _, _ = run_batch_overlay(t, *cols[1:7], v, enable=cols[7])
    _check_limits(v, t, tq)


@settings(max_examples=40, deadline=None)
@given(
    fault=st.sampled_from(FAULT_CLASSES),
    fw=st.floats(-8000, 8000, allow_nan=False),
    on_steps=st.integers(0, 600),
)
def test_property_every_fault_class_ramps_out_in_time(fault, fw, on_steps):
    v = load_vehicle("reference")
    o = v.overlay
    good = Inputs(fw=fw)
    bad = _vehicle_fault_classes(v)[fault](good)
    n_max = math.ceil(o.max_torque / o.max_rate * 1e9 / STEP_NS) + 1
    rows = [good.args()] * on_steps + [bad.args()] * (n_max + 5)
    cols = list(zip(*rows, strict=True))
    t = T0 + np.arange(len(rows), dtype=np.int64) * STEP_NS
    tq, active, _ = run_batch_overlay(t, *cols[:6], v, enable=cols[6])
    after = tq[on_steps:]
    assert np.all(
        np.abs(np.diff(np.concatenate([[tq[on_steps - 1] if on_steps else 0.0], after])))
        <= o.max_rate * STEP_NS * 1e-9 + TOL
    )
    assert after[n_max - 1] == 0.0 and np.all(after[n_max - 1 :] == 0.0)
    assert not np.any(active[on_steps:])


def test_batch_rejects_ragged_columns():
    v = load_vehicle("reference")
    with pytest.raises(ConfigError, match="Fw"):
        run_batch_overlay(
            np.arange(3), np.zeros(2), np.zeros(3), np.ones(3), np.ones(3), np.zeros(3), np.zeros(3), v
        )


@settings(max_examples=60, deadline=None)
@given(
    pattern=st.lists(st.tuples(st.booleans(), st.integers(1, 400)), min_size=1, max_size=12),
    fw=st.floats(-8000, 8000, allow_nan=False).filter(lambda x: abs(x) > 1.0),
)
def test_property_engages_only_after_the_override_hold_off(pattern, fw):
    """Whatever the override pattern: every (re-)engagement comes at least hold_off after the last
    overriding step (and rearm_delay after the conditions became ok)."""
    v = load_vehicle("reference")
    over = [o for o, n in pattern for _ in range(n)] + [False] * int(1.5e9 / STEP_NS)
    n = len(over)
    against = -np.sign(feedforward_torque(v, fw, 0.0))  # the driver steers against the overlay
    col = np.where(over, against * 2.0 * v.overlay.driver_override_torque, 0.0)
    t = T0 + np.arange(n, dtype=np.int64) * STEP_NS
    tq, active, state = run_batch_overlay(
        t, np.full(n, fw), np.zeros(n), np.full(n, VALID), np.full(n, 100 * KMH), np.zeros(n), col, v
    )
    last_override = None
    ok_since = 0
    for k in range(n):
        if over[k]:
            last_override = t[k]
            ok_since = None
        elif ok_since is None:
            ok_since = t[k]
        if active[k] and (k == 0 or not active[k - 1]):
            assert not over[k]
            if last_override is not None:
                assert t[k] - last_override >= TIMING.hold_off * 1e9
            assert t[k] - (ok_since if ok_since is not None else t[0]) >= TIMING.rearm_delay * 1e9
    assert active[-1]  # and it does come back after the last override


def test_timing_from_the_vehicle_file_when_present():
    """If [overlay] carries the timing (hold_off etc.), the limiter uses it."""
    base = load_vehicle("reference")
    Limits = dataclasses.make_dataclass(
        "Limits", [("hold_off", float, dataclasses.field(default=3.0))], bases=(OverlayLimits,), frozen=True
    )
    v = dataclasses.replace(base, overlay=Limits())
    lim, k = _engage(v)
    good = Inputs(fw=_saturating_fw(v))
    _run(lim, dataclasses.replace(good, col=10.0), 1, k)
    out = _run(lim, good, int(2.9e9 / STEP_NS), k + 1)
    assert not any(x.active for x in out)  # the default 1 s hold-off would have re-engaged
    out = _run(lim, good, int(0.5e9 / STEP_NS), k + 1 + len(out))
    assert out[-1].active
