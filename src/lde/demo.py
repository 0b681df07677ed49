"""``lde demo``: the simulator and the live service on python-can's virtual bus, closed loop, in lockstep.

Both sides run on one :class:`lde.clock.SimulatedClock`, faster than real time: per 3.9 ms step

1. the simulator takes the ``LDE_Overlay`` frames waiting on its bus (E2E checked by
   :class:`vcan_sim.closed_loop.OverlayReceiver`), applies the request, advances its plant by one
   period and sends the MDPS/ESC frames due in it, stamped with the simulated time
   (``preserve_timestamps``);
2. the clock moves to the step time ``t_k`` (the start of that period: every frame stamped at or
   before ``t_k`` is on the bus, later ones wait in the service for the next step, exactly as live)
   and the service runs :meth:`lde.service.service.Service.step_once` at ``t_k``: the code of the live
   loop, only the waiting is simulated. Its ``LDE_Overlay`` reaches the plant at the next period.

The scenario runs twice, with the overlay and without it (the service then requests zero torque),
with the same seed: same wind, same driver. The summary compares the estimate with the simulator's
truth (:mod:`lde.analysis.metrics`), and the driver's holding torque and the lateral drift with and without
the overlay. The overlay run is recorded to MCAP (plus the truth on ``/sim/truth``) and plotted
(:func:`lde.analysis.plots.plot_demo`).
"""

from __future__ import annotations

import itertools
import logging
import math
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from lde.analysis.metrics import Truth, accuracy
from lde.analysis.plots import plot_demo
from lde.can.busio import drain
from lde.can.profiles import load_profile
from lde.clock import SimulatedClock
from lde.errors import ConfigError
from lde.io.recording import Recorder
from lde.params import load_vehicle
from lde.service.service import Service
from lde.units import STEP_NS
from vcan_sim.closed_loop import OverlayReceiver
from vcan_sim.run import Simulation, simulate
from vcan_sim.scenarios import SCENARIOS
from vcan_sim.truth import TRUTH_COLUMNS

__all__ = [
    "DEFAULT_SCENARIO",
    "check_output_paths",
    "DemoRun",
    "DemoSummary",
    "SimDriver",
    "make_simulation",
    "run_closed_loop",
    "run_demo",
]

log = logging.getLogger(__name__)

#: the paper's heavy lateral load (Fig. 13): gusty 15 m/s crosswind from the right and a +-3 deg bank
DEFAULT_SCENARIO = "heavy_load"
#: samples before this time after the start are left out of the comparisons [s]
SETTLE_S = 2.0

_channels = itertools.count()

#: truth columns recorded on ``/sim/truth`` (SI; see vcan_sim.truth.TRUTH_COLUMNS)
TRUTH_TOPIC = "/sim/truth"
TRUTH_FIELDS = ("Fw", "Mw", "Mw_ref", "vx", "y", "psi", "delta_sw", "T_column", "T_driver", "T_overlay", "r")


