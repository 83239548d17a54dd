"""The energy governor's configuration, model and per-run state as separate objects
(`controllers.governors.energy_governor`): frozen parameters validated once, a model no call changes, and one state per
simulation row advanced by `step` / `step_rows` (a batch is a list of states)."""

import dataclasses
import math

import numpy as np
import pytest

from controllers.governors.energy_governor import (ContactEnergyGovernor, ContactGovernorParams, EnergyGovernor, GovernorParams,
                                         new_state, step, step_rows)
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, EstimateBatch, FilterContext

ROBOT = reference_robot()
SAFE = paper_safe_set()
COARSE = {"grid_hPa": 10.0, "escape_spacing_rad": 8e-3}  # small tables
STATIC_GAIN = ROBOT.array("gains") / ROBOT.array("stiffness")
PUSHES = np.array([[40.0, 40.0], [150.0, 150.0], [70.0, 20.0]])  # resting, pressing the plate, elsewhere (hPa)


def contact_governor(**extra) -> ContactEnergyGovernor:
    return ContactEnergyGovernor(FilterContext.for_robot(ROBOT, SAFE, 0.1), command_delay_s=0.02, actuator_tau_s=0.05,
                                 gain_lo_ratio=0.9, gain_hi_ratio=1.1, gain_estimate=True, gain_rest_s=0.15,
                                 **COARSE, **extra)


def inputs(i: int, b: int) -> tuple[Estimate, np.ndarray]:
    """Row b's i-th estimate (10 Hz): at the rest shape of its command, moving for its first b + 1 calls."""
    t = 0.1 * i
    q = STATIC_GAIN * np.minimum(PUSHES[b], 20.0 * (i + 1))
    qd = np.full(2, 0.05 if i <= b else 0.0)
    return Estimate(t, q, qd, t), PUSHES[b]


def same(out, want) -> None:
    assert out.action == want.action and out.infeasible == want.infeasible
    assert np.array_equal(out.u, want.u)
    assert {k: v for k, v in out.diagnostics.items() if k != "solve_us"} == pytest.approx(
        {k: v for k, v in want.diagnostics.items() if k != "solve_us"}, rel=0, abs=0, nan_ok=True)


def test_a_list_of_states_steps_as_each_state_alone():
    """`step_rows` over three states (different commands and rest times) equals `step` on each state alone, call
    by call, bit for bit (commands, actions, diagnostics but the wall time), and leaves each its own gain interval."""
    model = contact_governor().model
    together, alone = [new_state(model) for _ in PUSHES], [new_state(model) for _ in PUSHES]
    narrowed = set()
    for i in range(14):
        calls = [inputs(i, b) for b in range(len(PUSHES))]
        outs = step_rows(model, together, [e.q for e, _ in calls], [e.qd for e, _ in calls], [u for _, u in calls],
                         [e.t_capture for e, _ in calls], [e.t + model.command_delay for e, _ in calls])
        for b, (estimate, u_nom) in enumerate(calls):
            state, want = step(model, alone[b], estimate, u_nom)
            assert state is alone[b]  # the state advanced is the one passed in
            same(outs[b], want)
            assert together[b].ends.lo == alone[b].ends.lo and together[b].ends.hi == alone[b].ends.hi
            if (alone[b].ends.lo, alone[b].ends.hi) != (0.9, 1.1):
                narrowed.add(b)
    assert narrowed  # the rows' own gain estimates did narrow: the comparison covers the feedback


def test_rows_share_no_state():
    """Each `filter_batch` row holds a state of its own: distinct predictors, gain estimators and target governors;
    calling row 0 alone leaves row 1 as it was, and row 1 then continues as a governor called only with its own
    estimates. A copied state continues without touching the original."""
    gov, own = contact_governor(), contact_governor()
    first = [inputs(0, b) for b in range(2)]
    batch = lambda calls, rows: gov.filter_batch(  # noqa: E731
        EstimateBatch(np.array([e.t for e, _ in calls]), np.array([e.q for e, _ in calls]),
                      np.array([e.qd for e, _ in calls]), np.array([e.t_capture for e, _ in calls])),
        np.array([u for _, u in calls]), rows=rows)
    batch(first, [0, 1])
    own(*first[1])
    a, b = gov.rows
    assert a is not b and a.predictor is not b.predictor and a.gain_estimator is not b.gain_estimator
    latest, samples = b.predictor.latest_time, b.gain_estimator.samples
    for i in range(1, 6):
        batch([inputs(i, 0)], [0])
    assert a.predictor.latest_time > latest and b.predictor.latest_time == latest
    assert b.gain_estimator.samples == samples
    out = batch([inputs(6, 1)], [1])
    want = own(*inputs(6, 1))
    assert out.action[0] == want.action and np.array_equal(out.u[0], want.u)
    twin = a.copy()
    before = (a.predictor.latest_time, a.gain_estimator.samples, a.ends)
    step(gov.model, twin, *inputs(7, 0))
    assert twin.predictor.latest_time > before[0]
    assert (a.predictor.latest_time, a.gain_estimator.samples, a.ends) == before


