"""Arm-table friction (softcbf_mj.physics.table_friction): the force law, the COM velocities it reads, the
Coulomb deceleration of a sliding body, the dissipation, the arm held by friction, μ = 0 unchanged,
and the refusals (gravity, explicit stability, the batched plant)."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest

from scenarios import get
from scenarios.common import data_only
from scenarios.mujoco_contact import contact_batch_key
from softcbf_mj.physics import mjcf as mb
from softcbf_mj.physics.mujoco_batch_plant import MujocoBatchPlant
from softcbf_mj.physics.mujoco_plant import EXTRAS_UNITS, MujocoPlant
from softcbf_mj.outputs.runio import load_timeseries
from softcbf_mj.physics.table_friction import (
    SLIP_VELOCITY, TABLE_FRICTION_NUMERIC, TABLE_GRAVITY, TableFriction, check_table_friction, table_friction_of,
)

NO_PLATES = dict(H=np.zeros((0, 2)), h=np.zeros(0))


def _puck(mu: float, mass: float = 0.2, dt: float = 1e-4) -> mujoco.MjModel:
    """A body sliding freely in the plane (slide joints x, y) below a fixed `base`, carrying μ."""
    spec = mujoco.MjSpec()
    spec.option.timestep = dt
    spec.option.gravity = [0.0, 0.0, 0.0]
    base = spec.worldbody.add_body(name="base")
    base.add_geom(size=[0.01, 0, 0], contype=0, conaffinity=0)
    puck = base.add_body(name="puck", pos=[0.1, 0.0, 0.0])
    puck.add_joint(name="x", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
    puck.add_joint(name="y", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 1, 0])
    puck.add_geom(size=[0.02, 0, 0], mass=mass, contype=0, conaffinity=0)
    spec.add_numeric(name=TABLE_FRICTION_NUMERIC, data=[mu])
    return spec.compile()


def _slide(model: mujoco.MjModel, v0: tuple[float, float], seconds: float) -> tuple[np.ndarray, list[float]]:
    """Velocities (n+1, 2) m/s after each physics step and the friction power of each step (W)."""
    friction = TableFriction(model, table_friction_of(model))
    data = mujoco.MjData(model)
    data.qvel[:] = v0
    velocities, powers = [data.qvel.copy()], []
    for _ in range(int(round(seconds / model.opt.timestep))):
        mujoco.mj_step1(model, data)
        powers.append(friction.apply(data))
        mujoco.mj_step2(model, data)
        velocities.append(data.qvel.copy())
    return np.array(velocities), powers


def test_force_law_bounds_direction_and_the_coulomb_limit():
    friction = TableFriction(_puck(0.5, mass=0.2), 0.5)
    weight = 0.5 * 0.2 * TABLE_GRAVITY  # μ m g, N
    v = np.array([[0.0, 0.0], [SLIP_VELOCITY, 0.0], [0.03, -0.04], [-2.0, 1.0]])
    f = friction.forces(v)
    np.testing.assert_array_equal(f[0], 0.0)
    speed = np.linalg.norm(v, axis=1)
    magnitude = np.linalg.norm(f, axis=1)
    assert np.all(magnitude < weight)
    assert magnitude[1] == pytest.approx(weight / math.sqrt(2), rel=1e-12)  # at ‖v‖ = v_s
    np.testing.assert_allclose(np.einsum("ij,ij->i", f[1:], v[1:]), -magnitude[1:] * speed[1:], rtol=1e-12)  # opposes v
    # Coulomb for ‖v‖ ≫ v_s: relative shortfall v_s² / (2 ‖v‖²) to first order
    np.testing.assert_allclose(1 - magnitude[2:] / weight, SLIP_VELOCITY**2 / (2 * speed[2:] ** 2), rtol=1e-3)


def test_velocities_are_the_com_jacobian_times_qvel():
    plant = MujocoPlant.from_config(table_friction=0.3)
    plant.reset(np.array([0.4, -0.7]), np.array([1.5, -2.5]))
    model, data, friction = plant.model, plant.data, plant.table_friction
    mujoco.mj_step1(model, data)
    jac = np.zeros((3, model.nv))
    expected = []
    for body in friction.bodies:
        mujoco.mj_jacBodyCom(model, data, jac, None, body)
        expected.append((jac @ data.qvel)[:2])
    assert len(friction.bodies) == 2 * mb.DEFAULT_LINKS_PER_SEGMENT  # every link below the fixed base
    np.testing.assert_allclose(friction.velocities(data), np.array(expected), rtol=0, atol=1e-14)
    np.testing.assert_allclose(friction.weights, 0.3 * TABLE_GRAVITY * model.body_mass[friction.bodies], rtol=1e-15)


def test_a_sliding_body_decelerates_at_mu_g_along_its_velocity_and_stops():
    """v(t) = v0 − μ g t v̂0 while ‖v‖ ≫ v_s: the force is then constant, integrated exactly by the
    semi-implicit Euler step; the only error is the regularisation's shortfall μ g v_s²/(2‖v‖²), which
    adds up to ∫ μ g v_s²/(2v²) dt = (v_s²/2)(1/‖v‖ − 1/‖v0‖) (3.0e-5 m/s at 1.6 cm/s; 10 % slack for
    the higher orders)."""
    mu, v0 = 0.5, np.array([0.3, -0.4])  # 0.5 m/s
    model = _puck(mu)
    velocities, powers = _slide(model, tuple(v0), 0.15)
    t = np.arange(len(velocities)) * model.opt.timestep
    stop = np.linalg.norm(v0) / (mu * TABLE_GRAVITY)  # 0.102 s
    sliding = t < stop - 0.016 / (mu * TABLE_GRAVITY)  # ‖v‖ > 1.6 cm/s
    expected = v0 - (mu * TABLE_GRAVITY * t[sliding])[:, None] * v0 / np.linalg.norm(v0)
    speed_error = np.abs(np.linalg.norm(velocities[sliding], axis=1) - np.linalg.norm(expected, axis=1))
    shortfall = SLIP_VELOCITY**2 / 2 * (1 / np.linalg.norm(expected, axis=1) - 1 / np.linalg.norm(v0))
    np.testing.assert_allclose(speed_error, shortfall, rtol=0.1, atol=1e-12)
    direction = velocities[sliding] / np.linalg.norm(velocities[sliding], axis=1, keepdims=True)
    np.testing.assert_allclose(direction, np.broadcast_to(v0 / np.linalg.norm(v0), direction.shape), atol=1e-12)
    # stopped: below v_s within 2 ms of the Coulomb stop time, and no sign-flipping afterwards (μ g dt / v_s < 1)
    assert np.all(np.linalg.norm(velocities[t > stop + 0.002], axis=1) < SLIP_VELOCITY)
    after = velocities[t > stop + 0.002] @ v0
    assert np.all(after >= 0)
    assert max(powers) <= 0.0 and min(powers) < -0.9 * mu * 0.2 * TABLE_GRAVITY * 0.5  # ≈ −μ m g ‖v0‖ at the start


def test_friction_power_is_never_positive_and_the_power_column_has_its_unit():
    plant = MujocoPlant.from_config(table_friction=0.3)
    plant.reset(np.array([0.2, -0.1]))
    rng = np.random.default_rng(3)
    powers = [plant.step(rng.uniform(-150, 150, 2)).extras["table_friction_power_W"] for _ in range(400)]
    assert max(powers) <= 0.0
    assert min(powers) < -1e-3  # the arm moves: friction dissipates
    assert "W" in EXTRAS_UNITS["table_friction_power_W"]


def test_below_break_away_a_pressure_step_only_creeps():
    """20 hPa on segment 1: λ u = 0.11 N·m at each of its hinges, below the table's friction moment
    μ g Σ m_k (r_k − r_j) ≥ 0.17 N·m (μ = 2) of the links beyond any of them, so with μ = 2 the arm
    only creeps (every link below v_s, so the tip too) while without friction it bends by 0.11 rad."""
    moved, top_speed = {}, {}
    for mu in (0.0, 2.0):
        plant = MujocoPlant.from_config(table_friction=mu, **NO_PLATES)
        start = plant.reset(np.zeros(2)).tip
        tips = np.array([plant.step(np.array([20.0, 0.0])).tip for _ in range(1000)])
        moved[mu] = float(np.linalg.norm(tips[-1] - start))
        top_speed[mu] = float(np.max(np.linalg.norm(np.diff(tips, axis=0), axis=1)) / plant.control_dt)
    assert moved[0.0] > 0.015
    assert moved[2.0] < 0.05 * moved[0.0]
    assert top_speed[2.0] < SLIP_VELOCITY < top_speed[0.0]


def test_mu_zero_is_todays_model_and_stepping_bit_for_bit():
    assert mb.arm_xml(mb.ArmModelConfig(table_friction=0.0)) == mb.arm_xml(mb.ArmModelConfig())
    assert "numeric" not in mb.arm_xml(mb.ArmModelConfig())
    assert f'name="{TABLE_FRICTION_NUMERIC}"' in mb.arm_xml(mb.ArmModelConfig(table_friction=0.3))
    today, zero = MujocoPlant.from_config(), MujocoPlant.from_config(table_friction=0.0)
    assert zero.table_friction is None
    u = np.array([150.0, 120.0])
    for plant in (today, zero):
        plant.reset(np.array([0.1, 0.2]))
    for _ in range(300):
        a, b = today.step(u), zero.step(u)
        np.testing.assert_array_equal(a.segment_ends, b.segment_ends)
        np.testing.assert_array_equal(a.contact_forces, b.contact_forces)
        assert a.extras.keys() == b.extras.keys() and "table_friction_power_W" not in b.extras
    assert max(a.contact_forces) > 0.1  # through contact


def test_stepping_one_by_one_with_zero_force_is_mj_step():
    """The friction path (mj_step1, forces, mj_step2) equals mj_step(nstep) when the forces are zero:
    a model carrying μ, stepped with μ's forces zeroed, against the same model on the default path."""
    on = MujocoPlant.from_config(table_friction=0.3)
    off = MujocoPlant(on.model, on.control_dt)
    off.table_friction = None
    on.table_friction.weights = np.zeros_like(on.table_friction.weights)
    for plant in (on, off):
        plant.reset(np.array([0.3, -0.2]), np.array([0.5, 1.0]))
    for _ in range(50):
        a, b = on.step(np.array([80.0, -60.0])), off.step(np.array([80.0, -60.0]))
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.qd, b.qd)
    assert a.extras["table_friction_power_W"] == 0.0


