"""A fault is never a pass, and a falsification's resume cannot be turned against its user
(docs/studies.md#faulted-samples, docs/studies.md#falsification).

One test per defect found by hostile use: a filter that faults counted as a safe sample in a study (run alone and
batched), by the sequential stop, by the falsification's objective and by the bench (S1); a falsification
interrupted inside optuna's `ask()` that could not be resumed (D4); a refused resume that rewrote a finished
falsify.json, and a corrupt optuna.db that gave a traceback (D5).

The studies run paper_sim (the PCC plant, exact state, 1 kHz) pushing with 150 hPa from rest for a fraction of a
second: unfiltered, such a push violates F_max within 0.3 s (ρ_min_meas ≈ −3 after 0.5 s).
"""

from __future__ import annotations

import json
import math
import textwrap
from pathlib import Path

import optuna
import pytest

from softcbf.bench import FilterSpec, RunOptions, check_bench_json, run_bench, study_figures
from softcbf.study import Distribution, Study, StudyStore, run_study
from softcbf.study.analysis import tuning_summary
from softcbf.study.cli import main as study_main
from softcbf.study.falsify import STORAGE_FILE, falsify
from softcbf.study.report import write_report
from softcbf.study.sequential import run_until_bound
from softcbf_mj.outputs.runio import OutputDirError

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

PUSH = {"nominal": "step", "nominal_params": "seed=0;low_hPa=150;high_hPa=150"}
FILTERS = textwrap.dedent('''
    import numpy as np

    class RaiseFirst:  # a filter that never runs: it raises at its first call
        def __call__(self, estimate, u_nom):
            raise RuntimeError("boom at the first call")

    class RaiseAt:  # raises at call `at` (1: the first), else passes the nominal through within ±100 hPa
        def __init__(self, at: float = 1.0):
            self.at, self.calls = at, 0
        def __call__(self, estimate, u_nom):
            self.calls += 1
            if self.calls >= self.at:
                raise RuntimeError(f"boom at call {self.calls}")
            return np.clip(u_nom, -100.0, 100.0)
''')


@pytest.fixture()
def plugin(tmp_path: Path) -> Path:
    path = tmp_path / "hostile_filters.py"
    path.write_text(FILTERS, encoding="utf-8")
    return path


def push_study(plugin: Path, factory: str = "RaiseFirst", draws: int = 3, **fixed) -> Study:
    return Study("hostile", "paper_sim", (f"{plugin}:{factory}",), tuning_parameter="filter", draws=draws, seed=1,
                 fixed={"duration": 0.1, **PUSH, **fixed},
                 vary=(Distribution("plate_stiffness", "uniform", low=10.0, high=12.0),))


# -- S1: a fault is never a pass -------------------------------------------------------------------------------


@pytest.mark.parametrize("batch_size", [1, 3], ids=["alone", "batched"])
def test_a_study_counts_a_filter_that_faults_at_its_first_call_as_violations(plugin, tmp_path, batch_size):
    """Before the fix: every row "ok" with ρ_min_meas 1.0, the report "violations 0/3", P < 0.632."""
    study = push_study(plugin)
    outcome = run_study(study, tmp_path / "s", workers=1, batch_size=batch_size, progress=False)
    rows = StudyStore.open(tmp_path / "s").load_rows()
    assert [r["status"] for r in rows] == ["fault"] * 3
    assert all(r["fault_type"] == "RuntimeError" and r["error"].startswith("filter fault in the filter") for r in rows)
    assert (outcome.ran, outcome.failed, outcome.faulted) == (3, 0, 3)
    (summary,) = tuning_summary(rows, study.tunings)
    assert (summary["faulted"], summary["failed"], summary["violation"].k, summary["violation"].n) == (3, 0, 3, 3)
    assert summary["rho_min_meas"] is None  # a faulted run's ρ (1.0 over one period) is no verdict
    report = write_report(tmp_path / "s").read_text(encoding="utf-8")
    assert f"| {study.tunings[0]} | 3 | 0 | 3 | 3/3 | 1.000 |" in report
    assert "0 failed, 3 faulted" in report


def test_the_sequential_stop_never_bounds_a_filter_that_faults(plugin, tmp_path, capsys):
    """Before the fix: `--until-bound 0.5` ran 5 fault-only draws and printed "P(violation) < 0.4507"."""
    study = push_study(plugin, draws=6)
    result = run_until_bound(study, tmp_path / "s", 0.5, workers=1, batch_size=1, progress=False)
    (tuning,) = study.tunings
    assert result.violation[tuning].k == result.violation[tuning].n >= 1
    assert result.faulted[tuning] == result.violation[tuning].n and result.outcome.faulted == result.faulted[tuning]
    assert result.settled[tuning] and not result.bounded[tuning]


