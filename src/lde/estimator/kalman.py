"""Float Kalman filter: numba-compiled kernels, pure wrappers, a small class.

The model (:mod:`lde.estimator.model`) is linear with a direct feedthrough of the input to the measurement:

    x_{k+1} = Phi_k x_k + E_k u_k + w_k,   w ~ N(0, Qd_k)
    z_k     = H_k x_k + D_k u_k + v_k,     v ~ N(0, R)

Update (paper eq. 16, with the a-posteriori estimate propagated: SPEC erratum 4; the gain matrix
``Kg`` here is not the aligning-torque rate K of eq. 12: erratum 9):

    y  = z - H x - D u                       innovation
    S  = H P H^T + R
    Kg = P H^T S^-1
    x  = x + Kg y
    P  = (I - Kg H) P (I - Kg H)^T + Kg R Kg^T     Joseph form: stays symmetric positive
                                                    semi-definite under rounding and for any gain
    P  = (P + P^T) / 2                               remove the last rounding asymmetry

Predict:

    x = Phi x + E u
    P = Phi P Phi^T + Qd

A measurement row can be left out of an update (``use[i] = False``: a faulty input group); the
update then runs on the remaining rows with the matching block of R (R may be full).

The kernels are written for the model's 4 states (``NX``) and up to 4 measurement rows.

Layers: ``*_inplace`` kernels (``@njit``, no allocation in the predict, used by :mod:`lde.estimator.paper`),
pure ``kf_predict`` / ``kf_update`` (``@njit``, return new arrays), the :class:`KalmanFilter` class
around them. The same filter on filterpy's ``KalmanFilter`` is :mod:`lde.kalman_reference` (tests and
the benchmark suite; kept out of this module because importing filterpy pulls in scipy.stats: ~1 s
of every start-up).
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: state dimension of every kernel here (the model's 4 states): a compile-time constant lets LLVM
#: unroll the small matrix loops (3x faster than loops bounded by ``x.shape[0]``)
NX = 4

# --- kernels ------------------------------------------------------------------------------------


@njit(cache=True)
def predict_inplace(x, P, Phi, Eu, Qd, tmp):  # pragma: no cover - compiled
    """x <- Phi x + Eu,  P <- Phi P Phi^T + Qd.  ``Eu`` is E u (4,); ``tmp`` is a (4, 4) scratch."""
    n = NX
    # x = Phi x + E u   (tmp[:, 0] holds the old x)
    for i in range(n):
        tmp[i, 0] = x[i]
    for i in range(n):
        s = Eu[i]
        for j in range(n):
            s += Phi[i, j] * tmp[j, 0]
        x[i] = s
    # tmp = Phi P
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += Phi[i, k] * P[k, j]
            tmp[i, j] = s
    # P = tmp Phi^T + Qd, symmetric by construction: compute the upper triangle, mirror it
    for i in range(n):
        for j in range(i, n):
            s = 0.0
            for k in range(n):
                s += tmp[i, k] * Phi[j, k]
            s += 0.5 * (Qd[i, j] + Qd[j, i])
            P[i, j] = s
            P[j, i] = s


@njit(cache=True)
def invert_small(ws, a, ai, m):  # pragma: no cover - compiled
    """``ws[ai, :m, :m] <- ws[a, :m, :m]^-1`` by Gauss-Jordan elimination with partial pivoting
    (the row with the largest remaining entry of each column leads), overwriting ``ws[a]``.

    The same elimination as LAPACK's LU inverse, in loops over at most ``NX`` rows: numba compiles
    ``np.linalg.inv`` into a call to LAPACK, which it finds only in scipy, so a kernel with it
    would not compile on a plain install (scipy is no dependency). ``ws`` is a scratch array
    (slots, n, n) as in :func:`update_inplace`; a singular matrix (an exactly zero pivot) raises
    ``ZeroDivisionError``.
    """
    for i in range(m):
        for j in range(m):
            ws[ai, i, j] = 1.0 if i == j else 0.0
    for c in range(m):
        p = c
        big = abs(ws[a, c, c])
        for r in range(c + 1, m):
            v = abs(ws[a, r, c])
            if v > big:
                big = v
                p = r
        if p != c:
            for j in range(m):
                t = ws[a, c, j]
                ws[a, c, j] = ws[a, p, j]
                ws[a, p, j] = t
                t = ws[ai, c, j]
                ws[ai, c, j] = ws[ai, p, j]
                ws[ai, p, j] = t
        d = 1.0 / ws[a, c, c]
        for j in range(m):
            ws[a, c, j] *= d
            ws[ai, c, j] *= d
        for r in range(m):
            if r != c:
                f = ws[a, r, c]
                for j in range(m):
                    ws[a, r, j] -= f * ws[a, c, j]
                    ws[ai, r, j] -= f * ws[ai, c, j]


#: number of (4, 4) scratch matrices :func:`update_inplace` needs (``ws`` shape (UPDATE_WS, 4, 4))
UPDATE_WS = 9
# scratch slots: used rows of H (m, n); innovation y (row 0, m); P H^T (n, m), later Kg R (n, m);
# S = H P H^T + R (m, m); S^-1 (m, m); gain Kg (n, m); I - Kg H (n, n); (I - Kg H) P (n, n);
# used block of R (m, m). Indexed as ws[slot, i, j] (no array views: they cost ~100 ns per update).
_HC, _Y, _PHT, _S, _SI, _KG, _IKH, _T, _RC = 0, 1, 2, 3, 4, 5, 6, 7, 8


@njit(cache=True)
def update_inplace(x, P, z, H, Du, R, use, ws):  # pragma: no cover - compiled
    """Joseph-form update of x (4,), P (4, 4) with the rows of z (m <= 4) where ``use`` is True.

    ``H`` (m, n), ``Du`` = D u (m,), ``R`` (m, m); ``ws`` is a scratch array (UPDATE_WS, n, n)
    (no allocation here: the estimator step runs millions of times in a replay). Returns the
    normalised innovation squared y^T S^-1 y over the used rows (0.0 when no row is used; then x
    and P are unchanged).
    """
    # compact the used rows:  y = z - H x - D u
    m = 0
    for i in range(z.shape[0]):
        if use[i]:
            s = z[i] - Du[i]
            for j in range(NX):
                ws[_HC, m, j] = H[i, j]
                s -= H[i, j] * x[j]
            ws[_Y, 0, m] = s
            b = 0
            for i2 in range(z.shape[0]):
                if use[i2]:
                    ws[_RC, m, b] = R[i, i2]
                    b += 1
            m += 1
    if m == 0:
        return 0.0
    n = NX
    # PHt = P H^T
    for i in range(n):
        for a in range(m):
            s = 0.0
            for k in range(n):
                s += P[i, k] * ws[_HC, a, k]
            ws[_PHT, i, a] = s
    # S = H P H^T + R
    for a in range(m):
        for b in range(m):
            s = ws[_RC, a, b]
            for k in range(n):
                s += ws[_HC, a, k] * ws[_PHT, k, b]
            ws[_S, a, b] = s
    # S^-1: closed form for 1 and 2 rows, Gauss-Jordan for 3 and 4 (S is not needed after it)
    if m == 1:
        ws[_SI, 0, 0] = 1.0 / ws[_S, 0, 0]
    elif m == 2:
        det = ws[_S, 0, 0] * ws[_S, 1, 1] - ws[_S, 0, 1] * ws[_S, 1, 0]
        ws[_SI, 0, 0] = ws[_S, 1, 1] / det
        ws[_SI, 0, 1] = -ws[_S, 0, 1] / det
        ws[_SI, 1, 0] = -ws[_S, 1, 0] / det
        ws[_SI, 1, 1] = ws[_S, 0, 0] / det
    else:
        invert_small(ws, _S, _SI, m)
    # Kg = P H^T S^-1
    for i in range(n):
        for b in range(m):
            s = 0.0
            for a in range(m):
                s += ws[_PHT, i, a] * ws[_SI, a, b]
            ws[_KG, i, b] = s
    # x = x + Kg y
    for i in range(n):
        s = 0.0
        for a in range(m):
            s += ws[_KG, i, a] * ws[_Y, 0, a]
        x[i] += s
    # I_KH = I - Kg H
    for i in range(n):
        for j in range(n):
            s = 1.0 if i == j else 0.0
            for a in range(m):
                s -= ws[_KG, i, a] * ws[_HC, a, j]
            ws[_IKH, i, j] = s
    # T = I_KH P
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += ws[_IKH, i, k] * P[k, j]
            ws[_T, i, j] = s
    # KR = Kg R  (n, m), kept in the P H^T slot (no longer needed)
    for i in range(n):
        for b in range(m):
            s = 0.0
            for a in range(m):
                s += ws[_KG, i, a] * ws[_RC, a, b]
            ws[_PHT, i, b] = s
    # P = T I_KH^T + Kg R Kg^T, then symmetrised
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += ws[_T, i, k] * ws[_IKH, j, k]
            for b in range(m):
                s += ws[_PHT, i, b] * ws[_KG, j, b]
            P[i, j] = s
    for i in range(n):
        for j in range(i + 1, n):
            s = 0.5 * (P[i, j] + P[j, i])
            P[i, j] = s
            P[j, i] = s
    # NIS = y^T S^-1 y
    nis = 0.0
    for a in range(m):
        for b in range(m):
            nis += ws[_Y, 0, a] * ws[_SI, a, b] * ws[_Y, 0, b]
    return nis


# --- pure wrappers ----------------------------------------------------------------------------


@njit(cache=True)
def kf_predict(x, P, Phi, E, u, Qd):  # pragma: no cover - compiled
    """Pure predict: returns (Phi x + E u, Phi P Phi^T + Qd) as new arrays. ``E`` (n,), ``u`` scalar."""
    xn = x.copy()
    Pn = P.copy()
    predict_inplace(xn, Pn, Phi, E * u, Qd, np.empty_like(P))
    return xn, Pn


@njit(cache=True)
def kf_update(x, P, z, H, D, u, R, use):  # pragma: no cover - compiled
    """Pure Joseph-form update: returns (x+, P+, NIS) as new arrays / float. ``D`` (m,), ``u`` scalar."""
    xn = x.copy()
    Pn = P.copy()
    nis = update_inplace(xn, Pn, z, H, D * u, R, use, np.empty((UPDATE_WS, NX, NX)))
    return xn, Pn, nis


# --- class ------------------------------------------------------------------------------------


class KalmanFilter:
    """A float Kalman filter with a scalar input and input feedthrough, around the pure kernels.

    Initialise explicitly with ``x0`` (n,) and ``P0`` (n, n); :meth:`reset` returns to them (or
    to new values). The model matrices are passed to every call: they change with speed.
    """

    def __init__(self, x0: np.ndarray, P0: np.ndarray) -> None:
        x0 = np.asarray(x0, dtype=np.float64)
        P0 = np.asarray(P0, dtype=np.float64)
        if x0.ndim != 1 or P0.shape != (x0.size, x0.size):
            raise ValueError(f"x0 must be (n,) and P0 (n, n); got {x0.shape} and {P0.shape}")
        self._x0, self._P0 = x0.copy(), P0.copy()
        self.x = x0.copy()
        self.P = P0.copy()
        self.nis = 0.0  #: normalised innovation squared of the last update

    def reset(self, x0: np.ndarray | None = None, P0: np.ndarray | None = None) -> None:
        """Back to the initial state (or to new ``x0`` / ``P0``, which become the initial state)."""
        if x0 is not None:
            self._x0 = np.asarray(x0, dtype=np.float64).copy()
        if P0 is not None:
            self._P0 = np.asarray(P0, dtype=np.float64).copy()
        self.x = self._x0.copy()
        self.P = self._P0.copy()
        self.nis = 0.0

    def predict(self, Phi: np.ndarray, E: np.ndarray, u: float, Qd: np.ndarray) -> None:
        """x = Phi x + E u,  P = Phi P Phi^T + Qd."""
        self.x, self.P = kf_predict(self.x, self.P, Phi, E, float(u), Qd)

    def update(
        self,
        z: np.ndarray,
        H: np.ndarray,
        D: np.ndarray,
        u: float,
        R: np.ndarray,
        use: np.ndarray | None = None,
    ) -> None:
        """Joseph-form update with the rows of ``z`` where ``use`` is True (default: all)."""
        z = np.asarray(z, dtype=np.float64)
        use_ = np.ones(z.shape[0], dtype=np.bool_) if use is None else np.asarray(use, dtype=np.bool_)
        self.x, self.P, self.nis = kf_update(self.x, self.P, z, H, D, float(u), R, use_)


# --- steady-state analysis (tuning; docs/tuning.md) -------------------------------------------


def steady_state_gain(
    Phi: np.ndarray, H: np.ndarray, Qd: np.ndarray, R: np.ndarray, tol: float = 1e-12, max_iter: int = 200_000
) -> tuple[np.ndarray, np.ndarray]:
    """Iterate the Riccati recursion of the constant model to its fixed point.

    Returns (Kg, P_post): the steady-state Kalman gain (n, m) and a-posteriori covariance.
    Raises ``RuntimeError`` if it has not converged (relative change < ``tol``) in ``max_iter``.
    """
    n = Phi.shape[0]
    P = np.eye(n) * 1e6
    for _ in range(max_iter):
        # a-priori -> gain -> a-posteriori (Joseph) -> next a-priori
        S = H @ P @ H.T + R
        Kg = P @ H.T @ np.linalg.inv(S)
        IKH = np.eye(n) - Kg @ H
        Pp = IKH @ P @ IKH.T + Kg @ R @ Kg.T
        Pn = Phi @ Pp @ Phi.T + Qd
        if np.max(np.abs(Pn - P)) <= tol * np.max(np.abs(Pn)):
            return Kg, Pp
        P = Pn
    raise RuntimeError("Riccati recursion did not converge")


def closed_loop_time_constants(Phi: np.ndarray, H: np.ndarray, Kg: np.ndarray, dt: float) -> np.ndarray:
    """Time constants [s] of the a-posteriori error dynamics e+ <- (I - Kg H) Phi e+, from the
    eigenvalues lambda of that matrix: tau = -dt / ln|lambda|, slowest first."""
    lam = np.linalg.eigvals((np.eye(Phi.shape[0]) - Kg @ H) @ Phi)
    return np.sort(-dt / np.log(np.abs(lam)))[::-1]
