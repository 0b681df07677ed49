"""The zoo evaluation: spec sheets, typed study options, the cli engine (what a user runs), warm mode's
missing prerequisite, the per-plant table and the summary lines, ``lde evaluate --zoo``."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from lde.analysis import metrics
from lde.analysis.study import EstOptions, RunResult, RunSpec, SimOptions, zoo
from lde.analysis.study.specsheet import SPEC_SHEET_KEYS, spec_sheet_vehicle
from lde.cli import main
from lde.cli import replay_in_process as cli_engine
from lde.errors import ConfigError
from lde.params import load_vehicle
from vcan_sim import zoo as vcan_zoo

# --- spec sheets ------------------------------------------------------------------------------------


@pytest.mark.parametrize("plant", ["indep_twin", "loaded_twin", "suv_slow"])
def test_spec_sheet_gives_only_the_sheet_and_the_generic_defaults(tmp_path, plant):
    car = vcan_zoo.load_plant(plant)
    est = spec_sheet_vehicle(car, tmp_path)
    ref = load_vehicle("reference")
    # what a spec sheet gives: the car's (unloaded) body and steering ratio
    assert est.body == car.body
    assert est.steering.ratio == car.steering.ratio
    assert {k for _, k, _, _ in SPEC_SHEET_KEYS} == {
        "mass_kg",
        "yaw_inertia_kgm2",
        "lf_m",
        "lr_m",
        "track_front_m",
        "track_rear_m",
        "ratio",
    }
    # everything else the estimator reads is the shipped generic default, nothing from the plant
    assert est.tires == ref.tires and est.tires != car.tires
    assert est.estimator == ref.estimator
    assert est.overlay == ref.overlay
    assert est.corrections == ref.corrections and est.corrections.is_identity


def test_reference_tires_are_labelled_generic():
    from pathlib import Path

    text = Path(load_vehicle("reference").source).read_text()
    assert "generic mid-size-sedan" in text
    assert "not in the zoo" in text


# --- typed options ------------------------------------------------------------------------------------


def test_options_are_typed_and_iterate_as_pairs():
    s = RunSpec(
        "light_load",
        sim_options=(("friction_Nm", "0.6"), ("speed_kmh", 90)),
        est_options=(("calibrate", "lane_change"), ("calibrate_tires", 0), ("steering_friction_Nm", 0.3)),
    )
    assert isinstance(s.sim_options, SimOptions) and s.sim_options.friction_Nm == 0.6
    assert s.sim_options.speed_kmh == 90.0
    assert isinstance(s.est_options, EstOptions)
    assert s.est_options.calibrate == "lane_change" and s.est_options.calibrate_tires is False
    assert s.est_options.corrections == (("steering_friction_Nm", 0.3),)
    want = {"calibrate": "lane_change", "calibrate_tires": 0, "steering_friction_Nm": 0.3}
    assert dict(s.est_options) == want
    assert dict(s.sim_options) == {"friction_Nm": 0.6, "speed_kmh": 90.0}
    with pytest.raises(ConfigError, match="known"):
        SimOptions.parse([("frcition_Nm", 0.6)], strict=True)
    with pytest.raises(ConfigError, match="expected a number"):
        SimOptions.parse([("friction_Nm", "a lot")])
    with pytest.raises(ConfigError, match="0/1"):
        EstOptions.parse([("payload_known", 2)])


def test_unknown_option_fails_its_run_not_the_sweep():
    from lde.analysis.study import ClusterConfig, run_specs

    res = run_specs(
        [RunSpec("lane_change", duration=3.0, sim_options=(("warp_factor", 9),))],
        ClusterConfig(n_workers=0),
        progress=False,
    )
    assert not res[0].ok and "warp_factor" in res[0].error and "friction_Nm" in res[0].error


# --- the cli engine: what a user runs -------------------------------------------------------------------


def _zoo_spec(tmp_path, **kw):
    args = dict(
        scenario="wind_step",
        est_vehicle="spec-sheet",
        sim_vehicle="zoo:indep_twin",
        duration=10.0,
        estimator="cli",
        backend="fixed",
        work_dir=str(tmp_path / "runs"),
    )
    args.update(kw)
    return RunSpec(**args)


def test_cli_engine_scores_exactly_the_users_replay(tmp_path):
    """The engine's CSV is byte for byte what `lde replay LOG --profile P --backend B --vehicle
    SPEC_SHEET --csv OUT` writes, and its score is the metric of that CSV against the truth."""
    from lde.analysis.study.execute import run_one

    spec = _zoo_spec(tmp_path, profile="hyundai")
    res = run_one(spec, cli_engine.engine)
    assert res.ok, res.error
    d = tmp_path / "runs" / "indep_twin" / "hyundai-fixed" / "wind_step-s0"
    assert {p.name for p in d.iterdir()} == {"drive.log", "truth.csv", "spec_sheet.toml", "estimate.csv"}
    out = tmp_path / "mine.csv"
    argv = ["replay", str(d / "drive.log"), "--profile", "hyundai", "--backend", "fixed"]
    assert main(argv + ["--vehicle", str(d / "spec_sheet.toml"), "--csv", str(out), "-q"]) == 0
    assert out.read_bytes() == (d / "estimate.csv").read_bytes()
    e = cli_engine.read_estimate_csv(out)
    t, fw, mw, status = e.t, e.fw, e.mw, e.status
    truth = np.genfromtxt(d / "truth.csv", delimiter=",", names=True)
    acc = metrics.accuracy(
        t,
        fw,
        mw,
        metrics.Truth(truth["t"], truth["Fw"], truth["Mw"], truth["Mw_ref"]),
        valid=(status & 1) != 0,
    )
    assert acc.nrmse_fw == pytest.approx(res.accuracy.nrmse_fw, rel=1e-3)
    assert acc.nrmse_mw == pytest.approx(res.accuracy.nrmse_mw, rel=1e-3)
    # the estimate follows the 12 m/s crosswind step (a broken chain gives ~100 %)
    assert res.accuracy.kind is metrics.Kind.DISTURBED and res.accuracy.nrmse_fw < 0.5
    # wind apart from bank and the learner's state come from the same CSV's columns
    assert e.fw_wind is not None and e.bank is not None and e.learn_state is not None
    assert res.extra["learn_state"] == e.learn_state[-1]
    assert math.isfinite(res.extra["wind_nrmse"]) and math.isfinite(res.extra["bank_rms_deg"])


def test_cli_engine_reports_lde_errors_as_a_failed_run(tmp_path):
    from lde.analysis.study.execute import run_one

    res = run_one(
        _zoo_spec(tmp_path, est_vehicle=str(tmp_path / "missing.toml"), work_dir=""), cli_engine.engine
    )
    assert not res.ok and "exited with 2" in res.error and "vehicle file not found" in res.error


def test_warm_mode_learns_on_the_prior_drive_then_replays_with_it(tmp_path, monkeypatch):
    """Warm: `lde replay PRIOR --learned S` (no CSV) writes S, then `lde replay LOG --learned S --csv
    OUT` starts from it. Both real CLI runs, the float backend."""
    calls = []
    real = cli_engine.run_cli

    def spy(argv):
        calls.append(list(argv))
        return real(argv)

    monkeypatch.setattr(cli_engine, "run_cli", spy)
    (spec,) = zoo.zoo_specs(
        ["indep_twin"], scenarios=("wind_step",), profiles=("lde",), backends=("float",), mode=zoo.Mode.WARM
    )
    assert spec.est_options.learned_prior == zoo.PRIOR_SCENARIO
    from lde.analysis.study.execute import run_one

    res = run_one(RunSpec(**{**spec.__dict__, "duration": 8.0, "work_dir": str(tmp_path)}), cli_engine.engine)
    assert res.ok, res.error
    prior, run = calls
    d = tmp_path / "indep_twin" / "lde-float" / "wind_step-s0-warm"
    assert prior[:2] == ["replay", str(d / "prior.log")] and "--csv" not in prior
    assert prior[prior.index("--learned") + 1] == str(d / "learned")
    assert run[:2] == ["replay", str(d / "drive.log")]
    assert run[run.index("--learned") + 1] == str(d / "learned")
    assert run[run.index("--csv") + 1] == str(d / "estimate.csv")
    for argv in (prior, run):
        assert argv[argv.index("--vehicle") + 1] == str(d / "spec_sheet.toml")
    learned = json.loads((d / "learned").read_text())
    assert learned["format"] == "lde-learned" and learned["drives"] >= 1
    assert res.accuracy is not None and math.isfinite(res.accuracy.nrmse_fw)


def test_evaluate_refuses_an_unknown_backend(capsys, tmp_path):
    code = main(["evaluate", "--zoo", "--backends", "nope", "--plants", "indep_twin", "--out", str(tmp_path)])
    assert code == 2
    assert "unknown backend 'nope'" in capsys.readouterr().err


# --- tables and summary -----------------------------------------------------------------------------------


def _acc(kind, f, m, m_true=None, rms=(0.0, 0.0)):
    m_true = m if m_true is None else m_true
    return metrics.Accuracy(kind, 100, rms[0], rms[1], rms[1], 1000.0, 500.0, 500.0, f, m_true, m)


def _res(plant, scenario, acc, profile="lde", backend="fixed"):
    spec = RunSpec(
        scenario,
        est_vehicle="spec-sheet",
        sim_vehicle=f"zoo:{plant}",
        estimator="cli",
        backend=backend,
        profile=profile,
        group=plant,
    )
    return RunResult(spec, acc, "" if acc is not None else "boom")


def test_plant_table_and_summary():
    D, U = metrics.Kind.DISTURBED, metrics.Kind.UNDISTURBED
    results = [
        _res("indep_twin", "wind_step", _acc(D, 0.05, 0.08)),
        _res("indep_twin", "lane_change", _acc(U, math.nan, math.nan, rms=(65.0, 8.0))),
        _res("loaded_twin", "wind_step", _acc(D, 0.06, 0.12, m_true=0.07)),
        _res("loaded_twin", "lane_change", None),
        _res("indep_twin", "wind_step", _acc(D, 0.2, 0.02), profile="hyundai"),
    ]
    md = zoo.plant_table_markdown(results, backend="fixed", extras=False).splitlines()
    assert md[0] == "| plant | profile | wind_step | lane_change | met |"
    assert md[2] == "| indep_twin | lde | 5.0 / 8.0 | **65 N / 8 Nm** | 1/2 |"
    # Mw about the spec sheet's CG decides; the payload plant shows Mw about the true CG in brackets
    assert md[3] == "| loaded_twin | lde | **6.0 / 12.0 (7.0)** | **failed** | 0/2 |"
    assert md[4] == "| indep_twin | hyundai | **20.0 / 2.0** |  | 0/1 |"
    rows = zoo.plant_table_rows(results)
    assert rows[1]["wind_step_mw"] == 0.12 and rows[1]["wind_step_mw_true_cg"] == 0.07
    assert rows[0]["targets_met"] == 1 and rows[0]["runs"] == 2
    lines = zoo.summary_lines(results)
    assert lines[0].startswith("cold, crosswind/bank scenarios, NRMSE <= 10 % Fw and Mw")
    assert "met in 1 of 3 runs" in lines[0]
    assert "worst Fw 20.0 % (indep_twin, wind_step, hyundai, fixed)" in lines[0]
    assert "worst Mw 12.0 % (loaded_twin, wind_step, lde, fixed)" in lines[0]
    assert lines[1].startswith("cold, disturbance-free drive, RMS <= 60 N / 20 Nm: met in 0 of 1 runs")
    assert "1 run(s) failed" in lines[2]


def test_zoo_specs_cover_the_product_of_the_selection():
    specs = zoo.zoo_specs(["indep_twin", "suv_slow"], scenarios=("wind_step", "lane_change"))
    assert len(specs) == 2 * 2 * 2 * 2
    assert {(s.profile, s.backend) for s in specs} == {
        ("lde", "fixed"),
        ("lde", "float"),
        ("hyundai", "fixed"),
        ("hyundai", "float"),
    }
    assert all(s.estimator == "cli" and s.est_vehicle == "spec-sheet" for s in specs)
    with pytest.raises(ConfigError, match="no_such"):
        zoo.zoo_specs(["no_such"])
    with pytest.raises(ConfigError, match="scenario"):
        zoo.zoo_specs(["indep_twin"], scenarios=("no_such_drive",))


@pytest.mark.slow
def test_lde_evaluate_zoo_end_to_end(tmp_path, capsys):
    out = tmp_path / "zoo"
    argv = ["evaluate", "--zoo", "--plants", "compact_quick", "--scenarios", "wind_step,lane_change"]
    argv += ["--profiles", "lde", "--backends", "fixed", "--duration", "10", "--workers", "0"]
    assert main(argv + ["--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "cold, crosswind/bank scenarios" in printed and "| compact_quick | lde |" in printed
    assert (out / "spec_sheets" / "compact_quick.toml").is_file()
    runs = list(csv.DictReader((out / "zoo_runs.csv").open()))
    # cold and warm by default, cold first
    assert [r["scenario"] for r in runs] == ["wind_step", "lane_change"] * 2
    assert [r["est_options"] for r in runs] == [
        "",
        "",
        "learned_prior=prior_drive",
        "learned_prior=prior_drive",
    ]
    assert all(r["error"] == "" for r in runs)
    assert all(r["learn_state"] in ("0", "1", "2") and r["bank_rms_deg"] for r in runs)
    assert runs[0]["wind_nrmse"] and not runs[1]["wind_nrmse"]  # the lane change has no wind
    table = list(csv.DictReader((out / "zoo_table.csv").open()))
    assert [(r["plant"], r["mode"]) for r in table] == [("compact_quick", "cold"), ("compact_quick", "warm")]
    assert float(table[0]["lane_change_fw"]) > 0 and len(table[1]["learn_states"]) == 2
    md = (out / "zoo_table.md").read_text()
    assert "Measured with `lde evaluate --zoo --plants compact_quick" in md
    assert "**Cold**" in md and "**Warm**" in md


