"""``lde replay LOG... [--profile P] [--vehicle FILE] [--backend B] [--csv OUT] [--mcap OUT] [--smooth]``.

Replays CAN logs (MCAP, candump -L, or any python-can format; each also gzip-compressed, as
x.log.gz) through the estimator on the 3.9 ms grid and writes one CSV row per step (t in the log's
own time base; the columns are listed below) and/or an MCAP recording. A short summary goes to
stderr and names the files written; without --csv or --mcap nothing is written (the summary says so).
With several LOGs, --csv / --mcap name directories (one <log stem>.csv / .mcap each, the stem without
.gz) and a progress bar shows on a terminal.

Before anything is read or written, the outputs are checked: a LOG given twice (by any spelling of
its path) is an error, and so is an output that is one of the LOGs or another output (an output never
overwrites an input).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType

from lde.cli import BACKEND_HELP, PROFILE_HELP
from lde.errors import ConfigError, LdeError
from lde.replay.columns import columns_help

#: exit code of a replay that ran but gave no VALID estimate (no step, or every step invalid): the
#: outputs are written, and hold nothing usable (the warning says why); 2 is an error (unreadable log,
#: bad option), 0 success
EXIT_NOTHING_USABLE = 3


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "replay",
        help="replay CAN logs through the estimator (CSV / MCAP out)",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
        epilog=columns_help(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "logs", nargs="+", metavar="LOG", help="MCAP, candump -L text, ASC, BLF, TRC, CSV, ... (also as .gz)"
    )
    p.add_argument(
        "--profile",
        default=None,
        help=PROFILE_HELP + " (default: the one an lde recording names, else lde)",
    )
    p.add_argument("--vehicle", default=None, help="vehicle TOML file or shipped name (default: reference)")
    p.add_argument(
        "--backend",
        default=None,
        help=BACKEND_HELP,
    )
    p.add_argument("--csv", type=Path, default=None, help="CSV output (a directory with several LOGs)")
    p.add_argument(
        "--mcap", type=Path, default=None, help="MCAP recording output (a directory with several LOGs)"
    )
    p.add_argument(
        "--no-recorded-steps",
        action="store_true",
        help="for lde recordings: use the grid from the frames, not the recorded step times",
    )
    p.add_argument(
        "--mcap-index",
        action="store_true",
        help="--mcap with message and chunk indexes (random access in Foxglove; about twice the size)",
    )
    p.add_argument(
        "--reorder-window",
        type=float,
        default=None,
        metavar="SEC",
        help="text and python-can logs: how far (log time) a frame may lag behind an earlier line and "
        "still be put in time order (default 10; 0 = sort the whole log in memory)",
    )
    p.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="replay the LOGs on a local dask.distributed cluster of N worker processes",
    )
    p.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDR",
        help="replay the LOGs on an existing dask.distributed scheduler (tcp://host:8786); its workers "
        "must see the LOGs, the outputs and lde under the same paths",
    )
    p.add_argument(
        "--learned",
        type=Path,
        metavar="FILE",
        help="what the estimator learned about this car: read at start when FILE exists (checked against "
        "the vehicle and profile), written at the end; several LOGs pass it on in the given order "
        "(one after the other: not with --jobs / --scheduler)",
    )
    p.add_argument(
        "--smooth",
        action="store_true",
        help="also the non-causal RTS-smoothed estimate for analysis (CSV columns Fw_smooth, Mw_smooth, "
        "Fw_wind_smooth, Mw_wind_smooth, bank_deg_smooth; MCAP topic /lde/smooth): the float lateral "
        "filter run forward over the same inputs and grid, then backward; backends float and fixed",
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no summary on stderr")
    p.set_defaults(func=run)
    return p


def _out_names(logs: list[Path]) -> dict[Path, str]:
    """Output base name per log: its stem (``x`` of ``x.log`` and of ``x.log.gz``), or
    ``<stem>_<suffix>`` where stems collide."""

    def plain(p: Path) -> Path:
        return Path(p.stem) if p.suffix.lower() == ".gz" else p

    stems = [plain(p).stem for p in logs]
    out = {}
    for p in logs:
        q = plain(p)
        suffix = "_".join(x.lstrip(".") for x in (q.suffix, p.suffix if q is not p else "") if x)
        out[p] = f"{q.stem}_{suffix}" if stems.count(q.stem) > 1 and suffix else q.stem
    return out


def _out_path(opt: Path | None, name: str, suffix: str, many: bool) -> Path | None:
    """The output file of one log (nothing is created here)."""
    if opt is None:
        return None
    if many or opt.is_dir():
        return opt / f"{name}{suffix}"
    return opt


def _same_file(a: Path, b: Path) -> bool:
    """True if ``a`` and ``b`` name one file: the same resolved path, or (both existing) the same
    inode (a hard link, a bind mount)."""
    if a.resolve() == b.resolve():
        return True
    try:
        return a.exists() and b.exists() and a.samefile(b)
    except OSError:
        return False


def _check_paths(logs: list[Path], outputs: list[tuple[str, Path]], many: bool = False) -> None:
    """ConfigError (nothing read or written yet) for a LOG given twice, an output that is a LOG,
    two outputs that are one file, or an output in a missing directory (with several LOGs the
    output directory itself is created, its parent must exist)."""
    for i, a in enumerate(logs):
        for b in logs[:i]:
            if _same_file(a, b):
                raise ConfigError(f"LOG {a} is given twice (also as {b}): give each log once")
    for i, (opt, out) in enumerate(outputs):
        d = out.parent
        if not d.is_dir() and not (many and d.parent.is_dir()):
            raise ConfigError(f"{opt} {out}: no such directory {d if not many else d.parent}")
        for log in logs:
            if _same_file(out, log):
                raise ConfigError(f"{opt} {out} is the input log {log}: it would be overwritten")
        for opt2, out2 in outputs[:i]:
            if _same_file(out, out2):
                raise ConfigError(f"{opt} {out} and {opt2} {out2} are the same file: give two names")


def _summary(rep) -> str:
    """The summary of one replay (``rep``: its :class:`lde.replay.fleet.LogReport`), ending with the files
    it wrote."""
    causes = ", ".join(f"{k} {v}" for k, v in rep.rejected_by_cause.items() if v) or "none"
    not_read = f"; not read: {', '.join(rep.not_read)}" if rep.not_read else ""
    lines = [
        f"{rep.log}: {rep.format}, {rep.frames} frames, {rep.steps} steps = {rep.duration_s:.3f} s stepped"
        f" in {rep.segments} segment{'' if rep.segments == 1 else 's'}"
        f" ({'recorded step times' if rep.recorded_steps else 'grid from the first MDPS frame'})",
        f"  frames used {rep.used}, rejected {rep.rejected} ({causes}), re-synchronising {rep.resync},"
        f" ignored ids {rep.ignored}, lde's own {rep.tx}{not_read}",
        f"  profile {rep.profile}"
        f"{' (from the recording)' if rep.profile_origin == 'recording' else ''},"
        f" backend {rep.backend};"
        f" took {rep.seconds:.3f} s ("
        + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in rep.timings.items())
        + ")",
    ]
    if rep.buses:  # a log that names its buses: where the inputs came from
        on = sorted(set(rep.buses.values()))
        other = f"; {rep.other_bus} frames of them on other buses not used" if rep.other_bus else ""
        lines.append(f"  input messages read from bus {', '.join(on)}{other}")
    if rep.learned:
        lines.append(f"  learned (from {rep.learned_origin or 'the vehicle file'}): {rep.learned}")
    if rep.steps == 0:
        lines.append(
            "  note: no estimator step: the log has no accepted frame of the profile's anchor (MDPS) message"
        )
    if rep.written:
        lines.append("  wrote " + ", ".join(f"{what} {path}" for what, path in rep.written))
    return "\n".join(lines)


def _nothing_written_note(args: argparse.Namespace) -> str | None:
    """What a replay without ``--csv`` / ``--mcap`` did not write, and how to write it."""
    if args.csv is not None or args.mcap is not None:
        return None
    what = "the estimates were not written" if args.learned is not None else "nothing written"
    return (
        f"lde replay: {what} (no --csv or --mcap given): add --csv OUT.csv for a table of the estimates "
        "(columns: lde replay --help) and/or --mcap OUT.mcap for a recording (Foxglove); with several "
        "LOGs give directories"
    )


def _outputs_note(args: argparse.Namespace, reports: list) -> str | None:
    """With several LOGs: where their outputs went (the directories and how many files each)."""
    n = sum(1 for r in reports if r.ok)
    files = "file" if n == 1 else "files"
    parts = [f"{n} {kind} {files} in {d}" for kind, d in (("CSV", args.csv), ("MCAP", args.mcap)) if d]
    return f"lde replay: wrote {' and '.join(parts)}" if parts and n else None


@contextlib.contextmanager
def _signals_stop() -> Iterator[list[signal.Signals]]:
    """SIGINT and SIGTERM stop a replay in process after the piece it is on: its outputs are
    closed (complete, readable files of the steps so far), the logs after it are not replayed; the
    list yielded names the signal. A second signal interrupts at once (KeyboardInterrupt: the
    outputs of the running replay are then removed). The previous handlers are restored."""
    stopped: list[signal.Signals] = []

    def on_signal(signum: int, frame: FrameType | None) -> None:
        if stopped:
            raise KeyboardInterrupt
        stopped.append(signal.Signals(signum))

    old = {}
    if threading.current_thread() is threading.main_thread():
        old = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stopped
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def run(args: argparse.Namespace) -> int:
    if args.learned is not None and (args.jobs is not None or args.scheduler is not None):
        # one file read at the start and written at the end of each log: parallel jobs would race
        raise ConfigError(
            f"--learned {args.learned} with --{'jobs' if args.jobs is not None else 'scheduler'}: "
            "one learned file is passed from log to log in the given order; replay without "
            "--jobs / --scheduler"
        )
    with _gc_off() as resume:
        return _run(args, resume)


@contextlib.contextmanager
def _gc_off() -> Iterator[Callable[[], None]]:
    """The collector off until ``resume()``, which freezes what the start-up made; unfrozen at the
    end. The imports and numba's kernel loads make ~10^5 long-lived objects: collecting while they
    were made, and walking them in every full collection after, took 0.1-0.2 s of a warm start."""
    was_enabled = gc.isenabled()
    gc.disable()

    def resume() -> None:
        gc.freeze()
        if was_enabled:
            gc.enable()

    try:
        yield resume
    finally:
        gc.unfreeze()
        if was_enabled:
            gc.enable()


def _run(args: argparse.Namespace, resume_gc: Callable[[], None]) -> int:
    from lde.can.profiles import load_profile
    from lde.io import REORDER_WINDOW_NS
    from lde.params import load_vehicle
    from lde.replay.fleet import ReplayJob, run_jobs, summary_table
    from lde.replay.replay import resolve_backend

    logs = [Path(p) for p in args.logs]
    if args.reorder_window is not None and not args.reorder_window >= 0:
        raise ConfigError(f"--reorder-window {args.reorder_window}: give seconds >= 0")
    if args.jobs is not None and args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs}: give 1 or more")
    window = (
        REORDER_WINDOW_NS
        if args.reorder_window is None
        else (None if args.reorder_window == 0 else int(round(args.reorder_window * 1e9)))
    )
    many = len(logs) > 1
    for opt in (args.csv, args.mcap):
        if many and opt is not None and opt.exists() and not opt.is_dir():
            raise ConfigError(f"with several LOGs, {opt} must be a directory")
    _check_paths(logs, [])
    names = _out_names(logs)
    if len(set(names.values())) < len(names):
        raise ConfigError("several LOGs would write the same output file: give them different names")
    outs = {
        p: (_out_path(args.csv, names[p], ".csv", many), _out_path(args.mcap, names[p], ".mcap", many))
        for p in logs
    }
    planned = [(opt, o) for c, m in outs.values() for opt, o in (("--csv", c), ("--mcap", m)) if o]
    _check_paths(logs, planned, many)
    # the options are checked here once (each job loads them again where it runs)
    if args.profile is not None:
        for line in load_profile(args.profile).notes() if not args.quiet else ():
            print(f"lde replay: note: {line}", file=sys.stderr)
    vehicle = args.vehicle or "reference"
    if Path(vehicle).suffix.lower() == ".toml" or Path(vehicle).exists():
        vehicle = str(Path(vehicle).resolve())
    load_vehicle(vehicle)
    backend = resolve_backend(args.backend)
    resume_gc()  # the imports are done; the replay runs with the collector as usual
    if args.smooth:
        from lde.replay.smoother import check_backend

        check_backend(backend)
        if args.csv is None and args.mcap is None:
            raise ConfigError("--smooth writes its columns to --csv and/or --mcap: give one")
        if backend != "float" and not args.quiet:
            print(
                f"lde replay: note: --smooth with backend {backend}: the *_smooth columns are the float "
                "lateral filter's, smoothed (the smoother is float analysis); the other columns are "
                f"the {backend} backend's",
                file=sys.stderr,
            )
    if many:
        for opt in (args.csv, args.mcap):
            if opt is not None:
                try:
                    opt.mkdir(parents=True, exist_ok=True)
                except OSError as exc:
                    raise ConfigError(f"{opt}: cannot create the output directory: {exc}") from exc

    def absolute(p: Path | None) -> Path | None:
        return None if p is None else p.resolve()

    learned = absolute(args.learned)

    profile = args.profile
    if profile is not None and Path(profile).is_file():  # a profile file: the jobs may run elsewhere
        profile = str(Path(profile).resolve())
    jobs = [
        ReplayJob(
            log=p.resolve(),
            csv=absolute(outs[p][0]),
            mcap=absolute(outs[p][1]),
            profile=profile,
            vehicle=vehicle,
            backend=backend,
            use_recorded_steps=not args.no_recorded_steps,
            reorder_window_ns=window,
            mcap_index=args.mcap_index,
            learned=learned,
            smooth=args.smooth,
        )
        for p in logs
    ]
    on_dask = args.scheduler is not None or (args.jobs is not None and (args.jobs > 1 or many))
    # a bar only on a terminal: its carriage returns would land in a file or a pipe
    show_bar = (many or on_dask) and not args.quiet and sys.stderr.isatty()

    def report(rep) -> None:
        lines = [f"lde replay: warning: {rep.log}: {w}" for w in rep.warnings]  # even with -q
        if not args.quiet and rep.ok:
            lines.append(_summary(rep))
        if rep.error and many:  # said once, here (the table marks the log "error")
            lines.append(f"lde: error: {rep.error_line}")
        for text in lines:
            if show_bar:
                from tqdm import tqdm

                tqdm.write(text, file=sys.stderr)
            else:
                print(text, file=sys.stderr)

    with _signals_stop() as stopped:
        if on_dask:  # distributed is imported only here: ~0.5 s of start-up
            from lde.replay.fleet_dask import ClusterConfig, run_jobs_on_dask

            cfg = ClusterConfig(scheduler=args.scheduler, n_workers=args.jobs or 2)
            reports = run_jobs_on_dask(
                jobs, cfg, progress=show_bar, on_report=report, stop=lambda: bool(stopped)
            )
        else:
            reports = run_jobs(jobs, progress=show_bar, on_report=report, stop=lambda: bool(stopped))
    if stopped:
        left = len(jobs) - len(reports)
        rest = f"; {left} log{'s' if left > 1 else ''} not replayed" if left else ""
        print(f"lde replay: stopped by {stopped[0].name}{rest}", file=sys.stderr)
        return 128 + int(stopped[0])
    notes = [] if args.quiet else [n for n in (_nothing_written_note(args),) if n]
    if not many:
        if reports[0].error:
            raise LdeError(reports[0].error)
        for text in notes:
            print(text, file=sys.stderr)
        return 0 if reports[0].usable else EXIT_NOTHING_USABLE
    if not args.quiet:
        print(summary_table(reports), file=sys.stderr)
        notes += [n for n in (_outputs_note(args, reports),) if n]
        for text in notes:
            print(text, file=sys.stderr)
    if any(not r.ok for r in reports):
        return 2
    return 0 if all(r.usable for r in reports) else EXIT_NOTHING_USABLE
