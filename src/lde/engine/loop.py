"""THE compiled loop of the data path, live and in replay (one step's work exists only here).

For the frames handed in (time order) and the step times the grid makes due (:mod:`lde.engine.grid`),
:func:`run_loop` interleaves::

    frame  -> receiver (decode, E2E, latest sample)                    lde.engine.receiver.rx_feed
    step k -> inputs at t_k (sample-and-hold, staleness, trust)        lde.engine.receiver.rx_sample
           -> estimator step (backend, t_k passed in; each backend applies
              its own input corrections and learns what it learns)     lde.engine.backends
           -> status | extra bits (DEADLINE_MISS live, as recorded in replay)
           -> overlay law + limiter                                    lde.estimator.overlay.overlay_kernel
           -> finalise: a non-finite Fw, Mw, T_align or T_overlay is sent as 0 with VALID cleared
              and DEGRADED set (never NaN on the bus)
           -> output frames LDE_Estimate, LDE_Overlay (counters, CRCs)   lde.can.codec.encode_word
              (``encode`` False: a replay whose frames nobody reads; the counters then stay put)
           -> one row of every output column

The live service calls it once per step with the frames drained so far and one explicit step time;
replay calls it per chunk of a log with the anchored grid (or a recording's step times). The state
(receiver, grid, estimator, limiter, output counters) lives in arrays owned by
:class:`lde.engine.engine.Engine` and survives between calls, so a log cut into chunks, or a live run step
by step, gives the same rows as one call over everything.

The frame's and the step's work around the backend step are compiled functions of their own
(:func:`feed_frame`, :func:`sample_inputs`, :func:`step_outputs`), shared by every backend's loop:
a cold start compiles them beside the step on a second core (:mod:`lde.coldstart`).

The backend step (``step(bp, bs, t_ns, inputs, fresh, mdps_ok, esc_ok, out) -> status``: the
sampled SI inputs, a bit mask of the inputs that brought a new sample since the previous step, the
groups' validity; ``out`` the ``O_*`` slots) is bound into its own compiled copy of the loop by
:func:`make_loop` (one per backend, each cached on disk): numba's function-typed arguments would
make every call go through a function pointer and could not be cached.
"""

from __future__ import annotations

import math
import types
from typing import Any

import numpy as np
from numba import njit

from lde.can.bitfield import word_to_bytes
from lde.can.codec import encode_word
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
from lde.engine.loopargs import field
from lde.engine.receiver import (
    I_COLUMN_TORQUE,
    I_SPEED,
    I_STEERING_ANGLE,
    rx_count_ignored,
    rx_feed,
    rx_msg_of,
    rx_sample,
)
from lde.estimator.overlay import LP_GAIN, LS_STATE, overlay_kernel
from lde.estimator.paper import O_BANK, O_FW, O_FW_WIND, O_GAIN, O_LEARN, O_MW, O_MW_WIND, O_T_ALIGN
from lde.refcount import NO_REFCOUNT
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
    "make_loop",
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
        w = encode_word(
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
        )
        word_to_bytes(w, frames_row[j])
        counters[j] = advance_counter(counters[j], m_mod[j], m_inv[j])


# --- the loop's parts, each its own compiled (cached) function -------------------------------------
# They are shared by every backend's loop and do not depend on the backend step, so a cold start
# compiles them in its helper process (lde.coldstart) while this process compiles the step; the
# loop then only types three calls (its own compile: about a third). LLVM still sees their code
# when it optimises the loop's module (numba links a callee's module into its caller's).
# Without numba's reference counting (lde.refcount): it would incref and decref every array
# argument of a call (about 30 here, the tables are tuples of arrays) on each call: +13 % (fixed) /
# +30 % (float) engine CPU per hour measured with them as plain calls (docs/startup.md).


@njit(cache=True, **NO_REFCOUNT)
def feed_frame(la, g, t_ns, can_id, is_ext, dlc, w_le, anchor):  # pragma: no cover - compiled
    """One received frame of an input message (time ``t_ns`` [ns]): the receiver
    (:func:`lde.engine.receiver.rx_feed`), the count of accepted input frames since the previous step, the
    grid (:func:`lde.engine.grid.grid_frame`; ``anchor``: the row of the anchor message). ``la``: the
    loop's :class:`lde.engine.loopargs.LoopArrays`, one pointer instead of 26 arrays copied per frame."""
    st = field(la, "rxst")
    m, code = rx_feed(field(la, "tb"), st, t_ns, can_id, is_ext, dlc, w_le)
    accepted = code >= 0 and st[0][m, S_ACCEPTED] != 0
    if accepted:
        field(la, "used_since")[0] += 1
    grid_frame(g, t_ns, m >= 0, m == anchor and accepted)


