"""The zoo table from one command: its columns, the targets per mode, the payload about both CGs, the
document markers and `lde evaluate --zoo`'s options for them (lde.analysis.study.zoo,
lde.analysis.study.zooreport)."""

from __future__ import annotations

import math

import pytest

from lde.analysis import metrics
from lde.analysis.study import SPEC_SHEET, SPEC_SHEET_LOADED, EstOptions, RunResult, RunSpec, zoo, zooreport
from lde.cli import main

pytest.importorskip("vcan_sim.zoo")

D, U = metrics.Kind.DISTURBED, metrics.Kind.UNDISTURBED


def _acc(kind, f, m_ref, m_true=None, rms=(0.0, 0.0)):
    """An Accuracy with NRMSE Fw ``f``, Mw about the unloaded CG ``m_ref`` and about the true CG
    ``m_true`` (fractions); ``rms`` = RMS Fw [N], Mw [Nm] of a disturbance-free drive."""
    m_true = m_ref if m_true is None else m_true
    return metrics.Accuracy(kind, 100, rms[0], rms[1], rms[1], 1000.0, 500.0, 500.0, f, m_true, m_ref)


def _res(plant, scenario, acc, *, warm=False, loaded=False, profile="lde", backend="fixed", **extra):
    spec = RunSpec(
        scenario,
        est_vehicle=SPEC_SHEET_LOADED if loaded else SPEC_SHEET,
        sim_vehicle=f"zoo:{plant}",
        estimator="cli",
        backend=backend,
        profile=profile,
        est_options=EstOptions(learned_prior=zoo.PRIOR_SCENARIO) if warm else EstOptions(),
        group=plant,
    )
    return RunResult(spec, acc, "" if acc is not None else "boom", extra=dict(extra))


def _results():
    return [
        _res(
            "indep_twin", "wind_step", _acc(D, 0.08, 0.04), wind_nrmse=0.07, bank_rms_deg=0.1, learn_state=0
        ),
        _res("indep_twin", "lane_change", _acc(U, math.nan, math.nan, rms=(50.0, 9.0)), bank_rms_deg=0.4),
        _res("indep_twin", "wind_step", _acc(D, 0.08, 0.04), warm=True, wind_nrmse=0.12, learn_state=2),
        _res(
            "indep_twin",
            "lane_change",
            _acc(U, math.nan, math.nan, rms=(15.0, 7.0)),
            warm=True,
            learn_state=1,
        ),
        _res("loaded_twin", "wind_step", _acc(D, 0.06, 0.09, m_true=0.30), learn_state=0),
        _res("loaded_twin", "wind_step", _acc(D, 0.07, 0.60, m_true=0.05), loaded=True, learn_state=0),
    ]


# --- the table's columns --------------------------------------------------------------------------------


def test_table_rows_carry_every_column():
    rows = zoo.plant_table_rows(_results())
    assert [(r["plant"], r["mode"]) for r in rows] == [
        ("indep_twin", "cold"),
        ("indep_twin", "warm"),
        ("loaded_twin", "cold"),
        ("loaded_twin + load", "cold"),
    ]
    cold = rows[0]
    per_scenario = [f"{sc}_{c}" for sc in ("wind_step", "lane_change") for c in ("fw", "mw")]
    per_scenario += [
        f"{sc}_{c}" for sc in ("wind_step", "lane_change") for c in ("wind", "bank_deg", "learn_state")
    ]
    summary = ["targets_met", "runs", "wind_met", "wind_runs", "wind_worst", "bank_met", "bank_runs"]
    summary += ["bank_worst_deg", "learn_states"]
    assert set(cold) == {"plant", "profile", "backend", "mode", "prior", *per_scenario, *summary}
    assert [r["prior"] for r in rows] == ["", zoo.PRIOR_SCENARIO, "", ""]
    assert cold["wind_step_fw"] == 0.08 and cold["wind_step_mw"] == 0.04
    assert (cold["lane_change_fw"], cold["lane_change_mw"]) == (50.0, 9.0)
    assert cold["wind_step_wind"] == 0.07 and math.isnan(cold["lane_change_wind"])
    assert (cold["wind_met"], cold["wind_runs"], cold["bank_met"], cold["bank_runs"]) == (1, 1, 1, 2)
    assert cold["bank_worst_deg"] == 0.4 and cold["learn_states"] == "0-"
    assert cold["targets_met"] == 2  # cold: 8 % within 10 %, 50 N / 9 Nm within 60 N / 20 Nm
    # a payload plant: Mw about both CGs, whichever the file states
    assert rows[2]["wind_step_mw"] == 0.09 and rows[2]["wind_step_mw_true_cg"] == 0.30
    assert rows[2]["wind_step_mw_unloaded_cg"] == 0.09
    assert rows[3]["wind_step_mw"] == 0.05 and rows[3]["wind_step_mw_unloaded_cg"] == 0.60


