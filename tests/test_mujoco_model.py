"""The generated MJCF: compiles, steps without warnings, byte-stable, and built as documented."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from controllers.model.params import reference_robot, uniform_robot
from perception.plane import TagBoard
from softcbf_mj.physics import mjcf as mb
from softcbf_mj.physics.mujoco_plant import WARNINGS

REPO = Path(__file__).resolve().parents[1]
MODEL_DIR = REPO / "models" / "softcbf_arm"
SCENES = sorted((REPO / "models").glob("**/scene*.xml"))


def test_scenes_exist():
    assert MODEL_DIR / "scene.xml" in SCENES


# Generated variants (docs/beyond-the-paper.md#flexure-plate and any arm): flexure plates, friction, gravity, 1 and 3 segments,
# the camera loop's coarser rod; each must compile and step as warning-free as the files.
VARIANTS = {
    "flexure": dict(plate="flexure"),
    "flexure_friction": dict(plate="flexure", tip_friction=0.3),
    "ideal_friction": dict(tip_friction=0.3),
    "flexure_camera_rod": dict(plate="flexure", links_per_segment=mb.CAMERA_LINKS_PER_SEGMENT, physics_dt=mb.CAMERA_PHYSICS_DT),
    "gravity_vertical_arm": dict(gravity=(0.0, -9.81, 0.0)),
    "one_segment_flexure": dict(robot=uniform_robot(1), plate="flexure"),
    "three_segments_flexure": dict(robot=uniform_robot(3), plate="flexure", tip_friction=0.3),
}


def _scene_model(scene: Path | str) -> mujoco.MjModel:
    if isinstance(scene, Path):
        return mujoco.MjModel.from_xml_path(str(scene))
    return mb.build_model(mb.ArmModelConfig(**VARIANTS[scene]))


@pytest.mark.parametrize("scene", SCENES + sorted(VARIANTS), ids=lambda p: str(p.relative_to(REPO)) if isinstance(p, Path) else p)
def test_scene_steps_one_second_under_random_controls_without_warnings(scene):
    model = _scene_model(scene)
    data = mujoco.MjData(model)
    mujoco.mj_resetDataKeyframe(model, data, model.key("home").id)
    rng = np.random.default_rng(0)
    low, high = model.actuator_ctrlrange.T
    for _ in range(int(round(1.0 / model.opt.timestep))):
        data.ctrl[:] = rng.uniform(low, high)
        mujoco.mj_step(model, data)
    assert data.time == pytest.approx(1.0)
    assert np.all(np.isfinite(data.qpos)) and np.all(np.isfinite(data.qvel))
    warnings = {name: int(data.warning[i].number) for i, name in WARNINGS.items()}
    assert not any(warnings.values()), warnings


def test_generation_is_byte_stable():
    variant = mb.ArmModelConfig(robot=uniform_robot(3, length=0.1), H=[[1.0, 0.0], [0.2, 1.0]], h=[0.2, 0.12],
                                plate_stiffness=[5.0, 20.0], links_per_segment=7, tau_p=0.0)
    for config in (mb.ArmModelConfig(), variant):
        assert mb.arm_xml(config) == mb.arm_xml(config)
        assert mb.scene_xml(config) == mb.scene_xml(config)


def test_committed_files_equal_what_the_generator_writes_now(tmp_path):
    for name, text in ((mb.ARM_FILE, mb.arm_xml()), (mb.SCENE_FILE, mb.scene_xml()),
                       (mb.CALIBRATION_SCENE_FILE, mb.scene_xml(board=True))):
        committed = (MODEL_DIR / name).read_text(encoding="utf-8")
        assert committed == text, f"{name} is stale: run `python tools/generate_model.py`"
    written = mb.write_model_files(tmp_path)
    assert len(written) == 4 + 3 + 12  # 3 XML files, the board JSON, 3 arm + 12 board textures
    for path in written:
        name = path.relative_to(tmp_path)
        assert (MODEL_DIR / name).read_bytes() == path.read_bytes(), f"{name} is stale: run `python tools/generate_model.py`"
    assert sorted(p.name for p in (MODEL_DIR / mb.ASSETS_DIR).iterdir()) == sorted(
        p.name for p in written if p.parent.name == mb.ASSETS_DIR
    )


@pytest.mark.parametrize("board", [False, True], ids=["scene", "calibration_scene"])
def test_written_files_compile_to_the_runtime_model(tmp_path, board):
    """Numbers are rounded to the XML writer's precision first, so file and spec agree exactly."""
    config = mb.ArmModelConfig(robot=reference_robot().replace(gains=(1 / 170, 1 / 190)), plate_mass=1 / 70)
    mb.write_model_files(tmp_path, config)
    from_file = mujoco.MjModel.from_xml_path(str(tmp_path / (mb.CALIBRATION_SCENE_FILE if board else mb.SCENE_FILE)))
    runtime = mb.build_model(config, board=board)
    differing = []
    for name in dir(from_file):
        a = getattr(from_file, name)
        if isinstance(a, np.ndarray) and not name.startswith("_") and name != "tex_pathadr":  # where a texture was read from
            b = getattr(runtime, name)
            if name == "site_size":  # the writer keeps only the radius of a sphere site
                a, b = a[:, 0], b[:, 0]
            if a.shape != b.shape or not np.array_equal(a, b):
                differing.append(name)
    assert differing == []
    assert from_file.ntex == runtime.ntex == 3 + (12 if board else 0)  # the tags (the table is plain)


