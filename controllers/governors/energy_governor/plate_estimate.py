"""Online estimate of the plate's offset and stiffness from the arm's own deflection, with a certified set.

The true facet j pushes the tip back with f_j = s_j ψ(n_j) = s_j k₀ max(0, δ_j − o_j) (N): k₀ the model's
linear law ψ(n) = k₀ n (N/m, `LinearStiffness`), s_j its unknown stiffness ratio (1), o_j its unknown offset along
the facet's outward normal n̂_j (m, > 0: farther from the arm), δ_j = n̂_j·r − d_j the tip's penetration of the
model's (nominal) facet plane (m), r the tip (m). The contact certificate covers the prior box s ∈ [s_lo, s_hi],
o ∈ [o_lo, o_hi] (`stiffness_lo_ratio`, …, `plate_offset_hi_m`); this module narrows it per facet from rest
samples, where the arm is its own force sensor.

The force. At rest (the gain estimate's own rest test, `controllers.governors.energy_governor.gain_feedback`) the true arm,
of stiffness cK and actuator gain gΛ (g, c unknown scales), balances cKq = gΛp − J_r(q)ᵀn̂_j F + (M q̈ + (C + D)q̇
terms), F ≥ 0 the facet's normal force on the tip (N), so in the gain estimate's K-normalised form
(`controllers.governors.gain_estimate`, "in contact"; y the sample's residual, x = K⁻¹Λp its model rest shape, rad)

    c y = g x − F K⁻¹T + c δ,      T = J_r(q̂)ᵀn̂_j (N·m/N = m, the torque per newton), |δ_i| ≤ Δ + ε_i,

δ the estimate's error, the residual motion and the force's direction error (the gain estimate's Δ and, for an
averaged window, its noise bound ε_i). Projecting on T (Tᵀ K⁻¹T > 0) eliminates everything but F:

    F = (g Tᵀx − c Tᵀy + c Tᵀδ) / TᵀK⁻¹T,     |Tᵀδ| ≤ η = Σ_i |T_i| (Δ + ε_i)   (m·rad),

linear in (g, c) for each δ, so over the certified set of (g, c) (a convex polygon: the gain estimate's
`GainEnds.corners`) F's least and greatest values are at its vertices:

    f_lo = min_v (g_v Tᵀx − c_v (Tᵀy + η)) / TᵀK⁻¹T,    f_hi = max_v (g_v Tᵀx − c_v (Tᵀy − η)) / TᵀK⁻¹T   (N),

F ∈ [f_lo, f_hi] under the gain estimate's assumptions (its (1)–(4): the estimate within Δ, one gain and one
stiffness scale for every segment, no force on the arm but at the tip along n̂_j: the one facet near the tip, the
others farther than the clearance; quasi-static rest). Tangential forces (friction, a tilting sheet) are not in T:
the certified set assumes a frictionless plate (`gain_contact` "normal").

The penetration. The true tip r(q) differs from the estimate's r(q̂) by at most Σ_i ℓ_i |q_i − q̂_i|, ℓ_i = Σ_{k≥i} L_k
(a segment's angle moves the arcs beyond it: ‖∂r/∂q_i‖ ≤ ℓ_i, `controllers.energy.escape_energy`, step 3), so with the
estimate within Δ + ε_i per segment δ_j ∈ [δ̂_j − m, δ̂_j + m], m = Σ_i ℓ_i (Δ + ε_i) (m).

The set. Write v = 1/s (the compliance ratio): the law reads f = max(0, δ − o) k₀ / v. Each sample gives two
linear constraints on (v, o) (m, with v > 0):

    f ≤ f_hi:         δ_lo − o ≤ f_hi v / k₀      (where δ ≤ o it holds at once; f_hi < 0 contradicts f ≥ 0),
    f ≥ f_lo (> 0):   o + f_lo v / k₀ ≤ δ_hi     (contact: δ > o and δ − o ≥ f_lo v/k₀; none where f_lo ≤ 0).

The first is also the no-contact bound: a tip at δ_lo with f_hi ≈ 0 has the plate at o ≥ δ_lo − f_hi v/k₀. Each
facet's certified set is the prior box [1/s_hi, 1/s_lo] × [o_lo, o_hi] cut by every sample's half-planes: a convex
polygon (`clip`, Sutherland–Hodgman on the vertex list, ≤ 4 + 2S vertices), containing the true (v_j, o_j) whenever
every sample's intervals hold, and only shrinking. An empty polygon proves an assumption false: the estimate then
returns the prior for good (`inconsistent`, as the gain estimate; `prior` starts afresh).

What the certificate reads (`certified_box`). Force-safe on every plate of facet j's set means f ≤ F_max wherever
the tip may go, i.e. δ_j ≤ b_j = min over the polygon of o + F_max v / k₀ (linear: a vertex); with the hull over the
facets (lo = min 1/v, hi = max 1/v, o ∈ [o_lo', o_hi'], b = min_j b_j; every facet's set lies in it) the contact
certificate's plate terms hold unchanged with P's boundary `reach` = b − o_lo' beyond the nearest plane
(`controllers.governors.energy_governor.plate_certificate`, "learned plate"). The prior box gives b = o_lo + F_max/(s_hi k₀),
today's P; a sample pressing with f at δ gives b ≈ δ + (F_max − f_hi)/(s_hi' k₀): the boundary moves out to
where the proven force would reach F_max.

The credit. The contact certificate's own-facet term (`controllers.governors.energy_governor.plate_certificate`, (b) and
"plate offset") is the energy the true plate stores between the tip at x̂ and P's boundary b: for the plate (s, o),
exact for the linear law, s (E(b − o) − E(max(0, δ − o))) (J; the exit at b penetrates it by b − o, where its force
is ≤ F_max by b's definition). The hull's worst case takes the softest s and the farthest o together, but a sample
pressing with f at δ leaves only the plates along o + f v/k₀ ≈ δ, where the soft plates are the near ones: the
least credit over the polygon itself (`least_credit`) is larger. On that line, at the sample's own δ, the credit is
½k₀(b − δ)²/v + f (b − δ), least at the largest v: the first-order term f (b − δ) is the energy the arm's force f
would release moving to b, which the hull's 0.8·½k₀(b − δ)(b + δ − 2 o_hi) ≈ 0.67 f (b − δ) does not match, so
the margin at rest against the plate, ≈ −f (b − δ) + credit + ½ k_arm (b − δ)², stays negative until b − δ is
large (measured: the hull stopped the nominal push 1.7 mm short of b, at 0.76 F_max).

Assumptions added to the gain estimate's: the plate's law is linear in the penetration and its stiffness and
offset constant (a clamped sheet, whose stiffness varies along it, breaks the first: `stiffness_by_position` is
refused with the estimate); the contact is frictionless; the estimate's q̂ is within Δ + ε_i of the arm's q per
segment (Δ bounds the whole residual, so also its position part). State: `PlateEstimate`, frozen, one per
simulation row; `add_sample` returns the next one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

ROUNDING = 1e-12
"""Relative slack on the force interval (1): its sums' round-off (relative 1e-16 per operation), so that the worst
case, where the bound is exact (e.g. F = 0 at the error's corner), does not read as contact by an ulp."""

ROUNDING_M = 1e-12
"""Slack (m) on each half-plane's right side: the sample's arithmetic round-off (relative 1e-16 of terms ≲ 1 m·N),
so that a plate exactly on a constraint's line is not cut away by an ulp."""


@dataclass(frozen=True)
class PlateEstimate:
    """The certified (v, o) polygon of each facet (tuple of (V, 2) arrays: v = 1/s, o in m), the prior's, the
    samples taken, and whether the samples contradicted each other (then `polygons` is the prior)."""

    polygons: tuple
    prior_polygons: tuple
    samples: int = 0
    inconsistent: bool = False


def prior_estimate(n_facets: int, stiffness: tuple[float, float], offset: tuple[float, float]) -> PlateEstimate:
    """The prior: every facet's box v ∈ [1/s_hi, 1/s_lo], o ∈ [o_lo, o_hi] (stiffness ratios > 0, offsets m)."""
    (s_lo, s_hi), (o_lo, o_hi) = stiffness, offset
    if not (0.0 < s_lo <= s_hi < math.inf and o_lo <= o_hi):
        raise ValueError(f"the plate prior needs 0 < s_lo <= s_hi < inf and o_lo <= o_hi, got [{s_lo!r}, {s_hi!r}], "
                         f"[{o_lo!r}, {o_hi!r}]")
    box = np.array([[1.0 / s_hi, o_lo], [1.0 / s_lo, o_lo], [1.0 / s_lo, o_hi], [1.0 / s_hi, o_hi]])
    polygons = tuple(box.copy() for _ in range(n_facets))
    return PlateEstimate(polygons, polygons)


def clip(polygon: np.ndarray, a: float, b: float, c: float) -> np.ndarray:
    """The convex polygon (V, 2) cut to the half-plane a v + b o ≤ c (Sutherland–Hodgman): (V', 2), V' = 0 when
    empty."""
    if len(polygon) == 0:
        return polygon
    side = polygon @ np.array([a, b]) - c  # ≤ 0 inside
    out = []
    for i in range(len(polygon)):
        p, q, sp, sq = polygon[i], polygon[(i + 1) % len(polygon)], side[i], side[(i + 1) % len(polygon)]
        if sp <= 0.0:
            out.append(p)
        if (sp < 0.0 < sq) or (sq < 0.0 < sp):
            out.append(p + (q - p) * (sp / (sp - sq)))
    return np.array(out, dtype=float).reshape(-1, 2)


def contact_force(torque, stiffness, x, y, corners, noise) -> tuple[float, float]:
    """[f_lo, f_hi] (N) of the facet's normal force at a rest sample (module docstring, "the force"): torque
    T = J_r(q̂)ᵀn̂ (N,) m, stiffness K (N,) N·m/rad, x = K⁻¹Λp and y the residual (N,) rad, corners the certified
    (g, c) vertices, noise Δ + ε_i (N,) rad."""
    torque, k = np.asarray(torque, dtype=float), np.asarray(stiffness, dtype=float)
    weight = float(np.sum(torque * torque / k))  # TᵀK⁻¹T (m²/(N·m))
    if not weight > 0.0:
        raise ValueError(f"the force's torque J_r(q)ᵀn̂ must be nonzero, got {torque.tolist()}")
    tx, ty = float(torque @ np.asarray(x, dtype=float)), float(torque @ np.asarray(y, dtype=float))
    eta = float(np.sum(np.abs(torque) * np.asarray(noise, dtype=float)))
    low = min(g * tx - c * (ty + eta) for g, c in corners)
    high = max(g * tx - c * (ty - eta) for g, c in corners)
    slack = ROUNDING * max(abs(g * tx) + c * (abs(ty) + eta) for g, c in corners)  # the sums' round-off
    return (low - slack) / weight, (high + slack) / weight


def depth_margin(lengths, noise) -> float:
    """m = Σ_i ℓ_i (Δ + ε_i) (m), ℓ_i = Σ_{k≥i} L_k: the tip's error bound from the estimate's (module docstring)."""
    beyond = np.cumsum(np.asarray(lengths, dtype=float)[::-1])[::-1]
    return float(beyond @ np.asarray(noise, dtype=float))


def add_sample(estimate: PlateEstimate, facet: int, depth: tuple[float, float], force: tuple[float, float],
               psi_k: float) -> PlateEstimate:
    """The estimate with facet `facet`'s sample: its penetration interval [δ_lo, δ_hi] (m) of the model's facet
    plane and normal force interval [f_lo, f_hi] (N), ψ = k₀ n (`psi_k` N/m); module docstring, "the set"."""
    if estimate.inconsistent:
        return estimate
    (d_lo, d_hi), (f_lo, f_hi) = depth, force
    polygon = estimate.polygons[facet]
    if f_hi < 0.0:
        polygon = polygon[:0]
    else:  # −o − (f_hi/k₀) v ≤ −δ_lo
        polygon = clip(polygon, -f_hi / psi_k, -1.0, -d_lo + ROUNDING_M)
        if f_lo > 0.0:  # (f_lo/k₀) v + o ≤ δ_hi
            polygon = clip(polygon, f_lo / psi_k, 1.0, d_hi + ROUNDING_M)
    if len(polygon) == 0:
        return PlateEstimate(estimate.prior_polygons, estimate.prior_polygons, estimate.samples + 1, True)
    polygons = estimate.polygons[:facet] + (polygon,) + estimate.polygons[facet + 1:]
    return PlateEstimate(polygons, estimate.prior_polygons, estimate.samples + 1, False)


@dataclass(frozen=True)
class PlateBox:
    """The hull of the certified plates (module docstring, "what the certificate reads"): stiffness ratios [lo, hi]
    (1), offsets [offset_lo, offset_lo + width] (m), and P's boundary `reach` (m) beyond the nearest plane."""

    lo: float
    hi: float
    offset_lo: float
    width: float
    reach: float


def certified_box(estimate: PlateEstimate, f_max: float, psi_k: float) -> PlateBox:
    """The hull of every facet's polygon and the force-safe boundary b = min_j min_vertices (o + F_max v/k₀):
    reach = b − offset_lo (m)."""
    vertices = np.concatenate(estimate.polygons)
    offset_lo = float(vertices[:, 1].min())
    boundary = min(float(np.min(p[:, 1] + (f_max / psi_k) * p[:, 0])) for p in estimate.polygons)
    return PlateBox(1.0 / float(vertices[:, 0].max()), 1.0 / float(vertices[:, 0].min()), offset_lo,
                    float(vertices[:, 1].max()) - offset_lo, boundary - offset_lo)


CREDIT_PIECES = 16
"""Pieces per polygon edge of `least_credit`'s lower bound (each piece bounded over its bounding box)."""


def credit_pieces(polygon: np.ndarray, boundary: float, psi_k: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The pieces of the polygon's (V, 2) edges that `least_credit` bounds over, at P's boundary b = `boundary` (m):
    per piece (its bounding box [v₁, v₂] × [o₁, o₂]) the exit energy E(max(0, b − o₂))/v₂ (J), the weight ½ k₀/v₂
    (N/m) and o₂ (m), each (V·CREDIT_PIECES,): what a call needs, built once per certificate."""
    ends = np.roll(polygon, -1, axis=0)
    t = np.linspace(0.0, 1.0, CREDIT_PIECES + 1)[None, :, None]
    points = polygon[:, None, :] + (ends - polygon)[:, None, :] * t  # (V, pieces + 1, 2)
    v_most = np.maximum(points[:, :-1, 0], points[:, 1:, 0]).ravel()
    o_most = np.maximum(points[:, :-1, 1], points[:, 1:, 1]).ravel()
    weight = 0.5 * psi_k / v_most
    return weight * np.maximum(boundary - o_most, 0.0) ** 2, weight, o_most


def least_credit(pieces: tuple[np.ndarray, np.ndarray, np.ndarray], depth: float) -> float:
    """A lower bound (J) of the own facet's energy credit s (E(b − o) − E(max(0, δ − o))) over the plates (v = 1/s, o)
    of a convex polygon, E(n) = ½ k₀ n², from its `credit_pieces` at P's boundary b, δ = `depth` the tip's
    penetration of the model's facet plane (m, δ < b: the tip inside P). Module docstring, "the credit":
    h(o) = E(b − o) − E(max(0, δ − o)) ≥ 0 falls with o and 1/v with v, so the least value lies on the polygon's
    edges, and over each piece of an edge (inside its bounding box [v₁, v₂] × [o₁, o₂]) it is at least h(o₂)/v₂."""
    exit_energy, weight, offset = pieces
    return float(np.min(exit_energy - weight * np.maximum(depth - offset, 0.0) ** 2))
