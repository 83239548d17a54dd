"""The energy governor's compiled kernels (`controllers.governors.energy_governor`, e-erg and c-erg):
the look-ups of the escape-energy lower bounds Γ̲ (`controllers.energy.escape_energy`), the certificate, the
rays' bisections (step 3 of the governor) and the recovery's scan (step 4), over a leading row axis
where a governor call has state: row b is one governor's call, so `EnergyGovernor.__call__` (B = 1)
and `EnergyGovernor.filter_batch` (B rows) run the same code.

numba kernels, `@njit(cache=True)` (compiled once per machine into __pycache__), no fastmath and no
FMA contraction, so each IEEE operation happens in the order written and a row's floats do not depend on
the other rows. They are checked against their definitions, not against old floats: the look-ups against
plain Python evaluations within rounding (tests/test_energy_kernels.py), the table against a brute-force
minimisation (tests/test_energy_governor.py), the governors' commands against stored references within a
stated tolerance (tests/references/eerg_references.py). The module imports numba: its users load it lazily
(`controllers.core.lazy_import`), so `softcbf list` never does.

`escape_values(u, mode, table, flat, bound, lengths, gain, inverse_root_k, below)`, Γ̲_j(u) (J)
for every row j of P (`escape_energy.lower_bounds` and `lookup_arguments` hand the arguments over):
- the table (`EscapeEnergyTable.values`, bounds 4a and 4b of `controllers.energy.escape_energy`):
  cell index i_k = clip(⌊(u_k − lo_k)/Δ_k⌋, 0, G_k − 2) (Python's float floor division, which numba's
  `//` reproduces), offsets o_k = u_k − (lo_k + i_k Δ_k), the corners' cone bound
  ½ max(0, max_c (d̲_c − ‖u − u_c‖_w))² and, inside the cell, the bilinear bound minus the
  curvature ½ Σ_k w_k o_k (Δ_k − o_k), a loop over the 2^N corners (N ≤ 2: at most four);
- the second-order bound (`BoundaryDistanceBound.values`): ½ δ_j² with
  δ_j = 2|G_j| / (‖∇G_j‖ + √(‖∇G_j‖² + 2 C_j |G_j|)) from the tip and its Jacobian at the rest
  shape K⁻¹Λu (`pcc_model.kinematics_rows`, the same kernel);
- mode TABLE, BOUND, or BOTH: the table, and where its least row value is below `below` (J) the
  larger of the two per row (`GovernorModel.boundary_escape` of `controllers.governors.energy_governor.certificate`).
Layouts: `table` (5, N) float: lo, Δ, w, G_k, stride_k (hPa, hPa, J/hPa², 1, 1); `flat` (P', G) the
distances d̲ (J^{1/2}), a row out of reach +inf; `bound` (P', 5) float: H'_x, H'_y, h', C_j, reachable
(1/0); `gain` K⁻¹Λ (rad/hPa) and `inverse_root_k` 1/√k.

`certificate_terms(u, b, ...)`: the governor's (Γ, W) of a command u for row b, at the end (g, c) of least
Γ − W (`controllers.governors.energy_governor.certificate`, "actuator gain", "arm stiffness", "valve lag"): with r = g/c,
Γ_e = min_j (c·Γ̲_j(r·u) + o_j) (−inf where x̂ is not strictly inside P),
W_e = base + Σ_i ½ (c k_i e_i e_i + g²β_i max((p̂_i − u_i)², (p̄_i − u_i)²)), e_i = q̂_i − r a_i u_i, [p̂, p̄] the
pressure's interval (p̄ = p̂ without a lag interval: the same floats as one pressure).
`govern_rows(...)`: the governor's step 3 for B rows (`EnergyGovernor` module docstring): the held
command's margin Γ − ιW, the target's (≥ ε: "free"), else, with the held one > 0, the rays from u_prev
towards the target, 0 hPa and (parked certificate) u_nom, each bisected `bisection_steps` times,
the end point nearest the target ("governed", or "hold"), else RECOVER (the caller's step 4).

`recovery_scan(...)`: the recovery of `EnergyGovernor` (module docstring there, step 4) over the
candidates c = the grid commands, then the extra commands (u_prev, the target), for the gain ends e:
    Γ_e(c) = min_j (rows_e[j, c] + o_j)      (rows_e carry the end's stiffness scale),
    W_e(c) = base + ½ Σ_i (k_{e,i} (q̂_i − a_{e,i} c_i)² + β_{e,i} max((p̂_i − c_i)², (p̄_i − c_i)²)),
    m(c) = min_e (Γ_e(c) − ι W_e(c) − ε)            (ι: 1 + κ for the parked certificate, 1 for the contact one),
    D(c) = Σ_i (c_i − t_i)²  (t: the target);
the first candidate of least D among those with m ≥ 0 (when `inside`), else the first of greatest
score (m where `inside`, else −D) among the candidates whose rest shape lies inside P (`resting`; or,
with `resting_by_gamma`, those with Γ_e(c) ≥ ε at the first end), else none (−1: the target). The
sums run i = 0..N−1 from the first term, as numpy's reductions over a row of N < 8 entries do; the
minima and maxima keep the first of equal values, as np.min/np.argmin/np.argmax do (no NaN arises:
Γ ∈ [0, +inf], W finite). Loops over the candidates innermost, on the grid stored one column per
command: ≈ 35 µs for the 14 641 commands of the default table (loaded machine), against ≈ 0.9 ms for
the numpy expression it replaces (a loop per candidate over its gain ends, rows and segments: ≈ 250 µs).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from controllers.model import pcc_model

ROUNDING_SLACK = 1e-12
"""Relative slack (of Σ_i (|a_i| + |g_i| + |t_i|)², hPa²) for the rounding of the ray distances
(`ray_may_come_nearer`, whose docstring bounds the rounding)."""

TABLE, BOUND, BOTH = 0, 1, 2
"""`escape_values` modes: the table alone, the second-order bound alone, the larger of the two near P's boundary."""


