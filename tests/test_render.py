"""Offscreen rendering (OSMesa on the CPU-only CI): images, AprilTag detection across the arm's
working range against the camera model, the calibration scene, and backend errors that name the fix."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import mujoco
import numpy as np
import pytest

from perception.detect import TagDetector
from perception.plane import TagBoard, calibrate, tag_pose_on_plane
from softcbf_mj.camera import gl_backend
from softcbf_mj.physics import mjcf as mb
from softcbf_mj.camera import render as rd

REPO = Path(__file__).resolve().parents[1]
MODEL_DIR = REPO / "models" / "softcbf_arm"
ARM_TAGS = (0, 1, 2)
# Measured with perception.detect's refined corners over the poses below: ≤ 0.03 px, ≤ 0.06°,
# ±0.06 % and 0.013 mm (OpenCV's own sub-pixel refinement: 0.13 px, 0.49°, −0.9 %).
CENTRE_TOL_PX = 0.15  # detected tag centre vs. the projected true centre
ANGLE_TOL_DEG = 0.3  # tag angle from the detected corners vs. the body angle
SIZE_TOL = 0.005  # relative, tag size from the detected corners
PLANE_TOL_M = 1e-4  # board-calibrated vs. exact plane map over the image


@pytest.fixture(scope="module")
def model() -> mujoco.MjModel:
    return mb.build_model()


@pytest.fixture(scope="module")
def renderer(model):
    with rd.OffscreenRenderer(model) as r:
        yield r


def _bend(model: mujoco.MjModel, q: tuple[float, ...]) -> mujoco.MjData:
    """Data with every hinge of segment i at q_i / n (constant curvature), kinematics done."""
    data = mujoco.MjData(model)
    n = mb.DEFAULT_LINKS_PER_SEGMENT
    for i, qi in enumerate(q, start=1):
        for j in range(1, n + 1):
            data.qpos[model.joint(f"seg{i}_j{j}").qposadr[0]] = qi / n
    mujoco.mj_forward(model, data)
    return data


def _pressed_against_the_plate(model: mujoco.MjModel) -> mujoco.MjData:
    """1 s at (150, 150) hPa: the tip pushes the plate back (checked)."""
    data = mujoco.MjData(model)
    data.ctrl[:] = model.actuator_ctrlrange[:, 1]
    mujoco.mj_step(model, data, nstep=int(round(1.0 / model.opt.timestep)))
    mujoco.mj_forward(model, data)
    assert data.qpos[model.joint("plate1_slide").qposadr[0]] > 1e-3  # pushed out along the facet normal
    return data


_RNG = np.random.default_rng(8)
_POSES = [(0.0, 0.0), (1.0, 1.0), (-1.0, -1.0), (1.0, -1.0), (-1.0, 1.0)] + [tuple(q) for q in _RNG.uniform(-1, 1, (7, 2))]
WORKING_RANGE = [tuple(math.radians(60) * v for v in q) for q in _POSES]  # |q_i| <= 60°, corners included


def test_render_is_rgb_nonblank_deterministic_and_follows_the_state(model):
    straight, bent = _bend(model, (0.0, 0.0)), _bend(model, (0.5, -0.4))
    with rd.OffscreenRenderer(model, width=320, height=180) as r:
        first, again, other = r.render(straight), r.render(straight), r.render(bent)
    with rd.OffscreenRenderer(model, width=320, height=180) as r:
        fresh = r.render(straight)
    assert first.shape == (180, 320, 3) and first.dtype == np.uint8
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, fresh)
    assert first.std() > 20 and first.min() < 30 and first.max() > 240  # table, arm, black and white tag cells
    assert np.mean(np.any(first != other, axis=2)) > 0.002  # the arm moved in the image


@pytest.mark.parametrize("q", WORKING_RANGE + ["plate"], ids=lambda q: q if q == "plate" else "q=({:.0f}°, {:.0f}°)".format(*np.degrees(q)))
def test_every_arm_tag_is_detected_where_the_camera_model_puts_it(model, renderer, q):
    data = _pressed_against_the_plate(model) if q == "plate" else _bend(model, q)
    if q == "plate":
        q = tuple(data.ten_length[model.tendon(f"seg{i}_bend").id] for i in (1, 2))
    detections = TagDetector(tag_ids=ARM_TAGS).detect(renderer.render(data)[:, :, ::-1].copy())
    assert [d.tag_id for d in detections] == list(ARM_TAGS)
    K, (R, position) = rd.camera_matrix(model), rd.camera_pose_cv(model, data)
    plane_z = rd.tag_plane_z(model, data)
    to_plane = rd.ground_truth_calibration(model, data)
    body_angles = np.concatenate([[0.0], np.cumsum(q)])  # tag i's x axis is segment i's end direction
    for detection, placement in zip(detections, mb.arm_tag_placements(mb.ArmModelConfig())):
        x_axis = data.body(placement.body).xmat.reshape(3, 3)[:, 0]
        centre = data.site(placement.site).xpos + placement.offset * x_axis
        expected_px = rd.project(K, R, position, [centre[0], centre[1], plane_z])[0]
        assert np.linalg.norm(detection.centre - expected_px) < CENTRE_TOL_PX, (detection.tag_id, detection.centre, expected_px)
        pose = tag_pose_on_plane(to_plane.map_points(detection.corners))
        error = math.remainder(pose.angle - body_angles[detection.tag_id], 2 * math.pi)
        assert abs(math.degrees(error)) < ANGLE_TOL_DEG, (detection.tag_id, math.degrees(error))
        assert pose.size == pytest.approx(mb.DEFAULT_TAG_SIZE, rel=SIZE_TOL)


def test_camera_matrix_and_pose_are_the_documented_overhead_camera(model):
    data = _bend(model, (0.0, 0.0))
    f = 360 / math.tan(math.radians(22.5))
    np.testing.assert_allclose(rd.camera_matrix(model), [[f, 0, 639.5], [0, f, 359.5], [0, 0, 1]], rtol=1e-12)
    np.testing.assert_allclose(rd.camera_matrix(model, width=640, height=360), [[f / 2, 0, 319.5], [0, f / 2, 179.5], [0, 0, 1]], rtol=1e-12)
    R, position = rd.camera_pose_cv(model, data)
    np.testing.assert_allclose(R, np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    np.testing.assert_allclose(position, [0.122, 0.0, 0.65], atol=1e-12)
    assert rd.tag_plane_z(model, data) == pytest.approx(mb.TAG_PLANE_Z, abs=1e-12)
    u, v = rd.project(rd.camera_matrix(model), R, position, [0.0, 0.1, mb.TAG_PLANE_Z])[0]
    assert (u, v) == pytest.approx((639.5 - f * 0.122 / 0.625, 359.5 - f * 0.1 / 0.625), abs=1e-9)
    points = np.array([[0.0, 0.0], [0.3, -0.2], [-0.25, 0.15]])
    to_plane = rd.ground_truth_calibration(model, data)
    pixels = rd.project(rd.camera_matrix(model), R, position, np.column_stack([points, np.full(3, mb.TAG_PLANE_Z)]))
    np.testing.assert_allclose(to_plane.map_points(pixels), points, atol=1e-12)


def test_calibration_scene_board_calibrates_the_plane_like_the_exact_camera():
    """The committed files load from disk; a fit to the board's detected corners matches the exact map."""
    model = mujoco.MjModel.from_xml_path(str(MODEL_DIR / mb.CALIBRATION_SCENE_FILE))
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    board = TagBoard.load(MODEL_DIR / mb.CALIBRATION_BOARD_FILE)
    with rd.OffscreenRenderer(model) as r:
        detections = TagDetector().detect(r.render(data)[:, :, ::-1].copy())
    assert [d.tag_id for d in detections] == list(ARM_TAGS) + sorted(board.tags)
    fitted = calibrate(detections, board, min_tags=len(board.tags))
    exact = rd.ground_truth_calibration(model, data)
    grid = np.stack(np.meshgrid(np.linspace(0, 1279, 9), np.linspace(0, 719, 5)), axis=-1).reshape(-1, 2)
    assert np.max(np.linalg.norm(fitted.map_points(grid) - exact.map_points(grid), axis=1)) < PLANE_TOL_M


