"""The lateral filter (:mod:`lde.estimator.lateral`) in fixed point: the integer step an MDPS ECU without FPU
would run, its slow task, and the boundary (docs/design/firmware.md).

Three parts, each a compiled kernel:

- :func:`coef_set_kernel`, the **slow task** (float): from the parameter vector ``p`` (the learner
  writes the learned Cf, Cr, K, s and the input corrections into it every 128 steps) it computes
  every coefficient polynomial in ``w = 1/vx`` (:mod:`firmware_model.lat_coefs`) and every constant
  of the step (noises, P0, the corrections, the friction filter's constants) and quantises them
  into the integer **coefficient set** ``cs``. It runs at reset, after every push of the learner
  and after a learned-state file is loaded; the fast step uses the set it finds.
- :func:`step_kernel`, the **fast step** (integers only: no float, no true division; tested by
  ``tests/firmware/test_firmware_lateral.py``): the same step as :func:`lde.estimator.lateral.step_kernel`:
  validity, hold, the friction sign (a 10 Hz state-variable filter of the pinion angle and a tanh
  table), ``w = 1/vx`` by the normalised reciprocal, the coefficients, the three fresh-gated scalar
  updates (yaw rate, aligning torque, lateral acceleration; one reciprocal each), the outputs (the
  bank angle by an integer asin), the propagation ``X = Phi X + E delta``, ``P = Phi P Phi' + Qd``.
- :func:`quantise_kernel`, the **boundary**: SI floats to the input formats (and flags).

Units: the normalised ones of the paper's model: state i as ``X_i = x_i / 2**e_i`` in Q15.16, the
covariance as ``Pn_ij = P_ij / 2**(e_i + e_j)`` in Q15.16, each measurement scaled by a power of two
(the yaw rate by the state r's); the exponents and formats are generated offline
(:mod:`firmware_model.gen_lateral`). Arithmetic as :mod:`firmware_model.qformat`: stored values are
int32 (saturated and counted), sums of products in saturating int64 accumulators, right shifts
rounded HALF_UP. The kernels are written so that they also run interpreted on Python ints (numba
disabled, object arrays): ``tests/firmware/test_firmware_lateral.py`` requires the same integers, which
proves that no int64 intermediate wrapped.

The arithmetic helpers (``shr``, ``sat32``, ``mac``, the reciprocal, tanh and asin, the update and
the propagation) are inlined into the step (``inline="always"``): each takes the saturation counters
(an array), and as calls they cost numba's reference counting of it on every call; one hour of the
``fixed`` backend took 2.41 s of engine CPU with them as calls and 1.98 s inlined
(``scripts/engine_cpu.py``, side by side), for a longer first compile.

Array layouts (int64): ``tv`` the offline constants (``T_*``), ``ft`` the function tables (reciprocal
seeds, tanh, asin), ``cs`` the coefficient set (``CS_*``), state ``x`` (5), ``P`` (25, row-major),
``aux`` (``A_*``), ``sat`` (``S_*``), ``ws`` scratch (4, 16), ``iout`` (``IO_*``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from lde.estimator import lateral as E
from lde.status import DEGRADED, ESC_FAULT, LOW_SPEED, MDPS_FAULT, NOT_CONVERGED, VALID

from . import lat_coefs as LC
from .tables import LateralTables

INT32_MIN = -(2**31)
INT32_MAX = 2**31 - 1
INT64_MIN = -(2**63)
INT64_MAX = 2**63 - 1

# --- offline constants (tv) ----------------------------------------------------------------------
(T_F_STATE, T_F_COV, T_F_SPEED, T_F_STEER, T_F_TORQUE, T_F_RATE, T_F_Z, T_F_U, T_F_W, T_F_GAIN,
 T_F_PHI, T_F_E, T_F_H, T_F_D,
 T_E_B, T_E_R, T_E_FA, T_E_MA, T_E_FB, T_E_T, T_E_A,
 T_RECIP_BITS, T_RECIP_FRAC, T_TANH_UEXP, T_TANH_SEG,
 T_OFF_RECIP, T_OFF_TANH, T_OFF_ASIN, T_N_ASIN) = range(29)  # fmt: skip
N_T = 29
#: the exponents' slots in tv, in lat_coefs.X_* order
T_EX = (T_E_B, T_E_R, T_E_FA, T_E_MA, T_E_FB, T_E_T, T_E_A)

# --- the coefficient set (cs), written by the slow task -------------------------------------------
CS_POLY = 0  # per coefficient k, term j: raw at CS_POLY + 6k + 2j, right shift at + 1


def _slots(*r: int) -> tuple[np.int64, ...]:
    """Slot indices as int64 scalars: numba types a global int as a literal and compiles a helper
    taking it (``sat32``, ``_cmul``) once per literal (18 compilations); an np.int64 global is
    typed int64: one compilation each."""
    return tuple(np.int64(k) for k in range(*r))


(CS_NT, CS_NTF, CS_CTB, CS_IFW, CS_A1, CS_A2, CS_DT, CS_BANK, CS_NTA) = _slots(
    6 * LC.N_K, 6 * LC.N_K + 18, 2
)  # (raw, frac) pairs: N k_c/s_T, N T_fric/s_T, c_tb, 1/w_fric, dt W^2, 2 Z W dt, dt, 2**e_FB/(m g),
#    N k_a/s_T (k_c, k_a: the torque signals' factors to the aligning torque's unit, 1 in Nm)
_S = 6 * LC.N_K + 18
(CS_T0, CS_BR, CS_DSW, CS_RN_R, CS_RN_T, CS_RN_A) = _slots(_S, _S + 6)
CS_QD = _S + 6  # 5 slots
CS_P0 = _S + 11  # 5 slots
CS_VMIN = _S + 16
CS_CONV_NS = _S + 17
CS_NSAT = _S + 18  #: constants of this set that did not fit their format (saturated)
N_CS = _S + 19

# --- aux state ----------------------------------------------------------------------------------
(A_DELTA, A_T_ALIGN, A_Z, A_SVF_Y, A_SVF_YD, A_SVF_INIT, A_STEPS, A_HELD, A_CONV_START,
 A_UPDATES) = range(10)  # fmt: skip
N_AUX = 10
_NO_START = -1

# --- integer outputs (iout) -----------------------------------------------------------------------
IO_XB, IO_XR, IO_XFA, IO_XMA, IO_XFB, IO_FW, IO_TA, IO_BANK, IO_Z = range(9)
N_IO = 9

# --- saturation counters --------------------------------------------------------------------------
SAT_NAMES = (
    "in_speed",  # speed input outside Q7.24 (or not finite)
    "in_steer",  # steering-wheel angle outside Q4.27 (or not finite)
    "in_yaw",  # yaw rate outside its format (or not finite)
    "in_torque",  # a torque outside Q8.23, or their sum outside int32 (or not finite)
    "in_accel",  # lateral acceleration outside its format (finite: its update is skipped)
    "coef_set",  # a constant of the coefficient set outside its format (slow task)
    "coef",  # a scheduled coefficient
    "x_beta",
    "x_r",
    "x_fw",
    "x_mw",
    "x_fb",  # a state
    "cov",  # a covariance element, P h, or a Phi P product
    "innov",  # a measurement or an innovation
    "gain",  # a Kalman gain
    "acc64",  # an int64 accumulator
    "p_floor",  # a covariance diagonal below 0 floored to 0
    "s_nonpos",  # innovation variance <= 0: update skipped
    "output",  # T_align_hat or Fw = F_wind + F_bank
    "svf",  # the pinion-rate filter
)
(S_IN_SPEED, S_IN_STEER, S_IN_YAW, S_IN_TORQUE, S_IN_ACCEL, S_COEF_SET, S_COEF,
 S_X0, S_X1, S_X2, S_X3, S_X4, S_COV, S_INNOV, S_GAIN, S_ACC64, S_P_FLOOR, S_S_NONPOS,
 S_OUTPUT, S_SVF) = _slots(20)  # fmt: skip
N_SAT = 20

# --- input flags from the boundary -----------------------------------------------------------------
IN_SPEED_NAN = 1  #: speed not finite: LOW_SPEED, as the float step
IN_SPEED_SAT = 2
IN_STEER_BAD = 4
IN_YAW_BAD = 8
IN_TORQUE_BAD = 16
IN_ACCEL_NAN = 32  #: not finite: no accelerometer update (as the float step), not counted
IN_ACCEL_SAT = 64  #: finite but outside its format: no update, counted

# =============================================================================== arithmetic


@njit(cache=True, inline="always")
def shr(value, s):  # pragma: no cover - compiled
    """value * 2**-s rounded HALF_UP (s > 0); exact left shift for s <= 0."""
    if s > 0:
        return (value >> s) + ((value >> (s - 1)) & 1)
    return value << (-s)


@njit(cache=True, inline="always")
def sat32(sat, v, slot):  # pragma: no cover - compiled
    if v > INT32_MAX:
        sat[slot] += 1
        return INT32_MAX
    if v < INT32_MIN:
        sat[slot] += 1
        return INT32_MIN
    return v


@njit(cache=True, inline="always")
def add64(sat, a, b):  # pragma: no cover - compiled
    if b > 0 and a > INT64_MAX - b:
        sat[S_ACC64] += 1
        return INT64_MAX
    if b < 0 and a < INT64_MIN - b:
        sat[S_ACC64] += 1
        return INT64_MIN
    return a + b


@njit(cache=True, inline="always")
def mac(sat, acc, a, b):  # pragma: no cover - compiled
    """acc + a b (a, b int32 values: the product fits an int64) in a saturating int64."""
    return add64(sat, acc, a * b)


@njit(cache=True, inline="always")
def msb(a):  # pragma: no cover - compiled
    """floor(log2 a) of an integer a >= 1 (a count-leading-zeros instruction on an MCU)."""
    n = 0
    if a >= 1 << 32:
        a >>= 32
        n += 32
    if a >= 1 << 16:
        a >>= 16
        n += 16
    if a >= 1 << 8:
        a >>= 8
        n += 8
    if a >= 1 << 4:
        a >>= 4
        n += 4
    if a >= 1 << 2:
        a >>= 2
        n += 2
    if a >= 1 << 1:
        n += 1
    return n


@njit(cache=True, inline="always")
def recip(tv, ft, a):  # pragma: no cover - compiled
    """The normalised reciprocal of an integer 1 <= a < 2**62: (m, n) with 1/a = m 2**-(30 + n),
    m in Q1.30 (2**29 <= m <= 2**30). Normalise a to A in [1, 2) (Q1.30; rounded), a seed for A's
    interval from the table, two Newton steps y = y (2 - A y)."""
    f = tv[T_RECIP_FRAC]
    n = msb(a)
    if n <= f:
        am = a << (f - n)
    else:
        am = shr(a, n - f)
        if am >= 2 << f:  # rounded up to 2.0
            am >>= 1
            n += 1
    bits = tv[T_RECIP_BITS]
    y = ft[tv[T_OFF_RECIP] + ((am >> (f - bits)) & ((1 << bits) - 1))]
    two = 2 << f
    y = shr(y * (two - shr(am * y, f)), f)
    y = shr(y * (two - shr(am * y, f)), f)
    return y, n


@njit(cache=True, inline="always")
def tanh_q(tv, ft, u):  # pragma: no cover - compiled
    """tanh of u (Q F_U) in Q F_Z: the table with linear interpolation, odd; 1 beyond its end."""
    fu = tv[T_F_U]
    seg = tv[T_TANH_SEG]
    au = -u if u < 0 else u
    top = 1 << (fu + tv[T_TANH_UEXP])
    off = tv[T_OFF_TANH]
    if au >= top:
        z = ft[off + (1 << (tv[T_TANH_UEXP] + seg))]
    else:
        sh = fu - seg
        i = au >> sh
        fr = au - (i << sh)
        z = ft[off + i] + shr((ft[off + i + 1] - ft[off + i]) * fr, sh)
    return -z if u < 0 else z


@njit(cache=True, inline="always")
def isqrt(v):  # pragma: no cover - compiled
    """floor(sqrt(v)) of an integer v >= 0 (Newton from above)."""
    if v <= 0:
        return 0
    x = 1 << ((msb(v) >> 1) + 1)
    while True:
        y = (x + v // x) >> 1
        if y >= x:
            return x
        x = y


@njit(cache=True, inline="always")
def _asin_poly(tv, ft, a):  # pragma: no cover - compiled
    f = tv[T_F_Z]
    off = tv[T_OFF_ASIN]
    nt = tv[T_N_ASIN]
    a2 = shr(a * a, f)
    acc = ft[off + nt - 1]
    for k in range(nt - 2, -1, -1):
        acc = ft[off + k] + shr(acc * a2, f)
    return a + shr(a * shr(a2 * acc, f), f)


@njit(cache=True, inline="always")
def asin_q(tv, ft, x):  # pragma: no cover - compiled
    """asin of x (Q F_Z, clamped to [-1, 1]) in Q F_Z rad: the series for |x| <= 1/2, else
    pi/2 - 2 asin(sqrt((1 - |x|)/2)); odd."""
    f = tv[T_F_Z]
    one = 1 << f
    ax = -x if x < 0 else x
    if ax > one:
        ax = one
    if ax <= one >> 1:
        r = _asin_poly(tv, ft, ax)
    else:
        t = (one - ax) >> 1
        s = isqrt(t << f)
        r = ft[tv[T_OFF_ASIN] + tv[T_N_ASIN]] - 2 * _asin_poly(tv, ft, s)
    return -r if x < 0 else r


# =============================================================================== the slow task


#: the largest right shift a slow-task constant may need in the step (int64 operands)
MAX_SHIFT = 62


@njit(cache=True)
def _const(value, f_min):  # pragma: no cover - compiled
    """(raw, frac, saturated) of a float constant in an int32 with the most fractional bits that hold
    it, at least ``f_min`` (so that its use never needs a left shift; then it may saturate) and at
    most ``f_min + MAX_SHIFT`` (its use never shifts an int64 by more than 62 bits: a smaller value
    loses its low bits, down to 0, which is below half an LSB of the result)."""
    if value == 0.0 or not math.isfinite(value):
        return 0, f_min, not math.isfinite(value)
    f = 31 - math.frexp(abs(value))[1]  # |value| < 2**(31 - f)
    if f < f_min:
        f = f_min
    if f > f_min + MAX_SHIFT:
        f = f_min + MAX_SHIFT
    r = int(math.floor(abs(value) * 2.0**f + 0.5))
    if r == 0:
        return 0, f_min, False
    if r > INT32_MAX and f > f_min:
        f -= 1
        r = int(math.floor(abs(value) * 2.0**f + 0.5))
    hit = r > INT32_MAX
    if hit:
        r = INT32_MAX
    return (-r if value < 0 else r), f, hit


@njit(cache=True)
def _fixed(value, f):  # pragma: no cover - compiled
    """(raw, saturated) of a float in the int32 format with ``f`` fractional bits."""
    if not math.isfinite(value):
        return 0, True
    a = abs(value) * 2.0**f
    if a >= 2147483647.5:
        return (INT32_MAX if value > 0 else INT32_MIN), True
    r = int(math.floor(a + 0.5))
    return (-r if value < 0 else r), False


@njit(cache=True)
def coef_set_kernel(p, tv, cs):  # pragma: no cover - compiled
    """The slow task: the coefficient set ``cs`` (``CS_*``) from the parameter vector ``p`` (float).

    Polynomial term j of coefficient k is ``c_kj w^j``; the step has w and w^2 both in Q F_W
    (``fpow_j`` = 0, F_W, F_W fractional bits for j = 0, 1, 2): the term's raw gets at least
    ``f_group - fpow_j`` fractional bits, so the fast step only ever shifts it right, by
    ``frac + fpow_j - f_group``. Every other constant is (raw, frac) for the product it enters.
    Constants that do not fit their int32 are saturated and counted in ``cs[CS_NSAT]`` (while it is
    non-zero the step is DEGRADED); within the generator's parameter box this cannot happen."""
    ex = np.zeros(LC.N_EX, np.int64)
    for i in range(LC.N_EX):
        ex[i] = tv[T_EX[i]]
    c = np.zeros((LC.N_K, 3))
    LC.coef_polys(p, ex, c)
    nsat = 0
    fw = tv[T_F_W]
    groups = (tv[T_F_PHI], tv[T_F_E], tv[T_F_H], tv[T_F_D])
    for k in range(LC.N_K):
        fg = groups[LC.COEF_GROUP[k]]
        for j in range(3):
            fpow = 0 if j == 0 else fw
            raw, f, hit = _const(c[k, j], fg - fpow)
            nsat += hit
            cs[CS_POLY + 6 * k + 2 * j] = raw
            cs[CS_POLY + 6 * k + 2 * j + 1] = f + fpow - fg
    fs, fst, fz, fr = tv[T_F_STATE], tv[T_F_STEER], tv[T_F_Z], tv[T_F_RATE]
    s_t = 2.0 ** tv[T_E_T]
    n, dt = p[E.P_N], p[E.P_DT]
    consts = (
        (CS_NT, n * p[E.P_KC] / s_t, fs - tv[T_F_TORQUE]),
        (CS_NTF, n * p[E.P_TFRIC] / s_t, fs - fz),
        (CS_CTB, p[E.P_CTB], fst - tv[T_F_TORQUE]),
        (CS_IFW, 1.0 / p[E.P_FW], tv[T_F_U] - fr),
        (CS_A1, dt * E.SVF_W * E.SVF_W, fr - fst),
        (CS_A2, 2.0 * E.SVF_Z * E.SVF_W * dt, 0),
        (CS_DT, dt, fst - fr),
        (CS_BANK, 2.0 ** tv[T_E_FB] / (p[E.P_M] * p[E.P_G]), fz - fs),
        (CS_NTA, n * p[E.P_KA] / s_t, fs - tv[T_F_TORQUE]),
    )
    for slot, value, f_min in consts:
        raw, f, hit = _const(value, f_min)
        nsat += hit
        cs[slot] = raw
        cs[slot + 1] = f
    fixed = (
        (CS_T0, p[E.P_T0] / s_t, fs),
        (CS_BR, p[E.P_BR] / 2.0 ** tv[T_E_R], fs),
        (CS_DSW, p[E.P_DSW], fst),
        (CS_RN_R, p[E.P_RR] / 4.0 ** tv[T_E_R], tv[T_F_COV]),
        (CS_RN_T, p[E.P_RT] / s_t**2, tv[T_F_COV]),
        (CS_RN_A, p[E.P_RA] / 4.0 ** tv[T_E_A], tv[T_F_COV]),
        (CS_VMIN, p[E.P_VMIN], tv[T_F_SPEED]),
    )
    for slot, value, f in fixed:
        raw, hit = _fixed(value, f)
        nsat += hit
        cs[slot] = raw
    qs = (p[E.P_QB], p[E.P_QR], p[E.P_QFA], p[E.P_QMA], p[E.P_QFB])
    p0 = (p[E.P_P0B], p[E.P_P0R], p[E.P_P0FA], p[E.P_P0MA], p[E.P_P0FB])
    for i in range(5):
        sc = 4.0 ** tv[T_EX[i]]
        raw, hit = _fixed(qs[i] * dt / sc, tv[T_F_COV])
        nsat += hit
        cs[CS_QD + i] = raw
        raw, hit = _fixed(p0[i] * p0[i] / sc, tv[T_F_COV])
        nsat += hit
        cs[CS_P0 + i] = raw
    cs[CS_CONV_NS] = int(math.floor(p[E.P_CONV] * 1e9 + 0.5))
    cs[CS_NSAT] = nsat


