"""RPPR dynamics (docs/model.md#rppr-dynamics): structure of M and C, derivatives against finite differences,
energy balance of integrated trajectories, the single-segment closed form and the
linearisation's fast mode.

Finite-difference checks: central differences with step 1e-6 err by about
eps·|f|/h + h²·|f'''| ≈ 1e-10 of the differentiated quantity's own scale |f| (or of its
derivative's, if larger), while a wrong term is off by ≳ 1e-3 of it; so atol = 1e-7 · scale.
"""

import math

import numpy as np
import pytest

from controllers.model import pcc
from controllers.model.dynamics import PCCDynamics
from controllers.core.errors import ControllerInputError, NonFiniteCommandError, NonFiniteStateError
from controllers.model.params import RobotParams, reference_robot, uniform_robot
from derivative_cases import SEGMENT_COUNTS, central_difference, configurations, lengths

FD_RTOL = 1e-7


def _robot(n: int, damping: float | None = None) -> RobotParams:
    """An arm with unequal segments (so index mix-ups show) and the reference k, d, λ."""
    rng = np.random.default_rng(300 + n)
    ref = uniform_robot(n)
    return ref.replace(
        lengths=tuple(lengths(n)),
        masses=tuple(rng.uniform(0.05, 0.2, n)),
        damping=ref.damping if damping is None else (damping,) * n,
    )


def _assert_fd(analytic, numeric, value_scale: float, msg=""):
    """analytic ≈ numeric to FD_RTOL of max(|value|, |derivative|)."""
    scale = max(np.abs(analytic).max(), value_scale)
    np.testing.assert_allclose(analytic, numeric, rtol=0, atol=FD_RTOL * scale, err_msg=msg)


def _cases(n: int):
    rng = np.random.default_rng(400 + n)
    for q in configurations(n):
        yield q, rng.normal(0, 2.0, n), rng.uniform(-150, 150, n)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_mass_matrix_is_symmetric_positive_definite(n):
    dyn = PCCDynamics(_robot(n))
    for q in configurations(n):
        m = dyn.mass_matrix(q)
        np.testing.assert_array_equal(m, m.T)
        assert np.linalg.eigvalsh(m).min() > 0, f"q={q}"


