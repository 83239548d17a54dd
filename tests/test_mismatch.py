"""Model-mismatch parameters of `mujoco_contact`: they act on the true arm and plate only, and
their defaults build exactly the unchanged model (the same MJCF, so a bit-identical run)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

import softcbf_mj.physics.flexure_calibration  # noqa: F401 -- imported before the spy: they keep the real build_model
import softcbf_mj.physics.mjcf as mb
import softcbf_mj.physics.mujoco_batch_plant  # noqa: F401
import softcbf_mj.physics.mujoco_plant  # noqa: F401
from controllers.model.params import reference_robot
from scenarios import get
from scenarios.run_outputs import data_only
from softcbf_mj.physics.mjcf import ArmModelConfig, arm_xml

SHORT = dict(duration=0.3, t0=25.0, tunings="None", progress=False)


@pytest.fixture
def built(monkeypatch):
    """Run the scenario with the plant's model recorded: returns run(**params) -> (its ArmModelConfig's fields, summary)."""
    calls = []
    original = mb.build_model  # mujoco_contact imports it when it runs (issue 27), so it calls the spy

    def spy(config, *args, **kwargs):
        calls.append({f.name: getattr(config, f.name) for f in dataclasses.fields(config)})
        return original(config, *args, **kwargs)

    monkeypatch.setattr(mb, "build_model", spy)

    def run(tmp_path, **params):
        tmp_path.mkdir(parents=True, exist_ok=True)
        with data_only():  # the figures and the model built, not the plots
            summary = get("mujoco_contact").run(tmp_path, **{**SHORT, **params})
        return calls[-1], summary["runs"][0]

    return run


def test_defaults_build_the_reference_arm_and_the_paper_plate_exactly(built, tmp_path):
    changes, _ = built(tmp_path)
    config = ArmModelConfig(**changes)
    assert config.robot == reference_robot()
    assert config.H == ((0.36, 1.0),) and config.h == (0.15,)
    assert arm_xml(config) == arm_xml(ArmModelConfig())  # the same model, hence the same run


def test_true_arm_scales_change_the_plant_not_the_controller(built, tmp_path):
    changes, row = built(tmp_path, true_stiffness_scale=1.5, true_damping_scale=0.5, true_gain_scale=2.0,
                         true_length_scale=1.1, tunings="Low")
    ref, true = reference_robot(), changes["robot"]
    np.testing.assert_allclose(true.array("stiffness"), 1.5 * ref.array("stiffness"), rtol=1e-15)
    np.testing.assert_allclose(true.array("damping"), 0.5 * ref.array("damping"), rtol=1e-15)
    np.testing.assert_allclose(true.array("gains"), 2.0 * ref.array("gains"), rtol=1e-15)
    np.testing.assert_allclose(true.array("lengths"), 1.1 * ref.array("lengths"), rtol=1e-15)
    np.testing.assert_allclose(true.array("inertias"), 1.21 * ref.array("inertias"), rtol=1e-15)
    assert true.masses == ref.masses and true.u_max == ref.u_max
    assert row["rho_min_pred"] is not None  # the controller ran with its own (reference) model


def test_facet_offset_and_angle_move_the_true_plate(built, tmp_path):
    offset, angle = -0.002, 0.1
    changes, _ = built(tmp_path, facet_offset=offset, facet_angle=angle)
    H, h = np.array(changes["H"]), np.array(changes["h"])
    H0, h0 = np.array([0.36, 1.0]), 0.15
    n0 = H0 / np.linalg.norm(H0)
    foot = (h0 / np.linalg.norm(H0) + offset) * n0  # foot of the perpendicular, moved along the normal
    n = H[0] / np.linalg.norm(H[0])
    assert np.linalg.norm(H[0]) == pytest.approx(np.linalg.norm(H0), rel=1e-15)
    assert math.atan2(n[1], n[0]) - math.atan2(n0[1], n0[0]) == pytest.approx(angle, abs=1e-12)  # turned ccw
    assert H[0] @ foot == pytest.approx(h[0], abs=1e-15)  # the turned facet passes through the moved foot


@pytest.mark.slow
def test_mismatch_changes_the_measured_force(built, tmp_path):
    """Unfiltered, 0.3 s from the sinusoid's peak: measured 0.253 N nominal; a plate 2 mm closer
    presses harder (0.272 N); an arm 1.5× stiffer bends less and barely touches (0.032 N)."""
    _, nominal = built(tmp_path / "a")
    _, closer = built(tmp_path / "b", facet_offset=-0.002)
    _, stiffer = built(tmp_path / "c", true_stiffness_scale=1.5)
    assert nominal["force_max_N"] == pytest.approx(0.253, abs=0.01)
    assert closer["force_max_N"] > nominal["force_max_N"] + 0.01
    assert stiffer["force_max_N"] < 0.5 * nominal["force_max_N"]


@pytest.mark.parametrize("param, value, message", [
    ("true_stiffness_scale", 0.0, r"true_stiffness_scale must be in \[0.001, 1000\], got 0.0"),
    ("true_length_scale", float("nan"), r"true_length_scale must be finite and in \[0.001, 1000\]"),
    ("facet_angle", 2.0, r"facet_angle must be in \(-1.5708, 1.5708\) rad, got 2.0"),
    ("facet_offset", 1e300, r"facet_offset must be in \[-1, 1\] m, got 1e\+300"),
])
def test_bad_mismatch_values_are_refused(tmp_path, param, value, message):
    with pytest.raises(ValueError, match=message):
        get("mujoco_contact").run(tmp_path, **{**SHORT, param: value})