def test_a_disturbance_free_scenario_is_scored_by_rms_whatever_the_aero_side_force():
    """A large car's own side slip makes ~20 N of aero side force on a lane change; the run is still
    scored as disturbance-free (RMS), not as an NRMSE over a 20 N maximum."""
    from lde.analysis.study import Estimate
    from lde.analysis.study.execute import run_one

    def engine(spec):
        t = np.arange(0.0, 10.0, 0.01)
        fw = 25.0 * np.sin(t)  # the aero side force of the car's side slip
        return Estimate(
            t, fw + 30.0, np.full_like(t, 5.0), np.ones(t.size, bool), metrics.Truth(t, fw, 0 * t, 0 * t)
        )

    res = run_one(RunSpec("lane_change"), engine=engine)
    assert res.accuracy.kind is metrics.Kind.UNDISTURBED
    assert res.accuracy.rms_fw == pytest.approx(30.0) and res.accuracy.rms_mw == pytest.approx(5.0)
    disturbed = run_one(RunSpec("wind_step"), engine=engine)
    assert disturbed.accuracy.kind is metrics.Kind.FORCE_ONLY  # decided from the truth (no moment)


# --- warm after other prior drives ------------------------------------------------------------------


def test_warm_runs_once_per_prior_and_an_unknown_prior_is_refused():
    specs = zoo.zoo_specs(
        ["indep_twin"],
        scenarios=("wind_step",),
        profiles=("lde",),
        backends=("float",),
        modes=(zoo.Mode.COLD, zoo.Mode.WARM),
        priors=("prior_drive", "slalom", "prior_drive"),
    )
    assert [s.est_options.learned_prior for s in specs] == [None, "prior_drive", "slalom"]
    with pytest.raises(ConfigError, match="unknown prior scenario.*no_such_drive"):
        zoo.zoo_specs(["indep_twin"], mode=zoo.Mode.WARM, priors=("no_such_drive",))
    # another prior keeps its own run directory
    names = {str(cli_engine.run_dir_name(s)) for s in specs}
    assert names == {
        "indep_twin/lde-float/wind_step-s0",
        "indep_twin/lde-float/wind_step-s0-warm",
        "indep_twin/lde-float/wind_step-s0-warm-slalom",
    }


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--prior", "no_such_drive"], "lde: error: unknown prior scenario(s) no_such_drive"),
        (["--modes", "cold", "--prior", "slalom"], "lde: error: --prior applies to warm runs"),
        (
            ["--prior", "slalom", "--readme", "README.md"],
            "lde: error: --readme/--doc write the full zoo table",
        ),
    ],
)
def test_evaluate_prior_errors_are_one_line(capsys, tmp_path, argv, message):
    code = main(["evaluate", "--zoo", "--plants", "indep_twin", "--out", str(tmp_path), *argv])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(message)


