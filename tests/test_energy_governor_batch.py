"""e-erg and c-erg batched (`EnergyGovernor.filter_batch`, issue 23): row b is, bit for bit, the b-th of B
governors called in turn (their own command histories, target warm starts and gain estimates), through
resets of every row or of some, rows called in subsets (`rows=`), stale estimates and refused times; one
compiled step 3 for every row (`energy_kernels.govern_rows`)."""

import copy
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controllers.governors.energy_governor import ContactEnergyGovernor, EnergyGovernor
from controllers.core.errors import ControllerInputError, NonFiniteStateError
from controllers.model.params import reference_robot, uniform_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import Estimate, EstimateBatch, FilterContext

ROBOT = reference_robot()
SAFE = paper_safe_set()
COARSE = {"grid_hPa": 10.0, "escape_spacing_rad": 8e-3}  # small tables: the test builds many governors


def governor(certificate: str, gains: tuple, estimate: bool, period: float, robot=ROBOT):
    ctx = FilterContext.for_robot(robot, SAFE, period)
    if certificate == "park":
        return EnergyGovernor(ctx, command_delay_s=0.02, actuator_tau_s=0.05, **COARSE)
    return ContactEnergyGovernor(ctx, command_delay_s=0.02 if period > 0.01 else 0.0, actuator_tau_s=0.05,
                                 stiffness_lo_ratio=0.9, stiffness_hi_ratio=1.1, gain_lo_ratio=gains[0],
                                 gain_hi_ratio=gains[1], gain_estimate=estimate, gain_difference_s=0.002,
                                 gain_rest_s=period, **COARSE)  # a rest sample needs the previous estimate at rest too


def assert_rows_match(out, want):
    assert out.action.tolist() == [w.action for w in want]
    assert np.array_equal(out.u, np.array([w.u for w in want]))
    assert out.infeasible.tolist() == [w.infeasible for w in want]
    assert np.array_equal(out.rho_pred, np.array([w.rho_pred for w in want]), equal_nan=True)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), certificate=st.sampled_from(["park", "contact"]),
       gains=st.sampled_from([(1.0, 1.0), (0.9, 1.1)]), estimate=st.booleans(), camera=st.booleans(),
       n_rows=st.integers(1, 5), warm=st.integers(0, 2), subsets=st.booleans(), three=st.booleans())
def test_filter_batch_is_b_scalar_governors_bit_for_bit(seed, certificate, gains, estimate, camera, n_rows, warm,
                                                         subsets, three):
    """Closed-loop-like sequences (rest shapes drifting to and beyond the plate, velocities large enough to
    violate, nominals held, drifting and jumping beyond the box; resets of all rows or of some; rows called in
    subsets, some with estimates older than the predictor's horizon): commands, actions, flags and ρ_pred of
    every row equal those of B copies of the governor, bit for bit. c-erg also on a 3-segment arm (no table:
    the second-order bound alone)."""
    period = 0.1 if camera else 0.001
    three = three and certificate == "contact"
    robot = uniform_robot(3) if three else ROBOT
    n = robot.n_segments
    static_gain = robot.array("gains") / robot.array("stiffness")
    gov = governor(certificate, gains if certificate == "contact" else (1.0, 1.0),
                   estimate and certificate == "contact", period, robot)
    rng = np.random.default_rng(seed)
    t = 0.0
    for _ in range(warm):  # scalar calls first: the rows start from the governor's state
        gov(Estimate(t, np.zeros(n), np.zeros(n), t), rng.uniform(-150, 150, n))
        t += period
    copies = [copy.deepcopy(gov) for _ in range(n_rows)]
    u_nom = rng.uniform(0.0, 150.0, (n_rows, n))
    centre = rng.uniform(0.0, 80.0, (n_rows, n))
    actions = set()
    for k in range(30):
        kind = rng.integers(7)
        if kind == 0:
            u_nom = rng.uniform(-400.0, 400.0, (n_rows, n))  # jumps, beyond the box
        elif kind == 1 and rng.random() < 0.5:
            gov.reset()
            for c in copies:
                c.reset()
            t = 0.0
        elif kind == 1:  # some rows' new episodes
            some = np.flatnonzero(rng.random(n_rows) < 0.5)
            gov.reset(rows=some)
            for b in some:
                copies[b].reset()
        elif kind < 5:
            u_nom = np.clip(u_nom + rng.normal(0.0, 20.0, u_nom.shape), -150.0, 150.0)  # drifts (kind 5, 6: held)
        centre = np.clip(centre + rng.normal(0.0, 8.0, centre.shape), -20.0, 120.0)
        q = static_gain * centre + rng.normal(0.0, 0.02, centre.shape)
        qd = rng.normal(0.0, 0.3, centre.shape) * (rng.random((n_rows, 1)) < 0.7)
        ids = np.arange(n_rows)
        if subsets:
            ids = np.flatnonzero(rng.random(n_rows) < 0.7)
            ids = ids if len(ids) else rng.integers(n_rows, size=1)
        age = rng.uniform(0.03, 0.1, len(ids)) if camera else np.zeros(len(ids))
        age[rng.random(len(ids)) < 0.05] = 5.0  # beyond the prediction horizon: "stale"
        estimates = EstimateBatch(np.full(len(ids), t), q[ids], qd[ids], t - age)
        out = gov.filter_batch(estimates, u_nom[ids], rows=ids) if subsets else gov.filter_batch(estimates, u_nom)
        want = [copies[b](estimates[i], u_nom[b]) for i, b in enumerate(ids)]
        assert_rows_match(out, want)
        actions.update(out.action.tolist())
        t += period
    assert actions & {"governed", "hold", "recover"}  # the certificate bound somewhere, not only "free"


