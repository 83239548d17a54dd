"""`softcbf_mj.outputs.metrics.RunningFigures.update`, compiled: one pass over a block of T rows of B runs.

The figures' definitions are RunningFigures' docstring; this is their one implementation. Compiled
(numba, `@njit(cache=True)`, no fastmath) because a batched loop updates them every control period:
in numpy the update was ≈ 20 array operations of ≈ 2–3 µs each, 0.23 µs per simulation and period
at B = 256 (tools/bench_batch.py's split), a sixth of the batched PCC loop. Loaded on the first call
(`controllers.core.lazy_import`).

Every figure is a min, max or count except force_excess, whose block sum runs over t = 0, 1, … from
the block's first row, then is added to the running sum (numpy's order for a sum over axis 0). NaN
semantics are numpy's: rho_min_pred and u_peak_abs_hPa use fmin / fmax (a NaN is skipped), the block
maxima and minima (ρ_meas, the forces, |u|) propagate NaN, as np.min / np.max / np.minimum /
np.maximum do; on ties the first operand is kept (numpy's scalar loops).
"""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True, inline="always")
def _min(a, b):
    """np.minimum: NaN if either is NaN."""
    return a if (a <= b or math.isnan(a)) else b


@njit(cache=True, inline="always")
def _max(a, b):
    """np.maximum: NaN if either is NaN."""
    return a if (a >= b or math.isnan(a)) else b


@njit(cache=True, inline="always")
def _fmin(a, b):
    """np.fmin: a NaN is skipped (NaN only if both are)."""
    return a if (a <= b or math.isnan(b)) else b


@njit(cache=True, inline="always")
def _fmax(a, b):
    """np.fmax: a NaN is skipped (NaN only if both are)."""
    return a if (a >= b or math.isnan(b)) else b


@njit(cache=True, error_model="numpy")
def update(margin, contact_forces, u, rho_pred, infeasible, action, rows, has_action, has_rows, f_max, n_rows,
           rho_min_pred, rho_min_meas, force_max, violations, infeasible_rows, refused, vented, u_peak,
           force_excess) -> None:
    """Add T rows of B runs (RunningFigures.update's arguments, (T, B, …); action and rows read only if
    has_action / has_rows; f_max NaN: no force excess) to the running figures (B,), in place."""
    n_t, n_b = margin.shape
    n_p, n_u = contact_forces.shape[2], u.shape[2]
    for b in range(n_b):
        pred, meas, force, peak, excess = math.nan, math.inf, -math.inf, 0.0, 0.0
        for t in range(n_t):
            if has_rows and not rows[t, b]:  # a row that does not count (numpy: the neutral values)
                row_pred, row_meas, row_force, row_peak, row_excess = math.nan, math.inf, -math.inf, 0.0, 0.0
            else:
                n_rows[b] += 1
                row_pred, row_meas = rho_pred[t, b], margin[t, b]
                row_force = contact_forces[t, b, 0]
                for i in range(1, n_p):
                    row_force = _max(row_force, contact_forces[t, b, i])
                row_peak = abs(u[t, b, 0])
                for j in range(1, n_u):
                    row_peak = _max(row_peak, abs(u[t, b, j]))
                row_excess = 0.0
                if not math.isnan(f_max):
                    row_excess = _max(contact_forces[t, b, 0] - f_max, 0.0)
                    for i in range(1, n_p):
                        row_excess = _max(row_excess, _max(contact_forces[t, b, i] - f_max, 0.0))
                    row_excess = row_excess / f_max
                if row_meas < 0.0:
                    violations[b] += 1
                if infeasible[t, b]:
                    infeasible_rows[b] += 1
                if has_action and action[t, b] != 0:
                    refused[b] += 1
                    if action[t, b] == 2:
                        vented[b] = True
            if t == 0:
                pred, meas, force, peak, excess = row_pred, row_meas, row_force, row_peak, row_excess
            else:
                pred, meas = _fmin(pred, row_pred), _min(meas, row_meas)
                force, peak, excess = _max(force, row_force), _max(peak, row_peak), excess + row_excess
        if n_t > 0:
            rho_min_pred[b] = _fmin(rho_min_pred[b], pred)
            rho_min_meas[b] = _min(rho_min_meas[b], meas)
            force_max[b] = _max(force_max[b], force)
            u_peak[b] = _fmax(u_peak[b], peak)
            if not math.isnan(f_max):
                force_excess[b] += excess
