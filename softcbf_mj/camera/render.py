"""Offscreen camera images of the MuJoCo scene, the camera's pinhole model, and the tags' ground truth.

Rendering. `OffscreenRenderer(model, camera="overhead", width=None, height=None)` renders
`camera` into (H, W, 3) uint8 RGB images through MuJoCo's offscreen framebuffer; W × H
default to the camera's `resolution` (MuJoCo's 1 × 1 default means none: then the
framebuffer's offwidth × offheight) and may not exceed offwidth × offheight. Sites are
hidden (a camera sees no sites). The OpenGL context is one of MuJoCo's (`mujoco.osmesa`,
`mujoco.egl`, `mujoco.glfw`), picked by MUJOCO_GL when the renderer is created — not when
`mujoco` was imported, so import order does not matter — and `softcbf_mj.camera.gl_backend`
sets MUJOCO_GL when unset (osmesa on CPU-only machines, egl with an NVIDIA GPU). When no
GL context can be made, `RenderBackendError` names the backend, the cause and the fix.
(PyOpenGL binds one platform per process: osmesa and egl contexts cannot be mixed.)

Pinhole model. A MuJoCo camera of vertical field of view fovy renders square pixels without
distortion, its principal point at the image centre. In OpenCV's pixel convention (x
right, y down, pixel centres at integer coordinates; MuJoCo's image spans the pixel edges
[0, W] × [0, H]):

    K = [[f, 0, cx], [0, f, cy], [0, 0, 1]],  f = (H/2) / tan(fovy/2),  cx = (W − 1)/2,  cy = (H − 1)/2   [px]

MuJoCo cameras look along their −z with x right and y up (columns of `cam_xmat`); OpenCV's
camera axes are x right, y down, z forward, so

    R_world_from_cam = cam_xmat · diag(1, −1, −1),   c = cam_xpos  [m],

and a world point p (m) projects to s·[u, v, 1]ᵀ = K Rᵀ (p − c) (`project`). The exact
image-to-plane map of the tags' plane z = plane_z is `PlaneCalibration.from_pinhole(K, R,
c, plane_z)` (`ground_truth_calibration`).

Tags. Geoms named `tag{id}` are the AprilTags (`softcbf_mj.physics.mjcf`): flat boxes
whose top face is the texture (edge S = textured_size(s)); `tag_plane_z` is the height
(m) of those faces, `tag_poses` each tag's centre (x, y) m, angle θ rad of its image x
axis in the world xy plane and black-square size s m.
"""

from __future__ import annotations

import importlib
import math
import os
import re
from typing import Any

import mujoco
import numpy as np

from perception.plane import PlaneCalibration, TagPose, fovy_intrinsics
from perception.tags import QUIET_CELLS, TAG_CELLS
from softcbf_mj.camera.gl_backend import fix_for

_TAG_GEOM = re.compile(r"tag(\d+)")
_CV_FROM_MUJOCO_CAMERA = np.diag([1.0, -1.0, -1.0])
_GL_CONTEXTS = {"osmesa": "mujoco.osmesa", "egl": "mujoco.egl", "glfw": "mujoco.glfw", "cgl": "mujoco.cgl"}
_GLFW_ALIASES = ("", "1", "true", "on", "enable", "enabled", "glfw")
_EXTRA_SCENE_GEOMS = 100  # room for decorations beyond the model's geoms


class RenderBackendError(RuntimeError):
    """No OpenGL context for offscreen rendering; the message names the backend, the cause and the fix."""


def requested_gl_backend() -> str:
    """The backend MUJOCO_GL asks for now: "osmesa", "egl", "glfw" (also when unset) or the value as given."""
    value = os.environ.get("MUJOCO_GL", "").strip().lower()
    return "glfw" if value in _GLFW_ALIASES else value


def _camera_id(model: mujoco.MjModel, camera: str) -> int:
    camera_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
    if camera_id < 0:
        names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i) for i in range(model.ncam)]
        raise ValueError(f"the model has no camera {camera!r}; its cameras are {names}")
    return camera_id


