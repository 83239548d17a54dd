"""The paper's CBF-QP filter (`controllers.cbf.paper_filter.CBFFilter`) for B states at once (docs/model.md#control-barrier-function, docs/beyond-the-paper.md#batched-ground-truth).

For B states x_b = [q_b; q̇_b] ((B, N) rad and rad/s each, any number of segments N) and
nominal commands u_nom (B, N) hPa, every state gets what `CBFFilter` computes:

    u*_b = argmin ‖u − u_nom,b‖²  s.t.  L_gB_i(x_b) u ≤ γ/B_i(x_b) − L_fB_i(x_b)   (rows i of P)
                                        u_min ≤ u ≤ u_max                        (when bounded)

with u_nom first saturated to [u_min, u_max] when bounded (as `CBFFilter` does).

The maths below runs compiled, one state per loop iteration (`controllers.cbf.kernels.paper_cbf`,
numba, loaded on the first call): this module checks the input, evaluates the model, packs the
arguments (`PaperCBFKernel`) and calls the scalar filter for the states the kernel hands back. The
filter's own calls at one state (`CBFFilter.__call__`, `CBFFilter.step`) run the same kernel at B = 1:
there is one implementation of this QP, and the scalar QP (`controllers.cbf.qp`) is only the fallback.

Barrier terms: b, ḃ, B, L_fB, L_gB per row (`controllers.cbf.kernels.barrier_rows`, their one
implementation, derived in `controllers.cbf.barrier`) from the tip terms of
`controllers.model.dynamics_batch.BatchDynamics`; the kernel returns them (`KernelOutput`), and the scalar
fallback solves its QP on these very rows, so both paths see the same floats (log1p is the C library's,
which the math module calls too; numpy's differs by 1 ulp on ~1 % of arguments, and B's rounding reaches
u through 1/‖L_gB‖, which a chattering closed loop amplifies). Branches, as `CBFFilter` takes them:
- "disabled" (tuning None): u = u_nom, clipped to the bounds when they are on;
- "nominal": u_nom within the bounds and a_i·u_nom ≤ c_i for every row, tested
  exactly as the scalar filter tests it (u = u_nom); a_i = L_gB_i, c_i = γ/B_i − L_fB_i, or the
  quasi-static row of a row outside P (below);
- "recovery" (with `recovery`, the filter's `RecoveryRows`): some row has b_i ≤ B_MIN (the state is
  outside P, B_i undefined); that row is replaced by `CBFFilter`'s quasi-static row
  (H'_i J_r K⁻¹Λ) u ≤ b_i − ε_i + H'_i J_r q (the rest shape inside P by ε_i, linearised about q),
  the other rows keep their CBF rows, and the QP below is solved with them, labelled "recovery"
  (and "nominal" when u_nom already meets every row, as `CBFFilter` labels it);
- "qp" (when the enumeration has at most ENUMERATION_MAX_CANDIDATES = 500 candidates, below;
  else these states go to `fallback`, the scalar filter's QP): the QP above, solved exactly by
  enumeration. The rows are scaled to unit norm
  as `controllers.cbf.qp` scales them (â_i = a_i/‖a_i‖, b̂_i = c_i/‖a_i‖; rows with ‖a_i‖ ≤
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
  this step: one solve for every N (the chain of projections stays within 1e-9 hPa of the scalar
  filter's active-set QP in the tests, N = 2, 3 and 4). A subset whose unit rows span a parallelotope of
  volume ‖v_1‖⋯‖v_k‖ (|det A_S| when square) below SINGULAR_TOL = 1e-12 is skipped (nearly dependent
  rows: parallel at k = 2), and so are subsets holding both ±e_j. Count: with the box,
  1 + Σ_{k≤N} C(P + 2N, k) less those pairs: 14, 46, 146 candidates for N = 2, 3, 4 and one
  facet row (27, 106, 384 with three rows); unbounded 1 + Σ_k C(P, k) (`candidate_table`: the
  kernel's list of them, each with its prefixes). Every candidate is
  tested for feasibility with the scalar solver's tolerance (`controllers.cbf.qp.tolerances`):
  FEASIBILITY_RTOL·(1 + max(|lb|, |ub|)) + ROUNDING_RTOL·max|u₀| (hPa on unit rows; without the box
  the first term is FEASIBILITY_RTOL: a tolerance growing as FEASIBILITY_RTOL·|u_nom| accepted
  commands violating a row by ~1 hPa at |u_nom| = 1e10 hPa, where the scalar QP's acceptance is
  1e-3 hPa), and the feasible candidate nearest u₀ wins (ties: the first in the order above).
  u_nom itself within that tolerance gives u = u_nom, as the scalar solver's shortcut does (the
  enumeration stops there: no candidate is nearer). The
  result is clipped to the bounds, as `CBFFilter` clips it. The kernel's cost grows with the
  candidates (each tested against m rows): per QP state, one facet, the box, HW-High, B = 256
  (tools/bench_batch_filters.py, which forces the enumeration with `max_candidates`; load 6), 0.5,
  2.2, 10.6, 46 and 171 µs of CPU for 14, 46, 146, 454 and 1394 candidates (N = 2 … 6) against the
  scalar filter's 68–102 µs: up to ENUMERATION_MAX_CANDIDATES candidates the enumeration is
  the cheaper (N ≤ 5 with one facet and the box, N ≤ 4 with three rows, any N without the box:
  1 + Σ_k C(P, k) candidates); beyond, those states go to the fallback.
- Not covered here, handed to `fallback(b)` per state b (the scalar filter): no candidate is
  feasible (the rows and bounds cannot all hold: "slack", the rest target or "vent"), a row is zero
  with c_i < 0, a row is not finite (overflowed terms, |q̇| ≳ 1e154 rad/s: "slack"), and, without
  `recovery`, every state outside P. These are rare in closed loop (the MuJoCo contact batch of
  tools/bench_batch.py: 14 "slack" states in 16 000, against 4006 "recovery" states, a quarter, which
  the fallback took before the recovery rows were covered here); `resolved` marks the states that
  did not need the fallback. Without a fallback such states raise.

Agreement with `CBFFilter` (tests/test_cbf_batch.py, thousands of random states for N = 2, 3
and 4, one facet and a corner, with and without the box, inside and outside P): the same action
label, and commands within 1e-9 hPa. The enumeration is exact to rounding;
the scalar dual active-set method stops once every row holds within the feasibility
tolerance, so both can differ by up to that tolerance (≈ 1.5e-7 hPa at ±150 hPa) when a
row's violation at an intermediate iterate lies below it; in tests this never happened.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable, NamedTuple, Protocol

import numpy as np

from controllers.cbf.barrier import B_MIN, Tuning
from controllers.model.dynamics_batch import BatchDynamics
from controllers.core.errors import NonFiniteCommandError, NonFiniteStateError
from controllers.core.lazy_import import lazy_module
from controllers.model.params import RobotParams
from controllers.cbf.qp import FEASIBILITY_RTOL, ROUNDING_RTOL, ZERO_ROW_TOL
from controllers.model.safe_set import ForceSafeSet

cbf_kernels = lazy_module("controllers.cbf.kernels")  # numba loads on the first call (controllers.core.lazy_import)


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
    finite = np.isfinite(arr)
    if not finite.all():
        bad = ~finite.all(axis=1)
        raise error(f"{name} must be finite, got non-finite rows {np.flatnonzero(bad).tolist()}")
    return arr


def predicted_margin(safe_set: ForceSafeSet, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """ρ = min_i (n_max − n_i)/n_max at tips (x, y) (m, (B,) each), as `ForceSafeSet.margin_at` (same floats;
    compiled: `controllers.cbf.kernels.predicted_margins`)."""
    environment = safe_set.environment
    x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
    rho = np.empty(x.shape)
    cbf_kernels.predicted_margins(x, y, np.asarray(environment.normals, dtype=float),
                                  np.asarray(environment.offsets, dtype=float), float(safe_set.n_max), rho)
    return rho


ENUMERATION_MAX_CANDIDATES = 500
"""The most candidates (`candidate_table`) for which `cbf_qp_batch` solves QP states by enumeration
(module docstring: measured, 454 candidates cost 46 µs a state against the scalar QP's 101 µs, 1394
cost 171 µs against 102 µs); with more, the QP states go to the fallback."""

SINGULAR_TOL = 1e-12
"""A subset whose unit rows span a parallelotope of volume below this (‖v_1‖⋯‖v_k‖, |det A_S| when square) is
skipped: its rows are nearly dependent (module docstring)."""


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


def candidate_count(m: int, n: int, box_start: int | None) -> int:
    """len(candidate_table(m, n, box_start)) without building it: 1 (u_nom) + the subsets of 1..n of the m rows,
    less those holding both ±e_j. With the box (P = box_start rows of P, then n pairs ±e_j, each subset taking at
    most one of a pair), Σ_k Σ_i C(P, i) C(n, k − i) 2^(k − i); without it Σ_k C(m, k)."""
    if box_start is None:
        return 1 + sum(math.comb(m, k) for k in range(1, n + 1))
    return 1 + sum(math.comb(box_start, i) * math.comb(n, k - i) * 2 ** (k - i)
                   for k in range(1, n + 1) for i in range(0, k + 1))


@functools.lru_cache(maxsize=64)
def candidate_table(m: int, n: int, box_start: int | None) -> np.ndarray:
    """The candidates of `subset_levels(m, n, box_start)` as the kernel's table (C, n + 1) int: row 0 stands
    for u_nom; row g ≥ 1 (level by level, each in lexicographic order) holds the subset's size k, its last
    row, then the global indices (rows of this table) of its prefixes of sizes 1..k − 1."""
    levels = subset_levels(m, n, box_start)
    table = np.zeros((1 + sum(len(new) for _, new, _ in levels), n + 1), dtype=np.int64)
    start = [1]
    for size, (prefixes, new, _) in enumerate(levels, start=1):
        rows = slice(start[-1], start[-1] + len(new))
        table[rows, 0], table[rows, 1] = size, new
        for i in range(size - 1):
            table[rows, 2 + i] = start[i] + prefixes[:, i]
        start.append(rows.stop)
    table.setflags(write=False)
    return table


class RecoveryRows(NamedTuple):
    """The quasi-static rows of `CBFFilter` ("recovery", module docstring): static_gain (N,) rad/hPa, K⁻¹Λ;
    margins (P,) m, ε_i = recovery_margin·‖H'_i‖, the rest shape's margin inside row i of P."""

    static_gain: tuple[float, ...]
    margins: tuple[float, ...]

    @classmethod
    def of(cls, params: RobotParams, safe_set: ForceSafeSet, recovery_margin: float) -> "RecoveryRows":
        """The rows of a filter for `params` and `safe_set` whose rest shapes keep `recovery_margin` m inside P."""
        rows = np.asarray(safe_set.H_prime, dtype=float)
        return cls(tuple((params.array("gains") / params.array("stiffness")).tolist()),
                   tuple((recovery_margin * np.hypot(rows[:, 0], rows[:, 1])).tolist()))


CODE_LABELS = np.array(["disabled", "nominal", "qp", "recovery", "fallback"])
"""The action label of each of the kernel's codes (`controllers.cbf.kernels`: DISABLED … FALLBACK)."""