class SimDriver:
    """The simulator on a bus: one :meth:`step` = one 3.9 ms period, closed loop on ``LDE_Overlay``.

    Args:
        bus: the simulator's bus (open). With ``preserve_timestamps`` (virtual bus) the frames carry
            the simulated time; on other buses the driver or kernel stamps them.
        scenario: a vcan_sim scenario name.
        closed_loop: apply the overlay request received on the bus (else the scenario's script).
        duration: [s], default the scenario's.
    """

    step_ns = STEP_NS

    def __init__(
        self,
        bus: can.BusABC,
        scenario: str = DEFAULT_SCENARIO,
        *,
        vehicle: Any = None,
        profile: Any = "lde",
        seed: int = 1,
        closed_loop: bool = True,
        duration: float | None = None,
    ) -> None:

        self.bus = bus
        self.sim = Simulation(scenario, vehicle, profile, seed=seed, duration=duration)
        self.receiver = OverlayReceiver(self.sim.profile) if closed_loop else None
        self.closed_loop = closed_loop
        self.sent = 0

    @property
    def t_ns(self) -> int:
        """Simulated time [ns] (end of the last period)."""
        return self.sim.t_ns

    @property
    def done(self) -> bool:
        return self.sim.done

    def step(self) -> int:
        """Take overlay frames, advance one period, send its frames; returns the frames sent."""
        rx = self.receiver
        if rx is not None:
            t = self.sim.t_ns
            for msg in drain(self.bus):
                rx.on_message(msg, t)
        req = rx.request(self.sim.t_ns) if rx is not None else None
        frames = self.sim.step(req)
        n = len(frames)
        t_s = frames.t_ns
        for i in range(n):
            d = int(frames.dlc[i])
            self.bus.send(
                can.Message(
                    timestamp=(int(t_s[i]) // 1000) / 1e6,
                    arbitration_id=int(frames.can_id[i]),
                    is_extended_id=bool(frames.is_extended[i]),
                    data=frames.data[i, :d].tobytes(),
                    is_fd=d > 8,
                )
            )
        self.sent += n
        return n

    def truth(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """(truth columns, their times [ns]) so far."""
        return self.sim.truth()


def make_simulation(bus: can.BusABC, scenario: str | None = None, **kw: Any) -> SimDriver:
    """A :class:`SimDriver` (used by ``bench/bench_loop.py`` for a real-time feed)."""
    return SimDriver(bus, scenario or DEFAULT_SCENARIO, **kw)


@dataclass
class DemoRun:
    """One closed-loop run: per-step arrays (SI) and what it cost.

    ``series`` keys: ``t`` [s from the start], ``t_ns`` (step times), ``fw_hat``, ``mw_hat``,
    ``status``, ``t_overlay``, and the truth at the step times ``fw_true``, ``mw_true``,
    ``mw_ref_true``, ``driver_torque``, ``column_torque``, ``lateral_position``, ``speed``.
    """

    overlay: bool
    series: dict[str, np.ndarray]
    steps: int
    wall_s: float
    sim_s: float
    frames_sent: int
    overlay_frames_used: int


@dataclass
class DemoSummary:
    """Figures of ``lde demo`` (printed by :meth:`text`)."""

    scenario: str
    seed: int
    backend: str
    accuracy: Any  # lde.analysis.metrics.Accuracy of the overlay run
    hold_rms_on: float  # RMS driver torque after settling [Nm], with overlay
    hold_rms_off: float
    hold_mean_abs_on: float  # mean |driver torque| [Nm]
    hold_mean_abs_off: float
    drift_max_on: float  # max |lateral position| [m]
    drift_max_off: float
    drift_rms_on: float  # RMS lateral position [m]
    drift_rms_off: float
    overlay_max: float  # max |T_overlay| requested [Nm]
    wall_s: float
    sim_s: float
    mcap: Path | None = None
    png: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)

    def text(self) -> str:
        a = self.accuracy

        def red(on: float, off: float) -> str:
            return f"{100.0 * (on / off - 1.0):+.0f} %" if off > 0 else "n/a"

        wall_on = float(self.extra.get("wall_on", self.wall_s))
        lines = [
            f"lde demo: scenario {self.scenario} (seed {self.seed}), backend {self.backend}, "
            f"{self.sim_s:.1f} s simulated; closed loop with overlay in {wall_on:.1f} s "
            f"({self.sim_s / max(wall_on, 1e-9):.1f}x real time)",
            "",
            f"estimation (overlay run, after {SETTLE_S:g} s, {a.n} steps):",
            f"  Fw: RMS error {a.rms_fw:7.1f} N    NRMSE {100 * a.nrmse_fw:5.1f} %"
            f"  (max |Fw| {a.scale_fw:.0f} N)",
            f"  Mw: RMS error {a.rms_mw:7.1f} Nm   NRMSE {100 * a.nrmse_mw:5.1f} %"
            f"  (max |Mw| {a.scale_mw:.0f} Nm)",
            "",
            "closed loop                         without overlay   with overlay   change",
            f"  driver torque RMS [Nm]            {self.hold_rms_off:10.2f}      {self.hold_rms_on:10.2f}"
            f"     {red(self.hold_rms_on, self.hold_rms_off)}",
            f"  driver torque mean |T| [Nm]       {self.hold_mean_abs_off:10.2f}"
            f"      {self.hold_mean_abs_on:10.2f}"
            f"     {red(self.hold_mean_abs_on, self.hold_mean_abs_off)}",
            f"  lateral drift max |y| [m]         {self.drift_max_off:10.3f}      {self.drift_max_on:10.3f}"
            f"     {red(self.drift_max_on, self.drift_max_off)}",
            f"  lateral drift RMS y [m]           {self.drift_rms_off:10.3f}      {self.drift_rms_on:10.3f}"
            f"     {red(self.drift_rms_on, self.drift_rms_off)}",
            f"  max overlay request [Nm]          {0.0:10.2f}      {self.overlay_max:10.2f}",
        ]
        if self.mcap is not None:
            lines.append(f"\nrecording: {self.mcap}")
        if self.png is not None:
            lines.append(f"plot:      {self.png}")
        return "\n".join(lines)


def _truth_recorder_props() -> dict[str, dict[str, str]]:

    return {k: {"type": "number", "description": TRUTH_COLUMNS[k][1]} for k in TRUTH_FIELDS}


def run_closed_loop(
    scenario: str = DEFAULT_SCENARIO,
    *,
    overlay: bool = True,
    seed: int = 1,
    duration: float | None = None,
    vehicle: Any = None,
    profile: str = "lde",
    backend: str = "fixed",
    record: str | Path | None = None,
    grid: str = "fixed",
) -> DemoRun:
    """Simulator + service in lockstep on a virtual bus; returns the per-step series.

    With ``record`` the run is written to that MCAP file (service channels + ``/sim/truth``).
    ``grid="mdps"`` runs the live loop itself (:meth:`lde.service.service.Service.run` on the MDPS-locked
    grid,
    on the simulated clock), the simulator stepped after each step; its MDPS frames open each period,
    so the steps come at the same times as on the fixed grid and the run is the same, step for step.
    """

    veh = vehicle if vehicle is not None and not isinstance(vehicle, str) else load_vehicle(vehicle)
    prof = load_profile(profile)
    ch = f"lde-demo-{next(_channels)}"
    sim_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    svc_bus = can.Bus(interface="virtual", channel=ch, preserve_timestamps=True)
    recorder = None
    try:
        sim = SimDriver(sim_bus, scenario, vehicle=veh, profile=prof, seed=seed, duration=duration)
        sim_t0 = sim.t_ns
        clock = SimulatedClock(sim_t0)
        if record is not None:
            recorder = Recorder(
                record,
                metadata={
                    **prof.metadata(),
                    "vehicle": veh.name,
                    "backend": backend,
                    "step_ns": str(STEP_NS),
                    "scenario": scenario,
                    "seed": str(seed),
                    "overlay": str(int(overlay)),
                    "demo": "lockstep on a simulated clock",
                },
                extra_topics={TRUTH_TOPIC: _truth_recorder_props()},
            )
        svc = Service(
            svc_bus,
            prof,
            veh,
            clock,
            backend=backend,
            recorder=recorder,
            overlay_enabled=overlay,
            log_period_s=0,
            grid=grid,
        )
        n = sim.sim.n_steps
        t_ns = np.empty(n, np.int64)
        fw = np.empty(n)
        mw = np.empty(n)
        status = np.empty(n, np.int64)
        t_ov = np.empty(n)
        wall0 = time.perf_counter()
        k = 0
        if grid == "mdps":
            kk = [0]

            def on_step(r: Any) -> None:
                i = kk[0]
                t_ns[i], fw[i], mw[i], status[i], t_ov[i] = r.t_ns, r.fw, r.mw, r.status, r.t_overlay
                kk[0] = i + 1
                if not sim.done:
                    sim.step()  # the next period's frames: its MDPS frame triggers the next step

            sim.step()
            if n:
                svc.run(max_steps=n, on_step=on_step, t0_ns=sim_t0)
            k = kk[0]
        while not sim.done and k < n:
            # the period [t_k, t_k + 3.9 ms): its frames go out first (a frame stamped exactly t_k
            # is in it), then the service steps at t_k and keeps the later ones for the next step
            t_k = sim.t_ns
            sim.step()
            clock.sleep_until(t_k)
            r = svc.step_once(t_k)
            t_ns[k], fw[k], mw[k], status[k], t_ov[k] = r.t_ns, r.fw, r.mw, r.status, r.t_overlay
            k += 1
        wall = time.perf_counter() - wall0
        t_ns, fw, mw, status, t_ov = t_ns[:k], fw[:k], mw[:k], status[:k], t_ov[:k]
        truth, tt_ns = sim.truth()
        if recorder is not None and len(tt_ns):
            recorder.json_columns(TRUTH_TOPIC, tt_ns, {f: truth[f] for f in TRUTH_FIELDS})
        used = sim.receiver.stats.used if sim.receiver is not None else 0
    finally:
        if recorder is not None:
            recorder.close()
        sim_bus.shutdown()
        svc_bus.shutdown()

    series = {
        "t_ns": t_ns,
        "fw_hat": fw,
        "mw_hat": mw,
        "status": status,
        "t_overlay": t_ov,
        **_truth_series(t_ns, truth, tt_ns, t0_ns=sim_t0),
    }
    return DemoRun(
        overlay=overlay,
        series=series,
        steps=k,
        wall_s=wall,
        sim_s=k * STEP_NS / 1e9,
        frames_sent=sim.sent,
        overlay_frames_used=used,
    )


def _truth_series(
    t_ns: np.ndarray, truth: Mapping[str, np.ndarray], tt_ns: np.ndarray, t0_ns: int
) -> dict[str, np.ndarray]:
    """The truth columns the demo uses, at the step times ``t_ns`` (linear interpolation)."""
    tq = t_ns.astype(np.float64)
    tt = tt_ns.astype(np.float64)

    def at(col: str) -> np.ndarray:
        return np.interp(tq, tt, np.asarray(truth[col], np.float64))

    return {
        "t": (t_ns - t0_ns) / 1e9,
        "fw_true": at("Fw"),
        "mw_true": at("Mw"),
        "mw_ref_true": at("Mw_ref"),
        "driver_torque": at("T_driver"),
        "column_torque": at("T_column"),
        "lateral_position": at("y"),
        "speed": at("vx"),
    }


def run_without_overlay_fast(
    scenario: str = DEFAULT_SCENARIO,
    *,
    seed: int = 1,
    duration: float | None = None,
    vehicle: Any = None,
    profile: str = "lde",
) -> DemoRun:
    """The run without overlay through the simulator's fast path (whole run in a few jitted calls).

    Without overlay the service's output does not act on the plant (it requests zero torque, which
    is also the scenario's script), so the plant's trajectory is the same as in the lockstep loop
    (the simulator's open-loop and stepped runs are identical for one seed); only the estimates are
    not computed. Used by :func:`run_demo` to halve its time; ``run_closed_loop(overlay=False)``
    is the full loop.
    """

    wall0 = time.perf_counter()
    res = simulate(scenario, vehicle, profile, seed=seed, duration=duration)
    wall = time.perf_counter() - wall0
    t_ns = np.asarray(res.truth_t_ns, np.int64)
    nan = np.full(t_ns.size, np.nan)
    series = {
        "t_ns": t_ns,
        "fw_hat": nan,
        "mw_hat": nan,
        "status": np.zeros(t_ns.size, np.int64),
        "t_overlay": np.zeros(t_ns.size),
        **_truth_series(t_ns, res.truth, t_ns, t0_ns=res.t0_ns),
    }
    return DemoRun(
        overlay=False,
        series=series,
        steps=int(t_ns.size),
        wall_s=wall,
        sim_s=t_ns.size * STEP_NS / 1e9,
        frames_sent=len(res.frames),
        overlay_frames_used=0,
    )


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else math.nan


def summarise(on: DemoRun, off: DemoRun, scenario: str, seed: int, backend: str) -> DemoSummary:
    """The demo's figures from the two runs (after the settling window)."""

    s = on.series
    t = s["t"]
    acc = accuracy(
        t,
        s["fw_hat"],
        s["mw_hat"],
        Truth(t=t, fw=s["fw_true"], mw=s["mw_true"], mw_ref=s["mw_ref_true"]),
        settle=SETTLE_S,
        valid=(s["status"] & 1).astype(bool),
    )
    m_on = on.series["t"] >= SETTLE_S
    m_off = off.series["t"] >= SETTLE_S
    d_on, d_off = on.series["driver_torque"][m_on], off.series["driver_torque"][m_off]
    y_on, y_off = on.series["lateral_position"][m_on], off.series["lateral_position"][m_off]
    return DemoSummary(
        scenario=scenario,
        seed=seed,
        backend=backend,
        accuracy=acc,
        hold_rms_on=_rms(d_on),
        hold_rms_off=_rms(d_off),
        hold_mean_abs_on=float(np.mean(np.abs(d_on))),
        hold_mean_abs_off=float(np.mean(np.abs(d_off))),
        drift_max_on=float(np.max(np.abs(y_on))),
        drift_max_off=float(np.max(np.abs(y_off))),
        drift_rms_on=_rms(y_on),
        drift_rms_off=_rms(y_off),
        overlay_max=float(np.max(np.abs(on.series["t_overlay"]))),
        wall_s=on.wall_s + off.wall_s,
        sim_s=on.sim_s,
        extra={"wall_on": on.wall_s, "wall_off": off.wall_s, "overlay_frames_used": on.overlay_frames_used},
    )


def check_output_paths(outputs: Mapping[str, str | Path | None]) -> None:
    """ConfigError for an output (what -> path; None: not written) that is a directory, lies in a
    directory that does not exist or cannot be written, or is the same file as another output.
    Called before simulating, so a bad path never costs a run."""
    seen: dict[Path, str] = {}
    for what, value in outputs.items():
        if value is None:
            continue
        path = Path(value)
        if str(value) == "" or path.is_dir():
            raise ConfigError(f"{what} {str(value)!r}: is a directory, need a file name")
        parent = path.parent
        if not parent.is_dir():
            raise ConfigError(f"{what} {path}: no such directory {parent}")
        if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
            raise ConfigError(f"{what} {path}: not writable")
        key = path.resolve()
        if key in seen:
            raise ConfigError(f"{what} {path} is also the {seen[key]}: give two file names")
        seen[key] = what


def run_demo(
    scenario: str = DEFAULT_SCENARIO,
    *,
    seed: int = 1,
    duration: float | None = None,
    vehicle: Any = None,
    backend: str = "fixed",
    profile: str = "lde",
    mcap: str | Path | None = "lde_demo.mcap",
    png: str | Path | None = "lde_demo.png",
    full_off_run: bool = False,
) -> tuple[DemoSummary, DemoRun, DemoRun]:
    """Both runs (overlay on, then off), the summary, the recording and the plot.

    The run without overlay uses the simulator's fast path (:func:`run_without_overlay_fast`)
    unless ``full_off_run``. The output paths are checked before anything runs
    (:func:`check_output_paths`).

    Raises:
        ConfigError: unknown scenario, or an output path that cannot be written.
    """

    if scenario not in SCENARIOS:
        raise ConfigError(f"unknown scenario {scenario!r} (known: {', '.join(SCENARIOS)})")
    check_output_paths({"MCAP recording": mcap, "plot": png})
    kw: dict[str, Any] = {"seed": seed, "duration": duration, "vehicle": vehicle, "profile": profile}
    on = run_closed_loop(scenario, overlay=True, backend=backend, record=mcap, **kw)
    if full_off_run:
        off = run_closed_loop(scenario, overlay=False, backend=backend, **kw)
    else:
        off = run_without_overlay_fast(scenario, **kw)
    summary = summarise(on, off, scenario, seed, backend)
    summary.mcap = Path(mcap) if mcap is not None else None
    if png is not None:
        summary.png = plot_demo(
            _plot_series(on.series),
            _plot_series(off.series),
            png,
            title=f"lde demo: {scenario} (seed {seed}), closed loop on a virtual bus",
        )
    return summary, on, off


def _plot_series(s: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
    keys = (
        "t",
        "fw_hat",
        "fw_true",
        "mw_hat",
        "mw_true",
        "driver_torque",
        "lateral_position",
        "t_overlay",
        "speed",
    )
    return {k: s[k] for k in keys}
