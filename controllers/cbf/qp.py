"""The CBF filter's quadratic program (docs/model.md#control-barrier-function), solved thousands of times a second.

    u* = argmin_u ‖u − u_nom‖²   s.t.   A u ≤ b,   lb ≤ u ≤ ub (optional box)

u, u_nom, lb, ub: (N,) in hPa; A: (m, N), b: (m,) general rows (the CBF rows
L_gB_i u ≤ γ_i/B_i − L_fB_i; a row's units are whatever B's are, per hPa). Sized for
N = 1..4 and m = 1..6 (any size works; the native solver's cost grows like (m + 2N) N²).

Preprocessing, the same for every backend:
- Each general row is scaled to unit norm: â_i = a_i/‖a_i‖ (dimensionless),
  b̂_i = b_i/‖a_i‖ (hPa, the signed distance of the row's boundary from u = 0). L_gB is
  ≈ 1e-5…1e-4 per hPa; unscaled, solvers with absolute tolerances mis-solve the row.
- A row with a NaN or infinite coefficient or bound (‖a_i‖ or b_i not finite) cannot be
  evaluated: the problem is reported infeasible ("row i is not finite"), the row is never
  dropped (a caller that builds rows from overflowing terms learns it).
- A row with ‖a_i‖ ≤ `zero_row_tol` (default 1e-12, in A's units) reads 0 ≤ b_i: it is
  dropped if b_i ≥ 0 and makes the problem infeasible if b_i < 0. Such rows are never
  reported active.
- If u_nom satisfies every row and the box within the feasibility tolerance it is the
  answer (iterations = 0) and no backend runs.

Tolerances (hPa, on the unit rows), `tolerances(u_nom, lb, ub)`:
    feasibility  = FEASIBILITY_RTOL · s + ROUNDING_RTOL · max|u_nom|   (1e-9 · s + …)
    acceptance   = ACCEPT_RTOL · s + ROUNDING_RTOL · max|u_nom|        (1e-6 · s + …)
with s = 1 + max(|lb|, |ub|) over the bounds given (s = 1 without bounds) and
ROUNDING_RTOL = 1e-13 (≈ 450 ulp). The first term is fixed by the problem's box, not by
u_nom: a huge but finite u_nom (1e12 hPa) must not loosen the rows (it did when s also
held |u_nom|: the filter then returned a command violating its barrier row by 79 hPa as
"optimal"). The second term is the floating-point floor of the computation, which starts
at u_nom: an iterate's rounding error is a few ulp of max|u_nom|, 1e-4 hPa at 1e12 hPa;
for |u_nom| ≤ 1e4 hPa it is below 1e-9 hPa. b̂ is left out because a far, inactive row
— b̂ → ±∞ as L_gB → 0 — must not loosen the other rows' tolerance.
- feasibility: the native solver's and the shortcut's feasibility test;
- acceptance: a backend's answer counts as feasible only if it violates no row or bound
  by more than this; the same threshold marks a general row active (b̂_i − â_i u ≤ it).
  Callers (the CBF filter) check their own rows against it after the solve.

Backends (`available_backends()`):
- "native": a Goldfarb–Idnani dual active-set method specialised to the identity Hessian,
  in plain Python floats (faster than numpy for N ≤ 4). It starts from the unconstrained
  optimum u_nom and adds the most violated row each time; with working set W
  (linearly independent unit rows, Q R = [â_k]_{k∈W}, Q orthonormal) and added row p:
      z = (I − QQᵀ) â_p (primal step), r = R⁻¹ Qᵀ â_p (dual step), u ← u − t z,
      λ_W ← λ_W − t r, λ_p ← λ_p + t,
  with t = min(full step (â_p·u − b̂_p)/‖z‖², largest t keeping λ_W ≥ 0). A row that
  blocks the dual step leaves W. When z = 0 and no multiplier blocks, â_p = Σ r_k â_k with
  r ≤ 0, a certificate that the rows are inconsistent: "infeasible". Exact to rounding;
  parallel, duplicate and degenerate rows are handled by the dual steps. `iterations`
  counts the steps (row additions and removals); more than 200 gives "iteration_limit".
- "daqp": DAQP's own C API (daqp.solve), the box passed as simple bounds.
- "qpsolvers:<name>": the same problem through qpsolvers for name in daqp, quadprog, osqp,
  proxqp, piqp (those installed), with tolerances tightened to ≈ 1e-10; `iterations` is
  None and a failure reads "infeasible or failed" (qpsolvers does not tell them apart); an
  exception of the solver (OSQP refuses bounds beyond its 1e30 "infinity") reads "<name> failed".
  OSQP's max_iter is 4000 (its solves of the filter's and the tests' QPs take ≤ 375
  iterations; the least-violation QP, which it cannot solve, then fails in ≈ 15 ms, not
  in 100000 iterations ≈ 100 ms).
  quadprog has no feasibility tolerance and may call a degenerate problem (a dependent
  row violated by rounding at a vertex with more tight rows than N) infeasible.
`tools/bench_qp.py` measures them per solve, `tools/bench_filter.py --backends native,daqp`
inside the whole filter step. DEFAULT_BACKEND stays "native" (decided on the second of two
measurements): over 3000 states of each 30 s paper_sim configuration, timed round-robin
in one process (CPU time, 2-CPU x86_64 shared machine), the median of the steps that solve a
QP was 85 / 100 / 83 / 107 µs with native and 103 / 110 / 99 / 119 µs with daqp (Low off,
Low on, High off, High on), with identical actions and commands within 6.2e-11 hPa (the first
measurement, on another machine: 74 vs 76 µs). daqp stays available; the slack QP's fallback is
native.
"""

