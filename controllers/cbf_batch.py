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
- "qp" (N = 2; for N ≠ 2 these states go to `fallback`, the scalar filter's QP): the QP
  above, solved exactly by enumeration, which N = 2 makes cheap. With the
  rows scaled to unit norm as `controllers.qp` scales them (â_i = a_i/‖a_i‖,
  b̂_i = c_i/‖a_i‖; rows with ‖a_i‖ ≤ ZERO_ROW_TOL dropped when c_i ≥ 0) and the box as
  ±e_j rows, the minimiser of a strictly convex quadratic over a polygon is u_nom, or
  the projection of u_nom onto one row's line, or the intersection of two rows' lines
  (at most N = 2 rows are active at a non-degenerate vertex; at a degenerate vertex
  any two independent active rows give the same point). Every candidate is tested for
  feasibility with the scalar solver's tolerance FEASIBILITY_RTOL·(1 + max(|u_nom|, |lb|,
  |ub|)), and the feasible candidate nearest u_nom is the optimum: the optimum is a
  feasible candidate, and no feasible point is nearer. (Equivalently the KKT point:
  its multipliers are ≥ 0; the nearest-feasible test needs no multipliers.) u_nom
  itself within that tolerance gives u = u_nom, as the scalar solver's shortcut does.
  The result is clipped to the bounds, as `CBFFilter` clips it.
- Not covered here, handed to `fallback(b)` per state b (the scalar filter): some row
  has b_i ≤ B_MIN ("recovery", the quasi-static rows), or no candidate is feasible
  (the rows and bounds cannot all hold: "slack" / "vent"), or a row is zero with
  c_i < 0. These are rare in closed loop; `resolved` marks the states that did not
  need the fallback. Without a fallback such states raise.

Agreement with `CBFFilter` (tests/test_cbf_batch.py, thousands of random states): the
same action label, and commands within 1e-9 hPa. The enumeration is exact to rounding;
the scalar dual active-set method stops once every row holds within the feasibility
tolerance, so both can differ by up to that tolerance (≈ 1.5e-7 hPa at ±150 hPa) when a
row's violation at an intermediate iterate lies below it; in tests this never happened.
"""

from __future__ import annotations

import itertools
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


def _check(name: str, value: np.ndarray, shape: tuple[int, int], error: type[Exception]) -> np.ndarray:
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


def _row_products(a: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Σ_j a[s, i, j] u[s, j]: (S, P), summed in the order j = 0, 1, … (for N = 2 the scalar
    filter's a_0 u_0 + a_1 u_1)."""
    out = a[:, :, 0] * u[:, None, 0]
    for j in range(1, u.shape[1]):
        out = out + a[:, :, j] * u[:, None, j]
    return out


def _nearest_feasible(u_nom: np.ndarray, rows: np.ndarray, rhs: np.ndarray, tol: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """argmin ‖u − u_nom‖² over {u | rows u ≤ rhs + tol} by enumeration (module docstring).

    u_nom (S, 2); rows (S, m, 2) unit or zero rows; rhs (S, m); tol (S,). Returns (u (S, 2),
    found (S,)); u is NaN where no candidate is feasible.
    """
    m = rows.shape[1]
    r0, r1 = rows[..., 0], rows[..., 1]
    # Projections onto each row's line, in the operations of the scalar solver's first step
    # (t = (â·u − b̂)/‖â‖², u − t â), so that a one-row solution is the scalar filter's float for float.
    with np.errstate(divide="ignore", invalid="ignore"):
        step = ((r0 * u_nom[:, None, 0] + r1 * u_nom[:, None, 1]) - rhs) / (r0 * r0 + r1 * r1)
    singles = u_nom[:, None, :] - step[:, :, None] * rows
    pairs = list(itertools.combinations(range(m), 2))
    candidates = [u_nom[:, None, :], singles]
    if pairs:
        i, j = np.array(pairs).T
        a, b = rows[:, i], rows[:, j]  # (S, K, 2)
        det = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        ci, cj = rhs[:, i], rhs[:, j]
        with np.errstate(divide="ignore", invalid="ignore"):
            vertex = np.stack(((ci * b[..., 1] - cj * a[..., 1]) / det, (a[..., 0] * cj - b[..., 0] * ci) / det), axis=-1)
        vertex[np.abs(det) < 1e-12] = np.nan  # (nearly) parallel rows: no vertex
        candidates.append(vertex)
    cand = np.concatenate(candidates, axis=1)  # (S, K, 2)
    with np.errstate(invalid="ignore"):
        violation = np.max(np.einsum("smk,sck->scm", rows, cand) - rhs[:, None, :], axis=2)
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
) -> CBFBatchResult:
    """`CBFFilter` at B states (module docstring).

    dynamics: the controller's model (one `RobotParams`); q, qd, u_nom: (B, N); u_min,
    u_max: (N,) hPa, or None for the paper's unbounded QP (`CBFFilter(pressure_limits=False)`).
    fallback(b): the scalar filter's result at state b, for the states this enumeration
    does not cover (recovery, infeasible); required only when such a state occurs.
    """
    n_seg = dynamics.n
    n_states = np.shape(q)[0] if np.ndim(q) == 2 else -1
    shape = (n_states, n_seg)
    q = _check("q", q, shape, NonFiniteStateError)
    qd = _check("qd", qd, shape, NonFiniteStateError)
    u_nom = _check("u_nom", u_nom, shape, NonFiniteCommandError)
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
    satisfied = np.all(_row_products(A, u_nom) <= c, axis=1)
    if bounded:
        satisfied &= np.all((lo <= u_nom) & (u_nom <= hi), axis=1)
    solve = ~satisfied & ~recovery
    resolved[recovery] = False
    if n_seg != 2:  # the enumeration below is written for two commands: the scalar filter solves these QPs
        resolved[solve] = False
        solve[:] = False
    if np.any(solve):
        idx = np.flatnonzero(solve)
        a, c_s, u0 = A[idx], c[idx], u_nom[idx]
        norm = np.sqrt(a[..., 0] * a[..., 0] + a[..., 1] * a[..., 1])
        kept = norm > ZERO_ROW_TOL
        contradiction = np.any(~kept & (c_s < 0.0), axis=1)  # a zero row with c < 0: infeasible
        with np.errstate(divide="ignore", invalid="ignore"):
            rows = np.where(kept[..., None], a / norm[..., None], 0.0)
            rhs = np.where(kept, c_s / norm, 0.0)
        scale = 1.0 + np.max(np.abs(u0), axis=1)
        if bounded:
            box = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
            rows = np.concatenate((rows, np.broadcast_to(box, (len(idx), 4, 2))), axis=1)
            rhs = np.concatenate((rhs, np.broadcast_to(np.concatenate((hi, -lo)), (len(idx), 4))), axis=1)
            scale = np.maximum(scale, 1.0 + max(np.max(np.abs(lo)), np.max(np.abs(hi))))
        u_qp, found = _nearest_feasible(u0, rows, rhs, FEASIBILITY_RTOL * scale)
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
