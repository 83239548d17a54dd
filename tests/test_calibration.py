"""Calibration of K, D, Λ (softcbf_mj.physics.calibration, tools/calibrate.py).

On data of the PCC model itself the fit is exact up to the plant's integration error; on
the MuJoCo rod it recovers the built values when given the rod's own inertia, and with the
controller's (augmented-body) inertia segment 2 comes out scaled by that model's inertia
error — both measured here, the reasons in the module docstring and the model README.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from controllers.model.dynamics import PCCDynamics
from controllers.model.params import RobotParams, reference_robot
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.physics import calibration as cal
from softcbf_mj.physics.pcc_plant import PCCPlant

ROBOT = reference_robot()
DT = 1e-3
TOOL = Path(__file__).resolve().parents[1] / "tools" / "calibrate.py"


def errors(result: cal.CalibrationResult) -> dict[str, np.ndarray]:
    return {k: np.abs(np.array(v)) for k, v in result.relative_errors().items()}


@pytest.fixture(scope="module")
def pcc_recording() -> cal.Recording:
    """10 s of babbling on the PCC model (ROS2 at 1 ms, ideal actuator): ≈ 2 s."""
    plant = PCCPlant(ROBOT, paper_safe_set())
    return cal.record(plant, cal.babbling_commands(10.0, DT, ROBOT.u_min, ROBOT.u_max, seed=2))


@pytest.fixture(scope="module")
def mujoco_recording() -> tuple[cal.MujocoPlant, cal.Recording]:
    """15 s of babbling on the MuJoCo arm without plates (defaults: n = 10, τ_p = 0.05 s): ≈ 5 s."""
    plant = cal.free_mujoco_plant()
    return plant, cal.record(plant, cal.babbling_commands(15.0, DT, plant.u_min, plant.u_max, seed=1))


def test_pcc_data_recover_k_d_lambda_to_1e_3(pcc_recording):
    """Zero-order-held commands, q̈ from q̇: the residual error is ROS2's at 1 ms (2e-4 at 0.25 ms)."""
    rec = pcc_recording
    result = cal.fit_pcc_parameters(rec.t, rec.q, rec.command, ROBOT, rec.qd, u_kind="command")
    for field, err in errors(result).items():
        assert np.all(err < 1e-3), (field, err)
    assert all(s.r2 > 0.99999 for s in result.segments)


def test_pcc_data_without_qd_camera_path(pcc_recording):
    """q only (q̇, q̈ by differences of q), as from the camera: 2e-3."""
    rec = pcc_recording
    result = cal.fit_pcc_parameters(rec.t, rec.q, rec.command, ROBOT, None, u_kind="command")
    for field, err in errors(result).items():
        assert np.all(err < 2e-3), (field, err)


def test_mujoco_data_with_the_rods_inertia_recover_the_built_values(mujoco_recording):
    """K, Λ and D within 5 % of what the MuJoCo arm was built with (measured −2.6…−3.3 %;
    λ/k within 0.2 %). The common ≈ −3 % is the rod's departure from constant curvature
    while it accelerates (its internal modes, heavily damped by the hinges), which the
    CC-constrained inertia cannot represent; D is no worse than K here (−1.5 %, −2.7 %)."""
    plant, rec = mujoco_recording
    result = cal.fit_pcc_parameters(rec.t, rec.q, rec.u, ROBOT, rec.qd, inertial_torque=cal.rod_inertial_torque(plant))
    err = errors(result)
    for field in ("stiffness", "gains", "damping"):
        assert np.all(err[field] < 0.05), (field, err[field])
    assert np.all(err["gain_over_stiffness"] < 0.005), err
    assert all(s.r2 > 0.99 for s in result.segments)


def test_mujoco_data_with_the_controllers_inertia_scale_segment_2(mujoco_recording):
    """With the augmented-body M (what the controller uses), λ/k stays exact and segment 1
    within 5 %, but segment 2's k, d, λ come out ≈ 36 % high: its bending inertia is
    m L²/12 in that model and m L²/20 for the rod (checked below), so the fit scales the
    segment's parameters to reproduce q̈ with the larger M. Not a fit error: the written
    parameters are the ones that make the controller's model reproduce the rod's motion."""
    _, rec = mujoco_recording
    result = cal.fit_pcc_parameters(rec.t, rec.q, rec.u, ROBOT, rec.qd)
    rel = {k: np.array(v) for k, v in result.relative_errors().items()}
    assert np.all(np.abs(rel["gain_over_stiffness"]) < 0.005), rel
    for field in ("stiffness", "gains", "damping"):
        assert abs(rel[field][0]) < 0.05, (field, rel[field])
        assert 0.25 < rel[field][1] < 0.45, (field, rel[field])


