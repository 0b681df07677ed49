"""The fixed estimator step grid (SPEC section 3) over decoded signals: sample-and-hold and staleness.

Step times::

    t_k = t_start + k * STEP_NS,  k = 0, 1, ...  while t_k <= t_end
    t_start = the first accepted frame of the profile's anchor (MDPS) message, unless given
    t_end   = the last frame of the batch, unless given

or exactly the given ``step_times_ns`` (to replay a live recording on its recorded step times).

A silence longer than :data:`MAX_GAP_NS` (60 s) without any frame of an input message splits the
default grid into segments, each anchored again at its own first accepted anchor frame and ending
at its last input frame (the last segment at ``t_end``). Shorter gaps are stepped through (the
inputs go stale, then recover). A log that joins recordings from different time bases (one with
relative timestamps, one in epoch seconds) thus replays each part instead of asking for 10^11
steps across the jump. More than :data:`MAX_STEPS` steps in all is a :class:`LogFormatError`.

At each step (same rules as :meth:`lde.signals.Receiver.sample`, see :mod:`lde.signals`)::

    j = searchsorted(t_accepted, t_k, side="right") - 1     # latest accepted sample <= t_k
    value = values[j] if j >= 0 else NaN
    valid = j >= 0 and t_k - t_accepted[j] <= timeout
    trusted_m = trusted[searchsorted(t_frames_m, t_k, "right") - 1]   (False before any frame)
    mdps_ok = all MDPS inputs valid and all MDPS messages trusted; esc_ok likewise
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from .errors import LogFormatError
from .profiles import ESC_INPUTS, INPUT_NAMES, MDPS_INPUTS, Profile
from .signals import Decoded, InputSample
from .units import STEP_NS

__all__ = ["InputGrid", "build_grid", "step_times", "segmented_step_times", "MAX_GAP_NS", "MAX_STEPS"]

#: a silence of the input messages longer than this starts a new grid segment [ns]
MAX_GAP_NS = 60_000_000_000
#: at most this many steps in one grid (about 108 h at 3.9 ms; guards against corrupt timestamps)
MAX_STEPS = 100_000_000


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


@nb.njit(cache=True)
def _latest_at_or_before_sorted(ref: np.ndarray, query: np.ndarray) -> np.ndarray:
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


def step_times(t_start_ns: int, t_end_ns: int, step_ns: int = STEP_NS) -> np.ndarray:
    """``t_start + k * step`` for all k with ``t <= t_end`` -> int64 (empty if ``t_end < t_start``)."""
    if t_end_ns < t_start_ns:
        return np.zeros(0, dtype=np.int64)
    n = (int(t_end_ns) - int(t_start_ns)) // step_ns + 1
    return int(t_start_ns) + np.arange(n, dtype=np.int64) * step_ns


def segmented_step_times(
    anchor_t_ns: np.ndarray,
    input_t_ns: np.ndarray,
    t_end_ns: int | None,
    max_gap_ns: int = MAX_GAP_NS,
    step_ns: int = STEP_NS,
) -> np.ndarray:
    """Default step times: one grid per segment of input traffic (module docstring).

    Args:
        anchor_t_ns: sorted times of the accepted anchor (MDPS) frames [ns].
        input_t_ns: sorted times of every input-message frame (any status) [ns].
        t_end_ns: last possible step time of the last segment (the batch's last frame) [ns].
        max_gap_ns: a silence longer than this splits the segments [ns].

    Raises:
        LogFormatError: more than :data:`MAX_STEPS` steps in all.
    """
    a = np.asarray(anchor_t_ns, dtype=np.int64)
    f = np.asarray(input_t_ns, dtype=np.int64)
    if a.size == 0 or t_end_ns is None:
        return np.zeros(0, dtype=np.int64)
    if f.size == 0:
        f = a
    # segment k spans [f[lo_k], f[hi_k]]; a new one starts after every gap > max_gap_ns
    cut = np.flatnonzero(np.diff(f) > max_gap_ns) + 1
    lo = np.concatenate([[0], cut])
    hi = np.concatenate([cut - 1, [f.size - 1]])
    parts: list[np.ndarray] = []
    total = 0
    for k in range(lo.size):
        seg_start, seg_end = int(f[lo[k]]), int(f[hi[k]])
        if k == lo.size - 1 and int(t_end_ns) - seg_end <= max_gap_ns:
            seg_end = int(t_end_ns)  # the last segment runs to the batch's end (trailing other traffic)
        seg_end = min(seg_end, int(t_end_ns))
        i = int(np.searchsorted(a, seg_start, side="left"))
        if i >= a.size or a[i] > seg_end:
            continue  # no accepted anchor frame in this segment: no steps
        n = (seg_end - int(a[i])) // step_ns + 1
        total += n
        if total > MAX_STEPS:
            raise LogFormatError(
                f"the log's input frames would need more than {MAX_STEPS} estimator steps "
                f"({total * step_ns * 1e-9 / 3600:.0f} h at {step_ns * 1e-6:g} ms): corrupt timestamps?"
            )
        parts.append(step_times(int(a[i]), seg_end, step_ns))
    if not parts:
        return np.zeros(0, dtype=np.int64)
    return np.concatenate(parts)


def build_grid(
    decoded: Decoded,
    profile: Profile,
    t_start_ns: int | None = None,
    step_times_ns: np.ndarray | None = None,
    t_end_ns: int | None = None,
) -> InputGrid:
    """Sample decoded signals on the step grid (module docstring).

    Args:
        decoded: :func:`lde.signals.decode_batch` output for ``profile``.
        t_start_ns: first step time; default the first accepted frame of the anchor message, with
            a new segment after every silence longer than :data:`MAX_GAP_NS`.
        step_times_ns: explicit step times (int64, non-decreasing); overrides start/end.
        t_end_ns: last possible step time; default the last frame of the batch.
    """
    if step_times_ns is not None:
        t = np.ascontiguousarray(step_times_ns, dtype=np.int64).reshape(-1)
    elif t_start_ns is None:
        anchor = decoded.messages[profile.anchor_message]
        msgs = decoded.messages.values()
        every = np.concatenate(
            [m.t_ns for m in msgs] + [m.malformed_t_ns for m in msgs] + [np.zeros(0, np.int64)]
        )
        t = segmented_step_times(
            anchor.t_ns[anchor.accepted],
            np.sort(every),
            decoded.t_last_ns if t_end_ns is None else t_end_ns,
        )
    else:
        if t_end_ns is None:
            t_end_ns = decoded.t_last_ns
        if t_start_ns is None or t_end_ns is None:
            t = np.zeros(0, dtype=np.int64)
        else:
            t = step_times(int(t_start_ns), int(t_end_ns))
    n = t.shape[0]

    values: dict[str, np.ndarray] = {}
    valid: dict[str, np.ndarray] = {}
    age: dict[str, np.ndarray] = {}
    trusted_at: dict[str, np.ndarray] = {}
    for mname, m in decoded.messages.items():
        spec = profile.messages[mname]
        # latest accepted sample of this message at or before each step (shared by its inputs)
        t_acc = m.t_ns[m.accepted]
        j = latest_at_or_before(t_acc, t)
        have = j >= 0
        jj = np.maximum(j, 0)
        a = np.where(have, t - t_acc[jj], -1) if t_acc.shape[0] else np.full(n, -1, dtype=np.int64)
        fresh = have & (a <= spec.timeout_ns)
        for name in spec.inputs:
            v = decoded.inputs[name].value
            values[name] = np.where(have, v[jj], np.nan) if v.shape[0] else np.full(n, np.nan)
            age[name] = a
            valid[name] = fresh
        # the message's trust after its latest frame at or before each step
        jf = latest_at_or_before(m.t_ns, t)
        trusted_at[mname] = (
            (jf >= 0) & m.trusted[np.maximum(jf, 0)] if m.t_ns.shape[0] else np.zeros(n, np.bool_)
        )

    ok = {}
    for g, names in (("mdps", MDPS_INPUTS), ("esc", ESC_INPUTS)):
        o = np.ones(n, dtype=np.bool_)
        for name in names:
            o &= valid[name]
        for mname in profile.group_messages(g):
            o &= trusted_at[mname]
        ok[g] = o

    return InputGrid(
        t_ns=t,
        **values,
        valid=valid,
        age_ns=age,
        mdps_ok=ok["mdps"],
        esc_ok=ok["esc"],
    )