@pytest.mark.parametrize("q", [0.0, 1e-8, -1e-4, 0.3, 1.0, -1.7, 2.5, 4.0])
def test_single_segment_mass_matches_closed_form(q):
    """N = 1: c = ½ ℓ e^{iq/2}, φ = q/2, so J_c = ½(ℓ' + ½iℓ) e^{iq/2}, J_φ = ½ and
    M = (m/4)(ℓ'² + ℓ²/4) + I/4. With ℓ = 2L sin(q/2)/q this is
        M(q) = m L² (q² − 2q sin q + 2 − 2cos q) / (4q⁴) + I/4,
    whose numerator is q⁴/4 + O(q⁶), so M(0) = m L²/16 + I/4 (= m L²/12 for I = m L²/12).
    The closed form cancels catastrophically for |q| < 0.1; there M(q) = M(0) + O(q²)."""
    m_, length, inertia = 0.13, 0.122, 2.5e-4
    params = uniform_robot(1, length=length, mass=m_).replace(inertias=(inertia,))
    got = PCCDynamics(params).mass_matrix([q])[0, 0]
    if abs(q) >= 0.1:
        expected = m_ * length**2 * (q * q - 2 * q * math.sin(q) + 2 - 2 * math.cos(q)) / (4 * q**4) + inertia / 4
        np.testing.assert_allclose(got, expected, rtol=1e-12)
    else:
        np.testing.assert_allclose(got, m_ * length**2 / 16 + inertia / 4, rtol=max(q * q, 1e-15))
    if q == 0.0:
        default = PCCDynamics(uniform_robot(1, length=length, mass=m_)).mass_matrix([0.0])[0, 0]
        np.testing.assert_allclose(default, m_ * length**2 / 12, rtol=1e-15)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_mass_matrix_derivative_matches_finite_differences(n):
    dyn = PCCDynamics(_robot(n))
    for q in configurations(n):
        dm_fd = np.moveaxis(central_difference(dyn.mass_matrix, q), -1, 0)
        _assert_fd(dyn.mass_matrix_derivative(q), dm_fd, np.abs(dyn.mass_matrix(q)).max(), msg=f"q={q}")


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_coriolis_matrix_structure(n):
    """Ṁ − 2C is skew-symmetric, and C q̇ = Ṁ q̇ − ½ ∇_q(q̇ᵀ M q̇) (Euler–Lagrange, by finite differences)."""
    dyn = PCCDynamics(_robot(n))
    for q, qd, _ in _cases(n):
        c = dyn.coriolis_matrix(q, qd)
        m_dot = np.tensordot(qd, dyn.mass_matrix_derivative(q), axes=1)
        skew = m_dot - 2 * c
        np.testing.assert_allclose(skew, -skew.T, rtol=0, atol=1e-14 * np.abs(m_dot).max() + 1e-300)
        m_dot_fd = central_difference(lambda t: dyn.mass_matrix(q + t[0] * qd), np.zeros(1))[..., 0]
        grad_kinetic = central_difference(lambda x: dyn.kinetic_energy(x, qd), q)
        c_qd = m_dot_fd @ qd - grad_kinetic
        scale = np.abs(dyn.mass_matrix(q)).max() * np.abs(qd).max() ** 2
        _assert_fd(c @ qd, c_qd, scale, msg=f"q={q}")
        ev = dyn.evaluate(q, qd)
        _assert_fd(ev.bias - dyn.damping * qd - dyn.stiffness * q, c_qd, scale, msg=f"q={q}")


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_acceleration_jacobian_matches_finite_differences(n):
    dyn = PCCDynamics(_robot(n))
    for q, qd, u in _cases(n):
        d_q, d_qd = dyn.acceleration_jacobian(q, qd, u)
        scale = np.abs(dyn.acceleration(q, qd, u)).max()
        _assert_fd(d_q, central_difference(lambda x: dyn.acceleration(x, qd, u), q), scale, msg=f"q={q}")
        _assert_fd(d_qd, central_difference(lambda x: dyn.acceleration(q, x, u), qd), scale, msg=f"q={q}")


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_drift_input_split_and_tip_terms(n):
    """f, g, q̈ agree; r̈ = J q̈ + J̇ q̇ of `evaluate` matches d/dt (J_r q̇) along the motion."""
    dyn = PCCDynamics(_robot(n))
    lens = dyn.lengths
    for q, qd, u in _cases(n):
        x = np.concatenate((q, qd))
        ev = dyn.evaluate(q, qd)
        qdd = dyn.acceleration(q, qd, u)
        np.testing.assert_allclose(qdd, ev.drift_acc + ev.input_acc @ u, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(dyn.state_derivative(x, u), dyn.f(x) + dyn.g(x) @ u, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(ev.input_acc, np.linalg.solve(ev.mass, np.diag(dyn.gains)), rtol=1e-10)
        tip = ev.tip_terms
        np.testing.assert_allclose(tip[0], complex(*pcc.tip_position(q, lens)), atol=1e-15)
        jac = pcc.tip_jacobian(q, lens)
        np.testing.assert_allclose(tip[1], complex(*(jac @ qd)), atol=1e-14)

        def tip_velocity(t):
            return pcc.tip_jacobian(q + t[0] * qd, lens) @ (qd + t[0] * qdd)

        tip_acc_fd = central_difference(tip_velocity, np.zeros(1))[:, 0]
        _assert_fd(tip[2] + tip[3:] @ u, complex(*tip_acc_fd), abs(tip[1]), msg=f"q={q}")


def _rk4_energy_run(dyn: PCCDynamics, x0: np.ndarray, u: np.ndarray, dt: float, steps: int):
    """RK4 on [x; W] with Ẇ = q̇ᵀ(Λu − D q̇), the power of the non-conservative forces."""
    n = dyn.n

    def rhs(y):
        x = y[:-1]
        qd = x[n:]
        return np.append(dyn.state_derivative(x, u), qd @ (dyn.gains * u - dyn.damping * qd))

    y = np.append(x0, 0.0)
    for _ in range(steps):
        k1 = rhs(y)
        k2 = rhs(y + 0.5 * dt * k1)
        k3 = rhs(y + 0.5 * dt * k2)
        k4 = rhs(y + dt * k3)
        y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return y[:-1], y[-1]


def _energy(dyn: PCCDynamics, x: np.ndarray) -> float:
    q, qd = x[: dyn.n], x[dyn.n :]
    return dyn.kinetic_energy(q, qd) + dyn.elastic_energy(q)


@pytest.mark.parametrize("params", [reference_robot(), _robot(3)], ids=["reference", "N3"])
def test_energy_balance_under_constant_input(params):
    """E(T) − E(0) = ∫ q̇ᵀ(Λu − D q̇) dt to < 1e-4 relative (RK4, 1e-4 s steps, stable below the −3.7e3 s⁻¹ mode)."""
    dyn = PCCDynamics(params)
    rng = np.random.default_rng(7)
    n = dyn.n
    x0 = np.concatenate((rng.uniform(-1, 1, n), rng.normal(0, 3, n)))
    u = rng.uniform(-150, 150, n)
    x1, work = _rk4_energy_run(dyn, x0, u, 1e-4, 1500)
    change = _energy(dyn, x1) - _energy(dyn, x0)
    assert abs(work) > 1e-3 * _energy(dyn, x0)  # the test means something
    assert abs(change - work) < 1e-4 * max(abs(change), abs(work))


def test_energy_is_conserved_without_damping_or_input():
    dyn = PCCDynamics(_robot(3, damping=0.0))
    rng = np.random.default_rng(8)
    x0 = np.concatenate((rng.uniform(-1.5, 1.5, 3), rng.normal(0, 3, 3)))
    x1, work = _rk4_energy_run(dyn, x0, np.zeros(3), 1e-4, 1500)
    assert work == 0.0
    assert abs(_energy(dyn, x1) - _energy(dyn, x0)) < 1e-6 * _energy(dyn, x0)
    assert np.abs(x1 - x0).max() > 0.1  # it moved


def test_quasi_static_bend_and_restoring_sign():
    """q = Λu/k is an equilibrium (25° at 80 hPa, docs/model.md#rppr-dynamics); a bent arm at rest accelerates back."""
    dyn = PCCDynamics(reference_robot())
    u = np.array([80.0, -80.0])
    q_eq = dyn.gains * u / dyn.stiffness
    np.testing.assert_allclose(np.degrees(q_eq), [25.0, -25.0])
    np.testing.assert_allclose(dyn.acceleration(q_eq, np.zeros(2), u), 0.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.solve(dyn.K, dyn.Lambda @ u), q_eq, rtol=1e-15)
    np.testing.assert_array_equal(dyn.D, np.diag([0.07, 0.07]))
    single = PCCDynamics(uniform_robot(1))
    assert single.acceleration([0.3], [0.0], [0.0])[0] < 0
    assert single.acceleration([0.0], [1.0], [0.0])[0] < 0  # damping opposes motion
    assert single.acceleration([0.0], [0.0], [50.0])[0] > 0  # positive pressure bends towards +q


def test_linearisation_at_rest_has_the_stiff_mode_of_the_spec():
    """At x = 0: ∂q̈/∂q = −M⁻¹K, ∂q̈/∂q̇ = −M⁻¹D; the reference arm's fastest mode is ≈ −3.68e3 s⁻¹
    (docs/model.md#rppr-dynamics "near −3.7e3"), the slow ones ≈ −14.3 and −14.6 ± 14.3i s⁻¹ (|λ| ≈ 20 rad/s)."""
    dyn = PCCDynamics(reference_robot())
    zero = np.zeros(2)
    d_q, d_qd = dyn.acceleration_jacobian(zero, zero, zero)
    mass = dyn.mass_matrix(zero)
    np.testing.assert_allclose(d_q, -np.linalg.solve(mass, np.diag(dyn.stiffness)), rtol=1e-12)
    np.testing.assert_allclose(d_qd, -np.linalg.solve(mass, np.diag(dyn.damping)), rtol=1e-12)
    a = np.block([[np.zeros((2, 2)), np.eye(2)], [d_q, d_qd]])
    eig = np.linalg.eigvals(a)
    assert np.all(eig.real < 0)
    fastest = eig[np.argmin(eig.real)]
    assert abs(fastest.imag) < 1e-9 and fastest.real == pytest.approx(-3.68e3, rel=0.01)
    slow = np.sort_complex(eig[eig.real > -100])
    np.testing.assert_allclose(slow, [-14.59 - 14.28j, -14.59 + 14.28j, -14.34], atol=0.02)


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_mass_inverse_of_the_per_step_path(n):
    """M⁻¹ of the kernel (closed form for N ≤ 2, Cholesky beyond) against numpy's, and M M⁻¹ = I."""
    dyn = PCCDynamics(reference_robot() if n == 2 else uniform_robot(n))
    rng = np.random.default_rng(n)
    for q in rng.uniform(-3.0, 3.0, (20, n)):
        core = dyn.model_terms(q.tolist(), rng.normal(0.0, 2.0, n).tolist())
        np.testing.assert_allclose(core.mass_inv, np.linalg.inv(core.mass), rtol=1e-12)
        np.testing.assert_allclose(core.mass @ core.mass_inv, np.eye(n), atol=1e-12)


def test_input_errors():
    dyn = PCCDynamics(reference_robot())
    good = np.zeros(2)
    for call in (
        lambda: dyn.evaluate([np.nan, 0], good),
        lambda: dyn.evaluate(good, [0, np.inf]),
        lambda: dyn.acceleration([np.inf, 0], good, good),
        lambda: dyn.mass_matrix([np.nan, 0]),
        lambda: dyn.f([0, 0, np.nan, 0]),
        lambda: dyn.state_derivative([0, 0, 0, -np.inf], good),
    ):
        with pytest.raises(NonFiniteStateError, match="must be finite"):
            call()
    with pytest.raises(NonFiniteCommandError, match="u must be finite"):
        dyn.acceleration(good, good, [np.nan, 0])
    with pytest.raises(NonFiniteCommandError):
        dyn.acceleration_jacobian(good, good, [0, np.inf])
    with pytest.raises(ControllerInputError, match=r"q must have shape \(2,\)"):
        dyn.evaluate(np.zeros(3), good)
    with pytest.raises(ControllerInputError, match=r"x must have shape \(4,\)"):
        dyn.f(np.zeros(2))


def test_unchecked_acceleration_and_mass_gives_the_same_floats():
    dyn = PCCDynamics(reference_robot())
    rng = np.random.default_rng(11)
    for _ in range(5):
        q, qd, u = rng.uniform(-1, 1, 2), rng.uniform(-3, 3, 2), rng.uniform(-150, 150, 2)
        acc, mass = dyn.acceleration_and_mass_unchecked(q.tolist(), qd.tolist(), u.tolist())
        expected_acc, expected_mass = dyn.acceleration_and_mass(q, qd, u)
        np.testing.assert_array_equal(acc, expected_acc)
        np.testing.assert_array_equal(mass, expected_mass)
