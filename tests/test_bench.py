"""`softcbf bench` (softcbf.bench): filter specs, per-case parameters, pooled figures, and a quick run's outputs."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from controllers.nominal import step
from controllers.registry import NOMINALS
from scenarios import get
import softcbf.bench.runner
from softcbf.bench import (ACCEPT_TOL_HPA, CASES, DEFAULT_FILTERS, EERG_PARAMS, PLOT_FILE, RESULT_KEYS, ROW_SCHEMA, Case,
                           FilterSpec, RunOptions, case_filter_params, check_bench_json, nominal_acceptance, parse_filters,
                           pooled_figures, run_bench)
from softcbf.cli import main
from softcbf.study.analysis import clopper_pearson_upper, wilson_interval
from softcbf_mj.outputs.runio import RUN_MARKER

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

CASE = {c.name: c for c in CASES}


def test_filter_specs_with_parameters_and_nested_commas():
    specs = parse_filters("e-erg(contact_aware=true, kappa=0.1), paper-cbf(tuning=HW-High),none")
    assert specs == [FilterSpec("e-erg", {"contact_aware": "true", "kappa": "0.1"}),
                     FilterSpec("paper-cbf", {"tuning": "HW-High"}), FilterSpec("none")]
    assert [s.label for s in specs] == ["e-erg(contact_aware=true,kappa=0.1)", "paper-cbf(tuning=HW-High)", "none"]


@pytest.mark.parametrize("text, message", [
    ("e-erg(kappa=0.1", "unclosed"), ("e-erg)", "unmatched"), ("no-such-filter", "unknown name"),
    ("e-erg(kappa)", "name=value"), ("none,none", "twice"), ("none,,qsg", "NAME or NAME"), ("", "NAME or NAME"),
    ("e-erg(kappa=0.1,kappa=0.2)", "filter parameter kappa is given twice"),  # N8: the last value won
])
def test_bad_filter_specs_are_refused_by_name(text, message):
    with pytest.raises(ValueError, match=message):
        parse_filters(text)


def test_per_case_defaults_follow_the_loop_rate_and_the_spec_wins():
    paper = FilterSpec("paper-cbf")
    assert case_filter_params(paper, CASE["mujoco_contact"]) == {"tuning": "Low"}
    assert case_filter_params(paper, CASE["step"]) == {"tuning": "Low"}
    assert case_filter_params(paper, CASE["camera_loop"]) == {"tuning": "HW-High"}
    assert case_filter_params(paper, CASE["hardware_emulator"]) == {"tuning": "HW-High"}
    assert case_filter_params(FilterSpec("paper-cbf", {"tuning": "High"}), CASE["camera_loop"]) == {"tuning": "High"}
    assert case_filter_params(FilterSpec("e-erg", {"kappa": "0.2"}), CASE["camera_mismatch"]) == {**EERG_PARAMS, "kappa": "0.2"}
    assert case_filter_params(FilterSpec("none"), CASE["paper_sim_150"]) == {}


def _calls(u, u_nom, us):
    t = np.arange(len(u)) * 0.1
    return {"t": t, "u": np.array(u, float)[:, None], "u_nom": np.array(u_nom, float)[:, None], "filter_us": np.array(us, float)}


def test_pooled_figures_of_two_runs_by_hand():
    """Run A: deviation 0, 3 (held 3 hPa above a retreating u_nom: 0.1 s blocked); run B: deviation 1, −1, 1 (2 switches in 0.3 s)."""
    a = ({"rho_min_meas": 0.2, "t_violation_s": 0.0, "force_max_N": 0.1}, _calls([10.0, 8.0], [10.0, 5.0], [10.0, 30.0]))
    b = ({"rho_min_meas": -0.1, "t_violation_s": 0.25, "force_max_N": 0.2}, _calls([1.0, -1.0, 1.0], [0.0, 0.0, 0.0], [20.0, 40.0, 50.0]))
    fig = pooled_figures([a, b], 0.16)
    assert fig["rho_min_meas"] == -0.1 and fig["force_max_N"] == 0.2 and fig["t_violation_s"] == 0.25
    assert fig["f_max_N"] == 0.16 and fig["force_budget_used"] == pytest.approx(0.2 / 0.16)
    assert fig["u_dev_rms_hPa"] == pytest.approx(math.sqrt((0 + 9 + 1 + 1 + 1) / 5))
    assert fig["blocked_s"] == pytest.approx(0.1)
    assert fig["switches_per_s"] == pytest.approx((0 + 2 / 0.3) / 2)
    assert fig["filter_us_median"] == 30.0
    assert fig["filter_us_p99"] == pytest.approx(np.percentile([10, 30, 20, 40, 50], 99))
    assert fig["violation_probability"] == 0.5 and fig["draws"] == 2
    assert fig["violation_ci95"] == list(wilson_interval(1, 2))
    assert fig["violations"] == 1 and fig["violation_cp95_upper"] == clopper_pearson_upper(1, 2)
    single = pooled_figures([a], 0.16)
    assert single["violation_probability"] is None and single["violation_ci95"] is None and single["draws"] is None
    assert single["violations"] is None and single["violation_cp95_upper"] is None


def test_nominal_acceptance_is_the_share_of_calls_that_returned_u_nom():
    """Run A returns u_nom at its first call only, run B never (u − u_nom = ±1 hPa); 1 of 5 calls pooled. The tolerance
    is ACCEPT_TOL_HPA in every segment; a run without calls gives None."""
    a = ({"rho_min_meas": 0.2, "t_violation_s": 0.0, "force_max_N": 0.1}, _calls([10.0, 8.0], [10.0, 5.0], [10.0, 30.0]))
    b = ({"rho_min_meas": 0.1, "t_violation_s": 0.0, "force_max_N": 0.2}, _calls([1.0, -1.0, 1.0], [0.0, 0.0, 0.0], [2.0] * 3))
    assert pooled_figures([a, b], 0.16)["nominal_acceptance"] == pytest.approx(1 / 5)
    assert pooled_figures([a], 0.16)["nominal_acceptance"] == 0.5
    near = ({"rho_min_meas": 0.2, "t_violation_s": 0.0, "force_max_N": 0.1},
            _calls([10.0 + 0.5 * ACCEPT_TOL_HPA, 5.0 + 2 * ACCEPT_TOL_HPA], [10.0, 5.0], [1.0, 1.0]))
    assert pooled_figures([near], 0.16)["nominal_acceptance"] == 0.5
    two = {"t": np.array([0.0, 0.1]), "u": np.array([[1.0, 2.0], [1.0, 3.0]]), "u_nom": np.array([[1.0, 2.0], [1.0, 2.0]]),
           "filter_us": np.ones(2)}
    assert nominal_acceptance([({}, two)]) == 0.5  # one segment changed: not accepted
    empty = {k: v[:0] for k, v in two.items()}
    assert nominal_acceptance([({}, empty)]) is None


def test_bench_runs_the_recommended_filter_beside_the_baselines_and_quick_pushes_last_3_s():
    """Was: `softcbf bench` without --filters ran e-erg and paper-cbf only, and --quick pushed for 1 s."""
    from controllers.registry import find_preset

    specs = parse_filters(DEFAULT_FILTERS)
    assert [s.name for s in specs] == ["c-erg:recommended", "e-erg", "paper-cbf"] and specs[0].params == {}
    assert find_preset(specs[0].name).filter == "c-erg"
    import argparse

    from softcbf.bench import add_arguments

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert parser.parse_args(["--out", "x"]).filters == DEFAULT_FILTERS
    pushes = [c for c in CASES if c.asked_N is not None]
    assert len(pushes) == 15 and all(c.quick_duration_s() >= 3.0 for c in pushes)
    assert all(c.quick_duration_s() == 1.0 for c in CASES if c.asked_N is None)


def test_step_nominal_is_seeded_constant_and_in_range():
    assert NOMINALS["step"] is step

    class Robot:  # the only part of the context a nominal reads
        n_segments = 2

    class Context:
        robot = Robot()

    first, again, other = step(Context(), seed=3), step(Context(), seed=3), step(Context(), seed=4)
    q = np.zeros(2)
    levels = first(1.0, q, q)
    assert np.all((levels >= 60.0) & (levels <= 300.0)) and levels[0] != levels[1]
    assert np.array_equal(levels, again(7.0, q, q)) and not np.array_equal(levels, other(1.0, q, q))
    late = step(Context(), seed=3, t_step=0.5)
    assert np.array_equal(late(0.4, q, q), np.zeros(2)) and np.array_equal(late(0.5, q, q), levels)
    with pytest.raises(ValueError, match="low_hPa <= high_hPa"):
        step(Context(), low_hPa=300.0, high_hPa=60.0)


def test_camera_loop_takes_the_mismatch_parameters():
    camera = get("camera_loop")
    kwargs = camera.validate({"true_gain_scale": 1.1, "facet_offset": -1e-3})
    assert kwargs["true_gain_scale"] == 1.1 and kwargs["facet_offset"] == -1e-3
    with pytest.raises(ValueError, match="true_gain_scale"):
        camera.validate({"true_gain_scale": 0.0})
    with pytest.raises(ValueError, match="facet_offset"):
        camera.validate({"facet_offset": 2.0})


@pytest.mark.slow
def test_quick_bench_writes_the_contract(tmp_path):
    out = tmp_path / "bench"
    assert main(["bench", "--out", str(out), "--quick", "--filters", "none,paper-cbf",
                 "--cases", "paper_sim_150,step,hardware_emulator"]) == 0
    bench = json.loads((out / "bench.json").read_text())
    assert bench["quick"] is True and bench["battery"] == [c.name for c in CASES]
    assert set(bench["skipped"]) == {"hardware_emulator"} and "real time" in bench["skipped"]["hardware_emulator"]
    assert [(r["filter"], r["case"]) for r in bench["results"]] == [
        ("none", "paper_sim_150"), ("none", "step"), ("paper-cbf", "paper_sim_150"), ("paper-cbf", "step")]
    check_bench_json(bench)  # what --resume accepts
    for row in bench["results"]:
        assert tuple(row) == RESULT_KEYS
        assert row["force_asked_N"] is None and row["force_delivered_N"] is None and row["force_delivered_ratio"] is None
        assert row["faulted"] == 0 and row["fault"] is None
        for key in RESULT_KEYS[2:]:
            if key in ("violation_probability", "violation_ci95", "draws", "force_asked_N", "force_delivered_N",
                       "force_delivered_ratio", "faulted", "fault", "violations", "violation_cp95_upper",
                       "force_delivered_min_ratio", "force_delivered_median_ratio"):
                continue
            assert isinstance(row[key], float) and math.isfinite(row[key]), key
        multi = row["case"] == "step"
        assert (row["draws"] == 3) if multi else (row["draws"] is None and row["violation_ci95"] is None)
        assert (row["violations"] == round(3 * row["violation_probability"])) if multi else row["violations"] is None
        if multi:
            lo, hi = row["violation_ci95"]
            assert lo <= row["violation_probability"] <= hi
    by = {(r["filter"], r["case"]): r for r in bench["results"]}
    # Without a filter u = u_nom: no deviation, nothing blocked, no switch.
    assert by["none", "step"]["u_dev_rms_hPa"] == 0.0 and by["none", "step"]["blocked_s"] == 0.0
    assert by["none", "step"]["switches_per_s"] == 0.0
    assert by["none", "step"]["nominal_acceptance"] == 1.0 and by["paper-cbf", "step"]["nominal_acceptance"] < 1.0
    # Steps of 60…300 hPa from rest: the unfiltered arm violates in every start within 0.5 s.
    assert by["none", "step"]["violation_probability"] == 1.0 and by["none", "step"]["rho_min_meas"] < 0
    table = (out / "bench.md").read_text()
    assert "quick" in table and table.count("| paper-cbf |") == 2 and "hardware_emulator" in table
    assert (out / PLOT_FILE).stat().st_size > 1000


def test_unknown_case_is_a_usage_error(tmp_path, capsys):
    assert main(["bench", "--out", str(tmp_path / "b"), "--quick", "--cases", "nope"]) == 2
    assert "unknown case(s) nope" in capsys.readouterr().err


@pytest.mark.slow
def test_resume_keeps_finished_rows_and_continues_the_mismatch_study(tmp_path):
    out = tmp_path / "bench"
    argv = ["bench", "--out", str(out), "--quick", "--filters", "none", "--cases", "paper_sim_150,camera_mismatch"]
    assert main(argv) == 0
    first = json.loads((out / "bench.json").read_text())
    sentinel = out / "cases" / "none" / "paper_sim_150" / "sentinel"
    sentinel.write_text("kept")
    study = out / "cases" / "none" / "camera_mismatch"
    parts = sorted((study / "results").glob("sample-*.parquet"))
    assert len(parts) == 2
    kept_part = parts[0].stat().st_mtime_ns
    parts[1].unlink()  # an interrupted study: one sample stored, the other not
    interrupted = dict(first, results=[r for r in first["results"] if r["case"] != "camera_mismatch"])
    (out / "bench.json").write_text(json.dumps(interrupted))

    assert main(argv + ["--resume"]) == 0
    resumed = json.loads((out / "bench.json").read_text())
    assert sentinel.read_text() == "kept"  # the finished case did not run again
    assert parts[0].stat().st_mtime_ns == kept_part and parts[1].exists()  # only the missing sample ran
    timing = ("filter_us_median", "filter_us_p99", "wall_s")
    figures = [[{k: v for k, v in r.items() if k not in timing} for r in b["results"]] for b in (first, resumed)]
    assert figures[0] == figures[1]  # the same figures as the uninterrupted bench
    assert resumed["results"][0] == first["results"][0]  # the kept row, timing included

    assert main(argv[:-1] + ["paper_sim_150"]) == 2  # a bench folder needs --resume or --overwrite
    assert sentinel.exists()
    assert main(argv[:-1] + ["paper_sim_150", "--overwrite"]) == 0  # --overwrite replaces the bench folder's contents
    assert not sentinel.exists() and not study.exists()


def _bench_json(**row) -> dict:
    """A bench.json as a quick `softcbf bench --filters none --cases paper_sim_150` writes it, its row updated with `row`."""
    stored = {"filter": "none", "case": "paper_sim_150", "rho_min_meas": 1.0, "t_violation_s": 0.0, "force_max_N": 0.0,
              "violation_probability": None, "violation_ci95": None, "draws": None, "u_dev_rms_hPa": 0.0,
              "blocked_s": 0.0, "switches_per_s": 0.0, "filter_us_median": 12.0, "filter_us_p99": 30.0,
              "nominal_acceptance": 1.0, "wall_s": 3.0,
              "force_asked_N": None, "force_delivered_N": None, "force_delivered_ratio": None, "force_budget_used": 0.0,
              "f_max_N": 0.16, "faulted": 0, "fault": None, "violations": None, "violation_cp95_upper": None,
              "force_delivered_min_ratio": None, "force_delivered_median_ratio": None}
    return {"battery": [c.name for c in CASES], "quick": True, "mismatch_draws": 2, "filters": ["none"], "skipped": {},
            "results": [{**stored, **row}], "falsify": None, "worst_found": [], "contact_under_error": []}


QUICK_NONE = ["--quick", "--filters", "none", "--cases", "paper_sim_150"]


def test_resume_refuses_a_bench_of_another_kind(tmp_path, capsys):
    out = tmp_path / "bench"
    out.mkdir()
    (out / "bench.json").write_text(json.dumps(_bench_json()))
    assert main(["bench", "--out", str(out), "--filters", "none", "--cases", "paper_sim_150", "--resume"]) == 2
    assert "quick=True" in capsys.readouterr().err
    (out / "bench.json").write_text("{}")
    assert main(["bench", "--out", str(out), "--filters", "none", "--cases", "paper_sim_150", "--resume"]) == 2
    assert "not a bench.json" in capsys.readouterr().err


def test_resume_keeps_a_valid_row_without_running_it(tmp_path, capsys):
    out = tmp_path / "bench"
    out.mkdir()
    (out / "bench.json").write_text(json.dumps(_bench_json()))
    assert main(["bench", "--out", str(out), *QUICK_NONE, "--resume"]) == 0
    assert "kept from" in capsys.readouterr().out
    assert json.loads((out / "bench.json").read_text()) == _bench_json()
    assert not (out / "cases").exists()


GARBAGE = [  # N7: --resume kept rows of any value (a string ρ, NaN, a negative time, an unknown case...)
    (lambda b: b["results"][0].update(rho_min_meas="abc"), "results[0].rho_min_meas must be a finite number, got 'abc'"),
    (lambda b: b["results"][0].update(rho_min_meas=float("nan")), "results[0].rho_min_meas must be a finite number"),
    (lambda b: b["results"][0].update(force_max_N=float("inf")), "results[0].force_max_N must be finite"),
    (lambda b: b["results"][0].update(t_violation_s=-1.0), "results[0].t_violation_s must be >= 0, got -1.0"),
    (lambda b: b["results"][0].update(wall_s=True), "results[0].wall_s must be a number"),
    (lambda b: b["results"][0].update(filter_us_p99=None), "results[0].filter_us_p99 must be a number"),
    (lambda b: b["results"][0].update(rho_min_meas=None), "results[0].rho_min_meas must be a number (null only in a "
                                                          "row whose filter faulted)"),
    (lambda b: b["results"][0].update(faulted=1, fault={"type": "RuntimeError", "message": "boom", "where": "filter"}),
     "results[0].rho_min_meas must be null in a row whose filter faulted"),
    (lambda b: b["results"][0].update(fault={"type": "RuntimeError", "message": "boom", "where": "filter"}),
     "results[0]: fault must be set exactly when faulted > 0"),
    (lambda b: b["results"][0].update(faulted=1, fault="boom"), "results[0].fault must be null or"),
    (lambda b: b["results"][0].pop("fault"), "results[0] lacks fault"),
    (lambda b: b["results"][0].update(violation_probability=1.5, violation_ci95=[0.1, 0.9], draws=3),
     "results[0].violation_probability must be in [0, 1], got 1.5"),
    (lambda b: b["results"][0].update(violation_probability=0.5, violation_ci95=[0.9, 0.1], draws=2),
     "results[0].violation_ci95 must have lo <= hi"),
    (lambda b: b["results"][0].update(violation_probability=0.5, violation_ci95=[0.1, 0.9], draws=0),
     "results[0].draws must be >= 1, got 0"),
    (lambda b: b["results"][0].update(violation_probability=0.5), "must be null together"),
    (lambda b: b["results"][0].update(case="nope"), "results[0].case must be one of paper_sim_150"),
    (lambda b: b["results"][0].update(filter="qsg"), "results[0].filter 'qsg' is not one of its filters"),
    (lambda b: b["results"][0].pop("blocked_s"), "results[0] lacks blocked_s"),
    (lambda b: b["results"].append(dict(b["results"][0])), "results[1]: (none, paper_sim_150) has a row already"),
    (lambda b: b.update(results={}), "results must be a list of rows"),
    (lambda b: b.update(quick="yes"), "quick must be true or false, got 'yes'"),
    (lambda b: b.update(mismatch_draws=2.0), "mismatch_draws must be an integer >= 1, got 2.0"),
    (lambda b: b.update(filters="none"), "filters must be a list of names"),
    (lambda b: b.pop("skipped"), "it lacks skipped"),
    (lambda b: b["results"][0].update(nominal_acceptance=1.5), "results[0].nominal_acceptance must be in [0, 1], got 1.5"),
    (lambda b: b["results"][0].update(nominal_acceptance=None), "results[0].nominal_acceptance must be a number"),
]


@pytest.mark.parametrize("spoil, message", GARBAGE)
def test_resume_refuses_a_bench_json_of_garbage_values_naming_the_field(tmp_path, capsys, spoil, message):
    out = tmp_path / "bench"
    out.mkdir()
    bench = _bench_json()
    spoil(bench)
    (out / "bench.json").write_text(json.dumps(bench))
    before = (out / "bench.json").read_text()
    assert main(["bench", "--out", str(out), *QUICK_NONE, "--resume"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"error: --resume: {out / 'bench.json'} is not a bench.json"), err
    assert message in err
    assert (out / "bench.json").read_text() == before and not (out / "cases").exists()


def test_every_result_field_has_a_schema_entry():
    assert set(ROW_SCHEMA) == set(RESULT_KEYS)
    check_bench_json(_bench_json())
    check_bench_json(_bench_json(violation_probability=0.0, violation_ci95=[0.0, 0.56], draws=3, violations=0,
                                 violation_cp95_upper=0.63))


@pytest.mark.parametrize("make, options", [
    ("a user's folder", []), ("a user's folder", ["--overwrite"]), ("a user's folder", ["--resume"]),
    ("a run folder", ["--overwrite"]),
])
def test_bench_refuses_a_folder_that_is_not_a_bench_folder(tmp_path, capsys, make, options):
    """N7: `softcbf bench --out` wrote into any folder (a user's, a run folder)."""
    out = tmp_path / "folder"
    out.mkdir()
    if make == "a run folder":
        (out / RUN_MARKER).write_text("")
        (out / "summary.json").write_text(json.dumps({"scenario": "paper_sim", "params": {}, "runs": []}))
    (out / "keep.txt").write_text("data")
    before = sorted(p.name for p in out.iterdir())
    assert main(["bench", "--out", str(out), *QUICK_NONE, *options]) == 2
    err = capsys.readouterr().err
    assert f"{out} is not empty and is not a bench folder (it has no bench.json)" in err and err.count("\n") == 1
    assert sorted(p.name for p in out.iterdir()) == before and (out / "keep.txt").read_text() == "data"


def test_a_bench_folder_needs_resume_or_overwrite_and_is_locked_while_a_bench_runs(tmp_path, capsys):
    out = tmp_path / "bench"
    out.mkdir()
    (out / "bench.json").write_text(json.dumps(_bench_json()))
    assert main(["bench", "--out", str(out), *QUICK_NONE]) == 2
    assert "holds a bench (bench.json); pass --resume to continue it or --overwrite" in capsys.readouterr().err
    assert main(["bench", "--out", str(out), *QUICK_NONE, "--resume", "--overwrite"]) == 2
    assert "give one of them" in capsys.readouterr().err
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from softcbf_mj.outputs.runio import prepare_out_dir\n"
                               "prepare_out_dir(sys.argv[1], keep=True); print('locked', flush=True); time.sleep(600)",
                               str(out)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        for flag in ("--resume", "--overwrite"):
            assert main(["bench", "--out", str(out), *QUICK_NONE, flag]) == 2
            assert f"{out} is in use by another run (process {holder.pid})" in capsys.readouterr().err
        assert json.loads((out / "bench.json").read_text()) == _bench_json()
    finally:
        holder.kill()
        holder.wait()


def test_overwrite_never_empties_the_working_folder(tmp_path, capsys, monkeypatch):
    (tmp_path / "bench.json").write_text(json.dumps(_bench_json()))
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "--out", ".", *QUICK_NONE, "--overwrite"]) == 2
    assert "it is the working folder" in capsys.readouterr().err
    assert (tmp_path / "bench.json").is_file()


