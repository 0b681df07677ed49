"""lde.coldstart: a cold first run's compile split over two processes (docs/startup.md)."""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from numba import typeof

from lde import coldstart as C
from lde.can.profiles import PROFILE_NAMES, load_profile
from lde.engine.backends import DEFAULT_BACKEND, get_backend, make_backend_state
from lde.engine.engine import Engine
from lde.engine.loopargs import FIELDS, LoopArraysType
from lde.params import load_vehicle

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("backend", sorted(C.HELPER))
def test_the_written_out_state_types_are_the_real_states(backend: str) -> None:
    """The signatures compiled ahead are built from these types: a layout change of a backend's
    state must show here (else the run compiles the step a second time)."""
    s = make_backend_state(backend, load_vehicle("reference"))
    assert C.state_types(backend) == (typeof(s.params), typeof(s.state))


@pytest.mark.parametrize("profile", PROFILE_NAMES)
@pytest.mark.parametrize("vehicle", ["reference", "est3"])
def test_the_loop_fields_have_the_types_of_a_real_engines(profile: str, vehicle: str) -> None:
    """The loop's arguments and parts are compiled ahead for these types: an engine of any shipped
    profile and vehicle must give the same (else its loop compiles them again)."""
    e = Engine(load_profile(profile), load_vehicle(vehicle), "float")
    assert typeof(e._la) == LoopArraysType(
        [(n, typeof(v)) for n, v in zip(FIELDS, C.loop_fields(), strict=True)]
    )


def test_the_early_names_resolve_as_the_registry() -> None:
    for given, name in C.EARLY_NAMES.items():
        assert get_backend(DEFAULT_BACKEND if given is None else given).name == name
    assert set(C.EARLY_NAMES.values()) == set(C.HELPER) == set(C.MAIN)


@pytest.mark.parametrize("backend", sorted(C.HELPER))
def test_every_wait_names_a_helper_group_compiled_before_it_is_needed(backend: str) -> None:
    helper, main = C.HELPER[backend], C.MAIN[backend]
    waits = [m.removeprefix("wait ") for m in main if m.startswith("wait ")]
    assert waits == [h for h in helper if h in waits]  # in the helper's order: no wait blocks a later one
    assert "join" in main and main.index("join") > main.index("wait " + helper[0])
    # the run makes its backend state (the resets) right after the split: compiled by then
    assert helper.index("resets") < helper.index(waits[-1])
    for g in (*helper, *main):
        assert g.startswith("wait ") or g == "join" or g in C._GROUPS


def _fake(code: str) -> C._Helper:
    return C._Helper("float", time.perf_counter(), [sys.executable, "-c", code])


def test_a_helper_that_dies_is_not_waited_for() -> None:
    h = _fake("import sys; print('ready csv', flush=True); sys.exit(3)")
    t0 = time.perf_counter()
    why = h.wait_for("learner", time.perf_counter() + 60)
    assert why == "it ended (rc 3) before learner" and "csv" in h.ready
    assert time.perf_counter() - t0 < 30  # bounded by the helper's exit, not the deadline


def test_a_helper_that_hangs_is_ended_at_the_deadline() -> None:
    h = _fake("import time; time.sleep(600)")
    why = h.wait_for("learner", time.perf_counter() + 1.0)
    assert why == "timed out" and h.proc.poll() is not None


def test_a_ready_line_split_across_reads_is_heard() -> None:
    h = _fake(
        "import sys, time; sys.stdout.write('rea'); sys.stdout.flush(); time.sleep(0.3); print('dy learner')"
    )
    assert h.wait_for("learner", time.perf_counter() + 60) == ""
    h.proc.wait()


