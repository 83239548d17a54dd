"""The contact certificate's plate: P, its escape-energy bounds and the plate's energy terms, for a box of plates.

`PlateCertificate` is everything the certificate reads of the plate: the force-safe set P (built on the nearest
plate, its boundary `reach` beyond it), Γ̲^∂'s sources and their compiled look-up, the rows' credits c_j, the
recovery's grid, and the rows' offsets o_j at a state (`contact_offsets`). The governor's model holds the prior's
(`prior_plate`, from the parameters' intervals); with `plate_estimate` each state holds the one of the plates it
has learned (`learned_plate`, from `controllers.governors.energy_governor.plate_estimate.PlateBox`).

The plate. Two variants. Plain (`contact_aware` False): the environment does not push
back (the PCC plant, the paper's simulation); the certificate is (1 + κ)W_u(x̂) + ε ≤ Γ(u).
Contact-aware: a facet pushes back with force ψ_true(n) ∈ [lo·ψ(n), hi·ψ(n)]
(`stiffness_lo_ratio`, `stiffness_hi_ratio`); it stores E_true(n) = ∫₀ⁿ ψ_true with
lo·E(n) ≤ E_true(n) ≤ hi·E(n) (E = `ψ.energy`), a conservative force, so W_u + E_true
never grows. Safety is F_true ≤ F_max, which holds if n ≤ n_max = ψ⁻¹(F_max/hi) (the
stiffest plate): P is built with that n_max whenever hi ≠ 1, in both variants. Leaving P
through facet j's row means n_j ≥ n_max, where the plate holds at least lo·E(n_max). So

    (1 + κ) [W_u(x̂) + hi Σ_facets E(n_i(x̂))] + ε ≤ min_j (Γ_j(u) + c_j),

c_j = lo·E(n_max) for facet rows, 0 for vertex-correction rows, implies
W_u + E_true ≤ Γ_j + c_j along the motion, hence the tip stays in P. The plain variant
is not sound where the plate pushes back while the tip is in contact (the plate's
stored energy can return to the arm), and the contact-aware one is not sound where the
plate does not push back (nothing stops the tip at n_max).

Plate offset (`plate_offset_lo_m` ≤ `plate_offset_hi_m`, m; contact certificate only; default 0, 0: the model's
plate, the commands bit for bit those without it). The true facet i lies s_i farther than the model's along its
outward normal, s_i ∈ [s_lo, s_hi] independently per facet (< 0: nearer the arm): n̂_i·r ≤ d_i + s_i is free space
and the true penetration is n_i^s(r) = max(0, n̂_i·r − d_i − s_i). The force-safe set of a plate s,
P_s = {n̂_i·r ≤ d_i + s_i + n_max ∀i} (and its vertex rows), grows with every s_i, so P_near = P_{s_lo} (the nearest
plate, n_max = ψ⁻¹(F_max/hi)) lies inside every P_s: staying in P_near is force-safe for every plate of the box,
and P, Γ̲^∂ and the table are built on P_near (`nearest_environment`). The energy argument (b) holds for each
plate s with its own stored energy: V_s = W_u + Σ_i E_true,i(n_i^s) never grows. Write ν_i = n_i^{s_lo}(r̂) (m, the
nearest plate's penetration at x̂), t_i = s_i − s_lo ∈ [0, w], w = s_hi − s_lo. Where the tip first leaves P_near
through facet row j, n_j^s = n_max − t_j, so V_s ≥ Γ^∂_j(u) + lo·E(n_max − t_j); at x̂ (strictly inside P_near)
n_j^s(r̂) = max(0, ν_j − t_j) < n_max − t_j, and V_s(x̂) < Γ^∂_j + E_true,j(n_max − t_j) follows from
    W_u(x̂) + hi Σ_{i≠j} E(max(0, ν_i − t_i)) < Γ^∂_j(u) + lo (E(n_max − t_j) − E(max(0, ν_j − t_j))).
The right side's bracket falls with t_j (d/dt = ψ(ν_j − t_j) − ψ(n_max − t_j) ≤ 0, ψ increasing, ν_j < n_max;
where ν_j − t_j ≤ 0 it is E(n_max − t_j) alone, also falling) and the left side's sum with each t_i, so every
plate of the box is certified by the worst of each, t_j = w on the facet's own row and t_i = 0 on the others:
    o_j = lo (E(max(0, n_max − w)) − E(max(0, ν_j − w))) − hi Σ_{i≠j} E(ν_i)      (facet row j),
    o_j = −hi Σ_i E(ν_i)                                                          (vertex-correction row),
(b)'s offsets at w = 0 (the credit c_j = lo·E(max(0, n_max − w)): `GovernorModel.build`, `contact_offsets`;
tests/test_certificate_box.py checks the worst t by brute force and the forks on the PCC plant). What it costs: the
farthest plate stores only E(n_max − w) where the tip leaves P_near: with n_max = 11.9 mm (hi = 1.2) and w = 4 mm,
(7.9/11.9)² = 44 % of the credit the exact plate gives, and P_near is 2 mm smaller. Assumptions added: the plate
moves along its normal only (a turned plate, `facet_angle`, is not covered) and not during the run; the state
predictor's plate is the model's (an estimate error over the prediction span, left to κ); the gain estimate's
clearance test (`gain_clearance_m`) uses the nearest plate's planes.

Sheet (`stiffness_by_position`; contact certificate, contact-aware; default off). A clamped sheet's stiffness
depends on where it is touched (`softcbf_mj.physics.flexure`: K(s) = 3EI/s³ at distance s from the clamp, calibrated at
its free end ℓ: K(s) = k (ℓ/s)³), so the plate's stored energy is E_true(r) = ½K(s(r)) n(r)² (small deflection, n
the penetration of the undeformed sheet's line, s from the tip's position along it): a conservative field (the
beam's elastic energy) whose force is not purely normal (its tangential part, −½K'(s)n², is 1.5 n/s of the normal
one: ≈ 1.5 % at n = 12 mm, s = 0.12 m, which F_max's n_max does not cover). With [lo, hi] bounding K(s)/k over
the contact positions (`cantilever_stiffness_ratios`), lo E(n) ≤ E_true ≤ hi E(n) still holds pointwise, but (b)'s
"lo on the difference only" does not: x̂ and the exit may touch the sheet at different s. Bounding each end
alone, E_true,j(exit) ≥ lo E(n_max − w) and E_true,j(x̂) ≤ hi E(ν_j) (E falls with the offset t ∈ [0, w]), gives
    o_j = lo E(max(0, n_max − w)) − hi Σ_i E(ν_i)      (facet row j),
the parked certificate's credit per row: sound for any law ψ and any variation along the sheet within [lo, hi],
and (hi − lo) E at the plate dearer than (b). Safety: F = K(s)n ≤ F_max where n ≤ n_max = ψ⁻¹(F_max/hi).


Learned plate (`plate_estimate`; `controllers.governors.energy_governor.plate_estimate`). The estimate certifies a hull of
plates: stiffness ratios [lo', hi'], offsets [o_lo', o_lo' + w'], and a boundary b ≥ every plate's force-safe
penetration min (o + F_max v/k₀) of the nominal plane; P is then built on the plate o_lo' with its boundary
reach = b − o_lo' beyond it (`learned_plate`: n_max = reach, whatever F_max/hi' gives). The offset argument above
holds with reach in place of n_max: where the tip first leaves P through facet row j, a plate of the set with
t_j = o_j − o_lo' is penetrated by reach − t_j, where its force is at most F_max (b's definition), and its energy
is at least lo' E(reach − t_j); the bracket falls with t_j as before (ν_j < reach inside P). So
    o_j = lo' (E(max(0, reach − w')) − E(max(0, ν_j − w'))) − hi' Σ_{i≠j} E(ν_i),
today's offsets with (lo', hi', w', reach); the own facet's term is then taken tighter, as the least over the
facet's learned polygon of the plate's own energy between x̂ and the boundary (`plate_estimate.least_credit`, its
"credit": for each plate (s, o) of the set, V_s < Γ^∂_j + s E(b − o) at the exit, exact for the linear law,
with no need of the hull's worst-of-each), the other facets' terms and the vertex rows the hull's. Γ̲^∂ of the learned P is the second-order bound alone
(`BoundaryDistanceBound`, built in microseconds; the table would take seconds per P), and the recovery's
candidates are u_prev, u_nom and 0 hPa (as for N > 2). Each learned set lies in the prior, so b only grows and P
only widens (the prior's P lies inside every learned one); a certificate issued on any of them holds for the true
plate, which lies in each.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from controllers.energy.escape_energy import BoundaryDistanceBound, EscapeEnergyTable, lookup_arguments
from controllers.governors.energy_governor.parameters import GovernorParams
from controllers.governors.energy_governor.plate_estimate import PlateBox, credit_pieces, least_credit
from controllers.model.pcc import kinematics_unchecked
from controllers.model.safe_set import Environment, ForceSafeSet
from controllers.contract.safety_filter import FilterContext

BOUND_BELOW_J = 0.02
"""The contact certificate evaluates the second-order boundary bound only where the table's least row value is
below this (J): near the boundary, where the table is loose; beyond ≈ 0.01 J the table is the larger (measured
on the reference arm: 1.46e-2 against 1.15e-2 J at (32, 69) hPa, 0.10 against 0.057 J at rest), and the
bound's kinematics cost more than the table's look-up."""


def cantilever_stiffness_ratios(length_m: float, nearest_m: float, farthest_m: float) -> tuple[float, float]:
    """[lo, hi] of a clamped sheet's stiffness over its contact positions as multiples of its calibrated one (1):
    Euler–Bernoulli K(s) = 3EI/s³ calibrated at the free end s = ℓ = `length_m` (as the paper calibrated), touched
    between `nearest_m` and `farthest_m` from the clamp (m, 0 < nearest ≤ farthest): ((ℓ/farthest)³, (ℓ/nearest)³)
    (module docstring, "sheet"). The flexure plate's default (ℓ = 0.15 m, touched 10–33 mm from its free end, 0.117
    to 0.140 m from the clamp) gives [1.23, 2.11]."""
    if not 0.0 < nearest_m <= farthest_m < math.inf or not 0.0 < length_m < math.inf:
        raise ValueError(f"need 0 < nearest_m <= farthest_m and length_m > 0 (m), got length_m = {length_m!r}, "
                         f"nearest_m = {nearest_m!r}, farthest_m = {farthest_m!r}")
    return (length_m / farthest_m) ** 3, (length_m / nearest_m) ** 3


def nearest_environment(environment: Environment, offset_m: float) -> Environment:
    """The environment with every facet moved `offset_m` (m) along its outward normal (< 0: nearer the arm);
    itself at 0. ValueError (naming the offset) where a facet then no longer bounds free space."""
    if offset_m == 0.0:
        return environment
    H = np.asarray(environment.H, dtype=float)
    try:
        return Environment(H, np.asarray(environment.h, dtype=float) + offset_m * np.hypot(H[:, 0], H[:, 1]))
    except ValueError as exc:
        raise ValueError(f"plate_offset_lo_m = {offset_m!r} m moves the plate's facets so that {exc}") from exc


def tip_of(lengths: np.ndarray, q) -> tuple[float, float]:
    """The model's tip r(q) (m) as Python floats."""
    tip = kinematics_unchecked(np.asarray(q, dtype=float), lengths, 0).points[-1]
    return tip.real, tip.imag