@pytest.mark.slow
def test_falsify_takes_a_fault_as_the_worst_value_and_reports_it(plugin, tmp_path):
    """Before the fix: the faulted evaluation was its truncated ρ_min_meas 1.0, best ρ < 0 elsewhere or "no violation"."""
    study = Study("hostile", "paper_sim", (f"{plugin}:RaiseAt",), tuning_parameter="filter", draws=4, seed=1,
                  fixed={"duration": 0.1, **PUSH},
                  vary=(Distribution("filter_param.at", "uniform", low=1.0, high=1e6),))
    result = falsify(study, tmp_path / "f", budget=2, population=2, sampler="tpe", baseline=2, workers=1,
                     progress=False)
    best = result["best"]
    assert best["params"] == {"filter_param.at": 1.0} and best["value"] is None  # the vertex that faults
    assert best["fault"] == {"type": "RuntimeError", "message": "boom at call 1", "where": "filter"}
    assert result["faulted"] == 1 and result["failed"] == 0 and result["first_violation"] is not None
    assert result["worst"]["fault"]["type"] == "RuntimeError" and result["worst"]["value"] is None
    stored = json.loads((tmp_path / "f" / "falsify.json").read_text(encoding="utf-8"))
    assert stored["best"] == best and stored["faulted"] == 1
    search = optuna.load_study(study_name=stored["optuna_study"], storage=f"sqlite:///{tmp_path / 'f' / STORAGE_FILE}")
    told = {t.params["filter_param.at"]: t.value for t in search.trials}
    assert told[1.0] == -math.inf and math.isfinite(told[1e6])  # the sampler is told the fault is the worst
    report = write_report(tmp_path / "f").read_text(encoding="utf-8")
    assert "filter fault (RuntimeError in the filter)" in report and "its filter faulted again" in report


@pytest.mark.slow
def test_a_search_for_the_best_setting_never_picks_one_that_faulted(plugin, tmp_path):
    """Before the fix: maximising ρ_min_meas picked the setting whose filter raised at its first call (its truncated run's
    ρ 1.0) over the one that ran."""
    study = Study("hostile", "paper_sim", (f"{plugin}:RaiseAt",), tuning_parameter="filter", draws=4, seed=1,
                  fixed={"duration": 0.1, **PUSH}, objective="-rho_min_meas",
                  vary=(Distribution("filter_param.at", "uniform", low=1.0, high=1e6),))
    result = falsify(study, tmp_path / "f", budget=2, population=2, sampler="tpe", baseline=0, workers=1,
                     progress=False)
    best = result["best"]
    assert best["params"] == {"filter_param.at": 1e6} and best["fault"] is None and math.isfinite(best["value"])
    assert result["faulted"] == 1 and result["failed"] == 0 and result["first_violation"] is not None
    stored = json.loads((tmp_path / "f" / "falsify.json").read_text(encoding="utf-8"))
    search = optuna.load_study(study_name=stored["optuna_study"], storage=f"sqlite:///{tmp_path / 'f' / STORAGE_FILE}")
    assert {t.params["filter_param.at"]: t.value for t in search.trials}[1.0] == math.inf  # the worst for the search


@pytest.mark.slow
def test_bench_rows_carry_the_fault_and_no_clean_verdict(plugin, tmp_path):
    """Before the fix: a filter that faults at its first call ended the bench with "t must have shape (T,) with T >= 2";
    one that faults later gave the row ρ 1.0000, t_viol 0, no fault in bench.json or bench.md."""
    spec = FilterSpec(f"{plugin}:RaiseFirst")
    bench = run_bench(tmp_path / "b", [spec], RunOptions(quick=True), cases=["paper_sim_150", "step"])
    check_bench_json(json.loads((tmp_path / "b" / "bench.json").read_text(encoding="utf-8")))
    single, steps = bench["results"]
    for row, runs in ((single, 1), (steps, 3)):
        assert row["faulted"] == runs
        assert row["fault"] == {"type": "RuntimeError", "message": "boom at the first call", "where": "filter"}
        assert row["rho_min_meas"] is None and row["t_violation_s"] is None
    assert steps["violation_probability"] == 1.0 and steps["draws"] == 3  # every faulted start is a violation
    table = (tmp_path / "b" / "bench.md").read_text(encoding="utf-8")
    assert "| RuntimeError in the filter (1 run) |" in table and "| RuntimeError in the filter (3 runs) |" in table
    assert "1.0000" not in table


@pytest.mark.slow
def test_the_bench_mismatch_study_counts_its_faulted_samples(plugin, tmp_path):
    """The bench's study case (camera_mismatch: `study_figures` over a kept-runs study) pools faulted samples as
    violations; before the fix it pooled them as clean runs (and ended on "t must have shape (T,)" for a first-call fault)."""
    run_study(push_study(plugin), tmp_path / "s", workers=1, batch_size=1, keep_runs=True, progress=False)
    figures = study_figures(tmp_path / "s")
    assert (figures["faulted"], figures["draws"], figures["violation_probability"]) == (3, 3, 1.0)
    assert figures["rho_min_meas"] is None and figures["fault"]["type"] == "RuntimeError"


