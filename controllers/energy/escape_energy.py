"""Escape energy Γ(u): the least elastic energy about a command's rest shape that reaches outside P (docs/beyond-the-paper.md#filters-beyond-the-paper).

For a held command u (N,) hPa with rest shape q_u = K⁻¹Λu (rad) and each row j of the
force-safe set P = {r | H' r ≤ h'} (docs/model.md#force-safe-set),

    Γ_j(u) = min { ½ (q − q_u)ᵀ K (q − q_u)  :  g_j(q) = H'_j r(q) − h'_j ≥ 0 }   (J),
    Γ(u) = min_j Γ_j(u),

r(q) the PCC tip (m), K = diag(k_i) (N·m/rad). In the coordinates z = K^{1/2} q,
Γ_j(u) = ½ d_j(u)² with d_j(u) the Euclidean distance from z_u = K^{1/2} q_u to the
unsafe set S_j = {z : g_j ≥ 0}. A distance function is 1-Lipschitz, so

    |d_j(u) − d_j(u')| ≤ ‖K^{1/2} K⁻¹Λ (u − u')‖ = ‖u − u'‖_w,   w_i = λ_i²/k_i   (J^{1/2})   (*)

The table (N ≤ 2 segments; the q-space search below is a grid):
1. Commands: a regular grid over the box [u_lo, u_hi] with spacing ≤ `grid_hPa` (default
   2.5 hPa: 121 × 121 points for ±150 hPa; at most MAX_TABLE_COMMANDS points, else refused).
2. q-space: a regular grid with spacing Δq_i = `q_spacing_rad`/√k_i (uniform in z) over the rest
   shapes' box widened by `reach_rad` (default 1.2 rad) on every side; g_j on every point.
3. Band: the nearest point z* of S_j to z_u lies on g_j = 0; the grid point s nearest to
   it is within h_q = ½‖Δq‖ (rad) of it, so |g_j(s)| ≤ L_j h_q with L_j ≥ ‖∇g_j‖ from
   ‖∂r/∂q_i‖ ≤ Σ_{k≥i} L_k (a chord's rotation and length change move the tip by at most
   the arc beyond it): L_j = ‖H'_j‖ (Σ_i (Σ_{k≥i} L_k)²)^{1/2}. The band B_j = {s : |g_j(s)| ≤ L_j h_q}
   therefore holds such an s, and ‖z_u − z_s‖ ≤ d_j + h_z with h_z = ½‖K^{1/2}Δq‖.
   Beyond the q-grid's box nothing is searched: there the distance is at least the
   distance e(u) from z_u to the box's outside. Hence, at every command grid point,
       d_j ≥ d̲_j = max(0, min(min_{s∈B_j} ‖z_u − z_s‖ − h_z, e(u)))   (0 when g_j(q_u) ≥ 0).
   A row out of the arm's reach, ‖H'_j‖ Σ_i L_i < h'_j (the tip lies within Σ L_i of the base,
   so g_j < 0 for every q), has no unsafe set: Γ_j = +inf exactly (`values` returns inf for it,
   `distance` holds inf). A reachable row whose line the q-grid's box never meets (beyond the
   rest shapes' reach_rad) has an empty band: its minimum is +inf and d̲_j = e(u), the same
   saturation as every row far from its line.
4. Between grid points, two bounds from the cell's corners c (values Γ̲_c = ½ d̲_c²):
   a. Semiconcavity: ½‖u‖²_w − Γ_j(u) = max_{z∈S_j} (z·z_u − ½|z|²) is convex in u (a max of
      affine functions of z_u, which is linear in u), so it lies below the bilinear
      interpolation of its corner values (bilinear weights ω_c ≥ 0 are barycentric); with
      Σ_c ω_c ‖u_c‖²_w − ‖u‖²_w = Σ_i w_i (u_i − a_i)(b_i − u_i) on the cell [a, b]:
          Γ_j(u) ≥ Σ_c ω_c Γ̲_c − ½ Σ_i w_i (u_i − a_i)(b_i − u_i)
      (the correction is at most ≈ 4.6e-5 J at 2.5 hPa on the reference arm). Inside the box only.
   b. Lipschitz, from (*): d_j(u) ≥ max_c (d̲_c − ‖u − u_c‖_w), Γ ≥ ½ max(0, ·)²; valid
      anywhere, so it also covers commands outside the box (the nearest cell's corners).
   Γ̲_j(u) is the larger of the two.
So Γ̲_j(u) ≤ Γ_j(u) everywhere: the table is conservative. The look-up is compiled
(`controllers.energy.energy_kernels`: `lower_bounds` from Python, and inside the energy governor's kernels).

Boundary variant (`boundary=True`, the e-erg's contact certificate, `controllers.governors.energy_governor`):
S_j = {z : g_j = 0}, the row's boundary itself, so Γ^∂_j(u) = min {½ (q − q_u)ᵀK(q − q_u) : g_j(q) = 0}
is > 0 also for a rest shape beyond P (the arm, inside P, must still cross the boundary to leave).
Steps 3–4 hold unchanged for it: the nearest point of S_j lies on g_j = 0 by definition (the band
holds a grid point within h_q of it), a distance to any set is 1-Lipschitz, and ½‖u‖²_w − Γ^∂_j is a
max of affine functions of z_u whatever S_j is; only the rule "0 when g_j(q_u) ≥ 0" is dropped.
Γ_j ≤ Γ^∂_j (the boundary is part of the closed unsafe set), with equality for a rest shape inside P. Its looseness in d: h_z
(≈ 2.8e-3 J^{1/2} at the defaults) and the band's extent on the near side of g_j = 0 where
‖∇g_j‖ < L_j at the grid points, plus bound 4a's correction between them (measured: see
tests/test_energy_governor.py; d ≈ 0.1–1 J^{1/2} away from the plate). Γ saturates at ½ k_min reach²
(0.72 J at the defaults), above the elastic energy of any command step within ±150 hPa
of the reference arm (≤ 0.67 J). tests/test_energy_governor.py compares the table with a brute-force minimisation.
"""

