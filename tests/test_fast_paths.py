"""The per-step paths around the model against the plain code they stand in for (the dynamics'
memo, a filter sharing the plant's model, the safe set's point methods, the certificate energy),
and the closed loop's packed recording against a plain per-key one. The model's own per-step
implementation is tested in tests/test_pcc_model.py."""

import math

import numpy as np
import pytest

from controllers.model import pcc
from controllers.cbf.barrier import get_tuning
from controllers.model.dynamics import PCCDynamics
from closedloop.record import TIMESERIES_UNITS
from closedloop.step import ControlStep
from controllers.cbf.paper_filter import CBF_DIAGNOSTIC_UNITS, CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot, uniform_robot
from controllers.model.safe_set import Environment, ForceSafeSet, PowerLawStiffness, paper_safe_set
from derivative_cases import configurations
from controllers.contract.safety_filter import FilterContext
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant

ROBOT = reference_robot()
SAFE = paper_safe_set()


def _states(n: int, count: int = 300) -> list[tuple[list[float], list[float]]]:
    """(q, q̇) as Python lists: the delicate angles of `configurations` and random ones, both branches of ℓ."""
    rng = np.random.default_rng(7)
    qs = [q.tolist() for q in configurations(n)] + rng.uniform(-4.0, 4.0, (count, n)).tolist()
    return [(q, rng.normal(0.0, 3.0, n).tolist()) for q in qs]


def test_dynamics_memo_returns_the_terms_of_the_state_asked_for():
    dyn, fresh = PCCDynamics(ROBOT), PCCDynamics(ROBOT)
    for q, qd in _states(2, 20):
        first = dyn.model_terms(q, qd)
        assert dyn.model_terms(list(q), list(qd)) is first  # same state: kept
        other = dyn.model_terms([q[0] + 1e-9, q[1]], qd)
        assert other is not first and other.ends[-1] != first.ends[-1]
        assert dyn.model_terms(q, qd).mass.tolist() == fresh.model_terms(q, qd).mass.tolist()


def test_filter_sharing_the_plant_dynamics_gives_the_same_commands():
    plant = PCCPlant(ROBOT, SAFE)
    shared = CBFFilter(ROBOT, SAFE, get_tuning("High"), dynamics=plant.dynamics)
    alone = CBFFilter(ROBOT, SAFE, get_tuning("High"))
    state = plant.reset(np.array([0.3, 0.2]))
    for _ in range(300):
        x = np.concatenate((state.q, state.qd))
        a, b = shared.step(x, np.array([150.0, 150.0])), alone.step(x, np.array([150.0, 150.0]))
        assert a.u.tolist() == b.u.tolist() and a.constraint.tolist() == b.constraint.tolist() and a.action == b.action
        state = plant.step(a.u)
    with pytest.raises(ValueError, match="same params"):
        CBFFilter(ROBOT, SAFE, get_tuning("Low"), dynamics=PCCDynamics(uniform_robot(2, mass=0.2)))


@pytest.mark.parametrize("safe_set", [
    paper_safe_set(),
    ForceSafeSet(Environment.from_polygon([[0.05, -0.3], [0.3, -0.1], [0.28, 0.2], [0.0, 0.25]]),
                 PowerLawStiffness(30.0, 1.5), 0.2, row_scaling="unit"),
], ids=["paper", "box"])
def test_point_methods_match_the_array_methods(safe_set):
    rng = np.random.default_rng(3)
    for r in rng.uniform(-0.1, 0.4, (500, 2)):
        x, y = r.tolist()
        # n = n̂·r − d cancels near a facet: equal to the rounding of r (≈ 1e-17 m), not relatively
        np.testing.assert_allclose(safe_set.penetration_at(x, y), safe_set.penetration(r), rtol=0, atol=1e-16)
        np.testing.assert_allclose(safe_set.force_at(x, y), safe_set.force(r), rtol=1e-14, atol=1e-14)
        # ρ = (n_max − n)/n_max: the penetration's 1e-16 m above, the subtraction's rounding
        # (an ulp of n_max − n) over n_max, and the division's ulps of ρ itself
        assert math.isclose(safe_set.margin_at(x, y), float(safe_set.margin(r)), rel_tol=4e-16, abs_tol=2e-16 / safe_set.n_max)


