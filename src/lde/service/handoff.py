"""The live step's work after its outputs are sent, in one compiled call (:func:`after_send`).

Once a step's ``LDE_Estimate``, ``LDE_Overlay`` and ``LDE_Disturbance`` are on the bus, the service
(:meth:`lde.service.service.Service.step_once`) has three things left that touch only memory: the step's
timing into the statistics ring (:class:`lde.service.diagnostics.TimingStats`), ``LDE_Diag`` (values,
saturation, encoding, E2E counter and CRC) into its prebuilt frame, and the recorder's hand-off (the
sent frames and the step's row into the shared-memory rings of :class:`lde.io.recording.StepRing`).
Done in Python they were about 30 small numpy stores and calls (29-41 us per step live, on cold
caches); here they are one call of 5-9 us, so a live step
crosses from Python into compiled code twice (the engine's loop, then this) instead of once per
store.

The received input frames of the step (taken by the service before it, handed over as columns) go
into the frame ring first, in the order they were taken, then the sent frames.

The rings' heads are not advanced here: the call returns them and the caller publishes them after it
returns (a function boundary: every store of the rows is done before a head that makes them visible
to the writer process; x86 keeps stores in program order). The ``LDE_Diag`` frame's ring slot is
written but published only once the bus has taken the frame (its send comes after this call).

``ints`` (int64) carries the scalars in (``I_T_K`` .. ``I_N_SENT``) and out (``I_PERIOD`` ..).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from lde.can.codec import encode_word
from lde.can.e2e import advance_counter
from lde.service.diagnostics import DEADLINE_MISS_NS

__all__ = ["after_send", "N_INTS", "RING_LAY", "N_STATS"]

# in
I_T_K = 0  # step time t_k [ns, bus time base]
I_T_START = 1  # the step's start [ns, bus time base]
I_T_SENT = 2  # the outputs' send [ns, bus time base]
I_NEWEST = 3  # receive time of the newest input frame fed so far [ns]; -1: none yet
I_DIAG_CTR = 5  # LDE_Diag's E2E counter for this frame (advanced in place)
I_N_SENT = 6  # output frames in ``tx_t`` (sent or not), before LDE_Diag
# out
I_PERIOD = 7  # period error [ns]
I_STEP = 8  # step time [ns]
I_LATENCY = 9  # latency [ns], -1 without an input frame
I_MISS = 10  # this step started more than 1 ms late (0/1)
I_F_HEAD = 11  # the frame ring's head after the sent outputs (LDE_Diag not included)
I_S_HEAD = 12  # the step ring's head after this step's row
I_DIAG_SLOT = 13  # 1: LDE_Diag's frame is in the frame ring's slot at I_F_HEAD (publish after its send)
I_N_RX = 14  # in: received frames in ``rx`` / ``rx_word`` to record before the sent ones; out: 0
N_INTS = 15

#: ``stats_ctr`` (int64): steps recorded, deadline misses (late steps + skipped), skipped grid points
N_STATS = 3

#: ``ring_lay`` (int64): byte offsets in the ring memory of the control slots and the frame and timing
#: columns, then the capacities (:meth:`lde.io.recording.StepRing.kernel_layout`)
RING_LAY = ("ctl", "f_t", "f_word", "f_id", "f_ext", "f_dlc", "f_rx", "timing", "nf", "ns")
_CTL, _FT, _FW, _FID, _FEXT, _FDLC, _FRX, _TIMING, _NF, _NS = range(len(RING_LAY))
# the ring's control slots (lde.io.recording): heads written by the service, tails by the writer
_F_HEAD, _F_TAIL, _S_HEAD, _S_TAIL, _F_DROPPED, _S_DROPPED = range(6)

# LDE_Diag's ranges (dbc/lde.dbc, lde.service.diagnostics.diag_values): saturate, counter modulo 256
_PE_LO, _PE_HI, _ST_HI, _LAT_HI, _REJ_HI = -8192.0, 8191.0, 4095.0, 8191.0, 31


@njit(cache=True, inline="always")
def _sat(x, lo, hi):  # pragma: no cover - compiled
    return min(max(np.rint(x), lo), hi)


@njit(cache=True, inline="always")
def _put_frame(mem, lay, ctl, h, t_ns, can_id, dlc, word, is_rx=0):  # pragma: no cover - compiled
    """One frame (sent, or received: ``is_rx`` 1; 11-bit id) into the frame ring's slot of head ``h``
    (the caller checked for room)."""
    i = h & (lay[_NF] - 1)
    mem[lay[_FT] + 8 * i : lay[_FT] + 8 * i + 8].view(np.int64)[0] = t_ns
    mem[lay[_FW] + 8 * i : lay[_FW] + 8 * i + 8].view(np.uint64)[0] = word
    mem[lay[_FID] + 4 * i : lay[_FID] + 4 * i + 4].view(np.uint32)[0] = can_id
    mem[lay[_FEXT] + i] = 0
    mem[lay[_FDLC] + i] = dlc
    mem[lay[_FRX] + i] = is_rx


@njit(cache=True)
def after_send(
    ints,
    stats,
    stats_ctr,
    diag_vals,
    diag_int,
    diag_flt,
    ctr_parts,
    chk_parts,
    diag_meta,
    diag_out,
    frames,
    tx_meta,
    tx_t,
    block_mem,
    ring_mem,
    ring_tab,
    ring_lay,
    rx,
    rx_word,
):  # pragma: no cover - compiled
    """The step's timing, ``LDE_Diag`` and the recorder hand-off (module docstring).

    Args:
        ints: int64 scalars in and out (``I_*``).
        stats: int64 (3, capacity): period error, step time, latency [ns] (the statistics ring).
        stats_ctr: int64 (``N_STATS``): steps, deadline misses, skipped grid points (updated).
        diag_vals: float64, one physical value per ``LDE_Diag`` signal (work array).
        diag_int: int64 (5, n): the layout's shift, nbits, little-endian, signed, is_value rows.
        diag_flt: float64 (4, n): scale, offset, lo, hi.
        ctr_parts, chk_parts: the E2E scheme's counter and checksum fields.
        diag_meta: int64: length, scheme kind, frame id, counter modulus, invalid counter, then the
            value slots of PeriodError, StepTime, Latency, DeadlineMisses, E2ERejects, then the byte
            offset of the step's E2E rejection count (``StepBlock.e2e_rejects``) in ``block_mem``.
        diag_out: uint8, LDE_Diag's data bytes in its prebuilt frame (written).
        frames: uint8 (1, n_out, 8): the step's encoded output frames (the live StepBlock's).
        tx_meta: int64 (n_out + 1, 2): id and length of the outputs, then of LDE_Diag.
        tx_t: int64 (n_out + 1): the send time of each output [ns, bus time base], -1: the bus did
            not take it (not recorded); the last entry: LDE_Diag's stamp.
        block_mem: uint8, the memory the live StepBlock's columns are views of.
        ring_mem: uint8, the recorder's rings (empty: no recorder).
        ring_tab: int64 (k, 3): per step-row column its offset in ``block_mem``, its offset in
            ``ring_mem`` and its bytes per row.
        ring_lay: int64 (``RING_LAY``).
        rx: int64 (capacity, 3): the input frames received since the previous call, in the order
            they were taken (receive time [ns], 11-bit id, dlc); ``ints[I_N_RX]`` rows of it.
        rx_word: uint64 (capacity): their first 8 data bytes, little-endian.
    """
    t_start = ints[I_T_START]
    t_sent = ints[I_T_SENT]
    period = t_start - ints[I_T_K]
    step = t_sent - t_start
    newest = ints[I_NEWEST]
    lat = t_sent - newest if newest >= 0 else -1
    miss = 1 if period > DEADLINE_MISS_NS else 0
    cap = stats.shape[1]
    k = stats_ctr[0] % cap
    stats[0, k] = period
    stats[1, k] = step
    stats[2, k] = lat
    stats_ctr[0] += 1
    stats_ctr[1] += miss
    misses = stats_ctr[1]
    ints[I_PERIOD] = period
    ints[I_STEP] = step
    ints[I_LATENCY] = lat
    ints[I_MISS] = miss

    # LDE_Diag (lde.service.diagnostics.diag_values: saturated at the DBC ranges, rounding half to even)
    m = diag_meta
    diag_vals[m[5]] = _sat(period / 1e3, _PE_LO, _PE_HI)
    diag_vals[m[6]] = _sat(step / 1e3, 0.0, _ST_HI)
    diag_vals[m[7]] = _sat(lat / 1e3 if lat >= 0 else 0.0, 0.0, _LAT_HI)
    diag_vals[m[8]] = misses % 256
    rejects = block_mem[m[10] : m[10] + 8].view(np.int64)[0]
    diag_vals[m[9]] = min(max(rejects, 0), _REJ_HI)
    ctr = ints[I_DIAG_CTR]
    w = encode_word(
        diag_vals,
        diag_int[0],
        diag_int[1],
        diag_int[2],
        diag_int[3],
        diag_flt[0],
        diag_flt[1],
        diag_flt[2],
        diag_flt[3],
        diag_int[4],
        m[0],
        m[1],
        m[2],
        ctr_parts,
        chk_parts,
        ctr,
    )
    ints[I_DIAG_CTR] = advance_counter(ctr, m[3], m[4])
    for b in range(diag_out.shape[0]):
        diag_out[b] = np.uint8((w >> np.uint64(8 * b)) & np.uint64(0xFF))

    ints[I_DIAG_SLOT] = 0
    n_rx = ints[I_N_RX]
    ints[I_N_RX] = 0
    if ring_mem.shape[0] == 0:
        return
    lay = ring_lay
    ctl = ring_mem[lay[_CTL] : lay[_CTL] + 64].view(np.int64)
    nf = lay[_NF]
    fh = ctl[_F_HEAD]
    for r in range(n_rx):  # the received frames first, as they were taken
        if fh - ctl[_F_TAIL] >= nf:
            ctl[_F_DROPPED] += 1
            continue
        _put_frame(ring_mem, lay, ctl, fh, rx[r, 0], rx[r, 1], rx[r, 2], rx_word[r], 1)
        fh += 1
    n_out = ints[I_N_SENT]
    for j in range(n_out + 1):
        if j < n_out and tx_t[j] < 0:
            continue
        if fh - ctl[_F_TAIL] >= nf:
            if j < n_out:
                ctl[_F_DROPPED] += 1
            continue
        if j < n_out:
            word = np.uint64(0)
            for b in range(8):
                word |= np.uint64(frames[0, j, b]) << np.uint64(8 * b)
            _put_frame(ring_mem, lay, ctl, fh, tx_t[j], tx_meta[j, 0], tx_meta[j, 1], word)
            fh += 1
        else:  # LDE_Diag: its slot now, published by the caller once the bus took it
            _put_frame(ring_mem, lay, ctl, fh, tx_t[j], tx_meta[j, 0], tx_meta[j, 1], w)
            ints[I_DIAG_SLOT] = 1
    ints[I_F_HEAD] = fh

    ns = lay[_NS]
    sh = ctl[_S_HEAD]
    if sh - ctl[_S_TAIL] >= ns:
        ctl[_S_DROPPED] += 1
        ints[I_S_HEAD] = sh
        return
    i = sh & (ns - 1)
    for r in range(ring_tab.shape[0]):
        src, dst, nb = ring_tab[r, 0], ring_tab[r, 1] + ring_tab[r, 2] * i, ring_tab[r, 2]
        ring_mem[dst : dst + nb] = block_mem[src : src + nb]
    tm = ring_mem[lay[_TIMING] + 48 * i : lay[_TIMING] + 48 * i + 48].view(np.int64)
    tm[0] = period
    tm[1] = step
    tm[2] = lat
    tm[3] = miss
    tm[4] = misses
    tm[5] = stats_ctr[2]
    ints[I_S_HEAD] = sh + 1
