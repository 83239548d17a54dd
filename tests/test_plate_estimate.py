"""The plate learned online (controllers.governors.energy_governor.plate_estimate) against brute force on the PCC model.

Each equilibrium is solved directly on the PCC model whose plate pushes back (c K q = g Λ p − J_rᵀn̂ F, F = s k₀
max(0, n̂·r − d − o)) for a true arm (g, c) and plate (s, o) drawn from the standard box (its corners and uniform
draws); the estimate then sees q̂ = q + e with |e_i| ≤ Δ (the box's corners of e and random points), the certified
(g, c) vertices from a ratio interval that contains g/c, and must keep the true plate in its set, F within its force
interval, and the certified boundary force-safe for the true plate. A closed loop on the PCC plant with learning
shows the set narrowing and the force staying ≤ F_max; the MuJoCo loop is in tests/test_plate_estimate_mujoco.py.
"""

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

from controllers.governors.energy_governor import ContactEnergyGovernor
from controllers.governors.energy_governor.certificate import arm_corners
from controllers.governors.energy_governor.parameters import STANDARD_BOX_SETTING
from controllers.governors.energy_governor.plate_estimate import (PlateEstimate, add_sample, certified_box, clip, contact_force,
                                                        depth_margin, prior_estimate)
from controllers.model.params import reference_robot
from controllers.model.pcc import tip_jacobian, tip_position
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext

sys.path.insert(0, str(Path(__file__).parent))
from test_certificate_box import true_plant  # noqa: E402

ROBOT = reference_robot()
SAFE = paper_safe_set()
K0 = 11.16
K, A, L = ROBOT.array("stiffness"), ROBOT.array("gains") / ROBOT.array("stiffness"), ROBOT.array("lengths")
NORMAL, PLANE = SAFE.environment.normals[0], float(SAFE.environment.offsets[0])
BOX = {"g": (0.9, 1.1), "c": (0.9, 1.1), "s": (0.8, 1.2), "o": (-0.002, 0.002)}
DELTA = 1e-4


def equilibrium(p, g, c, s, o) -> np.ndarray:
    """q (N,) rad with c K q = g Λ p − J_r(q)ᵀn̂ F(q), F = s k₀ max(0, n̂·r(q) − d − o): damped Newton with a
    central-difference Jacobian from the free rest shape, to |residual| < 1e-13 N·m."""
    def residual(q):
        force = s * K0 * max(0.0, float(NORMAL @ tip_position(q, L)) - PLANE - o)
        return c * K * q - g * K * A * p + force * (NORMAL @ tip_jacobian(q, L))
    q = g / c * A * p
    for _ in range(200):
        r = residual(q)
        if np.max(np.abs(r)) < 1e-13:
            return q
        jac = np.array([(residual(q + h) - residual(q - h)) / 2e-9 for h in np.eye(2) * 1e-9]).T
        q = q - 0.7 * np.linalg.solve(jac, r)
    raise AssertionError(f"no equilibrium at p={p}, g={g}, c={c}, s={s}, o={o}")


def true_force(q, s, o) -> float:
    return s * K0 * max(0.0, float(NORMAL @ tip_position(q, L)) - PLANE - o)


def points(seed: int, interior: int) -> list[dict]:
    corners = [dict(zip(BOX, v)) for v in itertools.product(*BOX.values())]
    rng = np.random.default_rng(seed)
    return corners + [{n: float(rng.uniform(*BOX[n])) for n in BOX} for _ in range(interior)]


def sample(estimate, q, p, corners, error, noise=DELTA):
    """The estimate's sample at the true rest q seen as q + error (what `plate_feedback.update_plate` computes)."""
    q_hat = q + error
    torque = NORMAL @ tip_jacobian(q_hat, L)
    force = contact_force(torque, K, A * p, q_hat, corners, np.full(2, noise))
    depth, margin = float(NORMAL @ tip_position(q_hat, L)) - PLANE, depth_margin(L, np.full(2, noise))
    return add_sample(estimate, 0, (depth - margin, depth + margin), force, K0), force


def inside(polygon: np.ndarray, v: float, o: float) -> bool:
    """(v, o) in the convex polygon (the half-planes of its edges, either orientation, 1e-12 slack)."""
    edges = np.roll(polygon, -1, axis=0) - polygon
    cross = edges[:, 0] * (o - polygon[:, 1]) - edges[:, 1] * (v - polygon[:, 0])
    return bool(np.all(cross >= -1e-12) or np.all(cross <= 1e-12))


