"""cbf_qp_batch, and CBFFilter's calls (the same kernel at B = 1), against the filter's scalar QP
(`CBFFilter.step(..., scalar=True)`, the fallback's path, on the rows the kernel computed) on thousands of random
states: labels and commands (1e-9 hPa)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from controllers.cbf.barrier import TUNINGS, barrier_terms
from controllers.cbf.batch import (ENUMERATION_MAX_CANDIDATES, PaperCBFKernel, RecoveryRows, candidate_count,
                                   candidate_table, cbf_qp_batch, subset_levels)
from controllers.model.dynamics import PCCDynamics
from controllers.model.dynamics_batch import BatchDynamics
from controllers.core.errors import NonFiniteStateError
from controllers.cbf.paper_filter import CBFFilter
from controllers.model.params import reference_robot, uniform_robot
from controllers.cbf.qp import tolerances
from controllers.model.pcc import tip_jacobian, tip_positions
from controllers.model.safe_set import Environment, ForceSafeSet, LinearStiffness, paper_safe_set
from controllers.contract.safety_filter import Estimate, EstimateBatch

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
@pytest.mark.parametrize("recover", [False, True])
def test_batch_matches_scalar_filter(tuning, pressure_limits, recover):
    """With `recovery` the states outside P (b ≤ B_MIN on a row) are solved in the batch too, with the filter's
    quasi-static rows; without, they go to the fallback. Either way: the scalar filter's labels and commands."""
    params, safe_set = reference_robot(), paper_safe_set()
    scalar = CBFFilter(params, safe_set, TUNINGS[tuning], pressure_limits=pressure_limits)
    q, qd, u_nom = _states(hash((tuning, pressure_limits)) % 2**32)
    limits = (np.array(params.u_min), np.array(params.u_max)) if pressure_limits else (None, None)
    calls = []

    def fallback(i):
        calls.append(i)
        return scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True)

    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *limits, fallback=fallback,
                       recovery=RecoveryRows.of(params, safe_set, scalar.recovery_margin) if recover else None)
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True) for i in range(N_STATES)]
    actions = np.array([w.action for w in want])
    np.testing.assert_array_equal(out.action, actions)
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(out.infeasible, [w.infeasible for w in want])
    np.testing.assert_array_equal(out.rho_pred, [w.rho_pred for w in want])
    np.testing.assert_allclose(out.b, [w.b for w in want], rtol=0.0, atol=0.0)
    assert sorted(calls) == np.flatnonzero(~out.resolved).tolist()
    covered = set(actions[out.resolved])
    if tuning == "None":
        assert covered == {"disabled"}
    elif recover:  # the random states exercise every covered branch; only infeasible states are left
        assert covered == {"nominal", "qp", "recovery"}, covered
        assert set(actions[~out.resolved]) <= {"slack", "vent"}
        recovering = out.resolved & np.array([w.recovery for w in want])  # outside P, solved in the batch
        assert np.count_nonzero(recovering) > N_STATES // 20 and {"nominal", "recovery"} <= set(actions[recovering])
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
                       np.array(params.u_max),
                       fallback=lambda i: scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True))
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True) for i in range(N_STATES)]
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


