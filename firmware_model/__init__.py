"""The fixed-point firmware model of the lde Kalman step (integers only; see docs/firmware.md).

Public API (the fixed backend of ``lde replay`` / ``lde run``):

- :func:`run_batch` - same signature and :class:`lde.step.BatchResult` as :func:`lde.step.run_batch`,
  with the float filter as shadow check (``Status.SHADOW_DEVIATION``) by default.
- :class:`FixedEstimator` - ``step(t_ns, inputs)`` / ``reset()`` like :class:`lde.step.Estimator`.
- :func:`shadow_check`, :class:`ShadowChecker`, :func:`run_batch_with_shadow` - the deviation check.
- :func:`tables_for` - the generated constants for a vehicle.

Modules: ``qformat`` (Q formats, rounding, saturation), ``gen_tables`` (the generator:
``python -m firmware_model.gen_tables``), ``tables`` (typed constants), ``step`` (the pure-Python
integer reference), ``fast`` (its numba twin), ``shadow``, ``float_ref`` (the steady-state-gain
alternative, for measurement), ``riccati`` (offline DARE), ``synthetic`` (test drives),
``gen_golden`` (golden vectors).
"""

from __future__ import annotations

from .fast import FastState, FixedEstimator, run_batch
from .shadow import FW_BOUND_N, MW_BOUND_NM, ShadowChecker, ShadowReport, run_batch_with_shadow, shadow_check
from .tables import FixedTables, tables_for

__all__ = [
    "FW_BOUND_N",
    "MW_BOUND_NM",
    "FastState",
    "FixedEstimator",
    "FixedTables",
    "ShadowChecker",
    "ShadowReport",
    "run_batch",
    "run_batch_with_shadow",
    "shadow_check",
    "tables_for",
]
