"""`softcbf study tune` (softcbf.study.tune): the file's checks, a tiny search end to end on the PCC plant, its
resume, and that a setting whose filter faulted in the inner search is never safe.

The tiny search tunes a user's clip filter (limit_hPa) on paper_sim, 1 s from the sinusoid's peak, over an error
box of the sinusoid's amplitude; budget 2 settings × 2 inner evaluations.
"""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pytest

from softcbf.study.cli import main
from softcbf.study.definition import load_study
from softcbf.study.store import StudyStore
from softcbf.study.definition import Distribution
from softcbf.study.tune import (UNSAFE_OFFSET, evaluation_record, load_tune, nominal_value, told_value, tune,
                                typed_setting)

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

CLIP = '''
import numpy as np


class Clip:
    """Clips u_nom to +-limit_hPa; raises once the first segment's u_nom exceeds raise_above hPa."""

    def __init__(self, limit_hPa: float = 100.0, raise_above: float = 1e9):
        self.limit, self.raise_above = limit_hPa, raise_above

    def __call__(self, estimate, u_nom):
        if u_nom[0] > self.raise_above:
            raise RuntimeError("injected fault")
        return np.clip(u_nom, -self.limit, self.limit)
'''


def tune_text(plugin: Path, extra: str = "", tune_table: str = "") -> str:
    return (f'name = "tiny"\nscenario = "paper_sim"\nseed = 3\nfilter = "{plugin}:Clip"\ntunings = ["clip"]\n{extra}'
            '[fixed]\nduration = 1.0\nt0 = 25.0\n'
            '[vary.amplitude]\ndist = "uniform"\nlow = 60.0\nhigh = 150.0\n'
            + (tune_table or '[tune.limit_hPa]\ndist = "uniform"\nlow = 5.0\nhigh = 80.0\n'))


@pytest.fixture
def plugin(tmp_path) -> Path:
    path = tmp_path / "clip.py"
    path.write_text(CLIP, encoding="utf-8")
    return path