@pytest.mark.parametrize("n_seg", [2, 3])
@pytest.mark.parametrize("tuning", ["Low", "HW-High"])
@pytest.mark.parametrize("pressure_limits", [True, False])
def test_the_filter_call_is_the_kernel_and_agrees_with_the_scalar_qp(n_seg, tuning, pressure_limits):
    """B = 1 goes through the batched kernel (`CBFFilter.step` and `__call__`); where the kernel hands a state back
    (infeasible: "slack", the rest target) the scalar QP decides. On random states inside and outside P the two
    paths agree: the same label and b, commands within 1e-9 hPa, B within 1e-12 relative, the constraint within
    1e-9 /s (+1e-9 relative), the same active rows (measured on N = 2: 1e-10 hPa, 7e-12 /s)."""
    params = reference_robot() if n_seg == 2 else uniform_robot(n_seg)
    safe_set = paper_safe_set()
    filt = CBFFilter(params, safe_set, TUNINGS[tuning], pressure_limits=pressure_limits)
    rng = np.random.default_rng(n_seg * 10 + pressure_limits)
    q = rng.uniform(-0.3, 0.6, (600, n_seg))
    qd = rng.normal(0.0, 1.5, (600, n_seg))
    u_nom = rng.uniform(-250.0, 250.0, (600, n_seg))
    actions = set()
    for x, u in zip(np.hstack((q, qd)), u_nom):
        got, want = filt.step(x, u), filt.step(x, u, scalar=True)
        assert got.action == want.action and got.infeasible == want.infeasible, (x, u)
        np.testing.assert_allclose(got.u, want.u, rtol=0.0, atol=1e-9)
        np.testing.assert_array_equal(got.b, want.b)
        np.testing.assert_allclose(got.B, want.B, rtol=1e-12)
        np.testing.assert_allclose(got.constraint, want.constraint, rtol=1e-9, atol=1e-9)
        np.testing.assert_array_equal(got.active, want.active)
        assert got.recovery == want.recovery and got.rho_pred == want.rho_pred
        out = filt(Estimate(0.0, x[:n_seg], x[n_seg:], 0.0), u)
        assert out.action == got.action and np.array_equal(out.u, got.u)
        actions.add(got.action)
    assert {"nominal", "qp", "recovery"} <= actions  # the kernel's branches were compared