def test_options_names_and_limits():
    robot = reference_robot()
    config = mb.ArmModelConfig()
    model = mb.build_model(config)
    assert model.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    assert model.opt.jacobian == mujoco.mjtJacobian.mjJAC_AUTO
    assert np.all(model.opt.gravity == 0)
    assert model.opt.timestep == config.physics_dt
    n = config.links_per_segment
    for i in (1, 2):
        for j in range(1, n + 1):
            joint = model.joint(f"seg{i}_j{j}")
            assert joint.type[0] == mujoco.mjtJoint.mjJNT_HINGE
            np.testing.assert_array_equal(joint.axis, [0, 0, 1])
            assert model.jnt_stiffness[joint.id] == pytest.approx(n * robot.stiffness[i - 1])
            assert model.dof_damping[joint.dofadr[0]] == pytest.approx(n * robot.damping[i - 1])
        actuator = model.actuator(f"seg{i}_pressure")
        np.testing.assert_array_equal(actuator.ctrlrange, [robot.u_min[i - 1], robot.u_max[i - 1]])
        assert actuator.gear[0] == pytest.approx(robot.gains[i - 1], rel=1e-6)
        assert actuator.dyntype[0] == mujoco.mjtDyn.mjDYN_FILTEREXACT
        assert actuator.dynprm[0] == config.tau_p
        model.site(f"seg{i}_end")
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"seg1_j{n + 1}") == -1
    for name in ("tip", "plate1"):
        model.geom(name)
    model.joint("plate1_slide"), model.key("home"), model.camera("overhead")
    ideal = mb.build_model(mb.ArmModelConfig(tau_p=0.0))
    assert np.all(ideal.actuator_dyntype == mujoco.mjtDyn.mjDYN_NONE) and ideal.na == 0


@pytest.mark.parametrize(("links", "plate", "nv", "sparse"), [
    (10, "ideal", 21, False), (10, "flexure", 31, False), (20, "ideal", 41, False), (40, "ideal", 81, True),
])
def test_mujoco_chooses_the_jacobian(links, plate, nv, sparse):
    """No forced dense Jacobian: MuJoCo's `auto` makes the default arm dense and the convergence
    study's finest arm (nv = 81) sparse; the files carry no `jacobian` option."""
    model = mb.build_model(mb.ArmModelConfig(links_per_segment=links, plate=plate))
    assert (model.nv, model.opt.jacobian) == (nv, mujoco.mjtJacobian.mjJAC_AUTO)
    assert bool(mujoco.mj_isSparse(model)) is sparse
    assert "jacobian" not in (MODEL_DIR / "softcbf_arm.xml").read_text()


