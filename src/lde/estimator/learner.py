"""Online learning of what the paper neglects and a spec sheet does not give (docs/design/filters.md).

Runs beside the lateral filter (:mod:`lde.estimator.lateral`) on the same 3.9 ms grid, in every backend
(the fixed-point backend runs it as a slow floating-point task: its parameters change every 0.5 s).
Per step it low-pass filters the inputs (a second-order state-variable filter per signal: value and
derivatives, all signals with the same phase); every ``DECIM`` steps it feeds three small linear
regressions, each a Kalman filter over its coefficient vector (a random walk: slow for the physical
coefficients, faster for the intercept that carries the slowly varying disturbance); every ``PUSH``
steps it turns the coefficients into physical parameters, checks them against sanity bounds,
rate-limits them and writes them into the filter's parameter vector. Between pushes the filter is a
linear KF.

Regressions (per-tire forces; T = N (T_col + T_ast) as measured; T_true = T - N T_fric z - T_0;
z the friction sign; delta_f = (delta_sw - c_tb T_col - d_sw)/N; dots are the SVF derivatives):

R3 (kinematics; accelerometer scale s, aligning slope K, tire lag, friction, torsion twist)::

    a_y = s vx (delta_sw_dot/N - lf r_dot/vx + r) - (s/K) vx T_true_dot / 2 - s c_tb vx T_col_dot / N + c3

  from ``a_y = s a_kin - (s F_bank + (s - 1) F_wind)/m`` with ``a_kin = vx (beta_dot + r)`` and
  ``beta = delta_f - lf r/vx - T_true/(2K)``. The intercept c3 carries the bank and the gyro bias
  (``-s vx b_r``); the wind enters only with (s - 1) ~ 0.06: R3 is nearly blind to wind.

R1 (yaw and lateral balance without the rear force and without beta; trail t = K/Cf)::

    Iz r_dot + lr m a_y / s = (L/t) T_true + c1,      c1 = lr F_wind/s + M_wind

R2 (rear axle; Cr)::

    (lf T_true / t - Iz r_dot) / lr = 2 Cr alpha_r + 2 Cr sigma D_dot / vx + c2,  alpha_r = T_true/(2K) - D

  with ``D = delta_f - L r / vx``. Both axles' forces lag their kinematic slips by the relaxation
  length sigma [m] (``alpha_eff + (sigma / vx) alpha_eff_dot = alpha_kin``), and ``T_true`` is the
  front's lagged (effective) slip times 2K; then ``alpha_r,kin = alpha_f,kin - D`` gives the rear's
  effective slip ``T_true/(2K) - D / (1 + sigma s / vx)`` ~ ``alpha_r + sigma D_dot / vx``: a lag of
  D, so the coefficient 2 Cr sigma is positive (the front's lag cancels for equal sigma).

The regressions start in cascade (R1 once R3 has samples, R2 once R1 has): without it Cr ended 5 %
off; and R2 forgets its samples as fast as the K and trail it regressed them on still move
(``L_R2_UPQ``). They learn only when the drive is excited (lateral-force variation > 150 N; for R3 and R1 also
road-wheel rate RMS > 0.5 deg/s, or > 0.2 deg/s with > 450 N and the wind under 150 N: a lane change
at motorway speed; not for R2: on the fast ends of the manoeuvres alone it learned Cr 8-16 % low) and
disturbance-quiet (the filter's wind estimate varies less than half as much as
m a_y): a steady crosswind or a long bank gives no excitation and is never learned as a tire value. A
change of the wind is a step in R1's and R2's intercepts: their process noise grows with the change
the filter's wind estimate shows (``L_WIND_Q``), or the slopes take what the intercepts cannot follow.

Offsets (not identifiable from a steady state: a steady crosswind looks like them):

- gyro bias ``b_r``: a straight road returns to its heading. Between two steady straight moments
  8-120 s apart the heading change is the bias times the window (windows with more than 10 deg of
  heading change are dropped); the windows are averaged over ~10 minutes;
- angle offset ``d_sw``: the part of the filter's wind estimate that acts through the rear axle,
  (F, M) = o (s, -lr), split from a wind (F, M) = w (1, x_cp) with a generic centre of pressure
  (the vehicle file's ``wind_cp_m``, 0.3 m ahead of the CG), only while the wind estimate is small,
  averaged over 30 minutes of such driving (a 10-minute steady wind moves it by a fraction of its
  leak only).

Learned state of the tire group (``ST_*``): not learned (prior only), learning (after 150 excited
samples the values are pushed), learned (after 1000 excited samples, ~16 s of manoeuvres, and with a
torque of unknown scale its factor's posterior relative std under ``L_SCALE_SD``; it then learns
1000x slower in variance: a learned car is not re-learned by the next drive's disturbances). Off by
default: "learned" by the regressions' own uncertainty instead of the sample count (``L_LEARNED_ST``,
``L_LEARNED_SCR``).

Torques of unknown scale (``L_TSCALE``, from the profile: :func:`torque_scale_mode`): the aligning
torque is ``N (k_c T_col + k_a T_ast)``. With one torque of unknown scale its factor to the other
(in Nm) is learned in R3, whose tire-lag slot then holds the second torque's own rate coefficient
``s k / K``; with both unknown the overall scale is K's and not identifiable, so K keeps its prior and
both factors are learned in that unit. R3 learns without the disturbance-quiet gate until the state
is "learned" (the filter's wind estimate needs the scale), and nothing else is pushed before R3 has
its samples. Fw and Mw keep N and Nm (the torque enters the filter only through ``T / 2K``).
Constants tuned on zoo plants indep_twin, tires_minus25, suv_slow, angle_above_tb (docs/design/filters.md).
"""

from __future__ import annotations

import math
from collections.abc import Collection

import numpy as np
from numba import njit

from lde.estimator import lateral as E
from lde.estimator.outputs import O_FW_WIND, O_MW_WIND
from lde.params import Vehicle
from lde.units import DEG

__all__ = [
    "default_lp",
    "init_state",
    "learner_step",
    "push",
    "ST_NOT",
    "ST_LEARNING",
    "ST_LEARNED",
    "N_LS",
    "N_LP",
]

# --- signals filtered by the SVF -------------------------------------------------------------------
S_R, S_AY, S_T, S_Z, S_DSW, S_TCOL, S_VX = range(7)
N_SIG = 7

