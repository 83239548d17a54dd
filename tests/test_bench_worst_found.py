"""`softcbf bench`'s worst case found (softcbf.study.worst_found): each filter's falsification over the standard
mismatch box at a fixed budget, its bench.json entry, bench.md's table, the schema and --resume.

The quick search runs 4 evaluations of 1 s on mujoco_contact (the box's first 4 vertices); the filter's
falsification folder holds every evaluation's row, so the entry is checked against the rows it summarises.
"""

import copy
import json
import math
from pathlib import Path

import pytest

from softcbf.bench import (CASES, RECOMMENDED_FILTER, WIDER_BOX, WORST_KEYS, WORST_SCHEMA, FilterSpec, RunOptions,
                           beyond_certified, case_filter_params, check_bench_json, run_bench, table_markdown,
                           worst_case_searches, worst_case_text)
from softcbf.cli import main
from softcbf.study import StudyStore, load_study
from softcbf.study.falsify import default_population
from softcbf.study.worst_found import BOX_FILE, BUDGET, QUICK_BUDGET, box_study

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

ROOT = Path(__file__).resolve().parents[1]
CONTACT = next(c for c in CASES if c.name == "mujoco_contact")


def test_the_box_is_the_standard_file_with_the_filter_as_the_contact_case_runs_it():
    box = load_study(BOX_FILE)
    assert BOX_FILE == ROOT / "studies" / "mismatch_box_contact.toml"
    for spec in (FilterSpec("paper-cbf"), FilterSpec("c-erg"), FilterSpec("e-erg", {"kappa": "0.2"})):
        study = box_study(spec.name, case_filter_params(spec, CONTACT))
        assert study.tunings == (spec.name,) and study.tuning_parameter == "filter"
        assert study.vary == box.vary and study.seed == box.seed and study.scenario == "mujoco_contact"
        assert {k: v for k, v in study.fixed.items() if k != "filter_params"} == box.fixed
        assert study.fixed["filter_params"] == case_filter_params(spec, CONTACT)
    assert box_study("paper-cbf", {"tuning": "Low"}).fixed["filter_params"] == {"tuning": "Low"}
    assert box_study("c-erg", case_filter_params(FilterSpec("c-erg"), CONTACT)).fixed["filter_params"]["contact_aware"] == "true"
    assert box_study("none", {}, duration=1.0).fixed["duration"] == 1.0


def test_a_box_with_its_own_controller_or_another_objective_is_refused(tmp_path):
    with pytest.raises(ValueError, match="fixes no controller, it fixes filter"):
        box_study("paper-cbf", {}, box_file=ROOT / "studies" / "mismatch_box_contact_cerg.toml")
    maximised = tmp_path / "box.toml"
    maximised.write_text(BOX_FILE.read_text(encoding="utf-8").replace('objective = "rho_min_meas"',
                                                                       'objective = "-force_max_N"'), encoding="utf-8")
    with pytest.raises(ValueError, match="rho_worst_found minimises rho_min_meas; the box's objective is '-force_max_N'"):
        box_study("paper-cbf", {}, box_file=maximised)


@pytest.mark.parametrize("quick, whole, given, budget", [
    (False, True, None, BUDGET), (True, True, None, QUICK_BUDGET), (True, False, None, 0), (False, False, None, 0),
    (True, False, 3, 3), (False, True, 0, 0),
])
def test_the_budget_defaults_to_the_battery_and_is_off_with_cases(quick, whole, given, budget):
    searches = worst_case_searches([FilterSpec("none")], RunOptions(quick=quick, falsify_budget=given), whole)
    if budget == 0:
        assert searches is None
        return
    settings, studies = searches
    box = load_study(BOX_FILE)
    assert settings == {"budget": budget, "box": "mismatch_box_contact", "box_file": "studies/mismatch_box_contact.toml",
                        "scenario": "mujoco_contact", "duration_s": 1.0 if quick else box.fixed["duration"],
                        "objective": "rho_min_meas", "sampler": "cmaes", "seed": box.seed,
                        "population": default_population(box), "baseline": 0}
    assert list(studies) == ["none"] and studies["none"][0].fixed["duration"] == settings["duration_s"]
    assert studies["none"][1] == [d.parameter for d in box.vary]  # "none" certifies nothing


