"""A cold first run compiles on both cores: a helper process compiles part of the data path.

numba compiles a kernel in the process that first calls it, one kernel after the other: a first
``lde replay`` on an empty cache (:mod:`lde.jitcache`) used one core for 20-35 s. The kernels of a
backend's step are independent of one another until the step that joins them, and the data-path
loop's own parts (:mod:`lde.engine.loop`: ``feed_frame``, ``sample_inputs``, ``step_outputs``, and the
constructor of its fixed arrays) do not depend on the step at all: :func:`compile_split` starts
``lde.coldstart BACKEND`` in a new Python (the helper), which compiles its share (:data:`HELPER`) into
the on-disk cache and says so on its stdout (``ready NAME``), while this process compiles the rest
(:data:`MAIN`), waiting for a helper group just before the first of its own that needs it (numba
then loads it from the cache: it looks there before it compiles). The loop, compiled next by the
run itself, then finds its step and its parts compiled and only types their calls. After its
share the helper compiles the filters' resets and the CSV formatter (:mod:`lde.io`), which the
run needs later. The shares are balanced by the CPU seconds of each group
(``scripts/compile_profile.py``; docs/startup.md).

The helper is a plain child process: when it fails, dies or takes longer than ``timeout_s`` this
process stops waiting (and ends the helper) and compiles each group it would have waited for
itself, where it would have waited (not inside the joining step: numba would compile the firmware's
kernels there with the step's flags, without reference counting, and the coefficient set, which
allocates, fails to type: a cold ``fixed`` run crashed so). numba writes a cache entry with an
atomic rename, so a kernel is either complete in the cache or absent.

Signatures: a kernel compiled ahead must have exactly the argument types the caller gives it, else
the caller compiles it again. They are written out here (:func:`state_types`) from the backend
states' layouts (:func:`lde.engine.backends.make_backend_state`; ``tests/test_coldstart.py`` checks them
against real states) and the step's own unpacking (:func:`lde.engine.backends.lateral_fixed_step`).
"""

from __future__ import annotations

import atexit
import json
import os
import select
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = [
    "EARLY_NAMES",
    "HELPER",
    "MAIN",
    "REPLAY_ONLY",
    "SplitReport",
    "compile_split",
    "helper_main",
    "last_split",
    "start_helper",
    "state_types",
]

#: the helper's share per backend, in its order (each name is a group of :data:`_GROUPS`)
HELPER: dict[str, tuple[str, ...]] = {
    "fixed": ("fx-step", "resets", "loop-out", "loop-sample", "csv"),
    "float": ("learner", "resets", "loop-out", "csv"),
}
#: the helper's groups that only a replay needs (``lde run`` and ``lde demo`` write no CSV)
REPLAY_ONLY = frozenset({"csv"})
#: this process's share, in its order: groups of :data:`_GROUPS`, and ``wait NAME`` (wait for the
#: helper's group NAME, which the next ones need: the joining step its callees, the loop's
#: arguments and loop its parts). The helper's resets come before the last group waited for: the
#: run makes its backend state (which calls them) right after (they were compiled here in a race).
MAIN: dict[str, tuple[str, ...]] = {
    "fixed": (
        "float-step",
        "learner",
        "parse",
        "loop-feed",
        "loop-args",
        "wait fx-step",
        "join",
        "wait loop-out",
        "wait loop-sample",
    ),
    "float": (
        "float-step",
        "parse",
        "loop-args",
        "loop-feed",
        "loop-sample",
        "wait learner",
        "join",
        "wait loop-out",
    ),
}
#: ``--backend`` as given (None: the default) to the backend it names, for the backends with a split
#: (checked against :func:`lde.engine.backends.get_backend` by the tests; the CLI starts the helper before
#: it imports the registry)
EARLY_NAMES: dict[str | None, str] = {None: "fixed", "fixed": "fixed", "float": "float", "lateral": "float"}
_WAIT = "wait "
#: the helper's command: this process's ``sys.path`` first (``python -m`` would put the working
#: directory first: in a checkout it imported ``firmware_model`` from there while this process had
#: the installed one, and compiled into a cache this process never reads)
_HELPER_CODE = (
    "import json, sys; sys.path[:] = json.loads(sys.argv.pop(1)); "
    "from lde.coldstart import helper_main; sys.exit(helper_main(sys.argv[1:]))"
)


def _types() -> Any:
    from numba import types as T

    return T, T.float64[::1], T.float64[:, ::1], T.int64[::1], T.int64[:, ::1]