# =============================================================================== the fast step


@njit(cache=True)
def _set_p0(cs, P):  # pragma: no cover - compiled
    for k in range(25):
        P[k] = 0
    for i in range(5):
        P[6 * i] = cs[CS_P0 + i]


@njit(cache=True)
def reset_kernel(cs, x, P, aux, sat):  # pragma: no cover - compiled
    """x = 0, P = P0, held (the first usable step starts the filter); counters cleared."""
    for i in range(5):
        x[i] = 0
    _set_p0(cs, P)
    for k in range(N_AUX):
        aux[k] = 0
    aux[A_HELD] = 1
    aux[A_CONV_START] = _NO_START
    for k in range(sat.shape[0]):
        sat[k] = 0


@njit(cache=True, inline="always")
def _coef(cs, sat, k, w, w2):  # pragma: no cover - compiled
    """Coefficient k at w (Q F_W) and w2 = w^2 (Q F_W), in its group's format."""
    o = CS_POLY + 6 * k
    acc = 0
    if cs[o] != 0:
        acc = shr(cs[o], cs[o + 1])
    if cs[o + 2] != 0:
        acc = add64(sat, acc, shr(cs[o + 2] * w, cs[o + 3]))
    if cs[o + 4] != 0:
        acc = add64(sat, acc, shr(cs[o + 4] * w2, cs[o + 5]))
    return sat32(sat, acc, S_COEF)


