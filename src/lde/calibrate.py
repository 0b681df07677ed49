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
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import ConfigError, LdeError
from .params import FRICTION_RATE_WIDTH, VEHICLE_DIR, InputCorrections, Vehicle, load_vehicle
from .units import DEG, KMH

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


class CalibrationError(LdeError, ValueError):
    """The drive cannot identify the parameters (too short, too slow, no excitation)."""


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
class Calibration:
    """Identified parameters (SI) and fit diagnostics.

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
        torsion_identified: False when c_tb was not separable and the column was taken as rigid.
        accel_scale: s, lateral accelerometer reading per true lateral acceleration [-] (the body
            roll tilts the sensor toward gravity: s = 1 + g x roll gradient).
        n: samples used; rms_slip: residual of (b) [rad]; rms_align: residual of (c) [Nm].
        cond: condition number of the (b) regression (large: Cf and Cr not separable).
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

    def _torsion(self) -> str:
        return _torsion_text(self.torsion_compliance, self.torsion_identified)

    def corrections(self) -> InputCorrections:
        """The input corrections for the vehicle file's ``[corrections]`` (:mod:`lde.conditioning`).

        A negative friction (noise on a drive with little steering) is taken as none."""
        return InputCorrections(
            friction=max(0.0, self.friction),
            torsion_compliance=self.torsion_compliance,  # 0 when not identified
            steer_offset=self.steer_offset,
            yaw_bias=self.yaw_bias,
            align_offset=self.align_offset,
        )

    def summary(self) -> str:
        return (
            f"Cf = {self.cf:.0f} N/rad, Cr = {self.cr:.0f} N/rad, K = {self.align_rate:.0f} Nm/rad "
            f"(trail {1000 * self.trail:.1f} mm), steering friction {self.friction:.3f} Nm at the column, "
            f"steering-angle offset {self.steer_offset / DEG:.2f} deg, "
            f"yaw-rate bias {self.yaw_bias / DEG:.3f} deg/s, "
            f"T_align offset {self.align_offset:.2f} Nm, "
            f"torsion bar {self._torsion()}, accelerometer scale {self.accel_scale:.3f}; "
            f"{self.n} samples, residuals {self.rms_slip / DEG:.3f} deg and {self.rms_align:.2f} Nm, "
            f"cond {self.cond:.0f}"
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


def calibrate(
    drive: DriveData,
    base: Vehicle,
    *,
    smooth_s: float = SMOOTH_S,
    identify_torsion: bool = True,
    identify_friction: bool = True,
) -> Calibration:
    """Least-squares identification of Cf, Cr, K, torsion compliance, friction and offsets
    (module docstring (a)-(c)).

    ``identify_friction`` False: no friction term (a steering rate without its sign, profile
    ``hyundai``, cannot tell which way the friction acts); friction is then reported as 0."""
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
    delta_f = sm(drive.steering_angle) / N
    # the friction regressor is smoothed like the torque it explains (a smoothed sign step)
    if identify_friction:
        fric_sign = sm(np.tanh(np.asarray(drive.steering_rate, dtype=np.float64) / FRICTION_RATE_WIDTH))
    else:
        fric_sign = np.zeros_like(t)
    t_col = sm(drive.column_torque)
    t_align = N * (t_col + sm(drive.assist_torque))
    r_dot = np.gradient(r, t)

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

    # a yaw-rate bias: the drive returns to its initial heading (a straight road, a lane change and
    # back), so the true yaw rate averages to zero over it and the measured mean is the bias
    yaw_bias = float(np.mean(r[use]))
    r = r - yaw_bias
    # pass 1: (a)-(c) with the accelerometer as it reads
    p1 = _fit_bc(ay, r, r_dot, vx, delta_f, t_col, t_align, fric_sign, use, base, identify_torsion)
    # (d) accelerometer scale s and K from the kinematics, beta from the aligning torque
    scale, k = _fit_d(p1, ay, r, vx, delta_f, t_col, t_align, fric_sign, t, use, base)
    # pass 2: (a)-(c) with a_y / s; Cf = K / trail, then (b) for Cr with Cf fixed
    p2 = _fit_bc(ay / scale, r, r_dot, vx, delta_f, t_col, t_align, fric_sign, use, base, identify_torsion)
    cf = k / p2.trail
    p3 = _fit_bc(
        ay / scale, r, r_dot, vx, delta_f, t_col, t_align, fric_sign, use, base, identify_torsion, cf_fixed=cf
    )
    return Calibration(
        cf=cf,
        cr=p3.cr,
        align_rate=k,
        trail=p2.trail,
        friction=p2.friction,
        steer_offset=p3.d0 * N,
        yaw_bias=yaw_bias,
        align_offset=p2.t0,
        torsion_compliance=p3.c_tb,
        torsion_identified=p3.torsion_ok,
        accel_scale=scale,
        n=n,
        rms_slip=p3.rms_slip,
        rms_align=p2.rms_align,
        cond=p3.cond,
    )


@dataclass(frozen=True)
class _PassBC:
    cf: float
    cr: float
    d0: float
    c_tb: float
    torsion_ok: bool
    cond: float
    rms_slip: float
    trail: float
    friction: float
    t0: float
    rms_align: float


def _fit_bc(
    ay: np.ndarray,
    r: np.ndarray,
    r_dot: np.ndarray,
    vx: np.ndarray,
    delta_f: np.ndarray,
    t_col: np.ndarray,
    t_align: np.ndarray,
    fric_sign: np.ndarray,
    use: np.ndarray,
    base: Vehicle,
    identify_torsion: bool,
    cf_fixed: float | None = None,
) -> _PassBC:
    """Regressions (a)-(c) of the module docstring on the smoothed signals (rows ``use``)."""
    b = base.body
    m, iz, lf, lr, L, N = b.mass, b.yaw_inertia, b.lf, b.lr, b.wheelbase, base.steering.ratio
    n = int(np.count_nonzero(use))
    # (a) per-tire axle forces from the measurements
    ff = (lr * m * ay + iz * r_dot) / (2.0 * L)
    fr = (lf * m * ay - iz * r_dot) / (2.0 * L)
    # (b) delta_sw/N - L r / vx = Ff/Cf - Fr/Cr + (Tcol/N) c_tb + d0
    y1 = delta_f[use] - L * r[use] / vx[use]
    if cf_fixed is not None:
        y1 = y1 - ff[use] / cf_fixed
        base_cols = [-fr[use], np.ones(n)]
    else:
        base_cols = [ff[use], -fr[use], np.ones(n)]
    c1, cond, X1 = _lstsq(np.column_stack(base_cols + [t_col[use] / N]), y1)
    torsion_ok = identify_torsion and cond <= TORSION_MAX_COND
    if not torsion_ok:
        c1, cond, X1 = _lstsq(np.column_stack(base_cols), y1)
        c1 = np.append(c1, 0.0)
        X1 = np.column_stack([X1, np.zeros(n)])
    if cf_fixed is not None:
        c1 = np.concatenate([[1.0 / cf_fixed], c1])
    comp_f, comp_r, d0, c_tb = (float(v) for v in c1)
    if cond > MAX_COND:
        raise CalibrationError(
            f"the drive cannot separate Cf from Cr (condition number {cond:.3g}): it needs transient "
            "steering such as a lane change or a slalom, not only steady cornering"
        )
    if not (comp_f > 0.0 and comp_r > 0.0):
        raise CalibrationError(
            f"identified compliances are not positive (1/Cf = {comp_f:.3g}, 1/Cr = {comp_r:.3g} rad/N): "
            "the drive lacks transient steering (a lane change or a slalom identifies Cf and Cr)"
        )
    res1 = y1 - X1 @ c1[1:] if cf_fixed is not None else y1 - X1 @ c1
    # (c) N (Tcol + Tassist) = trail 2Ff + N T_fric S(tanh(rate/w)) + T_0
    X2 = np.column_stack([2.0 * ff[use], N * fric_sign[use], np.ones(n)])
    y2 = t_align[use]
    if np.any(fric_sign[use] != 0.0):
        c2, *_ = np.linalg.lstsq(X2, y2, rcond=None)
    else:  # no friction regressor (identify_friction=False)
        c2 = np.insert(np.linalg.lstsq(X2[:, [0, 2]], y2, rcond=None)[0], 1, 0.0)
    trail, fric, t0 = (float(v) for v in c2)
    res2 = y2 - X2 @ c2
    if not trail > 0.0:
        raise CalibrationError(f"identified trail K/Cf = {trail:.3g} m is not positive")
    return _PassBC(
        cf=1.0 / comp_f,
        cr=1.0 / comp_r,
        d0=d0,
        c_tb=c_tb,
        torsion_ok=torsion_ok,
        cond=cond,
        rms_slip=float(np.sqrt(np.mean(res1**2))),
        trail=trail,
        friction=fric,
        t0=t0,
        rms_align=float(np.sqrt(np.mean(res2**2))),
    )


def _fit_d(
    p: _PassBC,
    ay: np.ndarray,
    r: np.ndarray,
    vx: np.ndarray,
    delta_f: np.ndarray,
    t_col: np.ndarray,
    t_align: np.ndarray,
    fric_sign: np.ndarray,
    t: np.ndarray,
    use: np.ndarray,
    base: Vehicle,
) -> tuple[float, float]:
    """(d): accelerometer scale s and K from a_y = s vx (beta_dot + r), beta = delta - lf r/vx - alpha_f.

    ``alpha_f = T_align,corr / (2K)`` with the friction and offset of pass 1; the road-wheel angle
    corrected for the torsion twist and offset. Linear in (s, s/K)."""
    N, lf = base.steering.ratio, base.body.lf
    ta = t_align - N * p.friction * fric_sign - p.t0
    dc = delta_f - p.c_tb * t_col / N - p.d0
    u1 = vx * (np.gradient(dc - lf * r / vx, t) + r)
    u2 = vx * np.gradient(ta, t) / 2.0
    X = np.column_stack([u1[use], u2[use]])
    (a, b), *_ = np.linalg.lstsq(X, ay[use], rcond=None)
    if not (MIN_ACCEL_SCALE <= a <= MAX_ACCEL_SCALE and b < 0.0):
        raise CalibrationError(
            f"accelerometer scale {a:.3f} (or the aligning-torque slope) is implausible: "
            "check the lateral-acceleration signal and the steering ratio"
        )
    return float(a), float(-a / b)


def vehicle_toml(
    cal: Calibration,
    base: Vehicle,
    name: str = "calibrated",
    log: str = "",
    corrections: bool = True,
    tires: bool = True,
) -> str:
    """A vehicle file that ``extends`` the base vehicle and overrides ``[tires]`` and (with
    ``corrections``) ``[corrections]`` (:mod:`lde.conditioning`) with the calibration.

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
        "# bicycle-model equations over a drive without disturbance (src/lde/calibrate.py).",
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
            "[corrections]           # removed from the inputs before the step (src/lde/conditioning.py)",
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


def _lstsq(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Least squares with unit-norm columns: (coefficients, condition number, X)."""
    col = np.linalg.norm(X, axis=0)
    if np.any(col == 0.0):
        raise CalibrationError("no lateral excitation in the drive (no steering)")
    c, *_ = np.linalg.lstsq(X / col, y, rcond=None)
    return c / col, float(np.linalg.cond(X / col)), X


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