def _refuse_to_run(case, spec, folder, options):
    raise RuntimeError(f"case {case.name} ran")


@pytest.mark.parametrize("cases", ["", ",", "paper_sim_150,,step"])
def test_an_empty_case_list_is_a_usage_error_not_the_whole_battery(tmp_path, capsys, monkeypatch, cases):
    """N7: `--cases ""` ran the whole battery."""
    monkeypatch.setattr(softcbf.bench.runner, "CASES", tuple(Case(c.name, c.rate, _refuse_to_run) for c in CASES))
    assert main(["bench", "--out", str(tmp_path / "b"), "--quick", "--filters", "none", "--cases", cases]) == 2
    assert "--cases must name at least one case" in capsys.readouterr().err
    with pytest.raises(ValueError, match="--cases must name at least one case"):
        run_bench(tmp_path / "b", [FilterSpec("none")], RunOptions(quick=True), cases=[])
    assert not (tmp_path / "b").exists()


def test_a_fresh_bench_that_fails_before_its_first_row_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(softcbf.bench.runner, "CASES", tuple(Case(c.name, c.rate, _refuse_to_run) for c in CASES))
    with pytest.raises(RuntimeError, match="case paper_sim_150 ran"):
        run_bench(tmp_path / "new", [FilterSpec("none")], RunOptions(quick=True), cases=["paper_sim_150"])
    assert not (tmp_path / "new").exists()
    (tmp_path / "empty").mkdir()
    with pytest.raises(RuntimeError, match="case paper_sim_150 ran"):
        run_bench(tmp_path / "empty", [FilterSpec("none")], RunOptions(quick=True), cases=["paper_sim_150"])
    assert [p.name for p in (tmp_path / "empty").iterdir()] == [RUN_MARKER]  # as empty as it was: not refused next time
    with pytest.raises(RuntimeError, match="case paper_sim_150 ran"):
        run_bench(tmp_path / "empty", [FilterSpec("none")], RunOptions(quick=True), cases=["paper_sim_150"])