@pytest.mark.parametrize("point", points(3, 6), ids=lambda p: ",".join(f"{k}={v:.3g}" for k, v in p.items()))
def test_the_learned_set_holds_the_true_plate_over_the_box(point):
    """At every corner and draw of the box, over pressures from free space to the plate's F_max and estimate
    errors at the corners of |e_i| ≤ Δ: F lies in its interval, the true (1/s, o) in the set, and the certified
    boundary b keeps the true plate's force ≤ F_max."""
    g, c, s, o = point["g"], point["c"], point["s"], point["o"]
    corners = arm_corners(BOX["g"], BOX["c"], (g / c - 0.01, g / c + 0.01))
    estimate = prior_estimate(1, BOX["s"], BOX["o"])
    errors = [np.array(e) * DELTA for e in itertools.product((-1.0, 1.0), repeat=2)] + [np.zeros(2)]
    for level, error in zip(np.linspace(40.0, 80.0, 9), itertools.cycle(errors)):
        q = equilibrium(np.full(2, level), g, c, s, o)
        estimate, (f_lo, f_hi) = sample(estimate, q, np.full(2, level), corners, error)
        assert f_lo - 1e-12 <= true_force(q, s, o) <= f_hi + 1e-12
        assert not estimate.inconsistent and inside(estimate.polygons[0], 1.0 / s, o)
        box = certified_box(estimate, SAFE.f_max, K0)
        assert s * K0 * (box.offset_lo + box.reach - o) <= SAFE.f_max * (1.0 + 1e-9)
        assert box.lo <= s <= box.hi and box.offset_lo <= o <= box.offset_lo + box.width


def test_contact_narrows_the_boundary_and_free_space_does_not_cut_the_truth():
    """Samples pressing the nominal plate move the certified boundary beyond the prior's (P widens: the whole point);
    samples in free space near the plate (F = 0) only bound the offset from below, by the tip's own position."""
    corners = arm_corners(BOX["g"], BOX["c"], (0.995, 1.005))
    prior = prior_estimate(1, BOX["s"], BOX["o"])
    start = certified_box(prior, SAFE.f_max, K0)
    estimate = prior
    for level in (60.0, 70.0):
        estimate, _ = sample(estimate, equilibrium(np.full(2, level), 1.0, 1.0, 1.0, 0.0), np.full(2, level), corners,
                             np.zeros(2))
    learned = certified_box(estimate, SAFE.f_max, K0)
    assert learned.offset_lo + learned.reach > start.offset_lo + start.reach + 1e-3  # ≥ 1 mm wider
    free = prior
    q = equilibrium(np.full(2, 50.0), 1.0, 1.0, 1.0, 0.003)  # a plate 3 mm farther than the model's: no contact
    assert true_force(q, 1.0, 0.003) == 0.0
    free, (f_lo, f_hi) = sample(free, q, np.full(2, 50.0), corners, np.zeros(2))
    assert f_lo <= 0.0 <= f_hi
    box = certified_box(free, SAFE.f_max, K0)
    depth = float(NORMAL @ tip_position(q, L)) - PLANE
    assert box.lo == 0.8 and box.hi == 1.2  # no stiffness from a sample out of contact
    assert box.offset_lo + box.width == 0.002 and box.offset_lo <= 0.002
    assert box.offset_lo >= min(0.002, depth - depth_margin(L, np.full(2, DELTA)) - f_hi / (0.8 * K0)) - 1e-12


def test_a_contradiction_returns_the_prior_for_good():
    estimate = prior_estimate(1, BOX["s"], BOX["o"])
    wrong = add_sample(estimate, 0, (0.010, 0.0101), (0.0, 0.01), K0)  # 10 mm deep with ≤ 0.01 N: no plate of the box
    assert wrong.inconsistent and wrong.polygons is estimate.prior_polygons
    assert add_sample(wrong, 0, (0.0, 0.001), (0.0, 0.05), K0) is wrong
    assert add_sample(estimate, 0, (0.0, 0.001), (-0.2, -0.1), K0).inconsistent  # f_hi < 0 contradicts f >= 0


