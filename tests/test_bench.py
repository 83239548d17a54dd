"""`softcbf bench` (softcbf.bench): filter specs, per-case parameters, pooled figures, and a quick run's outputs."""

import json
import math

import numpy as np
import pytest

from controllers.nominal import step
from controllers.registry import NOMINALS
from scenarios import get
from softcbf.bench import (CASES, EERG_PARAMS, PLOT_FILE, RESULT_KEYS, FilterSpec, case_filter_params, parse_filters,
                           pooled_figures)
from softcbf.cli import main
from softcbf.study.analysis import wilson_interval

CASE = {c.name: c for c in CASES}


def test_filter_specs_with_parameters_and_nested_commas():
    specs = parse_filters("e-erg(contact_aware=true, kappa=0.1), paper-cbf(tuning=HW-High),none")
    assert specs == [FilterSpec("e-erg", {"contact_aware": "true", "kappa": "0.1"}),
                     FilterSpec("paper-cbf", {"tuning": "HW-High"}), FilterSpec("none")]
    assert [s.label for s in specs] == ["e-erg(contact_aware=true,kappa=0.1)", "paper-cbf(tuning=HW-High)", "none"]


@pytest.mark.parametrize("text, message", [
    ("e-erg(kappa=0.1", "unclosed"), ("e-erg)", "unmatched"), ("no-such-filter", "unknown name"),
    ("e-erg(kappa)", "name=value"), ("none,none", "twice"), ("none,,qsg", "NAME or NAME"),
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
    fig = pooled_figures([a, b])
    assert fig["rho_min_meas"] == -0.1 and fig["force_max_N"] == 0.2 and fig["t_violation_s"] == 0.25
    assert fig["u_dev_rms_hPa"] == pytest.approx(math.sqrt((0 + 9 + 1 + 1 + 1) / 5))
    assert fig["blocked_s"] == pytest.approx(0.1)
    assert fig["switches_per_s"] == pytest.approx((0 + 2 / 0.3) / 2)
    assert fig["filter_us_median"] == 30.0
    assert fig["filter_us_p99"] == pytest.approx(np.percentile([10, 30, 20, 40, 50], 99))
    assert fig["violation_probability"] == 0.5 and fig["draws"] == 2
    assert fig["violation_ci95"] == list(wilson_interval(1, 2))
    single = pooled_figures([a])
    assert single["violation_probability"] is None and single["violation_ci95"] is None and single["draws"] is None


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


def test_quick_bench_writes_the_contract(tmp_path):
    out = tmp_path / "bench"
    assert main(["bench", "--out", str(out), "--quick", "--filters", "none,paper-cbf",
                 "--cases", "paper_sim_150,step,hardware_emulator"]) == 0
    bench = json.loads((out / "bench.json").read_text())
    assert bench["quick"] is True and bench["battery"] == [c.name for c in CASES]
    assert set(bench["skipped"]) == {"hardware_emulator"} and "real time" in bench["skipped"]["hardware_emulator"]
    assert [(r["filter"], r["case"]) for r in bench["results"]] == [
        ("none", "paper_sim_150"), ("none", "step"), ("paper-cbf", "paper_sim_150"), ("paper-cbf", "step")]
    for row in bench["results"]:
        assert tuple(row) == RESULT_KEYS
        for key in RESULT_KEYS[2:]:
            if key in ("violation_probability", "violation_ci95", "draws"):
                continue
            assert isinstance(row[key], float) and math.isfinite(row[key]), key
        multi = row["case"] == "step"
        assert (row["draws"] == 3) if multi else (row["draws"] is None and row["violation_ci95"] is None)
        if multi:
            lo, hi = row["violation_ci95"]
            assert lo <= row["violation_probability"] <= hi
    by = {(r["filter"], r["case"]): r for r in bench["results"]}
    # Without a filter u = u_nom: no deviation, nothing blocked, no switch.
    assert by["none", "step"]["u_dev_rms_hPa"] == 0.0 and by["none", "step"]["blocked_s"] == 0.0
    assert by["none", "step"]["switches_per_s"] == 0.0
    # Steps of 60…300 hPa from rest: the unfiltered arm violates in every start within 0.5 s.
    assert by["none", "step"]["violation_probability"] == 1.0 and by["none", "step"]["rho_min_meas"] < 0
    table = (out / "bench.md").read_text()
    assert "quick" in table and table.count("| paper-cbf |") == 2 and "hardware_emulator" in table
    assert (out / PLOT_FILE).stat().st_size > 1000


def test_unknown_case_is_a_usage_error(tmp_path, capsys):
    assert main(["bench", "--out", str(tmp_path / "b"), "--quick", "--cases", "nope"]) == 2
    assert "unknown case(s) nope" in capsys.readouterr().err


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

    assert main(argv[:-1] + ["paper_sim_150"]) == 0  # without --resume the case runs again, replacing its folder
    assert not sentinel.exists()


def test_resume_refuses_a_bench_of_another_kind(tmp_path, capsys):
    out = tmp_path / "bench"
    out.mkdir()
    (out / "bench.json").write_text(json.dumps({"quick": True, "mismatch_draws": 2, "results": []}))
    assert main(["bench", "--out", str(out), "--filters", "none", "--cases", "paper_sim_150", "--resume"]) == 2
    assert "quick=True" in capsys.readouterr().err
    (out / "bench.json").write_text("{}")
    assert main(["bench", "--out", str(out), "--filters", "none", "--cases", "paper_sim_150", "--resume"]) == 2
    assert "not a bench.json" in capsys.readouterr().err
