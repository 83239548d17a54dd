"""Falsification (softcbf.study.falsify), exact statistics and the sequential stop (softcbf.study.sequential).

The searches run `mujoco_contact` for 0.3 s from the sinusoid's peak (t0 = 25 s), as tests/test_study.py
does: a sample costs ≈ 0.15 s. They run on an in-process Dask cluster (threads), which starts once, where a
local pool would start anew for every generation (the command-line test runs on the local pool). The batch
form is bit for bit the single run there, so the worst case's replay is checked bit for bit.
"""

from __future__ import annotations

import json
import math
import pickle
from pathlib import Path

import pytest
from scipy.stats import beta

from softcbf.cli import main as softcbf_main
from softcbf.study import Distribution, Study, StudyStore, load_study
from softcbf.study.analysis import (Proportion, binomial_cdf, clopper_pearson_interval, clopper_pearson_upper,
                                    wilson_interval)
from softcbf.study.falsify import (TUNING_COORDINATE, Candidate, CandidateStudy, default_population, falsify,
                                   objective_value, search_space, vertex_design)
from softcbf.study.report import write_report
from softcbf.study.sequential import draws_needed, run_until_bound
from softcbf_mj.outputs.runio import OutputDirError

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

ROOT = Path(__file__).resolve().parents[1]


def box(**overrides) -> Study:
    spec = {"name": "box", "scenario": "mujoco_contact", "tunings": ("Low",), "draws": 40, "seed": 5,
            "fixed": {"t0": 25.0, "duration": 0.3, "f_max": 0.16},
            "vary": (Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),
                     Distribution("facet_offset", "uniform", low=-0.003, high=0.002))}
    spec.update(overrides)
    return Study(**spec)


# -- exact statistics ----------------------------------------------------------------


def test_clopper_pearson_known_values_and_the_zero_violation_closed_form():
    assert clopper_pearson_upper(0, 300) == pytest.approx(0.0099, abs=5e-5)  # 0 violations in 300 draws: P < 1.0 % at 95 %
    for n in (1, 2, 10, 100, 300, 1000, 10**5):
        assert clopper_pearson_upper(0, n) == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-12)
        assert clopper_pearson_interval(0, n) == pytest.approx((0.0, 1 - 0.025 ** (1 / n)), rel=1e-12)
        assert clopper_pearson_interval(n, n) == pytest.approx((0.025 ** (1 / n), 1.0), rel=1e-12)
    # Clopper & Pearson (1934) / standard tables: 5 of 10 → [0.1871, 0.8129]; 1 of 20 → [0.00127, 0.2487]
    assert clopper_pearson_interval(5, 10) == pytest.approx((0.18709, 0.81291), abs=1e-5)
    assert clopper_pearson_interval(1, 20) == pytest.approx((0.0012650, 0.24873), abs=1e-5)


