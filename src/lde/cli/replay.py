"""``lde replay LOG... [--profile P] [--vehicle FILE] [--backend fixed|float] [--csv OUT] [--mcap OUT]``.

Replays CAN logs (MCAP, candump ``-L``, or any python-can format; each also gzip-compressed, as
``x.log.gz``) through the estimator on the 3.9 ms grid and writes one CSV row per step (``t`` in the
log's own time base) and/or an MCAP recording. A short summary goes to stderr. With several LOGs,
``--csv`` / ``--mcap`` name directories (one ``<log stem>.csv`` / ``.mcap`` each, the stem without
``.gz``) and a progress bar shows.

Before anything is read or written, the outputs are checked: a LOG given twice (by any spelling of
its path) is an error, and so is an output that is one of the LOGs or another output (an output never
overwrites an input).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from ..errors import ConfigError
from . import BACKEND_CHOICES

#: a log larger than this gets a progress bar even alone [bytes]
_LARGE_LOG = 50 << 20


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "replay",
        help="replay CAN logs through the estimator (CSV / MCAP out)",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
    )
    p.add_argument(
        "logs", nargs="+", metavar="LOG", help="MCAP, candump -L text, ASC, BLF, TRC, CSV, ... (also as .gz)"
    )
    p.add_argument(
        "--profile",
        default=None,
        help="CAN profile: lde, hyundai or a .dbc path (default: the one an lde recording names, else lde)",
    )
    p.add_argument("--vehicle", default=None, help="vehicle TOML file or shipped name (default: reference)")
    p.add_argument(
        "--backend",
        choices=BACKEND_CHOICES,
        default=None,
        help="estimator step: fixed-point firmware model or float (default: fixed when available)",
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
        "--learned",
        type=Path,
        metavar="FILE",
        help="what the estimator learned about this car: read at start when FILE exists (checked against "
        "the vehicle and profile), written at the end; several LOGs pass it on in the given order",
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


def _summary(path: Path, log, res, elapsed: float) -> str:
    f = res.frames
    causes = ", ".join(f"{k} {v}" for k, v in res.frames.rejected_by_cause().items() if v) or "none"
    skipped = log.stats
    extra = []
    for name in ("error_frames", "remote_frames", "malformed_lines", "truncated_last_line", "bad_messages"):
        v = getattr(skipped, name)
        if v:
            extra.append(f"{v} {name.replace('_', ' ')}")
    lines = [
        f"{path}: {log.format}, {f.total} frames, {len(res)} steps = {res.duration_s:.3f} s stepped"
        f" in {res.segments} segment{'' if res.segments == 1 else 's'}"
        f" ({'recorded step times' if res.recorded_steps else 'grid from the first MDPS frame'})",
        f"  frames used {f.used}, rejected {f.rejected} ({causes}), re-synchronising {f.resync},"
        f" ignored ids {f.ignored}, lde's own {f.tx}" + (f"; not read: {', '.join(extra)}" if extra else ""),
        f"  profile {res.profile.name if res.profile else '?'}"
        f"{' (from the recording)' if res.profile_origin == 'recording' else ''},"
        f" backend {res.backend};"
        f" took {elapsed:.3f} s (" + ", ".join(f"{k} {v * 1e3:.0f} ms" for k, v in res.timings.items()) + ")",
    ]
    if getattr(res, "learned", ""):
        start = getattr(res, "learned_origin", "") or "the vehicle file"
        lines.append(f"  learned (from {start}): {res.learned}")
    if len(res) == 0:
        lines.append(
            "  note: no estimator step: the log has no accepted frame of the profile's anchor (MDPS) message"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from ..params import load_vehicle
    from ..profiles import load_profile
    from ..replay import (
        CsvWriter,
        RecordingWriter,
        no_valid_note,
        profile_metadata,
        read_inputs,
        resolve_backend,
        run_replay,
    )

    logs = [Path(p) for p in args.logs]
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
    profile = load_profile(args.profile) if args.profile is not None else None
    profiles: dict = {}  # profiles named by recordings, loaded once
    vehicle = load_vehicle(args.vehicle or "reference")
    backend, _fn, note = resolve_backend(args.backend)
    if note and not args.quiet:
        print(f"lde replay: note: {note}", file=sys.stderr)
    if many:
        for opt in (args.csv, args.mcap):
            if opt is not None:
                try:
                    opt.mkdir(parents=True, exist_ok=True)
                except OSError as exc:
                    raise ConfigError(f"{opt}: cannot create the output directory: {exc}") from exc
    bar = None
    if many or any(p.is_file() and p.stat().st_size > _LARGE_LOG for p in logs):
        from tqdm import tqdm

        bar = tqdm(total=len(logs), unit="log", disable=args.quiet or None, file=sys.stderr)
    for path in logs:
        t0 = time.perf_counter()
        li = read_inputs(path, profile, use_recorded_steps=not args.no_recorded_steps, profiles=profiles)
        log = li.log
        csv_path, mcap_path = outs[path]
        sinks: list = []
        if csv_path is not None:
            sinks.append(CsvWriter(csv_path))
        if mcap_path is not None:
            meta = {
                "source": str(path),
                **profile_metadata(li.profile),
                "vehicle": vehicle.name,
                "backend": backend,
            }
            sinks.append(RecordingWriter(mcap_path, li.profile, meta))
        try:
            res = run_replay(
                log.frames,
                li.profile,
                vehicle,
                backend,
                sinks=tuple(sinks),
                step_times_ns=li.step_times_ns,
                tx_frames=li.tx_frames,
                overlay_enable=li.overlay_enable,
                extra_status=li.extra_status,
                output_frames=mcap_path is not None,
                learned=args.learned,
                learned_start=li.learned_start,
            )
        finally:
            for sink in sinks:
                sink.close()
        res.timings = {"read": li.read_s, **res.timings}
        res.profile, res.profile_origin = li.profile, li.profile_origin
        elapsed = time.perf_counter() - t0
        if bar is not None:
            bar.update(1)
        warn = no_valid_note(res)
        if warn:  # shown even with -q: the CSV is all zeros
            text = f"lde replay: warning: {path}: {warn}"
            if bar is not None:
                bar.write(text, file=sys.stderr)
            else:
                print(text, file=sys.stderr)
        if not args.quiet:
            text = _summary(path, log, res, elapsed)
            if bar is not None:
                bar.write(text, file=sys.stderr)
            else:
                print(text, file=sys.stderr)
    if bar is not None:
        bar.close()
    return 0
