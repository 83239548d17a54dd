"""The image-to-plane map: a homography from image pixels to the tags' plane, and tag boards.

Conventions. Image points are pixels in OpenCV's convention (x right, y down, pixel
centres at integer coordinates). Plane points are metres in the plane the tags lie in
(the table plane z = plane_z of the world frame, with its x, y axes; docs/model.md#frames-units-conventions). Tags are
flat, so one homography H (3 × 3, normalised to H[2, 2] = 1) maps every image point of
that plane to its plane point:

    [X, Y, W]ᵀ = H · [u, v, 1]ᵀ,   (x, y) = (X / W, Y / W)   [m]

Lens distortion is not modelled: undistort images first if the lens needs it.

From a pinhole camera. With intrinsics K (3 × 3, px), the camera's orientation
R_world_from_cam (3 × 3; its columns are the camera's x right, y down, z forward axes —
the OpenCV camera convention — in world coordinates) and position c (m), a plane point
p = (x, y, plane_z) projects to s·[u, v, 1]ᵀ = K Rᵀ (p − c) = K Rᵀ [e_x  e_y  (plane_z e_z − c)]·[x, y, 1]ᵀ,
so H = (K Rᵀ [e_x  e_y  plane_z e_z − c])⁻¹. The camera's optical axis must hit the
plane in front of the camera.

From a tag board. A `TagBoard` lists tags lying on the plane (black-square size s in m,
and each tag's pose (x, y, θ): centre and angle of its image x axis). A tag's corners,
in the order top-left, top-right, bottom-right, bottom-left of the upright tag (the order
of `Detection.corners`), lie at the centre + R(θ)·(±s/2, ±s/2):

    TL = (−s/2, +s/2), TR = (+s/2, +s/2), BR = (+s/2, −s/2), BL = (−s/2, −s/2)

since the tag's image "up" is the body's +y (`perception.tags`). `calibrate` fits H to
the detected corners of the board's tags by least squares in the plane (OpenCV's
normalised DLT followed by Levenberg–Marquardt, `cv2.findHomography` with method 0).

Tag pose from corners. The plane angle of a tag is θ = atan2 of the sum of its two
x edges (TR − TL) + (BR − BL) mapped to the plane; its centre is the mean of its four
plane corners; its size the mean of its four plane edge lengths.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from perception.detect import Detection

FORMAT_VERSION = 1


def fovy_intrinsics(width: int, height: int, fovy_deg: float) -> np.ndarray:
    """K (3 × 3, px) of a distortion-free camera with square pixels, vertical field of view
    `fovy_deg` and its principal point at the image centre (OpenCV pixel convention: pixel
    centres at integers), rendering `width` × `height` px: f = (H/2) / tan(fovy/2)."""
    f = (height / 2) / math.tan(math.radians(fovy_deg) / 2)
    return np.array([[f, 0.0, (width - 1) / 2], [0.0, f, (height - 1) / 2], [0.0, 0.0, 1.0]])


def _finite_points(points: Any, name: str) -> np.ndarray:
    array = np.asarray(points, dtype=float)
    if array.ndim == 1 and array.shape == (2,):
        array = array.reshape(1, 2)
    if array.ndim != 2 or array.shape[1] != 2:
        raise ValueError(f"{name} must have shape (n, 2) or (2,), got {np.shape(points)}")
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} must be finite, got non-finite values at rows {np.nonzero(~np.isfinite(array).all(axis=1))[0].tolist()}")
    return array


def _apply(H: np.ndarray, points: np.ndarray) -> np.ndarray:
    homogeneous = points @ H[:, :2].T + H[:, 2]
    return homogeneous[:, :2] / homogeneous[:, 2:3]


def tag_corners_on_plane(x: float, y: float, angle: float, tag_size: float) -> np.ndarray:
    """Plane corners (4, 2) m of a tag's black square: top-left, top-right, bottom-right, bottom-left."""
    if not tag_size > 0:
        raise ValueError(f"tag_size must be > 0 m, got {tag_size}")
    half = tag_size / 2.0
    local = np.array([[-half, half], [half, half], [half, -half], [-half, -half]])
    c, s = math.cos(angle), math.sin(angle)
    return local @ np.array([[c, s], [-s, c]]) + np.array([x, y])