def test_clopper_pearson_equals_the_beta_quantiles():
    for n in (1, 3, 17, 100, 999):
        for k in sorted({0, 1, n // 3, n // 2, n - 1, n}):
            low, high = clopper_pearson_interval(k, n, 0.9)
            assert low == (0.0 if k == 0 else pytest.approx(beta.ppf(0.05, k, n - k + 1), abs=1e-11))
            assert high == (1.0 if k == n else pytest.approx(beta.ppf(0.95, k + 1, n - k), abs=1e-11))
            upper = clopper_pearson_upper(k, n)
            assert upper == (1.0 if k == n else pytest.approx(beta.ppf(0.95, k + 1, n - k), abs=1e-11))
            assert low <= k / n <= high
            w_low, w_high = wilson_interval(k, n, 0.9)
            assert low <= w_high and w_low <= high  # both intervals overlap around k/n


def test_binomial_cdf_and_bad_counts():
    assert binomial_cdf(2, 4, 0.5) == pytest.approx(11 / 16, rel=1e-14)
    assert binomial_cdf(0, 5, 0.0) == 1.0 and binomial_cdf(4, 5, 1.0) == 0.0 and binomial_cdf(5, 5, 0.3) == 1.0
    assert clopper_pearson_interval(0, 0) == (0.0, 1.0) and clopper_pearson_upper(0, 0) == 1.0
    with pytest.raises(ValueError, match="0 <= k <= n, got k=3, n=2"):
        clopper_pearson_interval(3, 2)
    with pytest.raises(ValueError, match=r"confidence must lie in \(0, 1\), got 1.5"):
        clopper_pearson_upper(0, 10, 1.5)
    with pytest.raises(ValueError, match=r"p must lie in \[0, 1\], got 2"):
        binomial_cdf(1, 3, 2)


def test_proportion_carries_the_exact_bounds():
    p = Proportion.of([False] * 300)
    assert (p.k, p.n, p.low) == (0, 300, 0.0) and p.high == pytest.approx(3.8415 / (300 + 3.8415), rel=1e-4)
    assert p.upper == clopper_pearson_upper(0, 300) and p.exact == clopper_pearson_interval(0, 300)
    assert Proportion.of([True, False, None], confidence=0.9).exact == clopper_pearson_interval(1, 2, 0.9)


def test_sequential_stop_needs_n_star_violation_free_draws():
    n = draws_needed(0.01)
    assert n == 299 and 1 - 0.05 ** (1 / n) < 0.01 <= 1 - 0.05 ** (1 / (n - 1))
    assert draws_needed(0.5) == 5
    with pytest.raises(ValueError, match=r"until-bound target must lie in \(0, 1\), got 0"):
        draws_needed(0.0)


# -- the box ---------------------------------------------------------------------------


def test_search_space_is_the_vary_box_with_the_tuning_as_a_coordinate():
    study = box(tunings=("None", "Low"), vary=(
        Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),
        Distribution("tau_p", "loguniform", low=0.01, high=0.1),
        Distribution("links_per_segment", "choice", values=(4, 5)),
        Distribution("filter_param.slack_weight", "uniform", low=1e3, high=1e5)))
    space = search_space(study)
    assert list(space) == ["plate_stiffness", "tau_p", "links_per_segment", "filter_param.slack_weight",
                           TUNING_COORDINATE]
    assert (space["plate_stiffness"].low, space["plate_stiffness"].high, space["plate_stiffness"].log) == (8, 18, False)
    assert space["tau_p"].log and space["links_per_segment"].choices == (4, 5)
    assert space[TUNING_COORDINATE].choices == ("None", "Low")
    assert default_population(study) == 4 + int(3 * math.log(5))
    with pytest.raises(ValueError, match="vary.tau_p: falsify searches a box and dist 'normal' has no bounds"):
        search_space(box(vary=(Distribution("tau_p", "normal", mean=0.05, std=0.01),)))
    with pytest.raises(ValueError, match="varies no parameter and has one tuning"):
        search_space(box(vary=()))


def test_vertex_design_holds_every_vertex_that_fits_else_distinct_ones():
    study = box(tunings=("None", "Low"), vary=(
        Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),
        Distribution("tau_p", "loguniform", low=0.01, high=0.1),
        Distribution("links_per_segment", "choice", values=(4, 5))))
    space = search_space(study)
    vertices = vertex_design(space, 6, seed=3)
    assert sorted((v["plate_stiffness"], v["tau_p"]) for v in vertices) == [(8, 0.01), (8, 0.1), (18, 0.01), (18, 0.1)]
    assert vertex_design(space, 6, seed=3) == vertices and vertex_design(space, 6, seed=4) != vertices  # seeded order
    big = box(vary=tuple(Distribution(n, "uniform", low=0.5, high=2.0) for n in
                         ("true_stiffness_scale", "true_damping_scale", "true_gain_scale", "true_length_scale")))
    some = vertex_design(search_space(big), 6, seed=1)  # 16 vertices, 6 of them
    assert len(some) == 6 and len({tuple(v.values()) for v in some}) == 6
    assert all(x in (0.5, 2.0) for v in some for x in v.values())
    assert vertex_design({"links_per_segment": space["links_per_segment"]}, 6, seed=1) == []


def test_candidate_study_runs_candidate_e_as_sample_e_with_draw_e_seed():
    study = box()
    candidates = [Candidate({"plate_stiffness": 9.0, "facet_offset": 0.001}, "Low"),
                  Candidate({"plate_stiffness": 17.5, "facet_offset": -0.002}, "Low")]
    c = CandidateStudy.of(study, candidates)
    s = c.sample(1)
    assert (s.index, s.draw, s.tuning, s.values) == (1, 1, "Low", candidates[1].values)
    assert s.scenario_seed == study.sample(1).scenario_seed  # the seed of the study's draw 1
    assert s.kwargs["plate_stiffness"] == 17.5 and s.kwargs["tunings"] == "Low" and s.kwargs["progress"] is False
    assert c.n_samples == 2 and c.to_dict() == study.to_dict()
    assert pickle.loads(pickle.dumps(c)).sample(1) == s
    with pytest.raises(IndexError):
        c.sample(2)
    with pytest.raises(ValueError, match=r"candidate 0: plate_stiffness must lie in its box \[8, 18\], got 19"):
        CandidateStudy.of(study, [Candidate({"plate_stiffness": 19.0, "facet_offset": 0.0}, "Low")])
    with pytest.raises(ValueError, match="candidate 0: tuning must be one of"):
        CandidateStudy.of(study, [Candidate({"plate_stiffness": 9.0, "facet_offset": 0.0}, "High")])