def test_markdown_table_columns_and_cells():
    md = zoo.plant_table_markdown(_results()).splitlines()
    head = "| plant | profile | mode | wind_step | lane_change | met |"
    assert md[0] == head + " wind <= 10 % | bank <= 0.3 deg | learn state |"
    assert md[1].count("---|") == 9
    assert (
        md[2]
        == "| indep_twin | lde | cold | 8.0 / 4.0 | 50 N / 9 Nm | 2/2 | 1/1 (7.0 %) | 1/2 (0.40 deg) | `0-` |"
    )
    # warm: 8 % misses 5 %, 15 N / 7 Nm meets 20 N / 8 Nm; the wind misses 10 %
    assert (
        md[3] == "| indep_twin | lde | warm | **8.0 / 4.0** | 15 N / 7 Nm | 1/2 | 0/1 (12.0 %) | - | `21` |"
    )
    # spec sheet: Mw about the unloaded CG decides (9 %), the true CG's in brackets
    assert md[4] == "| loaded_twin | lde | cold | 6.0 / 9.0 (30.0) |  | 1/1 | - | - | `0-` |"
    # with the load: Mw about the true CG decides (5 %), the unloaded CG's in brackets
    assert md[5] == "| loaded_twin + load | lde | cold | 7.0 / 5.0 (60.0) |  | 1/1 | - | - | `0-` |"


def test_each_run_is_held_to_its_own_target():
    """Cold 10 %; warm 5 %; warm 10 % on a hard scenario or a plant with defects."""
    rs = [
        _res("indep_twin", "wind_step", _acc(D, 0.08, 0.04)),
        _res("indep_twin", "wind_step", _acc(D, 0.08, 0.04), warm=True),
        _res("indep_twin", "curve_800m", _acc(D, 0.08, 0.04), warm=True),
        _res("sensor_offsets", "wind_step", _acc(D, 0.08, 0.04), warm=True),
        _res("indep_twin", "wind_step", _acc(D, 0.04, 0.11)),
    ]
    assert [zoo.target_of(r).name for r in rs] == [
        "cold",
        "warm",
        "warm, with defects",
        "warm, with defects",
        "cold",
    ]
    assert [zoo.meets(r) for r in rs] == [True, False, True, True, False]
    lines = zoo.summary_lines(rs)
    assert lines[0].startswith("cold, crosswind/bank scenarios, NRMSE <= 10 % Fw and Mw")
    assert (
        "met in 1 of 2 runs" in lines[0] and "worst Mw 11.0 % (indep_twin, wind_step, lde, fixed)" in lines[0]
    )
    assert (
        lines[1].startswith("warm, crosswind/bank scenarios, NRMSE <= 5 %")
        and "met in 0 of 1 runs" in lines[1]
    )
    assert lines[2].startswith("warm, with defects, crosswind/bank scenarios, NRMSE <= 10 %")
    assert "met in 2 of 2 runs" in lines[2]


