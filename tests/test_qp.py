"""The filter's QP (docs/model.md#control-barrier-function): KKT conditions for every backend, infeasibility, zero rows, input checks.

Optimality is certified independently of the solvers' own multipliers. With unit rows
g_k (general rows scaled here, box rows ±e_j) and slacks s_k = c_k − g_k·u (hPa):
- primal feasibility:  min_k s_k ≥ −tol_p,
- stationarity:        u_nom − u = Σ_k λ_k g_k over the tight rows (s_k ≤ tol_a), with λ ≥ 0
                       from non-negative least squares (scipy.optimize.nnls); the residual
                       ‖u_nom − u − Gᵀλ‖ must be ≤ tol_s,
- dual feasibility:    λ ≥ 0 (by construction of nnls),
- complementarity:     max_k λ_k s_k ≤ tol_c.
For this strictly convex problem these conditions certify the unique minimiser. Tolerances
are relative to s = 1 + max|u_nom, lb, ub| (hPa, as in controllers.cbf.qp), per backend class:
exact active-set solvers (native, daqp, quadprog): tol_p = tol_a = tol_s = tol_c = 1e-9 s;
interior-point/ADMM/proximal solvers (osqp, proxqp, piqp):            1e-6 s.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import nnls

import math

from controllers.cbf.qp import available_backends, solve_lists, solve_qp, tolerances

BACKENDS = available_backends()
EXACT = {"native", "daqp", "qpsolvers:daqp", "qpsolvers:quadprog"}
# quadprog has no feasibility tolerance: a dependent row violated by rounding (≈1e-16) at a
# degenerate vertex makes it report "inconsistent constraints". It may refuse such problems
# (never return a wrong u); every other backend must solve them.
REFUSES_DEGENERATE = {"qpsolvers:quadprog"}


def tolerance(backend: str) -> float:
    return 1e-9 if backend in EXACT else 1e-6


def unit_rows(u_nom, A, b, lb, ub):
    """All constraints as unit rows G u ≤ c (zero general rows dropped) and the scale s."""
    A, b = np.asarray(A, float), np.asarray(b, float)
    norms = np.linalg.norm(A, axis=1)
    keep = norms > 1e-12
    G, c = [A[keep] / norms[keep, None]], [b[keep] / norms[keep]]
    n = len(u_nom)
    if ub is not None:
        G.append(np.eye(n))
        c.append(np.asarray(ub, float))
    if lb is not None:
        G.append(-np.eye(n))
        c.append(-np.asarray(lb, float))
    G, c = np.vstack(G), np.concatenate(c)
    bounds = [np.abs(x) for x in (u_nom, lb, ub) if x is not None]
    return G, c, 1.0 + np.max(np.concatenate(bounds)), keep


def kkt_residuals(u_nom, A, b, lb, ub, u, tight_tol):
    """(primal infeasibility, stationarity residual, complementarity) in hPa, and the scale s."""
    G, c, scale, _ = unit_rows(u_nom, A, b, lb, ub)
    slack = c - G @ u
    tight = slack <= tight_tol * scale
    lam = np.zeros(len(c))
    residual = np.linalg.norm(u_nom - u)
    if tight.any():
        lam[tight], residual = nnls(G[tight].T, u_nom - u)
    return max(0.0, -np.min(slack, initial=0.0)), residual, float(np.max(lam * np.abs(slack), initial=0.0)), scale


def random_problem(rng: np.random.Generator, box: bool, degenerate: bool):
    """A feasible problem: rows of scale 1e-5…1, b from a feasible point u_f plus slacks ≥ 0."""
    n = int(rng.integers(1, 5))
    m = int(rng.integers(1, 7))
    lb, ub = (-150.0 * np.ones(n), 150.0 * np.ones(n)) if box else (None, None)
    u_f = rng.uniform(-120.0, 120.0, n)
    A = rng.normal(size=(m, n)) * 10.0 ** rng.uniform(-5.0, 0.0, (m, 1))
    slack = rng.uniform(0.0, 30.0, m) * np.linalg.norm(A, axis=1)
    if degenerate:
        slack[rng.random(m) < 0.7] = 0.0  # many rows through u_f (more than n: a degenerate vertex)
        if m >= 2:
            A[1] = A[0] * 10.0 ** rng.uniform(-3, 3)  # a parallel duplicate of row 0, other scale
            slack[1] = slack[0] * np.linalg.norm(A[1]) / np.linalg.norm(A[0])
        if box:
            u_f[0] = 150.0  # the bound is tight too
    u_nom = u_f + rng.normal(0.0, 100.0, n)
    return u_nom, A, A @ u_f + slack, lb, ub


PROBLEMS = [random_problem(np.random.default_rng(seed), box=seed % 2 == 0, degenerate=seed % 3 == 0) for seed in range(300)]
DEGENERATE = [seed % 3 == 0 for seed in range(300)]


@pytest.mark.parametrize("backend", BACKENDS)
def test_kkt_on_random_feasible_problems(backend):
    tol = tolerance(backend)
    problems = PROBLEMS if backend in EXACT else PROBLEMS[:100]
    solved_active = 0
    for k, (u_nom, A, b, lb, ub) in enumerate(problems):
        sol = solve_qp(u_nom, A, b, lb, ub, backend=backend)
        if backend in REFUSES_DEGENERATE and DEGENERATE[k] and not sol.feasible:
            continue
        assert sol.feasible and sol.status == "optimal", f"problem {k}: {sol.status}"
        assert sol.u.shape == u_nom.shape and sol.active.shape == (len(b),)
        primal, stationarity, complementarity, scale = kkt_residuals(u_nom, A, b, lb, ub, sol.u, tol)
        assert primal <= tol * scale, f"problem {k}: violates a constraint by {primal:.2e} hPa"
        assert stationarity <= tol * scale, f"problem {k}: stationarity residual {stationarity:.2e} hPa"
        assert complementarity <= tol * scale, f"problem {k}: complementarity {complementarity:.2e}"
        # the active mask marks exactly the general rows that hold with equality
        G, c, _, keep = unit_rows(u_nom, A, b, lb, ub)
        G, c = G[: keep.sum()], c[: keep.sum()]
        expected = np.zeros(len(b), dtype=bool)
        accept = tolerances(u_nom.tolist(), None if lb is None else lb.tolist(), None if ub is None else ub.tolist())[1]
        expected[keep] = c - G @ sol.u <= accept
        np.testing.assert_array_equal(sol.active, expected, err_msg=f"problem {k}")
        solved_active += bool(sol.active.any())
    assert solved_active > len(problems) // 3  # the set exercises active rows, not only the shortcut


def test_exact_backends_agree():
    for u_nom, A, b, lb, ub in PROBLEMS:
        ref = solve_qp(u_nom, A, b, lb, ub, backend="native").u
        for backend in EXACT & set(BACKENDS):
            u = solve_qp(u_nom, A, b, lb, ub, backend=backend).u
            if u is not None or backend not in REFUSES_DEGENERATE:
                np.testing.assert_allclose(u, ref, atol=1e-7)


@pytest.mark.parametrize("backend", BACKENDS)
def test_cbf_row_of_realistic_scale(backend):
    """L_gB ≈ 1e-5…1e-4 per hPa: the answer is the exact projection onto the row, not a 20 hPa miss."""
    a = np.array([3e-5, 7e-5])
    u_nom = np.array([80.0, 80.0])
    b = a @ u_nom - 25.0 * np.linalg.norm(a)  # u_nom lies 25 hPa beyond the row
    sol = solve_qp(u_nom, a[None], np.array([b]), -150 * np.ones(2), 150 * np.ones(2), backend=backend)
    expected = u_nom - 25.0 * a / np.linalg.norm(a)
    np.testing.assert_allclose(sol.u, expected, atol=tolerance(backend) * 200)
    assert sol.active.tolist() == [True]


@pytest.mark.parametrize("backend", BACKENDS)
def test_degenerate_vertex_with_more_active_rows_than_variables(backend):
    # five rows through (−30, 40) in 2-D, two of them duplicates at other scales, plus a tight bound
    # normals at 45°, 45°, 72°, 90°, 117° and the bound u2 ≤ 40 (90°): u_nom − point at 80° lies in
    # their cone, so the point is the minimiser
    point = np.array([-30.0, 40.0])
    A = np.array([[1.0, 1.0], [2e-5, 2e-5], [1.0, 3.0], [0.0, 1e-4], [-1.0, 2.0]])
    b = A @ point
    u_nom = point + 50.0 * np.array([np.cos(np.radians(80)), np.sin(np.radians(80))])
    lb, ub = np.array([-150.0, -150.0]), np.array([150.0, 40.0])
    sol = solve_qp(u_nom, A, b, lb, ub, backend=backend)
    if backend in REFUSES_DEGENERATE and not sol.feasible:
        # quadprog has no feasibility tolerance: at a vertex with more tight rows than
        # variables a rounding-level violation makes it give up (docs/paper-cbf.md: not for the filter).
        # It may refuse, but never return a wrong u.
        pytest.xfail(f"{backend} has no feasibility tolerance and refuses this degenerate vertex: {sol.status}")
    assert sol.feasible
    primal, stationarity, complementarity, scale = kkt_residuals(u_nom, A, b, lb, ub, sol.u, tolerance(backend))
    assert max(primal, stationarity, complementarity) <= tolerance(backend) * scale
    np.testing.assert_allclose(sol.u, point, atol=tolerance(backend) * scale)
    assert sol.active.all()


INFEASIBLE = {
    "opposite rows": (np.zeros(2), np.array([[1e-5, 0.0], [-1e-5, 0.0]]), np.array([-1e-5, -1e-5]), None, None),
    "row beyond the box": (np.array([10.0, 10.0]), np.array([[1e-5, 1e-5]]), np.array([-4e-3]), -150 * np.ones(2), 150 * np.ones(2)),
    "three rows at 120 degrees": (np.zeros(2), np.array([[1.0, 0.0], [-0.5, np.sqrt(3) / 2], [-0.5, -np.sqrt(3) / 2]]),
                                  -np.ones(3), None, None),
    "zero row with b < 0": (np.zeros(3), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]), np.array([-1e-9, 1.0]), None, None),
    "four variables, box and two rows": (np.zeros(4), np.array([[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 1.0]]) * 3e-5,
                                         np.array([-1e-2, 5.0]), -150 * np.ones(4), 150 * np.ones(4)),
}


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("case", list(INFEASIBLE))
def test_infeasible_problems_are_flagged(backend, case):
    u_nom, A, b, lb, ub = INFEASIBLE[case]
    sol = solve_qp(u_nom, A, b, lb, ub, backend=backend)
    assert not sol.feasible and sol.u is None and sol.status != "optimal"
    assert sol.active.shape == (len(b),) and not sol.active.any()


@pytest.mark.parametrize("backend", BACKENDS)
def test_zero_rows_with_nonnegative_b_are_ignored(backend):
    A = np.array([[0.0, 0.0], [1e-13, 0.0], [1e-5, 1e-5]])
    b = np.array([0.0, 1e-20, -2e-3])  # third row: u1 + u2 ≤ −200 hPa
    sol = solve_qp(np.array([10.0, 10.0]), A, b, backend=backend)
    np.testing.assert_allclose(sol.u, [-100.0, -100.0], atol=tolerance(backend) * 200)
    assert sol.active.tolist() == [False, False, True]
    # a row just above the zero threshold is a real (scaled) row
    tiny = solve_qp(np.array([10.0]), np.array([[1e-11]]), np.array([-1e-11 * 5.0]), backend=backend)
    np.testing.assert_allclose(tiny.u, [-5.0], atol=tolerance(backend) * 20)


@pytest.mark.parametrize("backend", BACKENDS)
def test_box_only_clips_and_no_constraints_return_u_nom(backend):
    sol = solve_qp(np.array([200.0, -20.0, -400.0]), np.zeros((0, 3)), np.zeros(0), -150 * np.ones(3), 150 * np.ones(3),
                   backend=backend)
    np.testing.assert_allclose(sol.u, [150.0, -20.0, -150.0], atol=tolerance(backend) * 400)
    assert sol.feasible and sol.active.shape == (0,) and sol.active.dtype == bool
    free = solve_qp(np.array([3.0]), np.zeros((0, 1)), np.zeros(0), backend=backend)
    assert free.feasible and free.u.tolist() == [3.0] and free.iterations == 0


@pytest.mark.parametrize("backend", BACKENDS)
def test_far_inactive_row_does_not_loosen_the_box(backend):
    # L_gB → 0 at rest: b̂ = b/‖a‖ = 1e11 hPa; the bound must still be enforced to 1e-9 s
    sol = solve_qp(np.array([150.001, 0.0]), np.array([[1e-11, 0.0]]), np.array([1.0]),
                   -150 * np.ones(2), 150 * np.ones(2), backend=backend)
    assert sol.feasible and sol.u[0] <= 150.0 + 1e-9 * 151 and sol.active.tolist() == [False]


@pytest.mark.parametrize("backend", BACKENDS)
def test_huge_finite_u_nom_does_not_loosen_the_rows(backend):
    """C1: with s = 1 + max|u_nom| the feasibility tolerance was 1e-9 · 1e12 = 1000 hPa, and the box
    corner (150, 150), 67 hPa beyond the row, came back as "optimal".

    Row u_1 − u_2/2 ≤ 0 (scaled like L_gB), box ±150, u_nom far out along (1, 1): the solution is
    the vertex (75, 150) (KKT: u_nom − u = λ_1 (1, −½) + λ_2 (0, 1) with λ ≈ (2e12, 3e12) ≥ 0).
    Exact solvers must find it; the others may refuse (never return a wrong u).
    """
    A, b = np.array([[3e-5, -1.5e-5]]), np.array([0.0])
    box = dict(lb=-150 * np.ones(2), ub=150 * np.ones(2))
    _, accept = tolerances([1e12, 1e12], [-150.0] * 2, [150.0] * 2)
    assert accept < 0.11  # 1e-6 · 151 + 1e-13 · 1e12 hPa: the box's term and the rounding floor, not 1e-6 · u_nom
    for u_nom in ([1e12, 1e12], [1e6, 1e6], [1e12 + 0.3, 1e12]):
        sol = solve_qp(np.array(u_nom), A, b, backend=backend, **box)
        if backend not in EXACT and not sol.feasible:
            continue
        assert sol.feasible, (u_nom, sol.status)
        assert (A[0] @ sol.u - b[0]) / np.linalg.norm(A[0]) <= accept, (u_nom, sol.u)
        np.testing.assert_allclose(sol.u, [75.0, 150.0], atol=accept)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("row, rhs", [([math.nan, 1e-5], 0.0), ([math.inf, 0.0], 1.0), ([1e-5, 1e-5], math.nan),
                                      ([1e-5, 1e-5], -math.inf), ([0.0, 0.0], math.nan), ([1e-5, 1e-5], math.inf)])
def test_nonfinite_rows_are_infeasible_never_dropped(backend, row, rhs):
    """C4: a NaN/inf row used to read as a zero row (dropped): the caller got u_nom as 'optimal'."""
    u, active, status, _ = solve_lists([10.0, 10.0], [row, [1e-5, 0.0]], [rhs, 1.0], [-150.0] * 2, [150.0] * 2, backend)
    assert u is None and status.startswith("infeasible: row 0 is not finite") and active == [False, False]


def test_shortcut_returns_a_copy_of_u_nom_when_it_is_feasible():
    u_nom = np.array([1.0, 2.0])
    sol = solve_qp(u_nom, np.array([[1e-5, 0.0]]), np.array([1.0]), -np.ones(2) * 5, np.ones(2) * 5)
    assert sol.feasible and sol.iterations == 0 and sol.active.tolist() == [False]
    np.testing.assert_array_equal(sol.u, u_nom)
    assert sol.u is not u_nom


def test_native_reports_iterations():
    sol = solve_qp(np.array([100.0, 100.0]), np.array([[1e-5, 0.0]]), np.array([0.0]), -np.ones(2) * 50, np.ones(2) * 50)
    np.testing.assert_allclose(sol.u, [0.0, 50.0], atol=1e-12)
    assert sol.iterations == 2 and sol.active.tolist() == [True]


@pytest.mark.parametrize("kwargs, message", [
    (dict(u_nom=np.zeros(2), A=np.zeros(2), b=np.zeros(1)), r"A must have shape \(m, 2\)"),
    (dict(u_nom=np.zeros((2, 1)), A=np.zeros((1, 2)), b=np.zeros(1)), r"u_nom must have shape \(N,\)"),
    (dict(u_nom=np.zeros(2), A=np.zeros((1, 2)), b=np.zeros(2)), r"b must have shape \(1,\)"),
    (dict(u_nom=np.zeros(2), A=np.array([[np.nan, 0.0]]), b=np.zeros(1)), "A must be finite"),
    (dict(u_nom=np.array([0.0, np.inf]), A=np.zeros((1, 2)), b=np.zeros(1)), "u_nom must be finite"),
    (dict(u_nom=np.zeros(2), A=np.zeros((1, 2)), b=np.zeros(1), lb=np.ones(2), ub=np.zeros(2)), r"lb\[0\] = 1.0 exceeds ub\[0\] = 0.0"),
    (dict(u_nom=np.zeros(2), A=np.zeros((1, 2)), b=np.zeros(1), lb=np.zeros(3)), r"lb must have shape \(2,\)"),
    (dict(u_nom=np.zeros(2), A=np.zeros((1, 2)), b=np.zeros(1), backend="cvxopt"), "backend must be one of"),
])
def test_malformed_input_raises(kwargs, message):
    with pytest.raises(ValueError, match=message):
        solve_qp(**kwargs)


def test_backends_found_without_importing_qpsolvers_are_those_qpsolvers_finds():
    """available_backends() finds qpsolvers' solvers without importing it (QPSOLVERS_MODULES): the same set."""
    import subprocess
    import sys

    code = ("import sys; from controllers.cbf.qp import available_backends; names = available_backends(); "
            "print('qpsolvers' in sys.modules); import qpsolvers; "
            "print(sorted(names) == sorted(['native', 'daqp', *('qpsolvers:' + s for s in qpsolvers.available_solvers "
            "if s in ('daqp', 'quadprog', 'osqp', 'proxqp', 'piqp'))]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == ["False", "True"]