@njit(cache=True, inline="always")
def _cmul(cs, slot, v, f_in, f_out):  # pragma: no cover - compiled
    """A slow-task constant (raw, frac) times v (Q f_in), in Q f_out (int64, not saturated)."""
    return shr(cs[slot] * v, cs[slot + 1] + f_in - f_out)


@njit(cache=True, inline="always")
def _update(tv, ft, x, P, sat, h, unit, z, d, r, ph, g):  # pragma: no cover - compiled
    """One scalar measurement update in normalised units: ph = Pn h (h in Q F_H, or the unit vector
    of r when ``unit``), s = h ph + r, innovation z - h X - d, gains ph/s by one reciprocal,
    X += g innov, Pn -= g ph' (upper triangle, mirrored; a negative diagonal is floored)."""
    fh = tv[T_F_H]
    fk = tv[T_F_GAIN]
    if unit:
        for i in range(5):
            ph[i] = P[5 * i + 1]
        s = add64(sat, ph[1], r)
        hx = x[1]
    else:
        for i in range(5):
            acc = 0
            for j in range(5):
                if h[j] != 0:
                    acc = mac(sat, acc, P[5 * i + j], h[j])
            ph[i] = sat32(sat, shr(acc, fh), S_COV)
        acc = 0
        hxa = 0
        for j in range(5):
            if h[j] != 0:
                acc = mac(sat, acc, h[j], ph[j])
                hxa = mac(sat, hxa, h[j], x[j])
        s = add64(sat, shr(acc, fh), r)
        hx = shr(hxa, fh)
    if s <= 0:
        sat[S_S_NONPOS] += 1
        return
    innov = sat32(sat, z - hx - d, S_INNOV)
    m, n = recip(tv, ft, s)
    sh = tv[T_RECIP_FRAC] + n - fk  # ph / s = ph m 2**-(30 + n), the gain in Q F_GAIN
    for i in range(5):
        g[i] = sat32(sat, shr(ph[i] * m, sh), S_GAIN)
    for i in range(5):
        x[i] = sat32(sat, x[i] + shr(g[i] * innov, fk), S_X0 + i)
    for i in range(5):
        for j in range(i, 5):
            v = sat32(sat, P[5 * i + j] - shr(g[i] * ph[j], fk), S_COV)
            P[5 * i + j] = v
            P[5 * j + i] = v
        if P[6 * i] < 0:
            P[6 * i] = 0
            sat[S_P_FLOOR] += 1


