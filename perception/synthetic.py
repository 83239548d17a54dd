"""Synthetic camera images of AprilTags lying on a plane, with exact ground truth.

Used by the perception tests, `tools/bench_perception.py` and the detector backend
comparison; never by the estimator itself.

Geometry. A tag of black-square size s (m) with plane pose (x, y, θ) has its texture
(black square plus quiet zone, edge S = textured_size(s), see `perception.tags`) centred
at (x, y), its image x axis along (cos θ, sin θ) and its image "up" along
(−sin θ, cos θ). The camera is a homography `H_img_from_plane` (3 × 3) taking plane
points (m) to image pixels in OpenCV's pixel convention (pixel centres at integer
coordinates, x right, y down). The exact image corners of a tag are its plane corners,
`perception.plane.tag_corners_on_plane`, mapped through that homography.

Camera. `overhead_calibration()` is the testbed's default overhead camera as an exact
image-to-plane map: 1280 × 720 px, vertical field of view 45° (square pixels, principal
point at the image centre), at (0.122, 0, 0.65) m looking down −z with image right = +x
and image up = +y, onto the tags' plane z = 0.025 m (≈ 1390 px/m: a 30 mm tag spans
≈ 42 px).

Rendering. Each tag is warped into its image bounding box at `supersample` × the
resolution with bilinear interpolation and averaged down (cv2.INTER_AREA), so edges are
antialiased like a real lens's; a mask warped the same way composites it onto a uniform
background. Then optional Gaussian blur (σ in px) and additive Gaussian noise (σ in grey
levels), clipped to uint8.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import cv2
import numpy as np

from perception.plane import PlaneCalibration, fovy_intrinsics
from perception.tags import tag_image, textured_size

TAG_CELL_PX = 16  # texture resolution of a tag cell before warping
IMAGE_SIZE = (1280, 720)  # width, height px
FOVY_DEG = 45.0
CAMERA_POS = (0.122, 0.0, 0.65)  # m
PLANE_Z = 0.025  # m
R_DOWN = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])  # x right = +x, y down = −y, forward = −z


def pinhole_intrinsics(image_size: tuple[int, int] = IMAGE_SIZE, fovy_deg: float = FOVY_DEG) -> np.ndarray:
    """K (3 × 3) of the default overhead camera (`perception.plane.fovy_intrinsics`)."""
    return fovy_intrinsics(*image_size, fovy_deg)


def overhead_calibration(
    image_size: tuple[int, int] = IMAGE_SIZE,
    fovy_deg: float = FOVY_DEG,
    camera_pos: tuple[float, float, float] = CAMERA_POS,
    plane_z: float = PLANE_Z,
) -> PlaneCalibration:
    """The exact image-to-plane map of a camera looking straight down −z (image right = +x, up = +y)."""
    return PlaneCalibration.from_pinhole(pinhole_intrinsics(image_size, fovy_deg), R_DOWN, camera_pos, plane_z)


def arm_tag_poses(q: np.ndarray, theta0: float = 0.0, chord: float = 0.11) -> dict[int, tuple[float, float, float]]:
    """Plane poses {id: (x m, y m, θ rad)} of the tags of an arm bent by q (N,) rad, base tag 0 at the origin.

    Tag i sits `chord` m from tag i − 1 along the chord of a constant-curvature segment,
    direction θ_{i−1} + q_i/2, with θ_i = θ_{i−1} + q_i (θ_0 = theta0).
    """
    tags = {0: (0.0, 0.0, float(theta0))}
    x, y, theta = 0.0, 0.0, float(theta0)
    for i, qi in enumerate(np.asarray(q, dtype=float), start=1):
        x += chord * math.cos(theta + qi / 2)
        y += chord * math.sin(theta + qi / 2)
        theta += qi
        tags[i] = (x, y, theta)
    return tags


def tag_texture_to_plane(x: float, y: float, angle: float, tag_size: float, texture_px: int) -> np.ndarray:
    """3 × 3 map from texture pixel coordinates (centres at integers, y down) to plane metres."""
    edge = textured_size(tag_size)
    scale = edge / texture_px
    # texture pixel u (centre) → tag frame x_t = (u + 0.5)·scale − edge/2, y_t = edge/2 − (v + 0.5)·scale
    to_tag = np.array(
        [[scale, 0.0, 0.5 * scale - edge / 2], [0.0, -scale, edge / 2 - 0.5 * scale], [0.0, 0.0, 1.0]]
    )
    c, s = math.cos(angle), math.sin(angle)
    to_plane = np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])
    return to_plane @ to_tag


def render_tags(
    H_img_from_plane: np.ndarray,
    tags: Mapping[int, tuple[float, float, float]],
    tag_size: float,
    image_size: tuple[int, int] = IMAGE_SIZE,
    *,
    background: int = 128,
    blur_sigma_px: float = 0.0,
    noise_sigma: float = 0.0,
    supersample: int = 4,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Grey uint8 image (height, width) of `tags` {id: (x m, y m, θ rad)} seen through the homography."""
    H = np.asarray(H_img_from_plane, dtype=float)
    if H.shape != (3, 3) or not np.all(np.isfinite(H)):
        raise ValueError(f"H_img_from_plane must be a finite 3x3 array, got shape {H.shape}")
    width, height = image_size
    if width < 1 or height < 1:
        raise ValueError(f"image_size must be (width, height) >= 1 px, got {image_size}")
    if supersample < 1:
        raise ValueError(f"supersample must be >= 1, got {supersample}")
    if blur_sigma_px < 0 or noise_sigma < 0:
        raise ValueError(f"blur_sigma_px and noise_sigma must be >= 0, got {blur_sigma_px}, {noise_sigma}")
    canvas = np.full((height, width), float(background))
    for tag_id, (x, y, angle) in tags.items():
        texture = tag_image(tag_id, TAG_CELL_PX).astype(float)
        texture_px = texture.shape[0]
        tex_to_img = H @ tag_texture_to_plane(x, y, angle, tag_size, texture_px)
        edges = np.array([[-0.5, -0.5], [texture_px - 0.5, -0.5], [texture_px - 0.5, texture_px - 0.5], [-0.5, texture_px - 0.5]])
        box = cv2.perspectiveTransform(edges.reshape(-1, 1, 2), tex_to_img).reshape(-1, 2)
        x0 = max(int(math.floor(box[:, 0].min())) - 1, 0)
        y0 = max(int(math.floor(box[:, 1].min())) - 1, 0)
        x1 = min(int(math.ceil(box[:, 0].max())) + 2, width)
        y1 = min(int(math.ceil(box[:, 1].max())) + 2, height)
        if x1 <= x0 or y1 <= y0:
            continue
        # low-res ROI coordinate p ↦ high-res (p − origin + 0.5)·k − 0.5 (pixel centres at integers)
        k = supersample
        to_high = np.array([[k, 0.0, (0.5 - x0) * k - 0.5], [0.0, k, (0.5 - y0) * k - 0.5], [0.0, 0.0, 1.0]])
        size_high = ((x1 - x0) * k, (y1 - y0) * k)
        warped = cv2.warpPerspective(texture, to_high @ tex_to_img, size_high, flags=cv2.INTER_LINEAR)
        mask = cv2.warpPerspective(np.ones_like(texture), to_high @ tex_to_img, size_high, flags=cv2.INTER_LINEAR)
        roi = (x1 - x0, y1 - y0)
        warped = cv2.resize(warped, roi, interpolation=cv2.INTER_AREA)
        mask = cv2.resize(mask, roi, interpolation=cv2.INTER_AREA)
        view = canvas[y0:y1, x0:x1]
        view[:] = view * (1.0 - mask) + warped
    if blur_sigma_px > 0:
        canvas = cv2.GaussianBlur(canvas, (0, 0), blur_sigma_px)
    if noise_sigma > 0:
        generator = rng if rng is not None else np.random.default_rng(0)
        canvas = canvas + generator.normal(0.0, noise_sigma, canvas.shape)
    return np.clip(np.rint(canvas), 0, 255).astype(np.uint8)
