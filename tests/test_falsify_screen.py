"""Multi-fidelity falsification (softcbf.study.screen), its cheap scenario (scenarios.pcc_contact) and the
campaign over seeds (softcbf.study.campaign).

The searches run 0.3 s from the sinusoid's peak (t0 = 25 s), as tests/test_falsify.py does, on an in-process
Dask cluster (threads) that starts once.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from scenarios import get as get_scenario
from softcbf.cli import main as softcbf_main
from softcbf.study import Distribution, Study, StudyStore, load_study
from softcbf.study.campaign import campaign_row, falsify_seeds
from softcbf.study.falsify import Candidate, searched_value
from softcbf.study.report import write_report
from softcbf.study.screen import falsify_screened, ranked_candidates, screened_study
from softcbf_mj.outputs.runio import OutputDirError

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

ROOT = Path(__file__).resolve().parents[1]


def box(**overrides) -> Study:
    spec = {"name": "box", "scenario": "mujoco_contact", "tunings": ("Low",), "draws": 40, "seed": 5,
            "fixed": {"t0": 25.0, "duration": 0.3, "f_max": 0.16, "assumed_plate_stiffness": 11.16},
            "vary": (Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),
                     Distribution("facet_offset", "uniform", low=-0.003, high=0.002))}
    spec.update(overrides)
    return Study(**spec)


@pytest.fixture(scope="module")
def client():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as c:
        yield c


# -- the mapping onto the cheap scenario ----------------------------------------------------


@pytest.mark.parametrize("name", ["paper_low_plate_corner", "mismatch_box_contact", "mismatch_box_contact_cerg"])
def test_the_shipped_boxes_map_onto_pcc_contact_unchanged_but_for_the_scenario(name):
    study = load_study(ROOT / "studies" / f"{name}.toml")
    cheap = screened_study(study, "pcc_contact")
    assert cheap.scenario == "pcc_contact" and cheap.name == f"{name}_screen_pcc_contact"
    assert (cheap.vary, cheap.fixed, cheap.tunings, cheap.objective, cheap.seed) == \
        (study.vary, study.fixed, study.tunings, study.objective, study.seed)


def test_a_coordinate_the_cheap_scenario_cannot_represent_is_refused_by_name():
    with pytest.raises(ValueError, match="^--screen paper_sim cannot represent the study's varied coordinate "
                                         "'facet_offset': scenario paper_sim has no such parameter$"):
        screened_study(load_study(ROOT / "studies" / "paper_low_plate_corner.toml"), "paper_sim")
    plate_only = box(vary=(Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),))
    with pytest.raises(ValueError, match="fixed setting 'assumed_plate_stiffness'"):  # paper_sim's plate is the controller's
        screened_study(plate_only, "paper_sim")
    assert screened_study(box(vary=plate_only.vary, fixed={"t0": 25.0}), "paper_sim").scenario == "paper_sim"
    with pytest.raises(ValueError, match="varied coordinate 'links_per_segment'"):
        screened_study(box(vary=(Distribution("links_per_segment", "choice", values=(5, 10)),)), "pcc_contact")
    with pytest.raises(ValueError, match="already runs on mujoco_contact"):
        screened_study(box(), "mujoco_contact")


def test_ranked_candidates_are_worst_first_distinct_and_skip_rows_without_a_value():
    def row(sample, rho, plate, status="ok"):
        return {"sample": sample, "status": status, "tuning": "Low", "rho_min_meas": rho,
                "param.plate_stiffness": plate, "param.facet_offset": 0.0}

    rows = [row(0, 0.3, 8.0), row(1, -0.1, 18.0), row(2, 0.1, 12.0), row(3, -0.1, 18.0), row(4, None, 9.0, "error"),
            row(5, 0.1, 13.0)]
    ranked = ranked_candidates(rows, "rho_min_meas", box())
    assert [(e, v) for e, v, _ in ranked] == [(2, -0.1), (3, 0.1), (6, 0.1), (1, 0.3)]  # ties by evaluation
    assert ranked[0][2] == Candidate({"plate_stiffness": 18.0, "facet_offset": 0.0}, "Low")
    assert searched_value(rows[1], "-rho_min_meas") == 0.1  # "-NAME": the largest first
    assert [e for e, _, _ in ranked_candidates(rows, "-rho_min_meas", box())] == [1, 3, 6, 2]


# -- the cheap scenario ---------------------------------------------------------------------


def _run(tmp_path: Path, scenario: str, name: str, **params) -> dict:
    out = tmp_path / name
    out.mkdir()
    get_scenario(scenario).run(out, **{"duration": 0.5, "t0": 25.0, "tunings": "Low", "progress": False, **params})
    return json.loads((out / "summary.json").read_text())["runs"][0]


def test_pcc_contact_without_errors_is_paper_sim_and_its_errors_act_as_on_mujoco(tmp_path):
    """No error, no valve lag: the PCC plant of paper_sim, bit for bit. A stiffer, nearer plate and a stronger
    actuator push harder, as they do in mujoco_contact."""
    plain = _run(tmp_path, "pcc_contact", "plain", tau_p=0.0)
    paper = _run(tmp_path, "paper_sim", "paper", pressure_limits=True)
    assert plain["rho_min_meas"] == paper["rho_min_meas"] and plain["force_max_N"] == paper["force_max_N"]
    harder = _run(tmp_path, "pcc_contact", "harder", tau_p=0.0, plate_stiffness=14.0, facet_offset=-0.002,
                  true_gain_scale=1.1)
    assert harder["force_max_N"] > plain["force_max_N"] and harder["rho_min_meas"] < plain["rho_min_meas"]


def test_pcc_contact_batch_form_is_each_sample_run_alone(tmp_path):
    form = get_scenario("pcc_contact").batch
    base = {**get_scenario("pcc_contact").defaults(), "duration": 0.3, "t0": 25.0, "tunings": "Low",
            "progress": False, "plate_stiffness": 14.0}
    samples = [{**base, "true_gain_scale": 1.1}, {**base, "true_stiffness_scale": 0.9, "seed": 3, "q0_std": 0.01}]
    assert len({form.key(s) for s in samples}) == 1
    batched = form.run(samples, 1)
    for i, sample in enumerate(samples):
        alone = _run(tmp_path, "pcc_contact", f"alone{i}", **{k: v for k, v in sample.items()
                                                                 if k in ("duration", "t0", "plate_stiffness",
                                                                          "true_gain_scale", "true_stiffness_scale",
                                                                          "seed", "q0_std")})
        assert batched[i]["rho_min_meas"] == pytest.approx(alone["rho_min_meas"], abs=1e-12)
        assert batched[i]["force_max_N"] == pytest.approx(alone["force_max_N"], abs=1e-12)


# -- a screened search end to end -----------------------------------------------------------


@pytest.fixture(scope="module")
def screened(tmp_path_factory, client):
    """8 screened evaluations on pcc_contact, the 3 worst confirmed on mujoco_contact: (folder, falsify.json)."""
    out = tmp_path_factory.mktemp("screen") / "f"
    result = falsify_screened(box(), out, screen="pcc_contact", budget=8, confirm=3, population=4, client=client,
                              progress=False)
    return out, result


def test_a_screened_search_confirms_the_screens_worst_on_the_expensive_scenario(screened):
    out, result = screened
    cheap = StudyStore.open(out / "screen" / "search").load_rows()
    assert len(cheap) == 8
    assert StudyStore.open(out / "screen" / "search").study.scenario == "pcc_contact"
    confirmed = StudyStore.open(out / "search").load_rows()
    assert StudyStore.open(out / "search").study.scenario == "mujoco_contact" and len(confirmed) == 3
    worst_three = sorted(cheap, key=lambda r: (r["rho_min_meas"], r["sample"]))[:3]
    assert [c["screen_evaluation"] for c in result["confirmed"]] == [r["sample"] + 1 for r in worst_three]
    for c, r, cheap_row in zip(result["confirmed"], confirmed, worst_three):
        assert (r["param.plate_stiffness"], r["param.facet_offset"]) == \
            (cheap_row["param.plate_stiffness"], cheap_row["param.facet_offset"])
        assert c["screen_value"] == cheap_row["rho_min_meas"] and c["value"] == r["rho_min_meas"]
        assert c["violated"] == (r["rho_min_meas"] < 0)
    assert result["best"]["value"] == min(r["rho_min_meas"] for r in confirmed)
    assert result["expensive_evaluations"] == 4 and result["worst"]["value"] == result["best"]["value"]
    assert (result["screen"]["evaluations"], result["screen"]["scenario"]) == (8, "pcc_contact")
    text = write_report(out).read_text(encoding="utf-8")
    assert "Expensive evaluations spent: **4** on `mujoco_contact` (3 confirmations and the worst case's replay)" in text
    c = result["confirmed"][0]
    assert f"| 1 | {c['screen_evaluation']} | {c['screen_value']:.4g} | {c['value']:.4g} |" in text


def test_a_screened_search_resumes_confirming_only_the_new_candidates(screened, client, tmp_path):
    out, result = screened
    copy = tmp_path / "f"
    shutil.copytree(out, copy)
    with pytest.raises(OutputDirError, match="other screen_scenario"):
        falsify_screened(box(), copy, screen="camera_loop", budget=8, confirm=3, population=4, resume=True,
                         progress=False)
    before = StudyStore.open(copy / "search").load_rows()
    again = falsify_screened(box(), copy, screen="pcc_contact", budget=8, confirm=5, population=4, resume=True,
                             client=client, progress=False)
    rows = StudyStore.open(copy / "search").load_rows()
    assert len(rows) == 5 and rows[:3] == before and again["confirmed"][:3] == result["confirmed"]


def test_cli_refuses_a_screen_that_cannot_represent_the_box_and_confirm_without_screen(tmp_path, capsys):
    corner = str(ROOT / "studies" / "paper_low_plate_corner.toml")
    assert softcbf_main(["study", "falsify", corner, "--out", str(tmp_path / "a"), "--screen", "paper_sim",
                         "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("error: --screen paper_sim cannot represent the study's varied coordinate 'facet_offset': "
                       "scenario paper_sim has no such parameter")
    assert softcbf_main(["study", "falsify", corner, "--out", str(tmp_path / "b"), "--confirm", "3",
                         "--no-progress"]) == 2
    assert "--confirm counts the evaluations that confirm a screen" in capsys.readouterr().err
    assert softcbf_main(["study", "falsify", corner, "--out", str(tmp_path / "c"), "--seeds", "2", "--baseline", "4",
                         "--no-progress"]) == 2
    assert "--seeds runs its falsifications without --baseline" in capsys.readouterr().err
    assert not any((tmp_path / d).exists() for d in "abc")


# -- the campaign over seeds ----------------------------------------------------------------


def test_campaign_row_counts_falsified_runs_and_the_median_and_range_of_their_first_counterexample():
    def run(seed, first, evaluations):
        return {"seed": seed, "first_violation": first, "evaluations": evaluations,
                "best": {"value": -0.1 if first else 0.2, "fault": None}}

    row = campaign_row("Low", "box", [run(1, 3, 6), run(2, None, 12), run(3, 1, 6), run(4, 8, 12)])
    assert (row["runs"], row["falsified"], row["rate"], row["evaluations"]) == (4, 3, 0.75, 36)
    assert row["first_counterexample"] == {"median": 3.0, "min": 1, "max": 8}
    assert campaign_row("Low", "box", [run(1, None, 12)])["first_counterexample"] is None
    assert campaign_row("Low", "box", [run(1, 2, 6), run(2, 5, 6)])["first_counterexample"]["median"] == 3.5


def test_a_campaign_runs_every_filter_over_every_seed_and_writes_the_table(client, tmp_path, monkeypatch):
    import softcbf.study.campaign as campaign

    study = box(scenario="pcc_contact", tunings=("None", "Low"))
    calls = []
    real = campaign.falsify

    def spy(single, folder, **kwargs):
        calls.append((single.tunings, kwargs["seed"]))
        return real(single, folder, client=client, **{k: v for k, v in kwargs.items() if k not in ("workers",
                                                                                                     "scheduler")})

    monkeypatch.setattr(campaign, "falsify", spy)
    state = falsify_seeds(study, tmp_path / "c", seeds=2, seed=7, budget=4, population=4, stop_on_violation=True,
                          progress=False)
    assert calls == [(("None",), 7), (("None",), 8), (("Low",), 7), (("Low",), 8)]
    assert [r["filter"] for r in state["table"]] == ["None", "Low"] and all(r["runs"] == 2 for r in state["table"])
    for i, row in enumerate(state["table"]):
        runs = [json.loads((tmp_path / "c" / f"filter_{i}" / f"seed_{s}" / "falsify.json").read_text()) for s in (7, 8)]
        assert row == campaign_row(row["filter"], "box", runs)
    text = write_report(tmp_path / "c").read_text(encoding="utf-8")
    row = state["table"][0]
    first = row["first_counterexample"]
    shown = f"{first['median']:g} [{first['min']}, {first['max']}]" if first else "–"
    assert f"| None | box | 2 | {row['falsified']} | {row['rate']:.2f} | {shown} | {row['evaluations']} |" in text
    calls.clear()
    again = falsify_seeds(study, tmp_path / "c", seeds=2, seed=7, budget=4, population=4, stop_on_violation=True,
                          resume=True, progress=False)
    assert calls == [] and again["table"] == state["table"]  # finished runs are read, not run again
    with pytest.raises(OutputDirError, match="other seeds"):
        falsify_seeds(study, tmp_path / "c", seeds=3, seed=7, budget=4, population=4, stop_on_violation=True,
                      resume=True, progress=False)
