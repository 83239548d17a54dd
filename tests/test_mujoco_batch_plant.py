"""MujocoBatchPlant against B MujocoPlants: bit for bit, per-simulation mismatch included."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from controllers.model.params import reference_robot
from softcbf_mj.physics.mjcf import ArmModelConfig
from softcbf_mj.physics.mujoco_batch_plant import WARNING_NAMES, MujocoBatchPlant
from softcbf_mj.physics.mujoco_plant import MujocoPlant

LINKS, DT = 4, 2e-4  # a coarse rod keeps the test short; the code path is the same


def _configs() -> list[ArmModelConfig]:
    """Four mismatch samples: plate stiffness and offset, arm stiffness, damping, gain and length."""
    ref = reference_robot()
    configs = []
    for b, (k_plate, offset, k, d, g, length) in enumerate(
        [(11.16, 0.0, 1.0, 1.0, 1.0, 1.0), (14.0, 0.003, 1.1, 0.9, 1.05, 1.0),
         (9.0, -0.002, 0.9, 1.2, 0.95, 1.03), (11.16, 0.001, 1.0, 1.0, 1.1, 0.97)]):
        robot = dataclasses.replace(
            ref, lengths=tuple(v * length for v in ref.lengths), stiffness=tuple(v * k for v in ref.stiffness),
            damping=tuple(v * d for v in ref.damping), gains=tuple(v * g for v in ref.gains),
            inertias=tuple(v * length**2 for v in ref.inertias))
        configs.append(ArmModelConfig(robot=robot, plate_stiffness=k_plate, h=(0.15 + offset * np.hypot(0.36, 1.0),),
                                      links_per_segment=LINKS, physics_dt=DT))
    return configs


def _commands(rng: np.random.Generator, n_steps: int, n_sims: int) -> np.ndarray:
    """Piecewise-constant commands into the plate, some beyond the ±150 hPa ctrlrange."""
    u = np.repeat(rng.uniform(-60.0, 200.0, (n_steps // 50 + 1, n_sims, 2)), 50, axis=0)[:n_steps]
    return u


@pytest.mark.parametrize("nthread", [1, 2])
def test_batch_equals_serial_plants_bit_for_bit(nthread):
    configs = _configs()
    batch = MujocoBatchPlant.from_configs(configs, nthread=nthread)
    serial = [MujocoPlant.from_config(c) for c in configs]
    rng = np.random.default_rng(3)
    q0 = rng.normal(0.0, 0.2, (len(configs), 2))
    qd0 = rng.normal(0.0, 0.5, (len(configs), 2))
    u0 = rng.uniform(-100.0, 100.0, (len(configs), 2))
    states = batch.reset(q0, qd0, u0)
    rows = [p.reset(q0[b], qd0[b], u0[b]) for b, p in enumerate(serial)]
    touched = np.zeros(len(configs), dtype=bool)
    for u in _commands(rng, 600, len(configs)):
        for b, row in enumerate(rows):
            got = states.row(b)
            for name in ("t", "q", "qd", "segment_ends", "contact_forces", "u_applied"):
                np.testing.assert_array_equal(getattr(got, name), getattr(row, name), err_msg=f"sim {b} {name}")
            np.testing.assert_array_equal(got.extras["plate_displacement_m"], row.extras["plate_displacement_m"])
            np.testing.assert_allclose(got.extras["force_solver_N"], row.extras["force_solver_N"], rtol=1e-9, atol=1e-12)
            counts = {f"warning_{name}": float(c) for name, c in zip(WARNING_NAMES, got.extras["warnings"]) if c}
            assert counts == {k: v for k, v in row.extras.items() if k.startswith("warning_")}
            touched[b] |= bool(row.contact_forces[0] > 0)
        states = batch.step(u)
        rows = [p.step(u[b]) for b, p in enumerate(serial)]
    assert touched.all(), "every simulation must reach the plate, or contact goes untested"
    np.testing.assert_array_equal(batch.plate_stiffness[:, 0], [c.plate_stiffness[0] for c in configs])


def test_one_model_for_all_and_input_checks():
    config = ArmModelConfig(links_per_segment=LINKS, physics_dt=DT)
    plant = MujocoBatchPlant(MujocoPlant.from_config(config).model, 3)
    state = plant.reset(np.zeros((3, 2)))
    assert state.q.shape == (3, 2) and state.segment_ends.shape == (3, 3, 2) and state.contact_forces.shape == (3, 1)
    np.testing.assert_allclose(state.segment_ends[:, -1], [[0.244, 0.0]] * 3, atol=1e-12)
    with pytest.raises(ValueError, match=r"u must have shape \(3, 2\)"):
        plant.step(np.zeros(2))
    with pytest.raises(ValueError, match="u must be finite"):
        plant.step(np.full((3, 2), np.nan))
    with pytest.raises(ValueError, match="u0 must lie within"):
        plant.reset(np.zeros((3, 2)), u0=np.full((3, 2), 200.0))
    with pytest.raises(ValueError, match="n_sims must be an integer >= 1"):
        MujocoBatchPlant(plant.model, 0)
    with pytest.raises(ValueError, match=r"differ in \['opt.timestep'\]"):
        MujocoBatchPlant.from_configs([config, dataclasses.replace(config, physics_dt=1e-4)])


def test_reset_of_some_simulations_equals_a_fresh_plant_and_leaves_the_others_alone():
    """reset(ids=...) mid-run: the reset simulations restart as a fresh MujocoPlant (bit for bit, warm
    start and time included), the others go on as if nothing happened."""
    configs = _configs()
    batch = MujocoBatchPlant.from_configs(configs)
    untouched = MujocoBatchPlant.from_configs(configs)  # the same batch, never reset mid-run
    rng = np.random.default_rng(5)
    commands = _commands(rng, 300, len(configs))
    q0 = rng.normal(0.0, 0.2, (len(configs), 2))
    batch.reset(q0)
    untouched.reset(q0)
    for u in commands[:200]:
        batch.step(u)
        untouched.step(u)
    assert np.any(batch.state().contact_forces[[1, 3], 0] > 0), "the reset simulations must be in contact before"
    q_new, qd_new, u_new = rng.normal(0.0, 0.2, (2, 2)), rng.normal(0.0, 0.5, (2, 2)), rng.uniform(-100, 100, (2, 2))
    states = batch.reset(q_new, qd_new, u_new, ids=[3, 1])  # rows in the order of ids
    fresh = {3: MujocoPlant.from_config(configs[3]), 1: MujocoPlant.from_config(configs[1])}
    rows = {b: fresh[b].reset(q_new[i], qd_new[i], u_new[i]) for i, b in enumerate((3, 1))}
    others = untouched.state()
    for u in commands[200:]:
        for b in range(len(configs)):
            got = states.row(b)
            want = rows[b] if b in rows else others.row(b)
            for name in ("t", "q", "qd", "segment_ends", "contact_forces", "u_applied"):
                np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=f"sim {b} {name}")
        states, others = batch.step(u), untouched.step(u)
        rows = {b: fresh[b].step(u[b]) for b in rows}
    for bad in ([], [4], [1, 1], [-1]):
        with pytest.raises(ValueError, match=r"ids must be distinct simulations in \[0, 3\]"):
            batch.reset(np.zeros((max(len(bad), 1), 2)), ids=bad)
    with pytest.raises(ValueError, match=r"q0 must have shape \(1, 2\)"):
        batch.reset(np.zeros((4, 2)), ids=[0])
