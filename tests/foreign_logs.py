"""Logs as another producer could write them (SPEC sections 3-4), for ``tests/test_foreign_logs.py``.

A drive is simulated by ``vcan_sim`` with the input messages at *other* periods than lde's DBCs
give (a :class:`~lde.can.profiles.Profile` whose ``period_ns`` are replaced: the plant is sampled at
those times, not resampled from our own log), then rewritten the way an independent tool could:
jitter, bursts, slight disorder, a relative time base, a start mid-stream, a gap, other channel
names, foreign / extended / remote / error / CAN FD frames, a missing input message, and written
in the formats python-can reads (candump ``-L`` with and without the interface column, ASC, BLF,
CSV, TRC) or as MCAP by the ``mcap`` library's own writer.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lde.analysis.metrics import Accuracy, Truth, accuracy
from lde.can.frames import FrameBatch
from lde.can.profiles import Profile, load_profile
from vcan_sim.run import SimResult, simulate

MS = 1_000_000
SEC = 1_000_000_000


def profile_with_periods(profile: str, periods_ms: dict[str, float]) -> Profile:
    """``profile`` with some input messages' periods replaced [ms] (their timeouts stay 3 periods
    of the DBC's: what the receiver expects is lde's, what the producer sends is not)."""
    p = load_profile(profile)
    msgs = dict(p.messages)
    for name, ms in periods_ms.items():
        msgs[name] = replace(msgs[name], period_ns=round(ms * MS))
    return replace(p, messages=msgs)


def drive(
    profile: str = "lde",
    periods_ms: dict[str, float] | None = None,
    scenario: str = "wind_step",
    duration: float = 12.0,
    seed: int = 3,
) -> SimResult:
    """A simulated drive whose input frames come at ``periods_ms`` (default: the DBC's)."""
    prof = profile_with_periods(profile, periods_ms or {})
    return simulate(scenario, profile=prof, seed=seed, duration=duration)


def truth_of(res: SimResult) -> Truth:
    tr = res.truth
    return Truth(t=res.truth_t_ns / 1e9, fw=tr["Fw"], mw=tr["Mw"], mw_ref=tr.get("Mw_ref", tr["Mw"]))


def csv_accuracy(csv: Path, truth: Truth, t_shift_s: float = 0.0) -> Accuracy:
    """NRMSE of an ``lde replay --csv`` output against the truth (VALID steps after 2 s);
    ``t_shift_s`` is added to the CSV's ``t`` (a log rewritten to another time base)."""
    d = read_replay_csv(csv)
    valid = (d["status"] & 1).astype(bool) if "status" in d.dtype.names else None
    return accuracy(d["t"] + t_shift_s, d["Fw"], d["Mw"], truth, valid=valid)


def read_replay_csv(csv: Path) -> np.ndarray:
    """An ``lde replay --csv`` output as a structured array: one field per column, named by the
    header, each typed as its values read (``status`` an integer, the rest floats)."""
    return np.atleast_1d(np.genfromtxt(csv, delimiter=",", names=True, dtype=None, encoding="utf-8"))


# ----------------------------------------------------------------------------- rewriting frames
def with_times(f: FrameBatch, t_ns: np.ndarray) -> FrameBatch:
    return replace(f, t_ns=np.asarray(t_ns, np.int64))


def jitter(f: FrameBatch, sd_us: float, seed: int = 0) -> FrameBatch:
    """Gaussian timestamp jitter (clipped at 3 sd), file order kept as the new times sort."""
    rng = np.random.default_rng(seed)
    d = np.clip(rng.normal(0.0, sd_us, len(f)), -3 * sd_us, 3 * sd_us)
    return with_times(f, f.t_ns + np.round(d * 1000).astype(np.int64)).sort()


def bursts(f: FrameBatch, every_ms: float) -> FrameBatch:
    """Timestamps quantised up to ``every_ms`` (a logger that stamps per USB packet: several
    frames with one timestamp, never earlier than sent)."""
    q = round(every_ms * MS)
    return with_times(f, -(-f.t_ns // q) * q)


def swap_neighbours(f: FrameBatch, frac: float, seed: int = 0) -> FrameBatch:
    """File order with ``frac`` of adjacent pairs swapped (slightly out of time order)."""
    rng = np.random.default_rng(seed)
    idx = np.arange(len(f))
    for i in np.flatnonzero(rng.random(len(f) - 1) < frac):
        idx[i], idx[i + 1] = idx[i + 1], idx[i]
    return f.take(idx)


def cut(f: FrameBatch, t0_s: float | None = None, t1_s: float | None = None) -> FrameBatch:
    """Frames with relative time in [t0, t1) removed (t0 None: from the start)."""
    rel = f.t_ns - int(f.t_ns[0])
    lo = -1 if t0_s is None else round(t0_s * SEC)
    hi = np.iinfo(np.int64).max if t1_s is None else round(t1_s * SEC)
    return f.select(~((rel >= lo) & (rel < hi)))


def fd_messages(f: FrameBatch, ids: list[int], n: int, seed: int = 0) -> list:
    """``n`` CAN FD messages of 64 bytes with the given ids, at random times of the drive (a bus
    with FD traffic; an input's id on it is a frame of the wrong length)."""
    import can

    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(int(f.t_ns[0]), int(f.t_ns[-1]), n))
    return [
        can.Message(
            timestamp=int(t[i]) / 1e9,
            arbitration_id=int(rng.choice(ids)),
            is_extended_id=False,
            is_fd=True,
            data=rng.integers(0, 256, 64).astype(np.uint8).tobytes(),
        )
        for i in range(n)
    ]


def drop_ids(f: FrameBatch, ids: set[int]) -> FrameBatch:
    return f.select(~np.isin(f.can_id, list(ids)))


def foreign(f: FrameBatch, n: int, seed: int = 0) -> FrameBatch:
    """``n`` frames of other ECUs mixed in: 11-bit ids that are not lde's, 29-bit ids that carry
    an input's number, random payloads of random length."""
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(int(f.t_ns[0]), int(f.t_ns[-1]), n))
    ext = rng.random(n) < 0.5
    used = set(np.unique(f.can_id).tolist())
    std = np.array([i for i in range(0x100, 0x7FF, 7) if i not in used], np.uint32)
    ids = np.where(ext, rng.choice(np.unique(f.can_id), n) | 0x18DA0000, rng.choice(std, n)).astype(np.uint32)
    dlc = rng.integers(0, 9, n).astype(np.uint8)
    data = rng.integers(0, 256, (n, 8)).astype(np.uint8)
    data[np.arange(8)[None, :] >= dlc[:, None]] = 0
    other = FrameBatch(t_ns=t, can_id=ids, is_extended=ext, dlc=dlc, data=data, is_rx=np.ones(n, np.bool_))
    return FrameBatch.concat([f, other])


def at_dbc_limits(f: FrameBatch, profile: str, t0_s: float, t1_s: float) -> FrameBatch:
    """The input frames with relative time in [t0, t1) re-encoded with all their physical signals
    at the DBC's maximum and minimum value in turn, counters and checksums kept right (sensors
    pinned at their range ends). Returns a copy."""
    from lde.can.codec import MessageEncoder

    p = load_profile(profile)
    data = f.data.copy()
    for name, spec in p.messages.items():
        msg = p.db.get_message_by_name(name)
        enc = MessageEncoder(p, name)
        sch = spec.scheme
        kept = {
            s.name
            for s in msg.signals
            if (s.start, s.length) in {(fd[0], fd[1]) for fd in (*sch.counter_fields, *sch.checksum_fields)}
        }
        rel = f.t_ns - int(f.t_ns[0])
        rows = np.flatnonzero(
            (f.can_id == spec.frame_id) & (rel >= round(t0_s * SEC)) & (rel < round(t1_s * SEC))
        )
        for j, r in enumerate(rows):
            raw = bytes(f.data[r, : spec.length])
            dec = msg.decode(raw, decode_choices=False, scaling=True)
            counter = _counter_of(spec, raw)
            for s in msg.signals:
                if s.name in kept:
                    continue
                lim = s.maximum if j % 2 == 0 else s.minimum
                if lim is not None:
                    dec[s.name] = lim
            for k in kept:
                dec.pop(k, None)
            enc.counter = counter
            data[r, : spec.length] = np.frombuffer(enc.encode(dec), np.uint8)
    return replace(f, data=data)


def _counter_of(spec: object, raw: bytes) -> int:
    """The frame's counter from its (little-endian, LSB part first) counter fields."""
    w = int.from_bytes(raw.ljust(8, b"\0"), "little")
    c, shift = 0, 0
    for start, length in spec.scheme.counter_fields:  # type: ignore[attr-defined]
        c |= ((w >> start) & ((1 << length) - 1)) << shift
        shift += length
    return c


# ----------------------------------------------------------------------------- writers
def write_pycan(path: Path, f: FrameBatch, channel: str | int = "vcan0", extra: list | None = None) -> None:
    """Through python-can's own writer for the suffix (ASC, BLF, CSV, TRC, ...); ``extra``
    python-can messages (FD, remote, error frames) merged in by time."""
    import can

    msgs = f.to_messages(channel) + list(extra or [])
    msgs.sort(key=lambda m: m.timestamp)
    with can.Logger(str(path)) as w:
        for m in msgs:
            w.on_message_received(m)


def candump_line(m: object) -> str:
    """A python-can message as a candump ``-L`` line (FD ``##``, remote ``#R``, error frames)."""
    t = round(m.timestamp * 1e6)  # type: ignore[attr-defined]
    ts = f"({t // 1_000_000}.{t % 1_000_000:06d}) can0 "
    if m.is_error_frame:  # type: ignore[attr-defined]
        return ts + "20000080#0000000000000000\n"
    cid = f"{m.arbitration_id:08X}" if m.is_extended_id else f"{m.arbitration_id:03X}"  # type: ignore[attr-defined]
    if m.is_remote_frame:  # type: ignore[attr-defined]
        return ts + cid + "#R\n"
    sep = "##0" if m.is_fd else "#"  # type: ignore[attr-defined]
    return ts + cid + sep + bytes(m.data).hex().upper() + "\n"  # type: ignore[attr-defined]


def write_candump_plain(path: Path, f: FrameBatch, channel: str | None = "can0", decimals: int = 6) -> None:
    """candump ``-L`` text as another tool writes it; ``channel`` None: no interface column."""
    lines = []
    for i in range(len(f)):
        t = int(f.t_ns[i])
        ts = f"{t // SEC}.{(t % SEC) // 10 ** (9 - decimals):0{decimals}d}"
        cid = f"{int(f.can_id[i]):08X}" if f.is_extended[i] else f"{int(f.can_id[i]):03X}"
        payload = bytes(f.data[i, : min(int(f.dlc[i]), 8)]).hex().upper()
        col = "" if channel is None else f" {channel}"
        lines.append(f"({ts}){col} {cid}#{payload}\n")
    path.write_text("".join(lines))


@dataclass
class McapOptions:
    topic: str = "/can/rx"
    compression: str = "lz4"
    chunk_size: int = 1 << 20
    use_chunking: bool = True


def write_mcap_library(path: Path, f: FrameBatch, opt: McapOptions | None = None) -> None:
    """The frames as MCAP with lde's documented CAN schema, written by the ``mcap`` library's
    own ``Writer`` (its chunking, compression, indexes and summary), not by lde."""
    from mcap.writer import CompressionType, Writer

    from lde.io import CAN_SCHEMA_NAME, CAN_SCHEMA_TEXT, can_payloads

    opt = opt or McapOptions()
    comp = {"lz4": CompressionType.LZ4, "zstd": CompressionType.ZSTD, "none": CompressionType.NONE}
    payloads = can_payloads(f)
    with path.open("wb") as fh:
        w = Writer(
            fh, chunk_size=opt.chunk_size, compression=comp[opt.compression], use_chunking=opt.use_chunking
        )
        w.start(profile="", library="someone-else")
        sid = w.register_schema(CAN_SCHEMA_NAME, "ros2msg", CAN_SCHEMA_TEXT.encode())
        cid = w.register_channel(opt.topic, "cdr", sid)
        for i in range(len(f)):
            t = int(f.t_ns[i])
            w.add_message(cid, log_time=t, publish_time=t, data=bytes(payloads[i]), sequence=i)
        w.finish()
