"""The float Kalman filter of :mod:`lde.estimator.kalman` on filterpy's ``KalmanFilter``: the test oracle
it is checked against (a lockstep run in the Kalman filter's tests) and the anchor of the benchmark
suite (``bench/run_all.py``).

A test helper, not part of the product: filterpy is a dependency of the ``test`` extra only
(``pip install lde[test]``) and pulls in scipy.stats.
"""

from __future__ import annotations

import numpy as np
from filterpy.kalman import KalmanFilter as _FpKF

__all__ = ["FilterpyReference"]


class FilterpyReference:
    """The same filter on filterpy's ``KalmanFilter`` (a reference for tests, not for speed).

    filterpy has ``B`` for the input in the predict but no feedthrough in the measurement: the
    feedthrough is handled by updating with ``z - D u``. A left-out row is handled by passing the
    used rows of H, R and z.
    """

    def __init__(self, x0: np.ndarray, P0: np.ndarray) -> None:

        x0 = np.asarray(x0, dtype=np.float64)
        self._kf = _FpKF(dim_x=x0.size, dim_z=2, dim_u=1)
        self._kf.x = x0.reshape(-1, 1).copy()
        self._kf.P = np.asarray(P0, dtype=np.float64).copy()

    @property
    def x(self) -> np.ndarray:
        return self._kf.x[:, 0].copy()

    @property
    def P(self) -> np.ndarray:
        return self._kf.P.copy()

    def predict(self, Phi: np.ndarray, E: np.ndarray, u: float, Qd: np.ndarray) -> None:
        self._kf.predict(u=np.array([[u]]), B=E.reshape(-1, 1), F=Phi, Q=Qd)

    def update(
        self,
        z: np.ndarray,
        H: np.ndarray,
        D: np.ndarray,
        u: float,
        R: np.ndarray,
        use: np.ndarray | None = None,
    ) -> None:
        z = np.asarray(z, dtype=np.float64)
        idx = np.arange(z.size) if use is None else np.flatnonzero(use)
        if idx.size == 0:
            return
        zc = (z - D * u)[idx].reshape(-1, 1)
        self._kf.update(zc, R=R[np.ix_(idx, idx)], H=H[idx])
