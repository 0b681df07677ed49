"""Accuracy metrics of the disturbance estimate against the simulator's truth (issue 6, item 1).

All inputs are SI: time [s], force [N], moment [Nm]; ISO 8855 signs (left positive). Pure
functions on numpy arrays: no I/O, no clock.

The figure of merit per scenario (after a settling window, default 2 s from the first estimate):

    e_F = Fw_hat - Fw                    e_M = Mw_hat - Mw
    NRMSE_F = RMS(e_F) / max|Fw|         NRMSE_M = RMS(e_M) / max|Mw|

with ``Mw`` the yaw moment about the vehicle's *actual* CG, as in the paper (SPEC section 2). The
same figure with ``Mw_ref`` (the moment about the unloaded reference CG) is reported beside it.
Two scenario kinds need another denominator:

- no yaw moment (a bank only: the gravity component acts at the CG, so ``Mw`` about the actual
  CG is zero): ``NRMSE_M = RMS(e_M) / (1 m * max|Fw|)`` (:data:`MOMENT_ARM_M`);
- no disturbance at all (a lane change on a flat road in still air): no ratio is defined; the
  figures are the RMS of the estimate itself, ``RMS(Fw_hat)`` [N] and ``RMS(Mw_hat)`` [Nm].

The kind is decided from the truth with the thresholds :data:`ZERO_FORCE_N` and
:data:`ZERO_MOMENT_FRACTION` (:func:`classify`), or given by the caller.

Accuracy targets of issue 11 (:class:`Target`, :func:`target_figures`, :func:`meets`): on a
crosswind/bank scenario the NRMSE of Fw and of Mw, with Mw about the CG the estimator's vehicle file
states (the truth's ``Mw_ref``: for a car carrying a payload, the unloaded car's CG; without payload
``Mw_ref = Mw``); on a disturbance-free drive the RMS of the estimate in N and Nm. Cold
(:data:`COLD`: only the spec-sheet vehicle file) <= 10 % and <= 60 N / 20 Nm; warm (:data:`WARM`:
after learning on an earlier drive of the same car) <= 5 % and <= 20 N / 8 Nm, and <= 10 %
(:data:`WARM_DEFECTS`) with rack friction, sensor offsets, a rough driver, an 800 m curve or speed
ramps. Wind apart from bank (:func:`split_accuracy`, :data:`WIND_MAX_NRMSE`, :data:`BANK_MAX_RMS_DEG`):
the NRMSE of the wind's force ``Fw_wind`` against the truth's crosswind force (where the truth has
wind), and the RMS error of the bank angle in degrees.

Error index of the parameter study (paper eq. 19):

    J = q1 RMS(e_F) + q2 RMS(e_M)

with ``q1 = 1`` (per N) and ``q2 = 1 / (1 m)`` (per Nm): a yaw-moment error of 1 Nm weighs as
much as a force error of 1 N acting 1 m from the CG, about the distance from the CG to the front
axle; J is then in N. Over several load cases the study averages the per-case J
(:func:`mean_error_index`), so that each case counts once whatever its length.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np

from lde.errors import LdeError

#: settling window after the first estimate [s] (issue 6: "after a 2 s settling window")
SETTLE_S = 2.0
#: lever arm turning max|Fw| into a moment scale when the truth has no yaw moment [m]
MOMENT_ARM_M = 1.0
#: a truth force below this everywhere [N] counts as "no disturbance force"
ZERO_FORCE_N = 20.0
#: a truth moment below this fraction of (1 m * max|Fw|) counts as "no yaw moment"
ZERO_MOMENT_FRACTION = 0.02
#: eq. (19) weights: q1 [1/N], q2 [1/Nm] (J in N, see the module docstring)
Q1_PER_N = 1.0
Q2_PER_NM = 1.0 / MOMENT_ARM_M


class MetricsError(LdeError, ValueError):
    """Arrays that cannot be compared (lengths, non-finite values, nothing left after settling)."""


class Kind(enum.Enum):
    """How a scenario's errors are normalised."""

    DISTURBED = "disturbed"  #: force and moment: RMS / max|truth|
    FORCE_ONLY = "force_only"  #: no yaw moment (bank): moment error / (1 m * max|Fw|)
    UNDISTURBED = "undisturbed"  #: no disturbance: RMS of the estimate in N and Nm