@njit(cache=True, error_model="numpy")
def table_values(u, table, flat, out):
    """Γ̲_j(u) of the table (module docstring) into out (P',); u (N,) hPa, table (5, N), flat (P', G)."""
    n = u.shape[0]
    # the 2^N corners, in itertools.product order (the last axis fastest)
    flat_index, inside, curvature = 0, True, 0.0
    offsets, highs, t = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        lo, step, w, size, stride = table[0, k], table[1, k], table[2, k], int(table[3, k]), int(table[4, k])
        i = _cell(u[k], lo, step, size) if size > 1 else 0
        o = u[k] - (lo + i * step)
        inside = inside and 0.0 <= o and o <= step
        flat_index += i * stride
        curvature += 0.5 * w * o * (step - o)
        t[k] = o / step
        offsets[k] = w * o * o
        highs[k] = w * ((o - step) * (o - step))
    corners = 1 << n
    index, distance, weight = np.empty(corners, np.int64), np.empty(corners), np.empty(corners)
    for c in range(corners):
        k_flat, squared, product = 0, 0.0, 1.0
        for k in range(n):
            upper = (c >> (n - 1 - k)) & 1
            if upper:
                k_flat += int(table[4, k])
                squared += highs[k]
                product *= t[k]
            else:
                squared += offsets[k]
                product *= 1.0 - t[k]
        index[c], distance[c], weight[c] = flat_index + k_flat, math.sqrt(squared), product
    for j in range(flat.shape[0]):
        if flat[j, index[0]] == math.inf:
            out[j] = math.inf
            continue
        cone = flat[j, index[0]] - distance[0]
        for c in range(1, corners):
            value = flat[j, index[c]] - distance[c]
            if value > cone:
                cone = value
        best = 0.5 * cone * cone if cone > 0.0 else 0.0
        if inside:
            total = 0.0
            for c in range(corners):
                value = flat[j, index[c]]
                total += 0.5 * (value * value) * weight[c]
            total -= curvature
            if total > best:
                best = total
        out[j] = best