@njit(cache=True, **NO_REFCOUNT)
def sample_inputs(la, tk, vin, age):  # pragma: no cover - compiled
    """The inputs at step time ``tk`` [ns] into ``vin`` (SI) and ``age`` [ns]
    (:func:`lde.engine.receiver.rx_sample`). Returns (valid mask, fresh mask: the inputs that brought a new
    sample since the previous step at ``prev_t[0]``, which becomes ``tk``; mdps ok, esc ok).
    ``la``: the loop's :class:`lde.engine.loopargs.LoopArrays` (as :func:`feed_frame`)."""
    prev_t = field(la, "prev_t")
    mask, ok_m, ok_e = rx_sample(field(la, "tb"), field(la, "rxst"), tk, vin, age)
    fresh = 0
    for q in range(vin.shape[0]):
        if age[q] >= 0 and tk - age[q] > prev_t[0]:
            fresh |= 1 << q
    prev_t[0] = tk
    return mask, np.int64(fresh), bool(ok_m), bool(ok_e)


@njit(cache=True, **NO_REFCOUNT)
def step_outputs(la, tk, est, status, enable, vin, encode, frames_row, vals, scratch):  # pragma: no cover
    """After the backend step at ``tk`` [ns] (``est``: its ``O_*`` slots, ``status`` its bits): the
    overlay law and limiter, the finalisation, the output values ``vals`` (``V_*``) and, when
    ``encode``, the output frames into ``frames_row`` (one row per output message). Returns
    (torque [Nm], status, limiter state). ``la``: the loop's :class:`lde.engine.loopargs.LoopArrays`
    (the limiter's parameters and state, the output table and counters; as :func:`feed_frame`)."""
    lp, lsi, lsf = field(la, "lp"), field(la, "lsi"), field(la, "lsf")
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
        _encode_outputs(field(la, "otab"), vals, field(la, "counters"), frames_row, scratch)
    return torque, status, state


#: the backend's compiled step inside a specialised loop (:func:`make_loop` binds it)
STEP: Any = None


def _run_loop(
    bp,
    bs,
    la,
    g,
    explicit,
    ex_enable,
    ex_extra,
    encode,
    final,
    t_end,
    have_end,
    i0,
    t,
    can_id,
    is_ext,
    dlc,
    words,
    is_rx,
    anchor,
    o_t,
    o_status,
    o_est,
    o_tov,
    o_ovst,
    o_enable,
    o_in,
    o_age,
    o_mask,
    o_ok,
    o_used,
    o_rej,
    o_frames,
):  # pragma: no cover - compiled
    """Interleave frames and due steps (module docstring) from frame ``i0`` on. ``final``: no frame
    follows these; once they are fed the grid finishes (:func:`lde.engine.grid.grid_finish` with ``t_end``
    when ``have_end``) and the remaining steps run.

    Returns (next frame index, rows written). Stops when the rows are full, when the grid has no
    due step and no frame is left (a later call continues), with explicit step times when none is
    left (the frames after it stay unfed), or when the grid overflows (``g[G_OVERFLOW]``). Frames with
    ``is_rx`` False (lde's own, in a recording) are skipped.

    ``la``: the fixed arrays (receiver tables and state, the previous step time, the limiter's
    parameters and state, the output table and counters) as one :class:`lde.engine.loopargs.LoopArrays`:
    one argument to unbox per call instead of 51.
    """
    tb, otab, st = la.tb, la.otab, la.rxst
    used_since = la.used_since
    e2e = st[0]
    malformed = st[1]
    nf = t.shape[0]
    cap = o_t.shape[0]
    vals = np.zeros(N_V)
    scratch = np.empty(otab[9].shape[0])
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
            enable = True
            extra = 0
            if g[G_MODE] == MODE_EXPLICIT:
                j = g[G_K]
                if ex_enable.shape[0] > j:
                    enable = ex_enable[j]
                if ex_extra.shape[0] > j:
                    extra = ex_extra[j]
            vin = o_in[n]
            est = o_est[n]
            mask, fresh, ok_m, ok_e = sample_inputs(la, tk, vin, o_age[n])
            status = STEP(bp, bs, tk, vin, fresh, ok_m, ok_e, est)
            status |= extra
            # np.int64 / bool: numba types a call while the loop's types are still partial (the
            # literal 0 or True of their first assignment) and would compile the callee once more
            torque, status, state = step_outputs(
                la, tk, est, np.int64(status), bool(enable), vin, encode, o_frames[n], vals, scratch
            )
            o_t[n] = tk
            o_status[n] = status
            o_tov[n] = torque
            o_ovst[n] = state
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
            feed_frame(la, g, t[i], np.int64(can_id[i]), is_ext[i], np.int64(dlc[i]), words[i], anchor)
        else:  # an id the profile ignores: rx_feed's count and the grid's hook, without the call
            rx_count_ignored(st)
            grid_frame(g, t[i], False, False)
        i += 1
    return i, n


def make_loop(step: Any, name: str) -> Any:
    """The compiled loop (:func:`_run_loop`) with ``step`` bound as its backend step, under its own
    name (its own on-disk cache entry). It releases the GIL: a batch runs a shadow engine beside it."""
    code = _run_loop.__code__.replace(co_name=name)
    code = code.replace(co_qualname=name)  # numba caches by qualified name
    bound = dict(_run_loop.__globals__, STEP=step)
    fn = types.FunctionType(code, bound, name, _run_loop.__defaults__)
    fn.__module__ = _run_loop.__module__
    fn.__qualname__ = name
    fn.__doc__ = _run_loop.__doc__
    return njit(cache=True, nogil=True)(fn)
