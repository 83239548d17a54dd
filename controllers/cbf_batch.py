"""The paper's CBF-QP filter (`controllers.filter.CBFFilter`) for B states at once (docs/model.md#control-barrier-function, docs/beyond-the-paper.md#batched-ground-truth).

For B states x_b = [q_b; q̇_b] ((B, N) rad and rad/s each, any number of segments N) and
nominal commands u_nom (B, N) hPa, every state gets what `CBFFilter` computes:

    u*_b = argmin ‖u − u_nom,b‖²  s.t.  L_gB_i(x_b) u ≤ γ/B_i(x_b) − L_fB_i(x_b)   (rows i of P)
                                        u_min ≤ u ≤ u_max                        (when bounded)

with u_nom first saturated to [u_min, u_max] when bounded (as `CBFFilter` does).

Barrier terms: b, ḃ, B, L_fB, L_gB per row (`controllers.cbf`) from the tip terms of
`controllers.dynamics_batch.BatchDynamics`, in the scalar path's operation order, so
b, ḃ, B, L_fB, L_gB are the scalar filter's floats (log1p is the math module's, per state). Branches, as `CBFFilter` takes them:
- "disabled" (tuning None): u = u_nom, clipped to the bounds when they are on;
- "nominal": u_nom within the bounds and L_gB_i u_nom ≤ c_i for every row, tested
  exactly as the scalar filter tests it (u = u_nom);
- "qp" (N ≤ ENUMERATION_MAX_N = 4; for larger N these states go to `fallback`, the scalar
  filter's QP): the QP above, solved exactly by enumeration. The rows are scaled to unit norm
  as `controllers.qp` scales them (â_i = a_i/‖a_i‖, b̂_i = c_i/‖a_i‖; rows with ‖a_i‖ ≤
  ZERO_ROW_TOL dropped when c_i ≥ 0), the box added as the rows +e_j ≤ u_max,j and
  −e_j ≤ −u_min,j: m = P + 2N rows (P unbounded). Derivation: the minimiser u* of the
  strictly convex ‖u − u₀‖² over the polyhedron {u | â_i·u ≤ b̂_i} satisfies the KKT
  conditions u* = u₀ − Σ_{i∈S} μ_i â_i, μ ≥ 0, with S its active rows; dropping rows of S
  whose normals are dependent on the others (a degenerate vertex: the same point) leaves a
  subset of k ≤ N linearly independent rows, and u* is then the projection of u₀ onto their
  affine set {u | A_S u = b_S}:
      u_S = u₀ − A_Sᵀ (A_S A_Sᵀ)⁻¹ (A_S u₀ − b_S)
  (u₀ − u_S lies in the row space of A_S and u_S satisfies the rows). So u* is one of the
  candidates u₀ (S empty) and u_S over every subset of 1 ≤ k ≤ N rows; it is feasible, and no
  feasible candidate is nearer u₀ than the minimiser over the whole polyhedron: the feasible
  candidate nearest u₀ is the optimum (no multipliers needed). Candidates are built subset by
  subset in lexicographic order, each extending its prefix S' by one row a (`subset_levels`):
  with v = a orthogonalised against the prefix's rows (modified Gram–Schmidt; v ⊥ the rows of S'
  and a·v = ‖v‖²), u_S = u_S' − t v with t = (a·u_S' − b̂)/(a·v), which keeps S' satisfied and
  meets a's row, and u₀ − u_S stays in the row space: the projection above without forming
  (A_S A_Sᵀ)⁻¹. For one row this is t = (â·u₀ − b̂)/‖â‖², u₀ − t â, the scalar solver's first
  step float for float. Every level, the square one (k = N: the vertex A_S⁻¹ b_S) included, is
  this step, except the square level of N = 2, which keeps Cramer's rule (`_pair_vertices`, the
  formulas of before): there the chain of projections changed 2763 of 120 000 random states'
  commands, by up to 9e-10 hPa and 40× farther from the scalar filter than Cramer's (unbounded,
  |u| ≈ 4e4 hPa at a corner); with it the N = 2 floats of batched studies do not move (measured
  on the same 120 000 states: no command differs from the enumeration of before). For N = 3, 4
  the chain stays within 5e-12 hPa of the scalar filter in the tests. The feasibility products
  below are one matmul (rounding differences there could only flip a candidate lying within
  1e-14 of the tolerance). A subset whose unit rows span a parallelotope of volume ‖v_1‖⋯‖v_k‖
  (|det A_S| when square) below SINGULAR_TOL = 1e-12 is skipped (nearly dependent
  rows: parallel at k = 2), and so are subsets holding both ±e_j. Count: with the box,
  1 + Σ_{k≤N} C(P + 2N, k) less those pairs: 14, 46, 146 candidates for N = 2, 3, 4 and one
  facet row (27, 106, 384 with three rows); unbounded 1 + Σ_k C(P, k). Every candidate is
  tested for feasibility with the scalar solver's tolerance FEASIBILITY_RTOL·(1 + max(|u_nom|,
  |lb|, |ub|)), and the feasible candidate nearest u₀ wins (ties: the first in the order above).
  u_nom itself within that tolerance gives u = u_nom, as the scalar solver's shortcut does. The
  result is clipped to the bounds, as `CBFFilter` clips it. Above N = 4 the count (454
  candidates at N = 5, one row) makes the enumeration costlier per state than the scalar
  filter's QP (tools/bench_batch_filters.py, which times it there with `enumerate_up_to`), so
  those states go to the fallback.
- Not covered here, handed to `fallback(b)` per state b (the scalar filter): some row
  has b_i ≤ B_MIN ("recovery", the quasi-static rows), or no candidate is feasible
  (the rows and bounds cannot all hold: "slack" / "vent"), or a row is zero with
  c_i < 0. These are rare in closed loop; `resolved` marks the states that did not
  need the fallback. Without a fallback such states raise.

Agreement with `CBFFilter` (tests/test_cbf_batch.py, thousands of random states for N = 2, 3
and 4, one facet and a corner, with and without the box): the same action label, and commands
within 1e-9 hPa. The enumeration is exact to rounding;
the scalar dual active-set method stops once every row holds within the feasibility
tolerance, so both can differ by up to that tolerance (≈ 1.5e-7 hPa at ±150 hPa) when a
row's violation at an intermediate iterate lies below it; in tests this never happened.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from controllers.cbf import B_MIN, Tuning
from controllers.dynamics_batch import BatchDynamics
from controllers.errors import NonFiniteCommandError, NonFiniteStateError
from controllers.qp import FEASIBILITY_RTOL, ZERO_ROW_TOL
from controllers.safe_set import ForceSafeSet


class ScalarResult(Protocol):
    """What the fallback returns for one state: the scalar filter's result (FilterResult or FilterOutput)."""

    u: np.ndarray
    action: str
    infeasible: bool


