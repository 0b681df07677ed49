"""``lde warmup [--parts fixed,float,...] [--jobs N] [--background]``: compile lde's numba kernels now.

A first run after an install or an upgrade compiles the kernels it needs; after ``lde warmup`` the
first ``lde replay``, ``lde run`` or ``lde demo`` starts warm. Run it once after ``pip install``
(with ``--jobs 2`` on two cores; ``--background`` returns at once and leaves the compiling to a
detached process, e.g. in a post-install step). It also removes the kernels compiled for other
versions of lde's sources (lde.cli.kernels).
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


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser(
        "warmup",
        help="compile the numba kernels ahead of time (once after an install)",
        description=__doc__.split("\n\n")[1] if __doc__ else None,
    )
    p.add_argument(
        "--parts",
        default=None,
        help="comma-separated, of: a backend's name (its data path), logio (the log readers and writers), "
        "sim (the simulator), smooth (the smoother); default: all",
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
    from lde.cli.kernels import kernel_dir, prune_other_kernel_dirs

    where = os.environ.get("NUMBA_CACHE_DIR", "")
    ours = where == str(kernel_dir())  # the lde command's kernel directory (not a library's cache)
    print(f"lde warmup: compiling into {where or 'numba default cache'}", file=sys.stderr, flush=True)
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
    print(f"lde warmup: done in {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    if ours:
        for gone in prune_other_kernel_dirs(Path(where)):
            print(f"lde warmup: removed {gone} (kernels of other sources)", file=sys.stderr)
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
