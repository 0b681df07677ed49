"""The live step's work after its outputs are sent, in one compiled call (:func:`after_send`).

Once a step's ``LDE_Estimate``, ``LDE_Overlay`` and ``LDE_Disturbance`` are on the bus, the service
(:meth:`lde.service.service.Service.step_once`) has three things left that touch only memory: the step's
timing into the statistics ring (:class:`lde.service.diagnostics.TimingStats`), ``LDE_Diag`` (values,
saturation, encoding, E2E counter and CRC) into its prebuilt frame, and the recorder's records: the
step's frames (the input frames taken before it, in the order they were taken, then the sent
frames and ``LDE_Diag``) as :func:`lde.io.recording.frame_record` rows, and the step's row with its
timing as one :func:`lde.io.recording.step_record`. One compiled call instead of about 30 numpy
stores and calls from Python; the service then hands the two record buffers to the recorder
(:meth:`lde.io.recording.Recorder.put`: one write to a pipe each), leaving out ``LDE_Diag``'s record
when the bus did not take the frame (its send comes after this call).

``ints`` (int64) carries the scalars in (``I_T_K`` .. ``I_N_SENT``, ``I_N_RX``) and out
(``I_PERIOD`` ..).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from lde.can.codec import encode_word
from lde.can.e2e import advance_counter
from lde.service.diagnostics import DEADLINE_MISS_NS

__all__ = ["after_send", "N_INTS", "N_STATS"]

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
I_N_FRAMES = 11  # frame records written into ``frame_out`` (LDE_Diag's included, the last)
I_N_RX = 14  # in: received frames in ``rx`` / ``rx_word`` to record before the sent ones; out: 0
N_INTS = 15

#: ``stats_ctr`` (int64): steps recorded, deadline misses (late steps + skipped), skipped grid points
N_STATS = 3

# a frame record's byte offsets (lde.io.recording.frame_record): time, id, dlc, flags, data
_R_T, _R_ID, _R_DLC, _R_FLAGS, _R_DATA = 0, 8, 12, 13, 16
_RX_FLAG = 1  # flags bit 0: a received frame (0: sent)
#: the step record's timing: its last 6 int64 (lde.io.recording.step_record)
_TIMING_BYTES = 48

# LDE_Diag's ranges (dbc/lde.dbc, lde.service.diagnostics.diag_values): saturate, counter modulo 256
_PE_LO, _PE_HI, _ST_HI, _LAT_HI, _REJ_HI = -8192.0, 8191.0, 4095.0, 8191.0, 31


@njit(cache=True, inline="always")
def _sat(x, lo, hi):  # pragma: no cover - compiled
    return min(max(np.rint(x), lo), hi)


@njit(cache=True, inline="always")
def _put_frame(out, i, t_ns, can_id, dlc, word, flags):  # pragma: no cover - compiled
    """Frame record ``i`` of ``out`` (uint8 rows): an 11-bit frame, its first 8 data bytes ``word``
    (little-endian); the rest of a wider record's data stays zero."""
    r = out[i]
    r[_R_T : _R_T + 8].view(np.int64)[0] = t_ns
    r[_R_ID : _R_ID + 4].view(np.uint32)[0] = can_id
    r[_R_DLC] = dlc
    r[_R_FLAGS] = flags
    r[_R_DATA : _R_DATA + 8].view(np.uint64)[0] = word


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
    rx,
    rx_word,
    rec_tab,
    frame_out,
    step_out,
):  # pragma: no cover - compiled
    """The step's timing, ``LDE_Diag`` and the recorder's records (module docstring).

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
        rx: int64 (capacity, 3): the input frames received since the previous call, in the order
            they were taken (receive time [ns], 11-bit id, dlc); ``ints[I_N_RX]`` rows of it.
        rx_word: uint64 (capacity): their first 8 data bytes, little-endian.
        rec_tab: int64 (k, 3): per StepBlock column its offset in ``block_mem``, its offset in the
            step record and its bytes per row.
        frame_out: uint8 (capacity + n_out + 1, record size): the frame records (written; no rows:
            no recorder).
        step_out: uint8 (step record size): the step record (written), its timing the last 48 bytes.
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

    n_rx = ints[I_N_RX]
    ints[I_N_RX] = 0
    ints[I_N_FRAMES] = 0
    if frame_out.shape[0] == 0:
        return
    n = 0
    for r in range(n_rx):  # the received frames first, as they were taken
        _put_frame(frame_out, n, rx[r, 0], rx[r, 1], rx[r, 2], rx_word[r], _RX_FLAG)
        n += 1
    n_out = ints[I_N_SENT]
    for j in range(n_out):
        if tx_t[j] < 0:
            continue
        word = np.uint64(0)
        for b in range(8):
            word |= np.uint64(frames[0, j, b]) << np.uint64(8 * b)
        _put_frame(frame_out, n, tx_t[j], tx_meta[j, 0], tx_meta[j, 1], word, 0)
        n += 1
    _put_frame(frame_out, n, tx_t[n_out], tx_meta[n_out, 0], tx_meta[n_out, 1], w, 0)  # LDE_Diag
    ints[I_N_FRAMES] = n + 1

    for r in range(rec_tab.shape[0]):
        src, dst, nb = rec_tab[r, 0], rec_tab[r, 1], rec_tab[r, 2]
        step_out[dst : dst + nb] = block_mem[src : src + nb]
    at = step_out.shape[0] - _TIMING_BYTES
    tm = step_out[at:].view(np.int64)
    tm[0] = period
    tm[1] = step
    tm[2] = lat
    tm[3] = miss
    tm[4] = misses
    tm[5] = stats_ctr[2]
