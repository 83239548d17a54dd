"""Studies run batches (docs/studies.md#batches): batched rows equal single-run rows; tasks group by key.

The study runs `mujoco_contact` for 0.3 s from the sinusoid's peak (t0 = 25 s), so the
arm presses on the plate, with the true arm, its valves' lag, the plate and q0 drawn per sample.
"""

from __future__ import annotations

import math

import pytest

from scenarios import get as get_scenario
from softcbf.study import WALL_CLOCK_COLUMNS, Distribution, Study, StudyStore, run_study
from softcbf.study.execute import Task, group_tasks
from softcbf.study.runner import batch_key

# Their scenario runs write the data alone (conftest.no_run_reports): they read rows, never a run's plots.
pytestmark = pytest.mark.usefixtures("no_run_reports")

BATCH_FIGURES = ("rho_min_pred", "rho_min_meas", "force_max_N", "t_violation_s", "infeasible_steps", "u_peak_abs_hPa",
                 "sim_s")


@pytest.fixture(scope="module")
def mismatch() -> Study:
    return Study("mismatch", "mujoco_contact", ("None", "HW-High"), draws=3, seed=7,
                 fixed={"t0": 25.0, "duration": 0.3, "q0_std": 0.05},
                 vary=(Distribution("plate_stiffness", "uniform", low=8.0, high=18.0),
                       Distribution("facet_offset", "uniform", low=-0.003, high=0.002),
                       Distribution("true_stiffness_scale", "uniform", low=0.9, high=1.1),
                       Distribution("true_gain_scale", "uniform", low=0.9, high=1.1),
                       Distribution("tau_p", "uniform", low=0.02, high=0.1)))  # the valves' own lag per sample


def test_batched_study_rows_equal_the_single_run_rows(mismatch, tmp_path):
    single = run_study(mismatch, tmp_path / "single", workers=1, batch_size=1, progress=False)
    batched = run_study(mismatch, tmp_path / "batched", workers=1, progress=False)  # default: batches
    assert (single.ran, single.failed, batched.ran, batched.failed) == (6, 0, 6, 0)
    rows_single = StudyStore.open(tmp_path / "single").load_rows()
    rows_batched = StudyStore.open(tmp_path / "batched").load_rows()
    assert [r["batch_size"] for r in rows_batched] == [3] * 6  # one batch per tuning
    assert all("batch_size" not in r or r["batch_size"] is None for r in rows_single)
    assert min(r["force_max_N"] for r in rows_single) > 0  # the samples touch the plate
    assert any(r["rho_min_meas"] < 0 for r in rows_single) and any(r["rho_min_meas"] > 0 for r in rows_single)
    for one, many in zip(rows_single, rows_batched):
        assert {k: v for k, v in one.items() if k.startswith("param.") or k in ("sample", "draw", "tuning")} == \
               {k: v for k, v in many.items() if k.startswith("param.") or k in ("sample", "draw", "tuning")}
        for name in BATCH_FIGURES:
            if one[name] is None:
                assert many[name] is None, name
            else:
                assert math.isclose(many[name], one[name], rel_tol=0.0, abs_tol=1e-9), (one["sample"], name)
    assert not set(rows_batched[0]) - set(rows_single[0]) - {"batch_size", "refused_steps"} - WALL_CLOCK_COLUMNS


def test_samples_batch_by_what_they_must_share(mismatch):
    keys = [batch_key(mismatch, i) for i in range(mismatch.n_samples)]
    assert keys[0] == keys[2] == keys[4] != keys[1] == keys[3] == keys[5]  # tunings alternate, draws share
    flexure = Study("flex", "mujoco_contact", ("Low",), draws=1, fixed={"plate": "flexure"})
    assert batch_key(flexure, 0) is None
    broken = Study("broken", "mujoco_contact", ("Low",), draws=2, seed=7,  # seed 7: tau_p 0.035, -0.097 s
                   vary=(Distribution("tau_p", "normal", mean=0.02, std=0.05),))
    assert batch_key(broken, 0) is not None
    assert batch_key(broken, 1) is None  # fails its check: runs alone and records the error
    assert get_scenario("camera_loop").batch is None


def test_group_tasks_batches_by_key_holds_a_bounded_buffer_and_flushes_at_the_end():
    key = {0: "a", 1: "b", 2: "a", 3: None, 4: "a", 5: "b", 6: "a", 7: "b"}.get
    tasks = list(group_tasks(iter(range(8)), key, batch_size=2, buffer=100))
    assert tasks == [Task((0, 2), True), Task((3,), False), Task((1, 5), True), Task((4, 6), True), Task((7,), True)]
    free = list(group_tasks(iter(range(8)), key, batch_size=3, buffer=100))
    assert free == [Task((3,), False), Task((0, 2, 4), True), Task((1, 5, 7), True), Task((6,), True)]
    held = list(group_tasks(iter(range(8)), key, batch_size=3, buffer=3))  # 3 held: the largest group goes
    assert held == [Task((0, 2), True), Task((3,), False), Task((1, 5), True), Task((4, 6), True), Task((7,), True)]
    assert sorted(i for t in held for i in t.indices) == list(range(8))
    assert [t.indices for t in group_tasks(iter(range(4)), key, batch_size=1, buffer=1)] == [(0,), (1,), (2,), (3,)]


