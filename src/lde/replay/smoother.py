"""The offline smoother (``lde replay --smooth``): the Rauch-Tung-Striebel (RTS) estimate of the
lateral filter over a whole log, for analysis (non-causal: step k uses every later step too).

Two passes over the same inputs on the same step grid as the causal replay:

1. **Forward** (:class:`TracingEngine`): the float lateral filter and its learner (backend ``float``,
   :func:`lde.engine.backends.float.step`, unchanged) in the one data path, plus a trace row per step of
   what the backward pass needs: the a-priori state and covariance the step propagated to
   (``x_{k+1|k}``, ``P_{k+1|k}``), the transition ``Phi_k`` it used, its input term ``E_k u_k``, its
   process noise ``Qd`` and whether it propagated at all (a held step: low speed, ESC fault). The
   traced step is registered for its own state class (:class:`TracedState`), so the one compiled loop
   has a specialisation for it, used only here. The trace goes to a temporary file
   (:class:`TraceSpill`) chunk by chunk, so memory does not grow with the log.
2. **Backward** (:func:`rts_backward`): per step, newest first::

       x_k|k = Phi^-1 (x_{k+1|k} - E u)            P_k|k = Phi^-1 (P_{k+1|k} - Qd) Phi^-T
       C     = P_k|k Phi^T P_{k+1|k}^-1
       x_k|N = x_k|k + C (x_{k+1|N} - x_{k+1|k})   P_k|N = P_k|k + C (P_{k+1|N} - P_{k+1|k}) C^T

   The filtered state is recovered from the step's own propagation (``Phi = I + A dt`` has the
   identity in its disturbance rows and a 2x2 vehicle block that is invertible at any speed the
   filter runs at), so the causal kernel needs no extra output. Across a held step the filter does
   not propagate and restarts with ``P0``: the smoother does not carry information across a hold
   (each run of propagating steps is smoothed on its own; a held step's smoothed value is its
   filtered one).

**The learner**: the forward pass runs the filter with the parameters as they were learned at each
step (the pushes every 0.5 s change ``Phi``; the trace keeps the ``Phi_k`` actually used). RTS is
the exact smoother of that time-varying linear model, so the smoothed estimate differs from the
causal float estimate by the smoothing alone, and the two can be compared step by step. Freezing
the end-of-log parameters instead would mix a second, different estimator (a re-filter with learned
tires) into the comparison.

**The fixed backend**: the smoother is float analysis. With ``--backend fixed`` the causal columns
are the fixed-point model's; the smoothed columns are those of the float lateral filter on the same
inputs (the filter the fixed model is checked against within 5 N / 2 Nm at every step). The paper's
4-state backends have no smoother.

filterpy's ``rts_smoother`` is the reference in the tests (same matrices, same answer); it is not
used here: it has no input term ``E u`` in its backward step (our model has the steering input), it
needs every step's F, Q, x and P in memory at once (about 0.7 GB for one hour of steps), and it
is a Python loop (``bench/bench_smoother.py`` measures it on one hour of steps).
"""

from __future__ import annotations

import math
import shutil
import tempfile
import time
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from lde.can.frames import FrameBatch
from lde.can.profiles import Profile
from lde.engine.backends import BACKENDS, Backend, BackendState, get_backend
from lde.engine.backends import float as float_backend
from lde.engine.engine import Engine, StepBlock, recorded_steps
from lde.engine.loop import register_step
from lde.engine.receiver import I_SPEED
from lde.errors import ConfigError, LogFormatError
from lde.estimator import lateral as E
from lde.params import Vehicle
from lde.replay.columns import SMOOTHED

__all__ = [
    "SMOOTHED",
    "NS",
    "NT",
    "TracingEngine",
    "TraceSpill",
    "SmoothTrack",
    "rts_backward",
    "smooth_run",
    "check_backend",
]

NX = E.NX

