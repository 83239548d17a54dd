"""The flexure plate (docs/beyond-the-paper.md#flexure-plate): Euler–Bernoulli statics, the gauge, the calibration, and the plant's
readings; tip friction (μ = 0 is today's model bit for bit); gravity; the arm of any robot file."""

from __future__ import annotations

import dataclasses
import math
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from controllers.model.params import uniform_robot
from softcbf_mj.physics import mjcf as mb
from softcbf_mj.physics.flexure import FlexureParams, SheetInModel, chain_stiffness, thickness_for_tip_stiffness
from softcbf_mj.physics.flexure_calibration import calibrate_flexure, fit_thickness, load_sheet
from softcbf_mj.physics.mujoco_plant import MujocoPlant

REPO = Path(__file__).resolve().parents[1]
FLEXURE = mb.ArmModelConfig(plate="flexure")
SHEET = FLEXURE.flexures()[0]


# -- beam maths ---------------------------------------------------------------------


def test_chain_tip_stiffness_is_the_midpoint_rule_of_euler_bernoulli():
    """Σ (ℓ − s_j)² c = ℓ³/3 (1 − 1/(4n²)) for hinges at the cell centres (rigid gauge)."""
    for n in (1, 3, 10, 40):
        flex = dataclasses.replace(SHEET, links=n)
        expected = flex.euler_bernoulli_stiffness(flex.length) / (1 - 1 / (4 * n * n))
        assert flex.chain_stiffness(flex.length, gauge=False) == pytest.approx(expected, rel=1e-12)
    gauge_only = chain_stiffness(0.0, SHEET.hinge_positions(), np.full(SHEET.links, SHEET.hinge_stiffness), 1e4)
    assert gauge_only == pytest.approx(1e4, rel=1e-12)  # at the clamp only the gauge gives


def test_euler_bernoulli_thickness_gives_the_stiffness_asked_for():
    t = thickness_for_tip_stiffness(11.16, 0.15, 0.04, 2e9)
    flex = dataclasses.replace(SHEET, thickness=t)
    assert flex.euler_bernoulli_stiffness(0.15) == pytest.approx(11.16, rel=1e-12)
    assert t == pytest.approx(1.23491e-3, rel=1e-5)


def test_first_mode_and_damping():
    flex = SHEET
    area = flex.width * flex.thickness
    assert flex.first_mode == pytest.approx(3.5160 * math.sqrt(flex.bending_stiffness / (flex.density * area * flex.length**4)), rel=1e-4)
    assert flex.hinge_damping == pytest.approx(2 * 0.2 / flex.first_mode * flex.bending_stiffness / flex.cell, rel=1e-12)


# -- the sheet in MuJoCo ------------------------------------------------------------------


@pytest.mark.parametrize("load, tolerance", [(0.01, 0.003), (0.16, 0.02)])
def test_tip_stiffness_is_3EI_over_l_cubed(load, tolerance):
    """Measured 0.14 % (0.01 N) and 1.09 % (0.16 N: 14 mm of deflection stiffen the sheet) above 3EI/ℓ³."""
    result = load_sheet(FLEXURE, SHEET.length, load)
    assert result.stiffness_N_per_m == pytest.approx(float(SHEET.euler_bernoulli_stiffness(SHEET.length)), rel=tolerance)


