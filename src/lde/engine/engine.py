"""The one data path as an object: :class:`Engine` owns every state of the path and runs the
compiled loop (:mod:`lde.engine.loop`) over frames, live one step at a time or over a log in chunks.

    engine = Engine(profile, vehicle, "fixed")                  # anchored grid (a log)
    block = engine.feed(frames)                                 # any number of chunks, in time order
    block2 = engine.finish()                                    # the steps up to the log's end

    engine = Engine(profile, vehicle, "fixed", explicit=True)   # live / a recording's step times
    block = engine.feed(frames, step_times=[t_k], final=True)

Results come back as :class:`StepBlock` columns (one row per step). The same frames and step times
give the same rows whichever way they are cut: the live service and replay are the same code.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import numpy as np

from lde.can.codec import MessageCodec
from lde.can.e2e import ReceiverStats
from lde.can.frames import FrameBatch
from lde.can.profiles import INPUT_NAMES, Profile
from lde.engine.backends import BackendState, make_backend_state
from lde.engine.grid import (
    G_FINISH,
    G_K,
    G_MAX_STEPS,
    G_NSTEPS,
    G_OVERFLOW,
    G_PERIOD,
    G_SEGMENTS,
    MODE_ANCHORED,
    MODE_EXPLICIT,
    new_grid,
    overflow_error,
)
from lde.engine.loop import (
    N_V,
    V_ACTIVE,
    V_BANK_DEG,
    V_FW,
    V_FW_WIND,
    V_LEARN,
    V_MW,
    V_MW_WIND,
    V_STATE,
    V_STATUS,
    V_T_ALIGN,
    V_T_OVERLAY,
    V_ZERO,
    loop_arrays,
    run_loop,
)
from lde.engine.receiver import N_INPUTS, RxState, RxTables
from lde.errors import ConfigError
from lde.estimator import lateral as E
from lde.estimator import learner as Ln
from lde.estimator.conditioning import check_profile
from lde.estimator.learned import LearnedSnapshot, LearnedState, load_learned, parse_learned, save_snapshot
from lde.estimator.learner import tire_state
from lde.estimator.outputs import (
    N_OUT,
    O_BANK,
    O_BETA,
    O_FW,
    O_FW_WIND,
    O_LEARN,
    O_MW,
    O_MW_WIND,
    O_T_ALIGN,
    O_YAW,
)
from lde.estimator.overlay import (
    ALLOWED_ALWAYS,
    ALLOWED_NEVER,
    ALLOWED_ONCE_LEARNED,
    limiter_params,
    new_limiter_state,
)
from lde.params import Vehicle
from lde.units import STEP_S

__all__ = ["Engine", "StepBlock", "OutputTable", "OUTPUT_MESSAGES", "OUTPUT_SOURCES"]

#: the frames the pipeline encodes per step, in the order they are sent
OUTPUT_MESSAGES: tuple[str, ...] = ("LDE_Estimate", "LDE_Overlay", "LDE_Disturbance")
#: which per-step value each output signal carries (signals not listed: physical 0)
OUTPUT_SOURCES: dict[str, dict[str, int]] = {
    "LDE_Estimate": {"LatForce": V_FW, "YawMoment": V_MW, "AligningTorque": V_T_ALIGN, "Status": V_STATUS},
    "LDE_Overlay": {"OverlayTorque": V_T_OVERLAY, "Active": V_ACTIVE, "State": V_STATE},
    "LDE_Disturbance": {
        "WindForce": V_FW_WIND,
        "WindMoment": V_MW_WIND,
        "BankAngle": V_BANK_DEG,
        "LearnState": V_LEARN,
    },
}
assert N_V > V_ZERO


@dataclass(frozen=True, eq=False)
class OutputTable:
    """The output messages' layouts, concatenated for the compiled encoder (one signal per row,
    ``start``/``stop`` per message), with each signal's value source (``V_*``)."""

    names: tuple[str, ...]
    frame_id: np.ndarray
    length: np.ndarray
    args: tuple

    @classmethod
    def of(cls, profile: Profile, names: tuple[str, ...] = OUTPUT_MESSAGES) -> OutputTable:
        codecs = [MessageCodec(profile, n) for n in names]
        start, stop, rows = [], [], 0
        cols: dict[str, list[np.ndarray]] = {
            k: []
            for k in ("pos", "nbits", "le", "signed", "scale", "offset", "lo", "hi", "is_value", "source")
        }
        for c in codecs:
            lay = c.layout
            src = OUTPUT_SOURCES.get(c.name, {})
            start.append(rows)
            rows += len(c.order)
            stop.append(rows)
            cols["pos"].append(lay.pos)
            cols["nbits"].append(lay.nbits)
            cols["le"].append(lay.little_endian)
            cols["signed"].append(lay.signed)
            cols["scale"].append(lay.scale)
            cols["offset"].append(lay.offset)
            cols["lo"].append(lay.lo)
            cols["hi"].append(lay.hi)
            cols["is_value"].append(lay.is_value)
            cols["source"].append(np.array([src.get(s, V_ZERO) for s in c.order], np.int64))
        cat = {k: np.concatenate(v) for k, v in cols.items()}
        args = (
            np.array(start, np.int64),
            np.array(stop, np.int64),
            np.array([c.length for c in codecs], np.int64),
            np.array([c.scheme.kind_code for c in codecs], np.int64),
            np.array([c.frame_id for c in codecs], np.int64),
            np.stack([c.scheme.counter_parts for c in codecs]),
            np.stack([c.scheme.checksum_parts for c in codecs]),
            np.array([c.scheme.modulus for c in codecs], np.int64),
            np.array([c.scheme.invalid_counter for c in codecs], np.int64),
            cat["pos"],
            cat["nbits"],
            cat["le"],
            cat["signed"],
            cat["scale"],
            cat["offset"],
            cat["lo"],
            cat["hi"],
            cat["is_value"],
            cat["source"],
        )
        return cls(tuple(names), args[4], args[2], args)