def test_batch_size_must_be_positive(mismatch, tmp_path):
    with pytest.raises(ValueError, match="batch_size must be >= 1 .* got 0"):
        run_study(mismatch, tmp_path / "s", batch_size=0, progress=False)


def test_paper_sim_batches_equal_its_single_runs(tmp_path):
    study = Study("pcc", "paper_sim", ("None", "Low"), draws=3, seed=3,
                  fixed={"duration": 0.3, "q0_std": 0.1, "pressure_limits": True},
                  vary=(Distribution("amplitude", "uniform", low=60.0, high=150.0),))
    run_study(study, tmp_path / "single", workers=1, batch_size=1, progress=False)
    run_study(study, tmp_path / "batched", workers=1, progress=False)
    rows_single = StudyStore.open(tmp_path / "single").load_rows()
    rows_batched = StudyStore.open(tmp_path / "batched").load_rows()
    assert [r["batch_size"] for r in rows_batched] == [3] * 6 and all(r["status"] == "ok" for r in rows_single)
    assert len({r["u_peak_abs_hPa"] for r in rows_single}) == 6  # the draws differ
    for one, many in zip(rows_single, rows_batched):
        for name in BATCH_FIGURES:
            if one[name] is None:
                assert many[name] is None, name
            else:
                assert math.isclose(many[name], one[name], rel_tol=0.0, abs_tol=1e-9), (one["sample"], name)


def test_progress_counts_samples_from_the_start_to_the_end(mismatch, tmp_path, capsys):
    """The progress line starts at 0 of the samples before any worker runs and counts up to all of them (a
    running batch counts the fraction of its simulated time done: tests/test_progress_lines.py)."""
    study = Study("progress", "mujoco_contact", ("None",), draws=4, seed=7, fixed=mismatch.fixed,
                  vary=mismatch.vary)
    outcome = run_study(study, tmp_path / "s", workers=1, batch_size=2)
    assert (outcome.ran, outcome.failed) == (4, 0)
    counts = [int(line.split(" samples")[0].rsplit(" ", 1)[1].split("/")[0])
              for line in capsys.readouterr().err.splitlines() if "[study progress]" in line]
    assert counts[0] == 0 and counts[-1] == 4 and counts == sorted(counts)


def test_a_three_segment_study_batches_and_equals_its_single_runs(tmp_path):
    from controllers.model.params import uniform_robot

    robot = tmp_path / "three.json"
    uniform_robot(3).save(robot)
    study = Study("three", "mujoco_contact", ("Low",), draws=3, seed=3,
                  fixed={"robot": str(robot), "t0": 25.0, "duration": 0.2, "links_per_segment": 4},
                  vary=(Distribution("plate_stiffness", "uniform", low=9.0, high=13.0),))
    single = run_study(study, tmp_path / "single", workers=1, batch_size=1, progress=False)
    batched = run_study(study, tmp_path / "batched", workers=1, progress=False)
    assert (single.failed, batched.failed) == (0, 0)
    rows_single = StudyStore.open(tmp_path / "single").load_rows()
    rows_batched = StudyStore.open(tmp_path / "batched").load_rows()
    assert [r["batch_size"] for r in rows_batched] == [3] * 3
    for one, many in zip(rows_single, rows_batched):
        for name in BATCH_FIGURES:
            assert many[name] == pytest.approx(one[name], rel=0.0, abs=1e-9) if one[name] is not None else \
                many[name] is None, name


RAISE_ABOVE = 100.0  # hPa
FAULTY = '''
import numpy as np


class Faulty:
    """Clips u_nom to +-100 hPa, but returns NaN on calls 10-19, 1e300 hPa on calls 30-39, and raises once the
    nominal command of the first segment exceeds raise_above hPa."""

    def __init__(self, raise_above: float = 1e9):
        self.raise_above, self.calls = raise_above, 0

    def __call__(self, estimate, u_nom):
        self.calls += 1
        if u_nom[0] > self.raise_above:
            raise RuntimeError("injected fault")
        if 10 <= self.calls < 20:
            return np.array([np.nan, 0.0])
        if 30 <= self.calls < 40:
            return np.array([1e300, -1e300])
        return np.clip(u_nom, -100.0, 100.0)
'''