@pytest.mark.parametrize("s", [0.10, 0.12, 0.14])
def test_stiffness_along_the_sheet_is_3EI_over_s_cubed_in_series_with_the_gauge(s):
    """Where the arm touches (s = 0.10–0.15 m): within 1 % of Euler–Bernoulli in series with the
    gauge, 1 / (s³/3EI + 1/k_g), at 0.01 N (measured ≤ 0.58 %) and 1.5 % at 0.16 N (≤ 1.0 %);
    the hinge chain's own small-deflection stiffness within 0.01 % at 0.01 N. (Nearer the
    clamp the cells are coarser for s: +2.1 % at s = 0.05 m, n = 10; models/softcbf_arm/README.md.)"""
    small = load_sheet(FLEXURE, s, 0.01)
    large = load_sheet(FLEXURE, s, 0.16)
    series = 1.0 / (1.0 / float(SHEET.euler_bernoulli_stiffness(s)) + 1.0 / SHEET.gauge_stiffness)
    assert small.stiffness_N_per_m == pytest.approx(series, rel=0.01)
    assert large.stiffness_N_per_m == pytest.approx(series, rel=0.015)
    assert small.stiffness_N_per_m == pytest.approx(float(SHEET.chain_stiffness(s)), rel=1e-4)


def test_gauge_reads_the_load_and_the_sheet_turns_as_a_beam():
    result = load_sheet(FLEXURE, 0.12, 0.05)
    assert result.gauge_N == pytest.approx(0.05, rel=1e-5)
    assert result.rotation_rad == pytest.approx(0.05 * 0.12**2 / (2 * SHEET.bending_stiffness), rel=0.01)
    assert result.rotation_rad > 0.02  # it turns: the deformation is not purely normal


def test_default_sheet_calibrates_to_the_papers_k():
    result = calibrate_flexure()
    assert result.s_m == SHEET.length
    assert result.stiffness_N_per_m == pytest.approx(11.16, abs=0.005)
    assert fit_thickness(11.16) == SHEET.thickness  # how the default thickness was chosen


def test_sheet_lies_on_the_facet_with_its_clamp_and_free_end_where_documented():
    model = mb.build_model(FLEXURE)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    H, h = np.array(mb.PAPER_H[0]), mb.PAPER_h[0]
    normal = H / np.linalg.norm(H)
    tangent = np.array([-normal[1], normal[0]])
    foot = h / np.linalg.norm(H) * normal
    for site, sigma in (("plate1_surface", SHEET.clamp_at), ("plate1_calibration", SHEET.free_end_at)):
        expected = foot + FLEXURE.tip_radius * normal + sigma * tangent
        np.testing.assert_allclose(data.site(site).xpos[:2], expected, atol=2e-6)
    sheet = SheetInModel.from_model(model, 1)
    np.testing.assert_allclose(sheet.normal, normal, atol=1e-6)
    np.testing.assert_allclose(sheet.along, -tangent, atol=1e-6)  # free end at smaller σ
    np.testing.assert_allclose(sheet.starts[1:], SHEET.hinge_positions(), atol=1e-6)
    assert model.joint("plate1_gauge").type[0] == mujoco.mjtJoint.mjJNT_SLIDE
    assert model.nq == 2 * FLEXURE.links_per_segment + 1 + SHEET.links
    total = sum(model.body_mass[b] for b in sheet.bodies[1:])
    assert total == pytest.approx(SHEET.density * SHEET.width * SHEET.thickness * (SHEET.length - SHEET.cell / 2), rel=1e-5)


def test_plant_reports_the_gauge_the_true_force_and_where_the_arm_touches():
    """Pressed quasi-statically: the gauge reads the n̂ component of the arm's total contact force
    (the clamp reaction), not the normal contact force; contact location and stiffness as documented."""
    plant = MujocoPlant.from_config(plate="flexure")
    plant.reset(np.zeros(2))
    for k in range(6000):
        state = plant.step(np.full(2, 100.0 * min(1.0, k / 4000)))
    sheet = plant.sheets[0]
    total = np.zeros(2)
    force = np.zeros(6)
    for c in range(plant.data.ncon):
        mujoco.mj_contactForce(plant.model, plant.data, c, force)
        total += (plant.data.contact[c].frame.reshape(3, 3).T @ force[:3])[:2]
    gauge = state.contact_forces[0]
    assert gauge == pytest.approx(abs(sheet.normal @ total), rel=1e-6)  # at rest
    assert gauge == pytest.approx(sheet.gauge_stiffness * plant.data.qpos[sheet.gauge_qpos], rel=1e-12)
    assert state.extras["force_solver_N"][0] > gauge * 1.02  # the sheet turned: the contact normal is not n̂
    s = state.extras["contact_s_m"][0]
    assert 0.09 < s < SHEET.length
    assert state.extras["contact_stiffness_N_per_m"][0] == pytest.approx(float(sheet.stiffness(s)), rel=1e-12)
    assert 0.015 < state.extras["plate_displacement_m"][0] < 0.04
    assert not any(key.startswith("warning_") for key in state.extras)


