"""Offline discrete algebraic Riccati equation (float, numpy): the steady-state Kalman filter.

Used only by the table generator (never at run time). The filter form of the DARE for
``x+ = Phi x + w (Qd)``, ``z = H x + v (R)`` is, for the a-priori covariance P:

    P = Phi P Phi^T - Phi P H^T (H P H^T + R)^-1 H P Phi^T + Qd

which is the control DARE ``X = A^T X A - A^T X B (R + B^T X B)^-1 B^T X A + Q`` with
``A = Phi^T``, ``B = H^T``, ``Q = Qd`` (scipy: ``solve_discrete_are(Phi.T, H.T, Qd, R)``).

Solved with the structure-preserving doubling algorithm (SDA; Chu, Fan, Lin, Wang 2004), which
converges quadratically:

    A0 = A, G0 = B R^-1 B^T, H0 = Q
    W_k = I + G_k H_k
    A_{k+1} = A_k W_k^-1 A_k
    G_{k+1} = G_k + A_k W_k^-1 G_k A_k^T
    H_{k+1} = H_k + A_k^T H_k W_k^-1 A_k        ->  X
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


class RiccatiError(ArithmeticError):
    """The doubling iteration did not converge (the pair is not stabilisable/detectable)."""


def solve_dare(
    A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray, tol: float = 1e-13, max_iter: int = 100
) -> np.ndarray:
    """X of the control DARE ``X = A'XA - A'XB (R + B'XB)^-1 B'XA + Q`` by SDA (symmetric result)."""
    n = A.shape[0]
    Ak = np.array(A, dtype=np.float64)
    Gk = B @ np.linalg.solve(R, B.T)
    Hk = np.array(Q, dtype=np.float64)
    eye = np.eye(n)
    for _ in range(max_iter):
        W = eye + Gk @ Hk
        WiA = np.linalg.solve(W, Ak)  # W^-1 A
        WiG = np.linalg.solve(W, Gk)  # W^-1 G
        H_next = Hk + Ak.T @ Hk @ WiA
        G_next = Gk + Ak @ WiG @ Ak.T
        A_next = Ak @ WiA
        done = float(np.linalg.norm(H_next - Hk)) <= tol * max(1.0, float(np.linalg.norm(H_next)))
        Ak, Gk, Hk = A_next, 0.5 * (G_next + G_next.T), 0.5 * (H_next + H_next.T)
        if done:
            return Hk
    raise RiccatiError(f"SDA did not converge in {max_iter} doublings")


@dataclass(frozen=True)
class SteadyStateKF:
    """Steady-state Kalman filter of one discrete model: a-priori / a-posteriori covariances, gain."""

    P_prior: np.ndarray  # (n, n)
    P_post: np.ndarray  # (n, n)
    gain: np.ndarray  # (n, m): Kg = P_prior H^T (H P_prior H^T + R)^-1


def steady_state_kf(Phi: np.ndarray, H: np.ndarray, Qd: np.ndarray, R: np.ndarray) -> SteadyStateKF:
    """Steady-state filter of ``x+ = Phi x + w``, ``z = H x + v`` (the filter DARE above)."""
    P = solve_dare(Phi.T, H.T, Qd, R)
    S = H @ P @ H.T + R
    Kg = np.linalg.solve(S, H @ P).T
    Pp = (np.eye(P.shape[0]) - Kg @ H) @ P
    return SteadyStateKF(P, 0.5 * (Pp + Pp.T), Kg)