def rest_shape_inside(lengths: np.ndarray, a: list, rows: list, u) -> bool:
    """Whether the rest shape q_u = K⁻¹Λu (a = K⁻¹Λ per segment) of the command u (N,) hPa puts the tip strictly
    inside P (`rows`: (h'x, h'y, h') per row)."""
    x, y = tip_of(lengths, np.array(a) * np.asarray(u, dtype=float))
    return all(hx * x + hy * y < h for hx, hy, h in rows)


@dataclass(frozen=True, eq=False)
class PlateCertificate:
    """What the certificate reads of a box of plates (module docstring). box: the plates' hull (`PlateBox`);
    safe_set: P on the nearest plate; rows: P's rows (h'x, h'y, h'); facets: the nearest plate's (nx, ny, d);
    credit: c_j per row (J); n_facets; weight: the own facet's energy weight (lo, or hi for a sheet) and
    own_shift: the offset width w subtracted from the own facet's penetration (0 for a sheet or w = 0);
    contact_aware; table / boundary_bound: Γ̲'s sources; lookup: the kernels' look-up of them; grid /
    grid_values / grid_rest_inside / grid_columns: the recovery's candidates (G, N), their Γ̲ rows (P', G), whether
    their rest shapes lie inside P, and the commands as (N, G); pieces: a learned plate's `credit_pieces` per facet (None:
    the hull's credit)."""

    box: PlateBox
    safe_set: ForceSafeSet
    rows: list
    facets: list
    credit: list
    n_facets: int
    weight: float
    own_shift: float
    contact_aware: bool
    table: EscapeEnergyTable | None
    boundary_bound: BoundaryDistanceBound | None
    lookup: tuple
    grid: np.ndarray
    grid_values: np.ndarray
    grid_rest_inside: np.ndarray
    grid_columns: np.ndarray
    pieces: tuple | None = None

    def contact_offsets(self, x: float, y: float) -> tuple[list[float], bool]:
        """The rows' offsets o_j (J) at the tip r = (x, y) (m) and whether it lies strictly inside P (every row
        H'_j r < h'_j). Facet row j: o_j = lo·(E(reach − w) − E(n_j − w)) − hi Σ_{i≠j} E(n_i) (a sheet: lo·E(reach
        − w) − hi Σ_i E(n_i)); vertex-correction row: o_j = −hi Σ_i E(n_i); n_i the nearest plate's penetrations at
        r (m), E = ψ.energy (0 below 0). Without contact_aware every o_j = 0 (the environment does not push back)."""
        inside = all(hx * x + hy * y < h for hx, hy, h in self.rows)
        if not self.contact_aware:
            return [0.0] * len(self.rows), inside
        plate, hi = self.safe_set, self.box.hi
        depths = plate.penetration_at(x, y)
        energies = np.asarray(plate.stiffness.energy(depths), dtype=float).tolist()
        if self.pieces is not None:  # a learned plate: the own facet's least credit over its polygon
            shift, total = self.box.offset_lo, hi * sum(energies)
            own = [least_credit(pieces, nx * x + ny * y - d + shift) for pieces, (nx, ny, d) in zip(self.pieces,
                                                                                                   self.facets)]
            return [own[j] - hi * (sum(energies) - energies[j]) if j < self.n_facets else -total
                    for j in range(len(self.rows))], inside
        own = energies if self.own_shift == 0.0 else \
            np.asarray(plate.stiffness.energy(np.asarray(depths) - self.own_shift), dtype=float).tolist()
        total = hi * sum(energies)
        offsets = [credit - self.weight * f - hi * (sum(energies) - e) if j < self.n_facets
                   else -total for j, (credit, e, f) in enumerate(zip(self.credit, energies + [0.0] * len(self.rows),
                                                                      own + [0.0] * len(self.rows)))]
        return offsets, inside

    def grid_rows_at_gain(self, gain: float) -> np.ndarray:
        """Lower bounds of Γ^∂_j(g·u_c) (J) for the recovery's grid commands u_c under the gain g: (P', G).

        g = 1: the table's values. Else, from (*) of `controllers.energy.escape_energy` (the distance to the boundary
        is 1-Lipschitz in z = K^{1/2}q and z moves by |g − 1| ‖u_c‖_w from u_c to g·u_c, w_i = λ_i²/k_i):
        d_j(g u_c) ≥ d̲_j(u_c) − |g − 1| ‖u_c‖_w, Γ ≥ ½ max(0, ·)². Without a table (N > 2, a learned plate) the
        grid's commands are bounded at g·u_c directly (`BoundaryDistanceBound`)."""
        if gain == 1.0:
            return self.grid_values
        if self.table is None:
            return np.array([self.boundary_bound.values(gain * c) for c in self.grid]).T
        shift = abs(gain - 1.0) * np.sqrt(np.sum(self.table.weights * self.grid**2, axis=1))  # (G,) J^{1/2}
        return 0.5 * np.maximum(self.table.distance - shift, 0.0) ** 2


