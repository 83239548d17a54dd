"""Contact under error in `softcbf bench` (softcbf.bench): the push draws over the standard box on both plants, the
push on the flexure sheet, their figures from stored rows and bench.json's "contact_under_error"."""

import numpy as np
import pytest

from softcbf.bench import (CASES, CONTACT_KEYS, FLEXURE_ASKED_N, PRINT_WIDTH, PUSH_BOX_DRAWS, PUSH_BOX_FILES,
                           PUSH_DURATION_S, PUSHES, QUICK_PUSH_BOX_DRAWS, QUICK_PUSH_DURATION_S, FilterSpec, RunOptions,
                           case_filter_params, check_bench_json, contact_text, contact_under_error, draw_figures,
                           planned_cases, push_box_study, run_bench, table_markdown)
from softcbf.study.analysis import clopper_pearson_upper
from softcbf.study.definition import load_study
from vocabulary.project_files import project_file

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

CASE = {c.name: c for c in CASES}
BOX_CASES = ("mujoco_push_box", "camera_push_box")
RECOMMENDED = FilterSpec("c-erg:recommended")


@pytest.mark.parametrize("name, plant", [("mujoco_push_box", "mujoco_contact"), ("camera_push_box", "camera_loop")])
def test_push_draws_run_the_150_hpa_push_over_the_standard_box_full_and_quick(name, plant):
    """≥ 100 draws in the full bench, 3 in --quick; the box is its file's (the camera's with noise 0–8 grey levels and
    drops 0–20 %), the push the 150 hPa push of the exact-plate case, the filter's parameters those of the case."""
    case = CASE[name]
    assert case.scenario_params["scenario"] == plant and case.resumable and case.rate == ("1kHz" if plant == "mujoco_contact" else "camera")
    assert case.draws(RunOptions()) == PUSH_BOX_DRAWS >= 100 and case.draws(RunOptions(quick=True)) == QUICK_PUSH_BOX_DRAWS == 3
    assert case.draws(RunOptions(mismatch_draws=7)) == PUSH_BOX_DRAWS
    assert case.quick_duration_s() == QUICK_PUSH_DURATION_S >= 3.0
    box = load_study(project_file(PUSH_BOX_FILES[plant]))
    for draws, duration in ((case.draws(RunOptions()), PUSH_DURATION_S), (case.draws(RunOptions(quick=True)), QUICK_PUSH_DURATION_S)):
        study = push_box_study(RECOMMENDED, case, draws, duration)
        assert study.scenario == plant and study.draws == draws and study.sampling == "monte_carlo"
        assert study.vary == box.vary and study.seed == box.seed
        assert study.tunings == ("c-erg:recommended",) and study.tuning_parameter == "filter"
        assert study.fixed["duration"] == duration and "t0" not in study.fixed
        assert study.fixed["nominal"] == "step"
        assert study.fixed["nominal_params"] == {"seed": "0", "low_hPa": "150", "high_hPa": "150"}
        assert study.fixed["filter_params"] == case_filter_params(RECOMMENDED, case) == {"contact_aware": "true"}
    ranges = {d.parameter: (d.low, d.high) for d in box.vary}
    assert ranges["plate_stiffness"] == pytest.approx((0.8 * 11.16, 1.2 * 11.16))
    assert ranges["facet_offset"] == (-0.002, 0.002) and ranges["tau_p"] == (0.02, 0.1)
    if plant == "camera_loop":
        assert ranges["pixel_noise"] == (0.0, 8.0) and ranges["drop_rate"] == (0.0, 0.2)
    else:
        assert "pixel_noise" not in ranges


def test_the_new_cases_are_planned_for_every_filter_and_the_flexure_case_asks_beyond_f_max():
    specs = [RECOMMENDED, FilterSpec("none")]
    names = [*BOX_CASES, "mujoco_push_flexure"]
    assert [(s.label, c.name) for s, c in planned_cases(specs, names, {})] == [(s.label, n) for s in specs for n in names]
    flexure = CASE["mujoco_push_flexure"]
    assert flexure.scenario_params["plate"] == "flexure" and flexure.scenario_params["duration"] == PUSH_DURATION_S
    assert flexure.scenario_params["nominal_params"] == PUSHES["mujoco_contact"]["push_150hPa"][0]
    assert flexure.asked_N == FLEXURE_ASKED_N > 0.16 and flexure.quick_duration_s() == QUICK_PUSH_DURATION_S
    assert case_filter_params(RECOMMENDED, flexure) == {"contact_aware": "true"}


def _run(rho, fault=None):
    row = {"rho_min_meas": rho, "t_violation_s": 0.0 if rho >= 0 else 0.5, "force_max_N": 0.15}
    if fault:
        row.update(status="fault", fault_type=fault, fault_message="boom", fault_where="filter")
    calls = {"t": np.array([0.0, 0.1]), "u": np.ones((2, 2)), "u_nom": np.ones((2, 2)), "filter_us": np.array([5.0, 7.0])}
    return row, calls


