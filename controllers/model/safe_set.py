"""Force-safe set P of a deformable planar environment (docs/model.md#force-safe-set, paper §III).

Shapes and units (SI; positions in m, forces in N):

- Free space N = {r ∈ R² | H r ≤ h}, H (P, 2), h (P,): one row per facet (a wall the
  tip may touch). Row i's outward unit normal is n̂_i = H_iᵀ/‖H_i‖ and its signed
  offset d_i = h_i/‖H_i‖ (m), so the facet line is L_i = {r | n̂_i·r = d_i}.
  Rows may have any scale and may be vertical (H_i = [a, 0]).
- Facet i deforms only along n̂_i. Penetration n_i(r) = max(0, n̂_i·r − d_i) (m);
  contact force magnitude F_i = ψ(n_i) (N) with ψ strictly increasing, ψ(0) = 0
  (`LinearStiffness`, `PowerLawStiffness`). Force limit F_max (N) per facet, so
  n_max = ψ⁻¹(F_max) (m).
- Lemma 1 (general form): each facet moves out by n_max,
  H_i r ≤ h_i + n_max ‖H_i‖   ⇔   n̂_i·r ≤ d_i + n_max.
  In the paper's slope-intercept form H_i = [−m_i, 1] this is h'_i = h_i + n_max √(m_i²+1).
- Vertex correction: at each vertex c of N where facets i and j meet, add the half-plane
  whose boundary passes through c + n_max n̂_i and c + n_max n̂_j on the side of N:
  m̂·r ≤ m̂·c + n_max m̂·n̂_i with m̂ = (n̂_i + n̂_j)/‖n̂_i + n̂_j‖ (the bisector of the
  normal cone at c; m̂·n̂_i = m̂·n̂_j = cos(θ_ij/2)). Inside that cone the Lemma rows and
  this row leave the triangle {c, c + n_max n̂_i, c + n_max n̂_j}; on a facet's interior
  the distance to N is n̂_i·r − d_i ≤ n_max. Hence every point of P lies within n_max of N.
- P = {r | H' r ≤ h'}, H' (P', 2), h' (P',), P' = P + (number of vertices): the P Lemma
  rows in facet order, then one correction row per vertex in `Environment.vertices` order.

Row scaling of (H', h') — it sets the scale (and units) of the barrier b = h' − H' r
downstream (docs/model.md#control-barrier-function), so it is a required, explicit choice:
- "paper": each row divided by |H'_i[1]| so its second column is ±1 (the paper's
  slope-intercept form; b is a vertical distance in m). Rows within 1e-9 rad of vertical
  (|H'_i[1]| ≤ 1e-9 ‖H'_i‖), where that form does not exist, are scaled to unit norm instead.
- "unit": every row has unit norm (b is the Euclidean distance to the row's line, m).

Geometric validation (the paper's assumption 1: no redundant facets): every facet must
touch N along a segment longer than 1e-9 m; duplicate facets, an empty N and a zero-width
slab between two opposite facets are rejected with the facets named.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal, Protocol, get_args

import numpy as np
from numpy.typing import ArrayLike

from controllers.core.errors import as_real
from controllers.model.paper_experiment import PAPER_F_MAX, PAPER_PLATE_STIFFNESS

RowScaling = Literal["paper", "unit"]

GEOMETRY_TOL_M = 1e-9
"""Lengths (m) below this count as zero: facet segments, slab widths, duplicate offsets."""

_PARALLEL_TOL = 1e-12
"""|sin| of the angle between two unit normals below which the facets count as parallel."""

_VERTICAL_TOL = 1e-9
"""'paper' scaling falls back to unit norm where |H'_i[1]| ≤ this × ‖H'_i‖."""


def _positive_finite(name: str, value: float) -> float:
    value = as_real(name, value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be finite and > 0, got {value}")
    return value


class StiffnessLaw(Protocol):
    """Force–penetration law ψ of a facet, vectorised over numpy arrays.

    `force(n)`: F = ψ(n) in N for penetration n in m (ψ = 0 for n ≤ 0).
    `penetration(F)`: n = ψ⁻¹(F) in m (0 for F ≤ 0). NaN propagates.
    The built-in laws also give `energy(n)`: E(n) = ∫₀ⁿ ψ(s) ds in J, the energy the
    facet stores at penetration n (0 for n ≤ 0); the energy governor's contact-aware
    certificate needs it, other code does not.
    """

    def force(self, n: ArrayLike) -> np.ndarray: ...

    def penetration(self, force: ArrayLike) -> np.ndarray: ...


@dataclass(frozen=True)
class LinearStiffness:
    """ψ(n) = k n, k in N/m (the paper's plate: k = 11.16 N/m)."""

    k: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "k", _positive_finite("k", self.k))

    def force(self, n: ArrayLike) -> np.ndarray:
        return self.k * np.maximum(np.asarray(n, dtype=float), 0.0)

    def penetration(self, force: ArrayLike) -> np.ndarray:
        return np.maximum(np.asarray(force, dtype=float), 0.0) / self.k

    def energy(self, n: ArrayLike) -> np.ndarray:
        """E(n) = ½ k n² (J) for n ≥ 0, else 0."""
        n = np.maximum(np.asarray(n, dtype=float), 0.0)
        return 0.5 * self.k * n * n


