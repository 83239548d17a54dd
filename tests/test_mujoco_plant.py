"""MujocoPlant: statics against PCC, convergence, the plate, pressure dynamics, determinism."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from controllers.model.params import reference_robot
from controllers.model.pcc import segment_ends
from softcbf_mj.physics.mjcf import (
    DEFAULT_LINKS_PER_SEGMENT,
    DEFAULT_PHYSICS_DT,
    PAPER_H,
    PAPER_h,
    PAPER_PLATE_STIFFNESS,
    ArmModelConfig,
)
from softcbf_mj.physics.mujoco_plant import MUJOCO_VERSION, MujocoPlant
from softcbf_mj.physics.plant import PlantState

SCENE = Path(__file__).resolve().parents[1] / "models" / "softcbf_arm" / "scene.xml"
ROBOT = reference_robot()
H, h = np.array(PAPER_H[0]), PAPER_h[0]
NO_PLATE = dict(H=np.zeros((0, 2)), h=())


def penetration(tip: np.ndarray) -> float:
    """Signed distance (m) of the tip point beyond the paper's facet (> 0: outside free space)."""
    return float((H @ tip - h) / np.linalg.norm(H))


def pressures_for(q: np.ndarray) -> np.ndarray:
    """u = Λ⁻¹ K q (hPa), the static pressures for bending angles q without contact."""
    return ROBOT.array("stiffness") * q / ROBOT.array("gains")


def hold(plant: MujocoPlant, u, seconds: float) -> PlantState:
    for _ in range(int(round(seconds / plant.control_dt))):
        state = plant.step(np.asarray(u, dtype=float))
    return state


# -- statics -------------------------------------------------------------------------


@pytest.mark.parametrize("q_deg", [(30.0, -30.0), (-30.0, 15.0), (20.0, 30.0)])
def test_statics_match_pcc_kinematics_and_stiffness(q_deg):
    """Settled free arm: q = K⁻¹Λu within 1e-5 rad (λ is stored to 6 digits: ≤ 4e-7 rad);
    segment ends within 1e-4 m per segment of PCC(q), the first end within 10 % of the
    hinge-at-cell-centre estimate L q²/(12 n²)."""
    n = DEFAULT_LINKS_PER_SEGMENT
    plant = MujocoPlant.from_config(links_per_segment=n, **NO_PLATE)
    u = pressures_for(np.radians(q_deg))
    state = hold(plant, u, 1.5)  # the slowest mode decays as exp(−k t / d) ≈ exp(−14 t)
    assert np.max(np.abs(state.qd)) < 1e-6  # settled
    np.testing.assert_allclose(state.q, ROBOT.array("gains") * u / ROBOT.array("stiffness"), rtol=0, atol=1e-5)
    error = np.linalg.norm(state.segment_ends - segment_ends(state.q, ROBOT.lengths), axis=1)
    assert error[0] == 0.0
    assert np.all(error[1:] <= 1e-4 * np.arange(1, ROBOT.n_segments + 1)), error
    estimate = ROBOT.lengths[0] * state.q[0] ** 2 / (12 * n**2)
    assert error[1] == pytest.approx(estimate, rel=0.1)


# -- convergence ---------------------------------------------------------------------


