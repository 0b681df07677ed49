"""vcan_sim: the nonlinear vehicle that puts realistic CAN traffic on the bus (docs/design/simulator.md).

Entry points: :func:`vcan_sim.run.simulate` (fast path: frames + ground truth),
:class:`vcan_sim.run.Simulation` (step by step, closed loop), :data:`vcan_sim.scenarios.SCENARIOS`,
:func:`vcan_sim.identify.identify` (linear-equivalent C_f, C_r, K), and ``lde sim`` on the command line.
The plant is deliberately independent of the estimator's linear model (no lde.estimator.model/kalman/step).
"""

from __future__ import annotations

from .run import SimResult, Simulation, simulate
from .scenarios import SCENARIOS

__all__ = ["simulate", "Simulation", "SimResult", "SCENARIOS"]