def test_parked_rows_hold_their_own_target_governor():
    """The parked certificate's rows each hold their own quasi-static target governor (its warm start is state)."""
    gov = EnergyGovernor(FilterContext.for_robot(ROBOT, SAFE, 0.1), command_delay_s=0.02, **COARSE)
    calls = [inputs(0, b) for b in range(3)]
    gov.filter_batch(EstimateBatch(np.array([e.t for e, _ in calls]), np.array([e.q for e, _ in calls]),
                                   np.array([e.qd for e, _ in calls]), np.array([e.t_capture for e, _ in calls])),
                     np.array([u for _, u in calls]))
    targets = [s.target_governor for s in gov.rows] + [gov.state.target_governor]
    assert len({id(t) for t in targets}) == 4 and gov.model.target_governor not in targets


def test_reset_rows_resets_only_those_states():
    """reset(rows=[1]) starts row 1's state afresh (vented, the prior gain interval) and leaves rows 0 and 2, the
    same objects, where they were; row 1 then continues as a new governor's first call."""
    gov = contact_governor()
    for i in range(8):
        calls = [inputs(i, b) for b in range(3)]
        gov.filter_batch(EstimateBatch(np.array([e.t for e, _ in calls]), np.array([e.q for e, _ in calls]),
                                       np.array([e.qd for e, _ in calls]), np.array([e.t_capture for e, _ in calls])),
                         np.array([u for _, u in calls]))
    kept = [gov.rows[0], gov.rows[2]]
    before = [(s.predictor.latest_time, s.gain_estimator.samples, s.ends) for s in kept]
    assert gov.rows[1].predictor.latest_time > 0.0
    gov.reset(rows=[1])
    assert [gov.rows[0], gov.rows[2]] == kept  # the same objects
    assert [(s.predictor.latest_time, s.gain_estimator.samples, s.ends) for s in kept] == before
    assert gov.rows[1].predictor.latest_time == -math.inf and gov.rows[1].gain_estimator.samples == 0
    assert gov.gain_interval(1) == (0.9, 1.1)
    estimate, u_nom = inputs(8, 1)
    out = gov.filter_batch(EstimateBatch(np.array([estimate.t]), estimate.q[None], estimate.qd[None],
                                         np.array([estimate.t_capture])), u_nom[None], rows=[1])
    want = contact_governor()(estimate, u_nom)
    assert out.action[0] == want.action and np.array_equal(out.u[0], want.u)


def test_parameters_are_frozen_typed_and_validated_once():
    """One declaration: the c-erg's parameters are the e-erg's with the contact defaults; the values are checked
    and normalised at construction, refused with the parameter's name, and cannot change afterwards; the c-erg
    takes no margin_m or certificate."""
    params = ContactGovernorParams(kappa=1, bisection_steps=np.int64(8))
    assert (params.certificate, params.contact_aware, params.kappa, params.bisection_steps) == ("contact", True, 1.0, 8)
    assert type(params.kappa) is float and type(params.bisection_steps) is int
    assert [f.name for f in dataclasses.fields(ContactGovernorParams)] == [f.name for f in dataclasses.fields(GovernorParams)]
    with pytest.raises(dataclasses.FrozenInstanceError):
        params.kappa = 2.0
    with pytest.raises(ValueError, match="kappa must be in"):
        GovernorParams(kappa=-1.0)
    with pytest.raises(ValueError, match="gain_lo_ratio must be <= gain_hi_ratio"):
        ContactGovernorParams(gain_lo_ratio=1.1, gain_hi_ratio=0.9)
    with pytest.raises(ValueError, match="need certificate='contact'"):
        GovernorParams(gain_lo_ratio=0.9)
    with pytest.raises(TypeError, match="margin_m"):
        ContactEnergyGovernor(FilterContext.for_robot(ROBOT, SAFE, 0.1), margin_m=1e-3)
    assert ContactEnergyGovernor.check_arguments({"kappa": 2}) == {"kappa": 2.0, "certificate": "contact"}


def test_calls_never_change_the_model():
    """The model (tables, bounds, weights, the recovery's grid) is what it was after calls pressing the plate (one
    with a jolt of velocity) and resets."""
    gov = contact_governor()
    model = gov.model
    arrays = {name: np.array(getattr(model, name), copy=True) for name in ("grid_values", "grid", "rest", "beta", "credit")}
    for i in range(10):
        gov(Estimate(0.1 * i, STATIC_GAIN * 150.0, np.full(2, 0.5 if i == 3 else 0.0), 0.1 * i), PUSHES[1])
    gov.reset(rows=[0])
    gov.reset()
    assert gov.model is model
    for name, value in arrays.items():
        assert np.array_equal(getattr(model, name), value)
    with pytest.raises(dataclasses.FrozenInstanceError):
        model.n = 3