def test_summary_counts_wind_bank_and_payload_about_both_cgs():
    lines = zoo.summary_lines(_results())
    assert "cold, wind force NRMSE <= 10 % (runs with wind): met in 1 of 1 runs; worst 7.0 %" in lines
    assert "cold, bank angle RMS <= 0.3 deg: met in 1 of 2 runs; worst 0.40 deg" in lines
    assert "warm, wind force NRMSE <= 10 % (runs with wind): met in 0 of 1 runs; worst 12.0 %" in lines
    # the run whose file carries the load is not counted against the spec-sheet targets
    cold = next(ln for ln in lines if ln.startswith("cold, crosswind"))
    assert "met in 2 of 2 runs" in cold
    (payload,) = zoo.payload_lines(_results())
    assert payload.startswith("cold, payload loaded_twin (mean NRMSE): spec sheet: Fw 6.0 %")
    assert "Mw about the unloaded CG 9.0 %, about the true CG 30.0 % (1 runs)" in payload
    assert "spec sheet + load: Fw 7.0 %, Mw about the unloaded CG 60.0 %, about the true CG 5.0 %" in payload


def test_backends_are_compared_run_by_run():
    rs = [
        _res("indep_twin", "wind_step", _acc(D, 0.08, 0.04, rms=(100.0, 20.0))),
        _res("indep_twin", "wind_step", _acc(D, 0.11, 0.04, rms=(100.5, 20.25)), backend="float"),
        _res("indep_twin", "lane_change", _acc(U, math.nan, math.nan, rms=(30.0, 9.0))),
        _res("indep_twin", "lane_change", _acc(U, math.nan, math.nan, rms=(30.0, 9.0)), backend="float"),
        _res("suv_slow", "lane_change", _acc(U, math.nan, math.nan, rms=(30.0, 9.0))),  # no pair
    ]
    (line,) = zoo.backend_lines(rs)
    assert line == (
        "backends fixed and float: any run's RMS error differs by at most 0.5 N (Fw) and 0.25 Nm (Mw) "
        "over 2 pairs of runs; the target verdict differs in 1"
    )


def test_zoo_specs_cold_and_warm_with_the_load_rows():
    specs = zoo.zoo_specs(["indep_twin", "loaded_twin"], scenarios=("wind_step",), modes=tuple(zoo.Mode))
    # 2 modes x (indep_twin 1 + loaded_twin 2 files) x 2 profiles x 2 backends
    assert len(specs) == 2 * 3 * 2 * 2
    loaded = [s for s in specs if s.est_vehicle == SPEC_SHEET_LOADED]
    assert len(loaded) == 8 and {s.group for s in loaded} == {"loaded_twin"}
    assert sum(s.est_options.learned_prior == zoo.PRIOR_SCENARIO for s in specs) == 12
    assert len(zoo.zoo_specs(["loaded_twin"], scenarios=("wind_step",), load_signal=False)) == 4


# --- the documents ----------------------------------------------------------------------------------------


def _info():
    return zooreport.RunInfo("lde evaluate --zoo", 6, 12.0, 2, "2 cores", 1.0, 2.0, "2026-01-01 00:00")


def test_the_document_names_the_command_machine_and_date():
    doc = zooreport.doc_block(_results(), _info())
    assert doc.startswith("Measured with `lde evaluate --zoo`: 6 runs in 12 s wall on 2 cores")
    assert "2026-01-01 00:00" in doc.splitlines()[0]
    assert "- cold, wind force NRMSE <= 10 %" in doc and "- cold, payload loaded_twin" in doc
    assert "**Cold**" in doc and "**Warm**" in doc and zooreport.LEGEND in doc
    assert doc.count("| plant | profile | backend |") == 0  # one backend: no backend column
    assert doc.count("| plant | profile | wind_step |") == 2


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--modes", "cold,hot"], "unknown mode(s) hot"),
        (["--warm", "--modes", "warm"], "--warm is --modes warm"),
    ],
)
def test_evaluate_zoo_option_errors_are_one_line(capsys, tmp_path, argv, message):
    code = main(["evaluate", "--zoo", *argv, "--out", str(tmp_path)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and message in err[0]
