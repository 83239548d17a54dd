"""Property-based tests of the CBF filter (hypothesis): its guarantees over random robots,
safe sets, tunings, states and nominal commands, every QP backend, limits on and off.

Guarantee checked (controllers/cbf/paper_filter.py, module docstring): the command is finite, inside
[u_min, u_max] when the limits are on, and either every defined CBF row holds at it within
the QP's acceptance tolerance (`controllers.cbf.qp.tolerances`, hPa on unit rows) or the step is
flagged `infeasible`. A row whose terms are not finite must never pass unflagged. The rows
are recomputed here through `barrier_terms` (the compiled rows the filter's kernel runs, checked against
finite differences in tests/test_cbf.py) from the filter's own model.
Bad inputs raise only the documented errors: ControllerInputError subclasses from
`step`, ValueError from the constructors of RobotParams, Tuning, ForceSafeSet and CBFFilter.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, event, given, settings
from hypothesis import strategies as st

from controllers.cbf.barrier import B_MIN, TUNINGS, Tuning, barrier_terms
from controllers.core.errors import ControllerInputError
from controllers.cbf.paper_filter import ACTIONS, CBFFilter
from controllers.model.params import RobotParams
from controllers.cbf.qp import available_backends, tolerances
from controllers.model.safe_set import Environment, ForceSafeSet, LinearStiffness, PowerLawStiffness

SETTINGS = settings(max_examples=150, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def log_uniform(lo_exp: float, hi_exp: float):
    return st.floats(lo_exp, hi_exp).map(lambda e: 10.0**e)


@st.composite
def robots(draw) -> RobotParams:
    """1–3 segments; lengths 2 cm–0.5 m, masses 10 g–3 kg, k 0.1–10 N·m/rad, 10–60° at 80 hPa, limits 10–1000 hPa."""
    n = draw(st.integers(1, 3))
    per = lambda strategy: draw(st.lists(strategy, min_size=n, max_size=n))  # noqa: E731
    stiffness = per(log_uniform(-1, 1))
    bend = per(st.floats(math.radians(10), math.radians(60)))
    limit = per(log_uniform(1, 3))
    try:
        return RobotParams(lengths=per(st.floats(0.02, 0.5)), masses=per(log_uniform(-2, 0.5)), stiffness=stiffness,
                           damping=[k * d for k, d in zip(stiffness, per(st.floats(0.0, 0.5)))],
                           gains=[k * a / 80.0 for k, a in zip(stiffness, bend)],
                           u_min=[-v for v in limit], u_max=limit)
    except ValueError:  # e.g. the mass-matrix condition bound: a valid refusal, not this test's subject
        assume(False)


@st.composite
def safe_sets(draw, reach: float) -> ForceSafeSet:
    """A random polygon or 1–3 facets around the arm's reach, both stiffness laws and row scalings."""
    if draw(st.booleans()):
        k = draw(st.integers(3, 6))
        angles = np.sort(np.array(draw(st.lists(st.floats(0, 2 * math.pi), min_size=k, max_size=k, unique=True))))
        radius = draw(st.floats(0.3, 1.5)) * reach
        centre = np.array(draw(st.tuples(st.floats(-0.5, 0.5), st.floats(-0.5, 0.5)))) * reach
        vertices = centre + radius * np.column_stack((np.cos(angles), np.sin(angles)))
        make = lambda: Environment.from_polygon(vertices)  # noqa: E731
    else:
        p = draw(st.integers(1, 3))
        directions = np.array(draw(st.lists(st.floats(-math.pi, math.pi), min_size=p, max_size=p)))
        normals = np.column_stack((np.cos(directions), np.sin(directions)))
        distances = np.array(draw(st.lists(st.floats(0.2, 1.2), min_size=p, max_size=p))) * reach
        if draw(st.booleans()):
            normals[0] = [1.0, 0.0]  # a vertical facet: "paper" scaling falls back to unit rows
        make = lambda: Environment.from_facets(normals * distances[:, None], normals)  # noqa: E731
    law = (LinearStiffness(draw(log_uniform(0, 3))) if draw(st.booleans())
           else PowerLawStiffness(draw(log_uniform(0, 3)), draw(st.floats(1.0, 2.0))))
    try:
        return ForceSafeSet(make(), law, draw(log_uniform(-2, 1)), draw(st.sampled_from(["paper", "unit"])))
    except ValueError:  # redundant facets, an empty free space: refused by validation
        assume(False)


@st.composite
def tunings(draw) -> Tuning:
    if draw(st.booleans()):
        return draw(st.sampled_from(list(TUNINGS.values())))
    a_e, b_e, gamma = draw(st.tuples(log_uniform(-6, 150), log_uniform(-6, 150), log_uniform(-6, 300)))
    assume(math.isfinite(2.0 * a_e * b_e))
    return Tuning("random", a_e, b_e, gamma)


def magnitudes(typical: float, huge_exp: float):
    """Typical values, or huge finite ones of either sign."""
    return st.one_of(st.floats(-typical, typical),
                     st.tuples(st.sampled_from([-1.0, 1.0]), st.floats(0.0, huge_exp)).map(lambda t: t[0] * 10.0**t[1]))