def test_renderer_sizes_and_camera_are_checked(model):
    with pytest.raises(ValueError, match=r'image width 1281 px exceeds .* offwidth="1281"'):
        rd.OffscreenRenderer(model, width=1281)
    with pytest.raises(ValueError, match=r"offheight"):
        rd.OffscreenRenderer(model, height=721)
    with pytest.raises(ValueError, match=r"height must be an integer >= 1 px, got 0"):
        rd.OffscreenRenderer(model, height=0)
    with pytest.raises(ValueError, match=r"no camera 'side'; its cameras are \['overhead'\]"):
        rd.OffscreenRenderer(model, camera="side")
    r = rd.OffscreenRenderer(model, width=64, height=36)
    assert (r.width, r.height, r.backend) == (64, 36, rd.requested_gl_backend())
    r.close()
    with pytest.raises(RuntimeError, match="after close"):
        r.render(mujoco.MjData(model))


def test_gl_backend_rules():
    assert gl_backend.configure_mujoco_gl({"MUJOCO_GL": "EGL"}) == "egl"  # a set value is honoured
    environ: dict[str, str] = {}
    assert gl_backend.configure_mujoco_gl(environ, platform="darwin") == "" and environ == {}
    gpu = os.path.exists(gl_backend.NVIDIA_DEVICE) and gl_backend.library_available("egl")
    assert gl_backend.configure_mujoco_gl(environ, platform="linux") == ("egl" if gpu else "osmesa")
    assert environ == {"MUJOCO_GL": "egl" if gpu else "osmesa"}