class KernelOutput(NamedTuple):
    """`PaperCBFKernel.run`'s per-state results: u (B, N) hPa, code (B,) int8 (`controllers.cbf.kernels`' codes),
    b, B, constraint (B, P) (row-scaled m, 1, 1/s: the filter's diagnostics) and active (B, P) bool; the rows the
    scalar fallback reads: LfB (B, P) 1/s, LgB (B, P, N) 1/(s·hPa) (0 where b ≤ B_MIN), and per row of P its
    quasi-static row static_a (B, P, N) row-scaled m/hPa and static_c (B, P) row-scaled m (`RecoveryRows`; meaningful
    only with them)."""

    u: np.ndarray
    code: np.ndarray
    b: np.ndarray
    B: np.ndarray
    constraint: np.ndarray
    active: np.ndarray
    LfB: np.ndarray
    LgB: np.ndarray
    static_a: np.ndarray
    static_c: np.ndarray


class PaperCBFKernel:
    """The compiled paper CBF (`controllers.cbf.kernels.paper_cbf`) for one filter: the arguments that do not
    change between calls (the force-safe set's rows, the tuning, the pressure box, the recovery rows, the
    candidate table) packed once, so that a call passes only the states.

    n: the number of segments N; u_min, u_max: (N,) hPa or None (unbounded); recovery: the filter's quasi-static
    rows or None (states outside P are then FALLBACK); max_candidates: as `cbf_qp_batch`'s.
    """

    def __init__(self, n: int, safe_set: ForceSafeSet, tuning: Tuning, u_min: np.ndarray | None = None,
                 u_max: np.ndarray | None = None, recovery: RecoveryRows | None = None,
                 max_candidates: int = ENUMERATION_MAX_CANDIDATES) -> None:
        bounded = u_min is not None
        if bounded != (u_max is not None):
            raise ValueError("u_min and u_max must both be given or both be None")
        n_rows = len(safe_set.h_prime)
        self.facets = np.zeros((n_rows, 4))
        self.facets[:, :2], self.facets[:, 2] = safe_set.H_prime, safe_set.h_prime
        self.static_gain = np.zeros(n)
        if recovery is not None:
            self.static_gain = np.asarray(recovery.static_gain, dtype=float).reshape(n)
            self.facets[:, 3] = np.asarray(recovery.margins, dtype=float).reshape(n_rows)
        self.limits = np.zeros((2, n))
        if bounded:
            self.limits[0], self.limits[1] = u_min, u_max
        shape = (n_rows + 2 * n if bounded else n_rows, n, n_rows if bounded else None)
        # beyond max_candidates the enumeration costs more than the scalar QP, and the table is not built (it grows
        # as C(P + 2N, ≤ N): at N = 12, millions of subsets); the kernel never reads it then
        self.enumerate_qp = candidate_count(*shape) <= max_candidates
        self.table = candidate_table(*shape) if self.enumerate_qp else np.zeros((1, n + 1), dtype=np.int64)
        self.tuning, self.bounded, self.recover = tuning, bounded, recovery is not None
        self._ab = tuning.a_E * tuning.b_E  # as the scalar filter computes it
        self.n, self.rows = n, n_rows

    def outputs(self, count: int) -> KernelOutput:
        """Empty result arrays for `count` states."""
        rows = (count, self.rows)
        return KernelOutput(np.empty((count, self.n)), np.empty(count, dtype=np.int8), np.empty(rows), np.empty(rows),
                            np.empty(rows), np.empty(rows, dtype=np.bool_), np.empty(rows),
                            np.empty((*rows, self.n)), np.empty((*rows, self.n)), np.empty(rows))

    def run(self, kin: np.ndarray, tip_col: int, jac_col: int, q: np.ndarray, u_nom: np.ndarray,
            out: KernelOutput | None = None) -> KernelOutput:
        """The kernel at B states: kin (B, ·) complex `controllers.model.pcc_model` rows at (q, q̇), tip_col and jac_col
        their columns of r and J_r (`pcc_model.ModelLayout`), q and u_nom (B, N) finite (unchecked); out: result
        arrays to overwrite (`outputs(B)`; a caller at one state keeps one set), else new ones."""
        out = self.outputs(len(q)) if out is None else out
        cbf_kernels.paper_cbf(kin, tip_col, jac_col, q, u_nom, self.facets, self._ab, self.tuning.b_E,
                              self.tuning.gamma, self.static_gain, self.limits, self.table, self.tuning.disabled,
                              self.bounded, self.recover, self.enumerate_qp, B_MIN, FEASIBILITY_RTOL, ROUNDING_RTOL,
                              ZERO_ROW_TOL, SINGULAR_TOL, *out)
        return out


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
    max_candidates: int = ENUMERATION_MAX_CANDIDATES,
    recovery: RecoveryRows | None = None,
    kernel: PaperCBFKernel | None = None,
) -> CBFBatchResult:
    """`CBFFilter` at B states (module docstring).

    dynamics: the controller's model (one `RobotParams`); q, qd, u_nom: (B, N); u_min,
    u_max: (N,) hPa, or None for the paper's unbounded QP (`CBFFilter(pressure_limits=False)`).
    fallback(b): the scalar filter's result at state b, for the states this enumeration
    does not cover (infeasible, and recovery without `recovery`); required only when such a state occurs.
    max_candidates: the most candidates for which QP states are enumerated (default
    ENUMERATION_MAX_CANDIDATES; a larger value times the enumeration beyond it, tools/bench_batch_filters.py).
    recovery: the filter's quasi-static rows (`RecoveryRows`): states with a row b ≤ B_MIN are solved here
    with them, as `CBFFilter` solves them; None: those states go to the fallback.
    kernel: the packed arguments (`PaperCBFKernel`) of these safe_set, tuning, bounds, recovery and max_candidates,
    kept by a caller that calls often (built here when None).
    """
    n_seg = dynamics.n
    n_states = np.shape(q)[0] if np.ndim(q) == 2 else -1
    shape = (n_states, n_seg)
    q = checked_rows("q", q, shape, NonFiniteStateError)
    qd = checked_rows("qd", qd, shape, NonFiniteStateError)
    u_nom = checked_rows("u_nom", u_nom, shape, NonFiniteCommandError)
    if kernel is None:
        kernel = PaperCBFKernel(n_seg, safe_set, tuning, u_min, u_max, recovery, max_candidates)
    terms = dynamics.terms(q, qd)
    tip = terms.tip
    rho_pred = predicted_margin(safe_set, tip.real, tip.imag)
    out = kernel.run(terms.kin, terms.layout.tip_terms.start, terms.layout.tip_jac.start, q, u_nom)
    u, code = out.u, out.code
    action = CODE_LABELS[code]
    infeasible = np.zeros(len(q), dtype=bool)
    resolved = code != cbf_kernels.FALLBACK
    if not resolved.all():
        unresolved = np.flatnonzero(~resolved)
        if fallback is None:
            raise ValueError(f"state {unresolved[0]} needs the scalar filter (recovery or infeasible) but no fallback "
                             "was given")
        action = action.astype(object)
        for i in unresolved:
            result = fallback(int(i))
            u[i], action[i], infeasible[i] = np.asarray(result.u, dtype=float), result.action, bool(result.infeasible)
        action = action.astype(str)
    return CBFBatchResult(u, action, infeasible, rho_pred, out.b, resolved)


SCALAR_BELOW = 4
"""Batches smaller than this are filtered state by state (`CBFFilter.__call__`, the kernel at B = 1: it reuses
the model terms a plant sharing the filter's `PCCDynamics` has evaluated, and skips the batch's input checks and
margins; measured crossover on a 2-core machine: the batch call's fixed cost ≈ 0.2–0.4 ms)."""