def test_contact_tasks_are_in_the_battery_with_their_asked_force():
    """Issue 24: every plant has the four constant pushes (their asked force within 0.2 % F_max of the ratio:
    tools/force_levels.py's tolerance), the 150 hPa push and the force-target nominal."""
    from softcbf.bench import PUSH_PREFIX, PUSH_RATIOS, PUSHES

    for plant, prefix in PUSH_PREFIX.items():
        for ratio in PUSH_RATIOS:
            case = CASE[f"{prefix}_push_{round(ratio * 100):03d}"]
            assert case.scenario_params["scenario"] == plant and case.scenario_params["nominal"] == "step"
            assert abs(case.asked_N - ratio * 0.16) <= 2e-3 * 0.16
        assert CASE[f"{prefix}_push_150hPa"].asked_N > 0.16 and CASE[f"{prefix}_push_150hPa"].scenario_params["nominal_params"]["low_hPa"] == "150"
        assert CASE[f"{prefix}_force_target"].scenario_params["nominal"] == "force-target"
    assert all(CASE[c.name].asked_N is None for c in CASES if "push" not in c.name and "force_target" not in c.name)
    assert set(PUSHES) == set(PUSH_PREFIX)


def test_quick_contact_task_rows_hold_the_force_budget(tmp_path):
    """The unfiltered push asking 0.6 F_max delivers its request (ratio 1 within 2 %: the push settles within 0.5 s);
    bench.md links the delivered-against-asked plot."""
    from softcbf.bench import FORCE_PLOT_FILE

    out = tmp_path / "bench"
    assert main(["bench", "--out", str(out), "--quick", "--filters", "none", "--cases", "mujoco_push_060"]) == 0
    bench = json.loads((out / "bench.json").read_text())
    check_bench_json(bench)
    (row,) = bench["results"]
    assert row["force_asked_N"] == CASE["mujoco_push_060"].asked_N and row["f_max_N"] == 0.16
    assert row["force_delivered_ratio"] == pytest.approx(1.0, abs=0.02)
    assert row["force_delivered_ratio"] == row["force_delivered_N"] / row["force_asked_N"]
    assert row["force_budget_used"] == row["force_max_N"] / 0.16
    assert FORCE_PLOT_FILE in (out / "bench.md").read_text() and (out / FORCE_PLOT_FILE).stat().st_size > 1000


