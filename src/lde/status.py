"""The ``LDE_Estimate.Status`` bit map: defined here once, used by every layer.

==== =================== =============================================================================
bit  name                meaning
==== =================== =============================================================================
0    VALID               set exactly when none of MDPS_FAULT, ESC_FAULT, LOW_SPEED, NOT_CONVERGED is
1    DEGRADED            a yaw-rate-only update during an MDPS fault, a saturation inside the
                         fixed-point step, or a non-finite output replaced by 0 (never on the bus)
2    MDPS_FAULT          MDPS inputs stale, untrusted by the E2E receiver, or not finite
3    ESC_FAULT           ESC inputs stale, untrusted or not finite (the filter holds)
4    LOW_SPEED           below the model's minimum speed (the filter holds)
5    NOT_CONVERGED       within the convergence time after a (re)start, or held
6    SHADOW_DEVIATION    the fixed-point step left the float shadow's bound (fixed backend)
7    DEADLINE_MISS       the live step started more than 1 ms late (service only)
==== =================== =============================================================================

The module-level ints (``VALID`` ...) are the same values for the compiled kernels, which cannot
use an IntFlag.
"""

from __future__ import annotations

import enum

__all__ = [
    "Status",
    "STATUS_BITS",
    "STATUS_MEANINGS",
    "VALID",
    "DEGRADED",
    "MDPS_FAULT",
    "ESC_FAULT",
    "LOW_SPEED",
    "NOT_CONVERGED",
    "SHADOW_DEVIATION",
    "DEADLINE_MISS",
    "FAULT_BITS",
    "NOT_READY_BITS",
]


class Status(enum.IntFlag):
    """``LDE_Estimate.Status`` bit map (module docstring)."""

    VALID = 1
    DEGRADED = 2
    MDPS_FAULT = 4
    ESC_FAULT = 8
    LOW_SPEED = 16
    NOT_CONVERGED = 32
    SHADOW_DEVIATION = 64
    DEADLINE_MISS = 128


VALID = int(Status.VALID)
DEGRADED = int(Status.DEGRADED)
MDPS_FAULT = int(Status.MDPS_FAULT)
ESC_FAULT = int(Status.ESC_FAULT)
LOW_SPEED = int(Status.LOW_SPEED)
NOT_CONVERGED = int(Status.NOT_CONVERGED)
SHADOW_DEVIATION = int(Status.SHADOW_DEVIATION)
DEADLINE_MISS = int(Status.DEADLINE_MISS)

#: bits that are input faults: the overlay ramps out (FAULT state when they persist)
FAULT_BITS = MDPS_FAULT | ESC_FAULT | SHADOW_DEVIATION
#: bits that mean "estimate not usable yet": the overlay ramps out, no FAULT
NOT_READY_BITS = NOT_CONVERGED | LOW_SPEED

#: lower-case bit names in bit order (recording fields ``valid``, ``degraded``, ...)
STATUS_BITS: tuple[str, ...] = tuple(str(flag.name).lower() for flag in Status)

#: what each bit means, for a user (the CSV's decoded status columns, ``lde replay --help``)
STATUS_MEANINGS: dict[str, str] = {
    "valid": "the estimate is usable (none of mdps_fault, esc_fault, low_speed, not_converged)",
    "degraded": "a yaw-rate-only update during an MDPS fault, a saturation in the fixed-point step, or a "
    "non-finite output replaced by 0",
    "mdps_fault": "MDPS inputs stale, rejected by the E2E check or not finite (input fault)",
    "esc_fault": "ESC inputs stale, rejected by the E2E check or not finite (input fault; the filter holds)",
    "low_speed": "below the model's minimum speed (the filter holds)",
    "not_converged": "within the convergence time after a (re)start, or held",
    "shadow_deviation": "the fixed-point step left its float shadow's bound (fixed backends)",
    "deadline_miss": "the live step started more than 1 ms late (recordings of lde run)",
}