# --- a trace row (float64): what the backward pass needs of one forward step ---------------------
T_PROP = 0  # 1.0: the step propagated (0.0: held, no propagation)
T_F = 1  # Phi entries f00, f01, f02, f04, f10, f11, f13 (rows 2-4 of Phi are the identity)
T_EU = 8  # E u: the input's part of x_{k+1|k}, rows 0 and 1
T_Q = 10  # Qd diagonal (5)
T_X = 15  # x_{k+1|k} (5); a held step: its (held) state
T_P = 20  # P_{k+1|k}, upper triangle row by row (15)
NT = 35

# --- a smoothed row (float64, SI): the columns of the output -------------------------------------
S_FW, S_MW, S_FW_WIND, S_MW_WIND, S_BANK = range(5)
NS = 5  # in the order of SMOOTHED (lde.replay.columns): names, CSV decimals, units and meanings


def check_backend(name: str) -> None:
    """ConfigError unless ``name`` (a registered backend's name) runs the lateral filter (its
    module's ``SMOOTHABLE``: the smoothed float filter stands beside its estimate)."""
    if not get_backend(name).smoothable:
        able = ", ".join(b.name for b in BACKENDS.values() if b.smoothable)
        raise ConfigError(
            f"--smooth smooths the lateral filter (backend {able}); backend {name!r} has no smoother"
        )


# ------------------------------------------------------------------------------ forward: tracing


class TracedState(NamedTuple):
    """The float backend's state and the trace of the steps of one compiled call."""

    inner: float_backend.State  # the float backend's state (the filter and the learner)
    trace: np.ndarray  # (rows, NT) trace rows (T_* layout), one per step of the call
    tt: np.ndarray  # (rows,) int64 their step times [ns]
    cnt: np.ndarray  # (2,) int64 rows written, 1 when a row did not fit

    @property
    def p(self) -> np.ndarray:
        """The filter's parameter vector (a learning backend's ``p``)."""
        return self.inner.p

    @property
    def ls(self) -> np.ndarray:
        """The learner's state (a learning backend's ``ls``)."""
        return self.inner.ls


