"""Identify the linear-equivalent tire parameters from a drive without disturbance (issue 6, item 4).

Inputs are the estimator's SI inputs on the step grid (:class:`DriveData`): steering-wheel angle
and rate, yaw rate, lateral acceleration, speed, column and assist torque. The body parameters
(m, Iz, lf, lr, N) come from a base vehicle file; identified are the per-tire cornering
stiffnesses ``Cf``, ``Cr``, the aligning-torque rate ``K``, and — because they bias the estimate
exactly like a disturbance would — the steering Coulomb friction, a steering-angle offset, a
yaw-rate bias (the mean measured yaw rate: the drive must end on its initial heading, as a lane
change and back on a straight road does) and an aligning-torque (torque-sensor) offset.

Method (least squares on the bicycle-model equations, no disturbance: Fw = Mw = 0). With
``a_y`` the measured lateral acceleration and ``r_dot`` the derivative of the yaw rate, eqs. (7)-(8)
give the per-tire axle forces from measurements and body parameters only:

    2 F_f = (lr m a_y + Iz r_dot) / L          2 F_r = (lf m a_y - Iz r_dot) / L          (a)

Eq. (9): ``alpha_f - alpha_r = delta_f - L r / vx`` (beta cancels). The steering-angle sensor sits
above the torsion bar (the column torque sensor), which twists by ``T_column c_tb`` (``c_tb`` the
torsion compliance [rad/Nm]): the road wheels are at ``(delta_sw - c_tb T_column) / N``, 1-2 deg of
steering wheel less at a 3 Nm hold. With ``F = C alpha`` and a road-wheel angle offset ``d0``
(measured delta_f = true delta_f + d0):

    delta_sw/N - L r / vx = F_f (1/Cf) - F_r (1/Cr) + (T_column/N) c_tb + d0               (b)

linear in the compliances (1/Cf, 1/Cr, c_tb) and d0. Transients (r_dot != 0) separate Cf from Cr; a
steady-state-only drive gives only the understeer gradient (the fit reports its conditioning).
``c_tb`` is separable from 1/Cf only through the non-linear boost curve (the column torque is not
proportional to the aligning torque); where it is not (condition number above :data:`TORSION_MAX_COND`),
the column is taken as rigid (``c_tb = 0``; ``Calibration.torsion_identified`` False) and the twist
ends up in an effective, lower Cf.
Eq. (12) with alpha_f = F_f / Cf, plus the column friction the paper neglects (eq. 11):

    N (T_column + T_assist) = (K/Cf) 2 F_f + N T_fric S(tanh(delta_sw_dot / w)) + T_0       (c)

linear in the trail ``K/Cf`` [m], the Coulomb friction ``T_fric`` [Nm at the column] and the
offset ``T_0`` [Nm]; ``K = Cf (K/Cf)``. ``w`` (:data:`FRICTION_RATE_WIDTH`) smooths the sign and
``S`` is the low-pass below, applied to the regressor as to the torque it explains.

The lateral accelerometer rolls with the body and reads ``s a_y`` with ``s = 1 + g k_roll`` (about
1.06 for a sedan's 0.0065 rad per m/s^2): forces from (a) come out s times too large. The kinematics
give s and K without that error: with ``alpha_f = T_align,corr / (2K)`` (friction and offset of
(c) removed) and the road-wheel angle corrected for twist and offset,

    beta = delta_f - lf r / vx - alpha_f,     a_y,meas = s vx (beta_dot + r)
         = s vx (d/dt(delta_f - lf r/vx) + r) - (s / K) vx T_align,corr_dot / 2               (d)

linear in (s, s/K). The fit runs (a)-(c), then (d), then (a)-(c) again on ``a_y / s``; it takes
``Cf = K / trail`` (the aligning torque and the kinematics pin Cf better than (b), whose
regressors carry the sensors' sample-and-hold delays) and solves (b) once more for Cr, c_tb and d0
with that Cf.

All signals go through the same zero-phase Gaussian low-pass (sigma :data:`SMOOTH_S`) before
``r_dot`` is taken, so that no signal leads another. Samples are used where the speed exceeds
the estimator's minimum speed and the lateral acceleration stays in the tires' linear range
(|a_y| < :data:`MAX_LAT_ACCEL`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lde.errors import ConfigError, LdeError
from lde.params import FRICTION_RATE_WIDTH, VEHICLE_DIR, InputCorrections, Vehicle, load_vehicle
from lde.units import DEG, KMH

#: zero-phase Gaussian smoothing of every signal before differentiation [s]
SMOOTH_S = 0.04
#: the linear tire range used for the fit [m/s^2]
MAX_LAT_ACCEL = 4.0
#: a (b) regression worse conditioned than this cannot separate Cf from Cr
MAX_COND = 1.0e4
#: ... and with the torsion compliance as a fourth unknown, this (else the column is taken as rigid)
TORSION_MAX_COND = 100.0
#: plausible range of the accelerometer scale s (roll tilt: 1 + g x roll gradient) [-]
MIN_ACCEL_SCALE, MAX_ACCEL_SCALE = 0.85, 1.25
#: fewer usable samples than this is an error
MIN_SAMPLES = 500

#: two-sided 95 % quantile of the normal distribution
Z95 = 1.959963984540054
#: the Newey-West (Bartlett) window in units of the residuals' integrated correlation time (see
#: :func:`correlation_time`): the Bartlett kernel underestimates the long-run variance of an AR(1)
#: series by about tau_int / (2 L), 10 % at 5 tau_int; a wider window costs variance (4 L / 3 n)
HAC_LAG_FACTOR = 5.0

#: every identified quantity, in the order of :attr:`Calibration.intervals` and the printed report
QUANTITIES: tuple[str, ...] = (
    "cf",
    "cr",
    "align_rate",
    "trail",
    "accel_scale",
    "torsion_compliance",
    "friction",
    "steer_offset",
    "align_offset",
    "yaw_bias",
)
#: the input corrections: written only when their interval excludes zero
CORRECTIONS: tuple[str, ...] = ("torsion_compliance", "friction", "steer_offset", "align_offset", "yaw_bias")

#: systematic (model-mismatch) standard uncertainty added in quadrature to the HAC one:
#: (absolute in the quantity's SI unit, relative to the value). The regressions are the linear
#: bicycle model's, smoothed and differentiated; their bias does not shrink with the drive's length,
#: the HAC interval does. Sized from the errors on the linear-model drives of tests/analysis/test_calibrate.py
#: (Cf 3 %, friction 0.01 Nm, a twist of 0.10 deg/Nm found on a rigid column with a boost curve) and
#: issue 11's zoo twin (0.139 deg/Nm found where there is none): without it a long drive's interval
#: excludes zero for a bias and calibrate writes a twist the car does not have.
SYSTEMATIC: Mapping[str, tuple[float, float]] = {
    "cf": (0.0, 0.02),
    "cr": (0.0, 0.02),
    "align_rate": (0.0, 0.02),
    "trail": (0.0, 0.02),
    "accel_scale": (0.01, 0.0),
    "torsion_compliance": (0.1 * DEG, 0.1),
    "friction": (0.02, 0.05),
    "steer_offset": (0.05 * DEG, 0.05),
    "align_offset": (0.05, 0.0),
    "yaw_bias": (0.005 * DEG, 0.0),
}


class CalibrationError(LdeError, ValueError):
    """The drive cannot identify the parameters (too short, too slow, no excitation)."""


class _TwistNotSeparable(Exception):
    """(b) with the twist as an unknown is worse conditioned than :data:`TORSION_MAX_COND`."""


@dataclass(frozen=True)
class DriveData:
    """Estimator inputs on the step grid (SI; ISO 8855 signs), one row per step.

    Attributes:
        t: time [s]; steering_angle: steering wheel [rad]; steering_rate: steering wheel [rad/s];
        yaw_rate [rad/s]; lat_accel [m/s^2]; speed [m/s]; column_torque [Nm]; assist_torque [Nm]
        (motor assist referred to the column); valid: bool, the row's inputs are fresh and trusted.
    """

    t: np.ndarray
    steering_angle: np.ndarray
    steering_rate: np.ndarray
    yaw_rate: np.ndarray
    lat_accel: np.ndarray
    speed: np.ndarray
    column_torque: np.ndarray
    assist_torque: np.ndarray
    valid: np.ndarray


@dataclass(frozen=True)
class Interval:
    """A 95 % confidence interval ``value +- Z95 sqrt(se_stat^2 + se_sys^2)`` (SI units).

    Attributes:
        value: the estimate.
        se_stat: the statistical standard error: Newey-West (HAC) over the drive, propagated
            through every regression the quantity depends on (delta method).
        se_sys: the systematic (model-mismatch) standard uncertainty, :data:`SYSTEMATIC`.
    """

    value: float
    se_stat: float
    se_sys: float = 0.0

    @property
    def se(self) -> float:
        return math.hypot(self.se_stat, self.se_sys)

    @property
    def low(self) -> float:
        return self.value - Z95 * self.se

    @property
    def high(self) -> float:
        return self.value + Z95 * self.se

    @property
    def excludes_zero(self) -> bool:
        return self.low > 0.0 or self.high < 0.0

    def contains(self, x: float) -> bool:
        return self.low <= x <= self.high


#: how each quantity is printed: (label, unit, SI per printed unit, decimals)
_SHOW: Mapping[str, tuple[str, str, float, int]] = {
    "cf": ("front cornering stiffness Cf", "N/rad", 1.0, 0),
    "cr": ("rear cornering stiffness Cr", "N/rad", 1.0, 0),
    "align_rate": ("aligning-torque rate K", "Nm/rad", 1.0, 0),
    "trail": ("trail K/Cf", "mm", 1e-3, 1),
    "accel_scale": ("accelerometer scale s", "", 1.0, 3),
    "torsion_compliance": ("torsion-bar twist", "deg/Nm", DEG, 3),
    "friction": ("steering friction", "Nm", 1.0, 3),
    "steer_offset": ("steering-angle offset", "deg", DEG, 3),
    "align_offset": ("aligning-torque offset", "Nm", 1.0, 3),
    "yaw_bias": ("yaw-rate bias", "deg/s", DEG, 4),
}


@dataclass(frozen=True)
class Calibration:
    """Identified parameters (SI), their 95 % intervals and fit diagnostics.

    Attributes:
        cf, cr: cornering stiffness per tire [N/rad].
        align_rate: K, aligning-torque rate per front tire [Nm/rad].
        trail: K / Cf [m] (pneumatic plus mechanical trail).
        friction: Coulomb friction of the steering referred to the column [Nm].
        steer_offset: steering-wheel angle offset [rad] (measured minus true).
        yaw_bias: yaw-rate sensor bias [rad/s] (measured minus true): the mean measured yaw rate
            over the drive, which must end on its initial heading.
        align_offset: offset of N (T_column + T_assist) [Nm] at the steering axis.
        torsion_compliance: c_tb, steering-wheel angle per column torque [rad/Nm] (0: rigid).
        torsion_identified: False when c_tb was not in the model (not asked for, or not separable
            from 1/Cf) and the column was taken as rigid.
        accel_scale: s, lateral accelerometer reading per true lateral acceleration [-] (the body
            roll tilts the sensor toward gravity: s = 1 + g x roll gradient).
        n: samples used; rms_slip: residual of (b) [rad]; rms_align: residual of (c) [Nm].
        cond: condition number of the (b) regression (large: Cf and Cr not separable).
        intervals: 95 % interval of every quantity that was in the model (:data:`QUANTITIES`).
            A correction the data does not support keeps the value and interval of the fit that
            included it; the tires and the other corrections come from the refit without it.
        used: the corrections whose interval excludes zero (:meth:`corrections` writes only these).
        hac_lags: the Newey-West window [samples]; corr_time: the residuals' integrated
            correlation time [s] it was chosen from.
    """

    cf: float
    cr: float
    align_rate: float
    trail: float
    friction: float
    steer_offset: float
    yaw_bias: float
    align_offset: float
    torsion_compliance: float
    torsion_identified: bool
    accel_scale: float
    n: int
    rms_slip: float
    rms_align: float
    cond: float
    intervals: Mapping[str, Interval] = field(default_factory=dict)
    used: frozenset[str] = frozenset(CORRECTIONS)
    hac_lags: int = 0
    corr_time: float = 0.0

    def _torsion(self) -> str:
        return _torsion_text(self.torsion_compliance, self.torsion_identified)

    def supported(self, name: str) -> bool:
        """The correction ``name`` (:data:`CORRECTIONS`) is written: its interval excludes zero."""
        return name in self.used

    def corrections(self, gated: bool = True) -> InputCorrections:
        """The input corrections for the vehicle file's ``[corrections]`` (:mod:`lde.estimator.conditioning`).

        ``gated`` (default): only the corrections the drive supports (interval excludes zero), the
        others 0. A negative friction is taken as none."""

        def v(name: str, value: float) -> float:
            return value if not gated or name in self.used else 0.0

        return InputCorrections(
            friction=max(0.0, v("friction", self.friction)),
            torsion_compliance=v("torsion_compliance", self.torsion_compliance),  # 0 when not identified
            steer_offset=v("steer_offset", self.steer_offset),
            yaw_bias=v("yaw_bias", self.yaw_bias),
            align_offset=v("align_offset", self.align_offset),
        )

    def report_lines(self) -> list[str]:
        """One line per quantity: value, 95 % interval and, for a correction, whether it is used."""
        lines = []
        for q in QUANTITIES:
            label, unit, f, d = _SHOW[q]
            iv = self.intervals.get(q)
            if iv is None:
                why = {
                    "torsion_compliance": "not identified (rigid column assumed)",
                    "friction": "not identified (no signed steering rate)",
                }.get(q, "not identified")
                lines.append(f"{label:30s} {why}")
                continue
            val = f"{iv.value / f:.{d}f} {unit}".rstrip()
            ci = f"[{iv.low / f:.{d}f}, {iv.high / f:.{d}f}]"
            if q in CORRECTIONS:
                verdict = "used" if q in self.used else "not supported by this drive: written as 0"
            else:
                verdict = "used" if q not in ("trail", "accel_scale") else "(reported)"
            lines.append(f"{label:30s} {val:>18s}  95 % {ci:24s} {verdict}")
        return lines

    def summary(self) -> str:
        return (
            f"Cf = {self.cf:.0f} N/rad, Cr = {self.cr:.0f} N/rad, K = {self.align_rate:.0f} Nm/rad "
            f"(trail {1000 * self.trail:.1f} mm), steering friction {self.friction:.3f} Nm at the column, "
            f"steering-angle offset {self.steer_offset / DEG:.2f} deg, "
            f"yaw-rate bias {self.yaw_bias / DEG:.3f} deg/s, "
            f"T_align offset {self.align_offset:.2f} Nm, "
            f"torsion bar {self._torsion()}, accelerometer scale {self.accel_scale:.3f}; "
            f"{self.n} samples, residuals {self.rms_slip / DEG:.3f} deg and {self.rms_align:.2f} Nm, "
            f"cond {self.cond:.0f}; Newey-West window {self.hac_lags} samples "
            f"({self.corr_time:.2f} s correlation time)"
        )


def _torsion_text(c: float, identified: bool) -> str:
    if not identified:
        return "not identified (rigid column assumed)"
    k = "inf" if c <= 0.0 else f"{DEG / c:.2f}"
    return f"compliance {c / DEG:.3f} deg/Nm ({k} Nm/deg)"


def gaussian_smooth(x: np.ndarray, sigma_samples: float) -> np.ndarray:
    """Zero-phase Gaussian low-pass (kernel truncated at 4 sigma; edges by point reflection)."""
    x = np.asarray(x, dtype=np.float64)
    if sigma_samples <= 0.0:
        return x.copy()
    half = max(1, int(math.ceil(4.0 * sigma_samples)))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_samples) ** 2)
    k /= k.sum()
    if x.size <= half:
        return np.full_like(x, x.mean() if x.size else 0.0)
    # point reflection about the end samples keeps a linear trend through the edges
    padded = np.concatenate([2.0 * x[0] - x[half:0:-1], x, 2.0 * x[-1] - x[-2 : -half - 2 : -1]])
    return np.convolve(padded, k, mode="valid")


def correlation_time(e: np.ndarray) -> float:
    """Integrated autocorrelation time of ``e`` [samples]: ``1 + 2 sum_k rho_k`` over the lags up
    to the autocorrelation's first zero crossing (1 for white noise; ~2 tau for an AR(1) of time
    constant tau samples)."""
    e = np.asarray(e, dtype=np.float64) - float(np.mean(e))
    n = e.size
    if n < 2 or not np.any(e):
        return 1.0
    m = 1 << int(math.ceil(math.log2(2 * n)))
    f = np.fft.rfft(e, m)
    acf = np.fft.irfft(f * np.conj(f), m)[:n]
    rho = acf / acf[0]
    neg = np.flatnonzero(rho <= 0.0)
    k = int(neg[0]) if neg.size else n
    return float(max(1.0, 1.0 + 2.0 * np.sum(rho[1:k])))


def hac_covariance(psi: np.ndarray, lags: int) -> np.ndarray:
    """Newey-West (Bartlett) long-run covariance ``sum_i sum_j w_|i-j| psi_i psi_j'``,
    ``w_k = 1 - k / (lags + 1)``, of the per-sample contributions ``psi`` (n x p, rows in time
    order; not demeaned: a least-squares score sums to zero by itself). For OLS with
    ``psi_i = (X'X)^-1 x_i e_i`` this is statsmodels' ``OLS(...).fit(cov_type="HAC",
    cov_kwds={"maxlags": lags})`` covariance without its small-sample factor (a test compares)."""
    psi = np.asarray(psi, dtype=np.float64)
    if psi.ndim == 1:
        psi = psi[:, None]
    s = psi.T @ psi
    for k in range(1, min(int(lags), psi.shape[0] - 1) + 1):
        g = psi[k:].T @ psi[:-k]
        s += (1.0 - k / (lags + 1.0)) * (g + g.T)
    return s


def calibrate(
    drive: DriveData,
    base: Vehicle,
    *,
    smooth_s: float = SMOOTH_S,
    identify_torsion: bool = True,
    identify_friction: bool = True,
    gate: bool = True,
    systematic: bool = True,
    hac_lag_factor: float = HAC_LAG_FACTOR,
) -> Calibration:
    """Least-squares identification of Cf, Cr, K, torsion compliance, friction and offsets
    (module docstring (a)-(d)), with a 95 % interval for each.

    ``identify_friction`` False: no friction term (a steering rate without its sign, profile
    ``hyundai``, cannot tell which way the friction acts); friction is then reported as 0.
    ``gate``: a correction whose interval contains zero is dropped (written as 0) and the rest
    refitted without it, once. ``systematic`` False leaves out the model-mismatch term of the
    intervals (:data:`SYSTEMATIC`; for measuring the statistical coverage alone).
    """
    sg = _signals(drive, base, smooth_s)
    terms = {"steer_offset", "align_offset", "yaw_bias"}
    if identify_friction:
        terms.add("friction")
    if identify_torsion:
        terms.add("torsion_compliance")
    full = _analyse(sg, base, frozenset(terms), systematic, hac_lag_factor)
    refused: frozenset[str] = frozenset()
    if gate:
        refused = frozenset(q for q in full.terms & set(CORRECTIONS) if not full.intervals[q].excludes_zero)
    final = _analyse(sg, base, full.terms - refused, systematic, hac_lag_factor) if refused else full
    intervals = {q: iv for q, iv in final.intervals.items()}
    intervals.update({q: full.intervals[q] for q in refused})
    o = {**final.out, **{q: full.out[q] for q in refused}}
    return Calibration(
        cf=o["cf"],
        cr=o["cr"],
        align_rate=o["align_rate"],
        trail=o["trail"],
        friction=o["friction"],
        steer_offset=o["steer_offset"],
        yaw_bias=o["yaw_bias"],
        align_offset=o["align_offset"],
        torsion_compliance=o["torsion_compliance"],
        torsion_identified="torsion_compliance" in full.terms,
        accel_scale=o["accel_scale"],
        n=sg.n,
        rms_slip=final.rms_slip,
        rms_align=final.rms_align,
        cond=final.cond,
        intervals={q: intervals[q] for q in QUANTITIES if q in intervals},
        used=frozenset(final.terms & set(CORRECTIONS)),
        hac_lags=final.lags,
        corr_time=final.corr_time * sg.dt,
    )


@dataclass(frozen=True)
class _Signals:
    """The smoothed signals of a drive on its own time grid, and the rows the fit uses."""

    t: np.ndarray
    dt: float
    r: np.ndarray
    r_dot: np.ndarray
    ay: np.ndarray
    vx: np.ndarray
    delta_f: np.ndarray
    fric_sign: np.ndarray
    t_col: np.ndarray
    t_align: np.ndarray
    use: np.ndarray
    n: int


def _signals(drive: DriveData, base: Vehicle, smooth_s: float) -> _Signals:
    t = np.asarray(drive.t, dtype=np.float64)
    n_all = t.size
    if n_all < MIN_SAMPLES:
        raise CalibrationError(f"the drive has {n_all} samples; at least {MIN_SAMPLES} are needed")
    dt = float(np.median(np.diff(t)))
    if not dt > 0.0:
        raise CalibrationError("drive time must increase")
    N = base.steering.ratio
    sig = smooth_s / dt

    def sm(a: np.ndarray) -> np.ndarray:
        a = np.asarray(a, dtype=np.float64)
        if a.shape != t.shape:
            raise CalibrationError(f"signal of shape {a.shape} does not match time {t.shape}")
        return gaussian_smooth(np.where(np.isfinite(a), a, 0.0), sig)

    r = sm(drive.yaw_rate)
    ay = sm(drive.lat_accel)
    vx = sm(drive.speed)
    # the friction regressor is smoothed like the torque it explains (a smoothed sign step)
    rate = np.asarray(drive.steering_rate, dtype=np.float64)
    t_col = sm(drive.column_torque)
    ok = np.asarray(drive.valid, dtype=bool).copy()
    for a in (drive.yaw_rate, drive.lat_accel, drive.speed, drive.steering_angle, drive.column_torque):
        ok &= np.isfinite(np.asarray(a, dtype=np.float64))
    # a bad sample spoils its smoothing neighbourhood: widen the mask by the kernel half width
    bad = gaussian_smooth((~ok).astype(np.float64), sig) > 1e-3
    use = ~bad & (vx > base.estimator.min_speed) & (np.abs(ay) < MAX_LAT_ACCEL)
    edge = int(math.ceil(4.0 * sig))
    use[:edge] = False
    use[n_all - edge :] = False
    n = int(np.count_nonzero(use))
    if n < MIN_SAMPLES:
        raise CalibrationError(
            f"only {n} usable samples (speed above {base.estimator.min_speed / KMH:.0f} km/h, "
            f"|a_y| < {MAX_LAT_ACCEL} m/s^2, valid inputs); at least {MIN_SAMPLES} are needed"
        )
    return _Signals(
        t=t,
        dt=dt,
        r=r,
        r_dot=np.gradient(r, t),
        ay=ay,
        vx=vx,
        delta_f=sm(drive.steering_angle) / N,
        fric_sign=sm(np.tanh(np.where(np.isfinite(rate), rate, 0.0) / FRICTION_RATE_WIDTH)),
        t_col=t_col,
        t_align=N * (t_col + sm(drive.assist_torque)),
        use=use,
        n=n,
    )


@dataclass
class _Stage:
    """One least-squares fit of the chain: its regressors (used rows), residual and coefficients."""

    name: str
    X: np.ndarray
    resid: np.ndarray
    coef: np.ndarray
    cond: float


@dataclass
class _Chain:
    out: dict[str, float]
    stages: list[_Stage]
    terms: frozenset[str]


def _ls(name: str, X: np.ndarray, y: np.ndarray, perturb: Mapping[str, np.ndarray] | None) -> _Stage:
    """Least squares with unit-norm columns; ``perturb[name]`` is added to the coefficients (for
    the chain's derivatives)."""
    col = np.linalg.norm(X, axis=0)
    if np.any(col == 0.0):
        raise CalibrationError("no lateral excitation in the drive (no steering)")
    c, *_ = np.linalg.lstsq(X / col, y, rcond=None)
    c = c / col
    cond = float(np.linalg.cond(X / col))
    resid = y - X @ c
    if perturb is not None and name in perturb:
        c = c + perturb[name]
    return _Stage(name, X, resid, c, cond)


def _chain(
    sg: _Signals, base: Vehicle, terms: frozenset[str], perturb: Mapping[str, np.ndarray] | None = None
) -> _Chain:
    """The identification of the module docstring, (a)-(d), as a chain of least-squares stages:
    yaw-rate mean, (b) and (c) with the raw accelerometer, (d), (c) on a_y / s, Cf = K / trail,
    (b) with Cf fixed. ``terms``: the corrections in the model (:data:`CORRECTIONS`)."""
    b = base.body
    m, iz, lf, lr, L, N = b.mass, b.yaw_inertia, b.lf, b.lr, b.wheelbase, base.steering.ratio
    u = sg.use
    n = sg.n
    ones = np.ones(n)
    stages: list[_Stage] = []
    # a yaw-rate bias: the drive returns to its initial heading (a straight road, a lane change and
    # back), so the true yaw rate averages to zero over it and the measured mean is the bias
    yaw_bias = 0.0
    if "yaw_bias" in terms:
        st = _ls("yaw", ones[:, None], sg.r[u], perturb)
        stages.append(st)
        yaw_bias = float(st.coef[0])
    r = sg.r[u] - yaw_bias
    r_dot, vx, delta_f, t_col = sg.r_dot[u], sg.vx[u], sg.delta_f[u], sg.t_col[u]
    t_align, fric_sign, ay = sg.t_align[u], sg.fric_sign[u], sg.ay[u]
    y_slip = delta_f - L * r / vx

    def forces(scale: float) -> tuple[np.ndarray, np.ndarray]:  # (a): per-tire axle forces
        a = ay / scale
        return (lr * m * a + iz * r_dot) / (2.0 * L), (lf * m * a - iz * r_dot) / (2.0 * L)

    def slip_cols() -> list[np.ndarray]:  # (b)'s correction columns: d0, c_tb
        cols = []
        if "steer_offset" in terms:
            cols.append(ones)
        if "torsion_compliance" in terms:
            cols.append(t_col / N)
        return cols

    def unpack_slip(c: np.ndarray) -> tuple[float, float]:  # (d0, c_tb) from (b)'s tail
        it = iter(c)
        d0 = float(next(it)) if "steer_offset" in terms else 0.0
        c_tb = float(next(it)) if "torsion_compliance" in terms else 0.0
        return d0, c_tb

    def align_fit(name: str, ff: np.ndarray) -> tuple[_Stage, float, float, float]:
        # (c) N (Tcol + Tassist) = trail 2Ff + N T_fric S(tanh(rate/w)) + T_0
        cols = [2.0 * ff]
        if "friction" in terms:
            cols.append(N * fric_sign)
        if "align_offset" in terms:
            cols.append(ones)
        st = _ls(name, np.column_stack(cols), t_align, perturb)
        it = iter(st.coef)
        trail = float(next(it))
        fric = float(next(it)) if "friction" in terms else 0.0
        t0 = float(next(it)) if "align_offset" in terms else 0.0
        if not trail > 0.0:
            raise CalibrationError(f"identified trail K/Cf = {trail:.3g} m is not positive")
        return st, trail, fric, t0

    # pass 1: (b) and (c) with the accelerometer as it reads
    ff, fr = forces(1.0)
    st = _ls("b1", np.column_stack([ff, -fr, *slip_cols()]), y_slip, perturb)
    stages.append(st)
    if "torsion_compliance" in terms and st.cond > TORSION_MAX_COND:
        raise _TwistNotSeparable
    if st.cond > MAX_COND:
        raise CalibrationError(
            f"the drive cannot separate Cf from Cr (condition number {st.cond:.3g}): it needs transient "
            "steering such as a lane change or a slalom, not only steady cornering"
        )
    comp_f, comp_r = float(st.coef[0]), float(st.coef[1])
    if not (comp_f > 0.0 and comp_r > 0.0):
        raise CalibrationError(
            f"identified compliances are not positive (1/Cf = {comp_f:.3g}, 1/Cr = {comp_r:.3g} rad/N): "
            "the drive lacks transient steering (a lane change or a slalom identifies Cf and Cr)"
        )
    d0, c_tb = unpack_slip(st.coef[2:])
    st, _, fric, t0 = align_fit("c1", ff)
    stages.append(st)
    # (d): a_y = s vx (d/dt(delta_f - lf r/vx) + r) - (s/K) vx T_align,corr_dot / 2, with the
    # friction and offset of (c) removed and the road-wheel angle corrected for twist and offset
    ta = sg.t_align - N * fric * sg.fric_sign - t0
    dc = sg.delta_f - c_tb * sg.t_col / N - d0
    r_all = sg.r - yaw_bias
    u1 = sg.vx * (np.gradient(dc - lf * r_all / sg.vx, sg.t) + r_all)
    u2 = sg.vx * np.gradient(ta, sg.t) / 2.0
    st = _ls("d", np.column_stack([u1[u], u2[u]]), ay, perturb)
    stages.append(st)
    scale, slope = float(st.coef[0]), float(st.coef[1])
    if not (MIN_ACCEL_SCALE <= scale <= MAX_ACCEL_SCALE and slope < 0.0):
        raise CalibrationError(_unsuitable_drive(st, sg, scale, slope))
    k = -scale / slope
    # pass 2: (c) with a_y / s; Cf = K / trail
    ff, fr = forces(scale)
    st, trail, fric, t0 = align_fit("c2", ff)
    stages.append(st)
    cf = k / trail
    # pass 3: (b) with Cf fixed, for Cr, the twist and the angle offset
    st = _ls("b3", np.column_stack([-fr, *slip_cols()]), y_slip - ff / cf, perturb)
    stages.append(st)
    if "torsion_compliance" in terms and st.cond > TORSION_MAX_COND:
        raise _TwistNotSeparable
    comp_r = float(st.coef[0])
    if not comp_r > 0.0:
        raise CalibrationError(
            f"identified rear compliance 1/Cr = {comp_r:.3g} rad/N is not positive: the drive lacks "
            "transient steering (a lane change or a slalom identifies Cf and Cr)"
        )
    d0, c_tb = unpack_slip(st.coef[1:])
    out = {
        "cf": cf,
        "cr": 1.0 / comp_r,
        "align_rate": k,
        "trail": trail,
        "accel_scale": scale,
        "torsion_compliance": c_tb,
        "friction": fric,
        "steer_offset": d0 * N,
        "align_offset": t0,
        "yaw_bias": yaw_bias,
    }
    return _Chain(out, stages, terms)


def _stage_interval(st: _Stage, lag_factor: float = HAC_LAG_FACTOR) -> tuple[np.ndarray, np.ndarray]:
    """One stage's coefficients and their 95 % HAC half widths (the stage alone, no chain)."""
    col = np.linalg.norm(st.X, axis=0)
    xn = st.X / col
    ginv = np.linalg.inv(xn.T @ xn)
    psi = ((xn * st.resid[:, None]) @ ginv) / col
    lags = int(min(math.ceil(lag_factor * correlation_time(st.resid)), st.resid.size // 2))
    se = np.sqrt(np.maximum(np.diag(hac_covariance(psi, lags)), 0.0))
    return st.coef, Z95 * se


def _unsuitable_drive(st: _Stage, sg: _Signals, scale: float, slope: float) -> str:
    """Why fit (d) is implausible, from its own 95 % interval: too wide to say anything (the drive
    lacks transient steering) or narrow and off (the drive is not undisturbed: a crosswind or a
    bank adds a lateral force the kinematics do not see, or a load). A faulty accelerometer is the
    last suspect: the message says what to drive instead."""
    coef, half = _stage_interval(st)
    lo, hi = scale - half[0], scale + half[0]
    rate = float(np.sqrt(np.mean(np.gradient(sg.delta_f, sg.t)[sg.use] ** 2)))  # road-wheel rate RMS
    what = (
        f"the kinematic fit (d) gives an accelerometer scale {scale:.3f} (95 % interval [{lo:.3f}, {hi:.3f}];"
        f" plausible {MIN_ACCEL_SCALE}-{MAX_ACCEL_SCALE}) and an aligning-torque slope {slope:.3g}"
        f"{'' if slope < 0.0 else ' (must be negative)'}"
    )
    wide = lo < MAX_ACCEL_SCALE and hi > MIN_ACCEL_SCALE or abs(slope) < half[1]
    if wide:
        why = (
            f"the drive lacks excitation: too little transient steering to identify it (road-wheel rate "
            f"{rate / DEG:.2f} deg/s RMS over {sg.n} samples); drive a few lane changes or a slalom at "
            "60-120 km/h"
        )
    else:
        why = (
            "the drive does not look undisturbed: a crosswind, a banked or crowned road or a changing "
            "load adds a lateral force the steering kinematics do not explain; calibrate on a calm day on "
            "a flat straight road (lane changes or a slalom at 60-120 km/h). Only if such a drive gives "
            "this too, check the vehicle file's steering ratio and the lateral-acceleration signal"
        )
    return f"unsuitable drive: {what}: {why}"


@dataclass(frozen=True)
class _Analysis:
    out: dict[str, float]
    intervals: dict[str, Interval]
    terms: frozenset[str]
    rms_slip: float
    rms_align: float
    cond: float
    lags: int
    corr_time: float  # [samples]


def _analyse(
    sg: _Signals, base: Vehicle, terms: frozenset[str], systematic: bool, lag_factor: float
) -> _Analysis:
    """The chain's estimates and their HAC covariance: each stage's per-sample contribution to its
    coefficients, ``(X'X)^-1 x_i e_i``, mapped to the outputs by the chain's total derivative
    (central differences: the stage's coefficients perturbed, every later stage refitted), summed
    over the stages per sample and put through the Newey-West kernel (:func:`hac_covariance`)."""
    try:
        chain = _chain(sg, base, terms)
    except _TwistNotSeparable:
        # the twist is not separable from 1/Cf on this drive: the column is taken as rigid
        terms = terms - {"torsion_compliance"}
        chain = _chain(sg, base, terms)
    names = [q for q in QUANTITIES if _in_model(q, terms)]
    base_out = np.array([chain.out[q] for q in names])
    n_all = sg.t.size
    psi = np.zeros((n_all, len(names)))
    for st in chain.stages:
        col = np.linalg.norm(st.X, axis=0)
        xn = st.X / col
        ginv = np.linalg.inv(xn.T @ xn)
        contrib = ((xn * st.resid[:, None]) @ ginv) / col  # rows: (X'X)^-1 x_i e_i
        h = np.sqrt(np.sum(contrib**2, axis=0))  # the stage's white-noise standard errors
        h = np.where(h > 0.0, h, 1e-9 * np.maximum(np.abs(st.coef), 1e-12))
        jac = np.empty((len(names), st.coef.size))
        for j in range(st.coef.size):
            dp = np.zeros(st.coef.size)
            dp[j] = h[j]
            hi = _chain(sg, base, terms, {st.name: dp}).out
            lo = _chain(sg, base, terms, {st.name: -dp}).out
            jac[:, j] = [(hi[q] - lo[q]) / (2.0 * h[j]) for q in names]
        psi[sg.use] += contrib @ jac.T
    tau = max(correlation_time(st.resid) for st in chain.stages)
    lags = int(min(math.ceil(lag_factor * tau), n_all // 2))
    cov = hac_covariance(psi, lags)
    intervals = {}
    for i, q in enumerate(names):
        se_sys = 0.0
        if systematic:
            a, rel = SYSTEMATIC[q]
            se_sys = math.hypot(a, rel * abs(base_out[i]))
        intervals[q] = Interval(float(base_out[i]), float(math.sqrt(max(cov[i, i], 0.0))), se_sys)
    by = {s.name: s for s in chain.stages}
    return _Analysis(
        out=chain.out,
        intervals=intervals,
        terms=terms,
        rms_slip=float(np.sqrt(np.mean(by["b3"].resid ** 2))),
        rms_align=float(np.sqrt(np.mean(by["c2"].resid ** 2))),
        cond=by["b3"].cond,
        lags=lags,
        corr_time=tau,
    )


def _in_model(q: str, terms: frozenset[str]) -> bool:
    return q in terms or q not in CORRECTIONS


def vehicle_toml(
    cal: Calibration,
    base: Vehicle,
    name: str = "calibrated",
    log: str = "",
    corrections: bool = True,
    tires: bool = True,
) -> str:
    """A vehicle file that ``extends`` the base vehicle and overrides ``[tires]`` and (with
    ``corrections``) ``[corrections]`` (:mod:`lde.estimator.conditioning`) with the calibration.

    Without ``corrections`` the calibration should come from ``calibrate(identify_torsion=False)``:
    the tire values are then effective ones for the paper's step, the twist folded in.
    """
    src = Path(base.source) if base.source else None
    if src is not None and src.parent == VEHICLE_DIR:
        extends = src.stem
    elif src is not None and src.exists():
        extends = str(src.resolve())
    else:
        extends = base.name
    from_log = f" from {log}" if log else ""
    what = "tire parameters and input corrections" if corrections else "effective tire parameters"
    lines = [
        f"# Written by `lde calibrate`{from_log}: {what} identified by least squares on the",
        "# bicycle-model equations over a drive without disturbance (src/lde/analysis/calibrate.py).",
        f"# {cal.n} samples; residuals {cal.rms_slip / DEG:.4f} deg (slip balance) and "
        f"{cal.rms_align:.3f} Nm (aligning torque); condition number {cal.cond:.1f}.",
        f"# Also identified: accelerometer scale {cal.accel_scale:.3f} (roll tilt; the estimator does not "
        "use a_y); the",
        "# body (mass, yaw inertia, CG, ratio) is the base vehicle's: lateral signals cannot tell the mass,",
        "# so the tire values scale with the assumed mass.",
        f"extends = {_toml_str(extends)}",
        f"name = {_toml_str(name)}",
        f"description = {_toml_str(f'{base.name} calibrated by lde calibrate{from_log}')}",
        "",
    ]
    tire_lines = [
        "[tires]",
        f"cf_N_per_rad = {cal.cf:.1f}",
        f"cr_N_per_rad = {cal.cr:.1f}",
        f"align_rate_Nm_per_rad = {cal.align_rate:.1f}",
        "",
    ]
    if tires:
        lines += tire_lines
    else:
        lines += ["# [tires] kept from the base vehicle (--keep-tires); identified:"]
        lines += ["#   " + t for t in tire_lines[1:-1]] + [""]
    if corrections:
        c = cal.corrections()
        lines += [
            "[corrections]           # removed from the inputs before the step (lde.estimator.conditioning)",
            f"steering_friction_Nm = {c.friction:.4f}        # Coulomb, at the column",
            f"friction_rate_deg_s = {c.friction_rate_width / DEG:.3f}",
            f"torsion_deg_per_Nm = {c.torsion_compliance / DEG:.5f}        # {cal._torsion()}",
            f"steering_angle_offset_deg = {c.steer_offset / DEG:.4f}",
            f"yaw_rate_bias_deg_s = {c.yaw_bias / DEG:.5f}",
            f"align_offset_Nm = {c.align_offset:.4f}          # at the steering axis",
            "",
        ]
    else:
        lines += [
            "# [corrections] not written (--no-corrections); identified: friction "
            f"{cal.friction:.3f} Nm, angle offset {cal.steer_offset / DEG:.3f} deg,",
            f"# yaw-rate bias {cal.yaw_bias / DEG:.4f} deg/s, T_align offset {cal.align_offset:.3f} Nm.",
        ]
    return "\n".join(lines)


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"') + '"'


def write_vehicle(
    cal: Calibration,
    base: Vehicle,
    path: Path,
    name: str = "calibrated",
    log: str = "",
    corrections: bool = True,
    tires: bool = True,
) -> Path:
    """Write :func:`vehicle_toml` to ``path`` and check that it loads."""

    try:
        path.write_text(vehicle_toml(cal, base, name=name, log=log, corrections=corrections, tires=tires))
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc}") from exc
    load_vehicle(path)
    return path