# --- learner parameters (lp) -------------------------------------------------------------------------
(L_W, L_ZETA, L_DECIM, L_PUSH, L_VMIN, L_AYMAX, L_DSWMAX,
 L_EXC_TAU, L_EXC_RDOT, L_SIG1, L_SIG2, L_SIG3, L_QI1, L_QI2, L_QI3, L_QPHYS,
 L_TORSION, L_B_TAU, L_B_GATE, L_D_TAU, L_D_GATE_F, L_D_GATE_M, L_RATE,
 L_LEARNED_REL, L_MIN_SAMPLES, L_SIG_B, L_ENABLE, L_RELAX, L_EXC_SW, L_SLIDE, L_SLOW,
 L_QUIET, L_EXC_F, L_SIG_CTB, L_SIGMA0, L_WIND_MAX, L_WIND_REL, L_WIND_SIG,
 L_WIND_Q, L_EXC_SW3, L_R3_ACC, L_EXC_SW2, L_EXC_F2, L_WIND_MAX2, L_R2_UPQ,
 L_LEARNED_ST, L_LEARNED_SCR, L_TSCALE, L_SCALE_SD) = range(49)  # fmt: skip
N_LP = 49

#: L_TSCALE: which torque's scale is learned. TS_KNOWN: both torques in Nm; TS_ASSIST: the assist's
#: factor to the column torque (in Nm); TS_COLUMN: the column's to the assist (in Nm); TS_BOTH: the
#: assist's to the column signal, whose own unit stays unknown (K, the friction, the twist in it)
TS_KNOWN, TS_ASSIST, TS_COLUMN, TS_BOTH = 0, 1, 2, 3

# --- learner state (ls, float) -----------------------------------------------------------------------
# svf: 3 * N_SIG (value, derivative, second derivative); then regression blocks
LS_SVF = 0
N1, N2, N3 = 2, 3, 6
LS_T1 = LS_SVF + 3 * N_SIG  # R1 theta: L/t, c1
LS_P1 = LS_T1 + N1
LS_T2 = LS_P1 + N1 * N1  # R2 theta: 2 Cr, 2 Cr sigma (sigma: the tires' relaxation length), c2
LS_P2 = LS_T2 + N2
LS_T3 = LS_P2 + N2 * N2  # R3 theta: s, s/K, s tau/K, s N Tfric/(2K), s c_tb, c3
LS_P3 = LS_T3 + N3
LS_B = LS_P3 + N3 * N3  # gyro bias, its variance
LS_D = LS_B + 2  # angle offset (steering wheel), its variance
LS_EXC = LS_D + 2  # excitation mean square of r_dot
LS_N = LS_EXC + 1  # excited samples used by R3, R1, R2 (3 counters)
LS_STEP = LS_N + 3  # steps since start
LS_INIT = LS_STEP + 1  # 1 once the SVF is initialised
LS_STATE = LS_INIT + 1  # learned state per group (tires, friction, offsets)
LS_WARM = LS_STATE + 3  # time since the SVF (re)started [s]
LS_FB = LS_WARM + 1  # the filter's bank force at the last regression sample [N]
LS_CX = LS_FB + 1  # learned wind centre of pressure x [m] (diagnostic)
LS_TB = LS_CX + 1  # gated driving time behind the gyro-bias average [s]
LS_TD = LS_TB + 1  # ... behind the angle-offset average [s]
LS_BP = LS_TD + 1  # band-pass filter states: m a_y (fast, slow), F_wind_hat (fast, slow), then the
# mean squares of the two band signals (4 + 2)
LS_RLP = LS_BP + 6  # 2 s low-pass of the yaw rate minus the bias (the anchor test of the gyro-bias windows)
LS_HI = LS_RLP + 1  # heading integral since the last anchor, int (r - b) dt [rad]
LS_HT = LS_HI + 1  # time since the last anchor [s]; < 0: no window open (waiting for an anchor)
LS_AC = LS_HT + 1  # how long the anchor condition has held [s]
N_LS = LS_AC + 1

ST_NOT, ST_LEARNING, ST_LEARNED = 0, 1, 2

#: the learned torsion twist's upper bound [rad/Nm] (the lower one is 0: a twist cannot be negative)
CTB_MAX = 2.0 * DEG