@njit(cache=True, inline="always")
def _predict(tv, cs, x, P, sat, c, delta, t):  # pragma: no cover - compiled
    """X = Phi_n X + E_n delta, Pn = Phi_n Pn Phi_n' + Qd_n (rows and columns 0, 1 change)."""
    fp = tv[T_F_PHI]
    sh_e = tv[T_F_E] + tv[T_F_STEER] - tv[T_F_STATE]
    f00, f01, f02 = c[LC.K_F00], c[LC.K_F01], c[LC.K_F02]
    f10, f11, f13 = c[LC.K_F10], c[LC.K_F11], c[LC.K_F13]
    x0, x1, x2, x3, x4 = x[0], x[1], x[2], x[3], x[4]
    acc = mac(sat, mac(sat, mac(sat, mac(sat, 0, f00, x0), f01, x1), f02, x2), f02, x4)
    x[0] = sat32(sat, shr(acc, fp) + shr(c[LC.K_E0] * delta, sh_e), S_X0)
    acc = mac(sat, mac(sat, mac(sat, 0, f10, x0), f11, x1), f13, x3)
    x[1] = sat32(sat, shr(acc, fp) + shr(c[LC.K_E1] * delta, sh_e), S_X1)
    # T = Phi_n Pn: rows 0 and 1 (t[0:5], t[5:10])
    for j in range(5):
        acc = mac(sat, mac(sat, mac(sat, 0, f00, P[j]), f01, P[5 + j]), f02, P[10 + j])
        acc = mac(sat, acc, f02, P[20 + j])
        t[j] = sat32(sat, shr(acc, fp), S_COV)
        acc = mac(sat, mac(sat, mac(sat, 0, f10, P[j]), f11, P[5 + j]), f13, P[15 + j])
        t[5 + j] = sat32(sat, shr(acc, fp), S_COV)
    for j in range(5):
        P[j] = t[j]
        P[5 + j] = t[5 + j]
    # Pn = T Phi_n': columns 0 and 1 (upper triangle, mirrored), then + Qd on the diagonal
    for i in range(5):
        acc = mac(sat, mac(sat, mac(sat, 0, P[5 * i], f00), P[5 * i + 1], f01), P[5 * i + 2], f02)
        acc = mac(sat, acc, P[5 * i + 4], f02)
        t[i] = sat32(sat, shr(acc, fp), S_COV)
        acc = mac(sat, mac(sat, mac(sat, 0, P[5 * i], f10), P[5 * i + 1], f11), P[5 * i + 3], f13)
        t[5 + i] = sat32(sat, shr(acc, fp), S_COV)
    for i in range(5):  # column and row 0 (P[0, 1] = P[1, 0] = (T Phi_n')[1, 0])
        P[5 * i] = t[i]
        P[i] = t[i]
    for i in range(1, 5):  # column and row 1
        P[5 * i + 1] = t[5 + i]
        P[5 + i] = t[5 + i]
    for i in range(5):
        P[6 * i] = sat32(sat, P[6 * i] + cs[CS_QD + i], S_COV)


