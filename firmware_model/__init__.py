"""The fixed-point firmware model of the lde Kalman step (integers only; see docs/firmware.md).

Public API (the fixed backend of ``lde replay`` / ``lde run``):

- :func:`run_batch` - same signature and :class:`lde.estimator.paper.BatchResult` as
:func:`lde.estimator.paper.run_batch`,
  with the float filter as shadow check (``Status.SHADOW_DEVIATION``) by default.
- :class:`FixedEstimator` - ``step(t_ns, inputs)`` / ``reset()`` like :class:`lde.estimator.paper.Estimator`.
- :func:`shadow_check`, :class:`ShadowChecker`, :func:`run_batch_with_shadow` - the deviation check.
- :func:`tables_for` - the generated constants for a vehicle.

Modules: ``qformat`` (Q formats, rounding, saturation), ``gen_tables`` (the generator:
``python -m firmware_model.gen_tables``), ``tables`` (typed constants), ``step`` (the pure-Python
integer reference), ``fast`` (its numba twin), ``shadow``, ``float_ref`` (the steady-state-gain
alternative, for measurement), ``riccati`` (offline DARE), ``synthetic`` (test drives),
``gen_golden`` (golden vectors).
"""

from __future__ import annotations

import importlib
from typing import Any

# Lazy exports (PEP 562): importing the package stays cheap and ``python -m
# firmware_model.gen_tables`` does not import the generator twice.
_EXPORTS = {
    "FastState": "fast",
    "FixedEstimator": "fast",
    "run_batch": "fast",
    "FW_BOUND_N": "shadow",
    "MW_BOUND_NM": "shadow",
    "ShadowChecker": "shadow",
    "ShadowReport": "shadow",
    "run_batch_with_shadow": "fast",
    "shadow_check": "shadow",
    "FixedTables": "tables",
    "tables_for": "tables",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f".{_EXPORTS[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(list(globals()) + __all__)