def plate_certificate(params: GovernorParams, context: FilterContext, box: PlateBox, safe_set: ForceSafeSet,
                      gridded: bool, rest: np.ndarray) -> PlateCertificate:
    """The plate certificate of `box` on P = `safe_set` (module docstring): the table only where `gridded` (the
    prior's, N ≤ 2), else the recovery's one grid command `rest` (0 hPa clipped to the box)."""
    robot, contact = context.robot, params.contact
    law = context.safe_set.stiffness
    u_lo = robot.array("u_min") if context.u_min is None else context.u_min
    u_hi = robot.array("u_max") if context.u_max is None else context.u_max
    table = EscapeEnergyTable(robot, safe_set, u_lo, u_hi, grid_hPa=params.grid_hPa, boundary=contact,
                              q_spacing_rad=params.escape_spacing_rad) if gridded else None
    boundary_bound = BoundaryDistanceBound(robot, safe_set) if contact else None
    width = box.width
    reach = box.reach if width == 0.0 else max(box.reach - width, 0.0)  # the farthest plate's at P's edge
    credit = box.lo * float(law.energy(reach)) if params.contact_aware else 0.0
    rows = [(hx, hy, h) for (hx, hy), h in zip(np.asarray(safe_set.H_prime).tolist(),
                                               np.asarray(safe_set.h_prime).tolist())]
    near = safe_set.environment
    facets = [(nx, ny, d) for (nx, ny), d in zip(near.normals.tolist(), near.offsets.tolist())]
    if table is None:  # N > 2 or a learned plate: the recovery's candidates are u_prev, u_nom and 0 hPa
        grid = np.array([rest.tolist()])
        grid_values = np.array([boundary_bound.values(grid[0].tolist())]).T
        a = (robot.array("gains") / robot.array("stiffness")).tolist()
        grid_rest_inside = np.array([rest_shape_inside(robot.array("lengths"), a, rows, grid[0])])
    else:
        grid, grid_values, grid_rest_inside = table.grid_commands(), table.grid_values(), table.rest_inside
    by_position = params.stiffness_by_position
    return PlateCertificate(box=box, safe_set=safe_set, rows=rows, facets=facets,
                            credit=[0.0 if corner else credit for corner in safe_set.is_vertex_correction.tolist()],
                            n_facets=context.safe_set.n_facets, weight=box.hi if by_position else box.lo,
                            own_shift=0.0 if by_position else width, contact_aware=params.contact_aware,
                            table=table, boundary_bound=boundary_bound,
                            lookup=lookup_arguments(table, boundary_bound, BOUND_BELOW_J), grid=grid,
                            grid_values=grid_values, grid_rest_inside=grid_rest_inside,
                            grid_columns=np.ascontiguousarray(grid.T))