@dataclass
class StepBlock:
    """Rows of steps (numpy columns; SI, ISO 8855 signs; ``t_align`` with the paper's sign).

    Attributes:
        t_ns: int64 step times [ns] in the frames' time base.
        status: uint8 ``LDE_Estimate.Status`` bits as sent.
        est: float64 (n, N_OUT): the estimator's ``O_*`` slots, finalised (Fw, Mw, T_align, beta, r).
        t_overlay: float64 overlay torque request [Nm]; overlay_state: uint8 limiter state;
        overlay_enable: bool, the limiter's enable input.
        inputs: float64 (n, N_INPUTS) the sampled inputs (raw, before the corrections), ages int64
            (n, N_INPUTS) [ns], valid_mask int64 (bit i: input i fresh), ok bool (n, 2) mdps/esc ok.
        frames_used: int64, input frames accepted since the previous step.
        e2e_rejects: int64, frames rejected (E2E or wrong length) since the start.
        frames: uint8 (n, n_outputs, 8), the encoded output frames (:data:`OUTPUT_MESSAGES`).
    """

    t_ns: np.ndarray
    status: np.ndarray
    est: np.ndarray
    t_overlay: np.ndarray
    overlay_state: np.ndarray
    overlay_enable: np.ndarray
    inputs: np.ndarray
    ages: np.ndarray
    valid_mask: np.ndarray
    ok: np.ndarray
    frames_used: np.ndarray
    e2e_rejects: np.ndarray
    frames: np.ndarray

    @classmethod
    def empty(cls, n: int, n_outputs: int = len(OUTPUT_MESSAGES)) -> StepBlock:
        return cls(
            t_ns=np.empty(n, np.int64),
            status=np.empty(n, np.uint8),
            est=np.full((n, N_OUT), np.nan),  # a slot a backend does not fill stays NaN
            t_overlay=np.empty(n),
            overlay_state=np.empty(n, np.uint8),
            overlay_enable=np.empty(n, np.bool_),
            inputs=np.empty((n, N_INPUTS)),
            ages=np.empty((n, N_INPUTS), np.int64),
            valid_mask=np.empty(n, np.int64),
            ok=np.empty((n, 2), np.bool_),
            frames_used=np.empty(n, np.int64),
            e2e_rejects=np.empty(n, np.int64),
            frames=np.zeros((n, n_outputs, 8), np.uint8),
        )

    @classmethod
    def packed(cls, n: int, n_outputs: int = len(OUTPUT_MESSAGES)) -> tuple[StepBlock, np.ndarray]:
        """:meth:`empty`, with every column a view into one uint8 buffer (returned too; each column
        64-byte aligned): the live service's one-row block, whose row the compiled hand-off
        (:mod:`lde.service.handoff`) copies into the recorder's step record as bytes. The columns have
        the same dtypes, shapes and (C-contiguous, aligned, writable) numba types as :meth:`empty`'s."""
        like = cls.empty(n, n_outputs)
        cols = [(f.name, getattr(like, f.name)) for f in fields(cls)]
        offs, size = [], 64  # room to align the first column
        for _, a in cols:
            offs.append(size)
            size = (size + a.nbytes + 63) & ~63
        mem = np.zeros(size, np.uint8)
        base = (-mem.ctypes.data) % 64
        views = {}
        for (name, a), off in zip(cols, offs, strict=True):
            o = base + off - 64
            v = mem[o : o + a.nbytes].view(a.dtype).reshape(a.shape)
            v[...] = a
            views[name] = v
        return cls(**views), mem

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def columns(self) -> tuple[np.ndarray, ...]:
        """The columns in field order: the compiled loop's ``out`` (:func:`lde.engine.loop.run_loop`)."""
        return tuple(getattr(self, f.name) for f in fields(self))

    def head(self, n: int) -> StepBlock:
        """The first ``n`` rows (views)."""
        return StepBlock(**{f.name: getattr(self, f.name)[:n] for f in fields(self)})

    def copy(self) -> StepBlock:
        return StepBlock(**{f.name: getattr(self, f.name).copy() for f in fields(self)})

    @classmethod
    def concat(cls, blocks: list[StepBlock]) -> StepBlock:
        if not blocks:
            return cls.empty(0)
        return cls(**{f.name: np.concatenate([getattr(b, f.name) for b in blocks]) for f in fields(cls)})

    # named views ------------------------------------------------------------------------
    @property
    def fw(self) -> np.ndarray:
        return self.est[:, O_FW]

    @property
    def mw(self) -> np.ndarray:
        return self.est[:, O_MW]

    @property
    def t_align(self) -> np.ndarray:
        return self.est[:, O_T_ALIGN]

    @property
    def beta(self) -> np.ndarray:
        return self.est[:, O_BETA]

    @property
    def yaw_rate(self) -> np.ndarray:
        return self.est[:, O_YAW]

    @property
    def fw_wind(self) -> np.ndarray:
        return self.est[:, O_FW_WIND]

    @property
    def mw_wind(self) -> np.ndarray:
        return self.est[:, O_MW_WIND]

    @property
    def bank(self) -> np.ndarray:
        """Road bank angle [rad] (NaN where the backend does not tell wind from bank)."""
        return self.est[:, O_BANK]

    @property
    def learn_state(self) -> np.ndarray:
        return self.est[:, O_LEARN].astype(np.int64)

    @property
    def overlay_active(self) -> np.ndarray:
        return (self.overlay_state == 1) | (self.overlay_state == 2)

    def input(self, name: str) -> np.ndarray:
        return self.inputs[:, INPUT_NAMES.index(name)]

    @property
    def mdps_ok(self) -> np.ndarray:
        return self.ok[:, 0]

    @property
    def esc_ok(self) -> np.ndarray:
        return self.ok[:, 1]


