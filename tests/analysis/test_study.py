"""lde.analysis.study: the Dask sweep machinery, summaries and outputs (synthetic engine, no simulator)."""

from __future__ import annotations

import csv

import pytest

from lde.analysis import study
from lde.analysis.study import ClusterConfig, RunSpec


def test_local_cluster_runs_four_specs_in_order(tmp_path):
    specs = study.candidate_specs(
        scenarios=("heavy", "light"), candidates=("est1", "est3"), seeds=(0,), trace_candidate="est1"
    )
    assert len(specs) == 4
    res = study.run_specs(specs, ClusterConfig(n_workers=2), engine=study.synthetic_engine, progress=False)
    assert [r.spec for r in res] == specs  # order kept although futures complete in any order
    assert all(r.ok for r in res), [r.error for r in res]
    # the synthetic engine's moment error grows with |lf - 1.071 m|: est1 (1.07 m) beats est3
    ranking = study.rank_candidates(res)
    assert [s.candidate for s in ranking] == ["est1", "est3"]
    assert ranking[0].n_runs == 2
    out = study.write_csv(res, tmp_path / "runs.csv")
    rows = list(csv.DictReader(out.open()))
    assert len(rows) == 4 and {"nrmse_fw", "nrmse_mw", "J_N", "error"} <= set(rows[0])
    assert study.plot_error_index(ranking, tmp_path / "j.png").stat().st_size > 1000
    assert study.plot_traces(res, tmp_path / "tr.png").stat().st_size > 1000


def test_failed_run_becomes_a_row_not_an_exception():
    specs = [RunSpec("heavy", est_vehicle="no-such-vehicle"), RunSpec("light", est_vehicle="est2")]
    res = study.run_specs(specs, ClusterConfig(n_workers=0), engine=study.synthetic_engine, progress=False)
    assert not res[0].ok and "no-such-vehicle" in res[0].error
    assert res[1].ok
    assert study.rank_candidates(res)[0].candidate == "est2"
    assert "no-such-vehicle" in study.table(res)


def test_unreachable_scheduler_is_a_clear_error():
    from lde.errors import LdeError

    with pytest.raises(LdeError, match="scheduler"):
        study.run_specs(
            [RunSpec("heavy")],
            ClusterConfig(scheduler="tcp://127.0.0.1:9", connect_timeout=1.0),
            progress=False,
        )


def test_spec_label_and_row_carry_options():
    s = RunSpec("light", payload="rear", sim_options=(("friction_Nm", 0.6),), est_options=(("comp", 1),))
    assert s.label == "light/rear/reference/s0/friction_Nm=0.6/comp=1"
    row = study.RunResult(s, None, "boom").as_row()
    assert row["sim_options"] == "friction_Nm=0.6" and row["error"] == "boom"


def _acc(kind, f, m):
    from lde.analysis.metrics import Accuracy

    return Accuracy(kind, 100, f * 1000, m * 500, m * 500, 1000.0, 500.0, 500.0, f, m, m)


def test_pivot_markdown_means_over_seeds_and_marks_failures():
    from lde.analysis.metrics import Kind

    res = [
        study.RunResult(RunSpec("heavy_load", seed=0, group="A"), _acc(Kind.DISTURBED, 0.02, 0.04)),
        study.RunResult(RunSpec("heavy_load", seed=1, group="A"), _acc(Kind.DISTURBED, 0.04, 0.06)),
        study.RunResult(RunSpec("heavy_load", group="B"), None, "boom"),
        study.RunResult(RunSpec("lane_change", group="A"), _acc(Kind.UNDISTURBED, 0.016, 0.012)),
    ]
    text = study.pivot_markdown(res)
    lines = text.splitlines()
    assert lines[0] == "| scenario | A | B |"
    assert lines[2] == "| heavy_load | 3.0 / 5.0 | failed |"
    assert lines[3].startswith("| lane_change | 16 N / 6 Nm |")


def test_a_spinning_simulated_car_is_discarded():
    import numpy as np

    from lde.errors import LdeError
    from lde.units import DEG

    ok = {"delta_sw": np.array([0.0, 10 * DEG]), "vx": np.array([27.8, 27.5])}
    study._check_plant(ok)
    with pytest.raises(LdeError, match="lost control"):
        study._check_plant({"delta_sw": np.array([0.0, 400 * DEG]), "vx": np.array([27.8, 27.0])})
    with pytest.raises(LdeError, match="lost control"):
        study._check_plant({"delta_sw": np.array([0.0, 1 * DEG]), "vx": np.array([27.8, -3.0])})


def test_tire_vehicle_file_extends_the_candidate(tmp_path):
    from lde.params import load_vehicle

    p = study.write_tire_vehicle(tmp_path / "est3_fig12.toml", "est3", 61800.0, 55700.0, 7120.0, "note")
    v = load_vehicle(p)
    assert v.body.mass == load_vehicle("est3").body.mass
    assert (v.tires.cf, v.tires.cr, v.tires.align_rate) == (61800.0, 55700.0, 7120.0)


def test_ladder_and_fault_specs_cover_every_step():
    lad = study.ladder_specs("est3", "/x/est3_fig12.toml", seeds=(0, 1), curvature=(90.0, 200.0, 120.0))
    assert len(lad) == 8 * len(study.TARGET_SCENARIOS) * 2
    assert len({s.group for s in lad}) == 8
    assert any(dict(s.est_options).get("kappa_r") == 200.0 for s in lad)
    assert any(dict(s.est_options).get("payload_known") for s in lad)
    faults = study.fault_specs("est3", "/x/est3_fig12.toml", seeds=(0,))
    assert {s.group.split(" / ")[1] for s in faults} == {
        "not compensated",
        "learned corrections",
        "learned corrections and tires",
    }
    assert all(s.sim_options for s in faults)
    # the fault study measures the product (lde replay) with what `lde calibrate` writes
    assert {s.estimator for s in faults} == {"replay"}
    assert any(dict(s.est_options).get("calibrate_tires") == 0 for s in faults)


@pytest.mark.slow
def test_smoke_preset_runs_the_real_chain_in_process():
    """vcan_sim -> CAN frames -> decode -> grid -> step -> metrics, 4 short runs (no cluster)."""
    pytest.importorskip("vcan_sim")
    specs = study.preset_specs("smoke", seeds=(0,), duration=8.0)
    assert len(specs) == 4
    res = study.run_specs(specs, ClusterConfig(n_workers=0), progress=False)
    assert all(r.ok for r in res), [r.error for r in res]
    for r in res:
        a = r.accuracy
        assert a is not None and a.n > 1000
        # the estimator follows the disturbance force (a broken chain gives ~100 % or NaN)
        assert a.nrmse_fw < 0.25, (r.spec.label, a.nrmse_fw)
    heavy = [r for r in res if r.spec.scenario == "heavy_load"]
    assert all(r.accuracy.scale_fw > 1000.0 for r in heavy)  # the heavy case really is heavy


def test_existing_scheduler_by_address():
    from distributed import LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        specs = study.candidate_specs(scenarios=("heavy",), candidates=("est1", "est2"), seeds=(0,))
        res = study.run_specs(
            specs,
            ClusterConfig(scheduler=lc.scheduler_address),
            engine=study.synthetic_engine,
            progress=False,
        )
    assert [r.spec for r in res] == specs and all(r.ok for r in res)