def test_three_segment_preset_is_uniform_robot_3_and_touches_the_paper_facet_from_rest():
    from controllers.model.params import uniform_robot
    from controllers.model.pcc import tip_position
    from controllers.model.safe_set import paper_environment
    from scenarios.common import load_robot

    robot = load_robot("three-segment")
    assert robot == uniform_robot(3)
    env = paper_environment()
    tip = tip_position(np.zeros(3), np.array(robot.lengths))
    gap = (env.offsets[0] - env.normals[0] @ tip) / np.linalg.norm(env.normals[0])  # > 0: inside the facet's half-plane
    assert 0.0 < gap < 0.02  # 17 mm inside at rest (models/robots/README.md): a push reaches the plate quickly
    for name, plant in (("paper_sim_3seg", "paper_sim"), ("mujoco_3seg", "mujoco_contact")):
        case = CASE[name]
        assert case.scenario_params["scenario"] == plant and case.scenario_params["robot"] == "three-segment"
        assert case.rate == "1kHz" and case.asked_N is None
        pushes_back = "false" if plant == "paper_sim" else "true"  # the PCC plant's plate pushes back nowhere
        assert case_filter_params(FilterSpec("c-erg"), case)["contact_aware"] == pushes_back
        get(plant).validate({k: v for k, v in case.scenario_params.items() if k != "scenario"})


