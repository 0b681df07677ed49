"""What a live step leaves allocated: ``Service.step_once`` without a bus (``bench_service_step``'s list
bus, recorder on), 2560 steps to warm up, then tracemalloc over 2560 more with the collector off and
the start-up frozen, as in ``Service.run``: the growth per step of the largest allocation sites, and
how much the young generation's count grows per step (a young collection runs at 700).

    python bench/alloc_step.py
"""

from __future__ import annotations

import gc
import sys
import tempfile
import time
import tracemalloc
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))

from bench_service_step import ListBus  # noqa: E402

from lde.can.codec import MessageEncoder, si_to_dbc  # noqa: E402
from lde.can.profiles import load_profile  # noqa: E402
from lde.clock import SimulatedClock  # noqa: E402
from lde.io.recording import Recorder  # noqa: E402
from lde.params import load_vehicle  # noqa: E402
from lde.service.service import Service  # noqa: E402
from lde.units import DEG, KMH, STEP_NS  # noqa: E402

N = 2560


def main() -> None:
    profile, vehicle = load_profile("lde"), load_vehicle("reference")
    t0 = time.time_ns()
    bus = ListBus()
    clock = SimulatedClock(t0)
    rec = Recorder(Path(tempfile.mkdtemp()) / "alloc.mcap")
    svc = Service(bus, profile, vehicle, clock, recorder=rec, log_period_s=0, timebase_offset_ns=0)
    mdps, esc = MessageEncoder(profile, "MDPS_Sensors"), MessageEncoder(profile, "ESC_Motion")
    sensors = {"column_torque": 0.5, "assist_torque": 1.0, "steering_angle": 0.4 * DEG, "steering_rate": 0.0}
    mv = si_to_dbc(profile, "MDPS_Sensors", sensors)
    ev = si_to_dbc(profile, "ESC_Motion", {"yaw_rate": 0.0, "lat_accel": 0.1, "speed": 100 * KMH})
    frames = []
    for k in range(2 * N):
        t_k = t0 + (k + 1) * STEP_NS
        m = [mdps.message(mv, t_k)]
        if k % 5 in (0, 3):
            m.insert(0, esc.message(ev, t_k - 1_000_000))
        frames.append((t_k, m))

    def steps(part: list) -> None:
        for t_k, m in part:
            bus.queue.extend(m)
            clock.sleep_until(t_k)
            svc.step_once(t_k, t_start=t_k)

    steps(frames[:N])
    gc.collect()
    gc.freeze()
    gc.disable()
    c0 = gc.get_count()[0]
    tracemalloc.start()
    s0 = tracemalloc.take_snapshot()
    steps(frames[N:])
    s1 = tracemalloc.take_snapshot()
    c1 = gc.get_count()[0]
    print(f"young-generation count per step: {(c1 - c0) / N:.3f}")
    for st in s1.compare_to(s0, "lineno")[:5]:
        print(f"{st.size_diff / N:8.2f} B/step  {st.traceback}")
    rec.close()
    bus.shutdown()


if __name__ == "__main__":
    main()
