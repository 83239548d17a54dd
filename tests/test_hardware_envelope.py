"""The hardware envelope: camera_loop's damping_scale, the `hardware-like` robot preset and the envelope studies."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from controllers.model.params import REFERENCE_DAMPING, REFERENCE_STIFFNESS, reference_robot
from scenarios import get
from scenarios.common import scale_damping
from scenarios.common import ROBOT_PRESETS, load_robot
from vocabulary.project_files import project_file
from softcbf.study.definition import load_study
from softcbf_mj.physics.mjcf import DEFAULT_TAU_P

ROOT = Path(__file__).resolve().parents[1]

# The preset's documented constants (models/robots/hardware_like.json "about", docs/hardware_envelope.md).
HARDWARE_LIKE_STIFFNESS = 1.0       # N·m/rad, k_i (the reference arm's)
HARDWARE_LIKE_DAMPING = 2.8         # N·m·s/rad, d_i = 40 × the reference 0.07
HARDWARE_LIKE_TIME_CONSTANT = 2.8   # s, d_i / k_i
HARDWARE_LIKE_TAU_P = 0.05          # s, pressure lag: camera_loop's default


def test_scale_damping_multiplies_every_d_i_and_nothing_else():
    robot = reference_robot()
    scaled = scale_damping(robot, 6.5)
    assert scaled.damping == pytest.approx(tuple(6.5 * d for d in robot.damping), rel=1e-15)
    for name in ("lengths", "masses", "inertias", "stiffness", "gains", "u_min", "u_max"):
        assert getattr(scaled, name) == getattr(robot, name)
    assert scale_damping(robot, 1.0) is robot


@pytest.mark.parametrize("value", [0.0, -1.0, float("nan"), float("inf")])
def test_camera_loop_refuses_a_damping_scale_that_is_not_positive_and_finite(tmp_path, value):
    with pytest.raises(ValueError, match=r"damping_scale must be (finite and )?> 0, got"):
        get("camera_loop").run(tmp_path, damping_scale=value, duration=0.1, progress=False)


def test_hardware_like_preset_loads_with_its_documented_constants():
    robot = load_robot("hardware-like")
    reference = reference_robot()
    assert reference.stiffness == (REFERENCE_STIFFNESS,) * 2 and reference.damping == (REFERENCE_DAMPING,) * 2
    assert robot.stiffness == pytest.approx((HARDWARE_LIKE_STIFFNESS,) * 2, rel=1e-12)
    assert robot.damping == pytest.approx((HARDWARE_LIKE_DAMPING,) * 2, rel=1e-12)
    for d, k in zip(robot.damping, robot.stiffness):
        assert d / k == pytest.approx(HARDWARE_LIKE_TIME_CONSTANT, rel=1e-12)
    # Everything but the damping is the reference arm's: the preset is the reference arm, slowed.
    assert robot.replace(damping=reference.damping) == reference
    assert DEFAULT_TAU_P == HARDWARE_LIKE_TAU_P
    about = json.loads(project_file(ROBOT_PRESETS["hardware-like"]).read_text(encoding="utf-8"))["about"]
    assert about["time_constant_d_over_k_s"] == HARDWARE_LIKE_TIME_CONSTANT
    assert about["damping_d_Nms_per_rad"] == HARDWARE_LIKE_DAMPING
    assert about["stiffness_k_Nm_per_rad"] == HARDWARE_LIKE_STIFFNESS
    assert about["tau_p_s"] == HARDWARE_LIKE_TAU_P
    assert (about["control_rate_Hz"], about["frame_rate_fps"]) == (50.0, 50.0)  # where the ordering was measured
    assert "not calibrated" in about["why"].lower()


def test_unknown_robot_name_lists_the_presets():
    with pytest.raises(ValueError, match=r"robot must be 'reference', one of hardware-like, three-segment or a robot JSON file, "
                                         r"got 'hardware-lik' \(no such file\)"):
        load_robot("hardware-lik")


@pytest.mark.parametrize("suffix, rate, tunings", [("", 10.0, ("None", "HW-Low", "HW-High")),
                                                    ("_20hz", 20.0, ("HW-Low", "HW-High")),
                                                    ("_50hz", 50.0, ("HW-Low", "HW-High"))])
def test_envelope_studies_are_the_documented_grids(suffix, rate, tunings):
    study = load_study(ROOT / "studies" / f"hardware_envelope{suffix}.toml")
    assert study.scenario == "camera_loop" and study.sampling == "grid" and study.tunings == tunings
    assert study.fixed["control_rate"] == rate and study.fixed["frame_rate"] == max(12.8, rate)
    assert study.fixed["t0"] == 0.0 and study.fixed["duration"] == 35.0
    assert study.n_samples == 12 * len(tunings)
    scales = sorted({study.sample(i).values["damping_scale"] for i in range(study.n_samples)})
    assert scales == [1.0, 2.5, 6.3, 16.0, 40.0, 100.0]
    assert sorted({study.sample(i).values["tau_p"] for i in range(study.n_samples)}) == [0.05, 0.2]
    # τ_p varies slowest, so the first half of the samples is the τ_p = 0.05 s row.
    assert {study.sample(i).values["tau_p"] for i in range(study.n_samples // 2)} == {0.05}


def _map_tool():
    spec = importlib.util.spec_from_file_location("hardware_envelope_map", ROOT / "tools" / "hardware_envelope_map.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_map_ordering_and_boundaries_on_a_hand_made_grid():
    tool = _map_tool()
    assert tool.ordering_holds({"None": -0.78, "HW-Low": 0.594, "HW-High": 0.767}) is True
    assert tool.ordering_holds({"None": -0.37, "HW-Low": 0.070, "HW-High": 0.0007}) is False  # Low > High
    assert tool.ordering_holds({"None": -0.5, "HW-Low": 0.1}) is None
    # One row (10 Hz, τ_p 0.05 s): HW-High holds at 2.8 and 7 s, HW-Low at 0.44 s and 7 s only.
    cells = {(10.0, 0.05, 0.44): {"None": -0.5, "HW-Low": 0.01, "HW-High": -0.02},
             (10.0, 0.05, 2.8): {"None": -0.4, "HW-Low": -0.01, "HW-High": 0.02},
             (10.0, 0.05, 7.0): {"None": -0.2, "HW-Low": 0.01, "HW-High": 0.02}}
    found = {b["tuning"]: b for b in tool.boundaries(cells)}
    assert (found["HW-High"]["holds_from_dk_s"], found["HW-High"]["violates_at_dk_s"]) == (2.8, 0.44)
    assert (found["HW-Low"]["holds_from_dk_s"], found["HW-Low"]["violates_at_dk_s"]) == (7.0, 2.8)
    assert (found[tool.ORDERING]["holds_from_dk_s"], found[tool.ORDERING]["violates_at_dk_s"]) == (7.0, 2.8)