def test_a_negative_budget_is_a_usage_error(tmp_path, capsys):
    assert main(["bench", "--out", str(tmp_path / "b"), "--quick", "--filters", "none", "--cases", "paper_sim_150",
                 "--falsify-budget", "-1"]) == 2
    assert "--falsify-budget must be >= 0" in capsys.readouterr().err and not (tmp_path / "b").exists()
    with pytest.raises(ValueError, match="--falsify-budget must be >= 0"):
        run_bench(tmp_path / "b", [FilterSpec("none")], RunOptions(quick=True, falsify_budget=-2), ["paper_sim_150"])


def _rows(folder: Path) -> list[dict]:
    return sorted(StudyStore.open(folder / "search").load_rows(), key=lambda r: r["sample"])


@pytest.mark.slow
def test_quick_worst_found_is_the_minimum_of_the_evaluations_run_and_resumes(tmp_path, capsys):
    out = tmp_path / "bench"
    argv = ["bench", "--out", str(out), "--quick", "--filters", "paper-cbf", "--cases", "paper_sim_150",
            "--falsify-budget", "4"]
    assert main(argv) == 0
    bench = json.loads((out / "bench.json").read_text())
    check_bench_json(bench)
    assert bench["falsify"]["budget"] == 4 and bench["falsify"]["box_file"] == "studies/mismatch_box_contact.toml"
    assert bench["falsify"]["duration_s"] == 1.0
    [entry] = bench["worst_found"]
    assert tuple(entry) == WORST_KEYS and entry["filter"] == "paper-cbf"
    folder = out / "cases" / "paper-cbf" / "worst_found"
    rows = _rows(folder)
    assert len(rows) == entry["evaluations"] == 4 and entry["failed"] == 0
    assert all(r["status"] == "ok" and r["tuning"] == "paper-cbf" for r in rows)
    worst = min(rows, key=lambda r: r["rho_min_meas"])
    assert entry["rho_worst_found"] == worst["rho_min_meas"] == min(r["rho_min_meas"] for r in rows)
    assert entry["evaluation"] == worst["sample"] + 1
    assert entry["params"] == {k.removeprefix("param."): v for k, v in worst.items() if k.startswith("param.")}
    assert set(entry["params"]) == {d.parameter for d in load_study(BOX_FILE).vary}
    violating = [r["sample"] + 1 for r in rows if r["rho_min_meas"] < 0]
    assert entry["first_violation"] == (violating[0] if violating else None)
    state = json.loads((folder / "falsify.json").read_text())
    assert state["study"]["fixed"]["filter_params"] == {"tuning": "Low"}  # the mujoco_contact case's paper-cbf tuning
    assert state["worst"]["value"] == entry["rho_worst_found"]  # worst/ replayed the same ρ
    table = (out / "bench.md").read_text()
    assert "## Worst case found" in table and "4 evaluations" in table and "mismatch_box_contact" in table
    assert f"| paper-cbf | {entry['rho_worst_found']:.4f} {WIDER_BOX} (plate_stiffness, " in table
    assert entry["beyond_certified"] == [d.parameter for d in load_study(BOX_FILE).vary]  # paper-cbf: the exact model
    assert f"rho_min_meas {entry['rho_worst_found']:.4f} {WIDER_BOX} (" in capsys.readouterr().out  # the printed line

    # --resume keeps a finished entry without running it
    stamp = (folder / "falsify.json").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv + ["--resume"]) == 0
    assert "paper-cbf worst case found: kept from" in capsys.readouterr().out
    assert json.loads((out / "bench.json").read_text()) == bench and (folder / "falsify.json").stat().st_mtime_ns == stamp
    # an interrupted search (its entry not written) continues in its folder: the stored evaluations are not run again
    parts = sorted((folder / "search" / "results").glob("*.parquet"))
    stamps = [p.stat().st_mtime_ns for p in parts]
    (out / "bench.json").write_text(json.dumps({**bench, "worst_found": []}))
    assert main(argv + ["--resume"]) == 0
    resumed = json.loads((out / "bench.json").read_text())
    assert [p.stat().st_mtime_ns for p in parts] == stamps
    assert {k: v for k, v in resumed["worst_found"][0].items() if k != "wall_s"} == \
        {k: v for k, v in entry.items() if k != "wall_s"}
    # another budget is another search: refused
    assert main(argv[:-1] + ["5", "--resume"]) == 2
    assert "falsify" in capsys.readouterr().err


