"""The estimator's outputs per step: one row of float64 slots that every backend's step fills.

The compiled loop (:mod:`lde.engine.loop`) hands each backend step a row ``out`` of :data:`N_OUT`
slots; the step writes its a-posteriori estimate there, the loop reads it for the overlay law and
the output frames, and :class:`lde.engine.engine.StepBlock` keeps the rows (``StepBlock.est``).
Kernels index the row with the ``O_*`` constants below; Python code uses the names of
:data:`OUTPUTS` (SI units, ISO 8855 signs: left positive).

A slot a backend cannot fill holds NaN (``fw_wind``, ``mw_wind``, ``bank`` of the paper's filter,
which does not tell wind from bank), except ``learn`` (:data:`LEARN_NONE` without a learner).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "Output",
    "OUTPUTS",
    "N_OUT",
    "O_FW",
    "O_MW",
    "O_T_ALIGN",
    "O_BETA",
    "O_YAW",
    "O_FW_WIND",
    "O_MW_WIND",
    "O_BANK",
    "O_LEARN",
    "O_GAIN",
    "LEARN_NONE",
]


class Output(NamedTuple):
    """One output slot: its name, unit and meaning."""

    name: str
    unit: str
    meaning: str


#: the slots, in row order (the ``O_*`` constants index them)
OUTPUTS: tuple[Output, ...] = (
    Output("fw", "N", "disturbance force Fw at the CG, left positive"),
    Output("mw", "Nm", "disturbance yaw moment Mw about the CG, left positive"),
    Output("t_align", "Nm", "aligning torque estimate 2K alpha_f at the steering axis (paper sign)"),
    Output("beta", "rad", "side slip beta"),
    Output("yaw_rate", "rad/s", "yaw rate r"),
    Output("fw_wind", "N", "the wind's part of Fw (NaN: the backend does not tell wind from bank)"),
    Output("mw_wind", "Nm", "the wind's yaw moment (NaN: not told apart)"),
    Output("bank", "rad", "road bank angle, road's left side lower positive (NaN: not told apart)"),
    Output("learn", "-", "learned state of the tires: 0 not learned, 1 learning, 2 learned, 3 no learner"),
    Output(
        "gain",
        "Nm/(N m)",
        "the overlay law's gain K / (N Cf L) from the backend's current (learned) tires; "
        "NaN: the vehicle file's (lde.estimator.overlay.feedforward_gain)",
    ),
)
N_OUT = len(OUTPUTS)
O_FW, O_MW, O_T_ALIGN, O_BETA, O_YAW, O_FW_WIND, O_MW_WIND, O_BANK, O_LEARN, O_GAIN = range(N_OUT)
#: ``learn`` of a backend without a learner
LEARN_NONE = 3