@njit(cache=True)
def traced_step(params, state, t_ns, inp, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
    """:func:`lde.engine.backends.float.step` (the float filter and the learner, unchanged), then one
    trace row (``T_*`` layout) into ``state.trace``; a full buffer sets the overflow slot."""
    st, trace, tt, cnt = state.inner, state.trace, state.tt, state.cnt
    p, f = st.p, st.filter
    x, P, fs, ints = f.x, f.P, f.fs, f.ints
    # the transition of this step, from the parameters before the learner may push after it
    vx = inp[I_SPEED]
    m, iz, lf, lr, dt = p[E.P_M], p[E.P_IZ], p[E.P_LF], p[E.P_LR], p[E.P_DT]
    cf, cr = p[E.P_CF], p[E.P_CR]
    status = float_backend.step(params, st, t_ns, inp, fresh, mdps_ok, esc_ok, out)
    c = cnt[0]
    if c >= trace.shape[0]:
        cnt[1] = 1
        return status
    row = trace[c]
    tt[c] = t_ns
    prop = ints[E.I_HELD] == 0  # a held step returns before the propagation with HELD set
    row[T_PROP] = 1.0 if prop else 0.0
    if prop:
        a00, a01, a0f, a10, a11, a13, b0, b1 = E.propagation_coefficients(m, iz, lf, lr, cf, cr, vx)
        delta = fs[E.F_DELTA]
        row[T_F + 0] = 1.0 + a00 * dt
        row[T_F + 1] = a01 * dt
        row[T_F + 2] = a0f * dt
        row[T_F + 3] = a0f * dt
        row[T_F + 4] = a10 * dt
        row[T_F + 5] = 1.0 + a11 * dt
        row[T_F + 6] = a13 * dt
        row[T_EU + 0] = b0 * dt * delta
        row[T_EU + 1] = b1 * dt * delta
        row[T_Q + 0] = p[E.P_QB] * dt
        row[T_Q + 1] = p[E.P_QR] * dt
        row[T_Q + 2] = p[E.P_QFA] * dt
        row[T_Q + 3] = p[E.P_QMA] * dt
        row[T_Q + 4] = p[E.P_QFB] * dt
    for i in range(NX):
        row[T_X + i] = x[i]
    k = T_P
    for i in range(NX):
        for j in range(i, NX):
            row[k] = P[i, j]
            k += 1
    cnt[0] = c + 1
    return status


register_step(TracedState, traced_step)


def _make_traced(
    vehicle: Vehicle, dt: float, angle_above_torsion_bar: bool, torque_scale: int = 0
) -> tuple[Any, TracedState]:
    params, inner = float_backend.make(vehicle, dt, angle_above_torsion_bar, torque_scale)
    return params, TracedState(inner, np.zeros((0, NT)), np.zeros(0, np.int64), np.zeros(2, np.int64))


#: the float backend traced for the smoother (not in the registry: only TracingEngine makes it)
TRACED = Backend(
    "float",
    "the lateral filter with the learner, traced for the RTS smoother",
    _make_traced,
    TracedState,
    learns=True,
    smoothable=True,
)


class TraceSpill:
    """The forward pass's trace rows (``NT`` float64 each) and step times, appended to files in a
    temporary directory (``workdir``: where; default the system's), read back newest first."""

    def __init__(self, workdir: str | Path | None = None) -> None:
        try:
            self.dir = Path(tempfile.mkdtemp(prefix="lde-smooth-", dir=workdir))
            self._fx = open(self.dir / "trace.f8", "wb")  # noqa: SIM115 - closed by finish()
            self._ft = open(self.dir / "t.i8", "wb")  # noqa: SIM115
        except OSError as exc:
            raise LogFormatError(f"--smooth: cannot write its temporary files: {exc}") from exc
        self.n = 0

    def append(self, rows: np.ndarray, t_ns: np.ndarray) -> None:
        try:
            rows.tofile(self._fx)
            t_ns.tofile(self._ft)
        except OSError as exc:
            raise LogFormatError(f"--smooth: cannot write its temporary files in {self.dir}: {exc}") from exc
        self.n += len(t_ns)

    def finish(self) -> None:
        self._fx.close()
        self._ft.close()

    def read(self, a: int, b: int) -> np.ndarray:
        """Trace rows [a, b)."""
        return np.fromfile(self.dir / "trace.f8", np.float64, (b - a) * NT, offset=a * NT * 8).reshape(-1, NT)

    def remove(self) -> None:
        for fh in (self._fx, self._ft):
            if not fh.closed:
                fh.close()
        shutil.rmtree(self.dir, ignore_errors=True)


class TracingEngine(Engine):
    """The data path (:class:`lde.engine.engine.Engine`) with backend ``float`` traced for the smoother:
    the same rows as an ``Engine(..., "float")``; after every compiled call the trace rows of its steps
    go to ``spill``."""

    def __init__(
        self, profile: Profile, vehicle: Vehicle, spill: TraceSpill, *, explicit: bool = False
    ) -> None:
        self.spill = spill
        super().__init__(profile, vehicle, "float", explicit=explicit, encode_outputs=False)

    def _new_backend_state(self) -> BackendState:
        params, state = _make_traced(
            self.vehicle, self._dt, self.profile.angle_above_torsion_bar, self.torque_scale
        )
        return BackendState(TRACED, params, state)

    @property
    def m_g(self) -> float:
        """The vehicle's weight [N] (the bank force of 1 rad)."""
        return float(self.vehicle.body.mass * self.est.state.inner.p[E.P_G])

    def run_arrays(self, *args: Any, **kw: Any) -> tuple[int, int]:
        out: StepBlock = args[6] if len(args) > 6 else kw["out"]
        st = self.est.state
        if st.trace.shape[0] < len(out):  # one trace row per row the call may write
            st = st._replace(trace=np.zeros((len(out), NT)), tt=np.zeros(len(out), np.int64))
            self.est.state = st
        trace, tt, cnt = st.trace, st.tt, st.cnt
        cnt[:] = 0
        i, n = super().run_arrays(*args, **kw)
        if cnt[1] or cnt[0] != n:
            raise RuntimeError("smoother trace out of step with the rows")
        self.spill.append(trace[:n], tt[:n])
        return i, n


# ------------------------------------------------------------------------------ backward: RTS


@njit(cache=True, inline="always")
def _phi_inv_vec(f, v, y):  # pragma: no cover - compiled
    """y = Phi^-1 v for Phi = [[A, B], [0, I]] given by its 7 entries ``f`` (T_F order)."""
    u0 = v[0] - f[2] * v[2] - f[3] * v[4]
    u1 = v[1] - f[6] * v[3]
    det = f[0] * f[5] - f[1] * f[4]
    y[0] = (f[5] * u0 - f[1] * u1) / det
    y[1] = (f[0] * u1 - f[4] * u0) / det
    for i in range(2, NX):
        y[i] = v[i]


@njit(cache=True, inline="always")
def _phi_inv_sym(f, S, tmp, out, col, res):  # pragma: no cover - compiled
    """out = Phi^-1 S Phi^-T (S symmetric)."""
    for j in range(NX):
        for i in range(NX):
            col[i] = S[i, j]
        _phi_inv_vec(f, col, res)
        for i in range(NX):
            tmp[i, j] = res[i]
    for i in range(NX):
        for j in range(NX):
            col[j] = tmp[i, j]
        _phi_inv_vec(f, col, res)
        for j in range(NX):
            out[i, j] = res[j]
    for i in range(NX):
        for j in range(i + 1, NX):
            s = 0.5 * (out[i, j] + out[j, i])
            out[i, j] = s
            out[j, i] = s


@njit(cache=True, inline="always")
def _spd_inverse(A, L, inv):  # pragma: no cover - compiled
    """inv = A^-1 of a symmetric positive definite A (Cholesky); False if A is not."""
    for j in range(NX):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        L[j, j] = math.sqrt(s)
        for i in range(j + 1, NX):
            s = A[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    # inv = L^-T L^-1, column by column: solve L y = e_c, then L^T z = y
    for c in range(NX):
        for i in range(NX):
            s = 1.0 if i == c else 0.0
            for k in range(i):
                s -= L[i, k] * inv[k, c]
            inv[i, c] = s / L[i, i]
        for i in range(NX - 1, -1, -1):
            s = inv[i, c]
            for k in range(i + 1, NX):
                s -= L[k, i] * inv[k, c]
            inv[i, c] = s / L[i, i]
    return True


@njit(cache=True, inline="always")
def _matmul(A, B, out):  # pragma: no cover - compiled
    """``out = A B`` for the square state matrices (no allocation; ``out`` is neither input)."""
    n = A.shape[0]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for m in range(n):
                s += A[i, m] * B[m, j]
            out[i, j] = s


@njit(cache=True)
def rts_backward(tr, xs, Ps, have, out_x, out_p, out_f):  # pragma: no cover - compiled
    """The RTS backward pass over trace rows ``tr`` (n, NT), newest (row n-1) first.

    ``xs`` (NX,), ``Ps`` (NX, NX), ``have`` (1,): the smoothed state of the step after row n-1 and
    whether it continues row n-1's run (the carry between chunks; ``have[0] = 0`` at the log's end).
    Writes the smoothed state of every row into ``out_x`` (n, NX), its covariance's diagonal into
    ``out_p`` (n, NX) and the filtered state it recovered into ``out_f`` (n, NX), and leaves the
    carry for row 0 in ``xs``, ``Ps``, ``have``. Returns the
    number of steps where the predicted covariance was not positive definite (smoothed = filtered).
    """
    n = tr.shape[0]
    f = np.empty(7)
    Pp = np.empty((NX, NX))
    Pf = np.empty((NX, NX))
    Pi = np.empty((NX, NX))
    L = np.zeros((NX, NX))
    C = np.empty((NX, NX))
    T = np.empty((NX, NX))
    D = np.empty((NX, NX))
    xp = np.empty(NX)
    xf = np.empty(NX)
    v = np.empty(NX)
    col = np.empty(NX)
    res = np.empty(NX)
    bad = 0
    for k in range(n - 1, -1, -1):
        r = tr[k]
        for i in range(NX):
            xp[i] = r[T_X + i]
        if r[T_PROP] == 0.0:  # held: no propagation, no smoothing across it
            for i in range(NX):
                xs[i] = xp[i]
                out_x[k, i] = xp[i]
                out_f[k, i] = xp[i]
                out_p[k, i] = math.nan
            have[0] = 0
            continue
        for i in range(7):
            f[i] = r[T_F + i]
        q = T_P
        for i in range(NX):
            for j in range(i, NX):
                Pp[i, j] = r[q]
                Pp[j, i] = r[q]
                q += 1
        # the filtered state and covariance of step k, from its own propagation
        for i in range(NX):
            v[i] = xp[i]
        v[0] -= r[T_EU + 0]
        v[1] -= r[T_EU + 1]
        _phi_inv_vec(f, v, xf)
        for i in range(NX):
            for j in range(NX):
                D[i, j] = Pp[i, j]
            D[i, i] -= r[T_Q + i]
        _phi_inv_sym(f, D, T, Pf, col, res)
        if have[0] == 1 and _spd_inverse(Pp, L, Pi):
            # C = Pf Phi^T Pp^-1; T = Pf Phi^T first (Phi^T's columns: Phi's rows)
            for i in range(NX):
                t0 = Pf[i, 0] * f[0] + Pf[i, 1] * f[1] + Pf[i, 2] * f[2] + Pf[i, 4] * f[3]
                t1 = Pf[i, 0] * f[4] + Pf[i, 1] * f[5] + Pf[i, 3] * f[6]
                T[i, 0] = t0
                T[i, 1] = t1
                for j in range(2, NX):
                    T[i, j] = Pf[i, j]
            _matmul(T, Pi, C)
            # x = xf + C (xs - xp);  P = Pf + C (Ps - Pp) C^T
            for i in range(NX):
                v[i] = xs[i] - xp[i]
            for i in range(NX):
                s = xf[i]
                for j in range(NX):
                    s += C[i, j] * v[j]
                xs[i] = s
            for i in range(NX):
                for j in range(NX):
                    D[i, j] = Ps[i, j] - Pp[i, j]
            _matmul(C, D, T)
            for i in range(NX):
                for j in range(i, NX):
                    s = Pf[i, j]
                    for m in range(NX):
                        s += T[i, m] * C[j, m]
                    Ps[i, j] = s
                    Ps[j, i] = s
        else:  # the last propagating step of a run (or a degenerate Pp): smoothed = filtered
            if have[0] == 1:
                bad += 1
            for i in range(NX):
                xs[i] = xf[i]
                for j in range(NX):
                    Ps[i, j] = Pf[i, j]
        for i in range(NX):
            out_x[k, i] = xs[i]
            out_p[k, i] = Ps[i, i]
            out_f[k, i] = xf[i]
        have[0] = 1
    return bad


# ------------------------------------------------------------------------------ the two passes

_BACK_ROWS = 1 << 16


@dataclass
class SmoothTrack:
    """The smoothed outputs of a log (``NS`` float64 per step, :data:`SMOOTHED` order, SI: the bank
    in rad), in a temporary file, read forward block by block by the replay's sinks
    (:meth:`rows_for`), which check that the causal rows have the same step times."""

    dir: Path
    n: int
    bad: int = 0
    timings: dict[str, float] | None = None

    def __post_init__(self) -> None:
        self._pos = 0
        self._last: tuple[int, np.ndarray] | None = None

    def rows_for(self, block: StepBlock) -> np.ndarray:
        """The smoothed rows of ``block`` (the causal replay's next rows; two sinks asking for the
        same block get the same rows). RuntimeError if the step times differ (not the same grid)."""
        if self._last is not None and self._last[0] == id(block):
            return self._last[1]
        m = len(block)
        a, b = self._pos, self._pos + m
        if b > self.n:
            raise RuntimeError(f"smoothed run has {self.n} steps, the causal replay more")
        t = np.fromfile(self.dir / "t.i8", np.int64, m, offset=a * 8)
        if not np.array_equal(t, block.t_ns):
            raise RuntimeError("smoothed run and causal replay are not on the same step grid")
        rows = np.fromfile(self.dir / "smooth.f8", np.float64, m * NS, offset=a * NS * 8).reshape(m, NS)
        self._pos = b
        self._last = (id(block), rows)
        return rows

    def read_all(self) -> tuple[np.ndarray, np.ndarray]:
        """(step times [ns], smoothed rows (n, NS)) of the whole log, in memory."""
        t = np.fromfile(self.dir / "t.i8", np.int64)
        rows = np.fromfile(self.dir / "smooth.f8", np.float64).reshape(-1, NS)
        return t, rows

    def close(self) -> None:
        """Remove the temporary files."""
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> SmoothTrack:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _backward(
    spill: TraceSpill, m_g: float, x_cp: float = 0.0, w_cp: float = 0.0, chunk: int = _BACK_ROWS
) -> int:
    """The backward pass over the spilled trace, newest chunk first, into ``smooth.f8`` (the moment
    blended with the centre-of-pressure prior as the causal output:
    :func:`lde.estimator.lateral.wind_moment_output`)."""
    n = spill.n
    xs, Ps, have = np.zeros(NX), np.zeros((NX, NX)), np.zeros(1, np.int64)
    bad = 0
    path = spill.dir / "smooth.f8"
    with open(path, "wb") as fh:
        fh.truncate(n * NS * 8)
        b = n
        while b > 0:
            a = max(0, b - chunk)
            tr = spill.read(a, b)
            ox, op, of = np.empty((b - a, NX)), np.empty((b - a, NX)), np.empty((b - a, NX))
            bad += int(rts_backward(tr, xs, Ps, have, ox, op, of))
            out = np.empty((b - a, NS))
            out[:, S_FW] = ox[:, E.IX_FA] + ox[:, E.IX_FB]
            mw = ox[:, E.IX_MA]
            if w_cp > 0.0:  # as the causal output (lde.estimator.lateral.wind_moment_output)
                mw = E.blend_wind_moment(mw, ox[:, E.IX_FA], x_cp, w_cp)
            out[:, S_MW] = mw
            out[:, S_FW_WIND] = ox[:, E.IX_FA]
            out[:, S_MW_WIND] = mw
            out[:, S_BANK] = np.arcsin(np.clip(ox[:, E.IX_FB] / m_g, -1.0, 1.0))
            fh.seek(a * NS * 8)
            out.tofile(fh)
            b = a
    return bad


def smooth_run(
    pieces: Iterable[FrameBatch],
    profile: Profile,
    vehicle: Vehicle,
    *,
    step_times_ns: np.ndarray | None = None,
    overlay_enable: np.ndarray | None = None,
    extra_status: np.ndarray | None = None,
    learned: str | Path | None = None,
    learned_start: str | None = None,
    workdir: str | Path | None = None,
) -> SmoothTrack:
    """The forward (traced) and backward passes over a log's frames (``pieces`` in time order, as
    :func:`lde.replay.replay.run_replay` takes them, with the same step times / events): the smoothed
    outputs in a :class:`SmoothTrack` (close it when done). ``learned`` is read (when it exists),
    never written: the causal replay writes it."""
    t0 = time.perf_counter()
    spill = TraceSpill(workdir)
    try:
        explicit = step_times_ns is not None
        engine = TracingEngine(profile, vehicle, spill, explicit=explicit)
        if learned is not None and Path(learned).exists():
            engine.load_learned(learned)
        elif learned_start:
            engine.load_learned_text(learned_start, "the recording's learned start")
        first = True
        it = iter(pieces)
        while True:
            chunk = next(it, None)
            final = chunk is None
            kw: dict[str, Any] = {}
            if step_times_ns is not None and first:
                kw = recorded_steps(step_times_ns, overlay_enable, extra_status)
            first = False
            engine.feed(FrameBatch.empty() if chunk is None else chunk, final=final, **kw)
            if final:
                break
        spill.finish()
        t1 = time.perf_counter()
        pv = engine.est.state.inner.p
        bad = _backward(spill, engine.m_g, float(pv[E.P_XCP]), float(pv[E.P_WCP]))
        (spill.dir / "trace.f8").unlink()
    except BaseException:
        spill.remove()
        raise
    t2 = time.perf_counter()
    return SmoothTrack(spill.dir, spill.n, bad, {"smooth_forward": t1 - t0, "smooth_backward": t2 - t1})
