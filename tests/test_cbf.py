"""Barrier of docs/model.md#control-barrier-function: tunings, the definitions of b, ḃ, B, and ∂B/∂q, ∂B/∂q̇, L_f B, L_g B
against finite differences of an independent B(q, q̇) built from the public kinematics. `barrier_terms` runs the
compiled barrier rows (`controllers.cbf.kernels.barrier_rows`), the one implementation the filter's kernel and its
scalar fallback use, so these are the filter's rows.

Finite-difference tolerance: central differences with step 1e-7 are accurate to ≈ 1e-8
relative here (b ≥ 0.02, so B's curvature is bounded); a wrong term is off by ≳ 1e-3.
"""

import dataclasses
import math
import re
import warnings

import numpy as np
import pytest

from controllers.model import pcc
from controllers.cbf.barrier import B_MIN, TUNINGS, Tuning, barrier_gradients, barrier_terms, get_tuning
from controllers.model.dynamics import PCCDynamics
from controllers.core.errors import ControllerInputError, NonFiniteCommandError
from controllers.model.params import uniform_robot
from derivative_cases import SEGMENT_COUNTS, central_difference, configurations

FD_RTOL = 1e-6
TUNINGS_UNDER_TEST = [TUNINGS["Low"], TUNINGS["High"], TUNINGS["HW-High"], Tuning("custom", 3.0, 0.5, 7.0)]


# -- tunings ------------------------------------------------------------------------
def test_paper_tunings():
    assert {name: (t.a_E, t.b_E, t.gamma) for name, t in TUNINGS.items()} == {
        "None": (0, 0, 0),
        "Low": (2, 2, 2),
        "High": (0.2, 0.2, 0.2),
        "HW-Low": (100, 100, 100),
        "HW-High": (10, 10, 10),
    }
    assert [t.disabled for t in TUNINGS.values()] == [True, False, False, False, False]


@pytest.mark.parametrize("name, expected", [("none", "None"), ("HIGH", "High"), (" Low ", "Low"), ("hw-low", "HW-Low"), ("Hw-High", "HW-High")])
def test_get_tuning_is_case_insensitive(name, expected):
    assert get_tuning(name) is TUNINGS[expected]


@pytest.mark.parametrize("name", ["Medium", "", "HW_Low", None])
def test_get_tuning_lists_valid_names(name):
    with pytest.raises(ValueError, match="valid: None, Low, High, HW-Low, HW-High"):
        get_tuning(name)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"gamma": -1}, "gamma must be >= 0 1/s, got -1.0"),
        ({"a_E": -0.5}, "a_E must be >= 0, got -0.5"),
        ({"b_E": math.nan}, "b_E must be finite and >= 0 s^2/m^2, got nan"),
        ({"gamma": math.inf}, "gamma must be finite and >= 0 1/s, got inf"),
        ({"a_E": "2"}, "a_E must be a number >= 0, got '2'"),
        ({"b_E": True}, "b_E must be a number >= 0 s^2/m^2, got True"),
        ({"a_E": None}, "a_E must be a number >= 0, got None"),
        ({"name": ""}, "name must be a non-empty string"),
    ],
)
def test_tuning_validation(kwargs, message):
    args = {"name": "t", "a_E": 1.0, "b_E": 1.0, "gamma": 1.0, **kwargs}
    with pytest.raises(ValueError, match=re.escape(message)):
        Tuning(**args)


def test_tuning_is_frozen_and_stores_floats():
    t = Tuning("t", 1, np.float32(0.5), 2)
    assert (t.a_E, t.b_E, t.gamma) == (1.0, 0.5, 2.0) and type(t.b_E) is float
    with pytest.raises(dataclasses.FrozenInstanceError):
        t.gamma = 3.0  # type: ignore[misc]


# -- barrier terms --------------------------------------------------------------------
def _rows_around_tip(q, lens, rng, n_rows):
    """Rows (H', h') with the tip inside at b ∈ [0.02, 0.3]: paper-style rows (second entry ±1) and unit rows."""
    tip = pcc.tip_position(q, lens)
    angles = rng.uniform(0, 2 * np.pi, n_rows)
    H = np.column_stack((np.cos(angles), np.sin(angles)))
    H[::2] /= np.abs(H[::2, 1:2])  # paper scaling on every other row
    h = H @ tip + rng.uniform(0.02, 0.3, n_rows)
    return H, h


def _reference_barrier(q, qd, lens, H, h, tuning):
    """B(q, q̇) of every row straight from the definition and the public kinematics."""
    b = h - H @ pcc.tip_position(q, lens)
    bdot = -H @ pcc.tip_jacobian(q, lens) @ qd
    s = tuning.b_E * bdot**2
    return -np.log(b / (1 + b)) + tuning.a_E * s / (1 + s)