from __future__ import annotations

import importlib.util
import math
import warnings
from dataclasses import dataclass
from functools import lru_cache
from operator import mul
from typing import Callable, NamedTuple, Sequence

import daqp
import numpy as np
from numpy.typing import ArrayLike

FEASIBILITY_RTOL = 1e-9
ACCEPT_RTOL = 1e-6
ROUNDING_RTOL = 1e-13
ZERO_ROW_TOL = 1e-12
_DEPENDENT_TOL = 1e-12
"""‖z‖ below which an added unit row counts as a combination of the working set's rows."""
_DEPENDENT_TOL_SQ = _DEPENDENT_TOL**2
_MAX_ITERATIONS = 200
_DAQP_INF = 1e30

_QPSOLVERS_SETTINGS: dict[str, dict[str, float | bool]] = {
    "daqp": {"primal_tol": 1e-10},
    "quadprog": {},
    "osqp": {"eps_abs": 1e-10, "eps_rel": 1e-10, "polishing": True, "max_iter": 4000},
    "proxqp": {"eps_abs": 1e-10, "eps_rel": 0.0},
    "piqp": {"eps_abs": 1e-10, "eps_rel": 1e-10},
}
QPSOLVERS_MODULES = {"daqp": "daqp", "quadprog": "quadprog", "osqp": "osqp", "proxqp": "proxsuite", "piqp": "piqp"}
"""The Python module each qpsolvers solver needs: a solver is available when qpsolvers and it are
installed (found without importing them: qpsolvers imports SciPy, ~0.4 s, which listing the
backends should not pay; it is imported at the first solve through it)."""

@dataclass(frozen=True, eq=False)
class QPSolution:
    """`u` (N,) hPa, None when infeasible; `active` (m,) bool over the general rows as given;
    `status` "optimal" iff feasible, otherwise why not; `iterations` when the backend says."""

    u: np.ndarray | None
    feasible: bool
    active: np.ndarray
    status: str
    iterations: int | None


def dot_lists(a: list[float], b: list[float]) -> float:
    return sum(map(mul, a, b))


def row_norm(a: Sequence[float]) -> float:
    """‖a‖ as √(a·a) (the floats every earlier result used), through hypot only where the squares overflow."""
    norm = math.sqrt(sum(map(mul, a, a)))
    return math.hypot(*a) if norm == math.inf else norm


def _split(Q: list[list[float]], a: list[float]) -> tuple[list[float], list[float]]:
    """a = Q d + z with z ⊥ span(Q): classical Gram–Schmidt applied twice (stable for ≤ 4 vectors)."""
    d = [0.0] * len(Q)
    z = list(a)
    for _ in range(2):
        for k, q in enumerate(Q):
            c = sum(map(mul, q, z))
            d[k] += c
            z = [zi - c * qi for zi, qi in zip(z, q)]
    return d, z


