"""Plots are matplotlib Figure objects: they never select a backend for their caller (no
``matplotlib.use``) and leave nothing in pyplot."""

from __future__ import annotations

import subprocess
import sys
import textwrap


def test_plots_leave_the_callers_backend_and_pyplot_alone(tmp_path):
    code = textwrap.dedent(
        f"""
        import sys
        import matplotlib
        matplotlib.use("pdf")  # the caller's choice
        import numpy as np
        from lde.analysis.plots import plot_demo
        from lde.analysis import study
        from lde.analysis.metrics import Accuracy, Kind
        from lde.analysis.study import CandidateScore, RunResult, RunSpec, TireIdentification

        t = np.linspace(0.0, 5.0, 50)
        run = {{k: np.sin(t) for k in ("fw_hat", "fw_true", "mw_hat", "mw_true", "driver_torque",
                                       "lateral_position", "t_overlay", "speed")}}
        run["t"] = t
        plot_demo(run, run, r"{tmp_path}/demo.png")
        scores = [CandidateScore("est1", 2, 100.0, 80.0, 20.0, 0.05, 0.06)]
        study.plot_error_index(scores, __import__("pathlib").Path(r"{tmp_path}/j.png"))
        trace = {{k: np.sin(t) for k in ("t", "fw_hat", "mw_hat", "fw", "mw", "mw_ref")}}
        acc = Accuracy(Kind.DISTURBED, 50, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0.1, 0.1, 0.1)
        study.plot_traces([RunResult(RunSpec("x"), acc, trace=trace)],
                          __import__("pathlib").Path(r"{tmp_path}/tr.png"))
        study.plot_tires([TireIdentification("heavy", 6e4, 5e4, 7e3, 6e4, 5e4, 0.01)],
                         __import__("pathlib").Path(r"{tmp_path}/tires.png"))
        print(matplotlib.get_backend(), "matplotlib.pyplot" in sys.modules)
        """
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["pdf", "False"]
    for name in ("demo.png", "j.png", "tr.png", "tires.png"):
        assert (tmp_path / name).stat().st_size > 1000