@njit(cache=True, inline="always")
def _friction_sign(tv, ft, cs, aux, sat, pinion):  # pragma: no cover - compiled
    """z = tanh(pinion_rate / w_fric) in Q F_Z, the pinion rate (Q F_RATE) from the 10 Hz
    state-variable filter of the pinion angle (Q F_STEER; semi-implicit Euler, as the float step):
    yd += dt W^2 (u - y) - 2 Z W dt yd;  y += dt yd."""
    fst, fr = tv[T_F_STEER], tv[T_F_RATE]
    if aux[A_SVF_INIT] == 0:
        aux[A_SVF_Y] = pinion
        aux[A_SVF_YD] = 0
        aux[A_SVF_INIT] = 1
    y, yd = aux[A_SVF_Y], aux[A_SVF_YD]
    e = sat32(sat, pinion - y, S_SVF)
    yd = sat32(sat, yd + _cmul(cs, CS_A1, e, fst, fr) - _cmul(cs, CS_A2, yd, fr, fr), S_SVF)
    y = sat32(sat, y + _cmul(cs, CS_DT, yd, fr, fst), S_SVF)
    aux[A_SVF_Y] = y
    aux[A_SVF_YD] = yd
    u = _cmul(cs, CS_IFW, yd, fr, tv[T_F_U])
    lim = 1 << (tv[T_F_U] + tv[T_TANH_UEXP])
    if u > lim:  # tanh is 1 there: no saturation, a clamp
        u = lim
    elif u < -lim:
        u = -lim
    return tanh_q(tv, ft, u)


