"""The PCC simulation plant: integrator agreement with the paper's forward Euler, statics, input checks."""

import numpy as np
import pytest

from controllers.model.params import reference_robot
from controllers.model.pcc import segment_ends
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.physics.pcc_plant import PCCPlant

ROBOT = reference_robot()
SAFE = paper_safe_set()


def tip_path(integrator, physics_dt, commands, q0):
    plant = PCCPlant(ROBOT, SAFE, integrator=integrator, physics_dt=physics_dt)
    plant.reset(q0)
    return np.array([plant.step(u).tip for u in commands])


def test_ros2_at_1ms_agrees_with_forward_euler_at_1e5():
    """Harsh input: ±150 hPa steps every 50 ms for 0.5 s (the paper's sinusoid is far gentler).

    Stated tolerance: 1e-4 m on the tip (0.7 % of n_max). RK4 at 0.1 ms is a second check.
    """
    rng = np.random.default_rng(0)
    commands = np.repeat(rng.uniform(-150, 150, (10, 2)), 50, axis=0)
    q0 = np.array([0.1, -0.2])
    reference = tip_path("euler", 1e-5, commands, q0)
    assert np.max(np.abs(tip_path("ros2", 1e-3, commands, q0) - reference)) < 1e-4
    assert np.max(np.abs(tip_path("rk4", 1e-4, commands, q0) - reference)) < 3e-5


def test_ros2_error_shrinks_with_the_step():
    rng = np.random.default_rng(1)
    commands = np.repeat(rng.uniform(-150, 150, (6, 2)), 50, axis=0)
    q0 = np.zeros(2)
    fine = tip_path("rk4", 2.5e-5, commands, q0)
    coarse = np.max(np.abs(tip_path("ros2", 1e-3, commands, q0) - fine))
    half = np.max(np.abs(tip_path("ros2", 5e-4, commands, q0) - fine))
    assert half < coarse / 2.5  # second order: ideally 4×


def test_statics_settle_at_k_inverse_lambda_u():
    plant = PCCPlant(ROBOT, SAFE)
    plant.reset(np.zeros(2))
    u = np.array([80.0, -40.0])
    for _ in range(3000):
        state = plant.step(u)
    np.testing.assert_allclose(state.q, ROBOT.array("gains") * u / ROBOT.array("stiffness"), atol=1e-9)
    np.testing.assert_allclose(state.segment_ends, segment_ends(state.q, ROBOT.array("lengths")))
    np.testing.assert_allclose(np.degrees(state.q[0]), 25.0, rtol=1e-9)  # 80 hPa → 25° (docs/model.md#rppr-dynamics)


def test_contact_force_is_psi_of_true_penetration():
    plant = PCCPlant(ROBOT, SAFE)
    state = plant.reset(np.array([0.8, 0.8]))
    n = (SAFE.environment.H[0] @ state.tip - SAFE.environment.h[0]) / np.linalg.norm(SAFE.environment.H[0])
    assert n > 0
    np.testing.assert_allclose(state.contact_forces, [11.16 * n])


@pytest.mark.parametrize("integrator, physics_dt, stable", [("ros2", 1e-3, True), ("rk4", 1e-4, True), ("rk4", 1e-3, False)])
def test_unforced_energy_never_grows_when_stable(integrator, physics_dt, stable):
    """With u = 0 and D > 0, T + V must decrease. The fast mode near q = 0 (≈ −3.7e3 1/s,
    docs/model.md#control-barrier-function) times 1 ms lies outside RK4's stability interval (−2.79, 0): RK4 at 1 ms gains
    energy, ROS2 (L-stable) does not."""
    plant = PCCPlant(ROBOT, SAFE, integrator=integrator, physics_dt=physics_dt)
    state = plant.reset(np.array([0.05, -0.05]))
    dyn = plant.dynamics
    energy = [dyn.kinetic_energy(state.q, state.qd) + dyn.elastic_energy(state.q)]
    for _ in range(300):
        state = plant.step(np.zeros(2))
        energy.append(dyn.kinetic_energy(state.q, state.qd) + dyn.elastic_energy(state.q))
    grows = np.max(np.diff(energy)) > 1e-12
    assert grows != stable


def test_bad_configuration_and_inputs():
    with pytest.raises(ValueError, match="integrator must be one of ros2, rk4, euler"):
        PCCPlant(ROBOT, SAFE, integrator="leapfrog")
    with pytest.raises(ValueError, match="integer multiple of the physics step"):
        PCCPlant(ROBOT, SAFE, physics_dt=3e-4)
    plant = PCCPlant(ROBOT, SAFE)
    plant.reset(np.zeros(2))
    with pytest.raises(ValueError, match="u must be finite"):
        plant.step(np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match=r"q0 and qd0 must have shape \(2,\)"):
        plant.reset(np.zeros(3))


def test_same_inputs_same_arrays():
    commands = np.tile([[50.0, -30.0]], (200, 1))
    np.testing.assert_array_equal(tip_path("ros2", 1e-3, commands, np.zeros(2)), tip_path("ros2", 1e-3, commands, np.zeros(2)))


def test_pressure_lag_follows_first_order_valve_and_agrees_with_fine_euler():
    """τ_p = 0.05 s: u_applied is the exact first-order response; the tip agrees with forward
    Euler at 1e-5 s (lag advanced per Euler step) to 1e-4 m, like the ideal-valve check above."""
    rng = np.random.default_rng(2)
    commands = np.repeat(rng.uniform(-150, 150, (6, 2)), 50, axis=0)
    q0 = np.array([0.1, -0.2])

    def run(integrator, physics_dt, tau_p):
        plant = PCCPlant(ROBOT, SAFE, integrator=integrator, physics_dt=physics_dt, tau_p=tau_p)
        plant.reset(q0)
        states = [plant.step(u) for u in commands]
        return np.array([s.tip for s in states]), np.array([s.u_applied for s in states])

    tips, pressure = run("ros2", 1e-3, 0.05)
    reference, _ = run("euler", 1e-5, 0.05)
    ideal, ideal_pressure = run("ros2", 1e-3, 0.0)
    assert np.max(np.abs(tips - reference)) < 1e-4
    assert np.max(np.abs(tips - ideal)) > 1e-3  # the lag changes the motion
    np.testing.assert_array_equal(ideal_pressure, commands)
    p, expected = np.zeros(2), []
    for u in commands:
        p = u + (p - u) * np.exp(-1e-3 / 0.05)
        expected.append(p)
    np.testing.assert_allclose(pressure, expected, rtol=1e-12, atol=1e-9)
    with pytest.raises(ValueError, match="tau_p must be finite and >= 0 s"):
        PCCPlant(ROBOT, SAFE, tau_p=-0.01)
