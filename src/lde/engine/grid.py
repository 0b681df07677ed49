"""The estimator's step times and the order of frames and steps: one compiled state machine.

A step at ``t_k`` uses exactly the frames with time ``<= t_k`` (SPEC section 3). Every path (the live
service, replay, :func:`build_grid`) feeds frames in time order and asks the grid, before each frame,
which steps are due (:func:`grid_due`); a due step runs before that frame is fed, a step at the same
time as a frame runs after it.

Step times come from one of two sources:

* **explicit** (``MODE_EXPLICIT``): given times, non-decreasing: the live service's clock (one per
  call), a recording's recorded step times, or a fixed grid (``t_start_ns``);
* **anchored** (``MODE_ANCHORED``): the default for a log::

      t_k = t_anchor + k * STEP_NS,   t_anchor = the first accepted frame of the anchor (MDPS) message

  A silence longer than :data:`MAX_GAP_NS` (60 s) without any frame of an input message splits the
  grid into segments, each anchored again at its own first accepted anchor frame and ending at its
  last input frame (the last segment at the end of the log if that is within :data:`MAX_GAP_NS`
  of its last input frame). Shorter gaps are stepped through (the inputs go stale, then recover).
  A log that joins recordings from different time bases thus replays each part.

* **MDPS-locked** (the live service's default, :func:`new_lock`): every step runs right after the
  MDPS frame it consumes. A step is triggered by each anchor-message frame that comes more than half
  a period after the previous step's reference time ``t_ref`` and at most 1.5 periods after it: the step
  time is that frame's receive time and it becomes the new ``t_ref``. When no such frame has come
  by ``t_ref + 1.5 P`` (a lost or late frame, no sender yet), a step runs at that time and ``t_ref``
  advances by exactly one period (the phase is kept: the next frame of a sender on its own period
  triggers again). One step per window ``(t_ref + P/2, t_ref + 3P/2]``: the grid follows the sender's
  clock and its phase, and its steps are P/2 to 3P/2 apart. The rule is a function of the anchor
  frames' times alone, so :func:`locked_step_times` gives a log's step times offline, the ones the
  live loop took (``docs/service.md``).

Streaming: the grid never needs frames it has not seen. A step beyond the last input frame waits
until the next input frame shows whether the segment goes on (gap <= 60 s) or ends, or until the end
of the log (:func:`grid_finish`). More than :data:`MAX_STEPS` steps in all is an error
(``G_OVERFLOW``; :class:`lde.errors.LogFormatError` at the Python boundary).
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np
from numba import njit

from lde.can.e2e import S_ACCEPTED
from lde.can.frames import FrameBatch
from lde.can.profiles import INPUT_NAMES, Profile
from lde.engine.receiver import (
    N_INPUTS,
    Decoded,
    InputSample,
    RxState,
    RxTables,
    rx_feed,
    rx_msg_of,
    rx_sample,
)
from lde.errors import LogFormatError
from lde.units import STEP_NS

__all__ = [
    "InputGrid",
    "build_grid",
    "step_times",
    "segmented_step_times",
    "latest_at_or_before",
    "new_grid",
    "grid_due",
    "grid_step_done",
    "grid_frame",
    "grid_finish",
    "overflow_error",
    "MAX_GAP_NS",
    "MAX_STEPS",
    "MODE_EXPLICIT",
    "MODE_ANCHORED",
    "new_lock",
    "lock_anchor",
    "lock_timeout",
    "lock_frame",
    "lock_deadline",
    "locked_step_times",
    "L_REF",
    "L_PERIOD",
    "L_TRIGGERED",
    "L_TIMEOUTS",
]

#: a silence of the input messages longer than this starts a new grid segment [ns]
MAX_GAP_NS = 60_000_000_000
#: at most this many steps in one run (about 108 h at 3.9 ms; guards against corrupt timestamps)
MAX_STEPS = 100_000_000

MODE_EXPLICIT, MODE_ANCHORED = 0, 1
_WAIT_ANCHOR, _RUNNING = 0, 1

# grid state slots (int64)
G_MODE = 0  # MODE_*
G_PHASE = 1  # _WAIT_ANCHOR / _RUNNING (anchored)
G_ANCHOR = 2  # t of the current segment's anchor frame [ns]
G_K = 3  # next step index in the segment (anchored) / next explicit time's index (explicit)
G_HAVE_INPUT = 4  # 1 once an input frame was seen
G_LAST_INPUT = 5  # time of the latest input-message frame [ns]
G_HAVE_RX = 6  # 1 once any frame was fed
G_LAST_RX = 7  # time of the latest frame fed [ns]
G_FINISH = 8  # 1: the log has ended (no more frames)
G_END = 9  # finishing: the last possible step time [ns]
G_NSTEPS = 10  # steps run so far
G_MAX_STEPS = 11
G_PERIOD = 12  # [ns]
G_MAX_GAP = 13  # [ns]
G_SEGMENTS = 14  # segments started (anchored)
G_OVERFLOW = 15  # 1: more than G_MAX_STEPS steps were asked for
N_G = 16


def new_grid(
    mode: int, period_ns: int = STEP_NS, max_gap_ns: int = MAX_GAP_NS, max_steps: int = MAX_STEPS
) -> np.ndarray:
    """A fresh grid state (int64 ``G_*`` slots)."""
    g = np.zeros(N_G, np.int64)
    g[G_MODE] = mode
    g[G_PHASE] = _WAIT_ANCHOR
    g[G_MAX_STEPS] = max_steps
    g[G_PERIOD] = period_ns
    g[G_MAX_GAP] = max_gap_ns
    return g


@njit(cache=True, inline="always")
def grid_due(g, explicit, have_next, t_next, next_is_input):  # pragma: no cover - compiled
    """Is a step due before the next frame (time ``t_next``; ``have_next`` False: no frame is
    available now)? Returns (due, t_k). Sets ``G_OVERFLOW`` instead when the step budget is spent."""
    if g[G_NSTEPS] >= g[G_MAX_STEPS]:
        g[G_OVERFLOW] = 1
        return False, np.int64(0)
    if g[G_MODE] == MODE_EXPLICIT:
        j = g[G_K]
        if j >= explicit.shape[0]:
            return False, np.int64(0)
        tk = explicit[j]
        if not have_next:
            return g[G_FINISH] == 1, tk
        return tk < t_next, tk
    if g[G_PHASE] != _RUNNING:
        return False, np.int64(0)
    tk = g[G_ANCHOR] + g[G_K] * g[G_PERIOD]
    if not have_next:
        return g[G_FINISH] == 1 and tk <= g[G_END], tk
    if next_is_input:
        if t_next - g[G_LAST_INPUT] > g[G_MAX_GAP]:
            return tk <= g[G_LAST_INPUT], tk  # the segment ends at its last input frame
        return tk < t_next, tk
    return tk < t_next and tk <= g[G_LAST_INPUT], tk


@njit(cache=True, inline="always")
def grid_step_done(g):  # pragma: no cover - compiled
    """The due step has run."""
    g[G_K] += 1
    g[G_NSTEPS] += 1


@njit(cache=True, inline="always")
def grid_frame(g, t_ns, is_input, accepted_anchor):  # pragma: no cover - compiled
    """A frame at ``t_ns`` was fed (``is_input``: an input message's id, any status;
    ``accepted_anchor``: an anchor-message frame whose values were accepted)."""
    if g[G_MODE] == MODE_ANCHORED and is_input:
        if g[G_HAVE_INPUT] == 1 and t_ns - g[G_LAST_INPUT] > g[G_MAX_GAP]:
            g[G_PHASE] = _WAIT_ANCHOR  # a silence: the segment has ended
        if accepted_anchor and g[G_PHASE] == _WAIT_ANCHOR:
            g[G_PHASE] = _RUNNING
            g[G_ANCHOR] = t_ns
            g[G_K] = 0
            g[G_SEGMENTS] += 1
    if is_input:
        g[G_HAVE_INPUT] = 1
        g[G_LAST_INPUT] = t_ns
    g[G_HAVE_RX] = 1
    g[G_LAST_RX] = t_ns


@njit(cache=True, inline="always")
def grid_finish(g, t_end, have_end):  # pragma: no cover - compiled
    """The log has ended; the remaining steps run up to ``t_end`` (default: the last frame fed;
    the last segment ends at its last input frame when the end is further than the gap limit)."""
    g[G_FINISH] = 1
    end = t_end if have_end else g[G_LAST_RX]
    if g[G_HAVE_INPUT] == 1 and end - g[G_LAST_INPUT] > g[G_MAX_GAP]:
        end = g[G_LAST_INPUT]
    g[G_END] = end


# ------------------------------------------------------------------------------ the MDPS-locked grid

# lock state slots (int64)
L_PERIOD = 0  # P [ns]
L_REF = 1  # t_ref: the last step's trigger frame time, or the nominal time after a timeout [ns]
L_TRIGGERED = 2  # steps triggered by an anchor frame
L_TIMEOUTS = 3  # steps run at a window's end (no anchor frame in it)
N_L = 4


def new_lock(t_first_ns: int, period_ns: int = STEP_NS) -> np.ndarray:
    """A fresh MDPS-locked grid whose first window is ``(t_first - P/2, t_first + P/2]`` (``t_first``:
    the nominal time of the first step, the service's start)."""
    s = np.zeros(N_L, np.int64)
    s[L_PERIOD] = period_ns
    s[L_REF] = int(t_first_ns) - int(period_ns)
    return s


@njit(cache=True)
def lock_deadline(s):  # pragma: no cover - compiled
    """The end of the current window: the time of the timeout step if no anchor frame comes [ns]."""
    return s[L_REF] + s[L_PERIOD] + s[L_PERIOD] // 2


@njit(cache=True)
def lock_anchor(s, t_ns):  # pragma: no cover - compiled
    """An anchor-message frame received at ``t_ns`` (after every timeout step before ``t_ns`` was
    taken: :func:`lock_timeout`). Returns True when it triggers a step at ``t_ns``."""
    p = s[L_PERIOD]
    if t_ns > s[L_REF] + p // 2 and t_ns <= s[L_REF] + p + p // 2:
        s[L_REF] = t_ns
        s[L_TRIGGERED] += 1
        return True
    return False


@njit(cache=True)
def lock_timeout(s, t_ns):  # pragma: no cover - compiled
    """No anchor frame has come before ``t_ns`` (exclusive): the timeout step, if the window ended
    before ``t_ns``. Returns its time, or -1 (none due)."""
    end = lock_deadline(s)
    if end < t_ns:
        s[L_REF] += s[L_PERIOD]
        s[L_TIMEOUTS] += 1
        return end
    return np.int64(-1)


@njit(cache=True)
def lock_frame(s, t_ns):  # pragma: no cover - compiled
    """:func:`lock_timeout` then :func:`lock_anchor` for an anchor frame at ``t_ns``, in one call when
    no timeout step is due before it (the live service's common case): returns 1 when the frame
    triggers a step at ``t_ns``, 0 when it does not, and -1 (the state unchanged) when a window
    ended before ``t_ns``: the caller takes the timeout steps first (:func:`lock_timeout`)."""
    if lock_deadline(s) < t_ns:
        return np.int64(-1)
    return np.int64(1) if lock_anchor(s, t_ns) else np.int64(0)


@njit(cache=True)
def _locked_steps(s, anchor_t, t_end, out):  # pragma: no cover - compiled
    n = 0
    cap = out.shape[0]
    for i in range(anchor_t.shape[0]):
        t = anchor_t[i]
        if t > t_end:
            break
        while True:
            tk = lock_timeout(s, t)
            if tk < 0:
                break
            if n < cap:
                out[n] = tk
            n += 1
        if lock_anchor(s, t):
            if n < cap:
                out[n] = t
            n += 1
    while True:
        tk = lock_timeout(s, t_end + 1)
        if tk < 0:
            break
        if n < cap:
            out[n] = tk
        n += 1
    return n


def locked_step_times(
    anchor_t_ns: np.ndarray, t_first_ns: int, t_end_ns: int, period_ns: int = STEP_NS
) -> np.ndarray:
    """The MDPS-locked grid's step times (:func:`new_lock`, module docstring) for the receive times
    of the anchor-message frames (sorted, any E2E status), from the first window around
    ``t_first_ns`` to ``t_end_ns`` inclusive: what the live loop stepped on, for a replay of the
    bare frames."""
    a = np.ascontiguousarray(anchor_t_ns, dtype=np.int64)
    if a.size > 1 and bool(np.any(np.diff(a) < 0)):
        raise ValueError("anchor frame times must be sorted")
    n_max = (int(t_end_ns) - int(t_first_ns)) // (period_ns // 2) + 2
    if n_max > MAX_STEPS:
        raise overflow_error(MAX_STEPS, period_ns)
    out = np.empty(max(n_max, 0), np.int64)
    n = _locked_steps(new_lock(t_first_ns, period_ns), a, np.int64(t_end_ns), out)
    return out[: min(n, out.shape[0])]


def overflow_error(max_steps: int = MAX_STEPS, step_ns: int = STEP_NS) -> LogFormatError:
    """The error for a grid beyond its step budget."""
    return LogFormatError(
        f"the log's input frames would need more than {max_steps} estimator steps "
        f"({max_steps * step_ns * 1e-9 / 3600:.0f} h at {step_ns * 1e-6:g} ms): corrupt timestamps?"
    )


# ------------------------------------------------------------------------------ inputs on the grid


@dataclass
class InputGrid:
    """Estimator inputs on the step grid (SI, ISO 8855 signs; one row per step).

    Value arrays hold the latest accepted value (held when stale, NaN before the first sample);
    ``valid[name]`` says fresh; ``age_ns[name]`` is the sample's age (-1 before the first).
    """

    t_ns: np.ndarray  # int64 [n]
    column_torque: np.ndarray  # Nm
    assist_torque: np.ndarray  # Nm
    steering_angle: np.ndarray  # rad
    steering_rate: np.ndarray  # rad/s
    yaw_rate: np.ndarray  # rad/s
    lat_accel: np.ndarray  # m/s^2
    speed: np.ndarray  # m/s
    valid: dict[str, np.ndarray]  # bool [n] per input
    age_ns: dict[str, np.ndarray]  # int64 [n] per input
    mdps_ok: np.ndarray  # bool [n]
    esc_ok: np.ndarray  # bool [n]

    def __len__(self) -> int:
        return int(self.t_ns.shape[0])

    def values(self, name: str) -> np.ndarray:
        return getattr(self, name)

    @classmethod
    def from_columns(
        cls, t_ns: np.ndarray, values: np.ndarray, ages: np.ndarray, valid_mask: np.ndarray, ok: np.ndarray
    ) -> InputGrid:
        """From the kernels' columns: values (n, N_INPUTS), ages (n, N_INPUTS), the valid bit mask
        (n,) and ok (n, 2) = (mdps_ok, esc_ok)."""
        return cls(
            t_ns=t_ns,
            **{n: values[:, i] for i, n in enumerate(INPUT_NAMES)},
            valid={n: (valid_mask >> i & 1).astype(np.bool_) for i, n in enumerate(INPUT_NAMES)},
            age_ns={n: ages[:, i] for i, n in enumerate(INPUT_NAMES)},
            mdps_ok=ok[:, 0].astype(np.bool_),
            esc_ok=ok[:, 1].astype(np.bool_),
        )

    def row(self, i: int) -> InputSample:
        """Step ``i`` as the live receiver's :class:`InputSample` (for lockstep checks)."""
        return InputSample(
            t_ns=int(self.t_ns[i]),
            **{n: float(self.values(n)[i]) for n in INPUT_NAMES},
            valid={n: bool(self.valid[n][i]) for n in INPUT_NAMES},
            age_ns={n: int(self.age_ns[n][i]) for n in INPUT_NAMES},
            mdps_ok=bool(self.mdps_ok[i]),
            esc_ok=bool(self.esc_ok[i]),
        )


@njit(cache=True)
def _inputs_kernel(
    tb,
    st,
    g,
    explicit,
    final,
    t_end,
    have_end,
    i0,
    t,
    can_id,
    is_ext,
    dlc,
    data,
    anchor,
    out_t,
    out_v,
    out_age,
    out_mask,
    out_ok,
):  # pragma: no cover
    """Feed the frames from ``i0`` on and sample at every due step (the grid's rule). Returns
    (next frame index, steps written); stops early when the output is full or the grid overflows."""
    e2e = st[0]
    nf = t.shape[0]
    cap = out_t.shape[0]
    i = i0
    n = 0
    while n < cap:
        have = i < nf
        if not have and final and g[G_FINISH] == 0:
            grid_finish(g, t_end, have_end)
        t_next = t[i] if have else np.int64(0)
        is_input = have and rx_msg_of(tb, np.int64(can_id[i]), is_ext[i]) >= 0
        due, tk = grid_due(g, explicit, have, t_next, is_input)
        if g[G_OVERFLOW] == 1:
            break
        if due:
            mask, ok_m, ok_e = rx_sample(tb, st, tk, out_v[n], out_age[n])
            out_t[n] = tk
            out_mask[n] = mask
            out_ok[n, 0] = ok_m
            out_ok[n, 1] = ok_e
            grid_step_done(g)
            n += 1
            continue
        if not have:
            break
        m, code = rx_feed(tb, st, t[i], np.int64(can_id[i]), is_ext[i], np.int64(dlc[i]), data[i])
        grid_frame(g, t[i], m >= 0, m == anchor and code >= 0 and e2e[m, S_ACCEPTED] != 0)
        i += 1
    return i, n


def step_times(t_start_ns: int, t_end_ns: int, step_ns: int = STEP_NS) -> np.ndarray:
    """``t_start + k * step`` for all k with ``t <= t_end`` -> int64 (empty if ``t_end < t_start``)."""
    if t_end_ns < t_start_ns:
        return np.zeros(0, dtype=np.int64)
    n = (int(t_end_ns) - int(t_start_ns)) // step_ns + 1
    if n > MAX_STEPS:
        raise overflow_error(MAX_STEPS, step_ns)
    return int(t_start_ns) + np.arange(n, dtype=np.int64) * step_ns


def _explicit(step_times_ns: np.ndarray) -> np.ndarray:
    t = np.ascontiguousarray(step_times_ns, dtype=np.int64).reshape(-1)
    if t.size > 1 and bool(np.any(np.diff(t) < 0)):
        raise ValueError("step times must be non-decreasing")
    return t


def build_grid(
    decoded: Decoded,
    profile: Profile,
    t_start_ns: int | None = None,
    step_times_ns: np.ndarray | None = None,
    t_end_ns: int | None = None,
) -> InputGrid:
    """The inputs at every step time (the receiver kernel fed in the grid's order).

    Args:
        decoded: :func:`lde.engine.receiver.decode_batch` output for ``profile`` (its frames are fed again).
        t_start_ns: a fixed grid from this time (to ``t_end_ns`` or the last frame); default the
            anchored grid (module docstring).
        step_times_ns: explicit step times (int64, non-decreasing); overrides start/end.
        t_end_ns: the end of the log for the anchored grid / the fixed grid; default its last frame.
    """
    frames = decoded.frames
    if frames is None:
        raise ValueError(
            "build_grid needs a Decoded from lde.engine.receiver.decode_batch (it carries the frames)"
        )
    if step_times_ns is not None:
        g, explicit = new_grid(MODE_EXPLICIT), _explicit(step_times_ns)
    elif t_start_ns is not None:
        end = decoded.t_last_ns if t_end_ns is None else t_end_ns
        times = np.zeros(0, np.int64) if end is None else step_times(int(t_start_ns), int(end))
        g, explicit = new_grid(MODE_EXPLICIT), times
    else:
        g, explicit = new_grid(MODE_ANCHORED), np.zeros(0, np.int64)
    used = decoded.used_profile if decoded.used_profile is not None else profile
    return _sample_frames(used, frames, g, explicit, t_end_ns)


def _sample_frames(
    profile: Profile, frames: FrameBatch, g: np.ndarray, explicit: np.ndarray, t_end_ns: int | None
) -> InputGrid:
    tb = RxTables.of(profile)
    st = RxState.initial(tb)
    tba, sta = tb.kernel_args(), st.kernel_args()
    chunks: list[tuple[np.ndarray, ...]] = []
    cap = 1 << 16
    i = 0
    while True:
        out = (
            np.empty(cap, np.int64),
            np.empty((cap, N_INPUTS)),
            np.empty((cap, N_INPUTS), np.int64),
            np.empty(cap, np.int64),
            np.empty((cap, 2), np.bool_),
        )
        i, n = _inputs_kernel(
            tba,
            sta,
            g,
            explicit,
            True,
            np.int64(t_end_ns or 0),
            t_end_ns is not None,
            i,
            frames.t_ns,
            frames.can_id,
            frames.is_extended,
            frames.dlc,
            frames.data,
            tb.anchor,
            *out,
        )
        chunks.append(tuple(a[:n] for a in out))
        if g[G_OVERFLOW]:
            raise overflow_error(int(g[G_MAX_STEPS]), int(g[G_PERIOD]))
        if n < cap:
            break
    cols = [np.concatenate([c[k] for c in chunks]) for k in range(5)]
    return InputGrid.from_columns(*cols)


def segmented_step_times(
    anchor_t_ns: np.ndarray,
    input_t_ns: np.ndarray,
    t_end_ns: int | None,
    max_gap_ns: int = MAX_GAP_NS,
    step_ns: int = STEP_NS,
) -> np.ndarray:
    """The anchored grid's step times for given frame times (module docstring).

    Args:
        anchor_t_ns: sorted times of the accepted anchor (MDPS) frames [ns] (input frames too).
        input_t_ns: sorted times of every input-message frame (any status) [ns].
        t_end_ns: the end of the log [ns] (None: no steps).

    Raises:
        LogFormatError: more than :data:`MAX_STEPS` steps in all.
    """
    a = np.asarray(anchor_t_ns, dtype=np.int64)
    f = np.asarray(input_t_ns, dtype=np.int64)
    if a.size == 0 or t_end_ns is None:
        return np.zeros(0, dtype=np.int64)
    t = np.concatenate([f, a])
    is_anchor = np.concatenate([np.zeros(f.size, np.bool_), np.ones(a.size, np.bool_)])
    order = np.argsort(t, kind="stable")
    t, is_anchor = t[order], is_anchor[order]
    g = new_grid(MODE_ANCHORED, step_ns, max_gap_ns)
    end = np.int64(t_end_ns)
    n = int(_event_steps(g.copy(), t, is_anchor, end, np.zeros(0, np.int64)))
    if n < 0:
        raise overflow_error(MAX_STEPS, step_ns)
    out = np.empty(n, np.int64)
    _event_steps(g, t, is_anchor, end, out)
    return out


@njit(cache=True)
def _event_steps(g, t, is_anchor, t_end, out):  # pragma: no cover - compiled
    """The grid over (time, accepted-anchor) events ending at ``t_end``; writes the step times into
    ``out`` (or only counts them when ``out`` is empty); returns the count, -1 on overflow."""
    none = np.zeros(0, np.int64)
    i = 0
    n = 0
    nf = t.shape[0]
    while True:
        have = i < nf
        if not have and g[G_FINISH] == 0:
            grid_finish(g, t_end, True)
        due, tk = grid_due(g, none, have, t[i] if have else np.int64(0), True)
        if g[G_OVERFLOW] == 1:
            return -1
        if due:
            if out.shape[0] > 0:
                out[n] = tk
            n += 1
            grid_step_done(g)
            continue
        if not have:
            return n
        grid_frame(g, t[i], True, is_anchor[i])
        i += 1


@nb.njit(cache=True)
def _latest_at_or_before_sorted(ref: np.ndarray, query: np.ndarray) -> np.ndarray:  # pragma: no cover
    """``searchsorted(ref, query, side="right") - 1`` for sorted ``query``: one merge pass."""
    out = np.empty(query.shape[0], dtype=np.int64)
    j = 0
    n = ref.shape[0]
    for i in range(query.shape[0]):
        q = query[i]
        while j < n and ref[j] <= q:
            j += 1
        out[i] = j - 1
    return out


def latest_at_or_before(ref: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Index of the last ``ref`` element ``<= query`` (-1 if none); ``ref`` sorted ascending."""
    if query.shape[0] > 1 and bool(np.all(query[1:] >= query[:-1])):
        return _latest_at_or_before_sorted(ref, query)
    return np.searchsorted(ref, query, side="right") - 1