def test_sparse_and_dense_jacobians_agree_through_contact_and_release():
    """The finest arm (n = 40, nv = 81) strikes the plate at (120, 120) hPa and is released to
    (-60, 60) hPa: MuJoCo's sparse factorisation (what `auto` picks there) follows the dense one
    to round-off. A guard on the path the finest arms now take: MuJoCo 4.0.0's sparse-Cholesky
    bug gave wrong accelerations in some sparse solves (this chain and plate agreed there too,
    to 6e-14 in qpos, so this does not detect 4.0.0)."""
    trajectories = {}
    for jacobian in (mujoco.mjtJacobian.mjJAC_DENSE, mujoco.mjtJacobian.mjJAC_SPARSE):
        spec = mb.build_spec(mb.ArmModelConfig(links_per_segment=40, tau_p=0.0))
        spec.option.jacobian = jacobian
        model = spec.compile()
        data = mujoco.MjData(model)
        qpos, in_contact = [], 0
        for k in range(400):  # 0.4 s of 1 ms periods
            data.ctrl[:] = (120.0, 120.0) if k < 250 else (-60.0, 60.0)
            mujoco.mj_step(model, data, nstep=10)
            qpos.append(data.qpos.copy())
            in_contact += data.ncon > 0
        assert in_contact > 50
        trajectories[int(jacobian)] = np.array(qpos)
    dense, sparse = trajectories.values()
    np.testing.assert_allclose(sparse, dense, rtol=0, atol=1e-9)


def test_arm_geoms_collide_only_with_plates():
    model = mb.build_model()
    base = model.body("base").id
    arm = [g for g in range(model.ngeom) if model.body_rootid[model.geom_bodyid[g]] == base]
    plates = [model.geom("plate1").id]
    others = [g for g in range(model.ngeom) if g not in arm and g not in plates]

    def collide(a, b):
        return bool(model.geom_contype[a] & model.geom_conaffinity[b] or model.geom_contype[b] & model.geom_conaffinity[a])

    assert all(not collide(a, b) for a in arm for b in arm)
    assert all(not collide(a, b) for a in arm + plates for b in others)
    colliding = [a for a in arm if collide(a, plates[0])]
    assert model.geom("tip").id in colliding and len(colliding) >= 2 * 10  # the links, not only the tip


def test_mass_and_inertia_of_each_segment():
    """Straight arm: segment i's links carry m_i (the base keeps segment 1's first half cell)
    with inertia m L²/12 about the segment centre."""
    robot = reference_robot()
    n = 10
    model = mb.build_model(mb.ArmModelConfig(links_per_segment=n, H=np.zeros((0, 2)), h=()))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    moving = [model.joint(f"seg{i}_j{j}").bodyid[0] for i in (1, 2) for j in range(1, n + 1)]
    mass = model.body_mass[moving]
    assert mass.sum() == pytest.approx(sum(robot.masses) - robot.masses[0] / (2 * n), rel=1e-6)
    # Straight arm: total inertia about x = L of the moving bodies equals the two rods' inertia,
    # minus the base half cell: computed from the same uniform density.
    com_x = data.xipos[moving, 0]
    izz = np.sum(model.body_inertia[moving, 2] + mass * (com_x - robot.lengths[0]) ** 2)
    L, m, c = robot.lengths[0], robot.masses[0], robot.lengths[0] / n
    half_cell = (m / (2 * n)) * ((c / 2) ** 2 / 12 + (L - c / 4) ** 2)
    rods = 2 * (m * L * L / 12 + m * (L / 2) ** 2)
    assert izz == pytest.approx(rods - half_cell, rel=1e-5)


def test_excess_inertia_is_spread_and_too_small_inertia_is_refused():
    robot = reference_robot()
    n = 10
    extra = robot.replace(inertias=tuple(m * L * L / 12 * 1.5 for m, L in zip(robot.masses, robot.lengths)))
    base = mb.build_model(mb.ArmModelConfig(links_per_segment=n))
    heavier = mb.build_model(mb.ArmModelConfig(robot=extra, links_per_segment=n))
    body = base.body("seg1_link3").id
    excess = robot.masses[0] * robot.lengths[0] ** 2 / 12 * 0.5 / n
    assert heavier.body_inertia[body, 2] - base.body_inertia[body, 2] == pytest.approx(excess, rel=1e-5)
    tiny = robot.replace(inertias=(1e-9, 1e-9))
    with pytest.raises(ValueError, match=r"inertias\[0\].*too small"):
        mb.build_model(mb.ArmModelConfig(robot=tiny, links_per_segment=n))


