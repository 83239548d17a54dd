"""Robustness studies (softcbf.study): definition and sampling, statistics, local runs —
determinism, resume after an interrupt, failing samples recorded, report.

Studies here run `mujoco_contact` for 0.3 s from the sinusoid's peak (t0 = 25 s), where the
arm presses the plate within 0.2 s; a sample costs ≈ 0.15 s plus a worker start (spawn).
"""

from __future__ import annotations

import math
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas
import pytest

from softcbf_mj.outputs.runio import OutputDirError
from softcbf.study import WALL_CLOCK_COLUMNS, Distribution, Study, StudyStore, load_study, run_study
from softcbf.study.analysis import (Proportion, clopper_pearson_interval, clopper_pearson_upper, crossing, sensitivity,
                                    tuning_summary, wilson_interval)
from softcbf.study.report import assumed_value, write_report

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

ROOT = Path(__file__).resolve().parents[1]
TINY_TOML = """
name = "tiny"
scenario = "mujoco_contact"
seed = 7
draws = 3
tunings = ["None", "Low"]
[fixed]
t0 = 25.0
duration = 0.3
f_max = 0.16
[vary.plate_stiffness]
dist = "uniform"
low = 8.0
high = 18.0
[vary.facet_offset]
dist = "uniform"
low = -0.003
high = 0.002
"""


def comparable(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k not in WALL_CLOCK_COLUMNS} for r in rows]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Study:
    path = tmp_path_factory.mktemp("def") / "tiny.toml"
    path.write_text(TINY_TOML, encoding="utf-8")
    return load_study(path)


@pytest.fixture(scope="module")
def reference(tiny, tmp_path_factory):
    """The tiny study on two local workers: (folder, rows)."""
    out = tmp_path_factory.mktemp("ref") / "study"
    outcome = run_study(tiny, out, workers=2, progress=False)
    assert (outcome.ran, outcome.failed, outcome.skipped) == (6, 0, 0)
    return out, StudyStore.open(out).load_rows()


# -- definition and sampling -------------------------------------------------------


def test_samples_are_draw_major_and_reproducible_from_study_seed_and_index(tiny):
    assert (tiny.n_draws, tiny.n_samples) == (3, 6)
    samples = [tiny.sample(i) for i in range(6)]
    assert [s.tuning for s in samples] == ["None", "Low"] * 3 and [s.draw for s in samples] == [0, 0, 1, 1, 2, 2]
    for first, second in zip(samples[::2], samples[1::2]):  # both tunings of a draw meet the same mismatch
        assert first.values == second.values and first.scenario_seed == second.scenario_seed
    again = Study.from_dict(tiny.to_dict())
    assert [again.sample(i) for i in range(6)] == samples
    s = samples[4]
    assert s.kwargs["tunings"] == "None" and s.kwargs["seed"] == s.scenario_seed and s.kwargs["progress"] is False
    assert 8.0 <= s.values["plate_stiffness"] <= 18.0 and -0.003 <= s.values["facet_offset"] <= 0.002
    other = Study.from_dict({**tiny.to_dict(), "seed": 8})
    assert other.sample(0).values != samples[0].values


def test_monte_carlo_draws_cover_their_distributions():
    study = Study("mc", "mujoco_contact", ("Low",), draws=2000, vary=(
        Distribution("plate_stiffness", "loguniform", low=5.0, high=20.0),
        Distribution("facet_angle", "normal", mean=0.01, std=0.02),
        Distribution("links_per_segment", "choice", values=(5, 10))))
    values = [study.sample(i).values for i in range(2000)]
    logk = [math.log(v["plate_stiffness"]) for v in values]
    assert min(logk) >= math.log(5.0) and max(logk) <= math.log(20.0)
    mean_logk = sum(logk) / len(logk)  # U(ln 5, ln 20): mean ln 10, std 0.40 -> standard error 0.009
    assert mean_logk == pytest.approx(math.log(10.0), abs=0.04)
    angles = [v["facet_angle"] for v in values]
    assert sum(angles) / len(angles) == pytest.approx(0.01, abs=4 * 0.02 / math.sqrt(2000))
    links = [v["links_per_segment"] for v in values]
    assert set(links) == {5, 10} and abs(links.count(5) - 1000) < 4 * math.sqrt(500)