def default_lp(torsion: bool = False, enable: bool = True) -> np.ndarray:
    """The learner's constants (``L_*`` slots); ``torsion``: the profile's angle sensor sits above the
    torsion bar; ``enable``: learn at all."""
    lp = np.zeros(N_LP)
    lp[L_W] = 2.0 * math.pi * 3.0  # SVF natural frequency [rad/s]
    lp[L_ZETA] = 0.8
    lp[L_DECIM] = 4  # regressions every 4 steps (15.6 ms)
    lp[L_PUSH] = 128  # parameters to the filter every 128 steps (0.5 s)
    lp[L_VMIN] = 50.0 / 3.6
    lp[L_AYMAX] = 4.0
    lp[L_DSWMAX] = 60.0 * DEG
    lp[L_EXC_TAU] = 1.0
    lp[L_EXC_RDOT] = 0.5 * DEG  # r_dot RMS [rad/s^2] above which R1-R3 learn
    lp[L_SIG1] = 150.0  # R1 residual std [Nm]
    lp[L_SIG2] = 150.0  # R2 residual std [N]
    lp[L_SIG3] = 0.10  # R3 [m/s^2]
    lp[L_QI1] = 20.0**2  # R1 intercept random walk [Nm^2/s]
    lp[L_QI2] = 20.0**2  # R2 intercept random walk [N^2/s]
    lp[L_QI3] = 0.03**2
    lp[L_QPHYS] = (0.002) ** 2  # relative random walk of the physical coefficients per second
    lp[L_TORSION] = 1.0 if torsion else 0.0
    lp[L_B_TAU] = 600.0  # s of windows (a running average before)
    lp[L_B_GATE] = (
        0.3 * DEG
    )  # anchor of the gyro-bias windows: 2 s mean yaw rate (minus the bias) within this
    lp[L_D_TAU] = 1800.0  # s of gated driving (a running average before)
    lp[L_D_GATE_F] = 150.0
    lp[L_D_GATE_M] = 200.0
    lp[L_RATE] = 0.02  # max relative change per push of a pushed tire parameter
    lp[L_LEARNED_REL] = 0.05
    lp[L_MIN_SAMPLES] = 1000  # excited regression samples (15.6 ms each: ~16 s of manoeuvres) to 'learned'
    lp[L_SIG_B] = 0.3 * DEG
    lp[L_ENABLE] = 1.0 if enable else 0.0
    lp[L_RELAX] = 1.0  # learn the tire relaxation terms
    # road-wheel angle rate RMS [rad/s] above which R1-R3 learn (8 deg/s at N = 16). 0.2 deg/s (tuned on
    # the zoo) let the learner move the tires during a crosswind step on the linear sample drive: Fw
    # settled 17 % low (tests/replay/test_replay.py acceptance test); 0.5 keeps it at 0.1 %
    lp[L_EXC_SW] = 0.5 * DEG
    lp[L_SLIDE] = 0.0  # |steering-wheel rate| [rad/s] below which a sample is left out (stiction)
    lp[L_QUIET] = 0.5  # learn only while the filter's wind varies less than this share of m a_y (0.2-3 Hz)
    lp[L_EXC_F] = 150.0  # ... and m a_y varies by more than this [N RMS, 0.2-3 Hz]
    lp[L_SLOW] = 1000.0  # once learned, the regressions' noise variance is this much larger (slower)
    lp[L_SIG_CTB] = 0.3 * DEG  # prior std of the torsion twist in the angle [rad/Nm]
    # prior of R2's relaxation coefficient, as a length [m] (std 0.4 m): the tires' lag is +0.4-0.6 m
    # (vcan_sim's plants), but the measured aligning torque carries the rack's damping and inertia, a
    # lead, and with it the fit is -0.3..+0.1 m; a lag prior (+0.4) was worse on the zoo
    # (docs/design/filters.md, "The learner")
    lp[L_SIGMA0] = -0.4
    # learn only while the filter's wind force (3 s mean) is below this [N]; off (inf): 150 N is
    # better on the zoo (a crosswind slalom moved Cf -11 % in 40 s) but stops the learning in a steady
    # crosswind that tests/estimator/test_learner_long.py requires (docs/design/filters.md, "When it
    # learns: the gates")
    lp[L_WIND_MAX] = math.inf
    # the same, relative: learn only while |wind, 3 s mean| < this x the band RMS of m a_y (the
    # manoeuvre's force excitation); off (inf) (docs/design/filters.md, "When it learns: the
    # gates")
    lp[L_WIND_REL] = math.inf
    # the regressions' noise variance grows by (wind, 3 s mean / this [N])^2: slower, not stopped,
    # in a strong wind; off (inf)
    lp[L_WIND_SIG] = math.inf
    # a change of the wind moves R1's and R2's intercepts (c1 = lr F_wind/s + M_wind, c2 = -M_wind/lr
    # + ...) far faster than their random walks (L_QI1, L_QI2) allow, and what an intercept does not
    # follow is fitted into the slopes (a crosswind slalom moved Cf -11 % in 40 s): their process
    # noise grows by this x the square of the change the filter's wind estimate shows (its 0.05 s
    # minus its 3 s low-pass); 1-16 alike on the zoo, 0 is the learner before (docs/design/filters.md,
    # "The learner")
    lp[L_WIND_Q] = 4.0
    # R3's own steering-rate gate [rad/s road-wheel RMS]; < 0: R1's (L_EXC_SW), as shipped (0.25 and
    # 0.1 deg/s were worse on the zoo: docs/design/filters.md, "What it cannot learn")
    lp[L_EXC_SW3] = -1.0
    # R3's residual variance grows by (road-wheel angle acceleration / this [rad/s^2])^2: the
    # measured aligning torque carries the rack's damping and inertia (a lead that grows with the
    # steering's acceleration), which R3 does not model. Where the twist is learned (the angle above
    # the bar) 1 deg/s^2: K and the twist nearer the truth on every above-bar zoo plant, and better on
    # both plant sets once R2 forgets its early samples (L_R2_UPQ); on a pinion angle it cost the
    # lde profile's runs, so off (inf) there (docs/design/filters.md, "The learner")
    lp[L_R3_ACC] = 1.0 * DEG if torsion else math.inf
    # the low-rate tier of the steering gate (R3, R1): a sample whose road-wheel rate RMS is under
    # L_EXC_SW but above L_EXC_SW2 [rad/s] counts when the manoeuvre's force is large, m a_y band RMS
    # above L_EXC_F2 [N], and the filter's wind (3 s mean) is under L_WIND_MAX2 [N]. A lane change at
    # motorway speed needs ~1/v^2 of the rate a town one does (0.2-0.35 deg/s at 90-100 km/h, under
    # 0.5); R1 needs the aligning torque to vary well above what a wind does to it, hence the force
    # (300 N let the acceptance drive of tests/replay/test_replay.py learn its crosswind as tires; 350-500 N
    # keep it) and the wind bound (without it the crosswind slalom lost 6 of 45 warm runs on the
    # tuning plants; 0.15 deg/s met more but took R3 and R1 samples from the 0.14 deg/s slow weave
    # that tests/estimator/test_learner.py keeps to R2). < 0: off (the gate before issue 11's lane-change
    # priors; docs/design/filters.md, "When it learns: the gates")
    lp[L_EXC_SW2] = 0.2 * DEG
    lp[L_EXC_F2] = 450.0
    lp[L_WIND_MAX2] = 150.0
    # R2 regresses on K, the trail t = K/Cf and the twist as R3 and R1 have them at each sample: while
    # those still move (the first 20-40 s of a drive), its samples are taken on a model that is then
    # left behind, and Cr kept them (K 7200 -> 5350 and the twist 0.5 -> 0 deg/Nm under R2's first
    # samples left Cr 6 % high, Mw 10-13 % warm). At each push R2's covariance is scaled by 1 + this x
    # ((dK/K)^2 + (dt/t)^2) of the push: the samples on the old model are forgotten as fast as it
    # moves, and not at all once it has settled. 0: off (docs/design/filters.md, "The learner")
    lp[L_R2_UPQ] = 3.0e3
    # "learned" by the regressions' own uncertainty instead of a sample count: the posterior relative
    # std of the trail (R1) and of Cr (R2) below these, R2 running; 0: by L_MIN_SAMPLES
    lp[L_LEARNED_ST] = 0.0
    lp[L_LEARNED_SCR] = 0.0
    # torque signals of unknown scale (TS_*): the assist's scale relative to the column's (TS_ASSIST,
    # TS_BOTH: K then in the column signal's unit) or the column's relative to the assist's
    # (TS_COLUMN). R3's tire-lag slot then carries the second torque's own rate coefficient
    lp[L_TSCALE] = TS_KNOWN
    # a torque factor of unknown scale counts as learned once its posterior relative std is under this
    # (the overlay waits for it: lde.engine.engine.Engine.overlay_allowed)
    lp[L_SCALE_SD] = 0.05
    return lp