# -- D4, D5: a falsification's resume ----------------------------------------------------------------------------


def small_box(plugin: Path) -> Study:
    return Study("resume", "paper_sim", (f"{plugin}:RaiseAt",), tuning_parameter="filter", draws=4, seed=1,
                 fixed={"duration": 0.05, **PUSH}, vary=(Distribution("filter_param.at", "uniform", low=1e5, high=1e6),))


@pytest.mark.slow
@pytest.mark.parametrize("at_ask", [2, 3], ids=["a-vertex", "a-sampled-candidate"])
def test_a_falsification_interrupted_inside_ask_resumes(plugin, tmp_path, monkeypatch, at_ask):
    """Before the fix: every --resume failed with KeyError: 'filter_param.at' (a RUNNING trial without params). Ask 2 pops
    the second vertex of generation 0 (enqueued), ask 3 is the sampler's first candidate."""
    original = optuna.Study.ask
    calls = []

    def interrupted(self, fixed_distributions=None):
        calls.append(1)
        if len(calls) == at_ask:  # inside ask(): the trial exists, its parameters do not
            original(self)
            raise KeyboardInterrupt
        return original(self, fixed_distributions)

    monkeypatch.setattr(optuna.Study, "ask", interrupted)
    with pytest.raises(KeyboardInterrupt):
        falsify(small_box(plugin), tmp_path / "f", budget=4, population=2, sampler="tpe", baseline=0, workers=1,
                progress=False)
    monkeypatch.setattr(optuna.Study, "ask", original)
    result = falsify(small_box(plugin), tmp_path / "f", budget=4, population=2, sampler="tpe", baseline=0, workers=1,
                     progress=False, resume=True)
    assert (result["status"], result["evaluations"], result["failed"], result["faulted"]) == ("done", 4, 0, 0)
    rows = StudyStore.open(tmp_path / "f" / "search").load_rows()
    assert [r["sample"] for r in rows] == [0, 1, 2, 3]
    assert all(1e5 <= r["param.filter_param.at"] <= 1e6 for r in rows)
    assert {1e5, 1e6} <= {r["param.filter_param.at"] for r in rows}  # both vertices evaluated
    search = optuna.load_study(study_name=result["optuna_study"], storage=f"sqlite:///{tmp_path / 'f' / STORAGE_FILE}")
    states = [t.state.name for t in search.trials]
    assert states.count("FAIL") == 1 and states[at_ask - 1] == "FAIL"  # the interrupted ask: failed, asked anew
    assert states.count("COMPLETE") == 4


@pytest.fixture()
def finished(plugin, tmp_path) -> Path:
    falsify(small_box(plugin), tmp_path / "f", budget=2, population=2, sampler="tpe", baseline=0, workers=1,
            progress=False)
    return tmp_path / "f"


@pytest.mark.parametrize("spoil", ["missing", "empty"])
def test_a_refused_resume_leaves_a_finished_falsification_as_it_was(plugin, finished, spoil):
    """Before the fix: falsify.json rewritten to status "running", best null, and a fresh optuna.db made."""
    before = (finished / "falsify.json").read_bytes()
    db = finished / STORAGE_FILE
    db.unlink()
    if spoil == "empty":
        db.write_bytes(b"")
    with pytest.raises(OutputDirError, match="optuna"):
        falsify(small_box(plugin), finished, budget=4, population=2, sampler="tpe", baseline=0, workers=1,
                progress=False, resume=True)
    assert (finished / "falsify.json").read_bytes() == before
    assert db.exists() == (spoil == "empty") and (spoil == "missing" or db.read_bytes() == b"")


def test_a_corrupt_optuna_storage_is_one_line_and_exit_2(plugin, finished, capsys):
    """Before the fix: a 34-frame SQLAlchemy traceback ("file is not a database")."""
    (finished / STORAGE_FILE).write_bytes(b"not a database, " * 64)
    before = (finished / "falsify.json").read_bytes()
    study_file = finished.parent / "box.toml"
    study_file.write_text(textwrap.dedent(f'''
        name = "resume"
        scenario = "paper_sim"
        tunings = ["{small_box(plugin).tunings[0]}"]
        tuning_parameter = "filter"
        draws = 4
        seed = 1
        [fixed]
        duration = 0.05
        nominal = "step"
        nominal_params = "seed=0;low_hPa=150;high_hPa=150"
        [vary."filter_param.at"]
        dist = "uniform"
        low = 1e5
        high = 1e6
    '''), encoding="utf-8")
    code = study_main(["falsify", str(study_file), "--out", str(finished), "--budget", "2", "--population", "2",
                       "--sampler", "tpe", "--baseline", "0", "--workers", "1", "--resume", "--no-progress",
                       "--initial", "vertices"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "is not a readable optuna storage" in err, err
    assert (finished / "falsify.json").read_bytes() == before