_MAX_HINT_ROWS = 1 << 21
_NO_TIMES = np.zeros(0, np.int64)
_NO_BOOL = np.zeros(0, np.bool_)
_NO_U8 = np.zeros(0, np.uint8)


def recorded_steps(
    step_times_ns: np.ndarray, enable: np.ndarray | None, extra_status: np.ndarray | None
) -> dict[str, Any]:
    """:meth:`Engine.feed`'s keyword arguments for a recording's step times [ns]: its overlay
    enables and extra status bits are passed only where they have one value per step time (a
    recording cut short may hold fewer), else the defaults (enabled, no extra bits) apply."""
    times = np.ascontiguousarray(step_times_ns, np.int64)
    en = enable if enable is not None and len(enable) == len(times) else None
    ex = extra_status if extra_status is not None and len(extra_status) == len(times) else None
    return {"step_times": times, "enable": en, "extra_status": ex}


class Engine:
    """Every state of the data path (receiver, grid, estimator, limiter, output counters) and the
    compiled loop over it.

    Args:
        profile: the CAN profile.
        vehicle: parameters, tuning, corrections and overlay limits.
        backend: a registered backend name (:mod:`lde.engine.backends`).
        explicit: step times are given with each :meth:`feed` (live, a recording's steps); else the
            anchored grid (:mod:`lde.engine.grid`).
        dt: the model period [s] (the grid period).
        encode_outputs: encode the output frames (``StepBlock.frames``); False for a replay whose
            output is only a CSV (the frames are then zeros).
    """

    def __init__(
        self,
        profile: Profile,
        vehicle: Vehicle,
        backend: str = "fixed",
        *,
        explicit: bool = False,
        dt: float = STEP_S,
        encode_outputs: bool = True,
    ) -> None:
        check_profile(vehicle, profile.steering_rate_signed, profile.name)
        self.profile = profile
        self.vehicle = vehicle
        self.backend_name = backend
        self.explicit = explicit
        self.encode_outputs = encode_outputs
        self.rx_tables = RxTables.of(profile)
        self.outputs = OutputTable.of(profile)
        self._dt = dt
        self.reset()

    def reset(self) -> None:
        """Back to the start: nothing received, no step run."""
        vehicle = self.vehicle
        self.rx = RxState.initial(self.rx_tables)
        self.grid = new_grid(MODE_EXPLICIT if self.explicit else MODE_ANCHORED)
        self.prev_t = np.full(1, np.iinfo(np.int64).min, np.int64)  # the previous step's time
        self.lp = limiter_params(vehicle, allowed=self.overlay_allowed)
        self.lsi, self.lsf = new_limiter_state()
        self.counters = np.zeros(len(self.outputs.names), np.int64)
        self.used_since = np.zeros(1, np.int64)
        self._steps, self._enable, self._extra = _NO_TIMES, _NO_BOOL, _NO_U8
        self.frames_fed = 0
        self.est: BackendState = self._new_backend_state()
        self.backend = self.est.backend
        # the loop's backend-independent arrays as one compiled argument (lde.engine.loop.LoopArrays)
        self._la = loop_arrays(
            self.rx_tables.kernel_args(),
            self.outputs.args,
            self.rx.kernel_args(),
            self.grid,
            self.prev_t,
            self.lp,
            self.lsi,
            self.lsf,
            self.counters,
            self.used_since,
            self.rx_tables.anchor,
        )
        self.learned_from: LearnedState | None = None

    def _new_backend_state(self) -> BackendState:
        """The backend's parameters and state at the start (:meth:`reset`)."""
        return make_backend_state(
            self.backend_name,
            self.vehicle,
            self._dt,
            self.profile.angle_above_torsion_bar,
            self.torque_scale,
        )

    @property
    def torque_scale(self) -> int:
        """Which torque's scale the learner learns (:func:`lde.estimator.learner.torque_scale_mode`
        of the profile's inputs of unknown scale; 0: both torques in Nm)."""
        return Ln.torque_scale_mode(self.profile.unknown_scale)

    @property
    def overlay_allowed(self) -> int:
        """When the overlay may be enabled (``lde.estimator.overlay.ALLOWED_*``): always when both
        torques are in Nm; with one of unknown scale only once the learner reports "learned", which
        needs that torque's factor to the other (in Nm) known to ``L_SCALE_SD``; never when both are
        of unknown scale (their unit to Nm is not identifiable from driving: a torque request in
        unknown units is unsafe). The loop's enable is this and the step's own enable
        (``LP_ALLOWED`` of the limiter's parameters carries it)."""
        ts = self.torque_scale
        if ts == Ln.TS_KNOWN:
            return ALLOWED_ALWAYS
        return ALLOWED_NEVER if ts == Ln.TS_BOTH else ALLOWED_ONCE_LEARNED

    @property
    def steps(self) -> int:
        """Steps run so far."""
        return int(self.grid[G_NSTEPS])

    @property
    def segments(self) -> int:
        """Grid segments started (anchored mode)."""
        return int(self.grid[G_SEGMENTS])

    # ------------------------------------------------------------------ learned state
    @property
    def learns(self) -> bool:
        """The backend learns the car online (:mod:`lde.estimator.learner`)."""
        return self.backend.learns

    def _require_learning(self) -> None:
        if not self.learns:
            raise ConfigError(
                f"backend {self.backend.name!r} does not learn: --learned needs a learning backend"
            )

    def load_learned(self, path: str | Path) -> LearnedState | None:
        """Start from a learned-state file (``--learned``) when it exists (None when it does not):
        checked against this vehicle and profile (ConfigError otherwise)."""
        self._require_learning()
        if not Path(path).exists():
            return None
        e = self.est
        return self._use(load_learned(path, self.profile.name, e.state.p, e.params.lp))

    def load_learned_text(self, text: str, source: str) -> LearnedState:
        """:meth:`load_learned` of a learned-state file's text (a recording's learned start)."""
        self._require_learning()
        e = self.est
        return self._use(parse_learned(text, source, self.profile.name, e.state.p, e.params.lp))

    def _use(self, got: LearnedState) -> LearnedState:
        self.est.state.ls[:] = got.learner
        self.est.params_changed()  # the fixed backend re-quantises its coefficient set from p
        self.learned_from = got
        return got

    def learned_snapshot(self, seconds: float) -> LearnedSnapshot:
        """A copy of what was learned: the drives and driving time so far plus ``seconds`` of this
        run (valid steps). ConfigError for a backend that does not learn."""
        self._require_learning()
        prev = self.learned_from
        st = self.est.state
        return LearnedSnapshot(
            self.vehicle.name,
            self.profile.name,
            st.p.copy(),
            st.ls.copy(),
            (prev.drives if prev is not None else 0) + 1,
            (prev.seconds if prev is not None else 0.0) + float(seconds),
        )

    def save_learned(self, path: str | Path, seconds: float) -> None:
        """Write what was learned (atomically); see :meth:`learned_snapshot`."""
        save_snapshot(path, self.learned_snapshot(seconds))

    @property
    def learn_summary(self) -> str:
        """What the learner holds now, one line (empty for a backend that does not learn)."""
        if not self.learns:
            return ""
        p, ls, lp = self.est.state.p, self.est.state.ls, self.est.params.lp
        state = ("not learned", "learning", "learned")[min(2, tire_state(ls))]
        # with both torques of unknown scale K and the friction are in the column signal's unit
        unit = "unit" if self.torque_scale == Ln.TS_BOTH else "Nm"
        text = (
            f"tires {state}: Cf {p[E.P_CF]:.0f} Cr {p[E.P_CR]:.0f} N/rad, K {p[E.P_K]:.4g} {unit}/rad, "
            f"accel scale {p[E.P_S]:.3f}, friction {p[E.P_TFRIC]:.3g} {unit}, angle offset "
            f"{np.degrees(p[E.P_DSW]):.3f} deg, gyro bias {np.degrees(p[E.P_BR]):.4f} deg/s"
        )
        scales = Ln.torque_scales(p, lp, ls)
        if scales:
            overlay = (
                "overlay off (the torques' unit to Nm is not identifiable)"
                if self.overlay_allowed == ALLOWED_NEVER
                else "overlay off until learned"
            )
            text += f"; torques of unknown scale: {scales}; Fw, Mw in N, Nm as far as these are right"
            text += f"; {overlay}"
        return text

    def stats(self) -> dict[str, ReceiverStats]:
        """Per input message counts so far."""
        return self.rx.stats(self.rx_tables)

    @property
    def n_ignored(self) -> int:
        return int(self.rx.ignored[0])

    # ------------------------------------------------------------------ running
    def run_arrays(
        self,
        t_ns: np.ndarray,
        can_id: np.ndarray,
        is_extended: np.ndarray,
        dlc: np.ndarray,
        data: np.ndarray,
        is_rx: np.ndarray,
        out: StepBlock,
        *,
        i0: int = 0,
        step_times: np.ndarray = _NO_TIMES,
        enable: np.ndarray = _NO_BOOL,
        extra_status: np.ndarray = _NO_U8,
        final: bool = True,
        t_end_ns: int | None = None,
    ) -> tuple[int, int]:
        """The compiled loop on raw frame columns from frame ``i0`` (the live hot path: no copies);
        ``data`` are the frames' bytes, uint8 [n, width] (:attr:`lde.can.frames.FrameBatch.data`).
        Fills ``out`` from row 0; returns (next frame index, rows written).

        ``final``: no frame follows these (live: every frame up to the step times has been given;
        replay: the log ends), so the steps after the last frame run too (anchored: up to
        ``t_end_ns`` or the last frame). Explicit mode: ``step_times`` are this call's steps
        (``enable``/``extra_status`` per step, or empty: on / 0); the frames after the last one stay
        unfed.
        """
        g = self.grid
        if self.explicit:
            g[G_K] = 0
            g[G_FINISH] = 0
        args = self._args(
            (t_ns, can_id, is_extended, dlc, data, is_rx),
            out,
            i0,
            step_times,
            enable,
            extra_status,
            final,
            t_end_ns,
        )
        i, n = run_loop(*args)
        if g[G_OVERFLOW]:
            raise overflow_error(int(g[G_MAX_STEPS]), int(g[G_PERIOD]))
        return int(i), int(n)

    def live_args(
        self,
        frames: tuple[np.ndarray, ...],
        out: StepBlock,
        step_times: np.ndarray,
        enable: np.ndarray,
        extra_status: np.ndarray,
    ) -> tuple:
        """The argument tuple of a live call (:meth:`run_live`): ``frames`` the six frame columns of
        :meth:`run_arrays`, ``final``, from frame 0. Built once per set of arrays by the caller, who
        refills the arrays in place; valid as long as :meth:`live_args_valid` says so."""
        return self._args(frames, out, 0, step_times, enable, extra_status, True, None)

    def live_args_valid(self, args: tuple) -> bool:
        """``args`` (:meth:`live_args`) still name this engine's state (not after :meth:`reset`)."""
        e = self.est
        return args[0] is e.params and args[1] is e.state and args[2] is self._la

    def run_live(self, args: tuple) -> tuple[int, int]:
        """:meth:`run_arrays` (explicit mode) on an argument tuple from :meth:`live_args`: the live
        step's engine call without rebuilding its arguments."""
        g = self.grid
        g[G_K] = 0
        g[G_FINISH] = 0
        i, n = run_loop(*args)
        if g[G_OVERFLOW]:
            raise overflow_error(int(g[G_MAX_STEPS]), int(g[G_PERIOD]))
        return i, n

    def _args(
        self,
        frames: tuple[np.ndarray, ...],
        out: StepBlock,
        i0: int,
        step_times: np.ndarray,
        enable: np.ndarray,
        extra_status: np.ndarray,
        final: bool,
        t_end_ns: int | None,
    ) -> tuple:
        e = self.est
        return (
            e.params,
            e.state,
            self._la,
            frames,
            (step_times, enable, extra_status),
            out.columns(),
            i0,
            final,
            np.int64(t_end_ns or 0),
            t_end_ns is not None,
            self.encode_outputs,
        )

    def feed(
        self,
        frames: FrameBatch,
        *,
        step_times: np.ndarray | None = None,
        enable: np.ndarray | None = None,
        extra_status: np.ndarray | None = None,
        final: bool = False,
        t_end_ns: int | None = None,
        block_rows: int = 1 << 16,
    ) -> StepBlock:
        """Run ``frames`` (time-sorted; lde's own ``is_rx`` False frames are skipped) and every step
        that becomes due. ``final``: the log ends after these frames.

        Explicit mode: ``step_times`` (non-decreasing, after every step time given before) join the
        steps still pending; with ``final`` all of them run, otherwise those after the last frame of
        this call wait for the next call. Frames after the last step time are not fed.
        """
        if self.explicit and step_times is not None:
            t = np.ascontiguousarray(step_times, np.int64).reshape(-1)
            m = t.shape[0]
            en = np.ones(m, np.bool_) if enable is None else np.ascontiguousarray(enable, np.bool_)
            ex = (
                np.zeros(m, np.uint8)
                if extra_status is None
                else np.ascontiguousarray(extra_status, np.uint8)
            )
            if en.shape != (m,) or ex.shape != (m,):
                raise ValueError("enable / extra_status need one value per step time")
            self._steps = np.concatenate([self._steps, t])
            self._enable = np.concatenate([self._enable, en])
            self._extra = np.concatenate([self._extra, ex])
        return self._feed(frames, final, t_end_ns, block_rows)

    def _feed(self, frames: FrameBatch, final: bool, t_end_ns: int | None, block_rows: int) -> StepBlock:
        blocks: list[StepBlock] = []
        i = 0
        rows = self._rows_hint(frames, block_rows)
        while True:
            out = StepBlock.empty(rows, len(self.outputs.names))
            i, n = self.run_arrays(
                frames.t_ns,
                frames.can_id,
                frames.is_extended,
                frames.dlc,
                frames.data,
                frames.is_rx,
                out,
                i0=i,
                step_times=self._steps,
                enable=self._enable,
                extra_status=self._extra,
                final=final,
                t_end_ns=t_end_ns,
            )
            if self.explicit:
                self._steps, self._enable, self._extra = self._steps[n:], self._enable[n:], self._extra[n:]
            blocks.append(out.head(n))
            if n < rows:
                break
            rows = block_rows
        self.frames_fed = i
        return StepBlock.concat(blocks) if len(blocks) > 1 else blocks[0]

    def _rows_hint(self, frames: FrameBatch, block_rows: int) -> int:
        """Rows to allocate for one call: the steps it will most likely run (explicit: the pending
        step times; anchored: the frames' time span / the period), so that the rows come in one
        block without a copy; at most :data:`_MAX_HINT_ROWS` (untouched rows cost no memory)."""
        if self.explicit:
            hint = len(self._steps) + 1
        elif len(frames):
            hint = (int(frames.t_ns[-1]) - int(frames.t_ns[0])) // int(self.grid[G_PERIOD]) + 64
        else:
            hint = 0
        return int(min(max(hint, block_rows), _MAX_HINT_ROWS))

    def finish(self, t_end_ns: int | None = None) -> StepBlock:
        """The log has ended: the remaining steps run (anchored: up to ``t_end_ns`` or the last frame;
        explicit: every pending step time)."""
        return self.feed(FrameBatch.empty(), final=True, t_end_ns=t_end_ns)