@njit(cache=True, error_model="numpy", inline="always")
def _cell(v, lo, step, size):
    """min(max(int((v − lo) // step), 0), size − 2) for a finite v (the floor is clipped as a float first)."""
    cell = (v - lo) // step
    if cell < 0.0:
        return 0
    if cell > size - 2:
        return size - 2
    return int(cell)


@njit(cache=True, error_model="numpy")
def bound_values(u, bound, lengths, gain, inverse_root_k, out):
    """½ δ_j(u)² (J) of the second-order bound (module docstring) into out (P',); u (N,) hPa, bound (P', 5),
    lengths (N,) m, gain K⁻¹Λ (N,) rad/hPa, inverse_root_k 1/√k (N,)."""
    n = u.shape[0]
    q = np.empty((1, n))
    for i in range(n):
        q[0, i] = gain[i] * u[i]
    kin = pcc_model.kinematics_rows(q, np.zeros((1, n)), lengths)
    tip = kin[0, 4 * n]
    x, y = tip.real, tip.imag
    for j in range(bound.shape[0]):
        if bound[j, 4] == 0.0:
            out[j] = math.inf
            continue
        hx, hy, h, c = bound[j, 0], bound[j, 1], bound[j, 2], bound[j, 3]
        size = abs(hx * x + hy * y - h)
        squared = 0.0
        for i in range(n):
            d = kin[0, n + i]
            term = (hx * d.real + hy * d.imag) * inverse_root_k[i]
            squared += term * term
        slope = math.sqrt(squared)
        delta = 2.0 * size / (slope + math.sqrt(slope * slope + 2.0 * c * size)) if size > 0.0 else 0.0
        out[j] = 0.5 * delta * delta


@njit(cache=True, error_model="numpy")
def escape_values(u, mode, table, flat, bound, lengths, gain, inverse_root_k, below):
    """Γ̲_j(u) (J) for every row j (module docstring): (P',)."""
    rows = flat.shape[0] if mode != BOUND else bound.shape[0]
    out = np.empty(rows)
    if mode == BOUND:
        bound_values(u, bound, lengths, gain, inverse_root_k, out)
        return out
    table_values(u, table, flat, out)
    if mode == TABLE:
        return out
    least = out[0]
    for j in range(1, rows):
        if out[j] < least:
            least = out[j]
    if least >= below:  # far from the boundary: the table is the tighter bound
        return out
    second = np.empty(rows)
    bound_values(u, bound, lengths, gain, inverse_root_k, second)
    for j in range(rows):
        if second[j] > out[j]:
            out[j] = second[j]
    return out


@njit(cache=True, error_model="numpy", inline="always")
def _margins(commands, rows, offsets, terms, base, q, p, p_far, target, inflation, eps, margin, first_gamma, distance,
             start):
    """m, Γ at the first gain end and D (module docstring) of the candidates commands (N, C) hPa (one column
    each) with their rows (E, P', C), into margin, first_gamma and distance [start, start + C). Loops over
    the candidates innermost (contiguous: compiled to vector instructions), each candidate's operations in
    the order of the module docstring."""
    n, count = commands.shape
    gamma, energy = np.empty(count), np.empty(count)
    for e in range(terms.shape[0]):
        offset = offsets[0]
        for c in range(count):
            gamma[c] = rows[e, 0, c] + offset
        for j in range(1, offsets.shape[0]):
            offset = offsets[j]
            for c in range(count):
                value = rows[e, j, c] + offset
                gamma[c] = value if value < gamma[c] else gamma[c]
        if e == 0:
            for c in range(count):
                first_gamma[start + c] = gamma[c]
        for i in range(n):
            k, a, beta, qi, pi, pf = terms[e, 0, i], terms[e, 1, i], terms[e, 2, i], q[i], p[i], p_far[i]
            for c in range(count):
                u = commands[i, c]
                diff, lag, far = qi - a * u, pi - u, pf - u
                square, far_square = lag * lag, far * far
                if far_square > square:
                    square = far_square
                term = k * (diff * diff) + beta * square
                energy[c] = term if i == 0 else energy[c] + term
        for c in range(count):
            at_end = gamma[c] - inflation * (base + 0.5 * energy[c]) - eps
            margin[start + c] = at_end if e == 0 or at_end < margin[start + c] else margin[start + c]
    for i in range(n):
        aim = target[i]
        for c in range(count):
            d = commands[i, c] - aim
            distance[start + c] = d * d if i == 0 else distance[start + c] + d * d