@dataclass(frozen=True, eq=False)
class CBFBatchResult:
    """B filter results: u (B, N) hPa, action (B,) str, infeasible (B,) bool, rho_pred (B,)
    (the predicted margin, min over facets), b (B, P) (row-scaled m, the barrier per row),
    resolved (B,) bool (False: the state went to the fallback)."""

    u: np.ndarray
    action: np.ndarray
    infeasible: np.ndarray
    rho_pred: np.ndarray
    b: np.ndarray
    resolved: np.ndarray


def checked_rows(name: str, value: np.ndarray, shape: tuple[int, int], error: type[Exception]) -> np.ndarray:
    """value as a float array of `shape` (B, N) with finite rows, else `error` naming the shape or the non-finite rows."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise error(f"{name} must have shape {shape}, got {arr.shape}")
    bad = ~np.all(np.isfinite(arr), axis=1)
    if np.any(bad):
        raise error(f"{name} must be finite, got non-finite rows {np.flatnonzero(bad).tolist()}")
    return arr


def predicted_margin(safe_set: ForceSafeSet, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """ρ = min_i (n_max − n_i)/n_max at tips (x, y) (m, (B,) each), as `ForceSafeSet.margin_at` (same floats)."""
    n_max = safe_set.n_max
    normals, offsets = safe_set.environment.normals.tolist(), safe_set.environment.offsets.tolist()
    margins = [(n_max - np.maximum(nx * x + ny * y - d, 0.0)) / n_max for (nx, ny), d in zip(normals, offsets)]
    return np.min(margins, axis=0)


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Σ_j x[..., j] y[..., j], summed in the order j = 0, 1, … (for N = 2 the scalar solver's x_0 y_0 + x_1 y_1)."""
    out = x[..., 0] * y[..., 0]
    for j in range(1, x.shape[-1]):
        out = out + x[..., j] * y[..., j]
    return out