@dataclass(frozen=True)
class Truth:
    """The simulator's ground truth on its own time base.

    Attributes:
        t: time [s], strictly increasing, the same time base as the estimates.
        fw: lateral disturbance force at the CG [N].
        mw: disturbance yaw moment about the actual CG [Nm].
        mw_ref: disturbance yaw moment about the unloaded reference CG [Nm] (= mw without payload).
        fw_wind: the crosswind's lateral force [N], left positive (None: not known).
        bank: road bank angle [rad], road's left side lower positive (None: not known).
    """

    t: np.ndarray
    fw: np.ndarray
    mw: np.ndarray
    mw_ref: np.ndarray
    fw_wind: np.ndarray | None = None
    bank: np.ndarray | None = None


@dataclass(frozen=True)
class Accuracy:
    """Accuracy of one run after the settling window. ``nrmse_*`` are fractions (0.05 = 5 %).

    ``rms_*`` are RMS errors (estimate minus truth) [N, Nm]; for an undisturbed scenario the truth is
    zero, so they are the RMS of the estimate. ``scale_*`` are the denominators [N, Nm] (NaN for
    an undisturbed scenario, whose ``nrmse_*`` are NaN too). ``mw_ref`` compares the moment estimate
    with the truth about the unloaded reference CG.
    """

    kind: Kind
    n: int
    rms_fw: float
    rms_mw: float
    rms_mw_ref: float
    scale_fw: float
    scale_mw: float
    scale_mw_ref: float
    nrmse_fw: float
    nrmse_mw: float
    nrmse_mw_ref: float

    @property
    def j(self) -> float:
        """The eq. (19) error index of this run [N] with the default weights."""
        return error_index(self.rms_fw, self.rms_mw)

    def as_row(self) -> dict[str, float | int | str]:
        """A flat mapping for CSV output (fractions as is, not percent)."""
        return {
            "kind": self.kind.value,
            "n": self.n,
            "rms_fw_N": self.rms_fw,
            "rms_mw_Nm": self.rms_mw,
            "rms_mw_ref_Nm": self.rms_mw_ref,
            "scale_fw_N": self.scale_fw,
            "scale_mw_Nm": self.scale_mw,
            "nrmse_fw": self.nrmse_fw,
            "nrmse_mw": self.nrmse_mw,
            "nrmse_mw_ref": self.nrmse_mw_ref,
            "J_N": self.j,
        }


def rms(x: np.ndarray) -> float:
    """sqrt(mean(x^2)) of a non-empty array."""
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        raise MetricsError("RMS of an empty array")
    return float(np.sqrt(np.mean(x * x)))


def nrmse(estimate: np.ndarray, truth: np.ndarray, scale: float | None = None) -> float:
    """RMS(estimate - truth) / scale, scale defaulting to max|truth| (must be > 0)."""
    e, y = _same_length(estimate, truth)
    s = float(np.max(np.abs(y))) if scale is None else float(scale)
    if not (s > 0.0 and math.isfinite(s)):
        raise MetricsError(f"NRMSE needs a positive finite scale, got {s!r}")
    return rms(e - y) / s


def error_index(rms_f: float, rms_m: float, q1: float = Q1_PER_N, q2: float = Q2_PER_NM) -> float:
    """Paper eq. (19): J = q1 RMS(e_F) + q2 RMS(e_M) [N with the default weights]."""
    return q1 * float(rms_f) + q2 * float(rms_m)


