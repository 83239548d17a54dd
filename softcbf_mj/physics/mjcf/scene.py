"""The scene around the arm: table, lights, the overhead camera and the calibration board of tags.

The camera looks down −z from above the middle of the reach (`overhead_camera_pose`); the board's tags
(`CALIBRATION_BOARD_IDS`) lie on the world in the tag plane, outside the arm's reach and inside the view
(`calibration_board`). Lighting and render settings: `add_scene`. Appearance only: nothing here touches
the arm or the plates, so the physics of the scene and of the arm file alone are the same.
"""

from __future__ import annotations

import math

import mujoco

from perception.plane import TagBoard, fovy_intrinsics
from perception.tags import arm_tag_ids, textured_size
from softcbf_mj.physics.mjcf.arm import VISUAL_RADIUS
from softcbf_mj.physics.mjcf.config import ArmModelConfig
from softcbf_mj.physics.mjcf.precision import r6
from softcbf_mj.physics.mjcf.tags import TAG_PLANE_Z, add_tag, tag_textures
from vocabulary.settings import setting

CAMERA_FOVY_DEG = 45.0
CAMERA_RESOLUTION = (setting("width").default, setting("height").default)  # px, width × height (the vocabulary's)
_CAMERA_FIELD_MARGIN = 1.1  # the image height covers ±1.1 Σ L around the workspace centre
_TABLE_COLOR = (0.78, 0.76, 0.72, 1.0)
CALIBRATION_BOARD_IDS = tuple(range(10, 22))  # tags of the calibration board (arm: 0..N)
# Board tag centres in units of the reach Σ L (x from the base, y): one column behind the
# base, three beyond the reach; every tag lies outside the reach circle and inside the view.
_BOARD_COLUMNS = (-1.25, 1.3, 1.7, 2.1)
_BOARD_ROWS = (-0.8, 0.0, 0.8)


def overhead_camera_pose(config: ArmModelConfig) -> tuple[tuple[float, float, float], float]:
    """Position (m) of the overhead camera and its focal length fx = fy (px).

    The camera looks down −z with image right = +x and image up = +y; it sits above
    (Σ L / 2, 0) at the height where the image height spans ±1.1 Σ L. Intrinsics:
    `perception.plane.fovy_intrinsics` (fx = fy = (H_px / 2) / tan(fovy / 2), centred principal point).
    """
    reach = sum(config.robot.lengths)
    half_fov = math.radians(CAMERA_FOVY_DEG) / 2
    height = r6(round(_CAMERA_FIELD_MARGIN * reach / math.tan(half_fov), 2))
    focal = float(fovy_intrinsics(*CAMERA_RESOLUTION, CAMERA_FOVY_DEG)[0, 0])
    return (r6(reach / 2), 0.0, height), focal


def calibration_board(config: ArmModelConfig | None = None) -> TagBoard:
    """The calibration scene's board: tags `CALIBRATION_BOARD_IDS` of `tag_size` in the tag plane.

    Centres at (column, row) × Σ L for the columns `_BOARD_COLUMNS` and rows `_BOARD_ROWS`
    (one column behind the base, three beyond the reach), angles 0, π/2, π, −π/2 in turn;
    refused unless every tag lies outside the reach circle (Σ L plus the tag's
    half-diagonal: no arm tag can slide under it) and wholly inside the overhead view.
    """
    config = config or ArmModelConfig()
    reach = sum(config.robot.lengths)
    arm_ids = arm_tag_ids(config.robot.n_segments)
    if set(arm_ids) & set(CALIBRATION_BOARD_IDS):
        raise ValueError(
            f"the arm's tags {list(arm_ids)} overlap the calibration board's {list(CALIBRATION_BOARD_IDS)}; "
            f"the board needs an arm of at most {CALIBRATION_BOARD_IDS[0] - 1} segments"
        )
    centres = [(c * reach, r * reach) for c in _BOARD_COLUMNS for r in _BOARD_ROWS]
    angles = [0.0, math.pi / 2, math.pi, -math.pi / 2]
    tags = {tag_id: (r6(x), r6(y), angles[k % 4]) for k, (tag_id, (x, y)) in enumerate(zip(CALIBRATION_BOARD_IDS, centres))}
    half_diagonal = textured_size(config.tag_size) / math.sqrt(2)
    (cam_x, cam_y, cam_z), focal = overhead_camera_pose(config)
    half_h = (CAMERA_RESOLUTION[1] / 2) * (cam_z - TAG_PLANE_Z) / focal
    half_w = (CAMERA_RESOLUTION[0] / 2) * (cam_z - TAG_PLANE_Z) / focal
    for tag_id, (x, y, _) in tags.items():
        if math.hypot(x, y) < reach + half_diagonal:
            raise ValueError(f"board tag {tag_id} at ({x:g}, {y:g}) m is within the arm's reach; use a smaller tag_size")
        if abs(x - cam_x) + half_diagonal > half_w or abs(y - cam_y) + half_diagonal > half_h:
            raise ValueError(f"board tag {tag_id} at ({x:g}, {y:g}) m leaves the overhead view; use a smaller tag_size")
    return TagBoard(config.tag_size, tags)


def add_scene(spec: mujoco.MjSpec, config: ArmModelConfig, board: bool) -> None:
    """Table, lights, overhead camera, render settings and optionally the calibration board.

    Lighting for detectable tags: a directional light straight down (diffuse 0.5) plus the
    headlight (ambient 0.25, diffuse 0.25), no specular light and no shadows, so an
    upward face of colour c is lit to c·1.0 everywhere in the view: tag white renders as
    255, tag black as 0, the table below saturation. No multisampling (offsamples 0): a
    tag's black-white edges lie inside its texture, not on polygon edges, so antialiasing
    does not change them (identical detections, measured) and costs 2-3× the render time
    on the CPU. The table is plain (untextured): a textured surface filling the view cost
    ≈ 40 % of a 1280×720 OSMesa frame (tools/bench_render.py: 20 → 12.5 ms, measured).
    """
    spec.visual.global_.offwidth = CAMERA_RESOLUTION[0]
    spec.visual.global_.offheight = CAMERA_RESOLUTION[1]
    spec.visual.quality.offsamples = 0
    spec.visual.headlight.diffuse = [0.25, 0.25, 0.25]
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.specular = [0.0, 0.0, 0.0]
    spec.worldbody.add_light(
        name="top", type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, pos=[0.12, 0.0, 1.5], dir=[0.0, 0.0, -1.0],
        diffuse=[0.5, 0.5, 0.5], specular=[0.0, 0.0, 0.0], castshadow=False,
    )
    spec.worldbody.add_geom(
        name="table", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0.0, 0.0, 0.05], rgba=list(_TABLE_COLOR),
        pos=[0.0, 0.0, -VISUAL_RADIUS], contype=0, conaffinity=0,
    )
    pos, _ = overhead_camera_pose(config)
    spec.worldbody.add_camera(
        name="overhead", pos=list(pos), fovy=CAMERA_FOVY_DEG, resolution=list(CAMERA_RESOLUTION)
    )
    if board:
        tags = calibration_board(config).tags
        spec.assets = {**spec.assets, **tag_textures(tags)}
        for tag_id, (x, y, angle) in tags.items():
            add_tag(spec, spec.worldbody, tag_id, x, y, angle, config.tag_size)