def test_arm_refusal_names_e_erg_on_three_segments_and_nothing_else():
    from softcbf.bench import arm_refusal

    for name in ("paper_sim_3seg", "mujoco_3seg"):
        reason = arm_refusal(FilterSpec("e-erg"), CASE[name])
        assert reason is not None and "3-segment" in reason and "N <= 2" in reason
        for other in ("c-erg", "qsg", "paper-cbf", "none"):
            assert arm_refusal(FilterSpec(other), CASE[name]) is None, other
    assert arm_refusal(FilterSpec("e-erg"), CASE["mujoco_contact"]) is None  # the reference arm: not probed


@pytest.mark.slow
def test_quick_three_segment_cases_skip_e_erg_and_the_unfiltered_arm_makes_contact(tmp_path):
    out = tmp_path / "bench"
    argv = ["bench", "--out", str(out), "--quick", "--filters", "e-erg,c-erg,none", "--cases", "paper_sim_3seg,mujoco_3seg"]
    assert main(argv) == 0
    bench = json.loads((out / "bench.json").read_text())
    check_bench_json(bench)
    assert set(bench["skipped"]) == {"e-erg x paper_sim_3seg", "e-erg x mujoco_3seg"}
    assert all("N <= 2" in reason for reason in bench["skipped"].values())
    by = {(r["filter"], r["case"]): r for r in bench["results"]}
    assert set(by) == {(f, c) for f in ("c-erg", "none") for c in ("paper_sim_3seg", "mujoco_3seg")}
    for case in ("paper_sim_3seg", "mujoco_3seg"):
        none, cerg = by["none", case], by["c-erg", case]
        assert none["force_budget_used"] > 1.0 and none["rho_min_meas"] < 0 and none["t_violation_s"] > 0.5
        assert cerg["rho_min_meas"] > 0 and cerg["t_violation_s"] == 0.0 and cerg["force_max_N"] > 0.0
    assert "e-erg x mujoco_3seg" in (out / "bench.md").read_text()
    assert main(argv + ["--resume"]) == 0  # the skip keys are no case names: --resume accepts its own bench.json
    assert json.loads((out / "bench.json").read_text())["results"] == bench["results"]
