"""PCCBatchPlant and BatchDynamics against PCCPlant and PCCDynamics: bit for bit, N = 2 and 3."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from controllers.model.dynamics import PCCDynamics
from controllers.model.dynamics_batch import BatchDynamics
from controllers.model.params import reference_robot, uniform_robot
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant
from softcbf_mj.physics.pcc_plant import PCCPlant


@pytest.mark.parametrize("n", [2, 3])
def test_batch_dynamics_equals_scalar_path_bit_for_bit(n):
    params = reference_robot() if n == 2 else uniform_robot(n)
    scalar, batch = PCCDynamics(params), BatchDynamics(params)
    rng = np.random.default_rng(0)
    q = rng.uniform(-3.5, 3.5, (500, n))  # both sides of the series switch |q| = 2
    q[:50] = rng.normal(0.0, 1e-6, (50, n))  # near the straight arm
    qd, u = rng.normal(0.0, 3.0, (500, n)), rng.uniform(-200.0, 200.0, (500, n))
    terms = batch.terms(q, qd)
    acc = batch.acceleration(terms, u)
    for b in range(len(q)):
        ev = scalar.evaluate_floats(q[b].tolist(), qd[b].tolist())
        core = scalar.model_terms(q[b].tolist(), qd[b].tolist())
        want = [*ev.tip, *core.mass.ravel().tolist(), *core.force.tolist(), *scalar.acceleration_from_terms(core, u[b].tolist())]
        got = [terms.tip[b], terms.tip_vel[b], terms.tip_drift_acc[b], *terms.tip_input_acc[b].tolist(),
               *terms.mass[b].ravel().tolist(), *terms.force[b].tolist(), *acc[b].tolist()]
        assert got == want, b


def _robots(count: int, n: int = 2):
    ref = reference_robot() if n == 2 else uniform_robot(n)
    rng = np.random.default_rng(1)
    return [dataclasses.replace(ref, stiffness=tuple(v * s for v in ref.stiffness), gains=tuple(v * g for v in ref.gains))
            for s, g in rng.uniform(0.9, 1.1, (count, 2))]


@pytest.mark.parametrize("integrator,n,tau_p", [("ros2", 2, 0.0), ("rk4", 2, 0.0), ("euler", 2, 0.0), ("ros2", 2, 0.03),
                                                ("ros2", 3, 0.0), ("rk4", 3, 0.02)])
def test_batch_plant_equals_serial_plants_bit_for_bit(integrator, n, tau_p):
    safe_set, robots = paper_safe_set(), _robots(5, n)
    physics_dt = {"ros2": 1e-3, "rk4": 2e-4, "euler": 1e-4}[integrator]
    batch = PCCBatchPlant(robots, safe_set, len(robots), integrator=integrator, physics_dt=physics_dt, tau_p=tau_p)
    serial = [PCCPlant(r, safe_set, integrator=integrator, physics_dt=physics_dt, tau_p=tau_p) for r in robots]
    rng = np.random.default_rng(2)
    q0, qd0 = rng.normal(0.0, 0.3, (5, n)), rng.normal(0.0, 0.5, (5, n))
    states = batch.reset(q0, qd0)
    rows = [p.reset(q0[b], qd0[b]) for b, p in enumerate(serial)]
    touched = np.zeros(5, dtype=bool)
    u_all = np.repeat(rng.uniform(-100.0, 250.0, (12, 5, n)), 50, axis=0)
    for u in u_all:
        for b, row in enumerate(rows):
            got = states.row(b)
            for name in ("t", "q", "qd", "segment_ends", "contact_forces", "u_applied"):
                np.testing.assert_array_equal(getattr(got, name), getattr(row, name), err_msg=f"sim {b} {name}")
            touched[b] |= bool(row.contact_forces[0] > 0)
        states = batch.step(u)
        rows = [p.step(u[b]) for b, p in enumerate(serial)]
    assert touched.sum() >= 3, "most simulations must cross the facet, or the contact force goes untested"


def test_input_checks_and_divergence_names_the_simulation():
    plant = PCCBatchPlant(reference_robot(), paper_safe_set(), 3, integrator="euler", physics_dt=1e-3)
    with pytest.raises(ValueError, match=r"u must be finite with shape \(3, 2\)"):
        plant.step(np.zeros(2))
    with pytest.raises(ValueError, match="params must be one RobotParams or n_sims = 3"):
        PCCBatchPlant(_robots(2), paper_safe_set(), 3)
    plant.reset(np.zeros((3, 2)))
    with pytest.raises(FloatingPointError, match=r"simulations \[0, 1, 2\]"):
        for _ in range(2000):  # forward Euler at 1 ms is unstable on the reference robot's fast mode
            plant.step(np.full((3, 2), 100.0))