@pytest.mark.parametrize(("changes", "message"), [
    (dict(table_friction=-0.1), "table_friction must be finite and >= 0"),
    (dict(table_friction=math.nan), "table_friction must be finite and >= 0"),
    (dict(table_friction=0.3, gravity=(0.0, -9.81, 0.0)), "cannot be combined with gravity"),
    (dict(table_friction=1.5, physics_dt=2e-4), "table_friction must be < 1.019 at physics_dt = 0.0002 s"),
])
def test_bad_table_friction_is_refused_naming_it(changes, message):
    with pytest.raises(ValueError, match=message):
        mb.ArmModelConfig(**changes)


def test_stability_limit_is_mu_g_dt_over_v_s_below_two():
    limit = 2 * SLIP_VELOCITY / (TABLE_GRAVITY * 1e-4)
    check_table_friction(limit * (1 - 1e-9), 1e-4, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="explicit stability"):
        check_table_friction(limit, 1e-4, (0.0, 0.0, 0.0))


def test_scenarios_take_table_friction_and_refuse_it_with_gravity():
    contact = get("mujoco_contact")
    params = contact.validate({"table_friction": 0.3})
    assert params["table_friction"] == 0.3 and contact_batch_key(params) is None
    assert contact_batch_key(contact.validate({})) is not None
    with pytest.raises(ValueError, match="cannot be combined with gravity"):
        contact.validate({"table_friction": 0.3, "gravity": 9.81})
    with pytest.raises(ValueError, match=r"table_friction must be in \[0, 2\]"):
        contact.validate({"table_friction": 2.5})
    assert get("camera_loop").validate({"table_friction": 0.5})["table_friction"] == 0.5
    with pytest.raises(ValueError, match="table_friction must be < 1.019"):
        get("camera_loop").validate({"table_friction": 1.5, "physics_dt": 2e-4})


def test_batched_plant_refuses_table_friction():
    with pytest.raises(ValueError, match=r"does not model arm-table friction \(table_friction > 0 in simulations \[1\]\)"):
        MujocoBatchPlant.from_configs([mb.ArmModelConfig(), mb.ArmModelConfig(table_friction=0.2)])


def test_mujoco_contact_records_the_friction_power(tmp_path):
    with data_only():
        summary = get("mujoco_contact").run(tmp_path, duration=0.3, tunings="Low", table_friction=0.3, t0=25.0,
                                            progress=False)
    series, units = load_timeseries(tmp_path / summary["runs"][0]["timeseries"])
    power = np.asarray(series["table_friction_power_W"])
    assert power.shape == (300,) and np.all(power <= 0) and np.min(power) < 0
    assert units["table_friction_power_W"] == EXTRAS_UNITS["table_friction_power_W"]