def state_types(backend: str) -> tuple[Any, Any]:
    """numba types of ``(params, state)`` of :func:`lde.engine.backends.make_backend_state` for
    ``backend`` (``fixed`` or ``float``), without making the state (that compiles kernels)."""
    T, f1, f2, i1, i2 = _types()
    if backend == "fixed":
        bp = T.Tuple((f1, i1, i1, f1, f1))  # lp, tv, ft, lsb, bound
        bs = T.Tuple((
            f1, i1, i1, i1, i1, i1, i2, i1,  # p, cs, x, P, aux, sat, ws, iout
            f1, f2, f1, i1, f1, f1, f1, f1,  # fx, fP, ffs, fints, fh, fph, fout, shadow
            f1, f2,  # ls, lws
        ))  # fmt: skip
        return bp, bs
    if backend == "float":
        return T.UniTuple(f1, 1), T.Tuple((f1, f1, f2, f1, i1, f1, f1, f1, f2))
    raise ValueError(f"no split compile for backend {backend!r}")


def _float_step() -> None:
    from lde.estimator import lateral as E

    T, f1, f2, i1, _ = _types()
    f, b = T.float64, T.boolean
    E.step_kernel.compile((f1, f1, f2, f1, i1, f1, f1, T.int64, f, f, f, f, f, f, b, b, b, b, b, f1))


def _learner() -> None:
    from lde.estimator import learner as Ln

    T, f1, f2, _, _ = _types()
    f = T.float64
    Ln.learner_step.compile((f1, f1, f2, f1, f1, f, f, f, f, f, f, f, T.boolean))


def _fx_step() -> None:
    from firmware_model import lateral as FX

    T, f1, _, i1, i2 = _types()
    f = T.float64
    q_args = (i1, f, f, f, f, f, f)
    FX.quantise_kernel.compile(q_args)
    sig = next(s for s in FX.quantise_kernel.nopython_signatures if tuple(s.args) == q_args)
    rets = tuple(sig.return_type)  # (v, s, y, c, a, q, flags) as the step unpacks them
    b = T.boolean
    FX.step_kernel.compile((i1, i1, i1, i1, i1, i1, i1, i2, T.int64, *rets, b, b, b, b, b, i1))
    FX.coef_set_kernel.compile((f1, i1, i1))


def _resets() -> None:
    """The filters' resets, which making a backend state calls (both backends' float filter, the
    fixed one's integer filter)."""
    from firmware_model import lateral as FX
    from lde.estimator import lateral as E

    _, f1, f2, i1, _ = _types()
    E.reset_kernel.compile((f1, f1, f2, f1, i1))
    FX.reset_kernel.compile((i1, i1, i1, i1, i1))


def _parse() -> None:
    from lde.io import open_log

    with tempfile.TemporaryDirectory(prefix="lde-coldstart-") as tmp:
        log = Path(tmp) / "x.log"
        log.write_text("(0.000000) can0 123#0011223344556677\n(0.001000) can0 1ABCDEF0#01\n")
        with open_log(log) as s:
            list(s)


def _csv() -> None:
    import numpy as np

    from lde.io.textfmt import EXACT, Column, format_rows, time_column

    cols = [time_column("t", np.arange(3) * 1000), Column("x", np.linspace(0, 1, 3), EXACT)]
    format_rows(cols, ["", ","], "\n")


def _join(backend: str) -> None:
    from numba import types as T

    from lde.engine import backends as B

    bp, bs = state_types(backend)
    f1 = T.float64[::1]
    step = B.lateral_fixed_step if backend == "fixed" else B.lateral_step
    # as the loop calls it (lde.engine.loop: fresh and the flags as sample_inputs returns them)
    step.compile((bp, bs, T.int64, f1, T.int64, T.boolean, T.boolean, f1))


def loop_fields() -> tuple[Any, ...]:
    """The loop's fixed arrays (:data:`lde.engine.loopargs.FIELDS`) as :meth:`lde.engine.engine.Engine.reset`
    makes them, for the ``lde`` profile and the reference vehicle: the loop's arguments and parts
    are compiled for their numba types, which are the same for every profile and vehicle
    (``tests/test_coldstart.py`` checks them against real engines)."""
    import numpy as np

    from lde.can.profiles import load_profile
    from lde.engine.engine import OutputTable
    from lde.engine.receiver import RxState, RxTables
    from lde.estimator.overlay import limiter_params, new_limiter_state
    from lde.params import load_vehicle

    profile = load_profile("lde")
    tables = RxTables.of(profile)
    outputs = OutputTable.of(profile)
    lsi, lsf = new_limiter_state()
    return (
        tables.kernel_args(),
        outputs.args,
        RxState.initial(tables).kernel_args(),
        np.full(1, np.iinfo(np.int64).min, np.int64),
        limiter_params(load_vehicle("reference")),
        lsi,
        lsf,
        np.zeros(len(outputs.names), np.int64),
        np.zeros(1, np.int64),
    )


def _loop_args() -> None:
    """The constructor of the loop's fixed arrays (:func:`lde.engine.loopargs.loop_arrays`)."""
    from lde.engine import loopargs

    loopargs._new.compile(_part_types())