def test_filter_batch_refuses_before_any_history_changes_and_counts_its_rows():
    """A row whose time goes backwards raises ControllerInputError with no history changed (the batched step
    then calls the rows one by one); a non-finite row raises for the call; fewer rows than histories without
    `rows` raise ValueError; bad `rows` raise ValueError."""
    gov = governor("contact", (1.0, 1.0), False, 0.1)
    twin = copy.deepcopy(gov)
    rest = EstimateBatch(np.array([0.5, 0.5]), np.zeros((2, 2)), np.zeros((2, 2)), np.array([0.45, 0.45]))
    push = np.full((2, 2), 150.0)
    first = gov.filter_batch(rest, push)
    assert first.action.tolist() == [twin(rest[0], push[0]).action] * 2
    backwards = EstimateBatch(np.array([0.6, 0.1]), np.zeros((2, 2)), np.zeros((2, 2)), np.array([0.55, 0.05]))
    with pytest.raises(ControllerInputError, match="row 1: t must not go backwards"):
        gov.filter_batch(backwards, push)
    later = EstimateBatch(np.array([0.6, 0.6]), np.zeros((2, 2)), np.zeros((2, 2)), np.array([0.55, 0.55]))
    want = twin(later[0], push[0])
    out = gov.filter_batch(later, push)  # row 0's history did not see the refused call
    assert np.array_equal(out.u[0], want.u) and np.array_equal(out.u[1], want.u)
    with pytest.raises(NonFiniteStateError, match="non-finite rows"):
        gov.filter_batch(EstimateBatch(np.array([0.7, 0.7]), np.array([[0.0, math.nan], [0.0, 0.0]]),
                                       np.zeros((2, 2)), np.array([0.7, 0.7])), push)
    with pytest.raises(ValueError, match="holds 2 and was called with 1 rows"):
        gov.filter_batch(EstimateBatch(np.array([0.7]), np.zeros((1, 2)), np.zeros((1, 2)), np.array([0.7])),
                         push[:1])
    for rows in ([0, 0], [-1, 1], [0.5, 1.0]):
        with pytest.raises(ValueError, match="rows must be"):
            gov.filter_batch(later, push, rows=np.array(rows))
    gov.reset(rows=np.array([1]))  # row 1 anew: its first call after a reset, row 0 goes on
    fresh = copy.deepcopy(gov)
    fresh.reset()
    out = gov.filter_batch(EstimateBatch(np.array([0.8]), np.zeros((1, 2)), np.zeros((1, 2)), np.array([0.75])),
                           push[:1], rows=np.array([1]))
    assert np.array_equal(out.u[0], fresh(Estimate(0.8, np.zeros(2), np.zeros(2), 0.75), push[0]).u)


@pytest.mark.parametrize("certificate", ["park", "contact"])
def test_a_batched_pcc_loop_with_one_shared_governor_equals_its_serial_loops(certificate):
    """run_batch_closed_loop calls the shared governor's filter_batch once per period (rows=, as the batched
    step does): the commands of each simulation are, bit for bit, those of the serial loop with a governor of
    its own, pushing towards the plate (the certificate binds)."""
    from closedloop.step import ControlStep
    from controllers.nominal import SinusoidNominal
    from softcbf_mj.loops.batch_loop import run_batch_closed_loop
    from softcbf_mj.loops.loop import run_closed_loop
    from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant
    from softcbf_mj.physics.pcc_plant import PCCPlant

    nominal = SinusoidNominal((100.0, 100.0), 1.0, (np.pi / 2, np.pi / 2))
    q0 = np.random.default_rng(5).normal(0.3, 0.1, (3, 2))
    plant = PCCBatchPlant(ROBOT, SAFE, 3)
    ctx = FilterContext.for_robot(ROBOT, SAFE, plant.control_dt)

    def build():
        cls = EnergyGovernor if certificate == "park" else ContactEnergyGovernor
        return cls(ctx, **COARSE)

    shared, served = build(), []
    original = shared.filter_batch

    def counted(estimates, u_nom, rows=None):
        served.append(len(estimates))
        return original(estimates, u_nom, rows=rows)

    shared.filter_batch = counted
    batch = run_batch_closed_loop(plant, shared, nominal, ctx, 0.4, q0, record_commands=True)
    assert served and max(served) == 3  # one call per period for the simulations
    governed = 0
    for b in range(3):
        log, _ = run_closed_loop(PCCPlant(ROBOT, SAFE), ControlStep(build(), nominal, ctx), SAFE, 0.4, q0[b])
        assert np.array_equal(batch.commands[:, b], log["u"])
        governed += int(np.sum(np.any(log["u"] != log["u_nom"], axis=1)))
    assert governed > 0  # the certificate bound


