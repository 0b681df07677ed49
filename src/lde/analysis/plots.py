"""Plots of ``lde demo`` in the style of the paper's Figs. 13-14 (estimate vs truth), plus the closed loop.

Layout (one PNG, 3 rows x 2 columns, shared time axis in seconds from the scenario start):

* top: lateral force ``Fw`` [N] and yaw moment ``Mw`` [Nm], estimate (solid) vs the simulator's
  truth (dashed), as in Figs. 13-14;
* middle: the driver's column torque [Nm] and the lateral position [m], without (grey) and with
  (colour) the overlay;
* bottom: the overlay torque request [Nm] and the speed [km/h] of the overlay run.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from lde.errors import LogFormatError

__all__ = ["plot_demo"]


def plot_demo(
    with_overlay: Mapping[str, np.ndarray],
    without_overlay: Mapping[str, np.ndarray] | None,
    path: str | Path,
    title: str = "",
) -> Path:
    """Write the demo figure to ``path`` (PNG) and return the path.

    Each run is a mapping of equal-length arrays: ``t`` [s], ``fw_hat``, ``fw_true`` [N],
    ``mw_hat``, ``mw_true`` [Nm], ``driver_torque`` [Nm], ``lateral_position`` [m],
    ``t_overlay`` [Nm], ``speed`` [m/s]. ``without_overlay`` may be None (only one run).

    Raises:
        LogFormatError: the file cannot be written (missing directory, no permission).
    """
    # a Figure with its own canvas, not pyplot: no global backend is selected (matplotlib.use would
    # change every caller's backend) and no figure stays in pyplot's registry

    on = with_overlay
    off = without_overlay
    fig = Figure(figsize=(12, 9), layout="constrained")
    ax = fig.subplots(3, 2, sharex=True)
    t = np.asarray(on["t"])

    a = ax[0, 0]
    a.plot(t, on["fw_true"], "k--", lw=1.2, label="true")
    a.plot(t, on["fw_hat"], "C0", lw=1.0, label="estimated")
    a.set_ylabel("lateral force $F_w$ [N]")
    a.legend(loc="best")
    a.set_title("Lateral force")

    a = ax[0, 1]
    a.plot(t, on["mw_true"], "k--", lw=1.2, label="true")
    a.plot(t, on["mw_hat"], "C3", lw=1.0, label="estimated")
    a.set_ylabel("yaw moment $M_w$ [Nm]")
    a.legend(loc="best")
    a.set_title("Yaw moment")

    a = ax[1, 0]
    if off is not None:
        a.plot(off["t"], off["driver_torque"], color="0.55", lw=1.0, label="without overlay")
    a.plot(t, on["driver_torque"], "C2", lw=1.0, label="with overlay")
    a.axhline(0.0, color="k", lw=0.5)
    a.set_ylabel("driver column torque [Nm]")
    a.legend(loc="best")
    a.set_title("Driver holding torque")

    a = ax[1, 1]
    if off is not None:
        a.plot(off["t"], off["lateral_position"], color="0.55", lw=1.0, label="without overlay")
    a.plot(t, on["lateral_position"], "C2", lw=1.0, label="with overlay")
    a.axhline(0.0, color="k", lw=0.5)
    a.set_ylabel("lateral position [m] (left +)")
    a.legend(loc="best")
    a.set_title("Lateral drift")

    a = ax[2, 0]
    a.plot(t, on["t_overlay"], "C1", lw=1.0)
    a.axhline(0.0, color="k", lw=0.5)
    a.set_ylabel("overlay torque request [Nm]")
    a.set_xlabel("time [s]")

    a = ax[2, 1]
    a.plot(t, np.asarray(on["speed"]) * 3.6, "C4", lw=1.0)
    a.set_ylabel("speed [km/h]")
    a.set_xlabel("time [s]")

    for row in ax:
        for a in row:
            a.grid(True, lw=0.3)
    if title:
        fig.suptitle(title)
    out = Path(path)
    try:
        fig.savefig(out, dpi=110)
    except OSError as exc:
        raise LogFormatError(f"{out}: cannot write the plot: {exc.strerror or exc}") from exc
    return out