def _with_entry(**entry) -> dict:
    """A bench.json with one quick worst-case search of the filter "none", its entry updated with `entry`."""
    settings = {"budget": 4, "box": "mismatch_box_contact", "box_file": "studies/mismatch_box_contact.toml",
                "scenario": "mujoco_contact", "duration_s": 1.0, "objective": "rho_min_meas", "sampler": "cmaes",
                "seed": 2027, "population": 9, "baseline": 0}
    found = {"filter": "none", "rho_worst_found": -0.5, "params": {"plate_stiffness": 13.392, "facet_offset": 0.002},
             "evaluation": 2, "evaluations": 4, "failed": 0, "first_violation": 1, "wall_s": 9.0, "faulted": 0,
             "fault": None, "beyond_certified": ["plate_stiffness", "facet_offset"]}
    return {"battery": [c.name for c in CASES], "quick": True, "mismatch_draws": 2, "filters": ["none"], "skipped": {},
            "results": [], "falsify": settings, "worst_found": [{**found, **entry}], "contact_under_error": []}


SPOILED = [
    (lambda b: b["worst_found"][0].pop("rho_worst_found"), "worst_found[0] lacks rho_worst_found"),
    (lambda b: b.pop("worst_found"), "it lacks worst_found"),
    (lambda b: b.update(worst_found={}), "worst_found must be a list of entries, got {}"),
    (lambda b: b.pop("falsify"), "it lacks falsify"),
    (lambda b: b.update(falsify=None), "worst_found must be [] when falsify is null"),
    (lambda b: b.update(falsify=None, worst_found={}), "worst_found must be [] when falsify is null (no search ran), got {}"),
    (lambda b: b["falsify"].pop("box"), "falsify lacks box"),
    (lambda b: b["falsify"].update(budget=0), "falsify.budget must be"),
    (lambda b: b["worst_found"][0].update(rho_worst_found=float("nan")), "worst_found[0].rho_worst_found must be a finite"),
    (lambda b: b["worst_found"][0].update(rho_worst_found="low"), "worst_found[0].rho_worst_found must be a finite"),
    (lambda b: b["worst_found"][0].update(rho_worst_found=None), "rho_worst_found must be null exactly when"),
    (lambda b: b["worst_found"][0].update(params=None), "params and evaluation must be null together"),
    (lambda b: b["worst_found"][0].update(faulted=1, fault={"type": "E", "message": "m", "where": "filter"}),
     "rho_worst_found must be null exactly when no evaluation finished or the worst one faulted"),
    (lambda b: b["worst_found"][0].update(rho_worst_found=None, fault={"type": "E", "message": "m", "where": "filter"}),
     "a fault needs faulted >= 1"),
    (lambda b: b["worst_found"][0].update(params=[1.0]), "worst_found[0].params must be null or {parameter: value}"),
    (lambda b: b["worst_found"][0]["params"].update(tau_p=float("inf")), "worst_found[0].params.tau_p must be"),
    (lambda b: b["worst_found"][0].update(evaluations=5), "failed <= evaluations <= falsify.budget"),
    (lambda b: b["worst_found"][0].update(failed=5, evaluations=4), "failed <= evaluations"),
    (lambda b: b["worst_found"][0].update(evaluation=0), "worst_found[0].evaluation must be >= 1"),
    (lambda b: b["worst_found"][0].update(first_violation=6), "worst_found[0].first_violation must be <= evaluations"),
    (lambda b: b["worst_found"][0].update(wall_s=-1.0), "worst_found[0].wall_s must be >= 0"),
    (lambda b: b["worst_found"][0].update(filter="qsg"), "worst_found[0].filter 'qsg' is not one of its filters"),
    (lambda b: b["worst_found"].append(dict(b["worst_found"][0])), "worst_found[1]: none has an entry already"),
    (lambda b: b["worst_found"][0].update(beyond_certified="plate_stiffness"), "worst_found[0].beyond_certified must be a list"),
    (lambda b: b["worst_found"][0].pop("beyond_certified"), "worst_found[0] lacks beyond_certified"),
]