@dataclass(frozen=True)
class TagPose:
    """A tag's pose on the plane: centre (x, y) m, angle θ rad of its x axis, black-square size m."""

    x: float
    y: float
    angle: float
    size: float


def tag_pose_on_plane(corners_plane: np.ndarray) -> TagPose:
    """Pose of a tag from its four plane corners (4, 2) m in the `Detection` order."""
    corners = np.asarray(corners_plane, dtype=float)
    if corners.shape != (4, 2):
        raise ValueError(f"corners_plane must have shape (4, 2), got {corners.shape}")
    x_axis = (corners[1] - corners[0]) + (corners[2] - corners[3])
    edges = np.hypot(*(corners[[1, 2, 3, 0]] - corners).T)
    centre = corners.sum(axis=0) / 4
    return TagPose(float(centre[0]), float(centre[1]), math.atan2(x_axis[1], x_axis[0]), float(edges.sum() / 4))


@dataclass(frozen=True)
class ReprojectionError:
    """Residuals of a calibration over n point pairs: in the plane (m) and in the image (px)."""

    rms_m: float
    max_m: float
    rms_px: float
    max_px: float
    n_points: int


@dataclass(frozen=True, eq=False)
class PlaneCalibration:
    """Homography `H` (3 × 3) from image pixels to plane metres, normalised to H[2, 2] = 1."""

    H: np.ndarray

    def __post_init__(self) -> None:
        H = np.array(self.H, dtype=float)
        if H.shape != (3, 3):
            raise ValueError(f"H must be a 3x3 homography (image px -> plane m), got shape {H.shape}")
        if not np.all(np.isfinite(H)):
            raise ValueError(f"H must be finite, got {H.tolist()}")
        scale = np.linalg.norm(H)
        if abs(H[2, 2]) < 1e-12 * scale:
            raise ValueError(f"H[2, 2] must be non-zero (the image origin must map to a finite plane point), got H = {H.tolist()}")
        H = H / H[2, 2]
        if abs(np.linalg.det(H)) < 1e-15 * np.linalg.norm(H) ** 3:
            raise ValueError(f"H must be invertible, got a singular matrix {H.tolist()}; fit it from non-collinear points")
        H.setflags(write=False)
        object.__setattr__(self, "H", H)

    def map_points(self, points_px: Any) -> np.ndarray:
        """Plane points (n, 2) m of image points (n, 2) or (2,) px."""
        return _apply(self.H, _finite_points(points_px, "points_px"))

    def map_to_image(self, points_m: Any) -> np.ndarray:
        """Image points (n, 2) px of plane points (n, 2) or (2,) m."""
        return _apply(np.linalg.inv(self.H), _finite_points(points_m, "points_m"))

    def reprojection_error(self, image_points: Any, plane_points: Any) -> ReprojectionError:
        """Residuals of the pairs: |H(image) − plane| in m and |H⁻¹(plane) − image| in px."""
        image = _finite_points(image_points, "image_points")
        plane = _finite_points(plane_points, "plane_points")
        if image.shape != plane.shape:
            raise ValueError(f"image_points and plane_points must pair up, got shapes {image.shape} and {plane.shape}")
        in_plane = np.linalg.norm(self.map_points(image) - plane, axis=1)
        in_image = np.linalg.norm(self.map_to_image(plane) - image, axis=1)
        return ReprojectionError(
            rms_m=float(np.sqrt(np.mean(in_plane**2))),
            max_m=float(in_plane.max()),
            rms_px=float(np.sqrt(np.mean(in_image**2))),
            max_px=float(in_image.max()),
            n_points=len(image),
        )

    @classmethod
    def fit(cls, image_points: Any, plane_points: Any) -> PlaneCalibration:
        """Least-squares homography from n ≥ 4 point pairs (image px, plane m) that are not all collinear."""
        image = _finite_points(image_points, "image_points")
        plane = _finite_points(plane_points, "plane_points")
        if image.shape != plane.shape:
            raise ValueError(f"image_points and plane_points must pair up, got shapes {image.shape} and {plane.shape}")
        if len(image) < 4:
            raise ValueError(f"a homography needs at least 4 point pairs, got {len(image)}")
        for name, points in (("image_points", image), ("plane_points", plane)):
            spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
            if not spread[1] > 1e-9 * spread[0]:
                raise ValueError(f"{name} are collinear or repeated: no homography fits them; use points spread over the plane")
        H, _ = cv2.findHomography(image, plane, 0)
        if H is None:
            raise ValueError(f"cv2.findHomography found no homography for these {len(image)} point pairs; check that they pair up")
        return cls(H)

    @classmethod
    def from_pinhole(
        cls, K: Any, R_world_from_cam: Any, cam_pos_world: Any, plane_z: float
    ) -> PlaneCalibration:
        """The exact map of a pinhole camera (OpenCV axes: x right, y down, z forward) onto the plane z = plane_z."""
        K = np.asarray(K, dtype=float)
        R = np.asarray(R_world_from_cam, dtype=float)
        c = np.asarray(cam_pos_world, dtype=float)
        if K.shape != (3, 3) or not np.all(np.isfinite(K)):
            raise ValueError(f"K must be a finite 3x3 intrinsic matrix, got {K.tolist()}")
        if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose([K[1, 0], *K[2]], [0.0, 0.0, 0.0, 1.0])):
            raise ValueError(f"K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, got {K.tolist()}")
        if R.shape != (3, 3) or not np.all(np.isfinite(R)):
            raise ValueError(f"R_world_from_cam must be a finite 3x3 rotation, got {R.tolist()}")
        if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError(
                f"R_world_from_cam must be a proper rotation (orthonormal, det +1), got {R.tolist()}; "
                "a MuJoCo camera's axes (x right, y up, z backward) become OpenCV's by negating its y and z columns"
            )
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ValueError(f"cam_pos_world must be a finite 3-vector (m), got {c.tolist()}")
        if not math.isfinite(plane_z):
            raise ValueError(f"plane_z must be finite (m), got {plane_z}")
        depth = (plane_z - c[2]) / R[2, 2] if R[2, 2] != 0 else math.inf
        if not 0 < depth < math.inf:
            raise ValueError(
                f"the camera's optical axis {R[:, 2].tolist()} from {c.tolist()} does not hit the plane z = {plane_z} in front of it"
            )
        plane_to_cam = np.column_stack([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], np.array([0.0, 0.0, plane_z]) - c])
        return cls(np.linalg.inv(K @ R.T @ plane_to_cam))

    def to_dict(self) -> dict[str, Any]:
        return {"format_version": FORMAT_VERSION, "H_plane_m_from_image_px": self.H.tolist()}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PlaneCalibration:
        if data.get("format_version") != FORMAT_VERSION or "H_plane_m_from_image_px" not in data:
            raise ValueError(
                f"a plane calibration needs format_version {FORMAT_VERSION} and H_plane_m_from_image_px, got keys {sorted(data)}"
            )
        return cls(np.asarray(data["H_plane_m_from_image_px"], dtype=float))

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> PlaneCalibration:
        return cls.from_dict(json.loads(Path(path).read_text(encoding="utf-8")))