@njit(cache=True, inline="always")
def _sat_total(sat):  # pragma: no cover - compiled
    n = 0
    for k in range(sat.shape[0]):
        n += sat[k]
    return n


@njit(cache=True, inline="always")
def _outputs(tv, ft, cs, x, aux, sat, iout):  # pragma: no cover - compiled
    for i in range(5):
        iout[i] = x[i]
    iout[IO_FW] = sat32(sat, x[2] + x[4], S_OUTPUT)  # F_wind and F_bank share one scale
    iout[IO_TA] = aux[A_T_ALIGN]
    sb = _cmul(cs, CS_BANK, x[4], tv[T_F_STATE], tv[T_F_Z])  # sin(phi_bank) = F_bank / (m g)
    one = 1 << tv[T_F_Z]
    if sb > one:
        sb = one
    elif sb < -one:
        sb = -one
    iout[IO_BANK] = asin_q(tv, ft, sb)
    iout[IO_Z] = aux[A_Z]


@njit(cache=True)
def step_kernel(
    tv, ft, cs, x, P, aux, sat, ws, t_ns, v, steer, yaw, tcol, tas, ay, flags,
    fresh_r, fresh_t, fresh_a, mdps_ok, esc_ok, iout,
):  # fmt: skip  # pragma: no cover - compiled
    """One integer step, the twin of :func:`lde.estimator.lateral.step_kernel` (module docstring); inputs
    raw (:func:`quantise_kernel`), fills ``iout`` (``IO_*``), returns the status bits. ``ws``: int64
    scratch (4, 16). A saturation in this step, or a saturated coefficient set, sets DEGRADED."""
    aux[A_STEPS] += 1
    # input faults are counted and reported by their group's fault bit, as the float step reports a
    # non-finite input; a saturated speed or acceleration (used / skipped where the float step uses
    # the true value) also degrades the step
    if flags & (IN_SPEED_NAN | IN_SPEED_SAT):
        sat[S_IN_SPEED] += 1
    if flags & IN_STEER_BAD:
        sat[S_IN_STEER] += 1
    if flags & IN_YAW_BAD:
        sat[S_IN_YAW] += 1
    if flags & IN_TORQUE_BAD:
        sat[S_IN_TORQUE] += 1
    if flags & IN_ACCEL_SAT:
        sat[S_IN_ACCEL] += 1
    sat_before = _sat_total(sat)
    status = DEGRADED if flags & (IN_SPEED_SAT | IN_ACCEL_SAT) else 0
    esc_valid = esc_ok and (flags & IN_YAW_BAD) == 0
    mdps_valid = mdps_ok and (flags & (IN_STEER_BAD | IN_TORQUE_BAD)) == 0
    if not esc_valid:
        status |= ESC_FAULT
    if not mdps_valid:
        status |= MDPS_FAULT | DEGRADED
    speed_ok = (flags & IN_SPEED_NAN) == 0 and v >= cs[CS_VMIN]
    if esc_valid and not speed_ok:
        status |= LOW_SPEED
    if not (esc_valid and speed_ok):
        aux[A_HELD] = 1
        aux[A_CONV_START] = _NO_START
        _outputs(tv, ft, cs, x, aux, sat, iout)
        if _sat_total(sat) != sat_before or cs[CS_NSAT] != 0:
            status |= DEGRADED
        return status | NOT_CONVERGED
    if aux[A_HELD] == 1:
        _set_p0(cs, P)  # (re)start after a reset or a hold: keep X, re-initialise Pn
        aux[A_HELD] = 0

    fst, fs = tv[T_F_STEER], tv[T_F_STATE]
    # inputs after the learned corrections
    if mdps_valid:
        pinion = sat32(sat, steer - _cmul(cs, CS_CTB, tcol, tv[T_F_TORQUE], fst), S_SVF)
        aux[A_Z] = _friction_sign(tv, ft, cs, aux, sat, pinion)
        aux[A_DELTA] = sat32(sat, pinion - cs[CS_DSW], S_SVF)
    zf = aux[A_Z]
    delta = aux[A_DELTA]
    # w = 1/vx (Q F_W) by the normalised reciprocal, and w^2
    m, n = recip(tv, ft, v)
    w = shr(m, tv[T_RECIP_FRAC] + n - tv[T_F_W] - tv[T_F_SPEED])
    w2 = shr(w * w, tv[T_F_W])
    c = ws[0]
    for k in range(LC.N_K):
        c[k] = _coef(cs, sat, k, w, w2)
    h, ph, g = ws[1, 0:5], ws[2, 0:5], ws[3, 0:5]
    fd = tv[T_F_D] + fst - fs

    # --- updates (sequential, scalar), each with a fresh sample only
    if fresh_r:
        z = sat32(sat, yaw - cs[CS_BR], S_INNOV)
        # bool(...) and int(0), not literals (hence the noqa): numba would compile _update once per
        # literal argument set (about 0.5 s each on a cold start)
        _update(tv, ft, x, P, sat, h, bool(True), z, int(0), cs[CS_RN_R], ph, g)  # noqa: UP018
    if fresh_t and mdps_valid:
        # N (k_c T_col + k_a T_ast) - N T_fric z - T_0 = 2K (delta_f - beta - lf r / vx), scaled by
        # 2**-e_T; with equal factors (both torques in Nm) one product of the sum: one rounding
        if cs[CS_NTA] == cs[CS_NT] and cs[CS_NTA + 1] == cs[CS_NT + 1]:
            tsum = sat32(sat, tcol + tas, S_IN_TORQUE)
            nt = _cmul(cs, CS_NT, tsum, tv[T_F_TORQUE], fs)
        else:
            nt = _cmul(cs, CS_NT, tcol, tv[T_F_TORQUE], fs) + _cmul(cs, CS_NTA, tas, tv[T_F_TORQUE], fs)
        fz = tv[T_F_Z]
        zt = nt - _cmul(cs, CS_NTF, zf, fz, fs) - cs[CS_T0]
        zt = sat32(sat, zt, S_INNOV)
        one = 1 << fz
        fu = sat32(sat, _cmul(cs, CS_NTF, one - shr(zf * zf, fz), fz, fs), S_INNOV)
        r = add64(sat, cs[CS_RN_T], shr(fu * fu, tv[T_F_COV]))  # sticking: +-T_fric anywhere
        for i in range(5):
            h[i] = 0
        h[0], h[1] = c[LC.K_HT0], c[LC.K_HT1]
        _update(tv, ft, x, P, sat, h, bool(False), zt, shr(c[LC.K_DT] * delta, fd), r, ph, g)  # noqa: UP018
    if fresh_a and (flags & (IN_ACCEL_NAN | IN_ACCEL_SAT)) == 0:
        # a_y = (s (2 Cf alpha_f + 2 Cr alpha_r) + F_wind) / m, scaled by 2**-e_A
        for i in range(5):
            h[i] = 0
        h[0], h[1], h[2] = c[LC.K_HA0], c[LC.K_HA1], c[LC.K_HA2]
        _update(tv, ft, x, P, sat, h, bool(False), ay, shr(c[LC.K_DA] * delta, fd), cs[CS_RN_A], ph, g)  # noqa: UP018

    # T_align_hat = 2K (delta_f - beta - lf r / vx): the aligning-torque row at the a-posteriori X
    acc = mac(sat, mac(sat, 0, c[LC.K_HT0], x[0]), c[LC.K_HT1], x[1])
    aux[A_T_ALIGN] = sat32(sat, shr(acc, tv[T_F_H]) + shr(c[LC.K_DT] * delta, fd), S_OUTPUT)
    aux[A_UPDATES] += 1
    _outputs(tv, ft, cs, x, aux, sat, iout)

    _predict(tv, cs, x, P, sat, c, delta, ws[3])

    # convergence timer: runs while both the MDPS and the ESC groups are used
    if not mdps_valid:
        aux[A_CONV_START] = _NO_START
    elif aux[A_CONV_START] == _NO_START:
        aux[A_CONV_START] = t_ns
    if aux[A_CONV_START] == _NO_START or t_ns - aux[A_CONV_START] < cs[CS_CONV_NS]:
        status |= NOT_CONVERGED
    if _sat_total(sat) != sat_before or cs[CS_NSAT] != 0:
        status |= DEGRADED
    if status == 0:
        status = VALID
    return status


