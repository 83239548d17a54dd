"""Scenario `mujoco_contact` (docs/ground-truth.md, docs/run-outputs.md): outputs, MuJoCo extras, contact figures, determinism,
and what the unfiltered and the Low-filtered arm do against the plate.

Short runs start at t0 = 25 s, the peak of the 100 s sinusoid: the arm, straight and vented
at t = 0, reaches the plate within 0.2 s.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from controllers.model.params import reference_robot
from controllers.model.pcc import tip_position
from controllers.model.safe_set import paper_safe_set
from scenarios import get
from scenarios.run_outputs import data_only
from softcbf_mj.outputs.runio import load_timeseries
from test_scenarios import SPEC_RUN_FIELDS

DURATION, T0 = 3.0, 25.0
F_MAX = 0.16
START = dict(t0=T0, seed=3, q0_std=0.02, progress=False)
CONTACT_FIELDS = ("force_solver_max_N", "t_contact_s", "contact_switches_per_s", "force_pred_max_N", "force_err_rms_N",
                  "force_err_max_N", "penetration_bias_mean_m", "penetration_bias_max_m", "penetration_bias_mean_pct",
                  "penetration_bias_max_pct", "switches_per_s")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """None and Low for 3 s (≈ 3–6 s wall), from a seeded, slightly bent start."""
    out = tmp_path_factory.mktemp("mujoco_contact")
    with data_only():  # the summary and the time series, not the plots
        get("mujoco_contact").run(out, duration=DURATION, tunings="None,Low", **START)
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    logs = {r["tuning"]: load_timeseries(out / r["timeseries"]) for r in summary["runs"]}
    return out, summary, logs


@pytest.mark.slow
def test_summary_has_the_spec_fields_every_parameter_and_finite_contact_figures(run):
    _, summary, _ = run
    assert summary["scenario"] == "mujoco_contact"
    assert set(summary["params"]) == set(get("mujoco_contact").defaults())
    assert summary["params"]["t0"] == T0 and summary["params"]["pressure_limits"] is True
    assert isinstance(summary["versions"]["mujoco"], str)
    assert [r["tuning"] for r in summary["runs"]] == ["None", "Low"]
    for row in summary["runs"]:
        for key, kind in SPEC_RUN_FIELDS.items():
            assert isinstance(row[key], kind), (key, row[key])
        for key in CONTACT_FIELDS:
            assert isinstance(row[key], float) and math.isfinite(row[key]), (key, row[key])
        assert row["sim_s"] == pytest.approx(DURATION) and row["t_contact_s"] > 1.0


def test_time_series_hold_the_mujoco_extras_with_units(run):
    _, _, logs = run
    for arrays, units in logs.values():
        steps = int(round(DURATION / 1e-3))
        assert len(arrays["t"]) == steps and set(arrays) <= set(units)
        for key, unit in (("plate_displacement_m", "m"), ("force_solver_N", "N")):
            assert arrays[key].shape == (steps, 1) and units[key] == unit and np.all(np.isfinite(arrays[key]))
        assert not any(k.startswith("warning_") for k in arrays)  # MuJoCo raised no warning
        # The measured force is the plate's spring: k_plate · displacement.
        np.testing.assert_allclose(arrays["contact_force"], np.maximum(11.16 * arrays["plate_displacement_m"], 0), rtol=1e-6)


def test_predicted_penetration_is_the_pcc_tip_of_the_estimate(run):
    """contact_figures reads the controller's penetration off its barrier b; check it against
    the PCC tip of the logged estimate on the samples in contact."""
    _, summary, logs = run
    arrays, _ = logs["None"]
    safe = paper_safe_set()
    contact = np.flatnonzero(arrays["force_solver_N"][:, 0] > 0)[::100]
    lengths = reference_robot().array("lengths")
    from_tip = np.array([safe.penetration(tip_position(q, lengths))[0] for q in arrays["q_est"][contact]])
    from_b = np.maximum(safe.n_max - arrays["b"][contact, 0] / np.hypot(*safe.H_prime[0]), 0)
    np.testing.assert_allclose(from_b, from_tip, rtol=0, atol=1e-12)
    bias = from_tip - np.maximum(arrays["plate_displacement_m"][contact, 0], 0)
    row = summary["runs"][0]
    assert bias.max() <= row["penetration_bias_max_m"] + 1e-15
    assert row["penetration_bias_mean_pct"] == pytest.approx(100 * row["penetration_bias_mean_m"] / safe.n_max)


@pytest.mark.slow
def test_unfiltered_arm_exceeds_f_max_and_low_holds_it(run):
    """Measured (3 s from the sinusoid's peak): None presses 0.252 N (ρ_meas −0.58) for 2.8 s;
    Low peaks at 0.158 N (ρ_meas +0.011; +0.005 from a straight start) — docs/model.md#control-barrier-function allows
    violations of order 0.01 at a 1 ms hold, so the assertion leaves 0.02. The loaded rod's
    predicted penetration is biased by +0.23…0.31 mm on average (1.6–2.2 % of n_max)."""
    _, summary, _ = run
    none, low = summary["runs"]
    assert none["force_max_N"] > 1.5 * F_MAX and none["t_violation_s"] > 2.0 and none["rho_min_meas"] < -0.5
    assert low["rho_min_meas"] > -0.02 and low["t_violation_s"] < 0.05
    assert low["force_max_N"] < 0.7 * none["force_max_N"]
    for row in (none, low):
        assert 0 < row["penetration_bias_mean_pct"] < 10
        assert row["force_err_rms_N"] < 0.05 * F_MAX


def test_same_seed_gives_identical_arrays(run, tmp_path):
    """A 1 s rerun of Low with the same seed (q0 perturbed by it) reproduces the first second exactly."""
    _, _, logs = run
    with data_only():
        get("mujoco_contact").run(tmp_path, duration=1.0, tunings="Low", **START)
    again, units = load_timeseries(tmp_path / "timeseries" / "Low.npz")
    first, _ = logs["Low"]
    for key in again:
        if not units[key].startswith("us"):  # wall-clock timings (filter_us, the filter's solve_us)
            np.testing.assert_array_equal(again[key], first[key][: len(again[key])], err_msg=key)
    assert np.all(again["q"][0] != 0)  # the seed did perturb the start