@dataclass(frozen=True)
class TagBoard:
    """Tags lying on the plane: black-square size `tag_size` m and poses {id: (x m, y m, θ rad)}."""

    tag_size: float
    tags: Mapping[int, tuple[float, float, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.tag_size) and self.tag_size > 0):
            raise ValueError(f"tag_size must be a finite size > 0 m, got {self.tag_size}")
        if not self.tags:
            raise ValueError("a TagBoard needs at least one tag, got none")
        poses: dict[int, tuple[float, float, float]] = {}
        for tag_id, pose in self.tags.items():
            if isinstance(tag_id, bool) or not isinstance(tag_id, (int, np.integer)) or tag_id < 0:
                raise ValueError(f"tag ids must be integers >= 0, got {tag_id!r}")
            try:
                values = tuple(float(v) for v in pose)
            except (TypeError, ValueError):
                values = ()
            if len(values) != 3 or not all(math.isfinite(v) for v in values):
                raise ValueError(f"tag {tag_id}'s pose must be finite (x m, y m, angle rad), got {pose!r}")
            poses[int(tag_id)] = values
        object.__setattr__(self, "tags", poses)

    def corners(self, tag_id: int) -> np.ndarray:
        """Plane corners (4, 2) m of tag `tag_id`, in the `Detection` order."""
        if tag_id not in self.tags:
            raise KeyError(f"tag {tag_id} is not on this board; its tags are {sorted(self.tags)}")
        return tag_corners_on_plane(*self.tags[tag_id], self.tag_size)

    def to_dict(self) -> dict[str, Any]:
        return {
            "tag_size_m": self.tag_size,
            "tags": [{"id": i, "x_m": x, "y_m": y, "angle_rad": a} for i, (x, y, a) in sorted(self.tags.items())],
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TagBoard:
        try:
            return cls(
                float(data["tag_size_m"]),
                {int(t["id"]): (t["x_m"], t["y_m"], t["angle_rad"]) for t in data["tags"]},
            )
        except (KeyError, TypeError) as error:
            raise ValueError(
                'a tag board is {"tag_size_m": s, "tags": [{"id": i, "x_m": x, "y_m": y, "angle_rad": a}, ...]}, '
                f"got {json.dumps(data)[:200]} ({error!r})"
            ) from error

    def save(self, path: str | Path) -> None:
        Path(path).write_text(json.dumps(self.to_dict(), indent=2) + "\n", encoding="utf-8")

    @classmethod
    def load(cls, path: str | Path) -> TagBoard:
        return cls.from_dict(json.loads(Path(path).read_text(encoding="utf-8")))


def board_correspondences(detections: Iterable[Detection], board: TagBoard) -> tuple[np.ndarray, np.ndarray, tuple[int, ...]]:
    """Image corners (4m, 2) px, plane corners (4m, 2) m and ids of the m board tags detected exactly once."""
    detections = list(detections)
    counts: dict[int, int] = {}
    for detection in detections:
        counts[detection.tag_id] = counts.get(detection.tag_id, 0) + 1
    used = [d for d in detections if d.tag_id in board.tags and counts[d.tag_id] == 1]
    used.sort(key=lambda d: d.tag_id)
    if not used:
        return np.empty((0, 2)), np.empty((0, 2)), ()
    image = np.concatenate([d.corners for d in used])
    plane = np.concatenate([board.corners(d.tag_id) for d in used])
    return image, plane, tuple(d.tag_id for d in used)


def calibrate(detections: Iterable[Detection], board: TagBoard, min_tags: int = 2) -> PlaneCalibration:
    """Fit the image-to-plane map to the corners of the board's tags detected exactly once (at least `min_tags`)."""
    if min_tags < 1:
        raise ValueError(f"min_tags must be >= 1, got {min_tags}")
    image, plane, ids = board_correspondences(detections, board)
    if len(ids) < min_tags:
        raise ValueError(
            f"calibration needs at least {min_tags} board tags detected exactly once, got {len(ids)} ({list(ids)}) "
            f"of the board's {sorted(board.tags)}; check the image shows the board and the tag ids"
        )
    return PlaneCalibration.fit(image, plane)
