"""The compiled escape-energy look-ups and recovery scan (`controllers.energy.energy_kernels`) against plain Python
and numpy evaluations of their definitions (`controllers.energy.escape_energy`'s module docstring): the look-ups
within RELATIVE_TOL (the kernels may order a sum or square differently, e.g. x·x where Python's `x ** 2` calls
libm's pow; both round within a few ulp of the exact value), the recovery's choice exactly, on the reference
arm's table and bound, for commands inside and outside the box, on several environments (an out-of-reach facet
included), N = 1 and 2 (table) and N = 3 (bound)."""

import math

import numpy as np
import pytest

from controllers.energy import energy_kernels
from controllers.model import pcc_model
from controllers.energy.escape_energy import BoundaryDistanceBound, EscapeEnergyTable, lower_bounds
from controllers.model.params import reference_robot, uniform_robot
from controllers.model.safe_set import ForceSafeSet, paper_safe_set

ROBOT = reference_robot()
SAFE = paper_safe_set()


RELATIVE_TOL, ABSOLUTE_TOL_J = 1e-12, 1e-14
"""The look-ups' agreement with the Python definitions: relative, and absolute (J) for values near 0 where the
bilinear bound's curvature correction cancels its interpolation (values reach ≈ 1 J, the table's own looseness
is ≈ 1e-3 J)."""


def close(got, expected) -> bool:
    """Whether two lists of Γ̲_j (J, +inf allowed) agree within RELATIVE_TOL and ABSOLUTE_TOL_J."""
    return got == pytest.approx(expected, rel=RELATIVE_TOL, abs=ABSOLUTE_TOL_J)