@pytest.mark.parametrize("n_seg", [2, 3])
def test_the_kernel_returns_the_rows_the_fallback_solves_on(n_seg):
    """The kernel's rows at each state (`KernelOutput`, which the scalar fallback reads): b, B, L_fB and L_gB are
    `barrier_terms`' (the same compiled function, checked against finite differences of B in tests/test_cbf.py),
    and every row's quasi-static row is its definition (H'_i J_r K⁻¹Λ) u ≤ b_i − ε_i + H'_i J_r q from the public
    kinematics; on states inside and outside P (three rows: a corner)."""
    params = reference_robot() if n_seg == 2 else uniform_robot(n_seg, length=0.07)  # a tip that reaches inside
    corner = Environment(np.array([[0.36, 1.0], [1.0, -1.0]]), np.array([0.15, 0.17]))
    safe_set = ForceSafeSet(corner, LinearStiffness(11.16), 0.16, row_scaling="paper")
    recovery = RecoveryRows.of(params, safe_set, 2e-3)
    kernel = PaperCBFKernel(n_seg, safe_set, TUNINGS["HW-High"], np.array(params.u_min), np.array(params.u_max),
                            recovery)
    rng = np.random.default_rng(40 + n_seg)
    q, qd = rng.uniform(-0.8, 0.8, (200, n_seg)), rng.normal(0.0, 1.5, (200, n_seg))
    u_nom = rng.uniform(-250.0, 250.0, (200, n_seg))
    terms = BatchDynamics(params).terms(q, qd)
    out = kernel.run(terms.kin, terms.layout.tip_terms.start, terms.layout.tip_jac.start, q, u_nom)
    dyn, H, h = PCCDynamics(params), np.asarray(safe_set.H_prime), np.asarray(safe_set.h_prime)
    gain, eps = np.array(recovery.static_gain), np.array(recovery.margins)
    outside = 0
    for s in range(len(q)):
        want = barrier_terms(dyn.evaluate(q[s], qd[s]), H, h, TUNINGS["HW-High"])
        np.testing.assert_array_equal(out.b[s], want.b)
        np.testing.assert_array_equal(out.B[s], want.B)
        np.testing.assert_array_equal(out.LfB[s], want.LfB)
        np.testing.assert_array_equal(out.LgB[s], want.LgB)
        h_jac = H @ tip_jacobian(q[s], dyn.lengths)  # H'_i J_r (P, N)
        np.testing.assert_allclose(out.static_a[s], h_jac * gain, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(out.static_c[s], want.b - eps + h_jac @ q[s], rtol=1e-12, atol=1e-14)
        outside += not want.defined.all()
        assert np.isfinite(out.LgB[s]).all() and (out.LgB[s][~want.defined] == 0.0).all()
    assert 0 < outside < len(q)


def _inside_states(params, safe_set, count: int, spread: float, seed: int):
    """`count` random states of `params` whose tip is inside every row of P (b > 0: no recovery), moving
    (some nearly at rest), with commands inside and beyond ±150 hPa."""
    rng = np.random.default_rng(seed)
    n = params.n_segments
    q = rng.uniform(-spread, spread, (4 * count, n))
    b = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS["None"], q, np.zeros_like(q), np.zeros_like(q)).b
    q = q[np.all(b > 0.0, axis=1)][:count]
    assert len(q) == count
    qd = rng.normal(0.0, 1.5, (count, n))
    qd[: count // 10] *= 1e-3
    return q, qd, rng.uniform(-250.0, 250.0, (count, n))


@pytest.mark.parametrize("n_seg", [3, 4])
@pytest.mark.parametrize("tuning", ["Low", "High", "HW-High"])
@pytest.mark.parametrize("corner", [False, True])
@pytest.mark.parametrize("pressure_limits", [True, False])
def test_n_segment_batch_matches_scalar_filter(n_seg, tuning, corner, pressure_limits):
    """N = 3 and 4: the QP states solved by the enumeration (subsets of up to N rows), against the scalar
    filter's QP on thousands of states inside P; a corner (three CBF rows) and the box give vertices."""
    params = uniform_robot(n_seg)
    safe_set = paper_safe_set()
    if corner:  # the corner of the N = 2 test, its facets placed at the 70th percentile of this arm's tips
        normals = np.array([[0.36, 1.0], [1.0, -1.0]])
        tips = tip_positions(np.random.default_rng(0).uniform(-0.4, 0.4, (2000, n_seg)), params.array("lengths"))
        safe_set = ForceSafeSet(Environment(normals, np.percentile(tips @ normals.T, 70, axis=0)), LinearStiffness(11.16),
                                0.16, row_scaling="paper")
        assert len(safe_set.H_prime) == 3
    scalar = CBFFilter(params, safe_set, TUNINGS[tuning], pressure_limits=pressure_limits)
    count = 2000 if n_seg == 3 else 1000
    q, qd, u_nom = _inside_states(params, safe_set, count, 0.4, n_seg)
    calls = []

    def fallback(i):
        calls.append(i)
        return scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True)

    limits = (np.array(params.u_min), np.array(params.u_max)) if pressure_limits else (None, None)
    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS[tuning], q, qd, u_nom, *limits, fallback=fallback)
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True) for i in range(count)]
    np.testing.assert_array_equal(out.action, [w.action for w in want])
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(out.infeasible, [w.infeasible for w in want])
    np.testing.assert_array_equal(out.rho_pred, [w.rho_pred for w in want])
    np.testing.assert_array_equal(out.b, [w.b for w in want])
    assert sorted(calls) == np.flatnonzero(~out.resolved).tolist()
    assert set(out.action[out.resolved]) == {"nominal", "qp"}
    assert np.count_nonzero(out.resolved & (out.action == "qp")) > count // 5  # the enumeration, not the fallback
    if corner:
        two_active = sum(int(np.count_nonzero(w.active)) >= 2 for w, ok in zip(want, out.resolved) if ok)
        assert two_active > 0, "no state with two active CBF rows: the multi-row candidates go untested"