from __future__ import annotations

import math

import numpy as np

from controllers.core.lazy_import import lazy_module
from controllers.model.params import RobotParams
from controllers.model.pcc import tip_positions
from controllers.model.safe_set import ForceSafeSet

energy_kernels = lazy_module("controllers.energy.energy_kernels")  # numba loads on the first kernel call (controllers.core.lazy_import)

MAX_SEGMENTS = 2
MAX_TABLE_COMMANDS = 2**18
"""Most command grid points G (`grid_hPa`'s bound): building takes ≈ 1 s per 15 000 on the reference arm
(measured: 14 641 in 0.96 s, 361 201 in 11 s) and the governor's recovery scans all G."""
_CHUNK = 512  # command grid points per distance block (memory: _CHUNK × band size floats)


class EscapeEnergyTable:
    """Γ̲_j(u) ≤ Γ_j(u) for every row j of `safe_set`, tabulated over [u_lo, u_hi] (see the module docstring)."""

    def __init__(self, robot: RobotParams, safe_set: ForceSafeSet, u_lo, u_hi, grid_hPa: float = 2.5,
                 q_spacing_rad: float = 4e-3, reach_rad: float = 1.2, boundary: bool = False) -> None:
        n = robot.n_segments
        if n > MAX_SEGMENTS:
            raise ValueError(f"the escape-energy table supports N <= {MAX_SEGMENTS} segments (a q-space grid), got N = {n}")
        for name, value in (("grid_hPa", grid_hPa), ("q_spacing_rad", q_spacing_rad), ("reach_rad", reach_rad)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0, got {value}")
        u_lo, u_hi = np.asarray(u_lo, dtype=float), np.asarray(u_hi, dtype=float)
        if u_lo.shape != (n,) or u_hi.shape != (n,) or not np.all(u_lo < u_hi):
            raise ValueError(f"u_lo < u_hi must have shape ({n},) hPa, got {u_lo} and {u_hi}")
        widths = (u_hi - u_lo).tolist()
        cells = [w / grid_hPa for w in widths]  # inf for a subnormal grid_hPa
        count = math.prod(c + 1.0 for c in cells)
        if not count <= MAX_TABLE_COMMANDS:  # (a float bound first: ceil(inf) would raise)
            finest = max(widths) / (math.floor(MAX_TABLE_COMMANDS ** (1.0 / n)) - 1)
            raise ValueError(f"grid_hPa must be >= {finest:.4g} hPa over the box {widths} hPa wide (at most "
                             f"{MAX_TABLE_COMMANDS} table commands), got {grid_hPa!r} ({count:.3g} commands)")
        sizes = [math.ceil(c) + 1 for c in cells]
        if math.prod(sizes) > MAX_TABLE_COMMANDS:
            raise ValueError(f"grid_hPa must be larger over the box {widths} hPa wide (at most {MAX_TABLE_COMMANDS} "
                             f"table commands), got {grid_hPa!r} ({math.prod(sizes)} commands)")
        self.n = n
        self.stiffness = robot.array("stiffness")
        self.static_gain = robot.array("gains") / self.stiffness  # K⁻¹Λ, rad/hPa
        self.weights = robot.array("gains") ** 2 / self.stiffness  # w, J per hPa²
        self.axes = [np.linspace(lo, hi, size) for lo, hi, size in zip(u_lo, u_hi, sizes)]
        self.spacing = np.array([a[1] - a[0] for a in self.axes])
        self.reach_rad = float(reach_rad)
        self.boundary = bool(boundary)
        commands = self.grid_commands()
        self.distance = self._distances(robot, safe_set, commands, float(q_spacing_rad))  # (P', G) J^{1/2}
        shape = [len(a) for a in self.axes]
        strides = [int(np.prod(shape[i + 1:])) for i in range(self.n)]  # C order: flat index Σ_i index_i · stride_i
        self.kernel_table = np.array([u_lo, self.spacing, self.weights, shape, strides], dtype=float)  # (5, N)

    @property
    def saturation_J(self) -> float:
        """½ min_i k_i reach_rad² (J): the escape energy the table resolves at least (Γ̲ saturates near it)."""
        return 0.5 * float(np.min(self.stiffness)) * self.reach_rad**2

    def grid_commands(self) -> np.ndarray:
        """The command grid: (G, N) hPa, G = Π_i G_i, C order over the axes."""
        mesh = np.meshgrid(*self.axes, indexing="ij")
        return np.stack([m.ravel() for m in mesh], axis=1)

    def grid_values(self) -> np.ndarray:
        """Γ̲_j at the grid commands: (P', G) J."""
        return 0.5 * self.distance**2

    def _distances(self, robot: RobotParams, safe_set: ForceSafeSet, commands: np.ndarray, spacing: float) -> np.ndarray:
        lengths = robot.array("lengths")
        rest = commands * self.static_gain
        root_k = np.sqrt(self.stiffness)
        lo = rest.min(axis=0) - self.reach_rad
        hi = rest.max(axis=0) + self.reach_rad
        dq = spacing / root_k
        axes = [np.linspace(a, b, int(math.ceil((b - a) / d)) + 1) for a, b, d in zip(lo, hi, dq)]
        dq = np.array([a[1] - a[0] for a in axes])
        q = np.stack([m.ravel() for m in np.meshgrid(*axes, indexing="ij")], axis=1)
        H, h = np.array(safe_set.H_prime, dtype=float), np.array(safe_set.h_prime, dtype=float)
        g = tip_positions(q, lengths) @ H.T - h  # (M, P')
        g_rest = tip_positions(rest, lengths) @ H.T - h  # (G, P')
        beyond = np.cumsum(lengths[::-1])[::-1]  # Σ_{k≥i} L_k
        lipschitz = np.hypot(H[:, 0], H[:, 1]) * math.sqrt(float(np.sum(beyond**2)))
        h_q = 0.5 * float(np.linalg.norm(dq))
        h_z = 0.5 * float(np.linalg.norm(root_k * dq))
        z_rest = rest * root_k
        outside = np.min(root_k * np.minimum(rest - lo, hi - rest), axis=1)  # e(u), J^{1/2}
        distance = np.full((H.shape[0], len(commands)), np.inf)
        reachable = np.hypot(H[:, 0], H[:, 1]) * float(np.sum(lengths)) >= h  # else g_j < 0 on the whole workspace
        for j in np.flatnonzero(reachable).tolist():
            band = q[np.abs(g[:, j]) <= lipschitz[j] * h_q] * root_k
            nearest = np.full(len(commands), np.inf)  # an empty band (the row's line beyond the q-grid's reach): d ≥ e(u)
            for start in range(0, len(commands) if len(band) else 0, _CHUNK):
                block = z_rest[start:start + _CHUNK]
                d2 = np.sum(block * block, axis=1)[:, None] - 2.0 * block @ band.T + np.sum(band * band, axis=1)
                nearest[start:start + _CHUNK] = np.sqrt(np.maximum(d2.min(axis=1), 0.0))
            d = np.maximum(np.minimum(nearest - h_z, outside), 0.0)
            if not self.boundary:
                d[g_rest[:, j] >= 0.0] = 0.0
            distance[j] = d
        self.rest_inside = np.all(g_rest < 0.0, axis=1)  # (G,): the grid command's rest shape lies inside P
        return distance

    def values(self, u) -> list[float]:
        """Γ̲_j(u) for every row j: P' floats (J). u: (N,) hPa (Python floats or an array).

        The larger of the two bounds 4a (inside the box) and 4b, in the compiled look-up
        (`controllers.energy.energy_kernels.table_values`, the loop over the 2^N cell corners; called from Python its
        dispatch costs ≈ 5 µs, inside the governor's kernels the look-up ≈ 0.1 µs)."""
        return lower_bounds(u, self, None)


class BoundaryDistanceBound:
    """Γ^∂_j(u) ≥ ½ δ_j(u)² for every row j, any number of segments N, without a grid.

    In z = K^{1/2} q (J^{1/2}) let G_j(z) = H'_j r(K^{-1/2} z) − h'_j, so Γ^∂_j(u) = ½ d_j² with d_j
    the distance from z_u = K^{1/2} q_u to the curve (surface for N > 2) G_j = 0. A PCC tip is
    a sum of arcs, r = Σ_i L_i ∫₀¹ e^{i θ_{i,s}} ds (complex, up to the base's fixed rotation) with
    the angle θ_{i,s} = a_{i,s}·q linear in q (a_{i,s} = (1, …, 1, s, 0, …, 0): the segments
    before i, then s at i). Hence ∂²r[w, w] = −Σ_i L_i ∫₀¹ (a_{i,s}·w)² e^{iθ} ds and, with
    w = K^{-1/2} v and (a·w)² ≤ ‖K^{-1/2} a‖² |v|²,

        |∇²G_j[v, v]| ≤ C_j |v|²,   C_j = ‖H'_j‖ Σ_i L_i (Σ_{k<i} 1/k_k + 1/(3 k_i))   (∫₀¹ s² ds = 1/3).

    Let z* be a nearest point of the boundary and δ = z* − z_u. Taylor's theorem with the
    integral remainder gives |G_j(z*) − G_j(z_u) − ∇G_j(z_u)·δ| ≤ ½ C_j |δ|², and G_j(z*) = 0, so
    |G_j(z_u)| ≤ ‖∇G_j(z_u)‖ |δ| + ½ C_j |δ|²; the right side grows with |δ|, hence

        d_j ≥ δ_j = 2 |G_j(z_u)| / (‖∇G_j(z_u)‖ + √(‖∇G_j(z_u)‖² + 2 C_j |G_j(z_u)|)),

    the positive root of the quadratic, written without cancellation (C_j = 0: |G|/‖∇G‖), with
    ∇G_j(z_u) = K^{-1/2} J_r(q_u)ᵀ H'_j exact (`pcc.tip_jacobian`). Valid on both sides of the
    boundary (a rest shape inside or beyond P). Tight near the boundary (the error is second
    order: ½ C_j d² against |G|, ≈ 1 % of d at d = 0.02 J^{1/2} on the reference arm), loose far
    from it (δ_j grows like √(2|G|/C_j)), where the table (`EscapeEnergyTable`, N ≤ 2) is the
    better bound; the energy governor's contact certificate takes the larger of the two. A row
    out of the arm's reach (‖H'_j‖ Σ L_i < h'_j) has +inf, as in the table.
    tests/test_escape_energy_bound.py checks C_j against finite differences of the kinematics and
    δ_j against a brute-force minimum over the boundary.
    """

    def __init__(self, robot: RobotParams, safe_set: ForceSafeSet) -> None:
        self.lengths = robot.array("lengths")
        stiffness = robot.array("stiffness")
        self.static_gain = robot.array("gains") / stiffness  # K⁻¹Λ, rad/hPa
        self.inverse_root_k = 1.0 / np.sqrt(stiffness)
        self.H = np.array(safe_set.H_prime, dtype=float)
        self.h = np.array(safe_set.h_prime, dtype=float)
        norms = np.hypot(self.H[:, 0], self.H[:, 1])
        before = np.concatenate(([0.0], np.cumsum(1.0 / stiffness)[:-1]))  # Σ_{k<i} 1/k_k
        self.curvature = norms * float(np.sum(self.lengths * (before + 1.0 / (3.0 * stiffness))))  # C_j, m/J
        self.reachable = norms * float(np.sum(self.lengths)) >= self.h
        self.kernel_bound = np.stack((self.H[:, 0], self.H[:, 1], self.h, self.curvature,
                                      self.reachable.astype(float)), axis=1)  # (P', 5), `energy_kernels` layout

    def values(self, u) -> list[float]:
        """½ δ_j(u)² for every row j (J); u: (N,) hPa. Compiled (`controllers.energy.energy_kernels.bound_values`: the tip
        r and its Jacobian J_r from the kinematic kernel `pcc_model.kinematics_rows`, then the rows' arithmetic);
        the governor evaluates it inside its kernels."""
        return lower_bounds(u, None, self)


_NO_TABLE = (np.zeros((5, 1)), np.zeros((1, 1)))
"""`energy_kernels.escape_values`' table arguments where there is no table (never read)."""
_NO_BOUND = (np.zeros((1, 5)), np.zeros(1), np.zeros(1), np.zeros(1))
"""Its bound arguments where there is no second-order bound (never read)."""


def lookup_arguments(table: EscapeEnergyTable | None, bound: BoundaryDistanceBound | None,
                     below: float = 0.0) -> tuple:
    """The look-up's arguments of the compiled kernels (`energy_kernels.escape_values` after u, and every kernel
    that looks Γ̲ up): the table's (`EscapeEnergyTable.values`), the second-order bound's
    (`BoundaryDistanceBound.values`), or with both the larger of the two per row, the bound evaluated only where
    the table's least row value is below `below` (J; both are lower bounds of Γ^∂_j, so either is valid
    everywhere)."""
    if table is None:
        mode, table_arrays = energy_kernels.BOUND, _NO_TABLE
    else:
        mode = energy_kernels.TABLE if bound is None else energy_kernels.BOTH
        table_arrays = (table.kernel_table, table.distance)
    bound_arrays = _NO_BOUND if bound is None else (bound.kernel_bound, bound.lengths, bound.static_gain,
                                                    bound.inverse_root_k)
    return (mode, *table_arrays, *bound_arrays, float(below))


def lower_bounds(u, table: EscapeEnergyTable | None, bound: BoundaryDistanceBound | None,
                 below: float = 0.0) -> list[float]:
    """Γ̲_j(u) for every row j (J), u (N,) hPa (`lookup_arguments`): one compiled call
    (`controllers.energy.energy_kernels.escape_values`)."""
    return energy_kernels.escape_values(np.asarray(u, dtype=float), *lookup_arguments(table, bound, below)).tolist()