def test_grid_enumerates_the_product_first_parameter_slowest():
    study = Study("grid", "mujoco_contact", ("None", "Low"), sampling="grid", vary=(
        Distribution("plate_stiffness", "uniform", low=10.0, high=12.0, points=3),
        Distribution("tau_p", "choice", values=(0, 0.05))))
    assert (study.n_draws, study.n_samples) == (6, 12)
    cells = [(study.sample(2 * d).values["plate_stiffness"], study.sample(2 * d).values["tau_p"]) for d in range(6)]
    assert cells == [(10.0, 0.0), (10.0, 0.05), (11.0, 0.0), (11.0, 0.05), (12.0, 0.0), (12.0, 0.05)]
    assert isinstance(cells[0][1], float)  # tau_p is a float parameter: 0 becomes 0.0


@pytest.mark.parametrize("change, message", [
    (dict(vary=(Distribution("stiffnes", "uniform", low=1.0, high=2.0),)), "has no parameter 'stiffnes'"),
    (dict(vary=(Distribution("links_per_segment", "uniform", low=5, high=10),)), "use dist = 'choice'"),
    (dict(vary=(Distribution("tau_p", "choice", values=("fast",)),)), "'tau_p' takes float values, got 'fast'"),
    (dict(fixed={"tunings": "Low"}), "given more than once"),
    (dict(draws=0), "needs draws, an integer >= 1"),
    (dict(scenario="nope"), "unknown scenario 'nope'"),
    (dict(sampling="grid", draws=None, vary=(Distribution("tau_p", "normal", mean=0.05, std=0.01),)), "has no grid"),
])
def test_invalid_studies_say_what_is_wrong(change, message):
    base = dict(name="bad", scenario="mujoco_contact", tunings=("Low",), draws=2)
    with pytest.raises(ValueError, match=message):
        Study(**{**base, **change})


def test_distribution_checks_its_keys():
    with pytest.raises(ValueError, match="low must be < high, got low=2.0, high=1.0"):
        Distribution("tau_p", "uniform", low=2.0, high=1.0)
    with pytest.raises(ValueError, match="takes exactly the keys mean, std"):
        Distribution("tau_p", "normal", low=0.0, high=1.0)


# -- statistics ---------------------------------------------------------------------


def test_wilson_interval_matches_the_closed_form_values():
    # Reference values (Wilson 1927; e.g. Brown, Cai & DasGupta 2001), z = 1.959964.
    assert wilson_interval(0, 10) == pytest.approx((0.0, 0.27753), abs=1e-5)
    assert wilson_interval(5, 10) == pytest.approx((0.23659, 0.76341), abs=1e-5)
    assert wilson_interval(1, 20) == pytest.approx((0.00889, 0.23613), abs=1e-5)
    for n in range(1, 60):  # the interval holds k/n for every k, its ends exactly 0 and 1 at k = 0 and n
        for k in range(n + 1):
            low, high = wilson_interval(k, n)
            assert low <= k / n <= high
        assert wilson_interval(0, n)[0] == 0.0 and wilson_interval(n, n)[1] == 1.0
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError, match="0 <= k <= n"):
        wilson_interval(3, 2)