def init_state(p: np.ndarray, lp: np.ndarray, friction_prior: float = 0.3) -> np.ndarray:
    """The learner state from the filter's starting parameters (the vehicle file's tires: generic for
    a spec sheet) and the friction prior [Nm]."""
    ls = np.zeros(N_LS)
    lf, lr, n = p[E.P_LF], p[E.P_LR], p[E.P_N]
    L = lf + lr
    k0 = p[E.P_K]
    t0 = k0 / p[E.P_CF]
    # R1: L/t (30 %), intercept;  R2: 2 Cr (30 %), 2 Cr sigma (sigma L_SIGMA0 +- 0.4 m), intercept
    ls[LS_T1 + 0] = L / t0
    _diag(ls, LS_P1, N1, ((0.3 * L / t0) ** 2, 2000.0**2))
    c2 = 2.0 * p[E.P_CR]
    rx = 1.0 if lp[L_RELAX] > 0 else 1e-6
    ls[LS_T2 + 0] = c2
    ls[LS_T2 + 1] = c2 * lp[L_SIGMA0]
    _diag(ls, LS_P2, N2, ((0.3 * c2) ** 2, (rx * 0.4 * c2) ** 2, 3000.0**2))
    ls[LS_CX] = p[E.P_XCP]  # the vehicle file's wind centre of pressure (the angle-offset split only)
    # R3: s (0.08), s/K (30 %), s tau/K (tau 0.015 +- 0.015 s), s N Tfric/(2K) (0.3 +- 0.4 Nm),
    #     s c_tb (0.3 deg/Nm if the angle is above the torsion bar), intercept
    ls[LS_T3 + 0] = p[E.P_S]  # generic roll tilt 1.06 (a sedan's ~4 deg/g roll gradient)
    ls[LS_T3 + 1] = p[E.P_S] / k0
    ls[LS_T3 + 2] = p[E.P_S] * 0.015 / k0
    ls[LS_T3 + 3] = p[E.P_S] * n * friction_prior / (2.0 * k0)
    # generic torsion bar 2 Nm/deg (0.5 +- 0.05 deg/Nm) where the angle sensor sits above it: the twist
    # is nearly collinear with the aligning torque (the column torque follows it), so the prior dominates
    sig_ctb = p[E.P_S] * lp[L_SIG_CTB]
    ls[LS_T3 + 4] = p[E.P_S] * p[E.P_CTB]
    _diag(
        ls,
        LS_P3,
        N3,
        (0.08**2, (0.3 / k0) ** 2, (rx * 0.015 / k0) ** 2, (n * 0.4 / (2.0 * k0)) ** 2, sig_ctb**2, 1.0),
    )
    if lp[L_TSCALE] != TS_KNOWN:
        # a torque of unknown scale: the lag slot is the other torque's rate coefficient s k / K (k its
        # factor to the reference torque, prior 1, std 2); with both unknown the reference itself (s/K,
        # and R1's L/t) is known to a factor of a few only
        ls[LS_T3 + 2] = ls[LS_T3 + 1]
        ls[LS_P3 + 2 * N3 + 2] = (2.0 * ls[LS_T3 + 1]) ** 2
        if lp[L_TSCALE] == TS_BOTH:
            ls[LS_P3 + N3 + 1] = (3.0 * ls[LS_T3 + 1]) ** 2
            ls[LS_P1] = (3.0 * ls[LS_T1]) ** 2
    ls[LS_B + 1] = lp[L_SIG_B] ** 2
    ls[LS_D + 1] = (1.0 * DEG) ** 2
    ls[LS_HT] = -1.0  # no gyro-bias window open: the first opens at the first anchor
    return ls


def _diag(ls, off, n, vals):
    for i in range(n):
        for j in range(n):
            ls[off + i * n + j] = 0.0
        ls[off + i * n + i] = vals[i]


#: the plausible learned tire and sensor values of a learned-state file (lde.estimator.learned checks them),
#: (low, high): Cf, Cr [N/rad], K [Nm/rad], the accelerometer scale s. The fixed-point model's
#: coefficient formats hold this whole box (firmware_model.gen_lateral.PARAM_BOX is this), and the
#: learner's push bounds lie inside it.
PLAUSIBLE = {"cf": (1e3, 1e6), "cr": (1e3, 1e6), "k": (10.0, 1e5), "s": (0.8, 1.4)}


@njit(cache=True, inline="always")
def _rls(ls, toff, poff, n, xr, y, r, ph):  # pragma: no cover - compiled
    """Kalman update of theta (ls[toff:toff+n]) with covariance ls[poff:...] (row-major n x n):
    y = xr . theta + v, var(v) = r. Returns the innovation."""
    innov = y
    for i in range(n):
        innov -= xr[i] * ls[toff + i]
    return _kupdate(ls, toff, poff, n, xr, innov, r, ph)


@njit(cache=True, inline="always")
def _kupdate(ls, toff, poff, n, xr, innov, r, ph):  # pragma: no cover - compiled
    """theta += k innov, P -= k (P h)^T with h = xr (linear: the regressors; EKF: the Jacobian)."""
    s = r
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += ls[poff + i * n + j] * xr[j]
        ph[i] = acc
        s += xr[i] * acc
    inv = 1.0 / s
    for i in range(n):
        ls[toff + i] += ph[i] * inv * innov
    for i in range(n):
        for j in range(n):
            ls[poff + i * n + j] -= ph[i] * ph[j] * inv
    return innov


@njit(cache=True, inline="always")
def _project_bound(ls, toff, poff, n, i, lo, hi):  # pragma: no cover - compiled
    """Keep coefficient ``i`` of theta within [lo, hi]: outside it, move theta to the bound along the
    covariance's row i (the estimate projection of a Kalman filter with an inequality constraint,
    W = P^-1: the most probable theta with theta_i on the bound); P is left as it is."""
    v = ls[toff + i]
    target = min(max(v, lo), hi)
    pii = ls[poff + i * n + i]
    if target == v or pii <= 0.0:
        return
    g = (v - target) / pii
    for j in range(n):
        ls[toff + j] -= ls[poff + j * n + i] * g
    ls[toff + i] = target


@njit(cache=True, inline="always")
def _svf(ls, k, u, w, zeta, dt):  # pragma: no cover - compiled
    """y'' = w^2 (u - y) - 2 zeta w y' (semi-implicit Euler); stores y, y', y''."""
    o = LS_SVF + 3 * k
    y = ls[o]
    yd = ls[o + 1]
    ydd = w * w * (u - y) - 2.0 * zeta * w * yd
    yd += dt * ydd
    y += dt * yd
    ls[o] = y
    ls[o + 1] = yd
    ls[o + 2] = ydd


