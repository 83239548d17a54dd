"""PCC kinematics (docs/model.md#pcc-kinematics): chord series accuracy, geometry against independent
constructions (arc integration, the paper's homogeneous transforms), and every
derivative against central finite differences.

Finite-difference tolerances: with step 1e-6 rad, the central-difference error here is
≈ 1e-10 (truncation h²·f'''/6 plus rounding eps·|f|/h, |f| ≲ 1 m); a wrong term
(a missing ½, a swapped index) changes the derivative by ≳ 1e-3. So atol = 1e-8.
"""

from fractions import Fraction
import math

import numpy as np
import pytest
from scipy.integrate import quad

from controllers.model import pcc
from controllers.core.errors import ControllerInputError, NonFiniteStateError
from derivative_cases import SEGMENT_COUNTS, central_difference, configurations, lengths

FD_ATOL = 1e-8


def _exact_sinc_half(q: float, terms: int = 60) -> list[float]:
    """d^a/dq^a sinc(q/2), a = 0..3, summed exactly in rationals: Σ_k (-1)^k (2k)_a q^{2k-a} / ((2k+1)! 4^k)."""
    x = Fraction(q)
    out = [Fraction(0)] * 4
    for k in range(terms):
        d_k = Fraction((-1) ** k, math.factorial(2 * k + 1) * 4**k)
        for a in range(4):
            if 2 * k >= a:
                out[a] += d_k * math.perm(2 * k, a) * x ** (2 * k - a)
    return [float(v) for v in out]


@pytest.mark.parametrize(
    "q", [0.0, 1e-300, 1e-12, -1e-8, 1e-4, 0.1, -0.5, 1.0, 1.999999, 2.0, 2.000001, -2.5, 3.0, 4.0, 6.0, 7.5]
)
def test_chord_derivatives_are_accurate_to_a_few_ulp(q):
    """ℓ, ℓ', ℓ'', ℓ''' on both sides of the series/closed-form switch (|q| = 2) within 5e-15 relative."""
    length = 0.3
    exact = np.array(_exact_sinc_half(q)) * length
    got = pcc.chord_derivatives([q], [length])[0]
    np.testing.assert_allclose(got, exact, rtol=5e-15, atol=1e-300)


def test_chord_at_zero_is_the_segment_length():
    got = pcc.chord_derivatives([0.0, 0.0], [0.1, 0.2])
    np.testing.assert_allclose(got[:, 0], [0.1, 0.2], rtol=0, atol=0)
    np.testing.assert_allclose(got[:, 2], [-0.1 / 12, -0.2 / 12], rtol=1e-15)  # ℓ'' = -L/12 at 0
    assert np.all(got[:, 1] == 0) and np.all(got[:, 3] == 0)


def test_straight_arm_points_along_plus_x():
    lens = np.array([0.1, 0.2, 0.15])
    ends = pcc.segment_ends(np.zeros(3), lens)
    np.testing.assert_allclose(ends[:, 0], [0, 0.1, 0.3, 0.45], rtol=1e-15)
    np.testing.assert_array_equal(ends[:, 1], 0.0)
    np.testing.assert_allclose(pcc.tip_position(np.zeros(3), lens), [lens.sum(), 0.0], rtol=1e-15)
    np.testing.assert_array_equal(pcc.segment_orientations(np.zeros(3)), np.zeros(4))


def test_positive_bending_moves_the_tip_towards_plus_y():
    lens = np.array([0.1, 0.2, 0.15])
    assert pcc.tip_position([0.3], [0.1])[1] > 0
    ends = pcc.segment_ends(np.full(3, 0.4), lens)
    assert np.all(np.diff(ends[:, 1]) > 0)
    mirrored = pcc.segment_ends(np.full(3, -0.4), lens)
    np.testing.assert_allclose(mirrored, ends * [1, -1], rtol=0, atol=1e-17)
    # A half circle (q = π) ends at (0, 2L/π) with the tip pointing along -x.
    np.testing.assert_allclose(pcc.tip_position([math.pi], [0.1]), [0.0, 0.2 / math.pi], atol=1e-17)