def test_sensitivity_bins_and_crossing():
    rows = [{"tuning": "Low", "status": "ok", "param.k": float(x), "rho_min_meas": -1.0 if x >= 7 else 0.5}
            for x in range(12)]
    rows.append({"tuning": "Low", "status": "error", "param.k": 0.0})
    curve = sensitivity(rows, "k", "Low", bins=4)  # edges 0, 2.75, 5.5, 8.25, 11
    assert [(b.violation.k, b.violation.n) for b in curve] == [(0, 3), (0, 3), (2, 3), (3, 3)]
    c = crossing(curve, level=0.05)
    centres = [b.centre for b in curve]
    expected = centres[1] + (0.05 - 0) / (2 / 3) * (centres[2] - centres[1])
    assert c["status"] == "crosses" and c["direction"] == "increasing" and c["value"] == pytest.approx(expected)
    summary = tuning_summary(rows, ["Low"])[0]
    assert (summary["samples"], summary["failed"]) == (13, 1)
    assert summary["violation"] == Proportion(5, 12, *wilson_interval(5, 12))


# -- local runs ---------------------------------------------------------------------


def test_rows_hold_the_draws_and_the_scenario_results(reference, tiny):
    out, rows = reference
    assert [r["sample"] for r in rows] == list(range(6))
    for row in rows:
        sample = tiny.sample(row["sample"])
        assert row["status"] == "ok" and row["error"] == ""
        assert row["param.plate_stiffness"] == sample.values["plate_stiffness"]
        assert row["sim_s"] == pytest.approx(0.3) and math.isfinite(row["force_max_N"])
        assert (row["rho_min_meas"] < 0) == (row["force_max_N"] > 0.16)  # ρ_meas = 1 − F/F_max
    assert not (out / "runs").exists()  # time series are not kept by default


def test_same_study_and_seed_give_identical_rows_on_one_worker(reference, tiny, tmp_path):
    run_study(tiny, tmp_path / "one", workers=1, progress=False)
    assert comparable(StudyStore.open(tmp_path / "one").load_rows()) == comparable(reference[1])


@pytest.mark.slow
def test_interrupted_study_resumes_without_loss_or_duplicates(reference, tmp_path):
    """SIGINT to the CLI mid-study (1 worker, samples of 1 s sim run one by one), then --resume."""
    study_file = tmp_path / "slow.toml"
    # 12 samples of 1 s: after the first two, ten remain to be interrupted even on a loaded machine
    study_file.write_text(TINY_TOML.replace("duration = 0.3", "duration = 1.0").replace("draws = 3", "draws = 6"),
                          encoding="utf-8")
    n = 12
    out = tmp_path / "study"
    # --batch-size 1: parts appear one at a time (a batch of 3 would store all three at once and
    # could end the study before the signal arrives on a loaded machine)
    cmd = [sys.executable, "-m", "softcbf.study", "run", str(study_file), "--out", str(out), "--workers", "1",
           "--batch-size", "1"]
    # as from a terminal: a job started in the background of a script (CI under nohup, `cmd &`)
    # inherits SIGINT ignored, and the child would keep ignoring it; a handler here resets to the
    # default on exec, so the child's Python raises KeyboardInterrupt as after a Ctrl-C
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    finally:
        signal.signal(signal.SIGINT, previous)
    deadline = time.monotonic() + 60
    while not len(list((out / "results").glob("sample-*.parquet"))) >= 2 and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and "--resume" in err
    store = StudyStore.open(out)
    stopped, corrupted = store.scan()
    assert corrupted == []
    assert 2 <= len(stopped) < n
    (out / "results" / f".sample-{n - 1:07d}.x.tmp").write_bytes(b"PAR1 torn")  # a part cut by a crash: ignored
    with pytest.raises(OutputDirError, match="pass --resume"):
        run_study(store.study, out, workers=1, progress=False)
    outcome = run_study(store.study, out, workers=2, resume=True, progress=False)
    assert outcome.skipped == len(stopped) and outcome.ran == n - len(stopped)
    rows = store.load_rows()
    assert [r["sample"] for r in rows] == list(range(n)) and all(r["status"] == "ok" for r in rows)
    study = load_study(study_file)
    assert [r["param.facet_offset"] for r in rows] == [study.sample(i).values["facet_offset"] for i in range(n)]