@njit(cache=True)
def learner_step(
    lp, ls, ws, p, kout, vx, angle, yaw, tcol, tast, ay, zfric, valid
):  # pragma: no cover - compiled
    """One learner step after the filter's step (``kout`` its outputs, ``valid``: the step was VALID).
    Writes learned values into ``p`` every PUSH steps (returns True then). ``ws``: scratch (2, N3)."""
    dt = p[E.P_DT]
    n = p[E.P_N]
    m, iz, lf, lr = p[E.P_M], p[E.P_IZ], p[E.P_LF], p[E.P_LR]
    L = lf + lr
    ok = valid and math.isfinite(ay) and math.isfinite(yaw) and math.isfinite(angle) and math.isfinite(tcol)
    ok = ok and math.isfinite(tast) and math.isfinite(vx)
    ls[LS_STEP] += 1.0
    if not ok:
        ls[LS_INIT] = 0.0
        ls[LS_HT] = -1.0  # no heading through a gap: the next gyro-bias window starts at an anchor
        return False
    unknown = lp[L_TSCALE] != TS_KNOWN
    # the SVF's torque channel: N (T_col + T_ast), or with a torque of unknown scale N T_ast as read
    T = n * tast if unknown else n * (tcol + tast)
    u = (yaw, ay, T, zfric, angle, tcol, vx)
    if ls[LS_INIT] == 0.0:
        for k in range(N_SIG):
            ls[LS_SVF + 3 * k] = u[k]
            ls[LS_SVF + 3 * k + 1] = 0.0
            ls[LS_SVF + 3 * k + 2] = 0.0
        ls[LS_INIT] = 1.0
        ls[LS_EXC] = 0.0
        for i in range(4):
            ls[LS_BP + i] = m * ay if i < 2 else kout[O_FW_WIND]
        ls[LS_BP + 4] = 0.0
        ls[LS_BP + 5] = 0.0
        ls[LS_WARM] = 0.0
    w, zeta = lp[L_W], lp[L_ZETA]
    for k in range(N_SIG):
        _svf(ls, k, u[k], w, zeta, dt)
    ls[LS_WARM] += dt
    o = LS_SVF
    r_f, r_d = ls[o + 3 * S_R], ls[o + 3 * S_R + 1]
    ay_f = ls[o + 3 * S_AY]
    T_f, T_d, T_dd = ls[o + 3 * S_T], ls[o + 3 * S_T + 1], ls[o + 3 * S_T + 2]
    z_f, z_d = ls[o + 3 * S_Z], ls[o + 3 * S_Z + 1]
    a_raw_d = T_d  # the assist part's rate as read (unknown scale)
    if unknown:
        # the aligning torque in the reference unit from the two parts: N (k_c T_col + k_a T_ast)
        kc, ka = p[E.P_KC], p[E.P_KA]
        tc = LS_SVF + 3 * S_TCOL
        T_f = n * kc * ls[tc] + ka * T_f
        T_d = n * kc * ls[tc + 1] + ka * T_d
        T_dd = n * kc * ls[tc + 2] + ka * T_dd
    a_f, a_d = ls[o + 3 * S_DSW], ls[o + 3 * S_DSW + 1]
    tc_f, tc_d = ls[o + 3 * S_TCOL], ls[o + 3 * S_TCOL + 1]
    v_f = ls[o + 3 * S_VX]
    a_exc = dt / lp[L_EXC_TAU]
    ls[LS_EXC] += a_exc * ((a_d / n) ** 2 - ls[LS_EXC])  # road-wheel rate: comparable across ratios
    # disturbance-quiet gate: band-pass (0.3 s low-pass minus 3 s low-pass) of m a_y (the manoeuvre's
    # lateral force) and of the filter's wind estimate; their mean squares over 2 s
    b = LS_BP
    u1 = m * ay
    u2 = kout[O_FW_WIND]
    ls[b + 0] += dt / 0.05 * (u1 - ls[b + 0])
    ls[b + 1] += dt / 3.0 * (u1 - ls[b + 1])
    ls[b + 2] += dt / 0.05 * (u2 - ls[b + 2])
    ls[b + 3] += dt / 3.0 * (u2 - ls[b + 3])
    e1 = ls[b + 0] - ls[b + 1]
    e2 = ls[b + 2] - ls[b + 3]
    ls[b + 4] += dt / 2.0 * (e1 * e1 - ls[b + 4])
    ls[b + 5] += dt / 2.0 * (e2 * e2 - ls[b + 5])

    istep = int(ls[LS_STEP])
    decim = int(lp[L_DECIM])
    if lp[L_ENABLE] > 0.0 and istep % decim == 0 and v_f > lp[L_VMIN] and ls[LS_WARM] > 1.0:
        tdec = decim * dt
        # time update (random walks): intercepts, and a slow relative walk of the physical ones
        qrel = lp[L_QPHYS] * tdec
        ls[LS_P1 + 0] += qrel * ls[LS_T1 + 0] ** 2
        ls[LS_P2 + 0] += qrel * ls[LS_T2 + 0] ** 2
        ls[LS_P2 + N2 + 1] += qrel * ls[LS_T2 + 1] ** 2
        ls[LS_P2 + N2 * N2 - 1] += lp[L_QI2] * tdec
        ls[LS_P1 + N1 * N1 - 1] += lp[L_QI1] * tdec
        ls[LS_P3 + 0] += qrel
        ls[LS_P3 + N3 + 1] += qrel * ls[LS_T3 + 1] ** 2
        # R3's intercept carries the bank (and the gyro bias): a random walk
        s = p[E.P_S]
        ls[LS_P3 + N3 * N3 - 1] += lp[L_QI3] * tdec
        if lp[L_WIND_Q] > 0.0:
            # a step A in the wind leaves e2 = A exp(-t/3 s) in the band: int e2^2 dt = 1.5 s A^2, so
            # the intercepts' variance grows by L_WIND_Q x the step's square over the event; the
            # moment through the generic centre of pressure (the vehicle file's, LS_CX)
            xc = ls[LS_CX]
            dq = lp[L_WIND_Q] * e2 * e2 * tdec / 1.5
            ls[LS_P1 + N1 * N1 - 1] += dq * (lr / s + xc) ** 2
            ls[LS_P2 + N2 * N2 - 1] += dq * (xc / lr) ** 2
        linear = abs(ay_f) < lp[L_AYMAX] and abs(a_f) < lp[L_DSWMAX]
        # R3 and R1 need the steering to move (R3 works on its rate, R1 on the aligning torque's
        # variation); R2 needs the lateral force to vary only: a steering-rate gate left it the fast
        # parts of the manoeuvres, where its quasi-static rear-axle model is worst (Cr 8-16 % low on
        # indep_twin, long_trail, tires_plus25; docs/design/filters.md, "The learner")
        force_exc = ls[LS_BP + 4] > lp[L_EXC_F] ** 2 and ls[LS_BP + 5] < (lp[L_QUIET] ** 2) * ls[LS_BP + 4]
        force_exc = force_exc and abs(ls[LS_BP + 3]) < lp[L_WIND_MAX]
        if lp[L_WIND_REL] < math.inf:
            force_exc = force_exc and abs(ls[LS_BP + 3]) < lp[L_WIND_REL] * math.sqrt(ls[LS_BP + 4])
        excited = force_exc and ls[LS_EXC] > lp[L_EXC_SW] ** 2
        gate3 = lp[L_EXC_SW3] if lp[L_EXC_SW3] >= 0.0 else lp[L_EXC_SW]
        excited3 = force_exc and ls[LS_EXC] > gate3**2
        if unknown and ls[LS_STATE] != ST_LEARNED:
            # a torque of unknown scale: the filter's wind estimate (the quiet gate) is meaningless
            # until the scale is learned; R3, nearly blind to wind, learns on the force excitation alone
            excited3 = ls[LS_BP + 4] > lp[L_EXC_F] ** 2 and ls[LS_EXC] > gate3**2
        if lp[L_EXC_SW2] >= 0.0 and force_exc:
            # the low-rate tier (default_lp): slow steering with a large manoeuvre force, no wind
            low = ls[LS_EXC] > lp[L_EXC_SW2] ** 2 and ls[LS_BP + 4] > lp[L_EXC_F2] ** 2
            low = low and abs(ls[LS_BP + 3]) < lp[L_WIND_MAX2]
            excited = excited or low
            excited3 = excited3 or low
        xr = ws[0]
        ph = ws[1]
        sliding = abs(a_d) > lp[L_SLIDE]
        # once learned the regressions slow down (a learned car is not re-learned by the next drive's
        # disturbances); where the state comes from the uncertainty, the slow-down waits for the
        # sample count as before
        settled = ls[LS_N] >= lp[L_MIN_SAMPLES] if lp[L_LEARNED_ST] > 0.0 else ls[LS_STATE] == ST_LEARNED
        slow = lp[L_SLOW] if settled else 1.0
        slow *= 1.0 + (ls[LS_BP + 3] / lp[L_WIND_SIG]) ** 2
        if linear and (force_exc or excited3) and sliding:
            tfric = p[E.P_TFRIC]
            # R3: a_y = s X0 - (s/K) X1 - (s tau/K) X2 + (s N Tfric/(2K)) Xz - (s c_tb) Xtb + c3
            xr[0] = v_f * a_d / n - lf * r_d + v_f * (r_f - p[E.P_BR])
            xr[1] = -v_f * T_d / 2.0
            xr[2] = -v_f * T_dd / 2.0
            if unknown:  # the reference torque's rate (slot 1) and the other's as read (slot 2)
                col_d = -v_f * n * tc_d / 2.0
                ast_d = -v_f * a_raw_d / 2.0
                ref_col = lp[L_TSCALE] != TS_COLUMN
                xr[1] = col_d if ref_col else ast_d
                xr[2] = ast_d if ref_col else col_d
            xr[3] = v_f * z_d
            xr[4] = -v_f * tc_d / n
            xr[5] = 1.0
            if excited3:
                w3 = 1.0 + (ls[LS_SVF + 3 * S_DSW + 2] / (n * lp[L_R3_ACC])) ** 2
                _rls(ls, LS_T3, LS_P3, N3, xr, ay_f, w3 * slow * lp[L_SIG3] ** 2, ph)
                # a twist is >= 0: push clamps it there, so R3 must too, or K, s and the friction stay
                # fitted to the negative twist the filter never uses (docs/design/filters.md, "Bounds
                # and rate")
                _project_bound(ls, LS_T3, LS_P3, N3, 4, 0.0, ls[LS_T3] * CTB_MAX)
                ls[LS_N + 1] += 1.0
            # cascade: R1 uses s (and the friction) from R3, R2 uses t from R1 and K from R3; a
            # regression starts only once what it uses has CASCADE samples (no generic-value bias)
            cascade = 0.15 * lp[L_MIN_SAMPLES]
            # R1: Iz r_dot + lr m a_y / s = (L/t) T_true + c1   (c1 = lr F_wind/s + M_wind - ...)
            s = p[E.P_S]
            T_true = T_f - n * tfric * z_f - p[E.P_T0]
            xr[0] = T_true
            xr[1] = 1.0
            if ls[LS_N + 1] > cascade and excited:
                _rls(ls, LS_T1, LS_P1, N1, xr, iz * r_d + lr * m * ay_f / s, slow * lp[L_SIG1] ** 2, ph)
                ls[LS_N + 2] += 1.0
            # R2: (lf T_true/t - Iz r_dot)/lr = 2 Cr alpha_r + 2 Cr sigma D'/vx + c2 (a lag of D)
            #     (c2 = 2 Cr d_f - M_wind/lr)
            #     alpha_r = T_true/(2K) - D,  D = delta_f - L r/vx
            t_tr = p[E.P_K] / p[E.P_CF]
            dfl = (a_f - p[E.P_CTB] * tc_f - p[E.P_DSW]) / n
            dfl_d = (a_d - p[E.P_CTB] * tc_d) / n
            D = dfl - L * (r_f - p[E.P_BR]) / v_f
            xr[0] = T_true / (2.0 * p[E.P_K]) - D
            xr[1] = (dfl_d - L * r_d / v_f) / v_f
            xr[2] = 1.0
            if ls[LS_N + 2] > cascade:
                _rls(
                    ls, LS_T2, LS_P2, N2, xr, (lf * T_true / t_tr - iz * r_d) / lr, slow * lp[L_SIG2] ** 2, ph
                )
            if excited:
                ls[LS_N] += 1.0
        # gyro bias: a straight road returns to its heading. Anchors are instants of straight steady
        # driving (2 s mean yaw rate within 0.3 deg/s of the bias, steering still); between two anchors
        # 8-120 s apart the heading change int (r - b) dt is, on a straight road, the bias times the
        # window: a window whose heading changed by more than 10 deg (a curve, a turn) is discarded, any
        # other (lane changes, a slalom, an S-bend that returns, gusts) counts whole. The windows are
        # averaged (running average over the first L_B_TAU s of windows, then an EMA of that length).
        ls[LS_RLP] += tdec / 2.0 * (r_f - ls[LS_B] - ls[LS_RLP])
        if ls[LS_HT] >= 0.0:  # a window is open (it began at an anchor)
            ls[LS_HI] += tdec * (r_f - ls[LS_B])
            ls[LS_HT] += tdec
        steady = (
            abs(ls[LS_RLP]) < lp[L_B_GATE]
            and abs(r_f - ls[LS_B]) < 2.0 * lp[L_B_GATE]
            and abs(a_d) < 5.0 * DEG
        )
        ls[LS_AC] = ls[LS_AC] + tdec if steady else 0.0
        anchor = ls[LS_AC] >= 1.5  # steady for 1.5 s (not the zero crossing inside a lane change)
        if anchor and ls[LS_HT] < 0.0:
            # the first window opens here: one that began elsewhere (a log that starts in a lane
            # change, after a stop) would hold a heading change of its start, not the bias
            ls[LS_HI] = 0.0
            ls[LS_HT] = 0.0
        elif anchor and ls[LS_HT] >= 8.0:
            if abs(ls[LS_HI]) < 10.0 * DEG:
                tw = ls[LS_HT]
                ls[LS_TB] += tw
                ls[LS_B] += tw / min(ls[LS_TB] + 5.0, lp[L_B_TAU]) * (ls[LS_HI] / tw)
            ls[LS_HI] = 0.0
            ls[LS_HT] = 0.0
        elif anchor and ls[LS_HT] < 8.0 and abs(ls[LS_HI]) > 10.0 * DEG:
            ls[LS_HI] = 0.0
            ls[LS_HT] = 0.0
        elif ls[LS_HT] > 120.0:
            ls[LS_HT] = -1.0  # too long to tell a bias from a curve: wait for the next anchor
        # angle offset: an offset d (steering wheel) shows in the filter as a 'wind' through the rear
        # axle, (F, M) = o (s, -lr) with o = 2 Cr d / N; a real wind has (F, M) = w (1, x) with x its
        # centre of pressure (learned; prior the vehicle file's wind_cp_m). Split the wind estimate
        # into the two, only while it is small (a strong wind's CoP error would leak), and learn d from
        # the offset part as a fixed-gain average over L_D_TAU of such driving (slow: a steady
        # 10-minute wind moves d by a fraction of its leak only).
        fa, ma = kout[O_FW_WIND], kout[O_MW_WIND]
        if (
            ls[LS_N] > 0.5 * lp[L_MIN_SAMPLES]
            and abs(fa) < lp[L_D_GATE_F]
            and abs(ma) < lp[L_D_GATE_M]
            and abs(a_d) < 5.0 * DEG
        ):
            s = p[E.P_S]
            xc = ls[LS_CX]
            o = (xc * fa - ma) / (xc * s + lr)
            d_obs = p[E.P_DSW] + o * n / (2.0 * p[E.P_CR])
            ls[LS_TD] += tdec
            ls[LS_D] += tdec / min(ls[LS_TD] + 5.0, lp[L_D_TAU]) * (d_obs - ls[LS_D])

    elif istep % decim == 0:
        ls[LS_HT] = -1.0  # slow or (re)starting: the heading is not followed, a window would miss a turn

    if istep % int(lp[L_PUSH]) == 0 and lp[L_ENABLE] > 0.0:
        push(lp, ls, p)
        return True
    return False