def _state_cases(n):
    rng = np.random.default_rng(500 + n)
    for q in configurations(n):
        yield q, rng.normal(0, 1.5, n), rng
    yield np.zeros(n), np.zeros(n), rng  # at rest: ḃ = 0, L_g B = 0


@pytest.mark.parametrize("n", SEGMENT_COUNTS)
@pytest.mark.parametrize("tuning", TUNINGS_UNDER_TEST, ids=lambda t: t.name)
def test_barrier_derivatives_match_finite_differences(n, tuning):
    params = uniform_robot(n, length=0.3 / n)
    dyn = PCCDynamics(params)
    lens = dyn.lengths
    for q, qd, rng in _state_cases(n):
        H, h = _rows_around_tip(q, lens, rng, 3)
        msg = f"q={q}, qd={qd}"
        ev = dyn.evaluate(q, qd)
        terms = barrier_terms(ev, H, h, tuning)
        assert terms.defined.all()
        np.testing.assert_allclose(terms.b, h - H @ pcc.tip_position(q, lens), rtol=1e-13, atol=1e-16)
        np.testing.assert_allclose(terms.bdot, -H @ pcc.tip_jacobian(q, lens) @ qd, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(terms.B, _reference_barrier(q, qd, lens, H, h, tuning), rtol=1e-13)

        dB_dq, dB_dqd = barrier_gradients(ev, H, h, tuning)
        fd_q = central_difference(lambda x: _reference_barrier(x, qd, lens, H, h, tuning), q, 1e-7)
        fd_qd = central_difference(lambda x: _reference_barrier(q, x, lens, H, h, tuning), qd, 1e-7)
        scale = np.abs(fd_q).max() + np.abs(fd_qd).max()
        np.testing.assert_allclose(dB_dq, fd_q, rtol=0, atol=FD_RTOL * scale, err_msg=msg)
        np.testing.assert_allclose(dB_dqd, fd_qd, rtol=0, atol=FD_RTOL * scale, err_msg=msg)

        # Lie derivatives: by their definition from the gradients, and as dB/dt along ẋ = f + g u.
        np.testing.assert_allclose(terms.LfB, dB_dq @ qd + dB_dqd @ ev.drift_acc, rtol=1e-10, atol=1e-12 * scale)
        np.testing.assert_allclose(terms.LgB, dB_dqd @ ev.input_acc, rtol=1e-10, atol=1e-16)
        x = np.concatenate((q, qd))
        for u in (np.zeros(n), rng.uniform(-150, 150, n)):
            xdot = dyn.state_derivative(x, u)
            along = central_difference(
                lambda t: _reference_barrier(*np.split(x + t[0] * xdot, 2), lens, H, h, tuning), np.zeros(1), 1e-8
            )[:, 0]
            rate = terms.LfB + terms.LgB @ u
            np.testing.assert_allclose(rate, along, rtol=0, atol=FD_RTOL * (np.abs(rate).max() + scale), err_msg=msg)
        np.testing.assert_allclose(terms.constraint(np.ones(n)), terms.LfB + terms.LgB.sum(axis=1) - tuning.gamma / terms.B)


def test_hand_computed_single_row():
    """N = 1, q = 0 (tip at (L, 0)), q̇ = 0.5: r = (0.2, 0), ṙ = J q̇ = (0, L/2 · 0.5)."""
    dyn = PCCDynamics(uniform_robot(1, length=0.2))
    ev = dyn.evaluate([0.0], [0.5])
    tuning = Tuning("t", 2.0, 3.0, 1.0)
    terms = barrier_terms(ev, [[0.0, 1.0]], [0.1], tuning)  # facet y ≤ 0.1
    b, bdot = 0.1, -0.05
    big_b = -math.log(b / (1 + b)) + 2.0 * 3.0 * bdot**2 / (1 + 3.0 * bdot**2)
    assert terms.b[0] == pytest.approx(b, rel=1e-15) and terms.bdot[0] == pytest.approx(bdot, rel=1e-15)
    assert terms.B[0] == pytest.approx(big_b, rel=1e-14)
    # L_g B = ∂B/∂ḃ · (−H' J_r M⁻¹ Λ) with ∂B/∂ḃ = 2 a b ḃ / (1 + b ḃ²)².
    dB_dbdot = 2 * 2.0 * 3.0 * bdot / (1 + 3.0 * bdot**2) ** 2
    jac_y = 0.2 / 2  # ∂r_y/∂q at q = 0
    expected_lgb = dB_dbdot * (-jac_y) * ev.input_acc[0, 0]
    assert terms.LgB[0, 0] == pytest.approx(expected_lgb, rel=1e-12)


def test_none_tuning_has_no_input_authority():
    dyn = PCCDynamics(uniform_robot(2))
    terms = barrier_terms(dyn.evaluate([0.2, 0.1], [1.0, -2.0]), [[0.36, 1.0]], [0.25], TUNINGS["None"])
    assert terms.defined.all() and np.all(terms.LgB == 0)
    np.testing.assert_allclose(terms.B, np.log1p(1 / terms.b))
    np.testing.assert_allclose(terms.LfB, -terms.bdot / (terms.b * (1 + terms.b)))


def test_rows_outside_the_set_are_flagged_not_raised():
    dyn = PCCDynamics(uniform_robot(2))
    q, qd = np.array([0.2, 0.1]), np.array([1.0, -2.0])
    ev = dyn.evaluate(q, qd)
    tip = np.array([ev.tip[0].real, ev.tip[0].imag])  # the very r the barrier uses, so row 1's b is exactly 0
    H = np.array([[0.0, 1.0], [1.0, 0.0], [0.36, 1.0], [0.0, -1.0]])
    h = H @ tip + np.array([-0.01, 0.0, 0.05, B_MIN * 0.5])  # outside, on the boundary, inside, b < B_MIN
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        terms = barrier_terms(ev, H, h, TUNINGS["Low"])
        values = terms.constraint([10.0, -10.0])
        dB_dq, dB_dqd = barrier_gradients(ev, H, h, TUNINGS["Low"])
    np.testing.assert_array_equal(terms.defined, [False, False, True, False])
    assert terms.b[0] < 0 and np.isfinite(terms.b).all() and np.isfinite(terms.bdot).all()
    np.testing.assert_array_equal(terms.B[~terms.defined], np.inf)
    assert np.isfinite(terms.LfB).all() and np.isfinite(terms.LgB).all()
    np.testing.assert_array_equal(terms.LgB[~terms.defined], 0.0)
    np.testing.assert_array_equal(values[~terms.defined], np.inf)
    assert np.isfinite(values[2])
    np.testing.assert_array_equal(dB_dq[~terms.defined], 0.0)
    np.testing.assert_array_equal(dB_dqd[~terms.defined], 0.0)
    # The defined row does not depend on the others.
    alone = barrier_terms(ev, H[2:3], h[2:3], TUNINGS["Low"])
    np.testing.assert_array_equal([alone.B[0], alone.LfB[0]], [terms.B[2], terms.LfB[2]])
    np.testing.assert_array_equal(alone.LgB[0], terms.LgB[2])


def test_barrier_is_finite_just_inside_and_for_large_b():
    dyn = PCCDynamics(uniform_robot(2))
    ev = dyn.evaluate([0.0, 0.0], [0.5, 0.5])  # tip at (2L, 0), moving towards +y
    terms = barrier_terms(ev, [[0.0, 1.0], [0.0, 1.0]], [1e-150, 1e6], TUNINGS["Low"])
    assert terms.defined.all() and terms.b[0] == 1e-150
    assert np.isfinite(terms.B).all() and np.isfinite(terms.LfB).all() and np.isfinite(terms.LgB).all()
    s = 2.0 * terms.bdot[1] ** 2
    assert terms.B[1] - 2.0 * s / (1 + s) == pytest.approx(1e-6 - 0.5e-12, rel=1e-9)  # −ln(b/(1+b)) at b = 1e6


def test_input_errors():
    dyn = PCCDynamics(uniform_robot(2))
    ev = dyn.evaluate([0.1, 0.1], [0.0, 0.0])
    low = TUNINGS["Low"]
    with pytest.raises(ControllerInputError, match=r"H must have shape \(P, 2\)"):
        barrier_terms(ev, [0.36, 1.0], [0.2], low)
    with pytest.raises(ControllerInputError, match=r"h must have shape \(1,\)"):
        barrier_terms(ev, [[0.36, 1.0]], [0.2, 0.3], low)
    with pytest.raises(ControllerInputError, match="H must be finite"):
        barrier_terms(ev, [[np.nan, 1.0]], [0.2], low)
    with pytest.raises(ControllerInputError, match="h must be finite"):
        barrier_terms(ev, [[0.36, 1.0]], [np.inf], low)
    terms = barrier_terms(ev, [[0.36, 1.0]], [0.3], low)
    with pytest.raises(NonFiniteCommandError):
        terms.constraint([np.nan, 0.0])