ENUMERATION_MAX_N = 4
"""The largest N whose QP states `cbf_qp_batch` solves by enumeration (module docstring: the
subsets grow as C(P + 2N, ≤ N)); QP states of larger N go to the fallback."""

SINGULAR_TOL = 1e-12
"""A subset whose unit rows span a parallelotope of volume below this (‖v_1‖⋯‖v_k‖; |det| of two rows for
N = 2) is skipped: its rows are nearly dependent (module docstring)."""


@functools.lru_cache(maxsize=64)
def subset_levels(m: int, n: int, box_start: int | None) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], ...]:
    """The subsets S of rows 0..m−1 with 1 ≤ |S| ≤ n, level by level (module docstring).

    Level k holds the subsets of size k in lexicographic order (`itertools.combinations`) as
    (prefixes, row, members): members (K, k) lists each subset's rows, row (K,) its last one, and
    prefixes (K, k − 1) the index in level i + 1 of its first i + 1 rows (i < k − 1), its prefix
    subsets. With box rows (rows box_start + j: +e_j, box_start + n + j: −e_j, j < n), subsets
    holding both ±e_j (parallel: no vertex) are left out.
    """
    levels, index = [], {(): 0}
    for size in range(1, n + 1):
        current = [subset + (row,) for subset in index if len(subset) == size - 1
                   for row in range(subset[-1] + 1 if subset else 0, m)
                   if box_start is None or row < box_start + n or row - n not in subset]  # not −e_j with +e_j
        if not current:
            break
        current.sort()
        index.update({subset: s for s, subset in enumerate(current)})
        prefixes = np.array([[index[subset[: i + 1]] for i in range(size - 1)] for subset in current], dtype=np.intp)
        members = np.array(current, dtype=np.intp)
        levels.append((prefixes.reshape(len(current), size - 1), members[:, -1].copy(), members))
    return tuple(levels)


def _pair_vertices(a: np.ndarray, b: np.ndarray, c_a: np.ndarray, c_b: np.ndarray) -> np.ndarray:
    """N = 2: the intersections of the lines a·u = c_a and b·u = c_b (rows (..., 2)) by Cramer's rule, NaN
    where |det| < SINGULAR_TOL (module docstring: the floats of the two-row vertex of before)."""
    det = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        vertex = np.stack(((c_a * b[..., 1] - c_b * a[..., 1]) / det, (a[..., 0] * c_b - b[..., 0] * c_a) / det), axis=-1)
    vertex[np.abs(det) < SINGULAR_TOL] = np.nan
    return vertex


def _nearest_feasible(u_nom: np.ndarray, rows: np.ndarray, rhs: np.ndarray, tol: np.ndarray,
                      box_start: int | None) -> tuple[np.ndarray, np.ndarray]:
    """argmin ‖u − u_nom‖² over {u | rows u ≤ rhs + tol} by enumeration (module docstring).

    u_nom (S, N); rows (S, m, N) unit or zero rows (rows box_start.. the box's ±e_j, or None);
    rhs (S, m); tol (S,). Returns (u (S, N), found (S,)); u is NaN where no candidate is feasible.
    """
    n = u_nom.shape[1]
    candidates = [u_nom[:, None, :]]
    basis: list[tuple[np.ndarray, np.ndarray]] = []  # per level: v (S, K, N) of its subsets' last rows, v·v
    volume = np.ones((len(u_nom), 1))  # per subset of the last level: ‖v_1‖⋯‖v_k‖
    u_parent = u_nom[:, None, :]
    levels = subset_levels(rows.shape[1], n, box_start)
    for size, (prefixes, new, members) in enumerate(levels, start=1):
        if size == n == 2:  # the square level of N = 2: Cramer's rule, the floats of before (module docstring)
            candidates.append(_pair_vertices(rows[:, members[:, 0]], rows[:, new], rhs[:, members[:, 0]], rhs[:, new]))
            break
        a, b = (rows, rhs) if size == 1 else (rows[:, new], rhs[:, new])  # (S, K, N), (S, K); level 1: every row
        v = a
        with np.errstate(divide="ignore", invalid="ignore"):
            for i in range(size - 1):  # modified Gram–Schmidt against the prefix's rows
                w, ww = basis[i][0][:, prefixes[:, i]], basis[i][1][:, prefixes[:, i]]
                v = v - (_dot(v, w) / ww)[..., None] * w
            u_p = u_parent[:, prefixes[:, -1]] if size > 1 else u_parent
            # For one row (v = a): t = (â·u − b̂)/‖â‖², u − t â, the scalar solver's first step, float for float.
            step = (_dot(a, u_p) - b) / _dot(a, v)
            u = u_p - step[..., None] * v
        candidates.append(u)
        if size == 1 and n == 2:
            u_parent = u  # (a unit row's volume is 1, a zero row's u is 0/0 = NaN; the next level is Cramer's)
            continue
        vv = _dot(v, v)
        volume = np.sqrt(vv) if size == 1 else volume[:, prefixes[:, -1]] * np.sqrt(vv)
        u[~(volume >= SINGULAR_TOL)] = np.nan
        basis.append((v, vv))
        u_parent = u
    cand = np.concatenate(candidates, axis=1)  # (S, C, N)
    with np.errstate(invalid="ignore"):
        violation = np.max(cand @ rows.transpose(0, 2, 1) - rhs[:, None, :], axis=2)  # (S, C): the largest row excess
        feasible = violation <= tol[:, None]
        distance = np.where(feasible, np.sum((cand - u_nom[:, None, :]) ** 2, axis=2), np.inf)
    best = np.argmin(distance, axis=1)
    found = np.isfinite(distance[np.arange(len(best)), best])
    u = cand[np.arange(len(best)), best]
    u[~found] = np.nan
    return u, found


