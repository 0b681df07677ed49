"""Synthetic lde-profile traffic for the benchmarks: any length, generated and written piece by piece.

MDPS_Sensors every 3.9 ms with 0..100 us of jitter, ESC_Motion every 10 ms (2 ms after it), about
1.28 M frames per hour, at ~100 km/h with small steering and noise, encoded with
:func:`lde.can.codec.encode_batch` (E2E counters and CRCs, counters continuous across pieces). Every
random source is seeded (``seed`` and the piece's index), so a 10-hour log starts with the same
hour as a 1-hour one.

    python bench/traffic.py --hours 1 --out /tmp/x        # /tmp/x/hour1.log and /tmp/x/hour1.mcap
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from lde.can.codec import encode_batch, si_to_dbc
from lde.can.frames import FrameBatch
from lde.can.profiles import Profile, load_profile
from lde.io import McapWriter, format_candump
from lde.units import DEG, KMH, STEP_NS

T0 = 1_700_000_000_000_000_000  # ns: the logs' epoch start
PIECE_S = 600.0  # seconds of traffic generated at once
MESSAGES = (("MDPS_Sensors", STEP_NS, 0), ("ESC_Motion", 10_000_000, 2_000_000))


def iter_traffic(
    profile: Profile, seconds: float, seed: int = 1, piece_s: float = PIECE_S
) -> Iterator[FrameBatch]:
    """The input frames of ``seconds`` of driving, in time order, ``piece_s`` seconds at a time."""
    done = {name: 0 for name, _, _ in MESSAGES}  # frames of each message generated so far
    total = {name: int(seconds * 1e9 / period) for name, period, _ in MESSAGES}
    piece = 0
    while any(done[n] < total[n] for n in done):
        rng = np.random.default_rng([seed, piece])
        parts = []
        for name, period, offset in MESSAGES:
            spec = profile.spec(name)
            a = done[name]
            b = min(total[name], int((piece + 1) * piece_s * 1e9 / period))
            n = b - a
            if n <= 0:
                continue
            t_nom = (np.arange(a, b, dtype=np.int64)) * period + offset
            ts = t_nom * 1e-9
            w = 2 * np.pi * 0.3
            si_all = {
                "steering_angle": 1.5 * DEG * np.sin(w * ts) + rng.normal(0, 0.05 * DEG, n),
                "steering_rate": 1.5 * DEG * w * np.cos(w * ts),
                "column_torque": 0.4 * np.sin(w * ts) + rng.normal(0, 0.01, n),
                "assist_torque": 1.2 * np.sin(w * ts) + rng.normal(0, 0.02, n),
                "yaw_rate": 0.01 * np.sin(w * ts - 0.2) + rng.normal(0, 0.03 * DEG, n),
                "lat_accel": 0.3 * np.sin(w * ts - 0.2) + rng.normal(0, 0.05, n),
                "speed": np.full(n, 100 * KMH) + rng.normal(0, 0.05 * KMH, n),
            }
            si = {i: si_all[i] for i in spec.inputs}
            modulus = 15  # E2E Profile 1 counters 0..14 (both messages of the lde profile)
            data = encode_batch(profile, name, si_to_dbc(profile, name, si), counter_start=a % modulus)
            parts.append(
                FrameBatch(
                    t_ns=T0 + t_nom + rng.integers(0, 101, n) * 1000,
                    can_id=np.full(n, spec.frame_id),
                    is_extended=np.zeros(n, bool),
                    dlc=np.full(n, spec.length),
                    data=data,
                    is_rx=np.ones(n, bool),
                )
            )
            done[name] = b
        piece += 1
        if parts:
            yield FrameBatch.concat(parts).sort()


def make_traffic(profile: Profile, seconds: float, seed: int = 1) -> FrameBatch:
    """All of :func:`iter_traffic` in one batch (short logs)."""
    return FrameBatch.concat(list(iter_traffic(profile, seconds, seed)))


def write_logs(
    out_dir: Path,
    hours: float,
    seed: int = 1,
    name: str | None = None,
    formats: tuple[str, ...] = ("log", "mcap"),
) -> dict[str, Path]:
    """``hours`` of traffic as candump ``-L`` text (``.log``) and/or an MCAP log (``.mcap``), written
    piece by piece (memory bounded by one piece). Returns the paths by suffix."""
    profile = load_profile("lde")
    name = name or f"hour{hours:g}"
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = {fmt: out_dir / f"{name}.{fmt}" for fmt in formats}
    cd = paths["log"].open("w", encoding="ascii") if "log" in paths else None
    mc = McapWriter(paths["mcap"]) if "mcap" in paths else None
    try:
        for piece in iter_traffic(profile, hours * 3600.0, seed):
            if cd is not None:
                cd.write(format_candump(piece))
            if mc is not None:
                mc.write_frames(piece)
    finally:
        if cd is not None:
            cd.close()
        if mc is not None:
            mc.close()
    return paths


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--hours", type=float, default=1.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", type=Path, required=True, help="output directory")
    ap.add_argument("--name", default=None, help="file stem (default hour<H>)")
    ap.add_argument("--formats", default="log,mcap", help="comma-separated: log (candump), mcap")
    args = ap.parse_args()
    t0 = time.perf_counter()
    paths = write_logs(args.out, args.hours, args.seed, args.name, tuple(args.formats.split(",")))
    for p in paths.values():
        print(f"{p}: {p.stat().st_size / 1e6:.1f} MB", file=sys.stderr)
    print(f"{time.perf_counter() - t0:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