@pytest.mark.parametrize("extra, table, message", [
    ("", "# no tune table\n", "needs a [tune] table"),
    ("", '[tune.limit_hPa]\ndist = "normal"\nmean = 50.0\nstd = 5.0\n', "tune.limit_hPa: the tuning box needs bounds"),
    ("", '[tune.limit_hPa]\ndist = "uniform"\nlow = 80.0\nhigh = 5.0\n', "tune.limit_hPa: low must be < high"),
    ("", '[tune.limit_hPa]\ndist = "uniform"\nlow = 5.0\n', "tune.limit_hPa: dist 'uniform' takes exactly the keys"),
    ("", '[tune]\nobjective = "-force_max_N"\n[tune.limit_hPa]\ndist = "uniform"\nlow = 5.0\nhigh = 80.0\n',
     "tune.objective must name a metric to maximise"),
    ('filter_params = "limit_hPa=10"\n', "", "limit_hPa are given twice"),
    ("", '[tune.limt_hPa]\ndist = "uniform"\nlow = 5.0\nhigh = 80.0\n', "limt_hPa"),
    ("", '[tune]\nobjective = "force_delivered_N"\n', "needs a tuning box"),
])
def test_a_bad_tune_file_is_refused_with_one_line_and_exit_2(plugin, tmp_path, capsys, extra, table, message):
    path = tmp_path / "tune.toml"
    text = tune_text(plugin, extra, table)
    path.write_text(text, encoding="utf-8")
    assert main(["tune", str(path), "--out", str(tmp_path / "out"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"error: tune file {path}: ") and message in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_a_tune_file_without_a_filter_or_with_two_tunings_is_refused(plugin, tmp_path):
    path = tmp_path / "tune.toml"
    path.write_text(tune_text(plugin).replace(f'filter = "{plugin}:Clip"\n', "").replace('["clip"]', '["Low"]'),
                    encoding="utf-8")
    with pytest.raises(ValueError, match="names the filter to tune"):
        load_tune(path)
    path.write_text(tune_text(plugin).replace('tunings = ["clip"]', 'tunings = ["a", "b"]'), encoding="utf-8")
    with pytest.raises(ValueError, match="runs one tuning"):
        load_tune(path)


def test_an_objective_the_rows_do_not_have_is_refused_with_the_columns(tmp_path):
    row = {"status": "ok", "sample": 0, "rho_min_meas": 0.3, "force_max_N": 0.1, "param.filter_param.a": 1.0}
    assert nominal_value(row, tmp_path, "force_max_N") == 0.1
    with pytest.raises(ValueError, match="'force_mx_N': the nominal run's row has no such column; numeric columns: "
                                         "force_max_N, rho_min_meas"):
        nominal_value(row, tmp_path, "force_mx_N")


def test_a_setting_runs_to_four_significant_digits_within_its_box():
    box = (Distribution("filter_param.a", "uniform", low=0.7, high=1.4),
           Distribution("filter_param.b", "loguniform", low=1.00001, high=3.0),
           Distribution("filter_param.c", "choice", values=("x", "y")))
    setting = typed_setting({"filter_param.a": 1.3999871, "filter_param.b": 1.0000123, "filter_param.c": "y"}, box)
    assert setting == {"filter_param.a": 1.4, "filter_param.b": 1.00001, "filter_param.c": "y"}
    assert typed_setting({"filter_param.a": 0.81234567, "filter_param.b": 2.5, "filter_param.c": "x"},
                         box)["filter_param.a"] == 0.8123


def test_a_setting_with_a_fault_or_a_violation_is_never_safe_and_ranks_behind_every_safe_one():
    params = {"filter_param.limit_hPa": 50.0}
    ok = {"status": "ok", "rho_min_meas": 0.4, "sample": 0}
    fault = {"status": "fault", "error": "RuntimeError: x", "fault_type": "RuntimeError", "fault_where": "filter",
             "fault_message": "x", "rho_min_meas": 0.9, "sample": 1}
    safe = evaluation_record(0, params, ok, 0.1, [ok, ok], 2)
    faulted = evaluation_record(1, params, ok, 0.5, [ok, fault], 2)
    violating = evaluation_record(2, params, ok, 0.5, [ok, {**ok, "rho_min_meas": -0.2}], 2)
    short = evaluation_record(3, params, ok, 0.5, [ok], 2)  # an inner search cut short: no verdict
    failed = evaluation_record(4, params, ok, 0.5, [ok, {"status": "error", "error": "boom", "sample": 1}], 2)
    assert safe["safe"] and (safe["worst_rho"], safe["first_violation"]) == (0.4, None)
    assert not faulted["safe"] and faulted["faulted"] == 1 and faulted["worst_rho"] is None
    assert faulted["fault"]["type"] == "RuntimeError" and faulted["first_violation"] == 2
    assert not violating["safe"] and violating["worst_rho"] == -0.2
    assert not short["safe"] and not failed["safe"]
    assert told_value(safe) == -0.1
    assert told_value(faulted) > told_value(violating) > UNSAFE_OFFSET > told_value(safe)


def test_tiny_tune_end_to_end_then_resume_keeps_every_finished_evaluation_once(plugin, tmp_path, capsys):
    path = tmp_path / "tune.toml"
    path.write_text(tune_text(plugin), encoding="utf-8")
    out = tmp_path / "out"
    assert main(["tune", str(path), "--out", str(out), "--budget", "2", "--inner-budget", "2", "--workers", "1",
                 "--no-progress"]) == 0
    printed = capsys.readouterr().out
    first = json.loads((out / "tune.json").read_text(encoding="utf-8"))
    assert first["status"] == "done" and len(first["evaluations"]) == 2
    for record in first["evaluations"]:
        assert record["nominal_status"] == "ok" and record["inner_evaluations"] == 2
        assert record["safe"] == (record["worst_rho"] >= 0)
    inner_rows = StudyStore.open(out / "inner" / "0001" / "search").load_rows()
    assert [r["batch_size"] for r in inner_rows] == [2, 2]  # the inner generation ran as one batch
    best = first["best"]
    if best is not None:  # the winner: the most force among the safe settings, typed and replayable
        assert best["value"] == max(r["value"] for r in first["evaluations"] if r["safe"])
        assert best["filter_params"] == {"limit_hPa": best["params"]["limit_hPa"]}  # typed
        assert f"--filter-param limit_hPa={best['params']['limit_hPa']}" in printed
        config = json.loads((out / "best" / "config.json").read_text(encoding="utf-8"))
        assert f'"limit_hPa": {best["params"]["limit_hPa"]}' in json.dumps(config)
        assert load_study(out / "winner.json").fixed["filter_params"] == best["filter_params"]
    assert (out / "tune.png").stat().st_size > 0
    parts = sorted(p.name for p in (out / "inner").iterdir())
    stamps = {p: (out / "inner" / p / "falsify.json").stat().st_mtime_ns for p in parts}

    assert main(["tune", str(path), "--out", str(out), "--budget", "3", "--inner-budget", "2", "--workers", "1",
                 "--no-progress", "--resume"]) == 0
    second = json.loads((out / "tune.json").read_text(encoding="utf-8"))
    assert second["evaluations"][:2] == first["evaluations"] and len(second["evaluations"]) == 3
    settings = [r["params"]["limit_hPa"] for r in second["evaluations"]]
    assert len(set(settings)) == 3, settings  # the resumed sampler draws a new setting, not its first again
    assert {p: (out / "inner" / p / "falsify.json").stat().st_mtime_ns for p in parts} == stamps  # not run again
    assert [r["sample"] for r in StudyStore.open(out / "nominal").load_rows()] == [0, 1, 2]
    search = optuna.load_study(study_name=second["optuna_study"], storage=f"sqlite:///{out / 'optuna.db'}")
    assert len(search.trials) == 3 and all(t.state == optuna.trial.TrialState.COMPLETE for t in search.trials)
    assert main(["tune", str(path), "--out", str(out), "--budget", "3", "--inner-budget", "5", "--resume",
                 "--no-progress"]) == 2
    assert "inner_budget" in capsys.readouterr().err


def test_a_setting_whose_filter_faults_in_the_inner_search_is_not_safe(plugin, tmp_path):
    """The filter faults only at the error box's large amplitudes (raise_above = 100 hPa, fixed; the nominal
    amplitude 80 hPa does not fault): every setting is unsafe and none is the winner."""
    path = tmp_path / "tune.toml"
    path.write_text(tune_text(plugin, 'filter_params = "raise_above=100"\n'), encoding="utf-8")
    result = tune(load_tune(path), tmp_path / "out", budget=1, inner_budget=2, workers=1, progress=False)
    (record,) = result["evaluations"]
    assert record["nominal_status"] == "ok" and record["value"] is not None
    assert record["faulted"] >= 1 and record["fault"]["type"] == "RuntimeError"
    assert not record["safe"] and result["best"] is None and result["safe"] == 0
    assert not (tmp_path / "out" / "best").exists()


def test_the_shipped_c_erg_tuning_searches_the_standard_box_stated_once(tmp_path):
    """studies/tune_cerg_box.toml names studies/mismatch_box_contact.toml's box (error_box), and its tuning box
    holds the README's setting and the one configured by hand (docs/studies.md, the standard box)."""
    root = Path(__file__).resolve().parents[1] / "studies"
    tuning = load_tune(root / "tune_cerg_box.toml")
    assert tuning.study.vary == load_study(root / "mismatch_box_contact.toml").vary
    assert tuning.objective == "force_delivered_N" and tuning.study.fixed["filter"] == "c-erg"
    box = {d.parameter.removeprefix("filter_param."): (d.low, d.high) for d in tuning.box}
    for name, value in {"gain_lo_ratio": 0.8, "gain_hi_ratio": 1.25, "stiffness_lo_ratio": 0.8,
                        "stiffness_hi_ratio": 1.4}.items():
        assert box[name][0] <= value <= box[name][1], name
    both = tmp_path / "both.toml"
    both.write_text((root / "tune_cerg_box.toml").read_text(encoding="utf-8")
                    + '\n[vary.tau_p]\ndist = "uniform"\nlow = 0.02\nhigh = 0.1\n', encoding="utf-8")
    with pytest.raises(ValueError, match="give the error box once"):
        load_tune(both)