@njit(cache=True, error_model="numpy")
def recovery_scan(grid, grid_rows, extra, extra_rows, offsets, terms, base, q, p, target, inflation, eps, inside,
                  resting_grid, resting_extra, resting_by_gamma, p_far=None):
    """(index, infeasible) of the recovery's choice (module docstring): index < G a grid command, G + e the
    extra command e, −1 none (the target). grid (N, G) hPa (one column per command), grid_rows (E, P', G)
    and extra_rows (E, P', X) J per gain end, extra (N, X) hPa, offsets (P',) J, terms (E, 3, N): k, a, β
    per end, base J, q (N,) rad, p (N,) hPa, target (N,) hPa, inflation ι, eps ε (J), inside (bool),
    resting_grid (G,), resting_extra (X,) bool; p_far (N,) hPa: the pressure interval's other end (None: p alone),
    the lag term β_i max((p_i − c_i)², (p̄_i − c_i)²). grid_rows and extra_rows carry each end's stiffness scale."""
    n_grid, total = grid.shape[1], grid.shape[1] + extra.shape[1]
    margin, first_gamma, distance = np.empty(total), np.empty(total), np.empty(total)
    far = p if p_far is None else p_far
    _margins(grid, grid_rows, offsets, terms, base, q, p, far, target, inflation, eps, margin, first_gamma, distance, 0)
    _margins(extra, extra_rows, offsets, terms, base, q, p, far, target, inflation, eps, margin, first_gamma, distance,
             n_grid)
    if inside:  # the first certified candidate of least distance
        best, best_distance = -1, math.inf
        for c in range(total):
            if margin[c] >= 0.0 and distance[c] < best_distance:
                best, best_distance = c, distance[c]
        if best >= 0:
            return best, False
    best, best_score = -1, -math.inf
    for c in range(total):
        if resting_by_gamma:
            resting = first_gamma[c] >= eps
        else:
            resting = resting_grid[c] if c < n_grid else resting_extra[c - n_grid]
        score = margin[c] if inside else -distance[c]
        if resting and (best < 0 or score > best_score):
            best, best_score = c, score
    return best, True


FREE, GOVERNED, HOLD, RECOVER = 0, 1, 2, 3
"""`govern_rows` action codes: "free", "governed", "hold", and "recover" (the held command failed: the caller
recovers)."""


@njit(cache=True, error_model="numpy")
def escape_into(u, mode, table, flat, bound, lengths, gain, inverse_root_k, below, out, second):
    """`escape_values` into out (P',); second (P',): scratch."""
    if mode == BOUND:
        bound_values(u, bound, lengths, gain, inverse_root_k, out)
        return
    table_values(u, table, flat, out)
    if mode == TABLE:
        return
    least = out[0]
    for j in range(1, out.shape[0]):
        if out[j] < least:
            least = out[j]
    if least >= below:
        return
    bound_values(u, bound, lengths, gain, inverse_root_k, second)
    for j in range(out.shape[0]):
        if second[j] > out[j]:
            out[j] = second[j]


