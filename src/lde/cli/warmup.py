"""``lde warmup [--parts fixed,float,...] [--jobs N] [--background]``: compile lde's numba kernels now.

A first run after an install or an upgrade compiles them (25-35 s of CPU per backend); after
``lde warmup`` the first ``lde replay``, ``lde run`` or ``lde demo`` starts warm. Run it once
after ``pip install`` (with ``--jobs 2`` on two cores; ``--background`` returns at once and leaves
the compiling to a detached process, e.g. in a post-install step).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from lde.errors import ConfigError

#: the parts of :data:`lde.warmup.PARTS` (named here so that ``lde --help`` imports no kernel; a test
#: checks they agree)
PART_NAMES = ("fixed", "float", "paper-fixed", "paper", "logio", "sim", "smooth")


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "warmup",
        help="compile the numba kernels ahead of time (once after an install)",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
    )
    p.add_argument(
        "--parts",
        default=None,
        help=f"comma-separated, of: {', '.join(PART_NAMES)} (the data path per backend, the log readers and "
        "writers, the simulator, the smoother; default: all)",
    )
    p.add_argument("--jobs", type=int, default=1, metavar="N", help="compile in N processes")
    p.add_argument(
        "--background",
        action="store_true",
        help="return at once; a detached process compiles (log: --log, default: lde-warmup.log, temp dir)",
    )
    p.add_argument("--log", type=Path, default=None, help="with --background: where its output goes")
    p.set_defaults(func=run)
    return p


def run(args: argparse.Namespace) -> int:
    from lde.jitcache import cache_dirs, is_warm

    print(f"lde warmup: compiling into {' or '.join(map(str, cache_dirs()))}", file=sys.stderr, flush=True)
    warm = is_warm()
    from lde.warmup import PARTS, warm_up

    parts = list(PARTS) if args.parts is None else [p.strip() for p in args.parts.split(",") if p.strip()]
    bad = [p for p in parts if p not in PARTS]
    if bad or not parts:
        raise ConfigError(f"--parts {args.parts}: choose from {', '.join(PARTS)}")
    if args.jobs < 1:
        raise ConfigError(f"--jobs {args.jobs}: give 1 or more")
    if args.background:
        return _detach(parts, args.jobs, args.log or Path(tempfile.gettempdir()) / "lde-warmup.log")
    t0 = time.perf_counter()
    for part, seconds in warm_up(parts, jobs=args.jobs):
        print(f"  {part}: {seconds:.1f} s", file=sys.stderr, flush=True)
    state = "were cached already" if warm else "compiled"
    print(
        f"lde warmup: done in {time.perf_counter() - t0:.1f} s (the data path's kernels {state})",
        file=sys.stderr,
    )
    return 0


def _detach(parts: list[str], jobs: int, log: Path) -> int:
    """Start ``lde warmup`` for ``parts`` in a new session (it survives this shell), output to ``log``."""
    argv = [sys.executable, "-m", "lde", "warmup", "--parts", ",".join(parts), "--jobs", str(jobs)]
    try:
        out = log.open("ab")
    except OSError as e:
        raise ConfigError(f"--log {log}: cannot write it ({e.strerror})") from None
    with out:
        proc = subprocess.Popen(
            argv,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=out,
            start_new_session=True,
            env=dict(os.environ),
        )
    print(
        f"lde warmup: compiling in the background (pid {proc.pid}, log {log}); commands started before it "
        "ends compile what they need themselves",
        file=sys.stderr,
    )
    return 0