def test_no_contact_gives_nan_location_and_zero_deflection():
    plant = MujocoPlant.from_config(plate="flexure")
    state = plant.reset(np.zeros(2))
    assert np.isnan(state.extras["contact_s_m"][0]) and np.isnan(state.extras["contact_stiffness_N_per_m"][0])
    assert state.extras["plate_displacement_m"][0] == 0.0 and state.contact_forces[0] == 0.0


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(plate="rubber"), "plate must be one of ideal, flexure"),
        (dict(tip_friction=-0.1), "tip_friction must be finite and >= 0"),
        (dict(gravity=(0.0, 1.0)), "gravity must be 3 finite numbers"),
        (dict(flexure=(FlexureParams(), FlexureParams())), r"flexure must be one FlexureParams or one per facet \(1\)"),
    ],
)
def test_config_validation(changes, message):
    with pytest.raises(ValueError, match=message):
        mb.ArmModelConfig(**changes)


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(clamp_at=0.1, free_end_at=0.1), "clamp_at and free_end_at must be finite and differ"),
        (dict(thickness=0.0), "thickness must be finite and > 0"),
        (dict(links=0), "links must be an integer >= 1"),
        (dict(calibration_fraction=1.5), r"calibration_fraction must lie in \(0, 1\]"),
    ],
)
def test_flexure_validation(changes, message):
    with pytest.raises(ValueError, match=message):
        FlexureParams(**changes)


def test_too_wide_a_sheet_is_refused():
    with pytest.raises(ValueError, match="flexure width must be <= 0.04 m"):
        mb.build_model(mb.ArmModelConfig(plate="flexure", flexure=FlexureParams(width=0.05)))


# -- friction ----------------------------------------------------------------------------


def _press(plant: MujocoPlant, seconds: float = 1.5) -> list:
    plant.reset(np.zeros(plant.n_segments))
    return [plant.step(np.array([120.0, 120.0 if k < 700 else -40.0])) for k in range(int(seconds * 1000))]


def test_zero_friction_is_the_unchanged_model_bit_for_bit():
    """The committed scene (written before friction existed; the generator test keeps it current)
    and the model built with tip_friction = 0 give identical trajectories through contact."""
    assert mb.arm_xml(mb.ArmModelConfig(tip_friction=0.0)) == (REPO / "models/softcbf_arm/softcbf_arm.xml").read_text()
    committed = _press(MujocoPlant.from_xml(REPO / "models/softcbf_arm/scene.xml"))
    built = _press(MujocoPlant.from_config(tip_friction=0.0))
    assert max(s.contact_forces[0] for s in built) > 0.2
    for a, b in zip(committed, built):
        np.testing.assert_array_equal(a.segment_ends, b.segment_ends)
        np.testing.assert_array_equal(a.contact_forces, b.contact_forces)
        np.testing.assert_array_equal(a.extras["force_tangential_N"], 0.0)


@pytest.mark.parametrize("plate", ["ideal", "flexure"])
def test_friction_acts_within_the_coulomb_cone(plate):
    plant = MujocoPlant.from_config(plate=plate, tip_friction=0.3)
    model = plant.model
    assert model.geom_condim[model.geom("tip").id] == 3 and model.geom_friction[model.geom("tip").id][0] == pytest.approx(0.3)
    states = _press(plant)
    tangential = np.array([s.extras["force_tangential_N"][0] for s in states])
    normal = np.array([s.extras["force_solver_N"][0] for s in states])
    assert tangential.max() > 0.01
    assert np.all(tangential <= 0.3 * normal * 1.001 + 1e-9)