# =============================================================================== the boundary


@njit(cache=True)
def quantise(value, f):  # pragma: no cover - compiled
    """(raw, bad) of a float in the int32 format with ``f`` fractional bits (bad: not finite or
    saturated)."""
    if not math.isfinite(value):
        return 0, True
    a = abs(value) * 2.0**f
    if a >= 2147483647.5:
        return (INT32_MAX if value > 0 else INT32_MIN), True
    r = int(math.floor(a + 0.5))
    return (-r if value < 0 else r), False


@njit(cache=True)
def quantise_kernel(tv, speed, steer, yaw, tcol, tas, ay):  # pragma: no cover - compiled
    """SI inputs to (v, steer, yaw, tcol, tas, ay, flags) raw: speed Q F_SPEED, steering-wheel angle
    Q F_STEER, yaw rate and lateral acceleration in their normalised Q15.16, torques Q F_TORQUE."""
    flags = 0
    if math.isfinite(speed):
        v, bad = quantise(speed, tv[T_F_SPEED])
        if bad:
            flags |= IN_SPEED_SAT
    else:
        v = 0
        flags |= IN_SPEED_NAN
    s, bad = quantise(steer, tv[T_F_STEER])
    if bad:
        flags |= IN_STEER_BAD
    y, bad = quantise(yaw, tv[T_F_STATE] - tv[T_E_R])
    if bad:
        flags |= IN_YAW_BAD
    c, bad1 = quantise(tcol, tv[T_F_TORQUE])
    a, bad2 = quantise(tas, tv[T_F_TORQUE])
    if bad1 or bad2:
        flags |= IN_TORQUE_BAD
    if math.isfinite(ay):
        q, bad = quantise(ay, tv[T_F_STATE] - tv[T_E_A])
        if bad:
            flags |= IN_ACCEL_SAT
    else:
        q = 0
        flags |= IN_ACCEL_NAN
    return v, s, y, c, a, q, flags