@pytest.mark.parametrize("H, h", [([[0.36, 1.0]], [0.15]), ([[1.0, 0.0]], [0.2]), ([[-0.5, -1.0]], [0.1])])
def test_plate_surface_is_the_facet_shifted_by_the_tip_radius(H, h):
    config = mb.ArmModelConfig(H=H, h=h)
    model = mb.build_model(config)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    normal = np.array(H[0]) / np.linalg.norm(H[0])
    surface = data.site("plate1_surface").xpos[:2]
    assert (np.array(H[0]) @ surface - h[0]) / np.linalg.norm(H[0]) == pytest.approx(config.tip_radius, abs=1e-6)
    np.testing.assert_allclose(data.site("plate1_surface").xmat.reshape(3, 3)[:2, 0], normal, atol=1e-6)
    np.testing.assert_allclose(model.jnt_axis[model.joint("plate1_slide").id], [1, 0, 0])
    assert model.jnt_stiffness[model.joint("plate1_slide").id] == pytest.approx(mb.PAPER_PLATE_STIFFNESS)


def test_overhead_camera_looks_down_with_documented_intrinsics():
    config = mb.ArmModelConfig()
    model = mb.build_model(config)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    camera = model.camera("overhead")
    assert camera.fovy[0] == mb.CAMERA_FOVY_DEG
    np.testing.assert_array_equal(model.cam_resolution[camera.id], mb.CAMERA_RESOLUTION)
    xmat = data.cam("overhead").xmat.reshape(3, 3)
    np.testing.assert_allclose(xmat[:, 2], [0, 0, 1], atol=1e-12)  # the camera looks along its −z
    np.testing.assert_allclose(xmat[:, 1], [0, 1, 0], atol=1e-12)  # image up = +y
    pos, focal = mb.overhead_camera_pose(config)
    assert focal == pytest.approx((mb.CAMERA_RESOLUTION[1] / 2) / math.tan(math.radians(mb.CAMERA_FOVY_DEG) / 2))
    np.testing.assert_allclose(data.cam("overhead").xpos, pos)
    # The whole reach circle is in view.
    half_height = pos[2] * math.tan(math.radians(mb.CAMERA_FOVY_DEG) / 2)
    assert half_height >= sum(config.robot.lengths)


def test_tags_leave_the_physics_bit_identical():
    """Same trajectory (1 s, random pressures, the tip striking the plate) with and without the tags
    (their texture, material and geom lines removed from the arm file; MjSpec.delete of a geom
    corrupts memory in MuJoCo 4.0.0)."""
    arm = mb.arm_xml()
    without = "\n".join(line for line in arm.splitlines() if 'name="tag' not in line)
    assert arm.count('name="tag') == 9 and 'name="tag' not in without  # 3 textures, 3 materials, 3 geoms
    textures = mb.tag_textures(range(3))
    trajectories, masses = [], []
    for text in (arm, without):
        model = mujoco.MjModel.from_xml_string(mb.scene_xml(), {mb.ARM_FILE: text.encode(), **textures})
        data = mujoco.MjData(model)
        rng = np.random.default_rng(3)
        low, high = model.actuator_ctrlrange.T
        rows = []
        for k in range(10_000):
            if k % 500 == 0:
                data.ctrl[:] = rng.uniform(0.3 * high, high)  # positive pressures bend towards the plate
            mujoco.mj_step(model, data)
            if k % 10 == 0:
                rows.append(np.concatenate([data.qpos, data.qvel, data.act]))
        plate = model.joint("plate1_slide").qposadr[0]
        trajectories.append(np.array(rows))
        masses.append((model.body_mass.copy(), model.body_inertia.copy()))
    np.testing.assert_array_equal(trajectories[0], trajectories[1])
    np.testing.assert_array_equal(masses[0][0], masses[1][0])
    np.testing.assert_array_equal(masses[0][1], masses[1][1])
    assert np.ptp(trajectories[0][:, plate]) > 1e-3  # the plate moved: contact happened