def test_a_faulted_draw_is_a_violation_never_a_pass_and_delivered_figures_skip_it():
    """Three draws: ρ 0.2 (0.12 N), ρ 0.1 (0.16 N), and one whose filter faulted at ρ 0.3 before its fault: two
    clean draws, yet one violation of three, no least ρ (no verdict), delivered min and median of the clean two."""
    fig = draw_figures([_run(0.2), _run(0.1), _run(0.3, "RuntimeError")], [0.12, 0.16, None], 0.16)
    assert fig["draws"] == 3 and fig["violations"] == 1 and fig["violation_probability"] == pytest.approx(1 / 3)
    assert fig["violation_cp95_upper"] == clopper_pearson_upper(1, 3)
    assert fig["rho_min_meas"] is None and fig["faulted"] == 1 and fig["fault"]["type"] == "RuntimeError"
    assert fig["force_delivered_min_ratio"] == pytest.approx(0.75) and fig["force_delivered_median_ratio"] == pytest.approx(0.875)
    clean = draw_figures([_run(0.2), _run(-0.1), _run(0.3)], [0.12, 0.17, 0.14], 0.16)
    assert clean["violations"] == 1 and clean["rho_min_meas"] == -0.1 and clean["faulted"] == 0
    assert clean["force_delivered_median_ratio"] == pytest.approx(0.14 / 0.16)
    none = draw_figures([_run(0.2)] * 100, [0.12] * 100, 0.16)
    assert none["violations"] == 0 and none["violation_cp95_upper"] == pytest.approx(1 - 0.05 ** (1 / 100))
    every = draw_figures([_run(0.2, "E"), _run(0.2, "E")], [None, None], 0.16)
    assert every["violations"] == 2 and every["force_delivered_min_ratio"] is None
    with pytest.raises(ValueError, match="one delivered force per draw"):
        draw_figures([_run(0.2)], [], 0.16)


def _row(filter_, case, **fields):
    row = {"filter": filter_, "case": case, "rho_min_meas": 0.1, "t_violation_s": 0.0, "force_max_N": 0.15,
           "violation_probability": None, "violation_ci95": None, "draws": None, "u_dev_rms_hPa": 1.0, "blocked_s": 0.0,
           "switches_per_s": 0.0, "filter_us_median": 10.0, "filter_us_p99": 20.0, "nominal_acceptance": 0.5,
           "wall_s": 1.0, "force_asked_N": None, "force_delivered_N": None, "force_delivered_ratio": None,
           "force_budget_used": 0.9, "f_max_N": 0.16, "faulted": 0, "fault": None, "violations": None,
           "violation_cp95_upper": None, "force_delivered_min_ratio": None, "force_delivered_median_ratio": None}
    return {**row, **fields}


def _box_row(filter_, case, violations, draws=3, **fields):
    return _row(filter_, case, draws=draws, violations=violations, violation_probability=violations / draws,
                violation_ci95=[0.0, 0.9], violation_cp95_upper=clopper_pearson_upper(violations, draws),
                force_asked_N=0.63, force_delivered_min_ratio=0.5, force_delivered_median_ratio=0.7, **fields)


def _bench(results):
    filters = list(dict.fromkeys(r["filter"] for r in results))
    return {"battery": [c.name for c in CASES], "quick": True, "mismatch_draws": 2, "filters": filters, "skipped": {},
            "results": results, "falsify": None, "worst_found": [], "contact_under_error": contact_under_error(results)}


def test_contact_under_error_per_filter_and_plant_from_stored_rows():
    results = [
        _row("c-erg:recommended", "mujoco_push_150hPa", force_asked_N=0.63757, force_delivered_N=0.128,
             force_delivered_ratio=0.8),
        _box_row("c-erg:recommended", "mujoco_push_box", 1, rho_min_meas=-0.02),
        _row("c-erg:recommended", "mujoco_push_flexure", rho_min_meas=0.013, force_asked_N=FLEXURE_ASKED_N,
             force_delivered_N=0.144, force_delivered_ratio=0.9),
        _box_row("c-erg:recommended", "camera_push_box", 0),
        _row("none", "paper_sim_150"),
    ]
    entries = contact_under_error(results)
    assert [(e["filter"], e["plant"]) for e in entries] == [("c-erg:recommended", "mujoco_contact"),
                                                          ("c-erg:recommended", "camera_loop")]
    mujoco, camera = entries
    assert tuple(mujoco) == CONTACT_KEYS
    assert mujoco["draws"] == 3 and mujoco["violations"] == 1 and mujoco["rho_min_meas"] == -0.02
    assert mujoco["violation_cp95_upper"] == clopper_pearson_upper(1, 3)
    assert mujoco["delivered_nominal_ratio"] == pytest.approx(0.8) and mujoco["delivered_min_ratio"] == 0.5
    assert mujoco["delivered_median_ratio"] == 0.7
    assert mujoco["flexure_ratio"] == pytest.approx(0.9) and mujoco["flexure_rho_min_meas"] == 0.013
    assert camera["violations"] == 0 and camera["delivered_nominal_ratio"] is None and camera["flexure_ratio"] is None
    bench = _bench(results)
    check_bench_json(bench)
    text = table_markdown(bench)
    assert "## Contact under error" in text and "| c-erg:recommended | mujoco_contact | 3 | 1 |" in text
    assert "| 0.800 | 0.500 | 0.700 | 0.0130 | 0.900 |" in text


