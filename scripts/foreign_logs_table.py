"""Every foreign-log case of docs/guide/reliability.md ("Bad input"), replayed in process:
exit code, warnings, NRMSE against the truth. ``python scripts/foreign_logs_table.py [CASE...] --out DIR``."""

import contextlib
import io
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from lde.cli import main
from lde.io import write_candump

from helpers import foreign_logs as F

args = sys.argv[1:]
out = Path(args[args.index("--out") + 1]) if "--out" in args else Path("foreign_logs_cases")
out.mkdir(exist_ok=True)
only = [a for a in args if not a.startswith("--") and a != str(out)]


def run(name, path, truth, *extra, shift=0.0):
    csv = out / f"{name}.csv"
    err = io.StringIO()
    t = time.perf_counter()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(["replay", str(path), "--csv", str(csv), *extra])
        except SystemExit as e:
            rc = e.code
        except BaseException:
            import traceback

            traceback.print_exc(file=err)
            rc = "TRACEBACK"
    dt = time.perf_counter() - t
    acc = ""
    if csv.exists() and truth is not None:
        try:
            a = F.csv_accuracy(csv, truth, shift)
            acc = f"Fw {a.nrmse_fw * 100:.2f}% Mw {a.nrmse_mw * 100:.2f}% n={a.n}"
        except Exception as e:
            acc = f"acc: {e}"
    warn = [
        l
        for l in err.getvalue().splitlines()
        if "warning" in l or "error" in l or "Trace" in l or "rejected" in l
    ]
    print(f"== {name}: rc={rc} {dt:.1f}s {acc}")
    for l in warn[:6]:
        print("   ", l[:400])
    sys.stdout.flush()


cases = {}


def case(f):
    cases[f.__name__] = f
    return f


base = {}


def drv(profile, periods=None, scenario="wind_step", duration=12.0):
    key = (profile, tuple(sorted((periods or {}).items())), scenario, duration)
    if key not in base:
        base[key] = F.drive(profile, periods, scenario, duration)
    return base[key]


def ours(profile):
    return drv(profile)


def candump_case(name, r, frames=None, profile="lde", shift=0.0):
    """``frames`` (default: the drive's own) written as a candump log and replayed against the
    drive's truth; ``--profile`` given for ``hyundai``."""
    p = out / f"{name}.log"
    write_candump(p, r.frames if frames is None else frames)
    run(name, p, F.truth_of(r), *(("--profile", profile) if profile != "lde" else ()), shift=shift)


@case
def periods():
    candump_case("lde_ours", ours("lde"))
    candump_case("hy_ours", ours("hyundai"), profile="hyundai")
    candump_case("lde_esc20_mdps4", drv("lde", {"ESC_Motion": 20, "MDPS_Sensors": 4}))
    candump_case("lde_esc20_mdps5", drv("lde", {"ESC_Motion": 20, "MDPS_Sensors": 5}))
    hy_car = drv("hyundai", {"MDPS12": 10, "SAS11": 10, "ESP12": 20, "WHL_SPD11": 20})
    candump_case("hy_car_rates", hy_car, profile="hyundai")
    hy_fast = drv("hyundai", {"MDPS12": 5, "SAS11": 10, "ESP12": 10, "WHL_SPD11": 20})
    candump_case("hy_mdps5", hy_fast, profile="hyundai")


@case
def rewrites():
    for prof, jit_us, burst_ms in (("lde", 300, 10), ("hyundai", 1000, 20)):
        r = ours(prof)
        tag = "lde" if prof == "lde" else "hy"
        candump_case(f"{tag}_jitter{jit_us}us", r, F.jitter(r.frames, jit_us), prof)
        candump_case(f"{tag}_bursts{burst_ms}ms", r, F.bursts(r.frames, burst_ms), prof)
        candump_case(f"{tag}_midstream", r, F.cut(r.frames, None, 3.0137), prof)
    r = ours("lde")
    candump_case("lde_swap5pct", r, F.swap_neighbours(r.frames, 0.05))
    t0 = int(r.frames.t_ns[0])
    candump_case("lde_relative", r, F.with_times(r.frames, r.frames.t_ns - t0), shift=t0 / 1e9)
    candump_case("lde_gap3s", r, F.cut(r.frames, 4.0, 7.0))
    candump_case("lde_no_esc", r, F.drop_ids(r.frames, {0x2A8}))
    candump_case("lde_no_mdps", r, F.drop_ids(r.frames, {0x2A0}))
    for prof in ("lde", "hyundai"):
        r = ours(prof)
        candump_case(f"{prof}_dbc_limits_4-4.5s", r, F.at_dbc_limits(r.frames, prof, 4.0, 4.5), prof)