def test_a_faulty_filter_gives_the_same_summary_rows_in_a_run_and_in_a_batched_study_sample(tmp_path):
    """Issue 23's fault injection: a user's filter with a NaN burst, huge values and an exception (in the samples
    whose drawn amplitude exceeds 100 hPa) gives, bit for bit, the same figures and fault fields in each sample run alone as in a batch."""
    plugin = tmp_path / "faulty.py"
    plugin.write_text(FAULTY, encoding="utf-8")
    study = Study("faulty", "paper_sim", ("Low",), draws=4, seed=5,
                  fixed={"duration": 0.3, "frequency": 1.0, "pressure_limits": True, "filter": f"{plugin}:Faulty",
                         "filter_params": f"raise_above={RAISE_ABOVE}"},
                  vary=(Distribution("amplitude", "uniform", low=20.0, high=150.0),))
    run_study(study, tmp_path / "single", workers=1, batch_size=1, progress=False)
    run_study(study, tmp_path / "batched", workers=1, progress=False)
    rows_single = StudyStore.open(tmp_path / "single").load_rows()
    rows_batched = StudyStore.open(tmp_path / "batched").load_rows()
    assert [r["batch_size"] for r in rows_batched] == [4] * 4
    faulted = [r.get("fault_type") == "RuntimeError" for r in rows_single]
    assert faulted == [r["param.amplitude"] > RAISE_ABOVE for r in rows_single]
    assert any(faulted) and not all(faulted), "the draws must fault some samples and not others"
    assert all(r["refused_steps"] >= 10 for r in rows_batched)  # the NaN burst is held in every sample
    assert all(r["u_peak_abs_hPa"] < 1e3 for r in rows_single)  # 1e300 hPa clipped to the limits
    for one, many in zip(rows_single, rows_batched):
        for name in (*BATCH_FIGURES, "fault_type", "fault_where", "fault_message"):
            assert many.get(name) == one.get(name), (one["sample"], name)


@pytest.mark.parametrize("isolate", [False, True])
def test_samples_that_differ_in_filter_parameters_batch_and_equal_their_single_runs(tmp_path, isolate):
    """The fault injection with the filter's own parameter varied (`vary."filter_param.raise_above"`): the samples
    share one batch (one filter instance per simulation, each built from its sample's parameters; isolated: all in
    the batch's one filter process), and each row's figures and fault fields equal, bit for bit, those of the
    sample run alone."""
    plugin = tmp_path / "faulty.py"
    plugin.write_text(FAULTY, encoding="utf-8")
    study = Study("faulty_params", "paper_sim", ("Low",), draws=4, seed=5,
                  fixed={"duration": 0.3, "frequency": 1.0, "amplitude": 120.0, "pressure_limits": True,
                         "filter": f"{plugin}:Faulty", "isolate": isolate},
                  vary=(Distribution("filter_param.raise_above", "uniform", low=60.0, high=180.0),))
    assert len({batch_key(study, i) for i in range(study.n_samples)}) == 1
    run_study(study, tmp_path / "single", workers=1, batch_size=1, progress=False)
    run_study(study, tmp_path / "batched", workers=1, progress=False)
    rows_single = StudyStore.open(tmp_path / "single").load_rows()
    rows_batched = StudyStore.open(tmp_path / "batched").load_rows()
    assert [r["batch_size"] for r in rows_batched] == [4] * 4
    faulted = [r.get("fault_type") == "RuntimeError" for r in rows_single]
    assert faulted == [r["param.filter_param.raise_above"] < 120.0 for r in rows_single]
    assert any(faulted) and not all(faulted), "the draws must fault some samples and not others"
    for one, many in zip(rows_single, rows_batched):
        for name in (*BATCH_FIGURES, "fault_type", "fault_where", "fault_message"):
            assert many.get(name) == one.get(name), (one["sample"], name)


def test_a_built_in_batch_filter_with_varied_parameters_batches_and_equals_its_single_runs(tmp_path):
    """The paper's CBF (which has `filter_batch`) with its gamma varied: one batch, one instance per simulation, the
    same figures as each sample run alone; with gamma fixed the samples share one `filter_batch` instance."""
    study = Study("gamma", "paper_sim", ("custom",), sampling="grid", seed=3,
                  fixed={"duration": 0.5, "t0": 25.0, "amplitude": 150.0, "filter_params": "a_E=1.0;b_E=1.0"},
                  vary=(Distribution("filter_param.gamma", "choice", values=(0.05, 1.0, 20.0)),))
    run_study(study, tmp_path / "single", workers=1, batch_size=1, progress=False)
    run_study(study, tmp_path / "batched", workers=1, progress=False)
    rows_single = StudyStore.open(tmp_path / "single").load_rows()
    rows_batched = StudyStore.open(tmp_path / "batched").load_rows()
    assert [r["batch_size"] for r in rows_batched] == [3] * 3
    assert len({r["u_peak_abs_hPa"] for r in rows_single}) == 3  # the parameter changes the runs
    for one, many in zip(rows_single, rows_batched):
        for name in BATCH_FIGURES:
            assert many[name] == one[name], (one["sample"], name)