@pytest.mark.parametrize("backend", sorted(C.HELPER))
def test_a_failed_helpers_groups_are_compiled_here_where_they_were_waited_for(
    backend: str, monkeypatch
) -> None:
    """The helper dies at once: each group this process would have waited for is compiled here in its
    place (before the joining step, which would otherwise compile the firmware's kernels itself)."""
    done: list[str] = []
    for g in C._GROUPS:
        monkeypatch.setitem(C._GROUPS, g, lambda g=g: done.append(g))
    monkeypatch.setattr(C, "_join", lambda b: done.append("join"))
    dead = C._Helper(backend, time.perf_counter(), [sys.executable, "-c", "import sys; sys.exit(1)"])
    rep = C.compile_split(backend, dead, logs=None)
    assert rep.helper_failed
    assert done == [m.removeprefix("wait ") for m in C.MAIN[backend]]


@pytest.mark.slow
def test_a_cold_fixed_split_without_its_helper_compiles(tmp_path: Path) -> None:
    """On an empty cache, with a helper that dies at once: the split compiles (on main at 4444421 the
    joining step compiled the coefficient set under its own flags and failed to type it)."""
    code = """
import sys, time
from lde import coldstart as C
h = C._Helper("fixed", time.perf_counter(), [sys.executable, "-c", "import sys; sys.exit(1)"])
rep = C.compile_split("fixed", h, logs=[])
print(rep.helper_failed)
"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "nb"), PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "it ended (rc 1)" in out.stdout


def test_the_split_goes_on_without_its_helper() -> None:
    """A helper that fails at once: this process compiles (or loads) everything itself."""
    from lde.engine.backends import lateral_step

    h = _fake("import sys; sys.exit(1)")
    rep = C.compile_split("float", h)
    assert rep.helper_failed in ("it ended (rc 1) before learner", "not needed (the cache was warm)")
    assert len(lateral_step.signatures) == 1


@pytest.mark.slow
def test_on_an_empty_cache_each_kernel_is_compiled_once(tmp_path: Path) -> None:
    """In a process with an empty cache, the split's groups, then the joining step and an engine's
    run (its loop): they find their callees compiled for exactly the signatures they call them
    with (no second compilation)."""
    code = """
import collections, sys
from numba.core import event
from lde import coldstart as C
names = collections.Counter()
class L(event.Listener):
    def on_start(self, ev): pass
    def on_end(self, ev): names[ev.data["dispatcher"].py_func.__qualname__] += 1
for g in ("fx-step", "float-step", "learner", "resets", "loop-args", "loop-feed", "loop-sample", "loop-out"):
    C._GROUPS[g]()
event.register("numba:compile", L())
C._join("fixed")
from lde.engine.engine import Engine
from lde.params import load_vehicle
from lde.can.profiles import load_profile
from vcan_sim.run import simulate
e = Engine(load_profile("lde"), load_vehicle("reference"), "fixed", shadow_thread=False)
e.feed(simulate("straight", seed=0, duration=0.3).frames, final=True)
print(dict(names))
"""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "nb"), PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    compiled = ast.literal_eval(out.stdout.strip().splitlines()[-1])
    assert compiled.get("lateral_fixed_step") == 1
    assert compiled.get("run_lateral_fixed") == 1
    for callee in (
        *("step_kernel", "learner_step", "quantise_kernel", "coef_set_kernel", "reset_kernel", "_new"),
        *("feed_frame", "sample_inputs", "step_outputs"),
    ):
        assert callee not in compiled, compiled


def test_no_helper_when_the_cache_dir_changed_after_numba_read_it(tmp_path: Path, monkeypatch) -> None:
    """numba reads NUMBA_CACHE_DIR once, at import: a helper started with another value (a test's
    monkeypatch) would compile into a cache this process never reads."""
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "elsewhere"))
    assert C.start_helper("float") is None
    assert C.start_helper("paper") is None  # no split for it at all


def test_the_live_helper_leaves_out_the_replays_groups(monkeypatch, capsys) -> None:
    done: list[str] = []
    for g in C._GROUPS:
        monkeypatch.setitem(C._GROUPS, g, lambda g=g: done.append(g))
    assert C.helper_main(["fixed", "--live"]) == 0
    assert done == [g for g in C.HELPER["fixed"] if g not in C.REPLAY_ONLY] and "csv" not in done
    heard = [line.split()[1] for line in capsys.readouterr().out.splitlines()]
    assert heard == done
    done.clear()
    assert C.helper_main(["fixed"]) == 0 and done == list(C.HELPER["fixed"])
    assert C.helper_main(["fixed", "--what"]) == 2 and C.helper_main(["paper"]) == 2


LIVE_EARLY = """
import sys
import lde.coldstart as C
def fake(backend, live=False):
    heavy = ("numba", "can", "lde.engine.engine", "lde.service.service", "lde.demo")
    heavy = [m for m in heavy if m in sys.modules]
    print("helper", backend, live, heavy, flush=True)
    sys.exit(0)
