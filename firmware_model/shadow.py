"""Shadow check: the float filter runs beside the fixed-point one and every step's deviation is
compared with the bound (issue 5: |dFw| <= 5 N and |dMw| <= 2 Nm at every step).

A deviating step gets ``Status.SHADOW_DEVIATION`` (bit 6) in the fixed backend's status and is
counted. The fixed backend does this itself by default (``firmware_model.run_batch(...,
shadow=True)`` and ``FixedEstimator(vehicle, shadow=True)``), so a replay or a live run with
``--backend fixed`` reports deviations in ``Status`` without further wiring; the counts are kept
in ``FastState.shadow_count`` / ``FixedEstimator.shadow.count``.

Batch: :func:`shadow_check` on two :class:`lde.estimator.paper.BatchResult`, or
:func:`firmware_model.fast.run_batch_with_shadow`.
Live: :class:`ShadowChecker` per step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lde.estimator.paper import BatchResult, EstimatorOutput, Status

FW_BOUND_N = 5.0  #: |Fw_fixed - Fw_float| bound [N]
MW_BOUND_NM = 2.0  #: |Mw_fixed - Mw_float| bound [Nm]
SHADOW_DEVIATION = int(Status.SHADOW_DEVIATION)  #: status bit 6


@dataclass(frozen=True)
class ShadowReport:
    """Result of a batch shadow check.

    Attributes:
        deviation: bool per step, True where a bound is exceeded.
        count: number of deviating steps.
        max_dfw: largest |dFw| [N]; max_dmw: largest |dMw| [Nm] (0.0 for an empty batch).
        status: the fixed backend's status with SHADOW_DEVIATION set on deviating steps (uint8).
    """

    deviation: np.ndarray
    count: int
    max_dfw: float
    max_dmw: float
    status: np.ndarray


def shadow_check(
    fixed: BatchResult, flt: BatchResult, fw_bound: float = FW_BOUND_N, mw_bound: float = MW_BOUND_NM
) -> ShadowReport:
    """Compare two batch results step by step (same grid). A non-finite difference deviates."""
    if fixed.t_ns.shape != flt.t_ns.shape or not np.array_equal(fixed.t_ns, flt.t_ns):
        raise ValueError("shadow_check needs the two results on the same step grid")
    dfw = np.abs(fixed.fw - flt.fw)
    dmw = np.abs(fixed.mw - flt.mw)
    dev = ~((dfw <= fw_bound) & (dmw <= mw_bound))
    status = fixed.status.astype(np.uint8) | np.where(dev, SHADOW_DEVIATION, 0).astype(np.uint8)
    return ShadowReport(
        dev, int(dev.sum()), float(np.max(dfw, initial=0.0)), float(np.max(dmw, initial=0.0)), status
    )


class ShadowChecker:
    """Per-step shadow check for the live loop (counts deviations since creation/reset)."""

    def __init__(self, fw_bound: float = FW_BOUND_N, mw_bound: float = MW_BOUND_NM) -> None:
        self.fw_bound = fw_bound
        self.mw_bound = mw_bound
        self.reset()

    def reset(self) -> None:
        self.count = 0  #: deviating steps
        self.steps = 0  #: checked steps
        self.max_dfw = 0.0  #: [N]
        self.max_dmw = 0.0  #: [Nm]

    def check(self, fixed: EstimatorOutput, flt: EstimatorOutput) -> Status:
        """The fixed output's status, with SHADOW_DEVIATION if this step exceeds a bound."""
        dfw = abs(fixed.fw - flt.fw)
        dmw = abs(fixed.mw - flt.mw)
        self.steps += 1
        self.max_dfw = max(self.max_dfw, dfw)
        self.max_dmw = max(self.max_dmw, dmw)
        if dfw <= self.fw_bound and dmw <= self.mw_bound:
            return fixed.status
        self.count += 1
        return fixed.status | Status.SHADOW_DEVIATION