def _step_into_plate(n: int, dt: float, seconds: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """Tip (T, 2) and plate force (T,) after a (120, 120) hPa step that strikes the plate at speed."""
    plant = MujocoPlant.from_config(links_per_segment=n, physics_dt=dt)
    tip, force = [], []
    for _ in range(int(round(seconds / plant.control_dt))):
        state = plant.step(np.array([120.0, 120.0]))
        tip.append(state.tip)
        force.append(state.contact_forces[0])
    return np.array(tip), np.array(force)


def test_dynamic_run_converges_and_the_defaults_are_close_to_the_finest_setting():
    """Against n = 20, dt = 25 µs: the tip error falls with n and with dt, and the defaults
    stay within 0.1 mm (0.7 % of n_max) and 1.6 mN (1 % of F_max) over the whole impact."""
    ref_tip, ref_force = _step_into_plate(20, 2.5e-5)
    assert ref_force.max() > 0.4  # the run does hit the plate

    def tip_error(n, dt):
        tip, force = _step_into_plate(n, dt)
        return np.max(np.linalg.norm(tip - ref_tip, axis=1)), np.max(np.abs(force - ref_force))

    by_n = [tip_error(n, 2.5e-5)[0] for n in (5, 10)]
    by_dt = [tip_error(20, dt)[0] for dt in (1e-3, 2.5e-4)]
    assert by_n[0] > by_n[1] > 0 and by_dt[0] > by_dt[1] > 0, (by_n, by_dt)
    tip_err, force_err = tip_error(DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT)
    assert tip_err < 1e-4 and force_err < 1.6e-3, (tip_err, force_err)


# -- plate ---------------------------------------------------------------------------


@pytest.mark.parametrize("u", [70.0, 120.0])
def test_quasi_static_push_gives_k_times_the_penetration(u):
    """Pressed and settled: the plate force is k·n(r) within 2 % (n: the tip point's
    penetration of the facet), and MuJoCo's contact force equals the spring force within
    0.5 % (what remains is the plate's damping and inertia)."""
    plant = MujocoPlant.from_config()
    state = hold(plant, [u, u], 1.5)
    depth = penetration(state.tip)
    assert depth > 0.005
    assert state.contact_forces[0] == pytest.approx(PAPER_PLATE_STIFFNESS * depth, rel=0.02)
    assert state.extras["plate_displacement_m"][0] == pytest.approx(depth, rel=0.02)
    assert state.extras["force_solver_N"][0] == pytest.approx(state.contact_forces[0], rel=0.005)


def test_reported_force_is_the_plates_spring_force():
    plant = MujocoPlant.from_config()
    plate = plant.model.joint("plate1_slide")
    for displacement in (0.002, 0.01, 0.03, -0.01):
        plant.reset(np.zeros(2))
        plant.data.qpos[plate.qposadr[0]] = displacement
        mujoco.mj_forward(plant.model, plant.data)
        state = plant.state()
        spring = -plant.data.qfrc_spring[plate.dofadr[0]]
        assert spring == pytest.approx(PAPER_PLATE_STIFFNESS * displacement, rel=1e-12)
        assert state.contact_forces[0] == pytest.approx(max(0.0, spring), rel=1e-12)


def test_contact_begins_when_the_tip_point_crosses_the_facet():
    """Slow approach (≈ 20 µm per control step): the first step with a solver contact force
    has the tip point within 0.5 mm of the facet."""
    plant = MujocoPlant.from_config()
    u0 = np.array([48.0, 48.0])
    plant.reset(ROBOT.array("gains") * u0 / ROBOT.array("stiffness"), u0=u0)
    assert penetration(plant.state().tip) < -0.003
    for k in range(1, 1000):
        state = plant.step(u0 + 20.0 * k * plant.control_dt)
        if state.extras["force_solver_N"][0] > 0:
            break
    else:
        pytest.fail("the tip never touched the plate")
    assert abs(penetration(state.tip)) < 5e-4, penetration(state.tip)


# -- pressure dynamics -----------------------------------------------------------------


def test_ideal_actuator_applies_the_command_at_once():
    plant = MujocoPlant.from_config(tau_p=0.0)
    u = np.array([100.0, -60.0])
    np.testing.assert_array_equal(plant.step(u).u_applied, u)


@pytest.mark.parametrize("tau_p", [0.05, 0.02])
def test_pressure_follows_a_first_order_lag(tau_p):
    plant = MujocoPlant.from_config(tau_p=tau_p, **NO_PLATE)
    u = np.array([100.0, -60.0])
    t, applied = [], []
    for _ in range(200):
        state = plant.step(u)
        t.append(state.t)
        applied.append(state.u_applied)
    t, applied = np.array(t), np.array(applied)
    expected = u * (1 - np.exp(-t / tau_p))[:, None]
    np.testing.assert_allclose(applied, expected, rtol=0, atol=1e-9 * np.abs(u).max())
    early = t < 3 * tau_p
    fitted = -t[early] / np.log(1 - applied[early, 0] / u[0])
    np.testing.assert_allclose(fitted, tau_p, rtol=1e-6)


def test_commands_beyond_the_limits_are_clamped_by_mujoco_and_reported():
    plant = MujocoPlant.from_config(tau_p=0.0, **NO_PLATE)
    state = plant.step(np.array([500.0, -500.0]))
    np.testing.assert_array_equal(state.u_applied, [ROBOT.u_max[0], ROBOT.u_min[1]])
    np.testing.assert_array_equal(plant.u_min, ROBOT.u_min)
    np.testing.assert_array_equal(plant.u_max, ROBOT.u_max)
    assert not any(key.startswith("warning_") for key in state.extras)


# -- interface -------------------------------------------------------------------------


def test_reset_spreads_each_angle_over_its_hinges():
    plant = MujocoPlant.from_config()
    q0, qd0, u0 = np.array([0.3, -0.2]), np.array([0.5, 1.0]), np.array([40.0, -20.0])
    state = plant.reset(q0, qd0, u0)
    n = DEFAULT_LINKS_PER_SEGMENT
    for i in (1, 2):
        for j in range(1, n + 1):
            joint = plant.model.joint(f"seg{i}_j{j}")
            assert plant.data.qpos[joint.qposadr[0]] == pytest.approx(q0[i - 1] / n, rel=1e-15)
            assert plant.data.qvel[joint.dofadr[0]] == pytest.approx(qd0[i - 1] / n, rel=1e-15)
    np.testing.assert_allclose(state.q, q0, rtol=1e-14)
    np.testing.assert_allclose(state.qd, qd0, rtol=1e-14)
    np.testing.assert_array_equal(state.u_applied, u0)
    assert state.t == 0.0 and state.contact_forces[0] == 0.0
    np.testing.assert_array_equal(state.segment_ends[0], [0.0, 0.0])
    np.testing.assert_allclose(state.tip, plant.data.site("seg2_end").xpos[:2], atol=1e-15)
    with pytest.raises(ValueError, match="ctrlrange"):
        plant.reset(q0, u0=np.array([200.0, 0.0]))


@pytest.mark.parametrize("bad, message", [([np.nan, 0.0], "finite"), ([np.inf, 0.0], "finite"), ([1.0], r"shape \(2,\)")])
def test_step_rejects_bad_commands(bad, message):
    plant = MujocoPlant.from_config()
    with pytest.raises(ValueError, match=message):
        plant.step(np.array(bad))


def test_physics_step_must_divide_the_control_period():
    with pytest.raises(ValueError, match=r"integer multiple of the physics step.*choose a physics step such as"):
        MujocoPlant.from_config(physics_dt=3e-4)
    model = MujocoPlant.from_config().model
    model.opt.timestep = 3e-4
    with pytest.raises(ValueError, match="integer multiple"):
        MujocoPlant(model)


def _random_run(plant: MujocoPlant, steps: int = 300) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(7)
    plant.reset(np.zeros(2))
    states = [plant.step(rng.uniform(60.0, 150.0, size=2)) for _ in range(steps)]
    return {
        name: np.array([getattr(s, name) for s in states])
        for name in ("t", "q", "qd", "segment_ends", "contact_forces", "u_applied")
    } | {
        key: np.array([s.extras[key] for s in states]) for key in ("plate_displacement_m", "force_solver_N")
    }


def test_same_inputs_give_identical_arrays():
    first = MujocoPlant.from_config()
    a, b = _random_run(first), _random_run(first)  # reset and replay on the same plant
    c = _random_run(MujocoPlant.from_config())  # a fresh plant
    d = _random_run(MujocoPlant.from_xml(SCENE))  # the committed file
    assert a["contact_forces"].max() > 0.1  # the run presses the plate
    for other in (b, c, d):
        for key in a:
            np.testing.assert_array_equal(a[key], other[key], err_msg=key)


def _reference_data(plant: MujocoPlant) -> mujoco.MjData:
    """A second MjData of the plant's model in the plant's current state (inputs copied, then mj_forward)."""
    data = mujoco.MjData(plant.model)
    for field in ("qpos", "qvel", "act", "ctrl", "xfrc_applied", "qacc_warmstart"):
        getattr(data, field)[:] = getattr(plant.data, field)
    data.time = plant.data.time
    mujoco.mj_forward(plant.model, data)
    return data


def _reference_period(plant: MujocoPlant, data: mujoco.MjData, u: np.ndarray) -> None:
    """One control period as MuJoCo's own steps take it: mj_step (mj_step1, friction, mj_step2
    with table friction), then mj_forward."""
    data.ctrl[:] = u
    if plant.table_friction is None:
        mujoco.mj_step(plant.model, data, nstep=plant.steps_per_control)
    else:
        for _ in range(plant.steps_per_control):
            mujoco.mj_step1(plant.model, data)
            plant.table_friction.apply(data)
            mujoco.mj_step2(plant.model, data)
    mujoco.mj_forward(plant.model, data)


def _assert_same_data(plant: MujocoPlant, data: mujoco.MjData, k: int) -> None:
    for field in ("qpos", "qvel", "act", "qacc", "qacc_warmstart", "actuator_force", "efc_force", "site_xpos"):
        assert getattr(plant.data, field).tobytes() == getattr(data, field).tobytes(), (k, field)
    assert plant.data.time == data.time and plant.data.ncon == data.ncon, k


@pytest.mark.parametrize("changes", [{}, dict(tau_p=0.0), dict(plate="flexure", tip_friction=0.5),
                                     dict(table_friction=0.3), dict(integrator="Euler"),
                                     dict(integrator="RK4", links_per_segment=2, **NO_PLATE)],
                         ids=["ideal", "no-pressure-lag", "flexure", "table-friction", "Euler", "RK4"])
def test_a_control_period_is_bit_identical_to_mujocos_own_steps(changes):
    """The first physics step of a period reuses the reporting mj_forward (module docstring):
    every quantity of the data, through contact, equals mj_step's bit for bit (RK4, not split,
    steps by mj_step: the rod is stable under it only when short and free)."""
    plant = MujocoPlant.from_config(**changes)
    rng = np.random.default_rng(3)
    plant.reset(np.zeros(2))
    data = _reference_data(plant)
    force = 0.0
    for k in range(200 if plant.n_facets == 0 else 400):
        u = rng.uniform(80.0, 150.0, size=2)
        state = plant.step(u)
        _reference_period(plant, data, u)
        _assert_same_data(plant, data, k)
        force = max(force, *state.extras["force_solver_N"], 0.0)
    assert not any(key.startswith("warning_") for key in state.extras)  # a stable run
    assert (force > 0) == (plant.n_facets > 0)  # the run reaches the plate


@pytest.mark.parametrize("edit", ["qpos", "qvel", "nan", "xfrc_applied", "act"])
def test_edits_of_the_data_between_steps_are_seen(edit, tmp_path, monkeypatch):
    """qpos or qvel changed after the last step (no mj_forward), a NaN that makes MuJoCo's check
    reset the data, a force applied to a link or a pressure state changed (inputs of the acceleration
    stages the reporting forward's solve stands for): the next period is still mj_step's from the edited data."""
    monkeypatch.chdir(tmp_path)  # MuJoCo writes the NaN's warning to MUJOCO_LOG.TXT here
    plant = MujocoPlant.from_config()
    u = np.array([140.0, 140.0])
    for _ in range(300):
        plant.step(u)
    data = _reference_data(plant)
    for target in (plant.data, data):
        if edit == "nan":
            target.qvel[plant.hinge_dofs[0][0]] = np.nan
        elif edit == "xfrc_applied":
            target.xfrc_applied[plant.model.geom_bodyid[plant.tip_geom], 1] = 0.02  # N, on the tip's body
        elif edit == "act":
            target.act[plant.act_adr[0]] -= 20.0
        else:
            getattr(target, edit)[plant.hinge_dofs[1][-1]] += 0.05
    for k in range(20):
        plant.step(u)
        _reference_period(plant, data, u)
        _assert_same_data(plant, data, k)


def test_warnings_are_reported():
    plant = MujocoPlant.from_config()
    plant.data.warning[mujoco.mjtWarning.mjWARN_BADQACC].number = 2
    assert plant.state().extras["warning_badqacc"] == 2.0


def test_versions_are_recorded():
    versions = MujocoPlant.versions()
    assert versions["mujoco"] == MUJOCO_VERSION == mujoco.__version__
    assert {"softcbf_mj", "python"} <= set(versions)


def test_plant_reads_its_parameters_from_a_variant_model():
    robot3 = ROBOT.replace(
        lengths=(0.1,) * 3, masses=(0.1,) * 3, stiffness=(1.0,) * 3, damping=(0.07,) * 3,
        gains=(5e-3,) * 3, u_min=(-100.0,) * 3, u_max=(120.0,) * 3,
    )
    plant = MujocoPlant.from_config(
        ArmModelConfig(robot=robot3, H=[[1.0, 0.0], [0.0, 1.0]], h=[0.35, 0.2], plate_stiffness=[5.0, 20.0]),
        links_per_segment=6,
        physics_dt=2e-4,
    )
    assert plant.n_segments == 3 and plant.n_facets == 2 and plant.steps_per_control == 5
    np.testing.assert_array_equal(plant.plate_stiffness, [5.0, 20.0])
    np.testing.assert_array_equal(plant.gains, [5e-3] * 3)
    state = plant.step(np.zeros(3))
    assert state.segment_ends.shape == (4, 2) and state.contact_forces.shape == (2,)
    # 18 cells of 0.1/6 m, each position stored to 6 significant digits: ≤ 1e-6 m in all.
    assert state.tip[0] == pytest.approx(0.3, abs=1e-6) and math.isclose(state.t, 1e-3)


def _numpy_state(plant: MujocoPlant, data: mujoco.MjData) -> dict[str, np.ndarray]:
    """The state's fixed-size arrays as numpy's indexing reads them from `data` (module docstring)."""
    ends = np.vstack([data.site_xpos[plant.site_ids, :2], data.geom_xpos[plant.tip_geom, :2]])
    spring = data.qpos[plant.plate_qpos]
    return {"q": data.ten_length[plant.tendon_ids], "qd": data.ten_velocity[plant.tendon_ids], "segment_ends": ends,
            "contact_forces": np.maximum(0.0, plant.plate_stiffness * spring),
            "u_applied": data.actuator_force[plant.actuator_ids]}


@pytest.mark.parametrize("changes", [{}, dict(plate="flexure", tip_friction=0.5)], ids=["ideal", "flexure"])
def test_the_compiled_state_read_is_numpys_and_each_state_keeps_its_values(changes):
    """`MujocoPlant.state` reads MuJoCo's arrays in one compiled call (softcbf_mj.physics.plant_kernel): through
    contact its arrays equal numpy's reads of a reference data bit for bit, and a state returned earlier
    keeps its values when the plant steps on (each state has arrays of its own)."""
    plant = MujocoPlant.from_config(**changes)
    plant.reset(np.zeros(2))
    data = _reference_data(plant)
    kept: list[tuple[PlantState, dict[str, bytes]]] = []
    for k in range(400):
        u = np.array([150.0, 150.0]) if k < 300 else np.array([0.0, 0.0])
        state = plant.step(u)
        _reference_period(plant, data, u)
        for key, value in _numpy_state(plant, data).items():
            assert getattr(state, key).tobytes() == value.tobytes(), (k, key)
        if plant.n_facets and not changes:  # the ideal plate: Δ is the slide joint's qpos
            assert state.extras["plate_displacement_m"].tobytes() == data.qpos[plant.plate_qpos].tobytes()
        if k % 50 == 0:
            kept.append((state, {key: getattr(state, key).tobytes() for key in ("q", "qd", "segment_ends",
                                                                              "contact_forces", "u_applied")}))
    assert max(s.contact_forces.max() for s, _ in kept) > 0.1  # the run presses the plate
    for state, values in kept:
        assert all(getattr(state, key).tobytes() == value for key, value in values.items())


def test_the_compiled_force_is_numpys_maximum():
    """max(0, k·x) as np.maximum(0.0, k·x): a negative force gives 0.0, −0.0 stays −0.0 (numpy keeps its
    second operand on a tie), NaN stays NaN."""
    from softcbf_mj.physics.plant_kernel import read_state

    x = np.array([-1.0, -0.0, 0.0, 2.0, np.nan, np.inf])
    stiffness = np.array([3.0, 3.0, 3.0, 3.0, 3.0, 0.0])  # 0 · inf = NaN
    n, p = 1, len(x)
    index = np.array([0, 0, 0, 0, *range(p)], dtype=np.int64)  # tendon, actuator, site, tip, plate qpos
    out = np.empty(5 * n + 2 + 2 * p)
    read_state(x, np.array([0.5]), np.array([0.25]), np.ones((1, 3)), np.full((1, 3), 2.0), np.array([7.0]), index,
               stiffness, out)
    forces = out[4 * n + 2:4 * n + 2 + p]
    assert forces.tobytes() == np.maximum(0.0, stiffness * x).tobytes()
    assert out[:4 * n + 2].tolist() == [0.5, 0.25, 1.0, 1.0, 2.0, 2.0]
    assert out[4 * n + 2 + p] == 7.0 and out[5 * n + 2 + p:].tobytes() == x.tobytes()


@pytest.mark.parametrize("changes, extra", [({}, 0), (dict(tau_p=0.0), 1)], ids=["pressure-lag", "no-pressure-lag"])
def test_a_period_solves_the_constraints_once_a_physics_step(changes, extra):
    """With pressure dynamics the reporting mj_forward's constraint solve stands for the period's first
    step (module docstring): steps_per_control solves a period, as bare mj_step; an ideal actuator,
    whose force a new command moves, solves once more (a held one moves nothing)."""
    plant = MujocoPlant.from_config(**changes)
    timer = plant.data.timer[mujoco.mjtTimer.mjTIMER_CONSTRAINT]
    plant.step(np.array([140.0, 140.0]))
    before = timer.number
    for k in range(20):
        plant.step(np.array([150.0, 120.0 + k]))
    assert timer.number - before == 20 * (plant.steps_per_control + extra)
    before = timer.number
    for _ in range(5):
        plant.step(np.array([150.0, 140.0]))
    assert timer.number - before == 5 * plant.steps_per_control + extra