def _append(Q: list[list[float]], R: list[list[float]], d: list[float], z: list[float]) -> None:
    """Extend Q R by a column whose split is (d, z); R is kept as its columns (column j has j+1 entries)."""
    norm = math.sqrt(dot_lists(z, z))
    Q.append([zi / norm for zi in z])
    R.append(d + [norm])


def _back_substitute(R: list[list[float]], d: list[float]) -> list[float]:
    r = [0.0] * len(d)
    for i in range(len(d) - 1, -1, -1):
        r[i] = (d[i] - sum(R[j][i] * r[j] for j in range(i + 1, len(d)))) / R[i][i]
    return r


def _dual_active_set(x: list[float], rows: list[list[float]], rhs: list[float],
                     tol: float) -> tuple[list[float] | None, str, int]:
    """Goldfarb–Idnani for min ½‖u − x‖² s.t. rows·u ≤ rhs (unit rows), from u = x (module docstring)."""
    working: list[int] = []
    lam: list[float] = []
    Q: list[list[float]] = []
    R: list[list[float]] = []
    iterations = 0
    while True:
        p, worst = -1, tol
        for k, (a, c) in enumerate(zip(rows, rhs)):
            if k not in working:
                violation = sum(map(mul, a, x)) - c
                if violation > worst:
                    p, worst = k, violation
        if p < 0:
            return x, "optimal", iterations
        a, lam_p = rows[p], 0.0
        while True:
            iterations += 1
            if iterations > _MAX_ITERATIONS:
                return None, "iteration_limit", iterations
            if Q:
                d, z = _split(Q, a)
                r = _back_substitute(R, d)
            else:  # empty working set: nothing to project out
                d, z, r = [], list(a), []
            zz = sum(map(mul, z, z))
            t_dual, block = math.inf, -1
            for k, (rk, lk) in enumerate(zip(r, lam)):
                if rk > 0.0 and lk < t_dual * rk:
                    t_dual, block = lk / rk, k
            t_full = (sum(map(mul, a, x)) - rhs[p]) / zz if zz > _DEPENDENT_TOL_SQ else math.inf
            t = min(t_dual, t_full)
            if t == math.inf:
                return None, "infeasible", iterations
            if lam:
                lam = [lk - t * rk for lk, rk in zip(lam, r)]
            lam_p += t
            if t_full < math.inf:
                x = [xi - t * zi for xi, zi in zip(x, z)]
            if t_full <= t_dual:
                working.append(p)
                lam.append(lam_p)
                _append(Q, R, d, z)
                break
            del working[block], lam[block]
            Q, R = [], []
            for k in working:
                _append(Q, R, *_split(Q, rows[k]))


class _Problem(NamedTuple):
    """The normalised problem as Python floats: general rows (â, b̂), the box, and all rows as (row, rhs)."""

    u0: list[float]
    A_hat: list[list[float]]
    b_hat: list[float]
    lb: list[float] | None
    ub: list[float] | None
    rows: list[Sequence[float]]
    rhs: list[float]
    tol: float

    def violation(self, u: list[float]) -> float:
        return max([sum(map(mul, a, u)) - c for a, c in zip(self.rows, self.rhs)], default=0.0)


BackendResult = tuple["list[float] | np.ndarray | None", str, "int | None"]


def _solve_native(problem: _Problem) -> BackendResult:
    return _dual_active_set(problem.u0, problem.rows, problem.rhs, problem.tol)


_DAQP_STATUS = {1: "optimal", 2: "optimal", -1: "infeasible", -2: "cycling", -3: "unbounded",
                -4: "iteration_limit", -5: "nonconvex", -6: "overdetermined initial active set"}


def _solve_daqp(problem: _Problem) -> BackendResult:
    n, m = len(problem.u0), len(problem.b_hat)
    upper, lower = problem.b_hat, [-_DAQP_INF] * m
    if problem.lb is not None or problem.ub is not None:
        upper = (problem.ub or [_DAQP_INF] * n) + upper
        lower = (problem.lb or [-_DAQP_INF] * n) + lower
    x, _, flag, info = daqp.solve(np.eye(n), -np.array(problem.u0), np.array(problem.A_hat).reshape(m, n),
                                  np.array(upper), np.array(lower), np.zeros(len(upper), dtype=np.int32),
                                  primal_tol=problem.tol)
    status = _DAQP_STATUS.get(flag, f"daqp exitflag {flag}")
    return (x if status == "optimal" else None), status, int(info["iterations"])