@pytest.mark.parametrize("n_seg, pressure_limits", [(5, True), (6, True), (6, False)])
def test_the_enumeration_up_to_its_candidate_count(n_seg, pressure_limits):
    """Up to ENUMERATION_MAX_CANDIDATES candidates the QP states are enumerated (N = 5 with the box: 454; N = 6
    without: 2), beyond they go to the fallback (N = 6 with the box: 1394); the scalar filter's labels either way."""
    params, safe_set = uniform_robot(n_seg), paper_safe_set()
    scalar = CBFFilter(params, safe_set, TUNINGS["HW-High"], pressure_limits=pressure_limits)
    q, qd, u_nom = _inside_states(params, safe_set, 200, 0.3, 1)
    limits = (np.array(params.u_min), np.array(params.u_max)) if pressure_limits else (None, None)
    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS["HW-High"], q, qd, u_nom, *limits,
                       fallback=lambda i: scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True))
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True) for i in range(len(q))]
    np.testing.assert_array_equal(out.action, [w.action for w in want])
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0.0, atol=1e-9)
    enumerated = len(candidate_table(1 + 2 * n_seg, n_seg, 1) if pressure_limits else candidate_table(1, n_seg, None)) \
        <= ENUMERATION_MAX_CANDIDATES
    assert enumerated == ((n_seg, pressure_limits) != (6, True))
    qp = out.action == "qp"
    assert np.any(qp) and np.all(out.resolved[qp] == enumerated)
    if not enumerated:
        np.testing.assert_array_equal(out.u[qp], [w.u for w, is_qp in zip(want, qp) if is_qp])


@pytest.mark.parametrize("n_seg, bounded, count", [(2, True, 14), (3, True, 46), (4, True, 146), (5, True, 454),
                                                    (6, True, 1394), (3, False, 2)])
def test_subset_levels_count_and_order(n_seg, bounded, count):
    """The candidates of one facet row: u_nom and the subsets of ≤ N rows without ±e_j together, in
    itertools.combinations order level by level (the tie order of before, for N = 2)."""
    m = 1 + 2 * n_seg if bounded else 1
    levels = subset_levels(m, n_seg, 1 if bounded else None)
    assert 1 + sum(len(rows) for _, rows, _ in levels) == count
    for size, (prefixes, rows, members) in enumerate(levels, start=1):
        want = [s for s in itertools.combinations(range(m), size)
                if not bounded or not any(1 + j in s and 1 + n_seg + j in s for j in range(n_seg))]
        assert [tuple(s) for s in members.tolist()] == want
        assert np.array_equal(members[:, -1], rows)
        for i in range(size - 1):  # prefixes[:, i]: the subset of the first i + 1 rows, in level i + 1
            assert np.array_equal(levels[i][2][prefixes[:, i]], members[:, : i + 1])


@pytest.mark.parametrize("n_seg", [3, 4])
@pytest.mark.parametrize("pressure_limits", [True, False])
def test_n_segment_recovery_rows_match_scalar_filter(n_seg, pressure_limits):
    """N = 3, 4 with states outside P: the quasi-static rows enumerated as the CBF rows are, against the scalar filter."""
    params, safe_set = uniform_robot(n_seg), paper_safe_set()
    scalar = CBFFilter(params, safe_set, TUNINGS["HW-High"], pressure_limits=pressure_limits)
    rng = np.random.default_rng(n_seg)
    count = 1000
    q, qd, u_nom = rng.uniform(-0.4, 0.8, (count, n_seg)), rng.normal(0.0, 1.5, (count, n_seg)), \
        rng.uniform(-250.0, 250.0, (count, n_seg))
    limits = (np.array(params.u_min), np.array(params.u_max)) if pressure_limits else (None, None)
    out = cbf_qp_batch(BatchDynamics(params), safe_set, TUNINGS["HW-High"], q, qd, u_nom, *limits,
                       fallback=lambda i: scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True),
                       recovery=RecoveryRows.of(params, safe_set, scalar.recovery_margin))
    want = [scalar.step(np.concatenate((q[i], qd[i])), u_nom[i], scalar=True) for i in range(count)]
    np.testing.assert_array_equal(out.action, [w.action for w in want])
    np.testing.assert_allclose(out.u, [w.u for w in want], rtol=0.0, atol=1e-9)
    np.testing.assert_array_equal(out.infeasible, [w.infeasible for w in want])
    assert np.count_nonzero(out.resolved & (out.action == "recovery")) > count // 20