def image_size(model: mujoco.MjModel, camera: str = "overhead", width: int | None = None, height: int | None = None) -> tuple[int, int]:
    """(W, H) px: the given values, else the camera's resolution, else the offscreen framebuffer's."""
    camera_id = _camera_id(model, camera)
    resolution = tuple(int(v) for v in model.cam_resolution[camera_id])
    default = resolution if resolution != (1, 1) else (int(model.vis.global_.offwidth), int(model.vis.global_.offheight))
    size = (default[0] if width is None else width, default[1] if height is None else height)
    for name, value in zip(("width", "height"), size):
        if isinstance(value, bool) or int(value) != value or value < 1:
            raise ValueError(f"{name} must be an integer >= 1 px, got {value!r}")
    return int(size[0]), int(size[1])


def camera_matrix(model: mujoco.MjModel, camera: str = "overhead", width: int | None = None, height: int | None = None) -> np.ndarray:
    """Intrinsics K (3 × 3, px) of `camera` rendering W × H px images, OpenCV pixel convention."""
    camera_id = _camera_id(model, camera)
    if np.any(model.cam_sensorsize[camera_id] != 0):
        raise ValueError(
            f"camera {camera!r} is defined by a physical sensor (sensorsize/focal); camera_matrix supports "
            "cameras defined by fovy only"
        )
    return fovy_intrinsics(*image_size(model, camera, width, height), float(model.cam_fovy[camera_id]))


def camera_pose_cv(model: mujoco.MjModel, data: mujoco.MjData, camera: str = "overhead") -> tuple[np.ndarray, np.ndarray]:
    """(R_world_from_cam (3 × 3), camera position (3,) m) in OpenCV's camera axes; needs kinematics of `data`."""
    camera_id = _camera_id(model, camera)
    R = data.cam_xmat[camera_id].reshape(3, 3) @ _CV_FROM_MUJOCO_CAMERA
    return R, data.cam_xpos[camera_id].copy()


def project(K: np.ndarray, R_world_from_cam: np.ndarray, cam_pos: np.ndarray, points_world: Any) -> np.ndarray:
    """Pixels (n, 2) of world points (n, 3) m: s·[u, v, 1]ᵀ = K Rᵀ (p − c); points must lie in front of the camera."""
    points = np.atleast_2d(np.asarray(points_world, dtype=float))
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"points_world must have shape (n, 3) or (3,), got {np.shape(points_world)}")
    in_camera = (points - cam_pos) @ R_world_from_cam
    if np.any(in_camera[:, 2] <= 0):
        raise ValueError(f"points {np.nonzero(in_camera[:, 2] <= 0)[0].tolist()} lie behind the camera")
    homogeneous = in_camera @ K.T
    return homogeneous[:, :2] / homogeneous[:, 2:3]


def tag_geoms(model: mujoco.MjModel) -> dict[int, int]:
    """Tag id → geom id of every geom named `tag{id}`, sorted by tag id."""
    found = {}
    for geom in range(model.ngeom):
        match = _TAG_GEOM.fullmatch(mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom) or "")
        if match:
            found[int(match.group(1))] = geom
    return dict(sorted(found.items()))


def tag_poses(model: mujoco.MjModel, data: mujoco.MjData) -> dict[int, TagPose]:
    """Each tag's centre (x, y) m, angle θ rad of its image x axis and black-square size s m (world frame)."""
    poses = {}
    for tag_id, geom in tag_geoms(model).items():
        xmat = data.geom_xmat[geom].reshape(3, 3)
        size = 2 * float(model.geom_size[geom, 0]) * TAG_CELLS / (TAG_CELLS + 2 * QUIET_CELLS)
        x, y = data.geom_xpos[geom, :2]
        poses[tag_id] = TagPose(float(x), float(y), math.atan2(xmat[1, 0], xmat[0, 0]), size)
    return poses