@dataclass(frozen=True)
class PowerLawStiffness:
    """ψ(n) = k n^p, k in N/m^p, p > 0 (p = 3/2: Hertz contact of a sphere on a flat)."""

    k: float
    exponent: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "k", _positive_finite("k", self.k))
        object.__setattr__(self, "exponent", _positive_finite("exponent", self.exponent))

    def force(self, n: ArrayLike) -> np.ndarray:
        return self.k * np.maximum(np.asarray(n, dtype=float), 0.0) ** self.exponent

    def penetration(self, force: ArrayLike) -> np.ndarray:
        return (np.maximum(np.asarray(force, dtype=float), 0.0) / self.k) ** (1.0 / self.exponent)

    def energy(self, n: ArrayLike) -> np.ndarray:
        """E(n) = k n^(p+1)/(p+1) (J) for n ≥ 0, else 0."""
        n = np.maximum(np.asarray(n, dtype=float), 0.0)
        return self.k * n ** (self.exponent + 1.0) / (self.exponent + 1.0)


def _frozen(a: np.ndarray) -> np.ndarray:
    a.setflags(write=False)
    return a


def _facet_segments(normals: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Vertices of N from each facet's segment L_i ∩ N; raises if a facet does not bound N.

    Facet i's line is r(s) = d_i n̂_i + s t_i with t_i = n̂_i rotated by +90°; facet j
    bounds s by (n̂_j·t_i) s ≤ d_j − d_i n̂_j·n̂_i. A finite end of the interval is a
    vertex shared with the facet that bounds it. Returns vertices (V, 2) and their
    facet pairs (V, 2) (i < j), sorted by pair.
    """
    p = len(offsets)
    for i in range(p):
        for j in range(i + 1, p):
            sin_ij = normals[i, 0] * normals[j, 1] - normals[i, 1] * normals[j, 0]
            if abs(sin_ij) > _PARALLEL_TOL:
                continue
            if normals[i] @ normals[j] > 0 and abs(offsets[i] - offsets[j]) <= GEOMETRY_TOL_M:
                raise ValueError(f"H rows {i} and {j} describe the same facet")
            if normals[i] @ normals[j] < 0 and abs(offsets[i] + offsets[j]) <= GEOMETRY_TOL_M:
                raise ValueError(f"facets {i} and {j} are opposite and coincide: free space has zero width")
    vertices: dict[tuple[int, int], np.ndarray] = {}
    untouched: list[str] = []
    for i in range(p):
        base = offsets[i] * normals[i]
        tangent = np.array([-normals[i, 1], normals[i, 0]])
        lo, hi, j_lo, j_hi = -math.inf, math.inf, -1, -1
        for j in range(p):
            if j == i:
                continue
            slope = normals[j] @ tangent
            room = offsets[j] - normals[j] @ base
            if abs(slope) <= _PARALLEL_TOL:
                if room < -GEOMETRY_TOL_M:
                    lo, hi = math.inf, -math.inf
                continue
            s = room / slope
            if slope > 0 and s < hi:
                hi, j_hi = s, j
            elif slope < 0 and s > lo:
                lo, j_lo = s, j
        if not hi - lo > GEOMETRY_TOL_M:
            untouched.append(f"facet {i} (touches N along {max(hi - lo, 0.0):.3g} m)")
            continue
        for s, j in ((lo, j_lo), (hi, j_hi)):
            if j >= 0:
                vertices.setdefault((min(i, j), max(i, j)), base + s * tangent)
    if len(untouched) == p:
        raise ValueError("free space N = {r | H r <= h} is empty or has no interior "
                         "(no facet bounds it along a segment)")
    if untouched:
        raise ValueError(f"redundant facet(s), remove them: {', '.join(untouched)} "
                         "(each facet must bound N along a segment)")
    pairs = sorted(vertices)
    return (np.array([vertices[k] for k in pairs], dtype=float).reshape(-1, 2),
            np.array(pairs, dtype=int).reshape(-1, 2))


@dataclass(frozen=True, eq=False)
class Environment:
    """Free space N = {r | H r ≤ h}: H (P, 2) (any row scale), h (P,) in m.

    Derived (read-only arrays): `normals` n̂ (P, 2), `offsets` d (P,) in m,
    `vertices` (V, 2) in m and `vertex_facets` (V, 2) — the two facets meeting at each
    vertex, i < j, sorted by pair.
    """

    H: np.ndarray
    h: np.ndarray
    normals: np.ndarray = field(init=False, repr=False)
    offsets: np.ndarray = field(init=False, repr=False)
    vertices: np.ndarray = field(init=False, repr=False)
    vertex_facets: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        H = np.array(self.H, dtype=float)
        h = np.array(self.h, dtype=float)
        if H.ndim != 2 or H.shape[1] != 2 or H.shape[0] < 1:
            raise ValueError(f"H must have shape (P, 2) with P >= 1, got {H.shape}")
        if h.shape != (H.shape[0],):
            raise ValueError(f"h must have shape (P,) = ({H.shape[0]},), got {h.shape}")
        for name, arr in (("H", H), ("h", h)):
            bad = np.argwhere(~np.isfinite(arr))
            if len(bad):
                index = ", ".join(str(k) for k in bad[0])
                raise ValueError(f"{name}[{index}] must be finite, got {arr[tuple(bad[0])]}")
        norms = np.hypot(H[:, 0], H[:, 1])
        for i, norm in enumerate(norms):
            if norm == 0.0:
                raise ValueError(f"H row {i} is zero")
        normals = H / norms[:, None]
        offsets = h / norms
        vertices, pairs = _facet_segments(normals, offsets)
        for name, value in (("H", H), ("h", h), ("normals", normals), ("offsets", offsets),
                            ("vertices", vertices), ("vertex_facets", pairs)):
            object.__setattr__(self, name, _frozen(value))

    @property
    def n_facets(self) -> int:
        return len(self.h)

    @classmethod
    def from_facets(cls, points: ArrayLike, normals: ArrayLike) -> "Environment":
        """One facet per (point on it, outward normal) pair: points (P, 2) m, normals (P, 2)."""
        pts = np.asarray(points, dtype=float)
        nrm = np.asarray(normals, dtype=float)
        if pts.ndim != 2 or pts.shape[1] != 2 or nrm.shape != pts.shape:
            raise ValueError(f"points and normals must both have shape (P, 2), got {pts.shape} and {nrm.shape}")
        return cls(nrm, np.einsum("ij,ij->i", nrm, pts))

    @classmethod
    def from_polygon(cls, vertices: ArrayLike) -> "Environment":
        """Bounded N from a strictly convex polygon's vertices (V, 2) in m, either orientation."""
        v = np.asarray(vertices, dtype=float)
        if v.ndim != 2 or v.shape[1] != 2 or v.shape[0] < 3:
            raise ValueError(f"vertices must have shape (V, 2) with V >= 3, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError("vertices must be finite")
        edges = np.roll(v, -1, axis=0) - v
        following = np.roll(edges, -1, axis=0)
        turns = edges[:, 0] * following[:, 1] - edges[:, 1] * following[:, 0]
        orientation = np.sign(turns.sum())
        for k, turn in enumerate(turns):
            if not turn * orientation > 0:
                raise ValueError("vertices must form a strictly convex polygon; "
                                 f"the turn at vertex {(k + 1) % len(v)} is {turn:.3g}")
        winding = np.sum(np.arctan2(np.abs(turns), np.einsum("ij,ij->i", edges, following))) / (2 * np.pi)
        if abs(winding - 1.0) > 1e-6:
            raise ValueError(f"vertices must form a simple convex polygon; they wind {winding:.3g} times (a star?)")
        outward = orientation * np.column_stack((edges[:, 1], -edges[:, 0]))
        return cls.from_facets(v, outward)


def paper_environment() -> Environment:
    """The paper's plate: one facet 0.36 x + y ≤ 0.15 m (slope m = −0.36, intercept 0.15 m)."""
    return Environment(np.array([[0.36, 1.0]]), np.array([0.15]))


@dataclass(frozen=True, eq=False)
class ForceSafeSet:
    """P = {r | H' r ≤ h'} for `environment`, ψ = `stiffness`, limit `f_max` (N) per facet.

    `row_scaling` ("paper" or "unit", see the module docstring) has no default on purpose.
    Derived: `n_max` (m), `H_prime` (P', 2), `h_prime` (P',), `is_vertex_correction` (P',)
    bool (False for the P Lemma rows, True for the correction rows that follow them).
    Point arguments r have shape (2,) or (T, 2); per-facet results then have shape (P,)
    or (T, P).
    """

    environment: Environment
    stiffness: StiffnessLaw
    f_max: float
    row_scaling: RowScaling
    n_max: float = field(init=False)
    H_prime: np.ndarray = field(init=False, repr=False)
    h_prime: np.ndarray = field(init=False, repr=False)
    is_vertex_correction: np.ndarray = field(init=False, repr=False)
    _unit_rows: np.ndarray = field(init=False, repr=False)
    _unit_offsets: np.ndarray = field(init=False, repr=False)
    _facets: tuple[tuple[float, float, float], ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        f_max = as_real("F_max", self.f_max, "N")
        if not f_max > 0.0:
            raise ValueError(f"F_max must be > 0, got {f_max}")
        if not math.isfinite(f_max):
            raise ValueError(f"F_max must be finite, got {f_max}")
        if self.row_scaling not in get_args(RowScaling):
            raise ValueError(f"row_scaling must be one of {get_args(RowScaling)}, got {self.row_scaling!r}")
        n_max = float(self.stiffness.penetration(f_max))
        if not (math.isfinite(n_max) and n_max > 0.0):
            raise ValueError(f"stiffness.penetration(F_max) must be finite and > 0, got {n_max} m")
        env = self.environment
        i, j = env.vertex_facets.T
        bisectors = env.normals[i] + env.normals[j]
        bisectors /= np.hypot(bisectors[:, 0], bisectors[:, 1])[:, None]
        corner_offsets = (np.einsum("ij,ij->i", bisectors, env.vertices)
                          + n_max * np.einsum("ij,ij->i", bisectors, env.normals[i]))
        rows = np.vstack((env.normals, bisectors))
        offsets = np.concatenate((env.offsets + n_max, corner_offsets))
        scale = np.ones(len(rows))
        if self.row_scaling == "paper":
            second = np.abs(rows[:, 1])
            scale = np.where(second > _VERTICAL_TOL, second, 1.0)
        object.__setattr__(self, "f_max", f_max)
        object.__setattr__(self, "n_max", n_max)
        object.__setattr__(self, "_unit_rows", _frozen(rows))
        object.__setattr__(self, "_unit_offsets", _frozen(offsets))
        object.__setattr__(self, "H_prime", _frozen(rows / scale[:, None]))
        object.__setattr__(self, "h_prime", _frozen(offsets / scale))
        object.__setattr__(self, "is_vertex_correction",
                           _frozen(np.arange(len(rows)) >= env.n_facets))
        object.__setattr__(self, "_facets", tuple((nx, ny, d) for (nx, ny), d in
                                                  zip(env.normals.tolist(), env.offsets.tolist())))

    @property
    def n_facets(self) -> int:
        return self.environment.n_facets

    def penetration(self, r: ArrayLike) -> np.ndarray:
        """n_i(r) = max(0, n̂_i·r − d_i) in m, shape (P,) or (T, P)."""
        r = np.asarray(r, dtype=float)
        return np.maximum(r @ self.environment.normals.T - self.environment.offsets, 0.0)

    def force(self, r: ArrayLike) -> np.ndarray:
        """F_i = ψ(n_i(r)) in N, shape (P,) or (T, P)."""
        return self.stiffness.force(self.penetration(r))

    def margins(self, r: ArrayLike) -> np.ndarray:
        """ρ_i = (n_max − n_i(r))/n_max per facet, shape (P,) or (T, P); 1 = no contact, < 0 = violation.

        Per facet as docs/model.md#force-safe-set defines it: near a vertex r can leave P through a correction
        row while every ρ_i ≥ 0 (by at most the factor 1/cos(θ/2) of the Lemma corner).
        """
        return (self.n_max - self.penetration(r)) / self.n_max

    def margin(self, r: ArrayLike) -> np.ndarray:
        """ρ = min_i ρ_i, scalar or shape (T,)."""
        return np.min(self.margins(r), axis=-1)

    def margin_from_force(self, force: ArrayLike) -> np.ndarray:
        """ρ = (n_max − ψ⁻¹(F))/n_max elementwise for measured forces F (N), e.g. shape (P,) or (T, P)."""
        return (self.n_max - self.stiffness.penetration(force)) / self.n_max

    def penetration_at(self, x: float, y: float) -> list[float]:
        """`penetration` at one point r = (x, y) given as Python floats (m): a list of P floats.

        The per-step path (numpy's per-call overhead dominates for one point); tested against `penetration`.
        """
        return [max(nx * x + ny * y - d, 0.0) for nx, ny, d in self._facets]

    def margin_at(self, x: float, y: float) -> float:
        """`margin` at one point r = (x, y) (m), as a Python float."""
        n_max = self.n_max
        return min([(n_max - n) / n_max for n in self.penetration_at(x, y)])

    def force_at(self, x: float, y: float) -> np.ndarray:
        """`force` at one point r = (x, y) (m): shape (P,), N (ψ is not called when nothing is penetrated: ψ(0) = 0)."""
        penetration = self.penetration_at(x, y)
        return self.stiffness.force(penetration) if any(penetration) else np.zeros(len(penetration))

    def contains(self, r: ArrayLike, tol: float = 0.0) -> np.ndarray:
        """Whether r ∈ P, i.e. every row's Euclidean excess (H'_i r − h'_i)/‖H'_i‖ ≤ tol (m); bool or (T,)."""
        r = np.asarray(r, dtype=float)
        return np.all(r @ self._unit_rows.T - self._unit_offsets <= tol, axis=-1)


def paper_safe_set() -> ForceSafeSet:
    """The paper's experiment: its plate, ψ(n) = `PAPER_PLATE_STIFFNESS` n, F_max = `PAPER_F_MAX`, "paper" row scaling."""
    return ForceSafeSet(paper_environment(), LinearStiffness(PAPER_PLATE_STIFFNESS), PAPER_F_MAX, row_scaling="paper")