@njit(cache=True, inline="always")
def scale_sd(ls):  # pragma: no cover - compiled
    """The posterior relative std of the learned torque factor theta_2 / theta_1 (R3, first order)."""
    a, b = ls[LS_T3 + 1], ls[LS_T3 + 2]
    if a <= 0.0 or b <= 0.0:
        return math.inf
    p11, p22, p12 = ls[LS_P3 + N3 + 1], ls[LS_P3 + 2 * N3 + 2], ls[LS_P3 + N3 + 2]
    v = p22 / (b * b) + p11 / (a * a) - 2.0 * p12 / (a * b)
    return math.sqrt(max(v, 0.0))


@njit(cache=True, inline="always")
def _lim(new, old, rate, lo, hi):  # pragma: no cover - compiled
    v = min(max(new, old * (1.0 - rate)), old * (1.0 + rate))
    return min(max(v, lo), hi)


@njit(cache=True, inline="always")
def push(lp, ls, p):  # pragma: no cover - compiled
    """Coefficients -> physical parameters, bounded and rate-limited, into the filter's p."""
    n = p[E.P_N]
    L = p[E.P_LF] + p[E.P_LR]
    rate = lp[L_RATE]
    s = ls[LS_T3 + 0]
    k = s / ls[LS_T3 + 1] if ls[LS_T3 + 1] > 0 else p[E.P_K]
    tfric = 2.0 * ls[LS_T3 + 3] / (ls[LS_T3 + 1] * n) if ls[LS_T3 + 1] > 0 else p[E.P_TFRIC]
    ctb = ls[LS_T3 + 4] / s
    # R1: t = L / theta1[0];  R2: Cr = theta2[0] / 2
    t = L / ls[LS_T1 + 0] if ls[LS_T1 + 0] > 0 else p[E.P_K] / p[E.P_CF]
    cr = 0.5 * ls[LS_T2 + 0]
    # excited samples behind the values (with a torque of unknown scale R3's own: the others wait for
    # the filter, which needs the scale)
    n_exc = ls[LS_N + 1] if lp[L_TSCALE] != TS_KNOWN else ls[LS_N]
    if n_exc < 0.15 * lp[L_MIN_SAMPLES]:
        # too few excited samples: the derived values are not yet meaningful; keep the prior tires
        k = p[E.P_K]
        t = p[E.P_K] / p[E.P_CF]
        cr = p[E.P_CR]
        s = p[E.P_S]
        tfric = p[E.P_TFRIC]
    p[E.P_S] = min(max(s, 0.95), 1.25)
    ts = lp[L_TSCALE]
    k_rate = rate
    if ts != TS_KNOWN:
        # the other torque's factor to the reference k = theta_2 / theta_1 (bounded 0.01..100, moving up
        # to 20 % per push until learned). With both scales unknown the overall scale is not
        # identifiable (it is K's): the aligning torque's unit is chosen so that K keeps its prior
        # (the vehicle file's), and both factors are learned in it, k_c = K theta_1 / s and
        # k_a = K theta_2 / s (their ratio is what the data determine); the friction is then
        # 2 K theta_3 / (s N) in that unit
        th1, th2 = ls[LS_T3 + 1], ls[LS_T3 + 2]
        if n_exc >= 0.15 * lp[L_MIN_SAMPLES] and th1 > 0 and th2 > 0:
            kr = 0.2 if ls[LS_STATE] != ST_LEARNED else rate
            if ts == TS_BOTH:
                p[E.P_KC] = _lim(p[E.P_K] * th1 / p[E.P_S], p[E.P_KC], kr, 1e-4, 1e4)
                p[E.P_KA] = _lim(p[E.P_K] * th2 / p[E.P_S], p[E.P_KA], kr, 1e-4, 1e4)
                tfric = 2.0 * p[E.P_K] * ls[LS_T3 + 3] / (p[E.P_S] * n)
            elif ts == TS_COLUMN:
                p[E.P_KC] = _lim(th2 / th1, p[E.P_KC], kr, 0.01, 100.0)
            else:
                p[E.P_KA] = _lim(th2 / th1, p[E.P_KA], kr, 0.01, 100.0)
        if ts == TS_BOTH:
            k = p[E.P_K]
        if ls[LS_STATE] != ST_LEARNED:
            k_rate = 0.2
    k_old = p[E.P_K]
    p[E.P_K] = _lim(k, p[E.P_K], k_rate, 2000.0, 20000.0)
    t_old = p[E.P_K] / p[E.P_CF]
    t_new = min(max(t, t_old * (1.0 - k_rate)), t_old * (1.0 + k_rate))
    t_new = min(max(t_new, 0.04), 0.25)
    if lp[L_R2_UPQ] > 0.0:  # R2's samples on the K and trail it had (lp[L_R2_UPQ], default_lp)
        dk = p[E.P_K] / k_old - 1.0
        dt = t_new / (k_old / p[E.P_CF]) - 1.0
        f = 1.0 + lp[L_R2_UPQ] * (dk * dk + dt * dt)
        for i in range(N2 * N2):
            ls[LS_P2 + i] *= f
    p[E.P_CF] = min(max(p[E.P_K] / t_new, 20000.0), 200000.0)
    p[E.P_CR] = _lim(cr, p[E.P_CR], rate, 20000.0, 200000.0)
    p[E.P_TFRIC] = min(max(tfric, 0.0), 2.0)
    p[E.P_CTB] = min(max(ctb, 0.0), CTB_MAX)
    p[E.P_BR] = min(max(ls[LS_B], -1.0 * DEG), 1.0 * DEG)
    p[E.P_DSW] = min(max(ls[LS_D], -5.0 * DEG), 5.0 * DEG)
    # learned state of the tire group: by the excited samples seen (a learned value stays learned)
    if ls[LS_STATE] == ST_LEARNED:
        pass
    elif lp[L_LEARNED_ST] > 0.0:
        # by the posterior relative std of the trail (R1's L/t) and of Cr (R2's 2 Cr), once R2 runs
        sd_t = math.sqrt(max(ls[LS_P1], 0.0)) / max(abs(ls[LS_T1]), 1e-9)
        sd_cr = math.sqrt(max(ls[LS_P2], 0.0)) / max(abs(ls[LS_T2]), 1e-9)
        r2_on = ls[LS_N + 2] > 0.15 * lp[L_MIN_SAMPLES]
        scale_ok = ts == TS_KNOWN or scale_sd(ls) < lp[L_SCALE_SD]
        if ls[LS_N] <= 0:
            ls[LS_STATE] = ST_NOT
        elif r2_on and scale_ok and sd_t < lp[L_LEARNED_ST] and sd_cr < lp[L_LEARNED_SCR]:
            ls[LS_STATE] = ST_LEARNED
        else:
            ls[LS_STATE] = ST_LEARNING
    elif ls[LS_N] <= 0:
        ls[LS_STATE] = ST_NOT
    elif ls[LS_N] < lp[L_MIN_SAMPLES] or (ts != TS_KNOWN and not scale_sd(ls) < lp[L_SCALE_SD]):
        ls[LS_STATE] = ST_LEARNING  # (a torque of unknown scale: its factor not yet known well enough)
    else:
        ls[LS_STATE] = ST_LEARNED


