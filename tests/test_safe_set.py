"""Force-safe set (docs/model.md#force-safe-set): Lemma 1, the vertex correction, scalings, ψ laws, margins, validation.

The central property — every point of the corrected P lies within n_max of N — is checked
against an independent distance: N is described here by its own vertex list (a far-away
bounding triangle or rectangle stands in for unbounded sides) and the distance is the
exact point-to-convex-polygon distance (0 inside, else the nearest edge segment).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.model.safe_set import (
    Environment,
    ForceSafeSet,
    LinearStiffness,
    PowerLawStiffness,
    paper_environment,
    paper_safe_set,
)

PAPER_N_MAX = 0.16 / 11.16
FAR = 100.0  # m: the far edges that close unbounded regions in the reference polygons


def polygon_distance(points: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """Exact Euclidean distance (m) from points (T, 2) to the convex polygon with CCW vertices (V, 2)."""
    start, end = vertices, np.roll(vertices, -1, axis=0)
    edge = end - start                                            # (V, 2)
    rel = points[:, None, :] - start[None]                        # (T, V, 2)
    cross = edge[None, :, 0] * rel[..., 1] - edge[None, :, 1] * rel[..., 0]
    inside = np.all(cross >= 0.0, axis=1)
    s = np.clip(np.einsum("tvk,vk->tv", rel, edge) / np.einsum("vk,vk->v", edge, edge), 0.0, 1.0)
    nearest = start[None] + s[..., None] * edge[None]
    dist = np.min(np.linalg.norm(points[:, None, :] - nearest, axis=2), axis=1)
    return np.where(inside, 0.0, dist)


def sample(rng: np.random.Generator, vertices: np.ndarray, n_max: float, count: int = 20000) -> np.ndarray:
    """Points in a box around `vertices` grown by 3 n_max, plus discs of radius 2 n_max at each vertex."""
    lo, hi = vertices.min(axis=0) - 3 * n_max, vertices.max(axis=0) + 3 * n_max
    box = rng.uniform(lo, hi, (count, 2))
    discs = [v + 2 * n_max * rng.uniform(-1.0, 1.0, (count // 4, 2)) for v in vertices]
    return np.vstack([box, *discs])


def in_rows(H: np.ndarray, h: np.ndarray, points: np.ndarray) -> np.ndarray:
    return np.all(points @ H.T <= h, axis=1)


def ccw(vertices: np.ndarray) -> np.ndarray:
    v = np.asarray(vertices, dtype=float)
    area = np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
    return v if area > 0 else v[::-1]


def random_convex_polygon(rng: np.random.Generator, count: int) -> np.ndarray:
    angles = np.sort(rng.uniform(0.0, 2 * np.pi, count))
    while np.max(np.diff(np.append(angles, angles[0] + 2 * np.pi))) > 0.9 * np.pi or np.min(np.diff(angles)) < 0.05:
        angles = np.sort(rng.uniform(0.0, 2 * np.pi, count))
    radii = np.array([0.15, 0.08])
    return rng.uniform(-0.2, 0.2, 2) + radii * np.column_stack((np.cos(angles), np.sin(angles)))


def wedge(apex: np.ndarray, normal_a: np.ndarray, normal_b: np.ndarray) -> tuple[Environment, np.ndarray]:
    """The corner {n̂_a·(r − apex) ≤ 0, n̂_b·(r − apex) ≤ 0} and a reference triangle for it."""
    env = Environment.from_facets([apex, apex], [normal_a, normal_b])
    na, nb = env.normals
    # edge directions along each facet, pointing into the other facet's free side
    da = np.array([-na[1], na[0]]) * -np.sign(nb @ np.array([-na[1], na[0]]))
    db = np.array([-nb[1], nb[0]]) * -np.sign(na @ np.array([-nb[1], nb[0]]))
    return env, ccw(np.array([apex, apex + FAR * da, apex + FAR * db]))


def cases() -> list[tuple[str, Environment, np.ndarray, np.ndarray]]:
    """(name, environment, reference polygon (CCW), vertices of N) for the sampling tests."""
    rng = np.random.default_rng(7)
    box = np.array([[0.1, -0.1], [0.3, -0.1], [0.3, 0.12], [0.1, 0.12]])
    out = [("box (vertical and horizontal facets)", Environment.from_polygon(box), ccw(box), box)]
    for k, count in enumerate((3, 5, 8)):
        poly = random_convex_polygon(rng, count)
        out.append((f"random {count}-gon #{k}", Environment.from_polygon(poly[::-1] if k == 1 else poly), ccw(poly), poly))
    apex = np.array([0.2, 0.05])
    for name, na, nb in (("right-angle corner", [0.0, 1.0], [1.0, 0.0]),
                         ("acute corner (20 deg)", [0.0, 1.0], [math.sin(math.radians(70)), -math.cos(math.radians(70))]),
                         ("obtuse corner (160 deg)", [0.0, 1.0], [math.sin(math.radians(20)), math.cos(math.radians(20))]),
                         ("corner with a vertical facet, rows of scale 5 and 0.3", [0.0, 5.0], [-0.3, 0.0])):
        env, ref = wedge(apex, np.array(na), np.array(nb))
        out.append((name, env, ref, apex[None]))
    slab = Environment(np.array([[0.36, 1.0], [-0.72, -2.0]]), np.array([0.15, 0.1]))
    out.append(("slab between parallel facets", slab,
                ccw(np.array([[-FAR, 0.15 + 0.36 * FAR], [FAR, 0.15 - 0.36 * FAR], [FAR, -0.05 - 0.36 * FAR], [-FAR, -0.05 + 0.36 * FAR]])),
                np.array([[0.0, 0.15], [0.0, -0.05]])))
    return out


CASES = cases()


@pytest.mark.parametrize("scaling", ["paper", "unit"])
@pytest.mark.parametrize("name, env, reference, corners", CASES, ids=[c[0] for c in CASES])
def test_corrected_set_lies_within_n_max_of_free_space(name, env, reference, corners, scaling):
    safe = ForceSafeSet(env, LinearStiffness(11.16), 0.16, row_scaling=scaling)
    n_max = safe.n_max
    points = sample(np.random.default_rng(1), corners, n_max)
    inside_p = in_rows(safe.H_prime, safe.h_prime, points)
    dist = polygon_distance(points[inside_p], reference)
    assert np.max(dist) <= n_max + 1e-12, f"{name}: a point of P is {np.max(dist) / n_max:.6f} n_max from N"
    # not vacuous: many samples of P lie outside N, some close to the n_max limit
    assert np.sum(dist > 0) > 500
    assert np.max(dist) > 0.97 * n_max
    # N ⊂ P, and `contains` agrees with the rows
    assert np.all(in_rows(safe.H_prime, safe.h_prime, points[polygon_distance(points, reference) == 0]))
    np.testing.assert_array_equal(safe.contains(points), inside_p)
    # the correction's defining points c + n_max n̂_i, c + n_max n̂_j lie on P's boundary
    for c, (i, j) in zip(env.vertices, env.vertex_facets):
        for k in (i, j):
            tip = c + n_max * env.normals[k]
            assert safe.contains(tip, tol=1e-12) and not safe.contains(c + 1.001 * n_max * env.normals[k])


@pytest.mark.parametrize("name, env, reference, corners", CASES[:-1], ids=[c[0] for c in CASES[:-1]])
def test_uncorrected_set_reaches_beyond_n_max_at_corners(name, env, reference, corners):
    safe = ForceSafeSet(env, LinearStiffness(11.16), 0.16, row_scaling="unit")
    lemma = ~safe.is_vertex_correction
    for c, (i, j) in zip(env.vertices, env.vertex_facets):
        # Lemma 1 alone leaves the corner where both shifted facets meet, n_max / cos(θ/2) from c
        ni, nj = env.normals[i], env.normals[j]
        corner = c + safe.n_max * (ni + nj) / (1.0 + ni @ nj)
        expected = safe.n_max / math.cos(math.acos(np.clip(ni @ nj, -1.0, 1.0)) / 2)
        assert in_rows(safe.H_prime[lemma], safe.h_prime[lemma] + 1e-12, corner[None])[0]
        assert polygon_distance(corner[None], reference)[0] == pytest.approx(expected, rel=1e-9)
        assert expected > safe.n_max * (1 + 1e-3)
        assert not safe.contains(corner)


def test_uncorrected_right_angle_corner_samples_exceed_n_max():
    env, reference = wedge(np.array([0.2, 0.05]), np.array([0.0, 1.0]), np.array([1.0, 0.0]))
    safe = ForceSafeSet(env, LinearStiffness(11.16), 0.16, row_scaling="paper")
    lemma = ~safe.is_vertex_correction
    points = sample(np.random.default_rng(2), env.vertices, safe.n_max)
    dist = polygon_distance(points[in_rows(safe.H_prime[lemma], safe.h_prime[lemma], points)], reference)
    assert np.max(dist) > 1.3 * safe.n_max  # the limit is √2 n_max


def test_paper_facet_reproduces_slope_intercept_constants():
    safe = paper_safe_set()
    m = -0.36
    assert safe.n_max == pytest.approx(PAPER_N_MAX, rel=1e-15)
    assert safe.n_max == pytest.approx(0.014337, abs=1e-6)
    np.testing.assert_allclose(safe.H_prime, [[-m, 1.0]], rtol=1e-15)
    np.testing.assert_allclose(safe.h_prime, [0.15 + PAPER_N_MAX * math.sqrt(m * m + 1)], rtol=1e-15)
    assert safe.is_vertex_correction.tolist() == [False]
    assert safe.n_facets == 1 and paper_environment().vertices.shape == (0, 2)
    unit = ForceSafeSet(paper_environment(), LinearStiffness(11.16), 0.16, row_scaling="unit")
    norm = math.hypot(0.36, 1.0)
    np.testing.assert_allclose(unit.H_prime, [[0.36 / norm, 1.0 / norm]], rtol=1e-15)
    np.testing.assert_allclose(unit.h_prime, [0.15 / norm + PAPER_N_MAX], rtol=1e-15)


def test_two_facet_corner_rows_and_scalings():
    env = Environment(np.array([[0.0, 2.0], [3.0, 0.0]]), np.array([0.2, 0.6]))  # y ≤ 0.1, x ≤ 0.2
    np.testing.assert_allclose(env.vertices, [[0.2, 0.1]])
    assert env.vertex_facets.tolist() == [[0, 1]]
    n = 0.01
    paper = ForceSafeSet(env, LinearStiffness(1.0), n, row_scaling="paper")
    unit = ForceSafeSet(env, LinearStiffness(1.0), n, row_scaling="unit")
    assert paper.is_vertex_correction.tolist() == [False, False, True]
    # row 1 is vertical: "paper" falls back to unit norm; the correction is x + y ≤ 0.3 + n_max
    np.testing.assert_allclose(paper.H_prime, [[0, 1], [1, 0], [1, 1]], atol=1e-15)
    np.testing.assert_allclose(paper.h_prime, [0.1 + n, 0.2 + n, 0.3 + n], rtol=1e-14)
    s = 1 / math.sqrt(2)
    np.testing.assert_allclose(unit.H_prime, [[0, 1], [1, 0], [s, s]], atol=1e-15)
    np.testing.assert_allclose(unit.h_prime, [0.1 + n, 0.2 + n, (0.3 + n) * s], rtol=1e-14)


def test_vertical_facets_use_unit_rows_under_paper_scaling():
    env = Environment(np.array([[-2.0, 0.0], [4.0, 0.0]]), np.array([0.1, 0.8]))  # −0.05 ≤ x ≤ 0.2
    safe = ForceSafeSet(env, LinearStiffness(11.16), 0.16, row_scaling="paper")
    np.testing.assert_allclose(safe.H_prime, [[-1, 0], [1, 0]])
    np.testing.assert_allclose(safe.h_prime, [0.05 + PAPER_N_MAX, 0.2 + PAPER_N_MAX], rtol=1e-14)
    np.testing.assert_allclose(safe.penetration([[0.21, 3.0], [-0.06, 0.0], [0.0, 0.0]]),
                               [[0.0, 0.01], [0.01, 0.0], [0.0, 0.0]], atol=1e-15)


def test_box_has_one_correction_per_vertex():
    box = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.1], [0.0, 0.1]])
    safe = ForceSafeSet(Environment.from_polygon(box), LinearStiffness(11.16), 0.16, row_scaling="paper")
    assert safe.n_facets == 4 and safe.H_prime.shape == (8, 2) and safe.h_prime.shape == (8,)
    assert safe.is_vertex_correction.tolist() == [False] * 4 + [True] * 4
    found = {tuple(np.round(v, 12)) for v in safe.environment.vertices}
    assert found == {tuple(v) for v in box}
    # each correction row is |x − x_c| + |y − y_c| ≤ n_max in the corner's quadrant
    for c, row, rhs in zip(safe.environment.vertices, safe.H_prime[4:], safe.h_prime[4:]):
        np.testing.assert_allclose(np.abs(row), [1.0, 1.0])
        assert rhs - row @ c == pytest.approx(safe.n_max, rel=1e-12)


def test_stiffness_laws_round_trip_and_set_n_max():
    n = np.linspace(0.0, 0.05, 101)
    for law in (LinearStiffness(11.16), PowerLawStiffness(50.0, 1.5), PowerLawStiffness(3.0, 0.7)):
        np.testing.assert_allclose(law.penetration(law.force(n)), n, rtol=1e-12, atol=1e-15)
        assert np.all(np.diff(law.force(n)) > 0)
        assert law.force(-0.01) == 0.0 and law.penetration(-1.0) == 0.0
        assert law.force(np.zeros((3, 2))).shape == (3, 2)
    hertz = PowerLawStiffness(50.0, 1.5)
    assert float(hertz.force(0.04)) == pytest.approx(50.0 * 0.04**1.5)
    safe = ForceSafeSet(paper_environment(), hertz, 0.16, row_scaling="paper")
    assert safe.n_max == pytest.approx((0.16 / 50.0) ** (1 / 1.5), rel=1e-14)
    r = np.array([0.0, 0.15]) + 0.5 * safe.n_max * safe.environment.normals[0]
    assert float(safe.force(r)[0]) == pytest.approx(0.16 * 0.5**1.5, rel=1e-12)
    assert float(safe.margin_from_force(safe.force(r))[0]) == pytest.approx(0.5, rel=1e-12)


def test_penetration_force_and_margins_at_known_points():
    safe = paper_safe_set()
    n_hat = safe.environment.normals[0]
    on_facet = np.array([0.0, 0.15])
    points = on_facet + np.outer([-1.0, 0.0, 0.5, 1.0, 2.0], n_hat) * safe.n_max
    np.testing.assert_allclose(safe.penetration(points)[:, 0], [0, 0, 0.5, 1, 2] * np.array(safe.n_max), atol=1e-15)
    np.testing.assert_allclose(safe.force(points)[:, 0], [0, 0, 0.08, 0.16, 0.32], rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(safe.margins(points)[:, 0], [1, 1, 0.5, 0, -1], atol=1e-12)
    np.testing.assert_allclose(safe.margin(points), [1, 1, 0.5, 0, -1], atol=1e-12)
    assert safe.margins(points[2]).shape == (1,) and np.ndim(safe.margin(points[2])) == 0
    np.testing.assert_array_equal(safe.contains(points, tol=1e-12), [True, True, True, True, False])
    np.testing.assert_allclose(safe.margin_from_force([0.0, 0.08, 0.16, 0.32]), [1, 0.5, 0, -1], atol=1e-12)
    # several facets: ρ is the minimum over facets, per-facet values keep their order
    box = ForceSafeSet(Environment.from_polygon([[0, 0], [0.2, 0], [0.2, 0.1], [0, 0.1]]), LinearStiffness(10.0), 0.1,
                       row_scaling="unit")
    r = np.array([0.205, 0.1025])  # 0.005 m past x = 0.2, 0.0025 m past y = 0.1
    margins = box.margins(r)
    assert sorted(np.round(margins, 12).tolist()) == [0.5, 0.75, 1.0, 1.0]
    assert box.margin(r) == pytest.approx(0.5)


@pytest.mark.parametrize("make, message", [
    (lambda: ForceSafeSet(paper_environment(), LinearStiffness(11.16), -0.16, "paper"), "F_max must be > 0, got -0.16"),
    (lambda: ForceSafeSet(paper_environment(), LinearStiffness(11.16), 0.16, "slope"), "row_scaling must be one of"),
    (lambda: LinearStiffness(0.0), "k must be finite and > 0, got 0.0"),
    (lambda: PowerLawStiffness(1.0, -1.5), "exponent must be finite and > 0, got -1.5"),
    (lambda: Environment(np.array([[0.0, 1.0], [0.0, 0.0]]), np.array([1.0, 1.0])), "H row 1 is zero"),
    (lambda: Environment(np.array([0.36, 1.0]), np.array([0.15])), r"H must have shape \(P, 2\)"),
    (lambda: Environment(np.array([[0.36, 1.0]]), np.array([0.15, 0.2])), r"h must have shape \(P,\) = \(1,\), got \(2,\)"),
    (lambda: Environment(np.array([[0.36, np.nan]]), np.array([0.15])), r"H\[0, 1\] must be finite, got nan"),
    (lambda: Environment(np.array([[0.0, 1.0], [0.0, 2.0]]), np.array([1.0, 2.0])), "H rows 0 and 1 describe the same facet"),
    (lambda: Environment(np.array([[0.0, 1.0], [0.0, -1.0]]), np.array([0.1, -0.1])), "opposite and coincide"),
    (lambda: Environment(np.array([[0.0, 1.0], [0.0, 1.0], [1.0, 0.0]]), np.array([0.1, 0.2, 0.0])), "redundant facet.*facet 1"),
    (lambda: Environment(np.array([[0.0, 1.0], [1.0, 0.0], [1.0, 1.0]]), np.zeros(3)),
     r"redundant facet.*facet 2 \(touches N along 0 m\)"),  # touches N only at the corner
    (lambda: Environment(np.array([[0.0, 1.0], [0.0, -1.0]]), np.array([-0.1, 0.0])), "is empty"),
    (lambda: Environment.from_polygon([[0, 0], [1, 0], [0.2, 0.2], [0, 1]]), "strictly convex"),
    (lambda: Environment.from_polygon([[0, 0], [1, 0], [2, 0], [0, 1]]), "strictly convex"),
    (lambda: Environment.from_polygon([[np.cos(a), np.sin(a)] for a in np.arange(5) * 4 * np.pi / 5]), "wind 2 times"),
])
def test_validation_messages(make, message):
    with pytest.raises(ValueError, match=message):
        make()


def test_environment_constructors_agree_and_arrays_are_read_only():
    square = np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]])
    a = Environment.from_polygon(square)
    b = Environment.from_polygon(square[::-1])
    c = Environment.from_facets([[0.05, 0.0], [0.1, 0.05], [0.05, 0.1], [0.0, 0.05]],
                                [[0.0, -3.0], [2.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])
    for env in (b, c):
        order = [np.flatnonzero(np.all(np.isclose(env.normals, n), axis=1))[0] for n in a.normals]
        np.testing.assert_allclose(env.normals[order], a.normals, atol=1e-15)
        np.testing.assert_allclose(env.offsets[order], a.offsets, atol=1e-15)
    safe = ForceSafeSet(a, LinearStiffness(11.16), 0.16, row_scaling="paper")
    for arr in (a.H, a.vertices, safe.H_prime, safe.h_prime, safe.is_vertex_correction):
        with pytest.raises(ValueError):
            arr[0] = 1


@pytest.mark.parametrize("law", [LinearStiffness(11.16), PowerLawStiffness(40.0, 1.5)])
def test_stored_energy_is_the_integral_of_the_force(law):
    n = np.linspace(0.0, 0.02, 20001)
    force = law.force(n)
    integral = np.concatenate(([0.0], np.cumsum(0.5 * (force[1:] + force[:-1]) * np.diff(n))))
    np.testing.assert_allclose(law.energy(n), integral, rtol=1e-6, atol=1e-12)
    assert law.energy(-0.01) == 0.0