def test_a_faulted_push_delivers_nothing_at_the_nominal_plate():
    faulted = _row("x", "camera_push_150hPa", rho_min_meas=None, t_violation_s=None, faulted=1,
                   fault={"type": "E", "message": "m", "where": "filter"}, force_asked_N=0.63)
    (entry,) = contact_under_error([faulted])
    assert entry["plant"] == "camera_loop" and entry["delivered_nominal_ratio"] is None and entry["draws"] is None


SPOILED = [
    (lambda b: b.pop("contact_under_error"), "it lacks contact_under_error"),
    (lambda b: b["contact_under_error"][0].update(violations=0),
     "contact_under_error[0].violations must be 1 (what its result rows give), got 0"),
    (lambda b: b["contact_under_error"][0].pop("flexure_ratio"), "contact_under_error must be a list of objects with"),
    (lambda b: b["contact_under_error"].pop(), "contact_under_error must hold 1 entries"),
    (lambda b: b["results"][0].update(violations=4), "results[0].violations must be <= draws (3), got 4"),
    (lambda b: b["results"][0].update(violation_cp95_upper=None), "must be null together"),
    (lambda b: b["results"][0].update(violation_cp95_upper=1.5), "results[0].violation_cp95_upper must be in [0, 1]"),
    (lambda b: b["results"][0].update(force_delivered_min_ratio=-0.1), "results[0].force_delivered_min_ratio"),
]


@pytest.mark.parametrize("spoil, message", SPOILED)
def test_the_schema_refuses_contact_figures_that_its_rows_do_not_give(spoil, message):
    bench = _bench([_box_row("c-erg", "mujoco_push_box", 1)])
    check_bench_json(bench)
    spoil(bench)
    with pytest.raises(ValueError, match=None) as err:
        check_bench_json(bench)
    assert message in str(err.value)


def test_the_printed_table_keeps_within_120_columns():
    long = "c-erg(" + ",".join(f"p{i}=0.{i}" for i in range(30)) + ")"
    entries = contact_under_error([_box_row(long, "mujoco_push_box", 0), _box_row("e-erg", "camera_push_box", 2)])
    lines = contact_text(entries, {long: "c-erg(p0=0.0,…)"})
    assert len(lines) == 3 and all(len(line) <= PRINT_WIDTH for line in lines)
    assert "c-erg(p0=0.0,…)" in lines[1] and "mujoco_contact" in lines[1] and "0.700" in lines[1]
    wide = contact_text(entries, {})  # a label too long for the line is cut, the figures kept
    assert all(len(line) <= PRINT_WIDTH for line in wide) and wide[2].rstrip().endswith("–")


def test_push_draws_whose_filter_faults_are_violations_in_a_real_quick_bench(tmp_path):
    """A filter that raises at its first call, through the study machinery: every draw faulted, so 3 violations of 3
    (never a pass), no least ρ_meas, no delivered force; bench.json passes its check."""
    import json

    plugin = tmp_path / "raising.py"
    plugin.write_text("class RaiseFirst:\n    def __call__(self, estimate, u_nom):\n"
                      "        raise RuntimeError('boom at the first call')\n", encoding="utf-8")
    spec = FilterSpec(f"{plugin}:RaiseFirst")
    bench = run_bench(tmp_path / "b", [spec], RunOptions(quick=True), cases=["mujoco_push_box"])
    check_bench_json(json.loads((tmp_path / "b" / "bench.json").read_text(encoding="utf-8")))
    (row,) = bench["results"]
    assert row["draws"] == 3 and row["violations"] == 3 and row["faulted"] == 3 and row["violation_probability"] == 1.0
    assert row["rho_min_meas"] is None and row["force_delivered_min_ratio"] is None
    assert row["violation_cp95_upper"] == 1.0
    (entry,) = bench["contact_under_error"]
    assert entry["plant"] == "mujoco_contact" and entry["violations"] == 3 and entry["delivered_median_ratio"] is None
    assert "| RuntimeError in the filter (3 runs) |" in (tmp_path / "b" / "bench.md").read_text(encoding="utf-8")
