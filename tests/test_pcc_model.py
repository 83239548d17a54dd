"""The one implementation of the PCC model's per-step terms (`controllers.model.pcc_model`), any N, against
independent checks: finite differences, the energy balance, M symmetric positive definite, and a
batch row equal to the same state alone, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.model import pcc
from controllers.model.dynamics import PCCDynamics
from controllers.model.params import reference_robot, uniform_robot
from controllers.model.pcc_model import ModelLayout, accelerations, model_terms, parameter_rows
from controllers.model.safe_set import paper_safe_set
from controllers.model.state_predictor import StatePredictor
from derivative_cases import SEGMENT_COUNTS, configurations, lengths


def _robot(n: int):
    base = reference_robot() if n == 2 else uniform_robot(n)
    return base.replace(lengths=tuple(lengths(n)), masses=tuple(np.linspace(0.05, 0.2, n)))


def _states(n: int, count: int = 60, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(q, q̇) (S, N): the delicate angles of `configurations` and random ones on both sides of |q| = 2."""
    rng = np.random.default_rng(seed + n)
    q = np.concatenate([np.array(configurations(n)), rng.uniform(-3.5, 3.5, (count, n))])
    return q, rng.normal(0.0, 3.0, q.shape)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_a_batch_row_is_the_state_alone_bit_for_bit(n):
    q, qd = _states(n)
    rows = parameter_rows(_robot(n))
    kin, dyn = model_terms(q, qd, rows)
    for b in range(len(q)):
        k1, d1 = model_terms(q[b : b + 1], qd[b : b + 1], rows)
        assert kin[b].tolist() == k1[0].tolist() and dyn[b].tolist() == d1[0].tolist(), b
    # one arm per state: the same floats as each arm's own evaluation
    arms = [_robot(n).replace(stiffness=tuple(np.full(n, 1.0 + 0.1 * b))) for b in range(len(q))]
    kin_p, dyn_p = model_terms(q, qd, parameter_rows(arms))
    u = np.random.default_rng(n).uniform(-200.0, 200.0, q.shape)
    acc = accelerations(dyn_p, parameter_rows(arms), u)
    for b, arm in enumerate(arms):
        k1, d1 = model_terms(q[b : b + 1], qd[b : b + 1], parameter_rows(arm))
        assert kin_p[b].tolist() == k1[0].tolist() and dyn_p[b].tolist() == d1[0].tolist(), b
        assert acc[b].tolist() == accelerations(d1, parameter_rows(arm), u[b : b + 1])[0].tolist(), b


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_mass_matrix_is_symmetric_positive_definite(n):
    q, qd = _states(n)
    layout = ModelLayout.of(n)
    _, dyn = model_terms(q, qd, parameter_rows(_robot(n)))
    for row in dyn:
        m = row[layout.mass].reshape(n, n)
        assert np.array_equal(m, m.T)
        assert np.linalg.eigvalsh(m).min() > 0.0
        np.testing.assert_allclose(row[layout.mass_inv].reshape(n, n) @ m, np.eye(n), atol=1e-10)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_tip_terms_against_finite_differences(n):
    """r, ṙ = J_r q̇ and r̈(u) = r̈₀ + Σ_j ∂r̈/∂u_j u_j against differences of the tensor path's r(q)
    along the motion q(t) = q + q̇ t + ½ q̈ t² (q̈ the model's acceleration under u)."""
    robot = _robot(n)
    layout, rows = ModelLayout.of(n), parameter_rows(robot)
    q, qd = _states(n, 20)
    q = np.clip(q, -2.5, 2.5)
    u = np.random.default_rng(n).uniform(-200.0, 200.0, q.shape)
    kin, dyn = model_terms(q, qd, rows)
    qdd = accelerations(dyn, rows, u)

    def tip(b, t, accelerating=True):
        path = q[b] + qd[b] * t + (0.5 * qdd[b] * t * t if accelerating else 0.0)
        return pcc.kinematics(path, robot.lengths, order=0).points[-1]

    def second(b, h):
        return (tip(b, h) - 2.0 * tip(b, 0.0) + tip(b, -h)) / (h * h)

    for b in range(len(q)):
        r, r_dot, drift = kin[b, layout.tip_terms][:3]
        r_ddot = drift + np.dot(kin[b, layout.tip_terms][3:], u[b])
        assert abs(r - tip(b, 0.0)) < 1e-15
        h = 1e-5
        assert abs(r_dot - (tip(b, h, False) - tip(b, -h, False)) / (2 * h)) < 1e-8 * (1.0 + abs(r_dot))
        h = 2e-4
        richardson = (4.0 * second(b, h / 2) - second(b, h)) / 3.0  # error O(h⁴)
        assert abs(r_ddot - richardson) < 1e-6 * (1.0 + abs(r_ddot)), b
        jac = pcc.kinematics(q[b], robot.lengths, order=1).jac[-1]
        np.testing.assert_allclose(kin[b, layout.tip_jac], jac, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_energy_balance(n):
    """dE/dt = −q̇ᵀDq̇ + q̇ᵀΛu for E = ½q̇ᵀM(q)q̇ + ½qᵀKq along the model's own q̈: checks C q̇
    (Ṁ − 2C skew) without the tensor path. dE/dt by a central difference along (q̇, q̈)."""
    robot = _robot(n)
    rows = parameter_rows(robot)
    layout = ModelLayout.of(n)
    k, d, g = robot.array("stiffness"), robot.array("damping"), robot.array("gains")
    q, qd = _states(n, 30)
    u = np.random.default_rng(n + 9).uniform(-200.0, 200.0, q.shape)
    _, dyn = model_terms(q, qd, rows)
    qdd = accelerations(dyn, rows, u)

    def energy(qs, qds):
        _, d1 = model_terms(qs[None, :], qds[None, :], rows)
        m = d1[0, layout.mass].reshape(n, n)
        return 0.5 * qds @ m @ qds + 0.5 * np.sum(k * qs * qs)

    h = 1e-6
    for b in range(len(q)):
        rate = (energy(q[b] + h * qd[b], qd[b] + h * qdd[b]) - energy(q[b] - h * qd[b], qd[b] - h * qdd[b])) / (2 * h)
        power = -np.sum(d * qd[b] ** 2) + np.sum(qd[b] * g * u[b])
        scale = np.sum(np.abs(qd[b] * g * u[b])) + np.sum(d * qd[b] ** 2) + np.abs(qd[b] @ (k * q[b])) + 1.0
        assert abs(rate - power) < 1e-6 * scale, (b, rate, power)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_per_step_path_matches_the_tensor_path(n):
    """Positions, Jacobians and bias accelerations J̇q̇ of the chord midpoints and the tip: the kernel
    against `pcc.kinematics` (order 2: J̇q̇ = q̇ᵀ ∂²P/∂q² q̇), and M against Σ m J_cᵀJ_c + AᵀIA."""
    robot = _robot(n)
    layout = ModelLayout.of(n)
    q, qd = _states(n, 20)
    kin, dyn = model_terms(q, qd, parameter_rows(robot))
    a = np.tril(np.ones((n, n)), -1) + 0.5 * np.eye(n)
    for b in range(len(q)):
        tensor = pcc.kinematics(q[b], robot.lengths, order=2)
        bias = np.einsum("pjk,j,k->p", tensor.hess, qd[b], qd[b])
        centre_jac = kin[b, layout.centre_jac].reshape(n, n)
        np.testing.assert_allclose(centre_jac, tensor.jac[:n], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(kin[b, layout.centre_bias_acc], bias[:n], rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(kin[b, layout.tip_bias_acc], bias[n], rtol=1e-11, atol=1e-13)
        np.testing.assert_allclose(kin[b, layout.ends][-1], tensor.points[n], rtol=0, atol=1e-15)
        jc = np.stack((centre_jac.real, centre_jac.imag), axis=1)  # (N, 2, N)
        mass = np.einsum("i,ixj,ixk->jk", robot.array("masses"), jc, jc) + a.T @ (robot.array("inertias")[:, None] * a)
        np.testing.assert_allclose(dyn[b, layout.mass].reshape(n, n), mass, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_pccdynamics_is_the_kernel_at_one_state(n):
    robot = _robot(n)
    dyn = PCCDynamics(robot)
    q, qd = _states(n, 10)
    kin, rows = model_terms(q, qd, parameter_rows(robot))
    for b in range(len(q)):
        ev = dyn.evaluate(q[b], qd[b])
        assert list(ev.tip) == kin[b, dyn.layout.tip_terms].tolist()
        assert ev.mass.ravel().tolist() == rows[b, dyn.layout.mass].tolist()


@pytest.mark.parametrize("tau", [0.0, 0.05])
@pytest.mark.parametrize("n", [2, 3])
def test_prediction_with_an_unreached_plate_is_the_kernel_loop(tau, n):
    """StatePredictor's two paths (the kernel's period loop without a plate, its ROS2 stages with the
    plate's push in between) give the same floats where the plate is never reached."""
    robot = _robot(n)
    far = paper_safe_set()  # the paper's plate at x = 0.2 m; these arms start curled away from it
    plain, plated = StatePredictor(PCCDynamics(robot), tau), StatePredictor(PCCDynamics(robot), tau, plate=far)
    rng = np.random.default_rng(n)
    for _ in range(20):
        for p in (plain, plated):
            p.reset()
        t = 0.0
        for _ in range(3):
            t += rng.uniform(0.003, 0.02)
            u = rng.uniform(-20.0, 20.0, n)
            plain.record(t, u)
            plated.record(t, u)
        q, qd = rng.uniform(-0.2, 0.0, n), rng.normal(0.0, 0.2, n)
        a = plain.predict(0.0, q, qd, t + 0.01)
        b = plated.predict(0.0, q, qd, t + 0.01)
        tip = pcc.tip_position(a[0], robot.lengths)
        assert not any(far.penetration_at(*tip.tolist()))
        assert all(x.tolist() == y.tolist() for x, y in zip(a, b))