@njit(cache=True, error_model="numpy")
def energy_at(u, q, p, p_far, terms, b, e, base):
    """W (J) of the command u (N,) hPa at row b's state q[b] (rad), the pressure interval's ends p[b], p_far[b]
    (hPa) and gain end e: base plus ½(k_i e_i e_i + β_i max((p_i − u_i)², (p̄_i − u_i)²)) segment by segment,
    e_i = q_i − a_i u_i, terms[b, e] = (k, a, β) (`GovernorModel.energy`;
    p_far = p: the one pressure)."""
    w = base
    for i in range(u.shape[0]):
        diff = q[b, i] - terms[b, e, 1, i] * u[i]
        lag, far = p[b, i] - u[i], p_far[b, i] - u[i]
        lag, far = lag * lag, far * far
        if far > lag:
            lag = far
        w = w + 0.5 * (terms[b, e, 0, i] * diff * diff + terms[b, e, 2, i] * lag)
    return w


@njit(cache=True, error_model="numpy")
def certificate_terms(u, b, gains, scales, ends, terms, base, q, p, p_far, offsets, inside, mode, table, flat,
                      bound, lengths, gain, inverse_root_k, below, scaled, rows, second):
    """(Γ, W) (J) of the command u (N,) for row b (`EnergyGovernor`'s certificate, module docstring there):
    at each of the row's `ends[b]` ends, rest-shape ratio r = gains[b, e] and arm stiffness scale c = scales[b, e],
    Γ_e = min_j (c·Γ̲_j(r·u) + o_j) (−inf where the state is not strictly inside P; c = 1 multiplies exactly) and
    W_e = base + Σ_i ½(k_i e_i e_i + β_i max((p_i − u_i)², (p̄_i − u_i)²)), e_i = q_i − a_i u_i, added segment by
    segment (the governor's `energy`); the pair of the first end with the
    least Γ − W. scaled, rows, second: scratch (N,), (P',), (P',)."""
    n = u.shape[0]
    best_gamma, best_w, best_key = 0.0, 0.0, 0.0
    for e in range(ends[b]):
        g, c = gains[b, e], scales[b, e]
        gamma = -math.inf
        if inside[b]:
            for i in range(n):
                scaled[i] = u[i] if g == 1.0 else g * u[i]
            escape_into(scaled, mode, table, flat, bound, lengths, gain, inverse_root_k, below, rows,
                        second)
            gamma = c * rows[0] + offsets[b, 0]
            for j in range(1, rows.shape[0]):
                value = c * rows[j] + offsets[b, j]
                if value < gamma:
                    gamma = value
        w = energy_at(u, q, p, p_far, terms, b, e, base[b])
        key = gamma - w
        if e == 0 or key < best_key:
            best_gamma, best_w, best_key = gamma, w, key
    return best_gamma, best_w


