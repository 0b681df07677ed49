"""A linear truth for the learner's tests: the linear bicycle model with per-tire stiffnesses of its
own (discretised exactly), its sensors, and the filter + learner arrays that drive on it.

Written independently of :mod:`lde.estimator` (the model's equations, not the filter's code), so that
a wrong sign in a regressor or a push moves the learned values away from this truth.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import expm

from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.outputs import N_OUT
from lde.status import VALID
from lde.units import DEG, STEP_NS, STEP_S

#: the truth's and the filter's forward speed [m/s] (100 km/h)
VX = 100.0 / 3.6


def bicycle_truth(m, iz, lf, lr, cf, cr, vx, sigma=0.0):
    """Exact discretisation of the linear bicycle model, state ``[beta, r]``; with a relaxation
    length ``sigma`` [m] > 0 the state is ``[beta, r, alpha_f, alpha_r]``, the slips that make the
    forces, each lagging its kinematic slip: ``alpha' = (vx / sigma) (alpha_kin - alpha)``."""
    if sigma > 0.0:
        w = vx / sigma
        a = np.array(
            [
                [0.0, -1.0, 2 * cf / (m * vx), 2 * cr / (m * vx)],
                [0.0, 0.0, 2 * lf * cf / iz, -2 * lr * cr / iz],
                [-w, -w * lf / vx, -w, 0.0],
                [-w, w * lr / vx, 0.0, -w],
            ]
        )
        b = np.array([[0.0], [0.0], [w], [0.0]])
    else:
        a = np.array(
            [
                [-2 * (cf + cr) / (m * vx), -1 - 2 * (lf * cf - lr * cr) / (m * vx**2)],
                [-2 * (lf * cf - lr * cr) / iz, -2 * (lf**2 * cf + lr**2 * cr) / (iz * vx)],
            ]
        )
        b = np.array([[2 * cf / (m * vx)], [2 * lf * cf / iz]])
    nx = a.shape[0]
    big = np.zeros((nx + 1, nx + 1))
    big[:nx, :nx], big[:nx, nx:] = a, b
    e = expm(big * STEP_S)
    return e[:nx, :nx], e[:nx, nx]


def weave(t):
    """Lane-change-like weaving: 0.2-0.6 Hz, up to ~25 deg at the steering wheel."""
    return DEG * (12 * math.sin(2 * math.pi * 0.25 * t) + 8 * math.sin(2 * math.pi * 0.55 * t + 1.0))


def sense(x, delta, body, tires, s, n_ratio, rng, wind=0.0):
    """The sensors of the linear truth at state ``x = [beta, r]`` and road-wheel angle ``delta``
    [rad]: (a_y [m/s^2], yaw rate [rad/s], column and assist torque [Nm]). ``tires``: per-tire
    (Cf, Cr, K); the aligning torque 2 K alpha_f splits 1:3 between driver and assist; ``wind``
    [N] acts on the body, so the accelerometer (roll-tilt scale ``s`` on the tire forces) feels it."""
    cf, cr, k = tires
    beta, r = x[:2]
    af = delta - beta - body.lf * r / VX
    ar = -beta + body.lr * r / VX
    if len(x) == 4:  # the lagged slips make the forces and the aligning torque
        af, ar = x[2], x[3]
    t_align = 2 * k * af
    ay = (s * (2 * cf * af + 2 * cr * ar) + wind) / body.mass + rng.normal(0, 0.02)
    yaw = r + rng.normal(0, 0.05 * DEG)
    tcol = t_align / n_ratio / 4 + rng.normal(0, 0.01)
    tast = 3 * t_align / n_ratio / 4
    return ay, yaw, tcol, tast


@dataclass
class Rig:
    """The filter's and the learner's arrays for a drive on the linear truth (:func:`rig_on_truth`)."""

    p: np.ndarray  # the filter's parameters (the learner pushes into them)
    lp: np.ndarray
    ls: np.ndarray
    truth: tuple[float, float, float]  # the truth's Cf, Cr [N/rad], K [Nm/rad]
    ad: np.ndarray  # the truth's discrete state transition and input
    bd: np.ndarray
    s: float  # the filter's accelerometer scale factor
    xs: np.ndarray = field(default_factory=lambda: np.zeros(E.NX))
    P: np.ndarray = field(default_factory=lambda: np.zeros((E.NX, E.NX)))
    fs: np.ndarray = field(default_factory=lambda: np.zeros(E.N_F))
    ints: np.ndarray = field(default_factory=lambda: np.zeros(E.N_I, np.int64))
    h: np.ndarray = field(default_factory=lambda: np.zeros(E.NX))
    ph: np.ndarray = field(default_factory=lambda: np.zeros(E.NX))
    out: np.ndarray = field(default_factory=lambda: np.zeros(N_OUT))
    ws: np.ndarray = field(default_factory=lambda: np.zeros((2, Ln.N3)))

    def step(self, i: int, angle: float, yaw: float, tcol: float, tast: float, ay: float) -> int:
        """Step ``i`` of the filter at VX with these measurements [rad, rad/s, Nm, Nm, m/s^2], then the
        learner; returns the filter's status."""
        st = E.step_kernel(
            self.p, self.xs, self.P, self.fs, self.ints, self.h, self.ph, 10**9 + i * STEP_NS, VX,
            angle, yaw, tcol, tast, ay, True, True, True, True, True, self.out,
        )  # fmt: skip
        Ln.learner_step(
            self.lp, self.ls, self.ws, self.p, self.out, VX, angle, yaw, tcol, tast, ay,
            self.fs[E.F_ZFRIC], bool(st & VALID),
        )  # fmt: skip
        return int(st)


def rig_on_truth(veh, p, lp, scales, sigma=0.0) -> Rig:
    """The learner started from ``p`` (the vehicle file's values, friction prior included), the filter
    reset, and a linear truth at VX whose Cf, Cr, K are the vehicle's tires times ``scales``, with
    relaxation length ``sigma`` [m] and no friction (``p``'s friction is set to 0)."""
    b, t = veh.body, veh.tires
    ls = Ln.init_state(p, lp, friction_prior=p[E.P_TFRIC])
    p[E.P_TFRIC] = 0.0  # the truth has no friction; the prior is left as a vehicle file gives it
    cf, cr, k = t.cf * scales[0], t.cr * scales[1], t.align_rate * scales[2]
    ad, bd = bicycle_truth(b.mass, b.yaw_inertia, b.lf, b.lr, cf, cr, VX, sigma)
    rig = Rig(p, lp, ls, (cf, cr, k), ad, bd, float(p[E.P_S]))
    E.reset_kernel(p, rig.xs, rig.P, rig.fs, rig.ints)
    return rig
