"""What a log holds: its buses, ids, frame counts, rates and lengths (before any profile).

Per (channel, id): the frames, the data lengths seen, the median period (the message's cycle),
the jitter (the spread of the periods between their 5th and 95th percentiles: a periodic message
sent by one ECU has a small one; a gateway or a logger that batches frames a large one) and the
largest gap. Times are integer nanoseconds in the log's own time base.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["IdStats", "LogSurvey", "survey_log"]


@dataclass(frozen=True)
class IdStats:
    """One id on one channel.

    Attributes:
        channel: the bus name (``""``: the log does not name it); can_id; extended: 29-bit id.
        frames: how many; lengths: the data lengths seen [bytes], ascending.
        period_ms: median time between frames [ms] (NaN with one frame).
        jitter_ms: 95th minus 5th percentile of those times [ms]; max_gap_ms: the longest [ms].
    """

    channel: str
    can_id: int
    extended: bool
    frames: int
    lengths: tuple[int, ...]
    period_ms: float
    jitter_ms: float
    max_gap_ms: float

    @property
    def rate_hz(self) -> float:
        """Frames per second from the median period (NaN with one frame)."""
        return 1000.0 / self.period_ms if self.period_ms > 0 else float("nan")

    @property
    def id_text(self) -> str:
        return f"0x{self.can_id:08X}" if self.extended else f"0x{self.can_id:03X}"


@dataclass(frozen=True)
class LogSurvey:
    """A log's ids per channel (sorted by channel, then id) and its time span."""

    frames: int
    start_ns: int
    end_ns: int
    channels: tuple[str, ...]
    ids: tuple[IdStats, ...]

    @property
    def duration_s(self) -> float:
        return (self.end_ns - self.start_ns) * 1e-9

    def on(self, can_id: int, extended: bool = False) -> list[IdStats]:
        """The stats of ``can_id`` on every channel that carries it."""
        return [s for s in self.ids if s.can_id == can_id and s.extended == extended]


def survey_log(
    t_ns: np.ndarray,
    can_id: np.ndarray,
    is_extended: np.ndarray,
    dlc: np.ndarray,
    channel: np.ndarray | None = None,
    channels: tuple[str, ...] = ("",),
) -> LogSurvey:
    """The survey of a log's frames (columns as :class:`lde.can.frames.FrameBatch` holds them;
    ``channel`` indexes ``channels``, None: every frame on ``channels[0]``)."""
    t = np.asarray(t_ns, dtype=np.int64)
    n = t.size
    if n == 0:
        return LogSurvey(0, 0, 0, (), ())
    ids = np.asarray(can_id, dtype=np.int64)
    ext = np.asarray(is_extended, dtype=bool)
    lens = np.asarray(dlc, dtype=np.int64)
    ch = np.zeros(n, np.int64) if channel is None else np.asarray(channel, dtype=np.int64)
    order = np.lexsort((t, ids, ext, ch))
    key = np.stack([ch[order], ext[order].astype(np.int64), ids[order]], axis=1)
    starts = np.flatnonzero(np.r_[True, np.any(key[1:] != key[:-1], axis=1)])
    ends = np.r_[starts[1:], n]
    out = []
    for a, b in zip(starts.tolist(), ends.tolist(), strict=True):
        rows = order[a:b]
        d = np.diff(t[rows]) * 1e-6
        if d.size:
            p5, p50, p95 = np.percentile(d, (5, 50, 95))
            period, jitter, gap = float(p50), float(p95 - p5), float(d.max())
        else:
            period = jitter = gap = float("nan")
        out.append(
            IdStats(
                channel=channels[int(key[a, 0])],
                can_id=int(key[a, 2]),
                extended=bool(key[a, 1]),
                frames=int(b - a),
                lengths=tuple(int(x) for x in np.unique(lens[rows])),
                period_ms=period,
                jitter_ms=jitter,
                max_gap_ms=gap,
            )
        )
    used = sorted({int(c) for c in np.unique(ch)})
    return LogSurvey(
        frames=n,
        start_ns=int(t.min()),
        end_ns=int(t.max()),
        channels=tuple(channels[c] for c in used),
        ids=tuple(out),
    )