def _arc_ends(q: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """Ends by integrating the unit tangent of constant-curvature arcs (independent of chords)."""
    def tangent(s, component, theta0, curvature):
        return component(theta0 + curvature * s)

    ends, theta0 = [np.zeros(2)], 0.0
    for qi, li in zip(q, lens):
        args = (theta0, qi / li)
        step = [quad(tangent, 0, li, args=(f, *args), epsabs=1e-15, epsrel=1e-13)[0] for f in (math.cos, math.sin)]
        ends.append(ends[-1] + step)
        theta0 += qi
    return np.array(ends)


def _transform_ends(q: np.ndarray, lens: np.ndarray) -> np.ndarray:
    """The paper's product of homogeneous transforms T_i(q_i) (with its q → 0 limit)."""
    t, ends = np.eye(3), [np.zeros(2)]
    for qi, li in zip(q, lens):
        c, s = math.cos(qi), math.sin(qi)
        # 1 - cos q = 2 sin²(q/2), evaluated stably for tiny q
        x, y = (li * s / qi, 2 * li * math.sin(qi / 2) ** 2 / qi) if qi != 0 else (li, 0.0)
        t = t @ np.array([[c, -s, x], [s, c, y], [0, 0, 1]])
        ends.append(t[:2, 2].copy())
    return np.array(ends)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_segment_ends_match_arc_integration_and_transforms(n):
    lens = lengths(n)
    for q in configurations(n):
        ends = pcc.segment_ends(q, lens)
        np.testing.assert_allclose(ends, _arc_ends(q, lens), rtol=0, atol=1e-13, err_msg=f"q={q}")
        np.testing.assert_allclose(ends, _transform_ends(q, lens), rtol=0, atol=1e-13, err_msg=f"q={q}")
        np.testing.assert_allclose(pcc.segment_orientations(q), np.concatenate(([0], np.cumsum(q))))
        np.testing.assert_allclose(pcc.centre_positions(q, lens), 0.5 * (ends[:-1] + ends[1:]), atol=1e-15)
        np.testing.assert_allclose(pcc.tip_position(q, lens), ends[-1], atol=1e-15)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_jacobians_match_finite_differences(n):
    lens = lengths(n)
    for q in configurations(n):
        msg = f"q={q}"
        tip_fd = central_difference(lambda x: pcc.tip_position(x, lens), q)
        np.testing.assert_allclose(pcc.tip_jacobian(q, lens), tip_fd, rtol=0, atol=FD_ATOL, err_msg=msg)
        centre_fd = central_difference(lambda x: pcc.centre_positions(x, lens), q)  # (N, 2, N)
        np.testing.assert_allclose(pcc.centre_jacobians(q, lens), centre_fd, rtol=0, atol=FD_ATOL, err_msg=msg)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_second_and_third_derivatives_match_finite_differences(n):
    lens = lengths(n)
    for q in configurations(n):
        msg = f"q={q}"
        dj = pcc.tip_jacobian_derivative(q, lens)  # [k] = ∂J/∂q_k
        dj_fd = np.moveaxis(central_difference(lambda x: pcc.tip_jacobian(x, lens), q), -1, 0)
        np.testing.assert_allclose(dj, dj_fd, rtol=0, atol=FD_ATOL, err_msg=msg)
        kin = pcc.kinematics(q, lens, order=3)
        np.testing.assert_allclose(kin.hess, kin.hess.transpose(0, 2, 1), rtol=0, atol=1e-15)
        hess_fd = central_difference(lambda x: pcc.kinematics(x, lens, order=2).jac, q)
        np.testing.assert_allclose(kin.hess, hess_fd, rtol=0, atol=FD_ATOL, err_msg=msg)
        third_fd = central_difference(lambda x: pcc.kinematics(x, lens, order=2).hess, q)
        np.testing.assert_allclose(kin.third, third_fd, rtol=0, atol=FD_ATOL, err_msg=msg)


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
def test_step_kinematics_matches_the_tensor_path(n):
    """The per-step scalar path (J, J̇, J̇q̇ of bodies and tip) against `kinematics`' tensors."""
    lens = lengths(n)
    rng = np.random.default_rng(n)
    for q in configurations(n):
        qd = rng.normal(0, 2, n)
        step = pcc.step_kinematics(q, qd, lens)
        kin = pcc.kinematics(q, lens, order=2)
        jac_dot = kin.hess @ qd
        centre_jac = np.zeros((n, n), complex)
        for i, row in enumerate(step.centre_jac):
            centre_jac[i, : len(row)] = row
        np.testing.assert_allclose(centre_jac, kin.jac[:n], rtol=0, atol=1e-15)
        np.testing.assert_allclose(step.centre_bias_acc, jac_dot[:n] @ qd, rtol=0, atol=1e-14)
        np.testing.assert_allclose(step.tip, kin.points[n], rtol=0, atol=1e-15)
        np.testing.assert_allclose(step.tip_jac, kin.jac[n], rtol=0, atol=1e-15)
        np.testing.assert_allclose(step.tip_vel, kin.jac[n] @ qd, rtol=0, atol=1e-14)
        np.testing.assert_allclose(step.tip_jac_dot, jac_dot[n], rtol=0, atol=1e-14)
        np.testing.assert_allclose(step.tip_bias_acc, jac_dot[n] @ qd, rtol=0, atol=1e-14)


def test_input_errors():
    with pytest.raises(NonFiniteStateError, match="q must be finite"):
        pcc.tip_position([0.1, np.nan], [0.1, 0.1])
    with pytest.raises(NonFiniteStateError):
        pcc.segment_ends([np.inf], [0.1])
    with pytest.raises(ControllerInputError, match=r"lengths must have shape \(2,\)"):
        pcc.tip_jacobian([0.1, 0.2], [0.1])
    with pytest.raises(ControllerInputError, match="lengths must be > 0"):
        pcc.tip_jacobian([0.1], [0.0])
    with pytest.raises(ControllerInputError, match=r"q must have shape \(N,\)"):
        pcc.tip_position([[0.1]], [0.1])
    with pytest.raises(ControllerInputError, match="order must be 0..3"):
        pcc.kinematics([0.1], [0.1], order=4)
    with pytest.raises(ControllerInputError, match="array of numbers"):
        pcc.tip_position(["a"], [0.1])


def test_tip_positions_vectorised_matches_tip_position():
    rng = np.random.default_rng(5)
    for n in (1, 2, 3):
        lengths = rng.uniform(0.05, 0.2, n)
        q = np.vstack((rng.uniform(-3.0, 3.0, (50, n)), np.zeros((1, n)), np.full((1, n), 1e-9)))
        expected = np.array([pcc.tip_position(row, lengths) for row in q])
        np.testing.assert_allclose(pcc.tip_positions(q, lengths), expected, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match=r"q must have shape \(T, 2\)"):
        pcc.tip_positions(np.zeros(2), [0.1, 0.1])