# =============================================================================== Python side


def tables_vectors(lt: LateralTables) -> tuple[np.ndarray, np.ndarray]:
    """(tv, ft): the offline constants (``T_*``) and the function tables of ``lt`` as int64 arrays."""
    f, g = lt.formats, lt.coef_groups
    tv = np.zeros(N_T, np.int64)
    tv[T_F_STATE], tv[T_F_COV], tv[T_F_SPEED], tv[T_F_STEER] = f["state"], f["cov"], f["speed"], f["steer"]
    tv[T_F_TORQUE], tv[T_F_RATE], tv[T_F_Z], tv[T_F_U] = f["torque"], f["rate"], f["z"], f["u"]
    tv[T_F_W], tv[T_F_GAIN] = f["w"], f["gain"]
    tv[T_F_PHI], tv[T_F_E], tv[T_F_H], tv[T_F_D] = g["phi"], g["e"], g["h"], g["d"]
    ex = (*lt.sigma_exp, lt.sigma_t_exp, lt.sigma_a_exp)
    for slot, e in zip(T_EX, ex, strict=True):
        tv[slot] = e
    tv[T_RECIP_BITS], tv[T_RECIP_FRAC] = lt.recip_bits, lt.recip_frac
    tv[T_TANH_UEXP], tv[T_TANH_SEG] = lt.tanh_u_exp, lt.tanh_seg_bits
    ft = np.array([*lt.recip_seeds, *lt.tanh_table, *lt.asin_coefs, lt.asin_half_pi], np.int64)
    tv[T_OFF_RECIP] = 0
    tv[T_OFF_TANH] = len(lt.recip_seeds)
    tv[T_OFF_ASIN] = len(lt.recip_seeds) + len(lt.tanh_table)
    tv[T_N_ASIN] = len(lt.asin_coefs)
    return tv, ft


def to_si(lt: LateralTables, iout: np.ndarray) -> tuple[float, ...]:
    """(beta, r, F_wind, M_wind, F_bank, Fw, T_align, bank, z) in SI from raw ``iout`` (exact
    power-of-two scalings)."""
    ls = [lt.state_lsb(i) for i in range(5)]
    fz = math.ldexp(1.0, -lt.formats["z"])
    return (
        *(float(iout[i]) * ls[i] for i in range(5)),
        float(iout[IO_FW]) * ls[2],
        float(iout[IO_TA]) * lt.t_align_lsb(),
        float(iout[IO_BANK]) * fz,
        float(iout[IO_Z]) * fz,
    )


def run_drive(
    lt: LateralTables,
    p: np.ndarray,
    inputs: tuple[np.ndarray, ...],
    *,
    python_ints: bool = False,
) -> dict[str, np.ndarray]:
    """The integer step over a drive outside the product loop (tests and benchmarks): ``inputs`` are
    (t_ns, speed, steer, yaw, tcol, tas, ay, fresh_r, fresh_t, fresh_a, mdps_ok, esc_ok) arrays in SI.
    Returns every step's ``iout`` (n, N_IO), status (n), the final x, P, aux, sat and the coefficient
    set. ``python_ints``: the integer arrays as object arrays of Python ints (with numba disabled,
    ``NUMBA_DISABLE_JIT=1``, this runs the same kernels in unbounded integers: the results equal the
    int64 run exactly when no intermediate wrapped)."""
    tv, ft = tables_vectors(lt)
    n = len(inputs[0])

    def arr(shape: int | tuple[int, int]) -> np.ndarray:
        a = np.zeros(shape, np.int64)
        return a.astype(object) * 0 if python_ints else a

    if python_ints:
        tv, ft = (np.array([int(v) for v in a], dtype=object) for a in (tv, ft))
    cs, x, P, aux, sat = arr(N_CS), arr(5), arr(25), arr(N_AUX), arr(N_SAT)
    ws, iout = arr((4, 16)), arr(N_IO)
    coef_set_kernel(np.asarray(p, np.float64), tv, cs)
    reset_kernel(cs, x, P, aux, sat)
    outs = np.zeros((n, N_IO), dtype=object if python_ints else np.int64)
    status = np.zeros(n, np.int64)
    t_ns, speed, steer, yaw, tcol, tas, ay, fr, ftq, fa, mdps, esc = inputs
    for k in range(n):
        v, s, y, c, a, q, flags = quantise_kernel(
            tv, float(speed[k]), float(steer[k]), float(yaw[k]), float(tcol[k]), float(tas[k]), float(ay[k])
        )
        status[k] = step_kernel(
            tv, ft, cs, x, P, aux, sat, ws, int(t_ns[k]), v, s, y, c, a, q, flags,
            bool(fr[k]), bool(ftq[k]), bool(fa[k]), bool(mdps[k]), bool(esc[k]), iout,
        )  # fmt: skip
        outs[k] = iout
    return {"iout": outs, "status": status, "x": x, "P": P, "aux": aux, "sat": sat, "cs": cs}