def mean_error_index(
    pairs: Iterable[tuple[float, float]], q1: float = Q1_PER_N, q2: float = Q2_PER_NM
) -> float:
    """Mean over load cases of the per-case eq. (19) index; ``pairs`` = (RMS e_F, RMS e_M) per case."""
    js = [error_index(f, m, q1, q2) for f, m in pairs]
    if not js:
        raise MetricsError("error index over no cases")
    return float(np.mean(js))


def classify(fw: np.ndarray, mw: np.ndarray) -> Kind:
    """The scenario kind from the truth (thresholds :data:`ZERO_FORCE_N`, :data:`ZERO_MOMENT_FRACTION`).

    A pure yaw moment with no force never occurs with crosswind or bank; it is treated as
    DISTURBED (its force error is then normalised by max|Mw| / 1 m, see :func:`accuracy`).
    """
    f = float(np.max(np.abs(fw))) if np.size(fw) else 0.0
    m = float(np.max(np.abs(mw))) if np.size(mw) else 0.0
    if f < ZERO_FORCE_N and m < ZERO_FORCE_N * MOMENT_ARM_M:
        return Kind.UNDISTURBED
    if m < ZERO_MOMENT_FRACTION * MOMENT_ARM_M * f:
        return Kind.FORCE_ONLY
    return Kind.DISTURBED


def settled_mask(t: np.ndarray, settle: float = SETTLE_S, t0: float | None = None) -> np.ndarray:
    """True where ``t >= t0 + settle`` [s]; ``t0`` defaults to the first time in ``t``."""
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        return np.zeros(0, dtype=bool)
    start = float(t[0]) if t0 is None else float(t0)
    return t >= start + settle


