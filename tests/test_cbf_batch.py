"""cbf_qp_batch against CBFFilter on thousands of random states: labels and commands (1e-9 hPa)."""

from __future__ import annotations

import numpy as np
import pytest

from controllers.cbf import TUNINGS
from controllers.cbf_batch import cbf_qp_batch
from controllers.dynamics_batch import BatchDynamics
from controllers.errors import NonFiniteStateError
from controllers.filter import CBFFilter
from controllers.params import reference_robot, uniform_robot
from controllers.safe_set import Environment, ForceSafeSet, LinearStiffness, paper_safe_set
from controllers.safety_filter import EstimateBatch

N_STATES = 3000


def _states(seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random states around the paper's facet (some outside P) and commands inside and beyond ±150 hPa."""
    rng = np.random.default_rng(seed)
    q = rng.uniform(-0.3, 0.6, (N_STATES, 2))
    qd = rng.normal(0.0, 1.5, (N_STATES, 2))
    qd[: N_STATES // 10] *= 1e-3  # nearly at rest: L_gB → 0
    u_nom = rng.uniform(-250.0, 250.0, (N_STATES, 2))
    return q, qd, u_nom


@pytest.mark.parametrize("tuning", ["None", "Low", "High", "HW-Low", "HW-High"])
@pytest.mark.parametrize("pressure_limits", [True, False])
def test_batch_matches_scalar_filter(tuning, pressure_limits):
    params, safe_set = reference_robot(), paper_safe_set()
    scalar = CBFFilter(params, safe_set, TUNINGS[tuning], pressure_limits=pressure_limits)
    q, qd, u_nom = _states(hash((tuning, pressure_limits)) % 2**32)
    limits = (np.array(params.u_min), np.array(params.u_max)) if pressure_limits else (None, None)
    calls = []

    def fallback(i):
        calls.append(i)
        return scalar.step(np.concatenate((q[i], qd[i])), u_nom[i])

    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *limits, fallback=fallback)
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i]) for i in range(N_STATES)]
    actions = np.array([w.action for w in want])
    np.testing.assert_array_equal(out.action, actions)
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(out.infeasible, [w.infeasible for w in want])
    np.testing.assert_array_equal(out.rho_pred, [w.rho_pred for w in want])
    np.testing.assert_allclose(out.b, [w.b for w in want], rtol=0.0, atol=0.0)
    assert sorted(calls) == np.flatnonzero(~out.resolved).tolist()
    covered = set(actions[out.resolved])
    assert covered <= {"disabled", "nominal", "qp"}
    if tuning == "None":
        assert covered == {"disabled"}
    else:  # the random states exercise every covered branch and the fallback
        assert covered == {"nominal", "qp"}, covered
        assert 0 < len(calls) < N_STATES // 2


def test_batch_matches_scalar_filter_at_a_corner():
    """Two facets and their vertex-correction row: three CBF rows, seven with the box."""
    params = reference_robot()
    corner = Environment(np.array([[0.36, 1.0], [1.0, -1.0]]), np.array([0.15, 0.17]))
    safe_set = ForceSafeSet(corner, LinearStiffness(11.16), 0.16, row_scaling="paper")
    assert len(safe_set.H_prime) == 3
    scalar = CBFFilter(params, safe_set, TUNINGS["HW-High"])
    q, qd, u_nom = _states(5)
    q = np.random.default_rng(6).uniform(-0.3, 0.9, q.shape)  # reaches the corner
    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS["HW-High"], q, qd, u_nom, np.array(params.u_min),
                       np.array(params.u_max), fallback=lambda i: scalar.step(np.concatenate((q[i], qd[i])), u_nom[i]))
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i]) for i in range(N_STATES)]
    np.testing.assert_array_equal(out.action, [w.action for w in want])
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0.0, atol=1e-9)
    assert {"nominal", "qp"} <= set(out.action[out.resolved])
    two_active = sum(int(np.count_nonzero(w.active)) >= 2 for w, ok in zip(want, out.resolved) if ok)
    assert two_active > 0, "no state with two active CBF rows: the vertex candidates go untested"


def test_non_finite_state_names_the_row_and_fallback_is_required():
    params, safe_set = reference_robot(), paper_safe_set()
    q, qd, u_nom = _states(0)
    qd[7, 1] = np.nan
    with pytest.raises(NonFiniteStateError, match=r"qd must be finite, got non-finite rows \[7\]"):
        cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS["Low"], q, qd, u_nom)
    qd[7, 1] = 0.0
    with pytest.raises(ValueError, match="needs the scalar filter"):
        cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS["Low"], q, qd, u_nom)


@pytest.mark.parametrize("n_states", [2, 64])
def test_cbf_filter_batch_equals_its_scalar_calls(n_states):
    params, safe_set = reference_robot(), paper_safe_set()
    filt = CBFFilter(params, safe_set, TUNINGS["HW-High"])
    q, qd, u_nom = (a[:n_states] for a in _states(5))
    estimates = EstimateBatch(np.zeros(n_states), q, qd, np.zeros(n_states))
    out = filt.filter_batch(estimates, u_nom)
    want = [filt(estimates[i], u_nom[i]) for i in range(n_states)]
    assert out.action.tolist() == [w.action for w in want]
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0, atol=1e-9)


@pytest.mark.parametrize("tuning", ["Low", "HW-High"])
def test_three_segment_batch_matches_scalar_filter(tuning):
    """N = 3: barrier terms and the nominal branch batched, every QP state through the fallback."""
    params, safe_set = uniform_robot(3), paper_safe_set()
    scalar = CBFFilter(params, safe_set, TUNINGS[tuning])
    rng = np.random.default_rng(3)
    count = 400
    q, qd = rng.uniform(-0.3, 0.6, (count, 3)), rng.normal(0.0, 1.5, (count, 3))
    u_nom = rng.uniform(-250.0, 250.0, (count, 3))
    calls = []

    def fallback(i):
        calls.append(i)
        return scalar.step(np.concatenate((q[i], qd[i])), u_nom[i])

    limits = np.array(params.u_min), np.array(params.u_max)  # CBFFilter's default pressure limits
    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *limits, fallback=fallback)
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i]) for i in range(count)]
    np.testing.assert_array_equal(out.action, [w.action for w in want])
    np.testing.assert_array_equal(out.u, [w.u for w in want])
    np.testing.assert_array_equal(out.rho_pred, [w.rho_pred for w in want])
    np.testing.assert_array_equal(out.b, [w.b for w in want])
    assert set(out.action[out.resolved]) == {"nominal"} and 0 < len(calls) < count
    assert sorted(calls) == np.flatnonzero(~out.resolved).tolist()