def _part_types() -> tuple[Any, ...]:
    from numba import typeof

    return tuple(typeof(v) for v in loop_fields())


def _loop_arrays_type() -> Any:
    """The numba type of the loop's :class:`lde.engine.loopargs.LoopArrays` (its fields' types)."""
    from lde.engine.loopargs import FIELDS, LoopArraysType

    return LoopArraysType(list(zip(FIELDS, _part_types(), strict=True)))


def _loop_feed() -> None:
    """The loop's receiver part per frame (:func:`lde.engine.loop.feed_frame`), for the argument
    types the loop (:func:`lde.engine.loop.make_loop`) calls it with."""
    from numba import types as T

    from lde.engine import loop as P

    i8, b, i1 = T.int64, T.boolean, T.int64[::1]
    P.feed_frame.compile((_loop_arrays_type(), i1, i8, i8, b, i8, T.uint8[::1], i8))


def _loop_sample() -> None:
    """The loop's receiver part per step (:func:`lde.engine.loop.sample_inputs`), as :func:`_loop_feed`."""
    from numba import types as T

    from lde.engine import loop as P

    P.sample_inputs.compile((_loop_arrays_type(), T.int64, T.float64[::1], T.int64[::1]))


def _loop_out() -> None:
    """The loop's output part (:func:`lde.engine.loop.step_outputs`: overlay, finalisation, encoders)."""
    from numba import types as T

    from lde.engine import loop as P

    i8, b, f1 = T.int64, T.boolean, T.float64[::1]
    P.step_outputs.compile((_loop_arrays_type(), i8, f1, i8, b, f1, b, T.uint8[:, ::1], f1, f1))


_GROUPS: dict[str, Callable[[], None]] = {
    "fx-step": _fx_step,
    "float-step": _float_step,
    "learner": _learner,
    "resets": _resets,
    "parse": _parse,
    "csv": _csv,
    "loop-args": _loop_args,
    "loop-feed": _loop_feed,
    "loop-sample": _loop_sample,
    "loop-out": _loop_out,
}


@dataclass
class SplitReport:
    """What :func:`compile_split` did (seconds from its start)."""

    backend: str
    helper_pid: int | None = None
    main_s: dict[str, float] = field(default_factory=dict)  # this process's groups: when each ended
    helper_s: dict[str, float] = field(default_factory=dict)  # the helper's: when this process heard
    helper_cpu: dict[str, float] = field(default_factory=dict)  # the helper's CPU seconds by then
    main_cpu_at_wait: float = 0.0  # this process's CPU seconds when it began to wait (the first time)
    waits: dict[str, float] = field(default_factory=dict)  # seconds this process waited for each group
    waited_s: float = 0.0  # this process waiting for the helper, in all
    helper_failed: str = ""  # why this process stopped waiting (empty: it did not)
    total_s: float = 0.0


class _Helper:
    """The helper process and its ``ready NAME`` lines."""

    def __init__(self, backend: str, t0: float, argv: list[str] | None = None) -> None:
        self.backend = backend
        self.t0 = t0
        self.ready: dict[str, float] = {}  # group: when this process heard it [s from t0]
        self.ready_cpu: dict[str, float] = {}  # group: the helper's CPU seconds by then
        self.proc = subprocess.Popen(
            argv or [sys.executable, "-c", _HELPER_CODE, json.dumps(sys.path), backend],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            env=dict(os.environ),
        )
        self._buf = b""
        atexit.register(self.stop)  # a run that ends (or fails) before the helper does ends it

    def wait_for(self, name: str, deadline: float) -> str:
        """Until the helper says ``ready name``: '' then, else why not (it ended, or the deadline)."""
        assert self.proc.stdout is not None
        fd = self.proc.stdout.fileno()
        while name not in self.ready:
            left = deadline - time.perf_counter()
            if left <= 0:
                self.stop()
                return "timed out"
            r, _, _ = select.select([fd], [], [], min(left, 1.0))
            if not r:
                continue
            chunk = os.read(fd, 4096)
            if not chunk:
                rc = self.proc.wait()
                return f"it ended (rc {rc}) before {name}"
            self._buf += chunk
            *lines, self._buf = self._buf.split(b"\n")
            for line in lines:
                word = line.decode(errors="replace").split()
                if len(word) >= 2 and word[0] == "ready":
                    self.ready[word[1]] = time.perf_counter() - self.t0
                    if len(word) == 3:
                        self.ready_cpu[word[1]] = float(word[2])
        return ""

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()


