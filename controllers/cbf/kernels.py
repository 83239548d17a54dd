"""The batched paper CBF's per-state arithmetic, compiled: barrier rows and the enumeration QP (controllers.cbf.batch).

One numba kernel, `paper_cbf`, runs `controllers.cbf.batch.cbf_qp_batch`'s maths for B states, one
state per loop iteration; the derivation (the QP, its candidates, the tolerances, the order of the
operations) is cbf_batch's module docstring, this module only its compiled form. Compiled like
`controllers.model.pcc_model`: `@njit(cache=True)` (compiled once per machine into __pycache__), no
fastmath (IEEE operations in the written order: a row's floats do not depend on the other rows nor on
B), error_model="numpy" (x/0 gives ±inf/NaN, never raises). Loaded on the first call through
`controllers.core.lazy_import`: `softcbf list` imports no numba.

Why compiled: in numpy a QP state cost ≈ 3.2 µs at N = 2, B = 256 (the enumeration's (S, C, N)
arrays and a dozen numpy calls per level), and the states the numpy path left to the scalar filter,
the quasi-static "recovery" rows, ≈ 35 µs each (tools/bench_batch_filters.py against the numpy version;
a quarter of the states of the MuJoCo contact batch of tools/bench_batch.py); one compiled loop does
either in well under a microsecond a state at N = 2 (0.3–0.6 µs, the same tool).

Arguments (shapes: B states, N inputs, P rows of P, m = P (+ 2N with the box) QP rows, C candidates):
- kin (B, ·) complex: `controllers.model.pcc_model` rows at the states; tip_col: the column of r (then ṙ,
  r̈ at u = 0, ∂r̈/∂u_1..N), jac_col: the first column of J_r (N columns);
- q (B, N) rad; u_nom (B, N) hPa (finite, checked by the caller);
- facets (P, 4): H'_i (x, y), h'_i, ε_i (the recovery margin of row i, m·‖H'_i‖);
- ab = a_E·b_E, b_e = b_E, gamma: the tuning (ab computed by the caller as the scalar filter does);
- static_gain (N,) rad/hPa: K⁻¹Λ of the recovery rows (cbf_batch: `recovery`), used only if `recover`;
- limits (2, N) hPa: (u_min, u_max), used only if `bounded`;
- table (C, N + 1) int: the candidates (`cbf_batch.candidate_table`): per candidate g ≥ 1 its size k,
  its last row and the global indices of its prefixes of sizes 1..k−1; row 0 stands for u_nom;
- flags: disabled (tuning None), bounded, recover (recovery rows computed here), enumerate (N within
  the enumeration's reach); tolerances: b_min (B_MIN), feasibility_rtol and rounding_rtol (`controllers.cbf.qp`'s),
  zero_row_tol, singular_tol.
Outputs, written per state: u (B, N) hPa, code (B,) int8 (DISABLED, NOMINAL, QP, RECOVERY, or
FALLBACK: the scalar filter decides), b (B, P) (the barrier per row), and the filter's diagnostics:
B (B, P) (+inf where b ≤ B_MIN), the constraint L_fB + L_gB u − γ/B at the command (B, P) (+inf there), and
active (B, P) bool (the barrier rows of the chosen candidate's subset); then the rows the scalar fallback reads
(`controllers.cbf.paper_filter.CBFFilter`): L_fB (B, P) and L_gB (B, P, N) (0 where b ≤ B_MIN), and every row's quasi-static
row (B, P, N) and its right-hand side (B, P) (meaningful only with `recover`).

The barrier rows (b, ḃ, B, L_fB, L_gB) have one implementation, `barrier_rows`: the kernel calls it per state,
`controllers.cbf.barrier.barrier_terms` at one state from Python.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

DISABLED, NOMINAL, QP, RECOVERY, FALLBACK = 0, 1, 2, 3, 4
"""The kernel's per-state codes: the action labels `cbf_batch.CODE_LABELS` (FALLBACK: the scalar filter's)."""


@njit(cache=True, error_model="numpy", inline="always")
def _dot(a, ra, b, rb, n):
    """Σ_j a[ra, j] b[rb, j], summed in the order j = 0, 1, … (the scalar solver's x_0 y_0 + x_1 y_1 + …)."""
    out = a[ra, 0] * b[rb, 0]
    for j in range(1, n):
        out += a[ra, j] * b[rb, j]
    return out


@njit(cache=True, error_model="numpy")
def paper_cbf(kin, tip_col, jac_col, q, u_nom, facets, ab, b_e, gamma, static_gain, limits, table, disabled, bounded,
              recover, enumerate_qp, b_min, feasibility_rtol, rounding_rtol, zero_row_tol, singular_tol, u, code, b_out,
              big_b_out, constraint_out, active_out, lfb_out, lgb_out, static_rows_out, static_rhs_out) -> None:
    """The batched paper CBF (module docstring), per state: the saturated u_nom and the barrier rows; then the
    state's code: DISABLED, FALLBACK (unevaluable rows, recovery without its rows, beyond the enumeration's reach,
    contradicting rows, or no feasible candidate), NOMINAL (u_nom satisfies every row), else QP or RECOVERY with
    the enumeration's nearest feasible candidate (rows scaled to unit norm first, as controllers.cbf.qp.solve_lists);
    then the state's diagnostics at its command (`_diagnostics`)."""
    n_states, n = u_nom.shape
    p = facets.shape[0]
    m = p + 2 * n if bounded else p
    n_cand = table.shape[0]
    rows = np.empty((m, n))  # the QP's rows (unit after scaling; the box rows ±e_j)
    rhs = np.empty(m)
    bdot, d_b, d_bdot = np.empty(p), np.empty(p), np.empty(p)  # ḃ, ∂B/∂b, ∂B/∂ḃ (`barrier_rows`; not returned)
    zero = np.zeros(m, dtype=np.bool_)  # a zero row (dropped: every candidate holding it is skipped)
    cand = np.empty((n_cand, n))  # per candidate: u_S
    basis = np.empty((n_cand, n))  # per candidate: v, its last row orthogonalised against its prefix's rows
    basis_sq = np.empty(n_cand)  # v·v
    volume = np.empty(n_cand)  # ‖v_1‖⋯‖v_k‖
    valid = np.empty(n_cand, dtype=np.bool_)
    u0 = np.empty((1, n))
    box_scale = _box_rows(limits, p, rows, rhs) if bounded else 0.0
    for s in range(n_states):
        _saturated_nominal(u_nom, limits, bounded, s, u0, u)
        recovery, unevaluable = _qp_rows(kin, tip_col, jac_col, q, facets, ab, b_e, gamma, static_gain, b_min, s, rows,
                                         rhs, b_out[s], bdot, big_b_out[s], lfb_out[s], lgb_out[s], d_b, d_bdot,
                                         static_rows_out[s], static_rhs_out[s])
        best = -1
        if disabled:
            code[s] = DISABLED
        elif unevaluable or (recovery and not recover):
            code[s] = FALLBACK
        elif _meets_rows(rows, rhs, u0, p, n):
            code[s] = NOMINAL
        elif not enumerate_qp or _unit_rows(rows, rhs, zero, p, n, zero_row_tol):
            code[s] = FALLBACK
        else:
            tol = _feasibility_tolerance(u0, box_scale, feasibility_rtol, rounding_rtol, n)
            best = _nearest_candidate(table, rows, rhs, zero, u0, tol, singular_tol, m, n, cand, basis, basis_sq,
                                      volume, valid)
            if best < 0:
                code[s] = FALLBACK
            else:
                for j in range(n):
                    v = cand[best, j]
                    if bounded:
                        v = min(max(v, limits[0, j]), limits[1, j])
                    u[s, j] = v
                code[s] = RECOVERY if recovery else QP
        _diagnostics(table, best, s, p, n, gamma, b_min, b_out, big_b_out, lgb_out[s], lfb_out[s], u, constraint_out,
                     active_out)


@njit(cache=True, error_model="numpy", inline="always")
def _meets_rows(rows, rhs, u0, p, n):
    """Whether u0 meets every barrier (or quasi-static) row a_i·u0 ≤ c_i as written (the "nominal" test)."""
    for i in range(p):
        if not _dot(rows, i, u0, 0, n) <= rhs[i]:
            return False
    return True


@njit(cache=True, error_model="numpy", inline="always")
def _diagnostics(table, best, s, p, n, gamma, b_min, b_out, big_b_out, lgb, lfb, u, constraint_out, active_out):
    """State s's constraint L_fB + L_gB u − γ/B per row at its command u[s] (+inf where b ≤ b_min), and the
    barrier rows among the chosen candidate's subset (`best`, −1: none) as active."""
    for i in range(p):
        active_out[s, i] = False
        if b_out[s, i] > b_min:
            total = lgb[i, 0] * u[s, 0]
            for j in range(1, n):
                total += lgb[i, j] * u[s, j]
            constraint_out[s, i] = lfb[i] + total - gamma / big_b_out[s, i]
        else:
            constraint_out[s, i] = math.inf
    if best > 0:
        size = table[best, 0]
        for k in range(size):  # its prefixes' last rows, then its own
            row = table[best, 1] if k == size - 1 else table[table[best, 2 + k], 1]
            if row < p:
                active_out[s, row] = True


@njit(cache=True, error_model="numpy", inline="always")
def _box_rows(limits, p, rows, rhs):
    """Write the box rows ±e_j ≤ ±(u_max, −u_min) after the P barrier rows; return max_j max(|u_min|, |u_max|)."""
    n = limits.shape[1]
    box_scale = 0.0
    for j in range(n):
        rhs_hi, rhs_lo = limits[1, j], limits[0, j]
        box_scale = max(box_scale, max(abs(rhs_lo), abs(rhs_hi)))
        for k in range(n):
            rows[p + j, k] = 1.0 if k == j else 0.0
            rows[p + n + j, k] = -1.0 if k == j else 0.0
        rhs[p + j] = rhs_hi
        rhs[p + n + j] = -rhs_lo
    return box_scale


@njit(cache=True, error_model="numpy", inline="always")
def _saturated_nominal(u_nom, limits, bounded, s, u0, u) -> None:
    """u_nom of state s saturated to the box (Python's min and max, as CBFFilter._clip) into u0[0] and u[s]."""
    for j in range(u_nom.shape[1]):
        v = u_nom[s, j]
        if bounded:
            v = min(max(v, limits[0, j]), limits[1, j])
        u0[0, j] = v
        u[s, j] = v


@njit(cache=True, error_model="numpy", inline="always")
def barrier_rows(tip, facets, ab, b_e, b_min, b, bdot, big_b, lfb, lgb, d_b, d_bdot) -> None:
    """The barrier rows of every row i of P at one state: the one implementation of `controllers.cbf.barrier`'s terms
    (its module docstring), which the kernel calls per state and `controllers.cbf.barrier.barrier_terms` at one state.

    tip (N + 3,) complex: r, ṙ, r̈ at u = 0, ∂r̈/∂u_1..N (`controllers.model.pcc_model`'s tip terms); facets (P, ≥ 3):
    H'_i (x, y), h'_i; ab = a_E·b_E, b_e = b_E. Written per row: b, ḃ (P,) (row-scaled m, m/s), and where
    b_i > b_min the barrier B_i, L_fB_i (1/s), L_gB_i (row i of lgb (P, N), 1/(s·hPa)), ∂B/∂b and ∂B/∂ḃ; rows
    with b_i ≤ b_min get B = +inf and L_fB = L_gB = ∂B/∂b = ∂B/∂ḃ = 0."""
    n = lgb.shape[1]
    r, r_dot, r_acc0 = tip[0], tip[1], tip[2]
    for i in range(facets.shape[0]):
        hx, hy, h_i = facets[i, 0], facets[i, 1], facets[i, 2]
        b_i = h_i - (hx * r.real + hy * r.imag)
        bdot_i = -(hx * r_dot.real + hy * r_dot.imag)
        b[i], bdot[i] = b_i, bdot_i
        if b_i > b_min:
            den = 1.0 + b_e * bdot_i * bdot_i
            big_b[i] = math.log1p(1.0 / b_i) + ab * bdot_i * bdot_i / den
            db, dbdot = -1.0 / (b_i * (1.0 + b_i)), 2.0 * ab * bdot_i / (den * den)
            d_b[i], d_bdot[i] = db, dbdot
            lfb[i] = db * bdot_i - dbdot * (hx * r_acc0.real + hy * r_acc0.imag)
            for j in range(n):
                a = tip[3 + j]
                lgb[i, j] = -dbdot * (hx * a.real + hy * a.imag)
        else:
            big_b[i], lfb[i], d_b[i], d_bdot[i] = math.inf, 0.0, 0.0, 0.0
            for j in range(n):
                lgb[i, j] = 0.0


@njit(cache=True, error_model="numpy", inline="always")
def _qp_rows(kin, tip_col, jac_col, q, facets, ab, b_e, gamma, static_gain, b_min, s, rows, rhs, b, bdot, big_b, lfb,
             lgb, d_b, d_bdot, static_rows, static_rhs):
    """State s's barrier rows (`barrier_rows`, into b, ḃ, B, L_fB, L_gB), the quasi-static row of every row of P
    (CBFFilter's "recovery": (H'_i J_r K⁻¹Λ) u ≤ b_i − ε_i + H'_i J_r q, into static_rows (P, N) and static_rhs (P,)),
    and the QP's rows a_i·u ≤ c_i: a_i = L_gB_i, c_i = γ/B_i − L_fB_i, or the quasi-static row where b_i ≤ B_MIN;
    return (recovery: a quasi-static row was taken, unevaluable: a CBF row is not finite)."""
    n = q.shape[1]
    barrier_rows(kin[s, tip_col:tip_col + 3 + n], facets, ab, b_e, b_min, b, bdot, big_b, lfb, lgb, d_b, d_bdot)
    recovery, unevaluable = False, False
    for i in range(facets.shape[0]):
        hx, hy = facets[i, 0], facets[i, 1]
        offset = 0.0
        for j in range(n):
            jac = kin[s, jac_col + j]
            hj = hx * jac.real + hy * jac.imag
            static_rows[i, j] = hj * static_gain[j]
            offset += hj * q[s, j]
        static_rhs[i] = b[i] - facets[i, 3] + offset
        if b[i] > b_min:
            total = 0.0
            for j in range(n):
                rows[i, j] = lgb[i, j]
                total += rows[i, j]
            rhs[i] = gamma / big_b[i] - lfb[i]
            if not math.isfinite(rhs[i] + total):
                unevaluable = True
        else:
            recovery = True
            for j in range(n):
                rows[i, j] = static_rows[i, j]
            rhs[i] = static_rhs[i]
    return recovery, unevaluable


@njit(cache=True, error_model="numpy", inline="always")
def _unit_rows(rows, rhs, zero, p, n, zero_row_tol):
    """Scale the P barrier rows to unit norm, zeroing (and marking in `zero`) the zero rows; return whether the
    rows contradict themselves (a zero row with rhs < 0, or an overflowed row: the scalar filter's "slack")."""
    contradiction = False
    for i in range(p):
        norm = math.sqrt(_dot(rows, i, rows, i, n))
        if not math.isfinite(norm + rhs[i]):
            contradiction = True  # an overflowed row: the scalar filter's "slack"
        zero[i] = not norm > zero_row_tol
        if zero[i]:
            if rhs[i] < 0.0:
                contradiction = True
            for j in range(n):
                rows[i, j] = 0.0
            rhs[i] = 0.0
        else:
            for j in range(n):
                rows[i, j] = rows[i, j] / norm
            rhs[i] = rhs[i] / norm
    return contradiction


@njit(cache=True, error_model="numpy", inline="always")
def _feasibility_tolerance(u0, box_scale, feasibility_rtol, rounding_rtol, n):
    """The scalar solver's feasibility tolerance (`controllers.cbf.qp.tolerances`, in its operation order): feasibility_rtol
    · (1 + the box's largest bound, 0 unbounded) + rounding_rtol · max_j |u0_j| (hPa on unit rows)."""
    largest = 0.0
    for j in range(n):
        largest = max(largest, abs(u0[0, j]))
    return feasibility_rtol * (1.0 + box_scale) + rounding_rtol * largest


@njit(cache=True, error_model="numpy", inline="always")
def _nearest_candidate(table, rows, rhs, zero, u0, tol, singular_tol, m, n, cand, basis, basis_sq, volume, valid):
    """The QP by enumeration: the index of the feasible candidate nearest u0 (the first of equals), or −1.

    Candidate g (row 0: u0 itself) comes from its prefix's candidate (`_projected`); it is skipped when its prefix
    is, when its last row is a zero row, or when its rows are (near) singular. The candidate's validity stays in
    this loop: as one compiled helper a candidate it cost 2.5× the kernel's CPU time a state (N = 2, B = 256)."""
    best, best_distance = -1, math.inf
    for g in range(table.shape[0]):
        size = table[g, 0]
        if g == 0:  # u_nom itself
            for j in range(n):
                cand[0, j] = u0[0, j]
            valid[0] = True
        else:
            row = table[g, 1]
            parent = table[g, size] if size > 1 else 0
            valid[g] = valid[parent] and not zero[row]
            if not valid[g]:
                continue
            if not _projected(table, rows, rhs, g, size, row, parent, singular_tol, n, cand, basis, basis_sq, volume):
                valid[g] = False
                continue
        feasible = True
        for i in range(m):
            if not _dot(cand, g, rows, i, n) - rhs[i] <= tol:
                feasible = False
                break
        if not feasible:
            continue
        distance = 0.0
        for j in range(n):
            d = cand[g, j] - u0[0, j]
            distance += d * d
        if distance < best_distance:
            best, best_distance = g, distance
            if g == 0:  # nothing is nearer u_nom than u_nom
                break
    return best


@njit(cache=True, error_model="numpy", inline="always")
def _projected(table, rows, rhs, g, size, row, parent, singular_tol, n, cand, basis, basis_sq, volume):
    """Candidate g: its prefix's candidate moved along `row` orthogonalised (modified Gram–Schmidt) against
    the prefix's rows onto `row`'s boundary, into cand[g] (basis, basis_sq and volume of g with it); return
    False if the rows' volume ‖v_1‖⋯‖v_k‖ is below singular_tol."""
    for j in range(n):
        basis[g, j] = rows[row, j]
    for i in range(size - 1):  # modified Gram–Schmidt against the prefix's rows
        w = table[g, 2 + i]
        coef = _dot(basis, g, basis, w, n) / basis_sq[w]
        for j in range(n):
            basis[g, j] = basis[g, j] - coef * basis[w, j]
    step = (_dot(rows, row, cand, parent, n) - rhs[row]) / _dot(rows, row, basis, g, n)
    for j in range(n):
        cand[g, j] = cand[parent, j] - step * basis[g, j]
    vv = _dot(basis, g, basis, g, n)
    basis_sq[g] = vv
    volume[g] = math.sqrt(vv) if size == 1 else volume[parent] * math.sqrt(vv)
    return volume[g] >= singular_tol


@njit(cache=True, error_model="numpy")
def predicted_margins(x, y, normals, offsets, n_max, out) -> None:
    """ρ = min_i (n_max − max(n̂_i·r − d_i, 0))/n_max at the tips r = (x, y) (m, (B,) each) into out (B,):
    `cbf_batch.predicted_margin` (numpy's maximum and minimum: a NaN propagates)."""
    for s in range(x.shape[0]):
        rho = math.inf
        for i in range(normals.shape[0]):
            depth = normals[i, 0] * x[s] + normals[i, 1] * y[s] - offsets[i]
            if not (depth >= 0.0 or math.isnan(depth)):
                depth = 0.0
            margin = (n_max - depth) / n_max
            if not (rho <= margin or math.isnan(rho)):
                rho = margin
        out[s] = rho