def learner_params(
    vehicle: Vehicle, angle_above_torsion_bar: bool, torque_scale: int = TS_KNOWN
) -> np.ndarray:
    """The learner's constants for a vehicle and a profile (``torque_scale``: :func:`torque_scale_mode`)."""
    lp = default_lp(torsion=angle_above_torsion_bar, enable=vehicle.learning.enabled > 0.0)
    lp[L_TSCALE] = torque_scale
    return lp


def torque_scale_mode(unknown: Collection[str]) -> int:
    """The ``TS_*`` mode for a profile whose inputs ``unknown`` (names) have an unknown scale."""
    col, ast = "column_torque" in unknown, "assist_torque" in unknown
    if col and ast:
        return TS_BOTH
    if col:
        return TS_COLUMN
    return TS_ASSIST if ast else TS_KNOWN


def torque_scales(p: np.ndarray, lp: np.ndarray, ls: np.ndarray) -> str:
    """What the learner holds about torques of unknown scale, one phrase (empty when both are in Nm):
    the learned factor, its posterior relative std, and the unit K and Fw/Mw are in."""
    ts = int(lp[L_TSCALE])
    if ts == TS_KNOWN:
        return ""
    sd = 100.0 * float(scale_sd(ls))
    sd_text = f"+-{sd:.0f} %" if math.isfinite(sd) else "not yet estimated"
    if ts == TS_COLUMN:
        return f"column torque {p[E.P_KC]:.4g} Nm per unit ({sd_text}); K, friction in Nm"
    if ts == TS_ASSIST:
        return f"assist torque {p[E.P_KA]:.4g} Nm per unit ({sd_text}); K, friction in Nm"
    return (
        f"assist torque {p[E.P_KA]:.4g} column units per unit ({sd_text}); K, friction in column units "
        "(their scale to Nm is not identifiable)"
    )


def tire_state(ls: np.ndarray) -> int:
    """The learned state of the tire group (``ST_*``)."""
    return int(ls[LS_STATE])