def _qpsolvers_backend(solver: str) -> Callable[[_Problem], BackendResult]:
    settings = _QPSOLVERS_SETTINGS[solver]

    def solve(problem: _Problem) -> BackendResult:
        import qpsolvers  # noqa: PLC0415 — 0.57 s to import (-X importtime): at the first solve (QPSOLVERS_MODULES)

        n, has_rows = len(problem.u0), len(problem.b_hat) > 0
        qp = qpsolvers.Problem(
            np.eye(n), -np.array(problem.u0),
            np.array(problem.A_hat) if has_rows else None, np.array(problem.b_hat) if has_rows else None,
            lb=None if problem.lb is None else np.array(problem.lb),
            ub=None if problem.ub is None else np.array(problem.ub))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # qpsolvers' dense→sparse conversion notice for osqp
            try:
                solution = qpsolvers.solve_problem(qp, solver=solver, **settings)
            except Exception as exc:  # noqa: BLE001 — a third-party solver's own exception types (e.g. OSQPException
                # for bounds beyond its 1e30 "infinity") all mean "this backend failed", never a crash of the filter
                return None, f"{solver} failed: {type(exc).__name__}: {exc}", None
        if not solution.found or solution.x is None:
            return None, "infeasible or failed", None
        return solution.x, "optimal", None

    return solve


_BACKENDS: dict[str, Callable[[_Problem], BackendResult]] = {"native": _solve_native, "daqp": _solve_daqp}
_BACKENDS.update({f"qpsolvers:{name}": _qpsolvers_backend(name) for name in _QPSOLVERS_SETTINGS
                  if importlib.util.find_spec("qpsolvers") and importlib.util.find_spec(QPSOLVERS_MODULES[name])})

DEFAULT_BACKEND = "native"


def available_backends() -> list[str]:
    """Backend names accepted by `solve_qp`, the installed qpsolvers solvers included."""
    return list(_BACKENDS)


def check_backend(name: object) -> str:
    """`name` if it is an available backend; ValueError "qp_backend must be one of …, got …" otherwise."""
    if not isinstance(name, str) or name not in _BACKENDS:
        raise ValueError(f"qp_backend must be one of {', '.join(_BACKENDS)}, got {name!r}")
    return name