def prior_plate(params: GovernorParams, context: FilterContext, gridded: bool, rest: np.ndarray) -> PlateCertificate:
    """The plate certificate of the parameters' intervals: P on the nearest plate with n_max = ψ⁻¹(F_max/hi) (the
    context's own P when both are the model's)."""
    nominal, hi = context.safe_set, params.stiffness_hi_ratio
    near = nearest_environment(nominal.environment, params.plate_offset_lo_m)
    safe_set = nominal if hi == 1.0 and near is nominal.environment else \
        ForceSafeSet(near, nominal.stiffness, nominal.f_max / hi, nominal.row_scaling)
    box = PlateBox(params.stiffness_lo_ratio, hi, params.plate_offset_lo_m,
                   params.plate_offset_hi_m - params.plate_offset_lo_m, safe_set.n_max)
    return plate_certificate(params, context, box, safe_set, gridded, rest)


def learned_plate(params: GovernorParams, context: FilterContext, box: PlateBox, polygons: tuple,
                  rest: np.ndarray) -> PlateCertificate:
    """The plate certificate of a learned set (module docstring, "learned plate"): P on the plate box.offset_lo
    with its boundary box.reach beyond it (n_max = reach, by F_max' = ψ(reach) less a relative 1e-12 of
    rounding), Γ̲^∂ the second-order bound alone, the own facet's credit the least over its (v, o) polygon."""
    nominal = context.safe_set
    near = nearest_environment(nominal.environment, box.offset_lo)
    f_reach = float(nominal.stiffness.force(box.reach)) * (1.0 - 1e-12)
    safe_set = ForceSafeSet(near, nominal.stiffness, f_reach, nominal.row_scaling)
    certificate = plate_certificate(params, context, PlateBox(box.lo, box.hi, box.offset_lo, box.width,
                                                              safe_set.n_max), safe_set, False, rest)
    boundary = box.offset_lo + safe_set.n_max
    return replace(certificate, pieces=tuple(credit_pieces(polygon, boundary, float(nominal.stiffness.k))
                                             for polygon in polygons))