C.start_helper = fake
from lde.cli import main
main(sys.argv[1:])
"""


@pytest.mark.parametrize("cmd", [["demo", "--no-mcap", "--no-plot"], ["run", "-i", "virtual", "-c", "x"]])
def test_a_live_command_on_a_cold_cache_says_so_and_starts_the_helper_before_its_imports(
    cmd: list[str], tmp_path: Path
) -> None:
    """``lde demo`` and ``lde run`` on an empty cache: the notice first, then the helper of the split
    (for a live command), both before numba, python-can or the engine are imported."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "nb"), PYTHONPATH=f"{ROOT / 'src'}:{ROOT}")
    argv = [sys.executable, "-c", LIVE_EARLY, *cmd, "--backend", "float"]
    out = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stderr.startswith("lde: compiling the numba kernels"), out.stderr
    assert out.stdout.strip() == "helper float True []"


@pytest.mark.parametrize("cmd", ["demo", "run"])
def test_a_live_command_compiles_the_split_before_its_work(cmd: str, monkeypatch, capsys) -> None:
    """Cold (as the cache check says): the split's share of this process, with the helper, then the
    command's work (the demo; the service's bus); warm: neither the notice nor the split."""
    import lde.coldstart
    import lde.demo
    import lde.jitcache
    import lde.service.service
    from lde.cli import main
    from lde.errors import ConfigError

    calls: list[tuple[Any, ...]] = []

    def work(*a: Any, **k: Any) -> None:
        calls.append(("work",))
        raise ConfigError("stop here")

    monkeypatch.setattr(
        lde.coldstart, "start_helper", lambda b, live=False: calls.append(("helper", b, live))
    )
    monkeypatch.setattr(
        lde.coldstart, "compile_split", lambda b, h, logs=None: calls.append(("split", b, logs))
    )
    monkeypatch.setattr(lde.demo, "run_demo", work)
    monkeypatch.setattr(lde.service.service, "open_bus", work)
    argv = [cmd, "--backend", "fixed", *(["-i", "virtual"] if cmd == "run" else ["--no-mcap", "--no-plot"])]
    for warm in (False, True):
        calls.clear()
        monkeypatch.setattr(lde.jitcache, "is_warm", lambda warm=warm: warm)
        assert main(argv) == 2
        err = capsys.readouterr().err
        if warm:
            assert calls == [("work",)] and "compiling" not in err
        else:
            assert calls == [("helper", "fixed", True), ("split", "fixed", []), ("work",)]
            assert err.startswith("lde: compiling the numba kernels")


def test_the_helper_imports_from_this_processs_path_not_its_working_directory(tmp_path: Path) -> None:
    """The helper's command replaces its ``sys.path`` with the one given (this process's): a
    ``firmware_model`` in the working directory (a checkout) is not imported instead."""
    shadow = tmp_path / "lde"
    shadow.mkdir()
    (shadow / "__init__.py").write_text("raise SystemExit('imported from the working directory')\n")
    code = C._HELPER_CODE.replace("from lde.coldstart import helper_main", "import lde; print(lde.__file__)")
    code = code.replace("; sys.exit(helper_main(sys.argv[1:]))", "")
    out = subprocess.run(
        [sys.executable, "-c", code, json.dumps(sys.path)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert not out.stdout.strip().startswith(str(tmp_path))
