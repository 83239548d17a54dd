"""`softcbf study tune --screen` (softcbf.study.tune with softcbf.study.screen): each setting's inner search
screened on pcc_contact and confirmed on mujoco_contact; what makes a screened setting safe, and its resume.

The tiny tunings tune a user's clip filter (limit_hPa) on mujoco_contact, 0.3 s from the sinusoid's peak, over
the plate's stiffness and offset: at limit_hPa 60–65 the nominal plate holds (ρ ≈ 0.07 on pcc_contact, 0.19 on
mujoco_contact at 65 hPa) and the stiff, near corner (18 N/m, −3 mm) violates on both plants (ρ ≈ −0.8, −0.5);
at 5–20 hPa the arm never reaches the plate.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from softcbf.study.cli import main
from softcbf.study.store import StudyStore
from softcbf.study.tune import evaluation_record, load_tune, told_value, tune, UNSAFE_OFFSET
from test_study_journal import CLIP  # a user's filter file: clips u_nom to ±limit_hPa

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")


def tune_file(tmp_path: Path, low: float, high: float) -> Path:
    plugin = tmp_path / "clip.py"
    plugin.write_text(CLIP, encoding="utf-8")
    path = tmp_path / "tune.toml"
    path.write_text(f'name = "tiny"\nscenario = "mujoco_contact"\nseed = 3\nfilter = "{plugin}:Clip"\n'
                    'tunings = ["clip"]\n'
                    '[fixed]\nduration = 0.3\nt0 = 25.0\nf_max = 0.16\nassumed_plate_stiffness = 11.16\n'
                    '[vary.plate_stiffness]\ndist = "uniform"\nlow = 8.0\nhigh = 18.0\n'
                    '[vary.facet_offset]\ndist = "uniform"\nlow = -0.003\nhigh = 0.002\n'
                    f'[tune.limit_hPa]\ndist = "uniform"\nlow = {low}\nhigh = {high}\n', encoding="utf-8")
    return path


def test_a_screened_setting_is_safe_only_when_confirmed_on_the_study_scenario_without_violation_or_fault():
    params = {"filter_param.limit_hPa": 50.0}
    ok = {"status": "ok", "rho_min_meas": 0.4, "sample": 0}
    cheap_violation = {**ok, "rho_min_meas": -0.3}
    fault = {"status": "fault", "error": "RuntimeError: x", "fault_type": "RuntimeError", "fault_where": "filter",
             "fault_message": "x", "rho_min_meas": 0.9, "sample": 1}
    failed = {"status": "error", "error": "boom", "sample": 1}
    screen = [ok, cheap_violation, ok, ok]
    safe = evaluation_record(0, params, ok, 0.1, [ok, ok], 4, screen, replays=1)
    assert safe["safe"] and safe["worst_rho"] == 0.4 and safe["inner_evaluations"] == 2
    assert safe["screen"] == {"evaluations": 4, "violations": 1, "first_violation": 2, "faulted": 0,
                              "worst_rho": -0.3}  # a cheap violation not confirmed is a candidate, not a verdict
    assert safe["expensive_runs"] == 4  # nominal, two confirmations, the worst's replay
    nothing = evaluation_record(1, params, ok, 0.1, [], 4, [failed] * 4)  # the screen ranked nothing
    assert not nothing["safe"] and nothing["inner_evaluations"] == 0 and nothing["failed"] == 4
    assert not evaluation_record(2, params, ok, 0.1, [], 4, screen)["safe"]  # no confirmation: no verdict
    confirmed = evaluation_record(3, params, ok, 0.1, [{**ok, "rho_min_meas": -0.2}], 4, screen, replays=1)
    assert not confirmed["safe"] and confirmed["first_violation"] == 1 and confirmed["worst_rho"] == -0.2
    cheap_fault = evaluation_record(4, params, ok, 0.1, [ok], 4, [ok, fault, ok, ok])
    assert not cheap_fault["safe"] and cheap_fault["faulted"] == 1 and cheap_fault["fault"]["type"] == "RuntimeError"
    assert cheap_fault["screen"]["faulted"] == 1 and cheap_fault["worst_rho"] is None
    short = evaluation_record(5, params, ok, 0.1, [ok], 4, [ok, ok])  # a screen short of its budget
    assert not short["safe"]
    assert told_value(confirmed) > UNSAFE_OFFSET > told_value(safe)
    single = evaluation_record(6, params, ok, 0.1, [ok, ok], 2, replays=1)  # unscreened: as before, no "screen"
    assert single["safe"] and "screen" not in single and single["expensive_runs"] == 4


def test_a_screened_tune_finds_the_violation_that_makes_a_setting_unsafe_then_resumes(tmp_path, capsys):
    path = tune_file(tmp_path, 60.0, 65.0)
    out = tmp_path / "out"
    args = ["tune", str(path), "--out", str(out), "--budget", "1", "--inner-budget", "4", "--screen", "pcc_contact",
            "--confirm", "2", "--workers", "1", "--no-progress"]
    assert main(args) == 0
    assert "runs on mujoco_contact: 3" in capsys.readouterr().out
    result = json.loads((out / "tune.json").read_text(encoding="utf-8"))
    assert (result["screen"], result["confirm"]) == ("pcc_contact", 2)
    (record,) = result["evaluations"]
    assert record["nominal_status"] == "ok" and record["value"] is not None
    # the screen's vertices hold the stiff near corner, which violates there; its first confirmation violates too
    assert record["screen"]["evaluations"] == 4 and record["screen"]["violations"] >= 1
    assert not record["safe"] and record["first_violation"] == 1 and record["worst_rho"] < 0
    assert result["best"] is None and result["safe"] == 0
    inner = out / "inner" / "0001"
    assert StudyStore.open(inner / "screen" / "search").study.scenario == "pcc_contact"
    confirmed = StudyStore.open(inner / "search").load_rows()
    assert StudyStore.open(inner / "search").study.scenario == "mujoco_contact"
    assert len(confirmed) == record["inner_evaluations"] == 1  # stopped at the first violation on mujoco_contact
    assert (confirmed[0]["param.plate_stiffness"], confirmed[0]["param.facet_offset"]) == (18.0, -0.003)
    # the study scenario's runs spent: the nominal run, the confirmation, the worst's replay
    assert (inner / "worst" / "config.json").is_file()
    assert record["expensive_runs"] == result["expensive_runs"] == 1 + len(confirmed) + 1
    stamp = (inner / "falsify.json").stat().st_mtime_ns

    assert main([*args, "--resume"]) == 0
    again = json.loads((out / "tune.json").read_text(encoding="utf-8"))
    assert again["evaluations"] == result["evaluations"] and (inner / "falsify.json").stat().st_mtime_ns == stamp
    unscreened = [a for a in args if a not in ("--screen", "pcc_contact", "--confirm", "2")]
    assert main([*unscreened, "--resume"]) == 2
    assert "other screen" in capsys.readouterr().err


def test_a_screened_tune_finds_a_setting_safe_after_confirming_on_the_study_scenario(tmp_path):
    result = tune(load_tune(tune_file(tmp_path, 5.0, 20.0)), tmp_path / "out", budget=1, inner_budget=4,
                  screen="pcc_contact", confirm=2, workers=1, progress=False)
    (record,) = result["evaluations"]
    assert record["safe"] and record["screen"]["violations"] == 0 and record["inner_evaluations"] == 2
    assert record["expensive_runs"] == 4 and result["best"]["evaluation"] == 1


@pytest.mark.parametrize("options, message", [
    ({"confirm": 2}, "give screen with it"),
    ({"screen": "paper_sim"}, "cannot represent the study's varied coordinate 'facet_offset'"),
    ({"screen": "pcc_contact", "confirm": 0}, "confirm must be an integer >= 1"),
])
def test_a_bad_screen_or_confirm_is_refused_before_anything_runs(tmp_path, options, message):
    with pytest.raises(ValueError, match=message):
        tune(load_tune(tune_file(tmp_path, 5.0, 20.0)), tmp_path / "out", budget=1, inner_budget=4, workers=1,
             progress=False, **options)
    assert not (tmp_path / "out").exists()


def test_cli_refuses_confirm_without_screen(tmp_path, capsys):
    assert main(["tune", str(tune_file(tmp_path, 5.0, 20.0)), "--out", str(tmp_path / "out"), "--confirm", "2",
                 "--no-progress"]) == 2
    assert "give --screen SCENARIO with it" in capsys.readouterr().err