def test_evaluate_without_zoo_refuses_prior(capsys):
    assert main(["evaluate", "--prior", "slalom"]) == 2
    assert "--prior" in capsys.readouterr().err


def _warm(res, prior):
    spec = RunSpec(**{**res.spec.__dict__, "est_options": EstOptions(learned_prior=prior)})
    return RunResult(spec, res.accuracy, res.error)


def test_tables_and_summary_report_each_prior_apart():
    D = metrics.Kind.DISTURBED
    cold = _res("indep_twin", "wind_step", _acc(D, 0.06, 0.08))
    shipped = _warm(_res("indep_twin", "wind_step", _acc(D, 0.04, 0.03)), zoo.PRIOR_SCENARIO)
    slalom = _warm(_res("indep_twin", "wind_step", _acc(D, 0.09, 0.07)), "slalom")
    results = [slalom, cold, shipped]
    assert [zoo.mode_label(r) for r in results] == ["warm after slalom", "cold", "warm"]
    rows = zoo.plant_table_rows(results)
    assert [(r["mode"], r["prior"], r["targets_met"]) for r in rows] == [
        ("warm", "slalom", 0),
        ("cold", "", 1),
        ("warm", "prior_drive", 1),
    ]
    md = zoo.plant_table_markdown(results, extras=False).splitlines()
    assert md[0] == "| plant | profile | mode | wind_step | met |"
    assert md[2] == "| indep_twin | lde | warm after slalom | **9.0 / 7.0** | 0/1 |"
    lines = zoo.summary_lines(results)
    # cold, the shipped prior (as the README's lines have them), then the other prior
    assert lines[0].startswith("cold, crosswind/bank scenarios") and "met in 1 of 1" in lines[0]
    assert lines[1].startswith("warm, crosswind/bank scenarios, NRMSE <= 5 %") and "met in 1 of 1" in lines[1]
    assert lines[2].startswith("warm after slalom, crosswind/bank scenarios, NRMSE <= 5 %")
    assert "met in 0 of 1" in lines[2]
    # the shipped prior's lines do not change when another prior is run beside it
    assert zoo.summary_lines([cold, shipped]) == lines[:2]
    from lde.analysis.study import zooreport

    info = zooreport.RunInfo("cmd", 3, 1.0, 2, "m", 0.0, 0.0, "today")
    doc = zooreport.doc_block(results, info)
    assert doc.index("**Cold**") < doc.index("**Warm**") < doc.index("**Warm after slalom**")