def tag_plane_z(model: mujoco.MjModel, data: mujoco.MjData) -> float:
    """Height (m) of the tags' textured top faces, which all lie in one horizontal plane."""
    geoms = list(tag_geoms(model).values())
    if not geoms:
        raise ValueError("the model has no tag geoms (named tag{id}); build it with softcbf_mj.physics.mjcf")
    normals = data.geom_xmat[geoms].reshape(-1, 3, 3)[:, :, 2]
    tops = data.geom_xpos[geoms, 2] + model.geom_size[geoms, 2] * normals[:, 2]
    if not (np.allclose(normals, [0.0, 0.0, 1.0], atol=1e-9) and np.ptp(tops) < 1e-9):
        raise ValueError(f"the tags must lie flat in one plane z = const, got top faces at z = {tops.tolist()} m")
    return float(tops.mean())


def ground_truth_calibration(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    camera: str = "overhead",
    width: int | None = None,
    height: int | None = None,
    plane_z: float | None = None,
) -> PlaneCalibration:
    """The exact image-to-plane map of `camera` for the plane z = plane_z (default: `tag_plane_z`)."""
    R, position = camera_pose_cv(model, data, camera)
    z = tag_plane_z(model, data) if plane_z is None else plane_z
    return PlaneCalibration.from_pinhole(camera_matrix(model, camera, width, height), R, position, z)


class OffscreenRenderer:
    """Renders `camera` of `model` into (height, width, 3) uint8 RGB images; use `with` or `close()`."""

    def __init__(self, model: mujoco.MjModel, camera: str = "overhead", width: int | None = None, height: int | None = None) -> None:
        self._gl: Any = None
        self._context: mujoco.MjrContext | None = None
        self.model = model
        self.camera = camera
        self.width, self.height = image_size(model, camera, width, height)
        buffer = {"width": int(model.vis.global_.offwidth), "height": int(model.vis.global_.offheight)}
        for name, value in (("width", self.width), ("height", self.height)):
            if value > buffer[name]:
                raise ValueError(
                    f"image {name} {value} px exceeds the model's offscreen framebuffer ({buffer[name]} px); "
                    f'raise it in the model, <visual><global off{name}="{value}"/></visual> '
                    f"(MjSpec: spec.visual.global_.off{name} = {value}), or render at most {buffer[name]} px"
                )
        self.backend = requested_gl_backend()
        if self.backend not in _GL_CONTEXTS:
            raise RenderBackendError(f"MUJOCO_GL={self.backend} cannot render; {fix_for(self.backend)}")
        try:  # each backend fails its own way: ImportError, OSError, RuntimeError, mujoco.FatalError
            self._gl = importlib.import_module(_GL_CONTEXTS[self.backend]).GLContext(self.width, self.height)
            self._gl.make_current()
            self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        except Exception as error:
            self.close()
            raise RenderBackendError(
                f"cannot create an offscreen OpenGL context with MUJOCO_GL={self.backend}: "
                f"{type(error).__name__}: {error}. Fix: {fix_for(self.backend)}"
            ) from error
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)
        self._scene = mujoco.MjvScene(model, maxgeom=model.ngeom + _EXTRA_SCENE_GEOMS)
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = _camera_id(model, camera)
        self._option = mujoco.MjvOption()
        self._option.sitegroup[:] = 0
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._pixels = np.empty((self.height, self.width, 3), dtype=np.uint8)

    def render(self, data: mujoco.MjData) -> np.ndarray:
        """The camera's image (height, width, 3) uint8 RGB of the state in `data` (kinematics must be current)."""
        if self._context is None:
            raise RuntimeError("render() called after close()")
        self._gl.make_current()
        mujoco.mjv_updateScene(self.model, data, self._option, None, self._camera, mujoco.mjtCatBit.mjCAT_ALL, self._scene)
        mujoco.mjr_render(self._rect, self._scene, self._context)
        mujoco.mjr_readPixels(self._pixels, None, self._rect, self._context)
        return np.flipud(self._pixels).copy()  # OpenGL's rows run bottom-up

    def close(self) -> None:
        """Free the GL resources; the renderer cannot be used afterwards."""
        if self._context is not None:
            self._gl.make_current()
            self._context.free()
            self._context = None
        if self._gl is not None:
            self._gl.free()
            self._gl = None

    def __enter__(self) -> OffscreenRenderer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