def test_objective_is_a_study_key_and_minus_maximises(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('name = "s"\nscenario = "paper_sim"\ntunings = ["Low"]\ndraws = 2\nobjective = "-force_max_N"\n'
                    '[vary.amplitude]\ndist = "uniform"\nlow = 10.0\nhigh = 20.0\n', encoding="utf-8")
    study = load_study(path)
    assert study.objective == "-force_max_N" and Study.from_dict(study.to_dict()) == study
    assert box().objective == "rho_min_meas"
    row = {"status": "ok", "force_max_N": 0.2, "rho_min_meas": float("nan")}
    assert objective_value(row, "-force_max_N") == 0.2 and objective_value(row, "rho_min_meas") is None
    assert objective_value({**row, "status": "error"}, "-force_max_N") is None
    with pytest.raises(ValueError, match="objective must name a summary metric"):
        box(objective="-")


# -- a search end to end ------------------------------------------------------------------


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as c:
        yield c


@pytest.fixture(scope="module")
def searched(tmp_path_factory, client):
    """CMA-ES, 8 evaluations in generations of 4, a uniform baseline of 6: (folder, falsify.json)."""
    out = tmp_path_factory.mktemp("falsify") / "f"
    result = falsify(box(), out, budget=8, population=4, baseline=6, client=client, progress=False)
    return out, result


def test_falsify_stores_every_evaluation_and_finds_the_best(searched):
    out, result = searched
    rows = StudyStore.open(out / "search").load_rows()
    assert [r["sample"] for r in rows] == list(range(8)) and all(r["status"] == "ok" for r in rows)
    assert [{"plate_stiffness": r["param.plate_stiffness"], "facet_offset": r["param.facet_offset"]}
            for r in rows[:4]] == vertex_design(search_space(box()), 4, 5)  # generation 0: the 4 vertices
    assert all(r["batch_size"] == 2 for r in rows)  # a generation of 4 shared out over 2 workers
    best = min(rows, key=lambda r: r["rho_min_meas"])
    assert result["best"] == {"value": best["rho_min_meas"], "tuning": "Low", "evaluation": best["sample"] + 1,
                              "params": {"plate_stiffness": best["param.plate_stiffness"],
                                         "facet_offset": best["param.facet_offset"]}, "fault": None}
    assert (result["evaluations"], result["failed"], result["faulted"], result["status"], result["stopped"]) == \
        (8, 0, 0, "done", "budget")
    first = next((r["sample"] + 1 for r in rows if r["rho_min_meas"] < 0), None)
    assert result["first_violation"] == first
    base = StudyStore.open(out / "random").load_rows()
    uniform = box(draws=6)
    assert [(r["param.plate_stiffness"], r["param.facet_offset"]) for r in base] == [
        (uniform.sample(i).values["plate_stiffness"], uniform.sample(i).values["facet_offset"]) for i in range(6)]
    assert result["random_baseline"]["evaluations"] == 6
    assert result["random_baseline"]["best"] == min(r["rho_min_meas"] for r in base)
    saved = json.loads((out / "falsify.json").read_text())
    assert saved["best"] == result["best"] and saved["random_baseline"] == result["random_baseline"]


def test_worst_case_replays_bit_for_bit_with_run_config(searched, tmp_path):
    out, result = searched
    assert result["worst"]["value"] == result["best"]["value"]  # run alone == the batched row, bit for bit
    assert softcbf_main(["run", "--config", str(out / "worst" / "config.json"), "--out", str(tmp_path / "r")]) == 0
    replay = json.loads((tmp_path / "r" / "summary.json").read_text())["runs"][0]
    assert replay["rho_min_meas"] == result["best"]["value"]


def test_report_understands_a_falsification_folder(searched):
    out, result = searched
    text = write_report(out).read_text(encoding="utf-8")
    assert (out / "plots" / "best_so_far.png").stat().st_size > 1000
    assert f"| search | 8 | 0 | 0 | {result['best']['value']:.6g} | {result['best']['evaluation']} | Low |" in text
    assert f"| uniform random | 6 | 0 | 0 | {result['random_baseline']['best']:.6g} |" in text
    assert "equal to the search's row, bit for bit" in text
    k = sum(r["rho_min_meas"] < 0 for r in StudyStore.open(out / "random").load_rows())
    assert f"| Low | 0 | {k}/6 | {k / 6:.3f} |" in text and f"| {clopper_pearson_upper(k, 6):.4f} |" in text


def test_resume_continues_the_same_search_up_to_a_larger_budget(searched, client, tmp_path):
    out, result = searched
    copy = tmp_path / "f"
    import shutil

    shutil.copytree(out, copy)
    with pytest.raises(OutputDirError, match="exists and is not empty; pass --resume"):
        falsify(box(), copy, budget=8, population=4, baseline=0, progress=False)
    with pytest.raises(OutputDirError, match="other sampler"):
        falsify(box(), copy, budget=8, population=4, sampler="tpe", resume=True, progress=False)
    before = StudyStore.open(copy / "search").load_rows()
    again = falsify(box(), copy, budget=12, population=4, baseline=6, resume=True, client=client, progress=False)
    rows = StudyStore.open(copy / "search").load_rows()
    assert [r["sample"] for r in rows] == list(range(12)) and rows[:8] == before
    assert again["evaluations"] == 12
    assert again["best"]["value"] == min(r["rho_min_meas"] for r in rows)


def test_a_storage_url_is_used_and_never_written_and_resume_needs_it(client, tmp_path):
    url = f"sqlite:///{tmp_path / 'server.db'}"
    result = falsify(box(), tmp_path / "f", budget=2, population=2, sampler="tpe", baseline=0, storage=url,
                     client=client, progress=False)
    assert result["evaluations"] == 2 and not (tmp_path / "f" / "optuna.db").exists()
    assert url not in (tmp_path / "f" / "falsify.json").read_text() and result["storage"] == "server database (--storage)"
    with pytest.raises(OutputDirError, match="optuna.db is missing .or the search ran on a server database: resume "
                                             "with its --storage"):
        falsify(box(), tmp_path / "f", budget=4, population=2, sampler="tpe", baseline=0, resume=True, client=client,
                progress=False)
    assert not (tmp_path / "f" / "optuna.db").exists()
    again = falsify(box(), tmp_path / "f", budget=4, population=2, sampler="tpe", baseline=0, storage=url,
                    resume=True, client=client, progress=False)
    assert again["evaluations"] == 4


def test_a_misspelt_objective_is_refused_after_the_first_generation(client, tmp_path):
    with pytest.raises(ValueError, match="objective 'rho_min_mes': the scenario's rows have no column"):
        falsify(box(objective="rho_min_mes"), tmp_path / "f", budget=2, population=2, sampler="tpe", baseline=0,
                client=client, progress=False)
    with pytest.raises(ValueError, match="population must be >= 4 with sampler cmaes"):
        falsify(box(), tmp_path / "g", budget=2, population=3, progress=False)


def test_cli_falsify_stops_on_violation_and_writes_the_report(tmp_path, capsys):
    study_file = tmp_path / "box.toml"
    study_file.write_text('name = "box"\nscenario = "mujoco_contact"\ntunings = ["None"]\ndraws = 10\nseed = 1\n'
                          '[fixed]\nt0 = 25.0\nduration = 0.3\n'
                          '[vary.plate_stiffness]\ndist = "uniform"\nlow = 14.0\nhigh = 18.0\n', encoding="utf-8")
    code = softcbf_main(["study", "falsify", str(study_file), "--out", str(tmp_path / "f"), "--budget", "6",
                         "--population", "2", "--sampler", "tpe", "--stop-on-violation", "--workers", "1", "--no-progress"])
    assert code == 0
    result = json.loads((tmp_path / "f" / "falsify.json").read_text())
    # unfiltered against a stiffer plate at the sinusoid's peak: the first evaluation violates
    assert (result["first_violation"], result["evaluations"], result["stopped"]) == (1, 2, "violation")
    assert result["random_baseline"]["evaluations"] == 2 and result["random_baseline"]["first_violation"] == 1
    assert "report:" in capsys.readouterr().out and (tmp_path / "f" / "report.md").is_file()


# -- the sequential stop ------------------------------------------------------------------


def test_until_bound_draws_n_star_without_violations_and_stops_at_one(client, tmp_path):
    safe = box(tunings=("Low",), fixed={"t0": 0.0, "duration": 0.3}, draws=20,
               vary=(Distribution("plate_stiffness", "uniform", low=10.0, high=12.0),))
    out = run_until_bound(safe, tmp_path / "safe", 0.5, client=client, progress=False)
    rows = StudyStore.open(tmp_path / "safe").load_rows()
    assert len(rows) == 5 and out.draws == 5 and out.bounded == {"Low": True}  # n* = 5 for a 50 % bound
    assert out.violation["Low"].upper == pytest.approx(1 - 0.05 ** (1 / 5)) and out.outcome.ran == 5
    hit = box(tunings=("None",), draws=20, vary=(Distribution("plate_stiffness", "uniform", low=14.0, high=18.0),))
    out = run_until_bound(hit, tmp_path / "hit", 0.2, client=client, progress=False)  # n* = 14: rounds of 4 draws
    assert out.violation["None"].k >= 1 and out.settled == {"None": True} and out.bounded == {"None": False}
    assert out.draws == 4 == len(StudyStore.open(tmp_path / "hit").load_rows())


def test_cli_until_bound_refuses_samples_and_a_bad_target(tmp_path, capsys):
    study_file = ROOT / "studies" / "paper_low_plate_corner.toml"
    assert softcbf_main(["study", "run", str(study_file), "--out", str(tmp_path / "s"), "--until-bound", "0.01",
                         "--samples", "3"]) == 2
    assert "--until-bound chooses the number of samples itself" in capsys.readouterr().err
    assert softcbf_main(["study", "run", str(study_file), "--out", str(tmp_path / "s"), "--until-bound", "1.5"]) == 2
    assert "must lie in (0, 1), got 1.5" in capsys.readouterr().err


@pytest.mark.parametrize("name", ["paper_low_plate_corner", "mismatch_box_camera", "mismatch_box_contact"])
def test_shipped_boxes_load_and_are_searchable(name):
    study = load_study(ROOT / "studies" / f"{name}.toml")
    space = search_space(study)
    assert set(space) == {d.parameter for d in study.vary} and study.objective == "rho_min_meas"
    if name == "paper_low_plate_corner":
        assert (space["plate_stiffness"].low, space["plate_stiffness"].high) == (9.5, 11.4)
        assert (space["facet_offset"].low, space["facet_offset"].high) == (-0.0015, 0.0015)
        assert (study.fixed["t0"], study.fixed["duration"], study.tunings) == (15.0, 12.0, ("Low",))


def test_the_camera_box_is_the_contact_box_plus_the_sensing_errors():
    camera, contact = (load_study(ROOT / "studies" / f"mismatch_box_{name}.toml") for name in ("camera", "contact"))
    physical = {d.parameter: d for d in contact.vary}
    assert set(physical) == {"plate_stiffness", "facet_offset", "true_gain_scale", "true_stiffness_scale",
                             "true_damping_scale", "tau_p"}
    assert {d.parameter: d for d in camera.vary if d.parameter in physical} == physical  # the same ranges
    sensing = {d.parameter: (d.low, d.high) for d in camera.vary if d.parameter not in physical}
    assert sensing == {"latency": (0.0, 0.06), "pixel_noise": (0.0, 8.0), "drop_rate": (0.0, 0.2)}
    assert (camera.scenario, contact.scenario) == ("camera_loop", "mujoco_contact")
    assert default_population(camera) == 10  # 4 + ⌊3 ln 9⌋ of the 2^9 vertices


def test_cli_until_bound_prints_the_bound_it_reached(tmp_path, capsys):
    study_file = tmp_path / "safe.toml"
    study_file.write_text('name = "safe"\nscenario = "mujoco_contact"\ntunings = ["Low"]\ndraws = 20\nseed = 5\n'
                          '[fixed]\nt0 = 0.0\nduration = 0.3\n'
                          '[vary.plate_stiffness]\ndist = "uniform"\nlow = 10.0\nhigh = 12.0\n', encoding="utf-8")
    assert softcbf_main(["study", "run", str(study_file), "--out", str(tmp_path / "s"), "--until-bound", "0.5",
                         "--workers", "1", "--no-progress"]) == 0
    out = capsys.readouterr().out
    bound = clopper_pearson_upper(0, 5)
    assert f"Low: 0/5 violations (0 of them filter faults); P(violation) < {bound:.4g} at 95 % (one-sided " \
           "Clopper–Pearson)" in out
    assert f"| {bound:.4f} |" in (tmp_path / "s" / "report.md").read_text(encoding="utf-8")
