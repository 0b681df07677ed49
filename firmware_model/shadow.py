"""The shadow check's bound: the float lateral filter runs beside the fixed-point one at every step
(backend ``fixed``, :mod:`lde.engine.backends.fixed`) and a step whose estimates differ by more than
this gets ``Status.SHADOW_DEVIATION`` (bit 6) and is counted."""

from __future__ import annotations

from lde.status import Status

FW_BOUND_N = 5.0  #: |Fw_fixed - Fw_float| bound [N]
MW_BOUND_NM = 2.0  #: |Mw_fixed - Mw_float| bound [Nm]
SHADOW_DEVIATION = int(Status.SHADOW_DEVIATION)  #: status bit 6