@pytest.mark.parametrize("integrator", ["ros2", "rk4", "euler"])
def test_plant_reports_the_kinematics_of_its_state(integrator):
    plant = PCCPlant(ROBOT, SAFE, integrator=integrator)
    state = plant.reset(np.array([0.7, 0.6]), np.array([1.0, -1.0]))
    for _ in range(30):
        state = plant.step(np.array([150.0, 150.0]))
        np.testing.assert_allclose(state.segment_ends, pcc.segment_ends(state.q, ROBOT.array("lengths")), rtol=0, atol=1e-16)
        np.testing.assert_allclose(state.contact_forces, SAFE.force(state.tip), rtol=1e-14, atol=1e-17)


COMPARED = ("t", "q", "qd", "q_est", "qd_est", "tip", "segment_ends", "u_nom", "u_filter", "u", "u_applied",
            "contact_force", "rho_pred", "rho_meas", "b", "active", "infeasible", "recovery", "action")


def _reference_loop(plant, controller, nominal, n_steps, q0):
    """The closed loop recorded key by key, as plainly as possible."""
    log = {key: [] for key in COMPARED}
    state = plant.reset(q0)
    for _ in range(n_steps):
        u_nom = nominal(state.t, state.q, state.qd)
        res = controller.step(np.concatenate((state.q, state.qd)), u_nom)
        for key, value in (("t", state.t), ("q", state.q), ("qd", state.qd), ("q_est", state.q), ("qd_est", state.qd),
                           ("tip", state.tip), ("segment_ends", state.segment_ends), ("u_nom", res.u_nom),
                           ("u_filter", res.u), ("u", res.u), ("u_applied", state.u_applied),
                           ("contact_force", state.contact_forces), ("rho_pred", res.rho_pred),
                           ("rho_meas", np.min(controller.safe_set.margin_from_force(state.contact_forces))),
                           ("b", res.b), ("active", res.active), ("infeasible", res.infeasible),
                           ("recovery", res.recovery), ("action", np.int8(0))):
            log[key].append(np.copy(value))
        state = plant.step(res.u)
    return {key: np.array(values) for key, values in log.items()}


def test_packed_recording_matches_a_plain_one():
    """The one recorder (closedloop.record) through the simulated loop, against a plain key-by-key loop."""
    nominal = SinusoidNominal.paper(2, 150.0, 0.5)
    q0 = np.array([0.3, 0.1])
    step = ControlStep(CBFFilter(ROBOT, SAFE, get_tuning("Low")), nominal, FilterContext.for_robot(ROBOT, SAFE, 1e-3))
    log, units = run_closed_loop(PCCPlant(ROBOT, SAFE), step, SAFE, 1.5, q0)
    ref = _reference_loop(PCCPlant(ROBOT, SAFE), CBFFilter(ROBOT, SAFE, get_tuning("Low")), nominal, 1500, q0)
    assert set(units) == set(log) and set(COMPARED) <= set(log)
    assert units["b"] == CBF_DIAGNOSTIC_UNITS["b"] and units["u"] == TIMESERIES_UNITS["u"]
    assert np.any(log["active"]) and np.any(log["rho_meas"] < 1)  # the run exercises the filter and the contact
    assert np.all(np.isfinite(log["filter_us"]))
    for key in COMPARED:
        assert log[key].shape == ref[key].shape and log[key].dtype == ref[key].dtype, key
        np.testing.assert_array_equal(log[key], ref[key], err_msg=key)


@pytest.mark.parametrize("tau", [0.0, 0.05])
def test_two_segment_certificate_energy_is_the_per_segment_sum(tau):
    """`GovernorModel.energy` for N = 2 against the per-segment sum in Python floats, within 1e-14 relative (the
    kernel squares as x·x, Python's `**` calls libm's pow: each may differ in the last bit)."""
    from controllers.governors.energy_governor import EnergyGovernor

    gov = EnergyGovernor(FilterContext.for_robot(ROBOT, SAFE, 1e-3, actuator_tau=tau))
    k, a, beta = ROBOT.array("stiffness").tolist(), (ROBOT.array("gains") / ROBOT.array("stiffness")).tolist(), gov.model.beta.tolist()
    assert any(beta) == (tau > 0)
    rng = np.random.default_rng(11)
    for _ in range(500):
        base, q, p, u = float(rng.uniform(0.0, 0.1)), rng.uniform(-3, 3, 2).tolist(), rng.uniform(-300, 300, 2).tolist(), tuple(rng.uniform(-300, 300, 2).tolist())
        total = base
        for ki, ai, bi, qi, pi, ui in zip(k, a, beta, q, p, u):
            e = qi - ai * ui
            total += 0.5 * (ki * e * e + bi * (pi - ui) ** 2)
        assert gov.model.energy(base, q, p, u) == pytest.approx(total, rel=1e-14, abs=0.0)