def test_clip_and_prior_are_checked():
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    np.testing.assert_allclose(clip(square, 1.0, 1.0, 1.0), [[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    assert len(clip(square, 1.0, 0.0, -1.0)) == 0 and len(clip(square, 1.0, 0.0, 5.0)) == 4
    with pytest.raises(ValueError, match="0 < s_lo <= s_hi"):
        prior_estimate(1, (1.2, 0.8), (0.0, 0.0))
    with pytest.raises(ValueError, match="torque"):
        contact_force(np.zeros(2), K, np.zeros(2), np.zeros(2), ((1.0, 1.0),), np.zeros(2))
    assert isinstance(prior_estimate(2, (1.0, 1.0), (0.0, 0.0)), PlateEstimate)


LEARNING = {**STANDARD_BOX_SETTING, "plate_estimate": True, "gain_noise_rad": DELTA, "gain_rest_s": 0.2}


@pytest.mark.parametrize("point", [{}, {"plate": 1.2, "offset": -0.002, "gain": 1.1, "arm": 0.9, "damping": 0.7,
                                        "tau": 0.02}], ids=["nominal", "corner"])
def test_the_closed_loop_learns_the_plate_and_stays_below_f_max(point):
    """c-erg over the standard box with the plate learned, 10 Hz on the PCC plant (exact state) pushing 150 hPa for
    6 s: the state certifies a learned plate (on the nominal plate a P ≥ 1 mm wider than the prior's; at the corner,
    the box's own worst plate, a hull narrowed to it), and the true force stays ≤ F_max throughout."""
    context = FilterContext(ROBOT, SAFE, ROBOT.array("u_min"), ROBOT.array("u_max"), 0.1, 0.0, 0.05)
    gov = ContactEnergyGovernor(context, **LEARNING)
    plant = true_plant(**point)
    state, worst = plant.reset(np.zeros(2)), 0.0
    for _ in range(60):
        out = gov(Estimate(state.t, state.q, state.qd, state.t), np.full(2, 150.0))
        for _ in range(100):
            state = plant.step(out.u)
            worst = max(worst, float(np.max(state.contact_forces)))
    learned, prior = gov.state.plate.box, gov.model.plate.box
    assert gov.state.plate is not gov.model.plate and not gov.state.plate_estimate.inconsistent
    if point:  # the box's stiffest, nearest plate: P cannot widen, the hull narrows to it
        assert learned.lo > 1.1 and learned.width < 0.001 and learned.offset_lo == -0.002
    else:
        assert learned.offset_lo + learned.reach > prior.offset_lo + prior.reach + 1e-3  # ≥ 1 mm wider
    assert worst <= SAFE.f_max


def test_the_least_credit_bounds_the_credit_over_the_polygon_from_below_and_closely():
    """`least_credit` against brute force: the own facet's credit s (E(b − o) − E(max(0, δ − o))) on a dense grid of
    plates inside learned polygons (a pressing sample's strip, cut from the prior box) is never below the bound, and
    the grid's least value is within 5 % of it, for tips inside P."""
    from controllers.governors.energy_governor.plate_estimate import credit_pieces, least_credit

    corners = arm_corners(BOX["g"], BOX["c"], (0.995, 1.005))
    rng = np.random.default_rng(11)
    for level in (55.0, 65.0, 75.0):
        s, o = float(rng.uniform(0.8, 1.2)), float(rng.uniform(-0.002, 0.002))
        q = equilibrium(np.full(2, level), 1.0, 1.0, s, o)
        estimate, _ = sample(prior_estimate(1, BOX["s"], BOX["o"]), q, np.full(2, level), corners, np.zeros(2))
        polygon, box = estimate.polygons[0], certified_box(estimate, SAFE.f_max, K0)
        boundary = box.offset_lo + box.reach
        grid = np.stack(np.meshgrid(np.linspace(0.8, 1.3, 400), np.linspace(-0.0025, 0.0025, 400)), -1).reshape(-1, 2)
        grid = grid[[inside(polygon, v, off) for v, off in grid]]
        for depth in (float(NORMAL @ tip_position(q, L)) - PLANE, boundary - 1e-3, -0.01):
            if depth >= boundary:  # the tip outside P (a sample pressing beyond F_max): no certificate to bound
                continue
            held = np.maximum(boundary - grid[:, 1], 0.0) ** 2 - np.maximum(depth - grid[:, 1], 0.0) ** 2
            least = float(np.min(0.5 * K0 * held / grid[:, 0]))
            bound = least_credit(credit_pieces(polygon, boundary, K0), depth)
            assert bound <= least + 1e-15 and bound >= 0.95 * least


def test_plate_estimate_is_refused_without_what_it_stands_on():
    with pytest.raises(ValueError, match="plate_estimate needs gain_estimate with gain_contact='normal'"):
        ContactEnergyGovernor.check_arguments({"plate_estimate": True})
    with pytest.raises(ValueError, match="plate_estimate needs"):
        ContactEnergyGovernor.check_arguments({**STANDARD_BOX_SETTING, "plate_estimate": True, "gain_contact": "any"})
    assert ContactEnergyGovernor.check_arguments({**STANDARD_BOX_SETTING, "plate_estimate": True})["plate_estimate"]
