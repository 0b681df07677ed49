"""Report of a ``bench/uml_timing.sh`` run: the service's timing from its recording's ``/lde/diag``
over the stretch in which the simulator was sending, and the output frames candump saw.

    python bench/uml_timing_report.py OUTDIR
"""

from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from lde.can.e2e import p01_check
from lde.can.profiles import load_profile
from lde.io import read_log
from lde.units import STEP_NS


def main(out: Path) -> None:
    log = read_log(out / "service.mcap", json_topics=["/lde/diag", "/lde/estimate"])
    d, e = log.mcap.json["/lde/diag"], log.mcap.json["/lde/estimate"]
    t = np.asarray(d["log_time"])
    rx = log.frames.t_ns[log.frames.is_rx]
    w = (t >= rx[0]) & (t <= rx[-1])
    q = np.percentile
    pe, st, lat = (np.asarray(d[k])[w] for k in ("period_error_us", "step_time_us", "latency_us"))
    lat = lat[lat >= 0]
    span = rx[-1] - rx[0]
    print(f"steps {int(w.sum())} of {round(span / STEP_NS)} grid points over {span / 1e9:.1f} s")
    print(f"period error p50 {q(pe, 50):.0f} p99 {q(pe, 99):.0f} max {pe.max():.0f} us")
    print(f"step time    p50 {q(st, 50):.0f} p99 {q(st, 99):.0f} us")
    print(f"latency      p50 {q(lat, 50):.0f} p99 {q(lat, 99):.0f} us")
    print(f"estimate valid in {100 * np.asarray(e['valid'])[w].mean():.1f} % of the steps")
    profile = load_profile("lde")
    frames: dict[int, list[bytes]] = defaultdict(list)
    for line in (out / "dump.log").read_text().splitlines():
        parts = line.split()
        if len(parts) >= 3 and "#" in parts[2]:
            cid, data = parts[2].split("#", 1)
            frames[int(cid, 16)].append(bytes.fromhex(data))
    for name in ("LDE_Estimate", "LDE_Overlay", "LDE_Diag"):
        fid = profile.output_id(name)
        got = frames[fid]
        ctr = [b[1] & 0x0F for b in got]
        breaks = sum(1 for a, b in zip(ctr, ctr[1:], strict=False) if (b - a) % 15 != 1)
        bad = sum(1 for b in got if not p01_check(fid, b))
        print(f"{name}: {len(got)} frames, {bad} bad CRC, {breaks} counter breaks")


if __name__ == "__main__":
    main(Path(sys.argv[1] if len(sys.argv) > 1 else "."))
