"""THE compiled loop of the data path, live and in replay (one step's work exists only here).

For the frames handed in (time order) and the step times the grid makes due (:mod:`lde.engine.grid`),
:func:`run_loop` interleaves::

    frame  -> receiver (decode, E2E, latest sample)                    lde.engine.receiver.rx_feed
    step k -> inputs at t_k (sample-and-hold, staleness, trust)        lde.engine.receiver.rx_sample
           -> estimator step (backend, t_k passed in; each backend applies
              its own input corrections and learns what it learns)     backend_step
           -> status | extra bits (DEADLINE_MISS live, as recorded in replay)
           -> overlay law + limiter                                    lde.estimator.overlay.overlay_kernel
           -> finalise: a non-finite Fw, Mw, T_align or T_overlay is sent as 0 with VALID cleared
              and DEGRADED set (never NaN on the bus)
           -> output frames LDE_Estimate, LDE_Overlay (counters, CRCs)   lde.can.codec.encode_row
              (``encode`` False: a replay whose frames nobody reads; the counters then stay put)
           -> one row of every output column

The live service calls it once per step with the frames drained so far and one explicit step time;
replay calls it per chunk of a log with the anchored grid (or a recording's step times). The state
(receiver, grid, estimator, limiter, output counters) lives in arrays owned by
:class:`lde.engine.engine.Engine` and survives between calls, so a log cut into chunks, or a live run step
by step, gives the same rows as one call over everything.

**One loop for every backend.** A backend (:mod:`lde.engine.backends`) declares its parameters and
state as two NamedTuples of arrays and registers its compiled step for its state's class
(:func:`register_step`). The loop calls the stub :func:`backend_step`; its numba overload picks the
registered step by the numba type of ``state``. numba compiles (and caches on disk) one
specialisation of :func:`run_loop` per backend, as it does for any argument type.

The receiver's tables and state, the grid, the limiter and the output counters do not depend on the
backend: they travel as one :class:`LoopArrays` (a numba ``StructRef``: one object to unbox per call
instead of 50 arrays), whose fields the loop reads once per call and hands to its parts (reading a
field takes a reference to each of its arrays: read per frame, it cost the float backend 1.31 s of
engine CPU per hour against 1.27 s read once, ``scripts/engine_cpu.py``). The frame's and the
step's work around the backend step (:func:`feed_frame`, :func:`sample_inputs`,
:func:`step_outputs`) are compiled functions of their own, compiled once for every backend's loop.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numba import njit, types
from numba.experimental import structref
from numba.extending import overload

from lde.can.codec import encode_row
from lde.can.e2e import S_ACCEPTED, S_N_REPEATED, S_N_WRONGCRC, S_N_WRONGSEQ, advance_counter
from lde.engine.grid import (
    G_FINISH,
    G_K,
    G_MODE,
    G_OVERFLOW,
    MODE_EXPLICIT,
    grid_due,
    grid_finish,
    grid_frame,
    grid_step_done,
)
from lde.engine.receiver import (
    I_COLUMN_TORQUE,
    I_SPEED,
    I_STEERING_ANGLE,
    rx_count_ignored,
    rx_feed,
    rx_msg_of,
    rx_sample,
)
from lde.estimator.learner import ST_LEARNED
from lde.estimator.outputs import O_BANK, O_FW, O_FW_WIND, O_GAIN, O_LEARN, O_MW, O_MW_WIND, O_T_ALIGN
from lde.estimator.overlay import ALLOWED_ONCE_LEARNED, LP_ALLOWED, LP_GAIN, LS_STATE, overlay_kernel
from lde.status import DEGRADED, VALID
from lde.units import DEG

__all__ = [
    "V_FW",
    "V_MW",
    "V_T_ALIGN",
    "V_STATUS",
    "V_T_OVERLAY",
    "V_ACTIVE",
    "V_STATE",
    "V_FW_WIND",
    "V_MW_WIND",
    "V_BANK_DEG",
    "V_LEARN",
    "V_ZERO",
    "N_V",
    "LOOP_FIELDS",
    "LoopArrays",
    "loop_arrays",
    "backend_step",
    "register_step",
    "run_loop",
    "finalise",
]

# --- the values an output frame's signals are taken from (lde.engine.engine.OUTPUT_SOURCES) ----------
V_FW, V_MW, V_T_ALIGN, V_STATUS, V_T_OVERLAY, V_ACTIVE, V_STATE = range(7)
V_FW_WIND, V_MW_WIND, V_BANK_DEG, V_LEARN, V_ZERO = range(7, 12)
N_V = 12


@njit(cache=True, inline="always")
def finalise(est, torque, status):  # pragma: no cover - compiled
    """The one output finalisation: a non-finite Fw, Mw, T_align or T_overlay becomes 0, VALID is
    cleared and DEGRADED set. Mutates ``est``; returns (torque, status)."""
    bad = False
    for k in (O_FW, O_MW, O_T_ALIGN):
        if not math.isfinite(est[k]):
            est[k] = 0.0
            bad = True
    if not math.isfinite(torque):
        torque = 0.0
        bad = True
    if bad:
        status = (status & ~VALID) | DEGRADED
    return torque, status


@njit(cache=True, inline="always")
def _rejects(e2e, malformed):  # pragma: no cover - compiled
    """Frames rejected so far: E2E (repeated, wrong sequence, wrong CRC) plus malformed."""
    n = 0
    for m in range(e2e.shape[0]):
        n += e2e[m, S_N_REPEATED] + e2e[m, S_N_WRONGSEQ] + e2e[m, S_N_WRONGCRC] + malformed[m]
    return n


@njit(cache=True, inline="always")
def _encode_outputs(otab, vals, counters, frames_row, values):  # pragma: no cover - compiled
    """Encode every output message (``otab``: lde.engine.engine.OutputTable.kernel_args) from ``vals``
    into ``frames_row`` (n_msg, 8); advances the counters. ``values``: scratch, one slot per signal."""
    (
        m_start,
        m_stop,
        m_length,
        m_kind,
        m_id,
        m_ctr,
        m_chk,
        m_mod,
        m_inv,
        shift,
        nbits,
        le,
        signed,
        scale,
        offset,
        lo,
        hi,
        is_value,
        source,
    ) = otab
    for j in range(m_start.shape[0]):
        a, b = m_start[j], m_stop[j]
        for k in range(a, b):
            values[k - a] = vals[source[k]]
        encode_row(
            values[: b - a],
            shift[a:b],
            nbits[a:b],
            le[a:b],
            signed[a:b],
            scale[a:b],
            offset[a:b],
            lo[a:b],
            hi[a:b],
            is_value[a:b],
            m_length[j],
            m_kind[j],
            m_id[j],
            m_ctr[j],
            m_chk[j],
            counters[j],
            frames_row[j],
        )
        counters[j] = advance_counter(counters[j], m_mod[j], m_inv[j])


# --- the loop's fixed arrays -----------------------------------------------------------------------

#: :class:`LoopArrays`' fields, in the constructor's order: ``tb`` (lde.engine.receiver.RxTables.kernel_args),
#: ``otab`` (lde.engine.engine.OutputTable.args), ``rxst`` (lde.engine.receiver.RxState.kernel_args),
#: ``grid`` (lde.engine.grid G_* slots), ``prev_t`` (1,) the previous step's time [ns], ``lp`` / ``lsi`` /
#: ``lsf`` the limiter's parameters and state (lde.estimator.overlay), ``counters`` the output messages'
#: counters, ``used_since`` (1,) the input frames accepted since the previous step, ``anchor`` the row
#: of the grid's anchor message
LOOP_FIELDS = ("tb", "otab", "rxst", "grid", "prev_t", "lp", "lsi", "lsf", "counters", "used_since", "anchor")


@structref.register
class LoopArraysType(types.StructRef):
    def preprocess_fields(self, fields: Any) -> tuple:
        return tuple((name, types.unliteral(t)) for name, t in fields)


class LoopArrays(structref.StructRefProxy):
    """The loop's backend-independent arrays (:data:`LOOP_FIELDS`) as one compiled argument. It
    holds the arrays themselves (references, not copies): stores by the compiled code are seen from
    Python and the other way round. A caller that replaces an array makes a new one."""


structref.define_proxy(LoopArrays, LoopArraysType, list(LOOP_FIELDS))


@njit(cache=True)
def _new_loop_arrays(
    tb, otab, rxst, grid, prev_t, lp, lsi, lsf, counters, used_since, anchor
):  # pragma: no cover
    return LoopArrays(tb, otab, rxst, grid, prev_t, lp, lsi, lsf, counters, used_since, anchor)


def loop_arrays(*arrays: Any) -> LoopArrays:
    """A :class:`LoopArrays` of ``arrays`` (:data:`LOOP_FIELDS` order), made by a cached compiled
    constructor (the proxy's own constructor would be compiled again in every process)."""
    if len(arrays) != len(LOOP_FIELDS):
        raise TypeError(
            f"loop_arrays takes {len(LOOP_FIELDS)} arguments ({', '.join(LOOP_FIELDS)}), got {len(arrays)}"
        )
    *head, anchor = arrays
    return _new_loop_arrays(*head, np.int64(anchor))  # type: ignore[call-arg]


# --- the backend step: one stub, the registered steps behind it ------------------------------------

#: a backend's state class -> its compiled step (register_step)
_STEPS: dict[type, Any] = {}


def register_step(state_class: type, step: Any) -> None:
    """Make ``step`` (a compiled function with :func:`backend_step`'s signature) the step of every
    backend whose state is a ``state_class`` (a NamedTuple class: numba types it by its class)."""
    _STEPS[state_class] = step


def backend_step(params, state, t_ns, inputs, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - stub
    """The step of the backend whose state ``state`` is (compiled code only): one estimator step at
    ``t_ns`` [ns] on the sampled ``inputs`` (SI, :data:`lde.can.profiles.INPUT_NAMES` order, raw: each
    backend applies its own corrections); ``fresh``: bit i set when input i brought a new sample at
    this step; ``mdps_ok`` / ``esc_ok``: the input groups' validity; fills ``out``
    (:mod:`lde.estimator.outputs`) and returns the status bits (:mod:`lde.status`)."""
    raise TypeError("backend_step runs inside compiled code only")


@overload(backend_step)
def _backend_step(params, state, t_ns, inputs, fresh, mdps_ok, esc_ok, out):
    step = _STEPS.get(getattr(state, "instance_class", None))
    if step is None:
        return None  # numba then says that no backend step takes these types

    def impl(params, state, t_ns, inputs, fresh, mdps_ok, esc_ok, out):  # pragma: no cover - compiled
        return step(params, state, t_ns, inputs, fresh, mdps_ok, esc_ok, out)

    return impl


# --- the loop's parts, shared by every backend's loop ---------------------------------------------
# feed_frame is its own compiled function. The two per-step parts are inlined into the loop: a call
# into a compiled function increfs and decrefs every array it is given (the receiver's and the
# output encoder's tables are tuples of about 20 arrays each), and inlining them measured -24 % of
# the engine's time on an hour's replay (CSV identical, the cold compile unchanged); inlining
# feed_frame as well measured no difference.


@njit(cache=True)
def feed_frame(tb, st, g, used_since, anchor, t_ns, can_id, is_ext, dlc, data):  # pragma: no cover - compiled
    """One received frame of an input message (time ``t_ns`` [ns]): the receiver
    (:func:`lde.engine.receiver.rx_feed`), the count of accepted input frames since the previous step, the
    grid (:func:`lde.engine.grid.grid_frame`)."""
    m, code = rx_feed(tb, st, t_ns, can_id, is_ext, dlc, data)
    accepted = code >= 0 and st[0][m, S_ACCEPTED] != 0
    if accepted:
        used_since[0] += 1
    grid_frame(g, t_ns, m >= 0, m == anchor and accepted)


@njit(cache=True, inline="always")
def sample_inputs(tb, st, prev_t, tk, vin, age):  # pragma: no cover - compiled
    """The inputs at step time ``tk`` [ns] into ``vin`` (SI) and ``age`` [ns]
    (:func:`lde.engine.receiver.rx_sample`). Returns (valid mask, fresh mask: the inputs that brought a new
    sample since the previous step at ``prev_t[0]``, which becomes ``tk``; mdps ok, esc ok)."""
    mask, ok_m, ok_e = rx_sample(tb, st, tk, vin, age)
    fresh = 0
    for q in range(vin.shape[0]):
        if age[q] >= 0 and tk - age[q] > prev_t[0]:
            fresh |= 1 << q
    prev_t[0] = tk
    return mask, np.int64(fresh), bool(ok_m), bool(ok_e)


@njit(cache=True, inline="always")
def step_outputs(
    otab, lp, lsi, lsf, counters, tk, est, status, enable, vin, encode, frames_row, vals, scratch
):  # pragma: no cover - compiled
    """After the backend step at ``tk`` [ns] (``est``: its output row, ``status`` its bits): the
    overlay law and limiter, the finalisation, the output values ``vals`` (``V_*``) and, when
    ``encode``, the output frames into ``frames_row`` (one row per output message). Returns
    (torque [Nm], status, limiter state)."""
    gain = est[O_GAIN]
    if math.isfinite(gain) and gain > 0.0:  # the backend's learned tires (else the vehicle file's)
        lp[LP_GAIN] = gain
    torque = overlay_kernel(
        lp,
        lsi,
        lsf,
        tk,
        est[O_FW],
        est[O_MW],
        status,
        vin[I_SPEED],
        vin[I_STEERING_ANGLE],
        vin[I_COLUMN_TORQUE],
        enable,
    )
    torque, status = finalise(est, torque, status)
    state = lsi[LS_STATE]
    vals[V_FW] = est[O_FW]
    vals[V_MW] = est[O_MW]
    vals[V_T_ALIGN] = est[O_T_ALIGN]
    vals[V_STATUS] = status
    vals[V_T_OVERLAY] = torque
    vals[V_ACTIVE] = 1.0 if (state == 1 or state == 2) else 0.0
    vals[V_STATE] = state
    # the wind / bank split and the learned state (0 on the bus where a backend has none)
    vals[V_FW_WIND] = est[O_FW_WIND] if math.isfinite(est[O_FW_WIND]) else 0.0
    vals[V_MW_WIND] = est[O_MW_WIND] if math.isfinite(est[O_MW_WIND]) else 0.0
    vals[V_BANK_DEG] = est[O_BANK] / DEG if math.isfinite(est[O_BANK]) else 0.0
    vals[V_LEARN] = est[O_LEARN]
    if encode:
        _encode_outputs(otab, vals, counters, frames_row, scratch)
    return torque, status, state


@njit(cache=True, nogil=True)
def run_loop(params, state, la, frames, steps, out, i0, final, t_end, have_end, encode):  # pragma: no cover
    """Interleave frames and due steps (module docstring) from frame ``i0`` on.

    ``params``, ``state``: the backend's (:mod:`lde.engine.backends`); ``la``: the loop's
    :class:`LoopArrays`; ``frames``: the frame columns (time [ns], id, extended, dlc, the data
    bytes as uint8 rows 8 to 64 wide, ``is_rx``: frames with ``is_rx`` False, lde's own in a
    recording, are skipped); ``steps``: explicit mode's step times [ns] and their overlay enables and
    extra status bits (or empty: on / 0); ``out``: the columns of :class:`lde.engine.engine.StepBlock`
    (in its field order), filled from row 0. ``final``: no frame follows these; once they are fed the
    grid finishes (:func:`lde.engine.grid.grid_finish` with ``t_end`` when ``have_end``) and the
    remaining steps run. ``encode``: encode the output frames.

    Returns (next frame index, rows written). Stops when the rows are full, when the grid has no
    due step and no frame is left (a later call continues), with explicit step times when none is
    left (the frames after it stay unfed), or when the grid overflows (``grid[G_OVERFLOW]``). It
    releases the GIL: a replay reads the next piece of its log in another thread meanwhile.
    """
    t, can_id, is_ext, dlc, data, is_rx = frames
    explicit, ex_enable, ex_extra = steps
    o_t, o_status, o_est, o_tov, o_ovst, o_enable, o_in, o_age, o_mask, o_ok, o_used, o_rej, o_frames = out
    tb, otab, st, g = la.tb, la.otab, la.rxst, la.grid
    used_since, prev_t, anchor = la.used_since, la.prev_t, la.anchor
    lp, lsi, lsf, counters = la.lp, la.lsi, la.lsf, la.counters
    e2e = st[0]
    malformed = st[1]
    nf = t.shape[0]
    cap = o_t.shape[0]
    vals = np.zeros(N_V)
    scratch = np.empty(otab[9].shape[0])
    allowed = lp[LP_ALLOWED] > 0.0  # Engine.overlay_allowed: the profile's torques have known units
    # ... or one of unknown scale whose factor the learner must report learned first
    once_learned = lp[LP_ALLOWED] == ALLOWED_ONCE_LEARNED
    i = i0
    n = 0
    while n < cap:
        while i < nf and not is_rx[i]:
            i += 1
        have = i < nf
        if not have and final and g[G_FINISH] == 0:
            grid_finish(g, t_end, have_end)
        t_next = t[i] if have else np.int64(0)
        is_input = have and rx_msg_of(tb, np.int64(can_id[i]), is_ext[i]) >= 0
        due, tk = grid_due(g, explicit, have, t_next, is_input)
        if g[G_OVERFLOW] == 1:
            break
        if due:
            enable = allowed
            extra = 0
            if g[G_MODE] == MODE_EXPLICIT:
                j = g[G_K]
                if ex_enable.shape[0] > j:
                    enable = allowed and ex_enable[j]
                if ex_extra.shape[0] > j:
                    extra = ex_extra[j]
            vin = o_in[n]
            est = o_est[n]
            mask, fresh, ok_m, ok_e = sample_inputs(tb, st, prev_t, tk, vin, o_age[n])
            status = backend_step(params, state, tk, vin, fresh, ok_m, ok_e, est)
            status |= extra
            if once_learned and est[O_LEARN] != ST_LEARNED:
                enable = False
            # np.int64 / bool: numba types a call while the loop's types are still partial (the
            # literal 0 or True of their first assignment) and would compile the callee once more
            torque, status, ovst = step_outputs(
                otab,
                lp,
                lsi,
                lsf,
                counters,
                tk,
                est,
                np.int64(status),
                bool(enable),
                vin,
                encode,
                o_frames[n],
                vals,
                scratch,
            )
            o_t[n] = tk
            o_status[n] = status
            o_tov[n] = torque
            o_ovst[n] = ovst
            o_enable[n] = enable
            o_mask[n] = mask
            o_ok[n, 0] = ok_m
            o_ok[n, 1] = ok_e
            o_used[n] = used_since[0]
            used_since[0] = 0
            o_rej[n] = _rejects(e2e, malformed)
            grid_step_done(g)
            n += 1
            continue
        if not have:
            break
        if g[G_MODE] == MODE_EXPLICIT and g[G_K] >= explicit.shape[0]:
            break  # no step left: later frames wait for the steps they belong to (time order)
        if is_input:
            feed_frame(
                tb,
                st,
                g,
                used_since,
                anchor,
                t[i],
                np.int64(can_id[i]),
                is_ext[i],
                np.int64(dlc[i]),
                data[i],
            )
        else:  # an id the profile ignores: rx_feed's count and the grid's hook, without the call
            rx_count_ignored(st)
            grid_frame(g, t[i], False, False)
        i += 1
    return i, n