def table_reference(table: EscapeEnergyTable, u) -> list[float]:
    """The table's look-up (`EscapeEnergyTable.values`) in Python floats: bounds 4a and 4b over the 2^N corners."""
    import itertools
    lo, step, w = (table.kernel_table[k].tolist() for k in range(3))
    shape, strides = [int(v) for v in table.kernel_table[3]], [int(v) for v in table.kernel_table[4]]
    rows = [d.tolist() if np.isfinite(d[0]) else None for d in table.distance]
    flat, dims, inside, curvature = 0, [], True, 0.0
    for v, lo_k, step_k, size, stride, w_k in zip(u, lo, step, shape, strides, w):
        i = min(max(int((v - lo_k) // step_k), 0), size - 2) if size > 1 else 0
        o = v - (lo_k + i * step_k)
        inside = inside and 0.0 <= o <= step_k
        flat += i * stride
        curvature += 0.5 * w_k * o * (step_k - o)
        t = o / step_k
        dims.append(((0, w_k * o * o, 1.0 - t), (stride, w_k * ((o - step_k) * (o - step_k)), t)))
    corners = [(sum(c[0] for c in combo), math.sqrt(sum(c[1] for c in combo)), math.prod(c[2] for c in combo))
               for combo in itertools.product(*dims)]
    result = []
    for row in rows:
        if row is None:
            result.append(math.inf)
            continue
        cone = max(row[flat + k] - dist for k, dist, _ in corners)
        best = 0.5 * cone * cone if cone > 0.0 else 0.0
        if inside:
            best = max(best, sum(0.5 * row[flat + k] ** 2 * weight for k, _, weight in corners) - curvature)
        result.append(best)
    return result


def bound_reference(bound: BoundaryDistanceBound, u) -> list[float]:
    """`BoundaryDistanceBound.values` in Python floats on the kinematic kernel's row."""
    n = len(bound.lengths)
    row = pcc_model.kinematics_rows(np.array(([g * float(v) for g, v in zip(bound.static_gain.tolist(), u)],)),
                                    np.zeros((1, n)), bound.lengths)[0]
    tip, tip_jac = row[4 * n].item(), row[n:2 * n].tolist()
    x, y = tip.real, tip.imag
    out = []
    for hx, hy, h, c, reachable in zip(bound.H[:, 0].tolist(), bound.H[:, 1].tolist(), bound.h.tolist(),
                                       bound.curvature.tolist(), bound.reachable.tolist()):
        if not reachable:
            out.append(math.inf)
            continue
        size = abs(hx * x + hy * y - h)
        slope = math.sqrt(sum(((hx * d.real + hy * d.imag) * s) ** 2
                              for d, s in zip(tip_jac, bound.inverse_root_k.tolist())))
        delta = 2.0 * size / (slope + math.sqrt(slope * slope + 2.0 * c * size)) if size > 0.0 else 0.0
        out.append(0.5 * delta * delta)
    return out


def environments():
    """The paper's plate, a second facet out of the arm's reach, and a two-facet corner."""
    from controllers.model.safe_set import Environment, LinearStiffness
    base = paper_safe_set()
    law = base.stiffness
    yield base
    far = Environment(np.vstack((base.environment.normals, [[0.0, -1.0]])),
                      np.concatenate((base.environment.offsets, [5.0])))
    yield ForceSafeSet(far, law, base.f_max, base.row_scaling)
    corner = Environment(np.array([[1.0, 0.0], [0.0, 1.0]]), np.array([0.12, 0.10]))
    yield ForceSafeSet(corner, LinearStiffness(11.16), base.f_max, base.row_scaling)


def commands(rng, n, count):
    """Commands inside the ±150 hPa box, beyond it, and on grid points and cell edges."""
    inside = rng.uniform(-150.0, 150.0, (count, n))
    outside = rng.uniform(-400.0, 400.0, (count // 4, n))
    grid = rng.integers(-60, 61, (count // 4, n)) * 2.5
    return np.vstack((inside, outside, grid, np.zeros((1, n)), np.full((1, n), 150.0), np.full((1, n), -150.0)))


@pytest.mark.parametrize("boundary", [False, True])
def test_table_look_up_is_its_definition(boundary):
    rng = np.random.default_rng(0)
    for safe in environments():
        for robot in (ROBOT, uniform_robot(1)):
            n = robot.n_segments
            table = EscapeEnergyTable(robot, safe, robot.array("u_min"), robot.array("u_max"), boundary=boundary,
                                      q_spacing_rad=8e-3)
            for u in commands(rng, n, 200):
                assert close(table.values(u), table_reference(table, u.tolist())), u


def test_bound_and_combined_look_up_are_their_definitions():
    rng = np.random.default_rng(1)
    for safe in environments():
        for robot in (ROBOT, uniform_robot(3)):
            bound = BoundaryDistanceBound(robot, safe)
            table = EscapeEnergyTable(robot, safe, robot.array("u_min"), robot.array("u_max"), boundary=True,
                                      q_spacing_rad=8e-3) if robot.n_segments == 2 else None
            for u in commands(rng, robot.n_segments, 200):
                second = bound_reference(bound, u.tolist())
                assert close(bound.values(u), second), u
                assert lower_bounds(tuple(u.tolist()), None, bound) == bound.values(u)
                if table is None:
                    continue
                first = table_reference(table, u.tolist())
                # the bound joins where the table's least value is below 0.02 J (decided on the kernel's floats)
                joined = min(table.values(u)) < 0.02
                expected = [max(t, b) for t, b in zip(first, second)] if joined else first
                assert close(lower_bounds(u, table, bound, 0.02), expected), u


def recovery_reference(grid, grid_rows, extra, extra_rows, offsets, terms, base, q, p, target, inflation, eps,
                       inside, resting_grid, resting_extra, resting_by_gamma):
    """The recovery's choice (`energy_kernels.recovery_scan`'s docstring) in numpy: the margins of every candidate at
    every gain end, the first certified candidate nearest the target, else the best resting one."""
    candidates = np.vstack((grid, extra))
    margins, first_gamma = None, None
    for e in range(len(terms)):
        rows = np.hstack((grid_rows[e], extra_rows[e]))
        gamma = np.min(rows + np.array(offsets)[:, None], axis=0)
        first_gamma = gamma if first_gamma is None else first_gamma
        k, a, beta = terms[e]
        x = k * (q - a * candidates) ** 2 + beta * (p - candidates) ** 2
        energy = base + 0.5 * (x[:, 0] + x[:, 1] if x.shape[1] == 2 else np.sum(x, axis=1))
        at_e = gamma - inflation * energy - eps
        margins = at_e if margins is None else np.minimum(margins, at_e)
    squared = (candidates - target) ** 2
    distance = squared[:, 0] + squared[:, 1] if squared.shape[1] == 2 else np.sum(squared, axis=1)
    if inside and np.any(margins >= 0.0):
        return int(np.argmin(np.where(margins >= 0.0, distance, np.inf))), False
    resting = first_gamma >= eps if resting_by_gamma else np.concatenate((resting_grid, resting_extra))
    if not np.any(resting):
        return -1, True
    score = margins if inside else -distance
    return int(np.argmax(np.where(resting, score, -np.inf))), True


def columns(args: tuple) -> tuple:
    """The reference's arguments in the kernel's layout: the commands one column each."""
    grid, grid_rows, extra, *rest = args
    return (np.ascontiguousarray(grid.T), grid_rows, np.ascontiguousarray(extra.T), *rest)


def test_recovery_scan_is_the_numpy_choice():
    """Random states and targets on the reference table, one and two gain ends, both certificates' rules."""
    rng = np.random.default_rng(2)
    table = EscapeEnergyTable(ROBOT, SAFE, ROBOT.array("u_min"), ROBOT.array("u_max"), boundary=True)
    grid, values = table.grid_commands(), table.grid_values()
    k, a = ROBOT.array("stiffness"), ROBOT.array("gains") / ROBOT.array("stiffness")
    beta = np.array([1e-6, 2e-6])
    seen = set()
    for trial in range(120):
        gains = (1.0,) if trial % 2 else (0.9, 1.1)
        terms = np.array([(k, g * a, g * g * beta) for g in gains])
        grid_rows = np.array([values if g == 1.0 else 0.5 * np.maximum(
            table.distance - abs(g - 1.0) * np.sqrt(np.sum(table.weights * grid**2, axis=1)), 0.0) ** 2 for g in gains])
        extra = rng.uniform(-150, 150, (2, 2))
        extra_rows = np.array([np.array([lower_bounds(g * c, table, None) for c in extra]).T for g in gains])
        q, p = rng.uniform(-1.5, 1.5, 2), rng.uniform(-150, 150, 2)
        base = rng.uniform(0.0, 0.05) * (trial % 3 != 0)
        offsets = rng.uniform(-0.02, 0.02, 1)
        args = (grid, grid_rows, extra, extra_rows, offsets, terms, base, q, p, extra[1], 1.0 + 0.5 * (trial % 4 == 1),
                1e-5, bool(trial % 5), table.rest_inside, rng.random(2) < 0.5, trial % 4 == 1)
        expected = recovery_reference(*args)
        got = energy_kernels.recovery_scan(*columns(args))
        assert (int(got[0]), bool(got[1])) == expected
        seen.add(expected[1])
    assert seen == {False, True}  # both certified and infeasible recoveries were compared


@pytest.mark.parametrize("n", [1, 3, 5])
def test_recovery_scan_sums_as_numpy_for_other_n(n):
    """N ≠ 2: numpy's row sums (np.sum over a row of N < 8 entries) are the kernel's sums from the first entry."""
    rng = np.random.default_rng(n)
    for trial in range(60):
        grid = rng.uniform(-150, 150, (500, n))
        rows = rng.uniform(0.0, 0.1, (1, 2, 500))
        extra = rng.uniform(-150, 150, (2, n))
        terms = np.array([(rng.uniform(0.5, 2.0, n), rng.uniform(0.005, 0.02, n), rng.uniform(0.0, 1e-5, n))])
        args = (grid, rows, extra, rng.uniform(0.0, 0.1, (1, 2, 2)), rng.uniform(-0.01, 0.01, 2), terms,
                rng.uniform(0.0, 0.01), rng.uniform(-1.5, 1.5, n), rng.uniform(-150, 150, n), extra[1], 1.5, 1e-5,
                bool(trial % 3), rng.random(500) < 0.3, rng.random(2) < 0.5, trial % 2 == 0)
        got = energy_kernels.recovery_scan(*columns(args))
        assert (int(got[0]), bool(got[1])) == recovery_reference(*args)