def _finite_list(name: str, value: ArrayLike, shape: tuple[int, ...] | None) -> list:
    arr = np.asarray(value, dtype=float)
    if shape is not None and arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {arr.shape}")
    values = arr.tolist()
    flat = values if arr.ndim == 1 else [x for row in values for x in row]
    if not all(map(math.isfinite, flat)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return values


def solve_qp(u_nom: ArrayLike, A: ArrayLike, b: ArrayLike, lb: ArrayLike | None = None,
             ub: ArrayLike | None = None, backend: str = DEFAULT_BACKEND,
             zero_row_tol: float = ZERO_ROW_TOL) -> QPSolution:
    """Solve min ‖u − u_nom‖² s.t. A u ≤ b, lb ≤ u ≤ ub; see the module docstring.

    Raises ValueError for malformed input (shapes, non-finite values, lb > ub, unknown
    backend); an infeasible problem is not an error but a QPSolution with feasible=False.
    """
    if backend not in _BACKENDS:
        raise ValueError(f"backend must be one of {available_backends()}, got {backend!r}")
    u_nom = np.asarray(u_nom, dtype=float)
    if u_nom.ndim != 1 or u_nom.size < 1:
        raise ValueError(f"u_nom must have shape (N,) with N >= 1, got {u_nom.shape}")
    n = u_nom.size
    u0 = _finite_list("u_nom", u_nom, None)
    A = np.asarray(A, dtype=float)
    if A.ndim != 2 or A.shape[1] != n:
        raise ValueError(f"A must have shape (m, {n}), got {A.shape}")
    m = A.shape[0]
    rows = _finite_list("A", A, None)
    b_list = _finite_list("b", b, (m,))
    lb_list = None if lb is None else _finite_list("lb", lb, (n,))
    ub_list = None if ub is None else _finite_list("ub", ub, (n,))
    if lb_list is not None and ub_list is not None:
        for j, (lo, hi) in enumerate(zip(lb_list, ub_list)):
            if lo > hi:
                raise ValueError(f"lb[{j}] = {lo} exceeds ub[{j}] = {hi}")
    u, active, status, iterations = solve_lists(u0, rows, b_list, lb_list, ub_list, backend, zero_row_tol)
    return QPSolution(None if u is None else np.array(u), u is not None, np.array(active, dtype=bool), status, iterations)


@lru_cache(maxsize=None)
def _unit_rows(n: int, sign: float) -> tuple[tuple[float, ...], ...]:
    """The box rows sign·e_j, j = 0..n−1 (read-only)."""
    return tuple(tuple(sign if k == j else 0.0 for k in range(n)) for j in range(n))


def solve_lists(u0: list[float], rows: list[list[float]], b_list: list[float], lb_list: list[float] | None,
           ub_list: list[float] | None, backend: str = DEFAULT_BACKEND,
           zero_row_tol: float = ZERO_ROW_TOL) -> tuple[list[float] | None, list[bool], str, int | None]:
    """`solve_qp` on Python float lists that were checked already (shapes, finite, lb ≤ ub, backend).

    Returns (u or None when infeasible, active, status, iterations) as Python objects.
    """
    n, m = len(u0), len(rows)
    active = [False] * m
    A_hat: list[list[float]] = []
    b_hat: list[float] = []
    kept: list[int] = []
    for i, (a, bi) in enumerate(zip(rows, b_list)):
        norm = math.sqrt(sum(map(mul, a, a)))  # row_norm, inlined: this loop runs every filter QP
        if not math.isfinite(norm + bi) and not math.isfinite((norm := math.hypot(*a)) + bi):
            return None, active, f"infeasible: row {i} is not finite (|a| = {norm}, b = {bi})", 0
        if norm > zero_row_tol:
            A_hat.append([x / norm for x in a])
            b_hat.append(bi / norm)
            kept.append(i)
        elif bi < 0.0:
            return None, active, f"infeasible: row {i} is zero (|a| = {norm:.1e}) and b = {bi:.3g} < 0", 0
    rows_all, rhs_all = list(A_hat), list(b_hat)
    if ub_list is not None:
        rows_all += _unit_rows(n, 1.0)
        rhs_all += ub_list
    if lb_list is not None:
        rows_all += _unit_rows(n, -1.0)
        rhs_all += [-value for value in lb_list]
    feasibility_tol, accept_tol = tolerances(u0, lb_list, ub_list)
    problem = _Problem(u0, A_hat, b_hat, lb_list, ub_list, rows_all, rhs_all, feasibility_tol)

    if problem.violation(u0) <= problem.tol:
        u, status, iterations = u0, "optimal", 0
    else:
        x, status, iterations = _BACKENDS[backend](problem)
        if x is None:
            return None, active, status, iterations
        u = list(map(float, x))
        excess = problem.violation(u)
        if not excess <= accept_tol:
            return None, active, f"{status} but violates a constraint by {excess:.3g} hPa", iterations
    for i, a, c in zip(kept, A_hat, b_hat):
        active[i] = c - sum(map(mul, a, u)) <= accept_tol
    return u, active, status, iterations


def tolerances(u0: Sequence[float], lb_list: Sequence[float] | None,
               ub_list: Sequence[float] | None) -> tuple[float, float]:
    """(feasibility, acceptance) tolerances in hPa on unit rows for a problem with these u_nom and bounds.

    See the module docstring: FEASIBILITY_RTOL / ACCEPT_RTOL times s = 1 + max(|lb|, |ub|),
    plus the rounding floor ROUNDING_RTOL · max|u_nom|.
    """
    scale = 1.0 + max(map(abs, (lb_list or []) + (ub_list or [])), default=0.0)
    floor = ROUNDING_RTOL * max(max(u0), -min(u0))
    return FEASIBILITY_RTOL * scale + floor, ACCEPT_RTOL * scale + floor
