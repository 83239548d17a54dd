"""The truth against the intervals a filter reports as certified (softcbf_mj.outputs.certified_truth)."""

import math

import numpy as np
import pytest

from scenarios import get as get_scenario
from scenarios.common import data_only
from softcbf_mj.outputs.certified_truth import CertifiedTruth, certified_truth_figures, outside_rows
from softcbf_mj.physics.ground_truth import build_truth


def test_rows_outside_their_interval_are_counted_and_nan_rows_skipped():
    lo, hi = np.array([0.9, 0.9, math.nan, 1.05]), np.array([1.1, 0.99, math.nan, 1.1])
    assert outside_rows(lo, hi, np.array([1.0])).tolist() == [False, True, False, True]
    assert outside_rows(lo, hi, np.array([0.95, 1.0])).tolist() == [False, True, False, True]  # any segment
    assert not outside_rows(np.array([0.9 / 1.1]), np.array([1.0]), np.array([0.9 / 1.1 * (1 + 1e-12)])).any()


def test_the_figures_name_the_coordinates_outside_and_their_time():
    log = {"gain_lo": np.array([0.9, 0.99, 0.995]), "gain_hi": np.array([1.1, 1.01, 0.999]),
           "plate_lo": np.full(3, 0.8), "plate_hi": np.full(3, 1.2),
           "plate_offset_lo_m": np.array([-2e-3, -2e-3, 1e-3]), "plate_offset_hi_m": np.full(3, 2e-3)}
    truth = CertifiedTruth((1.0, 1.0), 1.1, 0.0)
    assert certified_truth_figures(log, truth, 0.1) == {"certified_truth_outside_s": pytest.approx(0.1),
                                                        "certified_truth_outside": "gain,plate_offset"}
    assert certified_truth_figures(log, CertifiedTruth((1.0, 0.997), None, None), 0.1) == {
        "certified_truth_outside_s": pytest.approx(0.1), "certified_truth_outside": "gain"}
    assert certified_truth_figures({"u": np.zeros(3)}, truth, 0.1) == {}


def contact_truth(**values) -> CertifiedTruth:
    """The certified coordinates' truth of a mujoco_contact spec with `values` over its defaults."""
    scenario = get_scenario("mujoco_contact")
    spec = scenario.spec.from_flat({**scenario.defaults(), **values})
    model = spec.built
    return build_truth(spec.arm, spec.plate, model.robot, model.safe_set.environment, 1.0).certified(model.robot, 11.16)


def test_the_truth_of_a_ground_truth_is_each_segments_gain_to_stiffness_ratio_and_the_ideal_plate():
    truth = contact_truth(true_gain_scale=1.1, true_stiffness_scale=0.9, facet_offset=-0.002, plate_stiffness=13.392)
    assert truth.gain == pytest.approx((1.1 / 0.9,) * 2)
    assert truth.plate == pytest.approx(1.2) and truth.plate_offset == -0.002
    tilted = contact_truth(facet_angle=0.01)
    assert tilted.plate_offset is None and tilted.plate == pytest.approx(1.0)
    assert contact_truth(plate="flexure").plate is None


def test_a_run_whose_certified_gain_interval_excludes_the_true_gain_is_flagged(tmp_path, capsys):
    """c-erg told the gain lies in [0.9, 1.1] on an arm whose gain is 1.3: its interval excludes the truth from the
    first call, whatever the force does; the exact gain gives no time outside."""
    rows, warned = {}, {}
    for gain in (1.3, 1.0):
        out = tmp_path / f"g{gain}"
        out.mkdir()
        with data_only():
            summary = get_scenario("mujoco_contact").run(out, progress=False, duration=0.3, t0=15.0,
                                                         filter="c-erg:recommended", true_gain_scale=gain)
        rows[gain] = summary["runs"][0]
        warned[gain] = "excluded the true value" in capsys.readouterr().err
    assert rows[1.3]["certified_truth_outside"] == "gain"
    assert rows[1.3]["certified_truth_outside_s"] == pytest.approx(0.3)
    assert rows[1.0]["certified_truth_outside"] == "" and rows[1.0]["certified_truth_outside_s"] == 0.0
    assert warned == {1.3: True, 1.0: False}