def test_each_rows_rest_time_is_its_own():
    """`gain_rest_s` counts each history's own estimates at rest: held at the model's rest shape of 40 hPa at
    10 Hz, row 0 at rest from the start and row 1 moving (|q̇| above gain_rest_rad_s) for its first five
    estimates, one batched governor narrows each row's certified gain interval (`gain_interval(row)`) when a
    governor of its own does (its first sample: 0.3 s and 0.8 s with gain_rest_s = 0.25 s), with the same
    commands."""
    make = lambda: ContactEnergyGovernor(FilterContext.for_robot(ROBOT, SAFE, 0.1), actuator_tau_s=0.05,  # noqa: E731
                                         gain_lo_ratio=0.9, gain_hi_ratio=1.1, gain_estimate=True, gain_rest_s=0.25,
                                         **COARSE)
    shared, own = make(), [make(), make()]
    u = np.full((2, 2), 40.0)
    q = np.tile(ROBOT.array("gains") / ROBOT.array("stiffness") * 40.0, (2, 1))
    first = [None, None]
    for i in range(12):
        t = 0.1 * i
        qd = np.array([[0.0, 0.0], [0.05, 0.05] if i < 5 else [0.0, 0.0]])
        out = shared.filter_batch(EstimateBatch(np.full(2, t), q, qd, np.full(2, t)), u)
        for b in range(2):
            want = own[b](Estimate(t, q[b], qd[b], t), u[b])
            assert np.array_equal(out.u[b], want.u)
            interval = shared.gain_interval(b)
            assert interval == own[b].gain_interval()
            if first[b] is None and interval != (0.9, 1.1):  # the first sample narrows the prior
                first[b] = t
    assert first == [pytest.approx(0.3), pytest.approx(0.8)]


@pytest.mark.slow
def test_rows_that_learn_different_plates_are_their_own_governors_bit_for_bit():
    """c-erg over the standard box with `plate_estimate`, two rows pushing 150 hPa for 6 s at 10 Hz on PCC plants with
    different plates (the model's, and one 20 % stiffer and 2 mm nearer): each row learns its own plate (their
    certificates differ, so step 3 runs per plate), and every command equals, bit for bit, that of a governor of
    its own fed the same estimates."""
    import sys
    from pathlib import Path

    from controllers.governors.energy_governor.parameters import STANDARD_BOX_SETTING

    sys.path.insert(0, str(Path(__file__).parent))
    from test_certificate_box import true_plant

    ctx = FilterContext(ROBOT, SAFE, ROBOT.array("u_min"), ROBOT.array("u_max"), 0.1, 0.0, 0.05)
    options = {**STANDARD_BOX_SETTING, "plate_estimate": True, "gain_noise_rad": 1e-4, **COARSE}
    shared, alone = ContactEnergyGovernor(ctx, **options), [ContactEnergyGovernor(ctx, **options) for _ in range(2)]
    plants = [true_plant(), true_plant(plate=1.2, offset=-0.002)]
    states = [plant.reset(np.zeros(2)) for plant in plants]
    u_nom = np.full((2, 2), 150.0)
    for _ in range(60):
        t = states[0].t
        batch = shared.filter_batch(EstimateBatch(np.full(2, t), np.array([s.q for s in states]),
                                                  np.array([s.qd for s in states]), np.full(2, t)), u_nom)
        want = [gov(Estimate(t, s.q, s.qd, t), u_nom[b]) for b, (gov, s) in enumerate(zip(alone, states))]
        assert_rows_match(batch, want)
        for b, plant in enumerate(plants):
            for _ in range(100):
                states[b] = plant.step(batch.u[b])
    boxes = [row.plate.box for row in shared.rows]
    assert all(row.plate is not shared.model.plate for row in shared.rows) and boxes[0] != boxes[1]