def cbf_qp_batch(
    dynamics: BatchDynamics,
    safe_set: ForceSafeSet,
    tuning: Tuning,
    q: np.ndarray,
    qd: np.ndarray,
    u_nom: np.ndarray,
    u_min: np.ndarray | None = None,
    u_max: np.ndarray | None = None,
    fallback: Callable[[int], ScalarResult] | None = None,
    enumerate_up_to: int = ENUMERATION_MAX_N,
) -> CBFBatchResult:
    """`CBFFilter` at B states (module docstring).

    dynamics: the controller's model (one `RobotParams`); q, qd, u_nom: (B, N); u_min,
    u_max: (N,) hPa, or None for the paper's unbounded QP (`CBFFilter(pressure_limits=False)`).
    fallback(b): the scalar filter's result at state b, for the states this enumeration
    does not cover (recovery, infeasible); required only when such a state occurs.
    enumerate_up_to: the largest N whose QP states are enumerated (default ENUMERATION_MAX_N; a
    larger value times the enumeration beyond it, tools/bench_batch_filters.py).
    """
    n_seg = dynamics.n
    n_states = np.shape(q)[0] if np.ndim(q) == 2 else -1
    shape = (n_states, n_seg)
    q = checked_rows("q", q, shape, NonFiniteStateError)
    qd = checked_rows("qd", qd, shape, NonFiniteStateError)
    u_nom = checked_rows("u_nom", u_nom, shape, NonFiniteCommandError)
    bounded = u_min is not None
    if bounded != (u_max is not None):
        raise ValueError("u_min and u_max must both be given or both be None")
    terms = dynamics.terms(q, qd)
    tip, tip_vel, acc0, acc_u = terms.tip, terms.tip_vel, terms.tip_drift_acc, terms.tip_input_acc
    rho_pred = predicted_margin(safe_set, tip.real, tip.imag)
    rx, ry, vx, vy = tip.real, tip.imag, tip_vel.real, tip_vel.imag
    H, h = safe_set.H_prime.tolist(), safe_set.h_prime.tolist()
    ab, b_e, gamma = tuning.a_E * tuning.b_E, tuning.b_E, tuning.gamma
    b_rows, lgb_rows, c_rows, defined_rows = [], [], [], []
    with np.errstate(all="ignore"):  # rows with b ≤ B_MIN are masked out below
        for (hx, hy), h_i in zip(H, h):
            b = h_i - (hx * rx + hy * ry)
            bdot = -(hx * vx + hy * vy)
            den = 1.0 + b_e * bdot * bdot
            # math.log1p, not np.log1p (which differs by 1 ulp on ~1 % of arguments): B's rounding
            # reaches u through 1/‖L_gB‖ and a chattering closed loop amplifies it.
            inverse = np.where(b > B_MIN, 1.0 / b, 0.0).tolist()
            big_b = np.fromiter(map(math.log1p, inverse), float, len(inverse)) + ab * bdot * bdot / den
            db, dbdot = -1.0 / (b * (1.0 + b)), 2.0 * ab * bdot / (den * den)
            lfb = db * bdot - dbdot * (hx * acc0.real + hy * acc0.imag)
            lgb = -dbdot[:, None] * (hx * acc_u.real + hy * acc_u.imag)
            defined = b > B_MIN
            b_rows.append(b)
            defined_rows.append(defined)
            lgb_rows.append(np.where(defined[:, None], lgb, 0.0))
            c_rows.append(np.where(defined, gamma / big_b - lfb, 0.0))
    n = len(q)
    b_all = np.column_stack(b_rows) if b_rows else np.empty((n, 0))
    u = u_nom.copy()
    action = np.full(n, "nominal", dtype=object)
    infeasible = np.zeros(n, dtype=bool)
    resolved = np.ones(n, dtype=bool)
    lo = np.asarray(u_min, dtype=float) if bounded else None
    hi = np.asarray(u_max, dtype=float) if bounded else None
    if bounded:
        u_nom = np.clip(u_nom, lo, hi)  # saturated, as `CBFFilter` saturates it (module docstring)
        u = u_nom.copy()
    if tuning.disabled:
        action[:] = "disabled"
        return CBFBatchResult(u, action.astype(str), infeasible, rho_pred, b_all, resolved)

    A = np.stack(lgb_rows, axis=1) if lgb_rows else np.empty((n, 0, n_seg))  # (B, P, N)
    c = np.column_stack(c_rows) if c_rows else np.empty((n, 0))
    recovery = ~np.all(np.column_stack(defined_rows), axis=1) if defined_rows else np.zeros(n, dtype=bool)
    satisfied = np.all(_dot(A, u_nom[:, None, :]) <= c, axis=1)
    if bounded:
        satisfied &= np.all((lo <= u_nom) & (u_nom <= hi), axis=1)
    solve = ~satisfied & ~recovery
    resolved[recovery] = False
    if n_seg > enumerate_up_to:  # the enumeration's subsets outgrow the scalar filter: it solves these QPs
        resolved[solve] = False
        solve[:] = False
    if np.any(solve):
        idx = np.flatnonzero(solve)
        a, c_s, u0 = A[idx], c[idx], u_nom[idx]
        norm = np.sqrt(_dot(a, a))
        kept = norm > ZERO_ROW_TOL
        contradiction = np.any(~kept & (c_s < 0.0), axis=1)  # a zero row with c < 0: infeasible
        with np.errstate(divide="ignore", invalid="ignore"):
            rows = np.where(kept[..., None], a / norm[..., None], 0.0)
            rhs = np.where(kept, c_s / norm, 0.0)
        scale = 1.0 + np.max(np.abs(u0), axis=1)
        box_start = None
        if bounded:
            box_start = rows.shape[1]
            box = np.vstack((np.eye(n_seg), -np.eye(n_seg))) + 0.0  # rows +e_j, then −e_j (+ 0.0: no −0.0 entries)
            rows = np.concatenate((rows, np.broadcast_to(box, (len(idx), 2 * n_seg, n_seg))), axis=1)
            rhs = np.concatenate((rhs, np.broadcast_to(np.concatenate((hi, -lo)), (len(idx), 2 * n_seg))), axis=1)
            scale = np.maximum(scale, 1.0 + max(np.max(np.abs(lo)), np.max(np.abs(hi))))
        u_qp, found = _nearest_feasible(u0, rows, rhs, FEASIBILITY_RTOL * scale, box_start)
        found &= ~contradiction
        if bounded:
            u_qp = np.clip(u_qp, lo, hi)
        u[idx[found]] = u_qp[found]
        action[idx[found]] = "qp"
        resolved[idx[~found]] = False
    for i in np.flatnonzero(~resolved):
        if fallback is None:
            raise ValueError(f"state {i} needs the scalar filter (recovery or infeasible) but no fallback was given")
        result = fallback(int(i))
        u[i], action[i], infeasible[i] = np.asarray(result.u, dtype=float), result.action, bool(result.infeasible)
    return CBFBatchResult(u, action.astype(str), infeasible, rho_pred, b_all, resolved)


SCALAR_BELOW = 4
"""Batches smaller than this are filtered state by state with the scalar filter (measured
crossover on a 2-core machine: the vectorised filter's fixed cost ≈ 0.2–0.4 ms per call,
the scalar filter's ≈ 30–60 µs per state)."""
