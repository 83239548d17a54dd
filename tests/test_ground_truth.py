"""`softcbf_mj.physics.ground_truth.build_truth`: one MuJoCo ground truth for every MuJoCo scenario, so
that mujoco_contact and camera_loop take the same ground-truth settings, with one meaning."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_environment
from scenarios import get
from scenarios.common import controller_robot
from softcbf_mj.physics.ground_truth import build_truth
from scenarios.spec import Model, Plate, TrueArm
from vocabulary.settings import DEFAULT_OVERRIDES, SETTINGS

MUJOCO_SCENARIOS = ("mujoco_contact", "camera_loop")
GROUND_TRUTH = {f.metadata["setting"] for cls in (TrueArm, Plate) for f in dataclasses.fields(cls)} | {"damping_scale"}


def test_the_ground_truth_settings_are_settings_of_the_vocabulary():
    assert GROUND_TRUTH <= set(SETTINGS)
    for name in MUJOCO_SCENARIOS:  # both scenarios hold them as the same two sections
        assert {get(name).spec.SECTIONS[k] for k in ("arm", "plate", "model")} == {TrueArm, Plate, Model}


def test_both_mujoco_scenarios_take_every_ground_truth_setting_with_one_default():
    settings = GROUND_TRUTH
    assert {"true_stiffness_scale", "true_damping_scale", "true_length_scale", "true_gain_scale", "damping_scale",
            "facet_offset", "facet_angle", "gravity", "tip_friction", "table_friction", "plate"} <= settings
    for name in MUJOCO_SCENARIOS:
        defaults = get(name).defaults()
        assert settings <= set(defaults), (name, settings - set(defaults))
    contact, camera = (get(name).defaults() for name in MUJOCO_SCENARIOS)
    differing = {s for s in settings if contact[s] != camera[s]}
    assert differing == set(DEFAULT_OVERRIDES["camera_loop"]) & settings  # the coarser rod, declared once


@pytest.mark.parametrize("name", MUJOCO_SCENARIOS)
def test_each_mujoco_scenario_validates_the_ground_truth_settings(name):
    given = {"true_stiffness_scale": 1.5, "true_damping_scale": 0.5, "true_length_scale": 1.1, "facet_angle": 0.1,
             "gravity": 9.81, "damping_scale": 2.0}
    kwargs = get(name).validate(given)
    assert {k: kwargs[k] for k in given} == given
    with pytest.raises(ValueError, match=r"facet_angle must be in \(-1.5708, 1.5708\) rad, got 2.0"):
        get(name).validate({"facet_angle": 2.0})
    with pytest.raises(ValueError, match="table_friction"):  # refused with gravity, in both
        get(name).validate({"gravity": 9.81, "table_friction": 0.5})


def test_build_truth_scales_the_arm_and_moves_the_plates():
    spec = get("mujoco_contact").build({"true_stiffness_scale": 1.5, "true_damping_scale": 0.5, "true_gain_scale": 2.0,
                                        "true_length_scale": 1.1, "damping_scale": 3.0, "facet_offset": -0.002,
                                        "facet_angle": 0.1, "gravity": 9.81})
    model = controller_robot(spec.model)
    ref = reference_robot()
    np.testing.assert_allclose(model.array("damping"), 3.0 * ref.array("damping"), rtol=1e-15)
    truth = build_truth(spec.arm, spec.plate, model, paper_environment(), spec.model.damping_scale)
    arm = truth.robot
    np.testing.assert_allclose(arm.array("stiffness"), 1.5 * ref.array("stiffness"), rtol=1e-15)
    np.testing.assert_allclose(arm.array("damping"), 0.5 * 3.0 * ref.array("damping"), rtol=1e-15)
    np.testing.assert_allclose(arm.array("gains"), 2.0 * ref.array("gains"), rtol=1e-15)
    np.testing.assert_allclose(arm.array("lengths"), 1.1 * ref.array("lengths"), rtol=1e-15)
    np.testing.assert_allclose(arm.array("inertias"), 1.21 * ref.array("inertias"), rtol=1e-15)
    c, s = math.cos(0.1), math.sin(0.1)
    np.testing.assert_allclose(truth.plates.H, [[0.36 * c - s, 0.36 * s + c]], rtol=1e-15)
    np.testing.assert_allclose(truth.plates.h, [(0.15 - 0.002 * math.hypot(0.36, 1.0)) * c], rtol=1e-15)
    assert truth.config.gravity == (0.0, -9.81, 0.0) and truth.plate_stiffness == spec.plate.stiffness


def test_camera_loop_builds_the_contact_ground_truth(tmp_path):
    """camera_loop's true plates turned by facet_angle (was: no such parameter) and its arm scaled."""
    summary = get("camera_loop").run(tmp_path, duration=0.1, tunings="None", width=320, height=180,
                                     calibration="truth", saved_frames_hz=0.0, facet_angle=0.1,
                                     true_length_scale=1.1, progress=False)
    scene = json.loads(json.dumps(summary["scene"], default=lambda a: np.asarray(a).tolist()))
    c, s = math.cos(0.1), math.sin(0.1)
    np.testing.assert_allclose(scene["plates"]["H"], [[0.36 * c - s, 0.36 * s + c]], rtol=1e-15)
    np.testing.assert_allclose(scene["facets"]["H"], [[0.36, 1.0]], rtol=0)  # the controller keeps its facet
    np.testing.assert_allclose(scene["segment_lengths_m"], [1.1 * 0.122, 1.1 * 0.122], rtol=1e-15)



def test_the_spec_s_check_builds_the_controller_once_and_keeps_it():
    """Parse once (issue 25): the spec's check builds the controller's robot, safe set, runs and nominal
    parameters (`spec.built`), the same as building them again; equality, flat(), repr and pickling ignore it."""
    import pickle

    from scenarios.common import controller_runs, model_safe_set, nominal_arguments

    spec = get("mujoco_contact").build({"damping_scale": 2.0, "tunings": "Low,High", "nominal_params": "phase=0.5"})
    controller = spec.built
    assert controller.robot == controller_robot(spec.model) and controller.runs == tuple(controller_runs(spec.filter))
    assert [r.label for r in controller.runs] == ["Low", "High"] and controller.nominal_kwargs == nominal_arguments(spec.nominal)
    again = model_safe_set(spec.model, spec.assumed_plate_stiffness)
    np.testing.assert_array_equal(controller.safe_set.H_prime, again.H_prime)
    np.testing.assert_array_equal(controller.safe_set.h_prime, again.h_prime)
    assert "built" not in spec.flat() and "built" not in repr(spec)
    assert get("mujoco_contact").spec.from_flat(spec.flat()) == spec
    assert pickle.loads(pickle.dumps(spec)).built.robot == controller.robot