def test_rod_and_model_bending_inertia_of_segment_2(mujoco_recording):
    plant, _ = mujoco_recording
    m, L = ROBOT.masses[1], ROBOT.lengths[1]
    zero, unit = np.zeros((1, 2)), np.array([[0.0, 1.0]])
    rod = cal.rod_inertial_torque(plant)(zero, zero, unit)[0, 1]  # M_22 of the rod at q = 0
    model = PCCDynamics(ROBOT).mass_matrix(np.zeros(2))[1, 1]
    assert rod == pytest.approx(m * L**2 / 20, rel=0.01)  # n = 10 links: 0.2 %
    assert model == pytest.approx(m * L**2 / 12, rel=1e-12)


def test_commands_through_tau_p_reproduce_the_pressure_mujoco_applies(mujoco_recording):
    plant, rec = mujoco_recording
    np.testing.assert_allclose(cal.acting_pressure(rec.command, DT, 0.05, 0.0), rec.u, rtol=0, atol=1e-9)
    from_commands = cal.fit_pcc_parameters(rec.t, rec.q, rec.command, ROBOT, rec.qd, u_kind="command", tau_p=0.05)
    from_pressure = cal.fit_pcc_parameters(rec.t, rec.q, rec.u, ROBOT, rec.qd)
    for field in cal.FITTED:
        np.testing.assert_allclose(from_commands.params.array(field), from_pressure.params.array(field), rtol=1e-9)


def test_savgol_weights_keep_polynomials_and_reject_bad_windows():
    w = cal.savgol_weights(9, 3)
    x = np.arange(9) - 4.0
    for degree in range(4):
        assert w @ (0.3 * x**degree + 2.0) == pytest.approx(2.0 if degree else 2.3, abs=1e-12)
    with pytest.raises(ValueError, match="odd"):
        cal.savgol_weights(8, 3)
    with pytest.raises(ValueError, match="polyorder"):
        cal.savgol_weights(3, 3)


def test_babbling_stays_within_limits_and_is_seeded():
    a = cal.babbling_commands(5.0, DT, [-150, -100], [150, 50], seed=3)
    b = cal.babbling_commands(5.0, DT, [-150, -100], [150, 50], seed=3)
    assert a.shape == (5000, 2)
    np.testing.assert_array_equal(a, b)
    assert np.all(a >= [-150, -100]) and np.all(a <= [150, 50])
    assert np.ptp(a, axis=0).min() > 50  # it does move both segments
    assert not np.array_equal(a, cal.babbling_commands(5.0, DT, [-150, -100], [150, 50], seed=4))


@pytest.mark.parametrize(
    "change, message",
    [
        (dict(t=np.arange(200) * DT + np.r_[0.0, 0.0, 4e-4, np.zeros(197)]), "uniformly sampled"),
        (dict(q=np.zeros((200, 3))), "q must have shape"),
        (dict(u_kind="volts"), "u_kind"),
        (dict(u=np.zeros((200, 2))), "identically zero"),
    ],
)
def test_bad_inputs_are_refused_with_the_reason(change, message):
    t = np.arange(200) * DT
    data = dict(t=t, q=np.column_stack((np.sin(t), np.cos(t))), u=np.column_stack((np.cos(t), np.sin(3 * t))))
    data.update(change)
    kwargs = {"u_kind": data.pop("u_kind")} if "u_kind" in data else {}
    with pytest.raises(ValueError, match=message):
        cal.fit_pcc_parameters(data["t"], data["q"], data["u"], ROBOT, **kwargs)


def test_tool_fits_recorded_arrays_and_writes_a_loadable_robot(tmp_path, mujoco_recording):
    _, rec = mujoco_recording
    spec = importlib.util.spec_from_file_location("calibrate_tool", TOOL)
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    data, out = tmp_path / "rec.npz", tmp_path / "robot.json"
    rec.save(data)
    report = tool.main(["--out", str(out), "--data", str(data)])
    fitted = RobotParams.load(out)
    direct = cal.fit_pcc_parameters(rec.t, rec.q, rec.u, ROBOT, rec.qd)
    assert fitted == direct.params
    assert fitted.u_min == ROBOT.u_min and fitted.masses == ROBOT.masses and fitted.inertias == ROBOT.inertias
    assert (tmp_path / "robot.fit.json").is_file() and report["fit"]["samples"] == direct.samples