def start_helper(backend: str | None, live: bool = False) -> _Helper | None:
    """Start the helper for ``--backend`` as given (:data:`EARLY_NAMES`; None for a backend without
    a split, or when the process cannot be started). Cheap: call it before the heavy imports.
    ``live``: for a command that writes no CSV (``lde run``, ``lde demo``): the helper leaves out
    the CSV formatter (:data:`REPLAY_ONLY`)."""
    name = EARLY_NAMES.get(backend)
    if name is None:
        return None
    numba = sys.modules.get("numba")
    if numba is not None and os.environ.get("NUMBA_CACHE_DIR", "") != numba.config.CACHE_DIR:
        return None  # NUMBA_CACHE_DIR changed since numba read it: the helper would cache elsewhere
    try:
        argv = [sys.executable, "-c", _HELPER_CODE, json.dumps(sys.path), name, *(["--live"] if live else [])]
        return _Helper(name, time.perf_counter(), argv)
    except OSError:
        return None


def _reads_candump(logs: Sequence[Path]) -> bool:
    """Whether any of ``logs`` is a candump text log (the parser this process compiles ahead)."""
    from lde.errors import LogFormatError
    from lde.io import detect_format

    for p in logs:
        try:
            if detect_format(p).startswith("candump"):
                return True
        except LogFormatError:
            pass  # the run reports it
    return False


def compile_split(
    backend: str, helper: _Helper | None = None, timeout_s: float = 300.0, logs: Sequence[Path] | None = None
) -> SplitReport:
    """Compile ``backend``'s step on two processes (module docstring) with ``helper`` (started by
    :func:`start_helper`; a new one when None or started for another backend); the caller then
    runs as usual; ``logs`` (None: assume candump): the candump parser is compiled ahead only when
    one of them is a candump log. A backend without a split (``paper``, ``paper-fixed``) returns
    at once. The helper keeps running after this returns (the resets, the CSV formatter) and exits
    by itself."""
    t0 = time.perf_counter()
    rep = SplitReport(backend)
    if helper is not None and helper.backend != backend:
        helper.stop()
        helper = None
    if backend not in HELPER:
        return rep
    if helper is None:
        helper = start_helper(backend)
        if helper is None:
            rep.helper_failed = "not started"
    if helper is not None:
        rep.helper_pid = helper.proc.pid
        t0 = helper.t0
    from numba.core.event import install_recorder

    started = helper
    with install_recorder("numba:compile") as rec:
        for name in MAIN[backend]:
            if not name.startswith(_WAIT):
                if name == "parse" and logs is not None and not _reads_candump(logs):
                    continue
                if name == "join":
                    _join(backend)
                else:
                    _GROUPS[name]()
                rep.main_s[name] = time.perf_counter() - t0
                continue
            group = name[len(_WAIT) :]
            if helper is not None and not rep.waits and not rec.buffer:
                helper.stop()  # all loaded: this process's cache was warm after all
                rep.helper_failed = "not needed (the cache was warm)"
                helper = None
            if helper is None:
                # compiled here, before the group that needs it: numba would otherwise compile the
                # firmware's kernels inside the joining step, with its flags (no reference counting:
                # the coefficient set, which allocates, then fails to type)
                _GROUPS[group]()
                continue
            t_wait = time.perf_counter()
            if not rep.waits:
                rep.main_cpu_at_wait = time.process_time()
            why = helper.wait_for(group, t0 + timeout_s)
            rep.waits[group] = time.perf_counter() - t_wait
            if why:  # given up on: compiled here, as above
                rep.helper_failed = why
                helper = None
                _GROUPS[group]()
    rep.waited_s = sum(rep.waits.values())
    if started is not None:
        rep.helper_s = dict(started.ready)
        rep.helper_cpu = dict(started.ready_cpu)
    rep.total_s = time.perf_counter() - t0
    global _LAST
    _LAST = (rep, started)
    return rep


_LAST: tuple[SplitReport, _Helper | None] | None = None


def last_split() -> tuple[SplitReport, subprocess.Popen[bytes] | None] | None:
    """The last :func:`compile_split` of this process: its report and the helper process (for
    ``scripts/compile_profile.py``), or None."""
    if _LAST is None:
        return None
    rep, helper = _LAST
    return rep, None if helper is None else helper.proc


def helper_main(argv: list[str]) -> int:
    """The helper: compile this backend's :data:`HELPER` groups, ``ready NAME`` after each
    (``--live``: not those of :data:`REPLAY_ONLY`)."""
    live = argv[1:] == ["--live"]
    if not (len(argv) == 1 or live) or argv[0] not in HELPER:
        print(f"usage: python -m lde.coldstart {{{','.join(HELPER)}}} [--live]", file=sys.stderr)
        return 2
    from lde.lazyblas import defer_blas_import

    defer_blas_import()  # as lde replay: numba's BLAS check without importing scipy.linalg
    for name in HELPER[argv[0]]:
        if live and name in REPLAY_ONLY:
            continue
        _GROUPS[name]()
        print(f"ready {name} {time.process_time():.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(helper_main(sys.argv[1:]))
