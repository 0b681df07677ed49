"""Parameter studies and accuracy evaluations on Dask (issues 6 and 11): specs -> runs -> CSV + PNG.

A study is a list of :class:`RunSpec` (scenario, seed, simulated vehicle + payload, estimator
vehicle, typed simulator and estimator options). Each spec runs independently on a worker
(:func:`run_one`: simulate with :mod:`vcan_sim`, estimate, score with :mod:`lde.analysis.metrics`) and
returns a :class:`RunResult`; :func:`run_specs` maps the specs on a ``dask.distributed`` cluster
with a tqdm progress bar. A run that fails is a row with its error message (a sweep must survive
one bad case); the CLI exits non-zero when any row failed.

Modules, one idea each:

- :mod:`~lde.analysis.study.spec`: :class:`RunSpec`, :class:`SimOptions`, :class:`EstOptions`,
  :class:`RunResult`, :class:`Estimate`;
- :mod:`~lde.analysis.study.execute`: simulate + estimate + score (:func:`run_one`), in process;
- :mod:`~lde.analysis.study.runner`: the Dask runner (:func:`run_specs`, :class:`ClusterConfig`);
- :mod:`~lde.analysis.study.presets`: the paper's study, ``lde evaluate``'s set, the ladder, the faults;
- :mod:`~lde.analysis.study.zoo`: the zoo evaluation (cars the estimator was not fitted to) and its tables;
- :mod:`~lde.analysis.study.specsheet`: the spec-sheet vehicle file of a car;
- :mod:`~lde.analysis.study.tires`: Fig. 12 tire identification;
- :mod:`~lde.analysis.study.tables`: rankings, pivot tables, CSV and text tables;
- :mod:`~lde.analysis.study.plots`: matplotlib ``Figure`` plots (no global backend change).

The core package (``lde.params``, ``lde.replay.replay``, ``lde.estimator.paper``, ...) never imports this
package or
:mod:`vcan_sim`; the study and the CLI sit above it.
"""

from __future__ import annotations

from typing import Any

from lde.analysis.study.execute import (
    CALIBRATION_SEED_OFFSET,
    MAX_STEERING_WHEEL,
    SIM_OPTION_FIELDS,
    TRACE_DECIMATION,
    Engine,
    check_plant,
    default_engine,
    run_one,
    simulate_and_estimate,
    synthetic_engine,
)
from lde.analysis.study.presets import (
    CANDIDATES,
    EVALUATE_SCENARIOS,
    FAULT_CASES,
    PAPER_SCENARIOS,
    TARGET_SCENARIOS,
    all_payloads,
    candidate_specs,
    evaluation_specs,
    fault_specs,
    ladder_specs,
    preset_specs,
)
from lde.analysis.study.runner import ClusterConfig, run_specs
from lde.analysis.study.spec import (
    SPEC_SHEET,
    SPEC_SHEET_LOADED,
    Estimate,
    Estimator,
    EstOptions,
    OptionValue,
    RunResult,
    RunSpec,
    SimOptions,
)
from lde.analysis.study.tables import (
    TABLE_COLUMNS,
    CandidateScore,
    pivot_markdown,
    rank_candidates,
    scores_table,
    table,
    write_csv,
    write_scores_csv,
)
from lde.analysis.study.tires import (
    TireIdentification,
    identify_curvature,
    identify_tires,
    representative_tires,
    write_tire_vehicle,
)

#: the former private name of :func:`check_plant`
_check_plant = check_plant

_PLOTS = ("plot_error_index", "plot_traces", "plot_tires")

__all__ = [
    "CALIBRATION_SEED_OFFSET",
    "CANDIDATES",
    "EVALUATE_SCENARIOS",
    "FAULT_CASES",
    "MAX_STEERING_WHEEL",
    "PAPER_SCENARIOS",
    "SIM_OPTION_FIELDS",
    "SPEC_SHEET",
    "SPEC_SHEET_LOADED",
    "TABLE_COLUMNS",
    "TARGET_SCENARIOS",
    "TRACE_DECIMATION",
    "CandidateScore",
    "ClusterConfig",
    "Engine",
    "EstOptions",
    "Estimate",
    "Estimator",
    "OptionValue",
    "RunResult",
    "RunSpec",
    "SimOptions",
    "TireIdentification",
    "all_payloads",
    "candidate_specs",
    "check_plant",
    "default_engine",
    "evaluation_specs",
    "fault_specs",
    "identify_curvature",
    "identify_tires",
    "ladder_specs",
    "pivot_markdown",
    "preset_specs",
    "rank_candidates",
    "representative_tires",
    "run_one",
    "run_specs",
    "scores_table",
    "simulate_and_estimate",
    "synthetic_engine",
    "table",
    "write_csv",
    "write_scores_csv",
    "write_tire_vehicle",
    *_PLOTS,
]


def __getattr__(name: str) -> Any:  # the plots import matplotlib: only when used
    if name in _PLOTS:
        from lde.analysis.study import plots

        return getattr(plots, name)
    raise AttributeError(f"module 'lde.analysis.study' has no attribute {name!r}")