@case
def channels():
    r = ours("lde")
    p = out / "ch.log"
    write_candump(p, r.frames, channel="can1")
    run("lde_can1", p, F.truth_of(r))
    p = out / "noif.log"
    F.write_candump_plain(p, r.frames, None)
    run("lde_no_iface_col", p, F.truth_of(r))
    p = out / "ext.log"
    F.write_candump_plain(p, F.foreign(r.frames, 3000), "can0")
    run("lde_foreign", p, F.truth_of(r))


@case
def formats():
    for prof in ("lde", "hyundai"):
        r = ours(prof)
        x = ["--profile", prof]
        for suf in ("asc", "blf", "csv", "trc"):
            p = out / f"{prof}.{suf}"
            F.write_pycan(p, r.frames, channel=1 if suf in ("asc", "blf") else "can0")
            run(f"{prof}_{suf}", p, F.truth_of(r), *x, shift=r.frames.t_ns[0] / 1e9 if suf == "asc" else 0.0)
        p = out / f"{prof}_lib.mcap"
        F.write_mcap_library(p, r.frames)
        run(f"{prof}_mcap_lib", p, F.truth_of(r), *x)


@case
def mcap_variants():
    r = ours("lde")
    for name, o in {
        "zstd_small": F.McapOptions(compression="zstd", chunk_size=4096),
        "none": F.McapOptions(compression="none"),
        "unchunked": F.McapOptions(use_chunking=False),
        "topic_can0": F.McapOptions(topic="/vehicle/can0"),
    }.items():
        p = out / f"m_{name}.mcap"
        F.write_mcap_library(p, r.frames, o)
        run(f"mcap_{name}", p, F.truth_of(r))


@case
def tx_direction():
    r = ours("lde")
    f = replace(r.frames, is_rx=np.zeros(len(r.frames), bool))
    p = out / "tx.asc"
    F.write_pycan(p, f, channel=1)
    run("lde_asc_all_Tx", p, F.truth_of(r), shift=r.frames.t_ns[0] / 1e9)
    p = out / "tx.blf"
    F.write_pycan(p, f, channel=1)
    run("lde_blf_all_Tx", p, F.truth_of(r))


@case
def fd_remote_error():
    import can

    import lde.io.candump as c

    r = ours("lde")
    fd = F.fd_messages(r.frames, [0x2A0, 0x2A8, 0x300], 300)
    extra = (
        fd
        + [can.Message(timestamp=m.timestamp, is_remote_frame=True, arbitration_id=0x2A0) for m in fd[:50]]
        + [can.Message(timestamp=m.timestamp, is_error_frame=True) for m in fd[50:100]]
    )
    f = F.foreign(r.frames, 2000)
    for suf in ("asc", "blf"):
        p = out / f"fd.{suf}"
        F.write_pycan(p, f, channel=1, extra=extra)
        run(
            f"lde_fd_remote_error_foreign_{suf}",
            p,
            F.truth_of(r),
            shift=r.frames.t_ns[0] / 1e9 if suf == "asc" else 0.0,
        )
    lines = c.format_candump_bytes(f, "can0").decode().splitlines(True) + [F.candump_line(m) for m in extra]
    lines.sort(key=lambda s: s.split(")")[0])
    p = out / "fd.log"
    p.write_text("".join(lines))
    run("lde_fd_remote_error_foreign_candump", p, F.truth_of(r))
    p = out / "two.log"
    lines = c.format_candump_bytes(r.frames, "can0").decode().splitlines(True) + c.format_candump_bytes(
        r.frames, "can1"
    ).decode().splitlines(True)
    lines.sort(key=lambda s: s.split(")")[0])
    p.write_text("".join(lines))
    run("lde_inputs_on_two_channels", p, F.truth_of(r))


for n, f in cases.items():
    if not only or n in only:
        try:
            f()
        except Exception as e:
            import traceback

            traceback.print_exc()
            print("GENERATOR FAIL", n, e)