# Runs first in a fresh interpreter: no libOSMesa (and no libEGL) as far as Python can see.
_HIDE_GL_LIBRARIES = """
import ctypes, ctypes.util
_find, _load = ctypes.util.find_library, ctypes.CDLL.__init__
ctypes.util.find_library = lambda name: None if name in ("OSMesa", "EGL") else _find(name)
def _no_osmesa(self, name, *args, **kwargs):
    if name and "OSMesa" in str(name):
        raise OSError(f"{name}: cannot open shared object file: No such file or directory")
    _load(self, name, *args, **kwargs)
ctypes.CDLL.__init__ = _no_osmesa
"""


def _run(script: str, hide_gl_libraries: bool = True, **env: str) -> str:
    """stdout of `script` in a fresh interpreter without display, MUJOCO_GL unset unless given."""
    clean = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(
        [sys.executable, "-c", (_HIDE_GL_LIBRARIES if hide_gl_libraries else "") + script], env={**clean, **env}, cwd=REPO,
        capture_output=True, text=True, timeout=120,
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


_RENDER = """
from softcbf_mj.physics import mjcf
from softcbf_mj.camera import render
import mujoco
try:
    with render.OffscreenRenderer(mjcf.build_model(), width=64, height=36) as renderer:
        print("rendered", renderer.backend, renderer.render(mujoco.MjData(renderer.model)).shape)
except render.RenderBackendError as error:
    print(error)
"""


def test_missing_osmesa_requested_explicitly_fails_at_import_with_the_fix():
    out = _run("try:\n    import softcbf_mj\nexcept ImportError as error:\n    print(error)\n", MUJOCO_GL="osmesa")
    assert "MUJOCO_GL=osmesa but libOSMesa is not installed" in out
    assert "bash scripts/setup.sh" in out and "apt-get install libosmesa6" in out and "MUJOCO_GL=egl" in out


def test_no_gl_library_makes_the_renderer_name_the_fix():
    out = _run(_RENDER)
    assert "cannot create an offscreen OpenGL context with MUJOCO_GL=glfw" in out
    assert "set MUJOCO_GL=osmesa" in out and "bash scripts/setup.sh" in out and "apt-get install libosmesa6" in out


def test_the_backend_is_chosen_when_the_renderer_is_created_not_when_mujoco_was_imported():
    """`import mujoco` first (it binds glfw: no display here), then softcbf_mj picks the backend: renders."""
    backend = gl_backend.configure_mujoco_gl({})
    out = _run("import mujoco\n" + _RENDER, hide_gl_libraries=False)
    assert f"rendered {backend} (36, 64, 3)" in out