# -- gravity and any arm ------------------------------------------------------------------


def test_gravity_bends_the_arm_down_as_the_rod_statics_say():
    """Arm in a vertical plane (+y up), no pressure: the straight arm sags; at rest the root hinge
    balances the whole arm's weight moment, n k θ_1 = g Σ m_b x_b (small angles)."""
    g = 9.81
    plant = MujocoPlant.from_config(gravity=(0.0, -g, 0.0), H=np.zeros((0, 2)), h=())
    assert np.array_equal(plant.model.opt.gravity, [0.0, -g, 0.0])
    plant.reset(np.zeros(2))
    for _ in range(3000):
        state = plant.step(np.zeros(2))
    assert state.tip[1] < -0.005
    data, model = plant.data, plant.model
    first = model.joint("seg1_j1")
    moving = [b for b in range(first.bodyid[0], model.nbody) if model.body_rootid[b] == model.body("base").id]
    moment = g * sum(model.body_mass[b] * (data.xipos[b][0] - data.xanchor[first.id][0]) for b in moving)
    assert model.jnt_stiffness[first.id] * -data.qpos[first.qposadr[0]] == pytest.approx(moment, rel=1e-3)


@pytest.mark.parametrize("n", [1, 3])
def test_any_number_of_segments_builds_and_presses(n):
    plant = MujocoPlant.from_config(robot=uniform_robot(n), plate="flexure")
    assert plant.n_segments == n
    plant.reset(np.zeros(n))
    for _ in range(500):
        state = plant.step(np.full(n, 100.0))
    assert state.segment_ends.shape == (n + 1, 2)
    assert not any(key.startswith("warning_") for key in state.extras)


@pytest.mark.slow
def test_a_three_segment_robot_file_runs_mujoco_contact_from_the_command_line(tmp_path):
    robot = tmp_path / "robot3.json"
    uniform_robot(3).save(robot)
    out = tmp_path / "run"
    res = subprocess.run(
        [sys.executable, "-m", "scenarios", "mujoco_contact", "--out", str(out), "--robot", str(robot), "--duration", "0.2",
         "--t0", "25", "--tunings", "None,Low", "--plate", "flexure", "--progress", "false"],
        capture_output=True, text=True, timeout=600, cwd=REPO,
    )
    assert res.returncode == 0, res.stderr
    summary = __import__("json").loads((out / "summary.json").read_text())
    assert summary["scene"]["segment_lengths_m"] == [0.122] * 3
    assert [r["tuning"] for r in summary["runs"]] == ["None", "Low"]
    series = np.load(out / summary["runs"][0]["timeseries"])
    assert series["q"].shape[1] == 3 and "contact_s_m" in series and "force_tangential_N" in series


def test_written_flexure_variant_compiles_to_the_runtime_model(tmp_path):
    """Sheet, gauge, friction and gravity survive the XML writer's 6 digits exactly (as the default files)."""
    config = mb.ArmModelConfig(plate="flexure", tip_friction=0.3, gravity=(0.0, -9.81, 0.0), robot=uniform_robot(3))
    mb.write_model_files(tmp_path, config)
    from_file = mujoco.MjModel.from_xml_path(str(tmp_path / mb.SCENE_FILE))
    runtime = mb.build_model(config)
    differing = [
        name for name in dir(from_file)
        if isinstance(getattr(from_file, name), np.ndarray) and not name.startswith("_") and name not in ("tex_pathadr", "site_size")
        and not np.array_equal(getattr(from_file, name), getattr(runtime, name))
    ]
    assert differing == []