@pytest.mark.parametrize("tag_size", [mb.DEFAULT_TAG_SIZE, 0.02])
def test_tags_sit_where_documented(tag_size):
    """Visual-only flat boxes, top faces in the plane TAG_PLANE_Z above the plates, centred on the
    base / segment-end sites (the tip tag S/2 behind the tip), x axis along the body's x axis."""
    config = mb.ArmModelConfig(tag_size=tag_size)
    model = mb.build_model(config)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    data.qpos[:20] = rng.uniform(-0.1, 0.1, 20)
    mujoco.mj_forward(model, data)
    edge = tag_size * 10 / 8  # black square plus a one-cell quiet zone on each side
    plate_top = data.geom("plate1").xpos[2] + model.geom("plate1").size[2]
    for placement in mb.arm_tag_placements(config):
        geom = model.geom(f"tag{placement.tag_id}")
        assert geom.contype[0] == 0 and geom.conaffinity[0] == 0
        assert model.body(geom.bodyid[0]).name == placement.body
        np.testing.assert_allclose(geom.size, [edge / 2, edge / 2, 0.0005], rtol=1e-6)
        xmat = data.geom(geom.id).xmat.reshape(3, 3)
        body_xmat = data.body(placement.body).xmat.reshape(3, 3)
        np.testing.assert_allclose(xmat, body_xmat, atol=1e-12)
        top = data.geom(geom.id).xpos[2] + geom.size[2]
        assert top == pytest.approx(mb.TAG_PLANE_Z, abs=1e-12) and top - geom.size[2] * 2 > plate_top
        centre = data.site(placement.site).xpos + placement.offset * body_xmat[:, 0]
        np.testing.assert_allclose(data.geom(geom.id).xpos[:2], centre[:2], atol=1e-6)
    assert mb.arm_tag_placements(config)[-1].offset == pytest.approx(-edge / 2)
    assert [p.tag_id for p in mb.arm_tag_placements(config)] == [0, 1, 2]


def test_calibration_board_lies_in_the_tag_plane_at_the_documented_poses():
    config = mb.ArmModelConfig()
    board = TagBoard.load(MODEL_DIR / mb.CALIBRATION_BOARD_FILE)
    assert board == mb.calibration_board(config)
    assert sorted(board.tags) == list(mb.CALIBRATION_BOARD_IDS) and board.tag_size == config.tag_size
    model = mujoco.MjModel.from_xml_path(str(MODEL_DIR / mb.CALIBRATION_SCENE_FILE))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    reach = sum(config.robot.lengths)
    for tag_id, (x, y, angle) in board.tags.items():
        geom = data.geom(f"tag{tag_id}")
        np.testing.assert_allclose(geom.xpos, [x, y, mb.TAG_PLANE_Z - 0.0005], atol=1e-9)
        xmat = geom.xmat.reshape(3, 3)
        assert math.atan2(xmat[1, 0], xmat[0, 0]) == pytest.approx(math.atan2(math.sin(angle), math.cos(angle)), abs=1e-6)
        assert math.hypot(x, y) > reach + config.tag_size * 10 / 8 / math.sqrt(2)


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(H=[[0.0, 0.0]], h=[0.1]), r"H\[0\] must be non-zero"),
        (dict(H=[[0.36, 1.0]], h=[-0.1]), r"h\[0\] must be > 0"),
        (dict(H=[[0.36, 1.0]], h=[0.1, 0.2]), "one row per facet"),
        (dict(H=[[0.36, 1.0, 0.0]], h=[0.1]), r"H must have shape \(P, 2\)"),
        (dict(plate_stiffness=-1.0), "plate_stiffness must be finite and > 0"),
        (dict(links_per_segment=0), "links_per_segment must be an integer >= 1"),
        (dict(tau_p=-0.01), "tau_p must be >= 0"),
        (dict(physics_dt=0.0), "physics_dt must be > 0"),
        (dict(physics_dt=2e-3), "contact_timeconst .* must be >= 2 physics_dt"),
        (dict(integrator="leapfrog"), "integrator must be one of"),
        (dict(tag_size=0.0), "tag_size must be > 0 m"),
        (dict(tag_size=0.06), r"tag_size 0.06 m gives tags of 0.075 m .* use tag_size <= 0.0488 m"),
    ],
)
def test_config_validation_says_what_was_wrong(changes, message):
    with pytest.raises(ValueError, match=message):
        mb.ArmModelConfig(**changes)