@njit(cache=True, error_model="numpy")
def govern_rows(held, aim, rest, nominal, goals, gains, scales, ends, terms, base, q, p, p_far, offsets, inside,
                inflation, eps, steps, mode, table, flat, bound, lengths, gain, inverse_root_k, below):
    """Steps 3 of `EnergyGovernor` (its module docstring) for B rows at once, row b the floats of one governor
    call (B = 1 runs this kernel too): held, aim, nominal (B, N) hPa (u_prev, the target, u_nom clipped), rest (N,)
    the vented command, goals the rays' count (2: target and vent; 3: and u_nom), the certificate's terms per
    row (`certificate_terms`; inflation ι: margin = Γ − ιW), eps ε, steps: bisection_steps.
    Returns u (B, N), action (B,) FREE/GOVERNED/HOLD/RECOVER, σ (B,), Γ, W of u (B,), and the held margin (B,)."""
    rows_count, n = held.shape
    u_out, action = np.empty((rows_count, n)), np.empty(rows_count, np.int64)
    sigma_out, gamma_out, w_out, held_out = np.empty(rows_count), np.empty(rows_count), np.empty(rows_count), \
        np.empty(rows_count)
    scaled, rows, second = np.empty(n), np.empty(flat.shape[0] if mode != BOUND else bound.shape[0]), \
        np.empty(flat.shape[0] if mode != BOUND else bound.shape[0])
    point, direction, goal, best_u = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    sigma_min = 1.0
    for _ in range(steps):
        sigma_min *= 0.5  # 0.5 ** steps, exact
    for b in range(rows_count):
        gamma, w = certificate_terms(held[b], b, gains, scales, ends, terms, base, q, p, p_far, offsets, inside, mode,
                                     table, flat, bound, lengths, gain, inverse_root_k, below, scaled, rows, second)
        held_margin = gamma - inflation * w
        held_out[b] = held_margin
        gamma, w = certificate_terms(aim[b], b, gains, scales, ends, terms, base, q, p, p_far, offsets, inside, mode,
                                     table, flat, bound, lengths, gain, inverse_root_k, below, scaled, rows, second)
        if gamma - inflation * w >= eps:
            for i in range(n):
                u_out[b, i] = aim[b, i]
            action[b], sigma_out[b], gamma_out[b], w_out[b] = FREE, 1.0, gamma, w
            continue
        if not held_margin > 0.0:
            for i in range(n):
                u_out[b, i] = held[b, i]
            action[b], sigma_out[b], gamma_out[b], w_out[b] = RECOVER, math.nan, math.nan, math.nan
            continue
        moved, sigma, best = False, 0.0, 0.0
        for i in range(n):
            d = held[b, i] - aim[b, i]
            best += d * d
        for k in range(goals):
            for i in range(n):
                goal[i] = aim[b, i] if k == 0 else rest[i] if k == 1 else nominal[b, i]
                direction[i] = goal[i] - held[b, i]
            if k and not ray_may_come_nearer(held[b], goal, direction, aim[b], best, sigma_min):
                continue
            lo, hi = 0.0, 1.0
            for _ in range(steps):
                mid = 0.5 * (lo + hi)
                for i in range(n):
                    point[i] = held[b, i] + mid * direction[i]
                gamma, w = certificate_terms(point, b, gains, scales, ends, terms, base, q, p, p_far, offsets, inside,
                                             mode, table, flat, bound, lengths, gain, inverse_root_k, below, scaled,
                                             rows, second)
                if gamma - inflation * w >= eps:
                    lo = mid
                else:
                    hi = mid
            if k == 0:
                sigma = lo
            distance = 0.0
            for i in range(n):
                point[i] = held[b, i] + lo * direction[i]
                d = point[i] - aim[b, i]
                distance += d * d
            if distance < best:
                moved, best = True, distance
                for i in range(n):
                    best_u[i] = point[i]
        for i in range(n):
            u_out[b, i] = best_u[i] if moved else held[b, i]
        gamma, w = certificate_terms(u_out[b], b, gains, scales, ends, terms, base, q, p, p_far, offsets, inside, mode,
                                     table, flat, bound, lengths, gain, inverse_root_k, below, scaled, rows, second)
        action[b], sigma_out[b], gamma_out[b], w_out[b] = GOVERNED if moved else HOLD, sigma, gamma, w
    return u_out, action, sigma_out, gamma_out, w_out, held_out


@njit(cache=True, error_model="numpy")
def ray_may_come_nearer(start, goal, direction, aim, best, sigma_min):
    """`energy_governor.ray_may_come_nearer` (its docstring: False proves that no point of the ray for
    σ ∈ [sigma_min, 1] comes nearer `aim` than `best`); start, goal, direction, aim (N,) hPa."""
    n = start.shape[0]
    curvature, dot, scale = 0.0, 0.0, 0.0
    for i in range(n):
        curvature += direction[i] * direction[i]
    if curvature == 0.0:
        return False
    for i in range(n):
        dot += (start[i] - aim[i]) * direction[i]
    nearest = -dot / curvature
    if sigma_min > nearest:
        nearest = sigma_min
    if 1.0 < nearest:
        nearest = 1.0
    lowest = 0.0
    for i in range(n):
        gap = (start[i] - aim[i]) + nearest * direction[i]
        size = abs(start[i]) + abs(goal[i]) + abs(aim[i])
        lowest += gap * gap
        scale += size * size
    return lowest <= best + ROUNDING_SLACK * scale