@st.composite
def cases(draw):
    robot = draw(robots())
    n = robot.n_segments
    safe = draw(safe_sets(sum(robot.lengths)))
    filt = CBFFilter(robot, safe, draw(tunings()), pressure_limits=draw(st.booleans()),
                     qp_backend=draw(st.sampled_from(available_backends())))
    q = draw(st.lists(st.floats(-3.0, 3.0), min_size=n, max_size=n))
    qd = draw(st.lists(magnitudes(10.0, 200.0), min_size=n, max_size=n))
    u_nom = draw(st.lists(magnitudes(2.0 * max(robot.u_max), 15.0), min_size=n, max_size=n))
    return filt, np.array(q + qd), np.array(u_nom)


@SETTINGS
@given(cases())
def test_command_is_finite_bounded_and_safe_or_flagged(case):
    filt, x, u_nom = case
    n = filt.n
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no overflow/invalid warnings leak out of the filter either
        res = filt.step(x, u_nom)
    assert res.action in ACTIONS and res.u.shape == (n,)
    event(f"action {res.action}, infeasible {res.infeasible}")
    assert np.all(np.isfinite(res.u)), res
    if filt.pressure_limits:
        assert np.all(res.u >= filt.params.u_min) and np.all(res.u <= filt.params.u_max), res.u
    if not filt.enabled:
        assert res.action == "disabled"
        return
    with np.errstate(all="ignore"):
        terms = barrier_terms(filt.dynamics.evaluate(x[:n], x[n:]), filt.safe_set.H_prime, filt.safe_set.h_prime,
                              filt.tuning)
        c = filt.tuning.gamma / terms.B - terms.LfB
    assert res.recovery == bool(np.any(terms.b <= B_MIN))
    tol = tolerances(u_nom.tolist(), list(filt.params.u_min) if filt.pressure_limits else None,
                     list(filt.params.u_max) if filt.pressure_limits else None)[1]
    for i in np.flatnonzero(terms.b > B_MIN):
        a = terms.LgB[i]
        if not (np.all(np.isfinite(a)) and math.isfinite(c[i])):
            assert res.infeasible, f"row {i} is not finite and the step is not flagged: {res}"
            continue
        with np.errstate(all="ignore"):
            excess = (a @ res.u - c[i]) / max(np.linalg.norm(a), 1e-300)
        assert res.infeasible or excess <= tol or (np.linalg.norm(a) == 0.0 and c[i] >= 0.0), \
            f"row {i} violated by {excess:.3g} hPa (tolerance {tol:.3g}), not flagged: {res.action}"


NON_REAL = st.sampled_from([math.nan, math.inf, -math.inf, 1 + 2j, "a", None, 10**400, [1.0], b"x"])


@settings(max_examples=150, deadline=None, derandomize=True)
@given(robots(), st.integers(0, 1), st.integers(0, 3), NON_REAL, st.booleans())
def test_bad_step_inputs_raise_only_controller_input_errors(robot, which, index, junk, wrong_shape):
    filt = CBFFilter(robot, ForceSafeSet(Environment(np.array([[0.36, 1.0]]), np.array([0.15])), LinearStiffness(11.16),
                                         0.16, "paper"), TUNINGS["Low"])
    n = robot.n_segments
    args = [np.zeros(2 * n).tolist(), np.zeros(n).tolist()]
    if wrong_shape:
        args[which] = args[which] + [0.0]
    else:
        args[which] = list(args[which])
        args[which][index % len(args[which])] = junk
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ControllerInputError):
            filt.step(*args)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(st.sampled_from(["lengths", "masses", "stiffness", "damping", "gains", "u_min", "u_max", "inertias",
                        "a_E", "gamma", "f_max", "k", "exponent", "slack_weight", "recovery_margin"]),
       st.one_of(NON_REAL, st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**400, 10**400)))
def test_bad_configuration_raises_only_value_errors(field, value):
    robot = dict(lengths=[0.122, 0.122], masses=[0.13, 0.13], stiffness=[1.0, 1.0], damping=[0.07, 0.07],
                 gains=[5e-3, 5e-3], u_min=[-150.0, -150.0], u_max=[150.0, 150.0], inertias=None)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            if field in robot:
                robot[field] = [value, robot[field][1] if robot[field] else 1e-4]
                params = RobotParams(**robot)
            else:
                params = RobotParams(**robot)
            tuning = Tuning("t", value, 1.0, 1.0) if field == "a_E" else Tuning("t", 1.0, 1.0, value) if field == "gamma" \
                else TUNINGS["Low"]
            law = (LinearStiffness(value) if field == "k" else PowerLawStiffness(1.0, value) if field == "exponent"
                   else LinearStiffness(11.16))
            safe = ForceSafeSet(Environment(np.array([[0.36, 1.0]]), np.array([0.15])), law,
                                value if field == "f_max" else 0.16, "paper")
            extra = {field: value} if field in ("slack_weight", "recovery_margin") else {}
            filt = CBFFilter(params, safe, tuning, **extra)
        except ValueError:
            return
    res = filt.step(np.zeros(4), np.zeros(2))  # whatever was accepted must work
    assert np.all(np.isfinite(res.u))
