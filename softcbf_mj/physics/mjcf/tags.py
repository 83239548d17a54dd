"""The AprilTags of the generated model (docs/ground-truth.md, as on the hardware): textures, placements, geoms.

Tag 0 (`perception.tags`) lies on `base`, centred on the base point; tag i on the body that carries
`seg{i}_end`, centred on that site, except the tip tag, which is shifted back along its link by half
its textured edge so that its front edge is the tip point r and it never overhangs the plate. Each is
a flat box geom `tag{id}` (textured edge S = `textured_size(tag_size)`, m; 1 mm thick) whose top face
lies in the plane z = `TAG_PLANE_Z` above every other geom (plates reach z =
`softcbf_mj.physics.mjcf.plates.PLATE_HALF_HEIGHT`), so nothing occludes a tag from the overhead camera; its
image x axis runs along the body's x axis, its image up along +y. Tags are visual only (contype =
conaffinity = 0, density 0: no mass; the arm's bodies carry explicit inertials), textured with the
36h11 images of `perception.tags.tag_image` (PNG files `assets/tag{id}.png`; in-memory specs carry
the same bytes in `spec.assets`), with a matte material (no specular highlight). The calibration
scene adds a board of tags in the same plane (`softcbf_mj.physics.mjcf.scene.calibration_board`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import mujoco

from perception.tags import arm_tag_ids, tag_image, textured_size
from softcbf_mj.physics.mjcf.config import ArmModelConfig
from softcbf_mj.physics.mjcf.precision import r6, r6v

ASSETS_DIR = "assets"
TAG_PLANE_Z = 0.025  # m, top faces of all tags: above the plates (z <= PLATE_HALF_HEIGHT) and the arm
TAG_HALF_THICKNESS = 0.0005  # m
TAG_TEXTURE_CELL_PX = 16  # texture px per tag cell: 160 × 160 px textures (8 cells + 1 quiet cell each side)


def tag_texture_file(tag_id: int) -> str:
    """Path of tag `tag_id`'s texture relative to the model folder (MJCF `file` attribute)."""
    return f"{ASSETS_DIR}/tag{tag_id}.png"


def tag_textures(tag_ids: Any) -> dict[str, bytes]:
    """PNG bytes of the 36h11 textures of `tag_ids`, keyed by `tag_texture_file` (same ids, same bytes)."""
    textures = {}
    for tag_id in tag_ids:
        ok, png = cv2.imencode(".png", tag_image(int(tag_id), TAG_TEXTURE_CELL_PX))
        if not ok:
            raise RuntimeError(f"OpenCV could not encode tag {tag_id} as PNG")
        textures[tag_texture_file(int(tag_id))] = png.tobytes()
    return textures


@dataclass(frozen=True)
class TagPlacement:
    """Where an arm tag sits: its centre is site `site` + `offset` (m) along the body's x axis."""

    tag_id: int
    body: str
    site: str
    offset: float


def arm_tag_placements(config: ArmModelConfig) -> tuple[TagPlacement, ...]:
    """Tag 0 on `base` at the base point; tag i on the body of `seg{i}_end`, the tip tag shifted back by S/2."""
    n, n_seg = config.links_per_segment, config.robot.n_segments
    ids = arm_tag_ids(n_seg)
    placements = [TagPlacement(ids[0], "base", "base", 0.0)]
    for i in range(1, n_seg + 1):
        offset = -textured_size(config.tag_size) / 2 if i == n_seg else 0.0
        placements.append(TagPlacement(ids[i], f"seg{i}_link{n}", f"seg{i}_end", r6(offset)))
    return tuple(placements)


def add_tag(spec: mujoco.MjSpec, body: mujoco.MjsBody, tag_id: int, x: float, y: float, angle: float, tag_size: float) -> None:
    """Texture, matte material and flat visual box `tag{id}` centred at (x, y) of `body`, top face at TAG_PLANE_Z."""
    name = f"tag{tag_id}"
    spec.add_texture(name=name, type=mujoco.mjtTexture.mjTEXTURE_2D, file=tag_texture_file(tag_id))
    spec.add_material(name=name, textures=["", name], specular=0.0, shininess=0.0, reflectance=0.0)
    half = textured_size(tag_size) / 2
    body.add_geom(
        name=name, type=mujoco.mjtGeom.mjGEOM_BOX, material=name, contype=0, conaffinity=0, group=2, density=0.0,
        pos=r6v([x, y, TAG_PLANE_Z - TAG_HALF_THICKNESS]),
        quat=[r6(v) if abs(v) > 1e-12 else 0.0 for v in (math.cos(angle / 2), 0.0, 0.0, math.sin(angle / 2))],
        size=r6v([half, half, TAG_HALF_THICKNESS]),
    )