@pytest.mark.parametrize("m, n, box_start", [(3, 2, None), (5, 2, 1), (7, 3, 1), (9, 3, 3), (11, 4, 3), (13, 6, 1),
                                             (4, 4, None)])
def test_candidate_count_is_the_tables_length(m, n, box_start):
    assert candidate_count(m, n, box_start) == len(candidate_table(m, n, box_start))


def test_a_many_segment_filter_does_not_build_the_enumerations_table():
    """N = 12 with the box: millions of candidates; the filter is built at once and its QP states take the scalar QP."""
    filt = CBFFilter(uniform_robot(12), paper_safe_set(), TUNINGS["HW-High"])
    assert candidate_count(1 + 24, 12, 1) > 10**6
    out = filt(Estimate(0.0, np.full(12, 0.05), np.full(12, 0.5), 0.0), np.full(12, 150.0))
    assert np.all(np.isfinite(out.u)) and out.action in ("nominal", "qp", "slack", "recovery")


def test_candidate_table_follows_the_subset_levels():
    """The kernel's table: u_nom, then each level's subsets in order, with their sizes, last rows and prefixes."""
    levels = subset_levels(7, 3, 1)
    table = candidate_table(7, 3, 1)
    members = [()] + [tuple(m) for _, _, level in levels for m in level.tolist()]
    assert len(table) == len(members) and table[0].tolist() == [0, 0, 0, 0]
    for row, subset in zip(table[1:].tolist(), members[1:]):
        size = len(subset)
        assert row[:2] == [size, subset[-1]]
        assert [members[g] for g in row[2 : 2 + size - 1]] == [subset[: i + 1] for i in range(size - 1)]


@pytest.mark.parametrize("x, u_nom", [
    ([0.28960896, 0.52232169, -0.7334536, 2.64100095], [-2.20661731e10, -3.25720985e10]),
    ([0.31493941, 0.41934296, -0.40573409, -1.73969356], [7.77760075e07, -6.22589953e08]),
    ([0.50533644, -0.26606365, -2.01033122, -0.99026827], [-3.27364315e09, -5.20451985e09]),
])
def test_a_huge_unbounded_nominal_meets_every_row_within_the_qps_acceptance(x, u_nom):
    """Without the box, the kernel's feasibility tolerance is the scalar QP's (`controllers.cbf.qp.tolerances`), not
    1e-9·|u_nom|: at a corner (three rows) with |u_nom| up to 3e10 hPa the kernel's "qp" command meets every row within
    the acceptance tolerance (it used to accept a projection onto one row violating another by 0.2–1.2 hPa)."""
    params = reference_robot()
    corner = Environment(np.array([[0.36, 1.0], [1.0, -1.0]]), np.array([0.15, 0.17]))
    safe_set = ForceSafeSet(corner, LinearStiffness(11.16), 0.16, row_scaling="paper")
    filt = CBFFilter(params, safe_set, TUNINGS["HW-High"], pressure_limits=False)
    res = filt.step(np.array(x), np.array(u_nom))
    assert res.action == "qp" and not res.infeasible
    terms = barrier_terms(filt.dynamics.evaluate(x[:2], x[2:]), safe_set.H_prime, safe_set.h_prime, filt.tuning)
    excess = (terms.LgB @ res.u - (filt.tuning.gamma / terms.B - terms.LfB)) / np.linalg.norm(terms.LgB, axis=1)
    assert excess.max() <= tolerances(list(u_nom), None, None)[1], excess
    want = filt.step(np.array(x), np.array(u_nom), scalar=True)
    assert want.action == "qp"
    np.testing.assert_allclose(res.u, want.u, rtol=0.0, atol=1e-3)