@pytest.mark.parametrize("spoil, message", SPOILED)
def test_the_schema_refuses_a_bad_worst_found_naming_the_field(spoil, message):
    check_bench_json(_with_entry())
    check_bench_json(_with_entry(rho_worst_found=None, params=None, evaluation=None, failed=4, first_violation=None))
    check_bench_json(_with_entry(rho_worst_found=None, faulted=2, fault={"type": "E", "message": "m", "where": "filter"}))
    bench = copy.deepcopy(_with_entry())
    spoil(bench)
    with pytest.raises(ValueError, match=None) as error:
        check_bench_json(bench)
    assert message in str(error.value)


def test_every_worst_found_field_has_a_schema_entry():
    assert set(WORST_SCHEMA) == set(WORST_KEYS)
    assert math.isfinite(_with_entry()["worst_found"][0]["rho_worst_found"])


def test_the_worst_case_over_a_box_wider_than_the_filter_certifies_says_so():
    """Was: `bench --quick` showed the recommended filter's "worst case −0.63" with no word of why; the box is wider
    than what it certifies (plate ±20 % against its [0.9, 1.1], the offset, the arm's stiffness and damping, the valve
    lag it does not certify at all), and bench.md and the printed line now say so, naming those coordinates."""
    params = case_filter_params(RECOMMENDED_FILTER, CONTACT)
    box = box_study(RECOMMENDED_FILTER.name, params)
    beyond = beyond_certified(RECOMMENDED_FILTER.name, params, box)  # the preset's intervals, not c-erg's defaults
    # damping: certified from damping_lo_ratio = 1 up, open above; the box's 0.7 lies below (an infinite end once
    # made the tolerance infinite, and every damping "certified").
    assert beyond == ["plate_stiffness", "facet_offset", "true_stiffness_scale", "true_damping_scale", "tau_p"]
    assert "true_gain_scale" not in beyond  # its gain interval [0.9, 1.1] is the box's
    bench = _with_entry(filter="none", rho_worst_found=-0.631, beyond_certified=beyond)
    check_bench_json(bench)
    text = table_markdown(bench)
    assert f"| none | -0.6310 {WIDER_BOX} (plate_stiffness, facet_offset, true_stiffness_scale" in text
    assert worst_case_text(bench["worst_found"][0]).startswith("-0.6310 over a box wider than this filter certifies (")
    assert worst_case_text(_with_entry(beyond_certified=[])["worst_found"][0]) == "-0.5000"  # a box it certifies


def test_the_standard_box_preset_certifies_the_whole_standard_box():
    """c-erg:standard-box states an interval for every physical error of the standard box: nothing is beyond."""
    params = case_filter_params(FilterSpec("c-erg:standard-box"), CONTACT)
    assert beyond_certified("c-erg:standard-box", params, box_study("c-erg:standard-box", params)) == []


def test_a_box_within_the_certified_intervals_is_not_labelled(tmp_path):
    """A box of only the plate's stiffness within ±10 % and the gain within ±10 % lies inside what the recommended
    filter certifies at the bench's setting: nothing is beyond; the exact-model filters certify neither."""
    text = BOX_FILE.read_text(encoding="utf-8")
    narrow = text[:text.index("[vary.plate_stiffness]")] + (
        "[vary.plate_stiffness]\ndist = \"uniform\"\nlow = 10.044\nhigh = 12.276\n\n"
        "[vary.true_gain_scale]\ndist = \"uniform\"\nlow = 0.95\nhigh = 1.1\n")
    (tmp_path / "narrow.toml").write_text(narrow, encoding="utf-8")
    params = case_filter_params(RECOMMENDED_FILTER, CONTACT)
    study = box_study(RECOMMENDED_FILTER.name, params, box_file=tmp_path / "narrow.toml")
    assert beyond_certified(RECOMMENDED_FILTER.name, params, study) == []
    assert beyond_certified(RECOMMENDED_FILTER.name, {**params, "stiffness_hi_ratio": "1.05"}, study) == \
        ["plate_stiffness"]
    assert beyond_certified("c-erg", params, study) == ["plate_stiffness", "true_gain_scale"]  # the exact model
    assert beyond_certified("paper-cbf", {"tuning": "Low"}, study) == ["plate_stiffness", "true_gain_scale"]