def truth_at(truth: Truth, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Truth (Fw, Mw, Mw_ref) linearly interpolated at times ``t`` [s] (held beyond the ends)."""
    tt = np.asarray(truth.t, dtype=np.float64)
    if tt.size < 1 or np.any(np.diff(tt) <= 0.0):
        raise MetricsError("truth time must be non-empty and strictly increasing")
    t = np.asarray(t, dtype=np.float64)
    return (
        np.interp(t, tt, np.asarray(truth.fw, dtype=np.float64)),
        np.interp(t, tt, np.asarray(truth.mw, dtype=np.float64)),
        np.interp(t, tt, np.asarray(truth.mw_ref, dtype=np.float64)),
    )


def accuracy(
    t: np.ndarray,
    fw_hat: np.ndarray,
    mw_hat: np.ndarray,
    truth: Truth,
    *,
    settle: float = SETTLE_S,
    valid: np.ndarray | None = None,
    kind: Kind | None = None,
) -> Accuracy:
    """Accuracy of estimates ``(t [s], Fw_hat [N], Mw_hat [Nm])`` against ``truth``.

    Samples earlier than ``settle`` seconds after the first estimate, and samples where ``valid`` is
    False (e.g. the estimator's VALID status bit), are dropped. ``kind`` defaults to
    :func:`classify` on the truth over the kept samples.
    """
    t = np.asarray(t, dtype=np.float64)
    fw_hat, mw_hat = np.asarray(fw_hat, dtype=np.float64), np.asarray(mw_hat, dtype=np.float64)
    if not (t.shape == fw_hat.shape == mw_hat.shape) or t.ndim != 1:
        raise MetricsError(
            f"t, Fw, Mw must be 1-D of one length, got {t.shape}, {fw_hat.shape}, {mw_hat.shape}"
        )
    keep = settled_mask(t, settle)
    if valid is not None:
        valid = np.asarray(valid, dtype=bool)
        if valid.shape != t.shape:
            raise MetricsError(f"valid mask shape {valid.shape} != {t.shape}")
        keep &= valid
    keep &= np.isfinite(fw_hat) & np.isfinite(mw_hat)
    n = int(np.count_nonzero(keep))
    if n == 0:
        raise MetricsError(f"no valid estimate after the {settle:g} s settling window")
    fw, mw, mw_ref = truth_at(truth, t[keep])
    ef, em, em_ref = fw_hat[keep] - fw, mw_hat[keep] - mw, mw_hat[keep] - mw_ref
    k = classify(fw, mw) if kind is None else kind
    max_f = float(np.max(np.abs(fw)))
    if k is Kind.UNDISTURBED:
        s_f = s_m = s_mref = math.nan
    elif k is Kind.FORCE_ONLY:
        s_f = max_f
        s_m = MOMENT_ARM_M * max_f
        # about the reference CG a payload makes a moment d x Fw: normalise like a yawing case
        s_mref = max(float(np.max(np.abs(mw_ref))), s_m)
    else:
        # a pure moment (no force) cannot come from wind or bank; scale its force error like a bank's
        s_f = max_f if max_f >= ZERO_FORCE_N else float(np.max(np.abs(mw))) / MOMENT_ARM_M
        s_m = float(np.max(np.abs(mw)))
        s_mref = float(np.max(np.abs(mw_ref)))
    return Accuracy(
        kind=k,
        n=n,
        rms_fw=rms(ef),
        rms_mw=rms(em),
        rms_mw_ref=rms(em_ref),
        scale_fw=s_f,
        scale_mw=s_m,
        scale_mw_ref=s_mref,
        nrmse_fw=_ratio(rms(ef), s_f),
        nrmse_mw=_ratio(rms(em), s_m),
        nrmse_mw_ref=_ratio(rms(em_ref), s_mref),
    )


@dataclass(frozen=True)
class Target:
    """An accuracy target: NRMSE bound on crosswind/bank scenarios (Fw and Mw, fractions), RMS
    bounds on a disturbance-free drive [N, Nm]."""

    name: str
    max_nrmse: float
    max_rms_fw: float
    max_rms_mw: float

    def describe(self) -> str:
        return (
            f"{self.name}: NRMSE <= {100 * self.max_nrmse:g} % Fw and Mw on crosswind/bank scenarios, "
            f"RMS <= {self.max_rms_fw:g} N / {self.max_rms_mw:g} Nm on a disturbance-free drive"
        )


#: issue 11: cold (only the spec-sheet vehicle file)
COLD = Target("cold", 0.10, 60.0, 20.0)
#: issue 11: warm (after learning on an earlier drive of the same car)
WARM = Target("warm", 0.05, 20.0, 8.0)
#: issue 11: warm with 0.4-0.8 Nm friction, gyro bias and angle offset, a rough driver, an 800 m
#: curve, speed ramps (the disturbance-free bounds are the warm ones)
WARM_DEFECTS = Target("warm, with defects", 0.10, 20.0, 8.0)


def target_figures(acc: Accuracy, file_cg_is_true: bool = False) -> tuple[float, float]:
    """The two figures a :class:`Target` bounds: (NRMSE Fw, NRMSE Mw about the vehicle file's CG)
    as fractions, or for a disturbance-free drive (RMS Fw [N], RMS Mw [Nm]). The vehicle file's CG
    is the unloaded car's (the truth's ``Mw_ref``) unless ``file_cg_is_true`` (a file that carries
    the load: the truth's ``Mw``, about the actual CG)."""
    if acc.kind is Kind.UNDISTURBED:
        return acc.rms_fw, acc.rms_mw
    return acc.nrmse_fw, acc.nrmse_mw if file_cg_is_true else acc.nrmse_mw_ref


def meets(acc: Accuracy, target: Target, file_cg_is_true: bool = False) -> bool:
    """Whether a run's accuracy meets ``target`` (:func:`target_figures` against its bounds)."""
    f, m = target_figures(acc, file_cg_is_true)
    if acc.kind is Kind.UNDISTURBED:
        return f <= target.max_rms_fw and m <= target.max_rms_mw
    return f <= target.max_nrmse and m <= target.max_nrmse


#: a long drive is scored per window of this length [s] (a late minute cannot hide behind a good
#: average) and as a whole from :data:`LONG_SCORED_FROM_S` on
LONG_WINDOW_S = 60.0
#: a long (first) drive's score starts here [s after the first estimate]: the learner's first minute
LONG_SCORED_FROM_S = 120.0
#: a drive at least this long [s] gets the per-window figures (:func:`long_drive`)
LONG_DRIVE_MIN_S = 180.0


@dataclass(frozen=True)
class LongDrive:
    """A long drive's figures: the whole from :data:`LONG_SCORED_FROM_S` (``scored``), one
    :class:`Accuracy` per :data:`LONG_WINDOW_S` window from the first estimate (``windows``; a window
    with too few valid samples is None), and when the learner first reported "learned"
    (``learned_s``, seconds after the first estimate; NaN: never, or not reported)."""

    scored: Accuracy
    windows: tuple[Accuracy | None, ...]
    learned_s: float


def long_drive(
    t: np.ndarray,
    fw_hat: np.ndarray,
    mw_hat: np.ndarray,
    truth: Truth,
    *,
    valid: np.ndarray | None = None,
    learn_state: np.ndarray | None = None,
    learned: int = 2,
) -> LongDrive:
    """Per-window and from-minute-2 accuracy of a long drive (each window normalised by its own
    max |truth|, :func:`accuracy` with no settling inside the window), and the first time
    ``learn_state`` equals ``learned`` (the learner's ``ST_LEARNED``)."""
    t = np.asarray(t, dtype=np.float64)
    if t.size == 0:
        raise MetricsError("a long drive without estimates")
    t0 = float(t[0])
    scored = accuracy(t, fw_hat, mw_hat, truth, settle=LONG_SCORED_FROM_S, valid=valid)
    wins: list[Accuracy | None] = []
    n_win = int(math.ceil((float(t[-1]) - t0) / LONG_WINDOW_S - 1e-9))
    fw_hat, mw_hat = np.asarray(fw_hat, dtype=np.float64), np.asarray(mw_hat, dtype=np.float64)
    for i in range(n_win):
        sel = (t >= t0 + i * LONG_WINDOW_S) & (t < t0 + (i + 1) * LONG_WINDOW_S)
        ok = sel if valid is None else sel & np.asarray(valid, dtype=bool)
        if np.count_nonzero(ok) < 10:
            wins.append(None)
            continue
        wins.append(accuracy(t[sel], fw_hat[sel], mw_hat[sel], truth, settle=0.0, valid=ok[sel]))
    learned_s = math.nan
    if learn_state is not None:
        hit = np.flatnonzero(np.asarray(learn_state) == learned)
        if hit.size:
            learned_s = float(t[hit[0]]) - t0
    return LongDrive(scored, tuple(wins), learned_s)


#: issue 11: the wind's force within 10 % (NRMSE of Fw_wind, where the truth has wind)
WIND_MAX_NRMSE = 0.10
#: issue 11: bank angle RMS error at most 0.3 deg
BANK_MAX_RMS_DEG = 0.3
#: a truth crosswind force below this everywhere [N] counts as "no wind" (the car's own side slip
#: makes a few tens of newtons of aero side force on a large car)
WIND_MIN_N = 50.0


@dataclass(frozen=True)
class SplitAccuracy:
    """Wind apart from bank, after the settling window.

    Attributes:
        wind_nrmse: RMS(Fw_wind_hat - Fw_wind) / max|Fw_wind| (fraction; NaN when the truth has no
            wind, max below :data:`WIND_MIN_N`, or the estimate does not tell wind from bank).
        wind_scale: max|Fw_wind| of the truth [N].
        bank_rms_deg: RMS(bank_hat - bank) [deg] (NaN when the estimate does not tell).
    """

    wind_nrmse: float
    wind_scale: float
    bank_rms_deg: float

    def wind_met(self) -> bool | None:
        """Wind force within :data:`WIND_MAX_NRMSE` (None: not applicable)."""
        return None if math.isnan(self.wind_nrmse) else self.wind_nrmse <= WIND_MAX_NRMSE

    def bank_met(self) -> bool | None:
        """Bank RMS within :data:`BANK_MAX_RMS_DEG` (None: not applicable)."""
        return None if math.isnan(self.bank_rms_deg) else self.bank_rms_deg <= BANK_MAX_RMS_DEG


def split_accuracy(
    t: np.ndarray,
    fw_wind_hat: np.ndarray,
    bank_hat: np.ndarray,
    truth: Truth,
    *,
    settle: float = SETTLE_S,
    valid: np.ndarray | None = None,
) -> SplitAccuracy:
    """Accuracy of the wind force ``Fw_wind_hat`` [N] and the bank angle ``bank_hat`` [rad] at
    times ``t`` [s] against the truth's ``fw_wind`` and ``bank`` (samples kept as in
    :func:`accuracy`; a non-finite estimate everywhere gives NaN: the backend does not tell)."""
    if truth.fw_wind is None or truth.bank is None:
        raise MetricsError("the truth has no wind force or bank angle")
    t = np.asarray(t, dtype=np.float64)
    wh, bh = np.asarray(fw_wind_hat, dtype=np.float64), np.asarray(bank_hat, dtype=np.float64)
    if not (t.shape == wh.shape == bh.shape) or t.ndim != 1:
        raise MetricsError(
            f"t, Fw_wind, bank must be 1-D of one length, got {t.shape}, {wh.shape}, {bh.shape}"
        )
    keep = settled_mask(t, settle)
    if valid is not None:
        keep &= np.asarray(valid, dtype=bool)
    if not keep.any():
        raise MetricsError(f"no valid estimate after the {settle:g} s settling window")
    tt = np.asarray(truth.t, dtype=np.float64)
    w = np.interp(t[keep], tt, np.asarray(truth.fw_wind, dtype=np.float64))
    b = np.interp(t[keep], tt, np.asarray(truth.bank, dtype=np.float64))
    wk, bk = wh[keep], bh[keep]
    scale = float(np.max(np.abs(w)))
    wind = math.nan
    if scale >= WIND_MIN_N and np.all(np.isfinite(wk)):
        wind = rms(wk - w) / scale
    bank = float(np.degrees(rms(bk - b))) if np.all(np.isfinite(bk)) else math.nan
    return SplitAccuracy(wind, scale, bank)


def format_table(rows: Sequence[dict[str, object]], columns: Sequence[tuple[str, str, str]]) -> str:
    """A plain-text table. ``columns`` = (key, header, format spec); ``%`` specs print fractions as %."""
    cells = [[h for _, h, _ in columns]]
    for r in rows:
        line = []
        for key, _, spec in columns:
            v = r.get(key, "")
            if isinstance(v, float) and not math.isfinite(v):
                line.append("-")
            elif spec and isinstance(v, (int, float)):
                line.append(format(v, spec))
            else:
                line.append(str(v))
        cells.append(line)
    widths = [max(len(c[i]) for c in cells) for i in range(len(columns))]
    out = []
    for i, c in enumerate(cells):
        out.append("  ".join(s.rjust(w) if i else s.ljust(w) for s, w in zip(c, widths, strict=True)))
        if i == 0:
            out.append("  ".join("-" * w for w in widths))
    return "\n".join(out)


def _ratio(num: float, den: float) -> float:
    if not math.isfinite(den):
        return math.nan
    if den <= 0.0:
        raise MetricsError("NRMSE scale is zero: the truth has no disturbance of this kind")
    return num / den


def _same_length(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise MetricsError(f"arrays of different shapes {a.shape} and {b.shape}")
    return a, b