def test_a_failing_sample_is_recorded_and_the_study_goes_on(tmp_path):
    """A normal distribution's draws are unbounded, so the scenario refuses some only when they run (tau_p < 0)."""
    study = Study("fails", "mujoco_contact", ("None", "Low"), draws=2, seed=7, fixed={"t0": 25.0, "duration": 0.2},
                  vary=(Distribution("tau_p", "normal", mean=0.02, std=0.05),))
    outcome = run_study(study, tmp_path / "s", workers=2, progress=False)
    rows = StudyStore.open(tmp_path / "s").load_rows()
    assert [r["param.tau_p"] > 0 for r in rows] == [True, True, False, False]  # seed 7: 0.035, -0.097 s
    assert (outcome.ran, outcome.failed) == (4, 2)
    for row in rows:
        if row["param.tau_p"] < 0:
            assert row["status"] == "error" and row["error"].startswith("SettingError: tau_p must be >= 0 s")
            assert row["force_max_N"] is None
        else:
            assert row["status"] == "ok" and row["force_max_N"] > 0


def test_report_writes_markdown_plots_and_one_parquet(reference, tiny):
    out, rows = reference
    path = write_report(out, level=0.05, bins=3)
    text = path.read_text(encoding="utf-8")
    for s in tuning_summary(rows, ["None", "Low"]):
        v = s["violation"]
        exact = clopper_pearson_interval(v.k, v.n)
        assert (f"| {s['tuning']} | 3 | 0 | 0 | {v.k}/{v.n} | {v.p:.3f} | [{v.low:.3f}, {v.high:.3f}] "
                f"| [{exact[0]:.3f}, {exact[1]:.3f}] | {clopper_pearson_upper(v.k, v.n):.4f} |") in text
    assert "| plate_stiffness |" in text and "| facet_offset |" in text
    for name in ("rho_min_meas", "force_max_N", "violation_plate_stiffness", "violation_facet_offset"):
        assert (out / "plots" / f"{name}.png").stat().st_size > 1000
    assert "pandas.read_parquet" in text
    assert pandas.read_parquet(out / "results.parquet")["sample"].tolist() == list(range(6))


def test_report_figures_carry_units_the_assumed_value_and_f_max(reference):
    out, _ = reference
    write_report(out, level=0.05, bins=3, figure_format="svg")
    for name, texts in {"force_max_N": ["F_max = 0.16 N", "peak measured force [N]"],
                        "rho_min_meas": ["ρ = 0 (F = F_max)", "ρ_meas min [1]"],
                        "violation_plate_stiffness": ["true plate stiffness [N/m]", "assumed: 11.16"],
                        "violation_facet_offset": ["plate offset along its normal [mm]", "assumed: 0"]}.items():
        svg = (out / "plots" / f"{name}.svg").read_text(encoding="utf-8")
        for text in texts:  # matplotlib writes text into the svg as a comment beside its glyphs
            assert f"<!-- {text} -->" in svg, (name, text)
    with pytest.raises(ValueError, match="figure_format must be one of png, svg, pdf, got 'gif'"):
        write_report(out, figure_format="gif")


def test_assumed_value_reads_the_fixed_value_or_the_scenario_default():
    assert assumed_value("mujoco_contact", {"assumed_plate_stiffness": 12.0}, "plate_stiffness") == 12.0
    assert assumed_value("mujoco_contact", {}, "plate_stiffness") == 11.16  # the scenario's default
    assert assumed_value("mujoco_contact", {}, "true_gain_scale") == 1.0
    assert assumed_value("mujoco_contact", {}, "tau_p") is None
    assert assumed_value("mujoco_contact", {}, "not_a_known_parameter") is None


def test_preset_study_file_is_valid():
    study = load_study(ROOT / "studies" / "paper_tunings_plate_errors.toml")
    assert study.tunings == ("None", "Low", "High", "HW-Low", "HW-High") and study.n_samples == 1000
    assert {d.parameter for d in study.vary} == {"plate_stiffness", "facet_offset"}
