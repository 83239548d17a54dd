"""AprilTag 36h11 detection in camera images: tag ids and sub-pixel corners.

Detection. `TagDetector.detect(image)` takes a grey (h, w) or BGR (h, w, 3) uint8
image and returns one `Detection` per decoded tag: its id and its four corners in
pixels (OpenCV's convention: x right, y down, pixel centres at integer coordinates) in
the order top-left, top-right, bottom-right, bottom-left *of the upright tag* (as
`perception.tags.tag_image` draws it), wherever the tag lies in the image. The centre
is the intersection of the diagonals, the image of the tag's centre under any
perspective.

Backends (chosen by measurement, see perception/README.md):
- "opencv" (default): `cv2.aruco.ArucoDetector` with the AprilTag 36h11 dictionary finds
  and decodes the tags (reading the bits from the middle of each cell, which decodes
  blurred tags more often); their corners are then refined by fitting a line to each of the
  four edges of the black square (`refine_corners`, below); no extra dependency.
- "pupil": the AprilTag 3 library through `pupil-apriltags` (not a dependency; install
  it with `pip install pupil-apriltags`), quad decimation 2 and its own edge refinement.
  Its corners come in the order top-right, top-left, bottom-left, bottom-right of the
  upright tag and with pixel centres at +0.5 (measured: a mean offset of
  (+0.50, +0.50) px on synthetic images); both are converted here.

Edge refinement (`refine_corners`). For each edge a → b of the detected quad, with unit
normal n pointing out of the tag, the image is sampled (bilinearly) along n at offsets
o ∈ [−3, 3] px in 0.25 px steps, at points spread over the middle 70 % of the edge (one
every 2 px, at least 8). Across the edge the image steps from the black border up to
the white quiet zone; the edge lies at the centroid of the positive part of the
profile's derivative, o* = Σ o·g⁺(o) / Σ g⁺(o) (unbiased for a symmetric blur that fits
in the window, and blind to the downward steps of the data cells inside and of the
background outside). A total-least-squares line through the points a + s(b − a) + o*·n
is fitted per edge, the corners are the intersections of consecutive lines, and the
whole is repeated once from the refined quad. If an edge has fewer than 4 usable
samples, two lines are parallel or a corner moves by more than 3 px, the tag keeps its
unrefined corners. Measured on synthetic 42 px tags: corner error 0.02 px rms sharp,
0.04 px at blur σ 1 px + noise σ 3 (OpenCV's own `CORNER_REFINE_SUBPIX`: 0.24 and
0.39 px).

Ids outside `tag_ids` (when given) are dropped. A tag id seen twice in one image is
returned twice; deciding which is real is the caller's job (the estimator and the
calibration ignore duplicated ids).
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from perception.tags import dictionary

BACKENDS = ("opencv", "pupil")
# bit sampling of ArUco's decoder (defaults 4 and 0.13): 8 px per cell, reading only each cell's
# middle 40 %, decodes 97 % instead of 87 % of 42 px tags at blur σ 2 px + noise σ 8 (measured)
ARUCO_PIXELS_PER_CELL = 8
ARUCO_IGNORED_MARGIN_PER_CELL = 0.3
EDGE_PROFILE_HALF_PX = 3.0  # samples across an edge reach this far on both sides, px
EDGE_PROFILE_STEP_PX = 0.25
EDGE_SAMPLE_SPACING_PX = 2.0  # along an edge
EDGE_SAMPLE_SPAN = (0.15, 0.85)  # fractions of the edge sampled (corners are rounded by blur)
EDGE_MIN_SAMPLES = 8
EDGE_ITERATIONS = 2
EDGE_MAX_SHIFT_PX = 3.0  # a refinement moving a corner further is rejected
# index in pupil-apriltags' corners of the upright tag's top-left, top-right, bottom-right, bottom-left
PUPIL_TO_UPRIGHT = (1, 0, 3, 2)
PUPIL_PIXEL_OFFSET = 0.5  # pupil-apriltags' pixel centres sit at integer + 0.5, px
PUPIL_QUAD_DECIMATE = 2.0  # as accurate as 1.0 on 40 px tags and ~4x faster (measured)
# pupil-apriltags 1.0.4 can crash (SIGSEGV in apriltag_detector_destroy) when a Detector is
# freed after use (pupil-labs/apriltags issue #46; measured: every time a second detector
# replaced a used one); one Detector per setting is kept for the life of the process.
_PUPIL_DETECTORS: dict[bool, Any] = {}


@dataclass(frozen=True, eq=False)
class Detection:
    """A decoded tag: id and corners (4, 2) px, top-left, top-right, bottom-right, bottom-left of the upright tag."""

    tag_id: int
    corners: np.ndarray

    def __post_init__(self) -> None:
        if isinstance(self.tag_id, bool) or not isinstance(self.tag_id, (int, np.integer)) or self.tag_id < 0:
            raise ValueError(f"tag_id must be an integer >= 0, got {self.tag_id!r}")
        corners = np.array(self.corners, dtype=float)
        if corners.shape != (4, 2):
            raise ValueError(f"corners must have shape (4, 2) px, got {corners.shape}")
        if not np.all(np.isfinite(corners)):
            raise ValueError(f"corners must be finite, got {corners.tolist()}")
        corners.setflags(write=False)
        object.__setattr__(self, "tag_id", int(self.tag_id))
        object.__setattr__(self, "corners", corners)

    @property
    def centre(self) -> np.ndarray:
        """Intersection (2,) px of the diagonals TL–BR and TR–BL (the image of the tag's centre)."""
        p0, p1, p2, p3 = self.corners
        d02, d13 = p2 - p0, p3 - p1
        denominator = d02[0] * d13[1] - d02[1] * d13[0]
        if denominator == 0:
            return self.corners.mean(axis=0)
        r = p1 - p0
        s = (r[0] * d13[1] - r[1] * d13[0]) / denominator
        return p0 + s * d02


def as_grey(image: Any) -> np.ndarray:
    """The image as a contiguous grey uint8 (h, w) array; BGR (h, w, 3) is converted."""
    array = np.asarray(image)
    if array.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got dtype {array.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    if array.ndim == 3 and array.shape[2] == 3:
        return cv2.cvtColor(array, cv2.COLOR_BGR2GRAY)
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if array.ndim != 2 or min(array.shape) < 8:
        raise ValueError(f"image must be grey (h, w) or BGR (h, w, 3) with h, w >= 8, got shape {array.shape}")
    return np.ascontiguousarray(array)


def refine_corners(image: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Corners (4, 2) px re-estimated from lines fitted to the quad's four edges (module docstring).

    `image` is the grey image as float32 (h, w) (converted once per frame by the caller).
    """
    original = np.asarray(corners, dtype=float)
    offsets = np.arange(-EDGE_PROFILE_HALF_PX, EDGE_PROFILE_HALF_PX + 1e-9, EDGE_PROFILE_STEP_PX)
    midpoints = (offsets[:-1] + offsets[1:]) / 2
    quad = original
    for _ in range(EDGE_ITERATIONS):
        centre = quad.mean(axis=0)
        lines = []
        for k in range(4):
            a, b = quad[k], quad[(k + 1) % 4]
            length = float(np.hypot(*(b - a)))
            if length < 1.0:
                return original
            n = np.array([b[1] - a[1], a[0] - b[0]]) / length
            if n @ ((a + b) / 2 - centre) < 0:
                n = -n  # point out of the tag: black border → white quiet zone
            fractions = np.linspace(*EDGE_SAMPLE_SPAN, max(EDGE_MIN_SAMPLES, int(length / EDGE_SAMPLE_SPACING_PX)))
            points = a + np.outer(fractions, b - a)
            grid = (points[:, None, :] + offsets[None, :, None] * n).astype(np.float32)
            profile = cv2.remap(image, grid[..., 0], grid[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            rise = np.clip(np.diff(profile.astype(float), axis=1), 0.0, None)
            weight = rise.sum(axis=1)
            usable = weight > 0
            if usable.sum() < 4:
                return original
            on_edge = points[usable] + ((rise[usable] @ midpoints) / weight[usable])[:, None] * n
            mean = on_edge.mean(axis=0)
            lines.append((mean, np.linalg.svd(on_edge - mean, full_matrices=False)[2][0]))
        refined = np.empty((4, 2))
        for k in range(4):  # corner k: where edge k − 1 (into it) meets edge k (out of it)
            (p1, d1), (p2, d2) = lines[k - 1], lines[k]
            system = np.column_stack([d1, -d2])
            if abs(np.linalg.det(system)) < 1e-6:
                return original
            refined[k] = p1 + np.linalg.solve(system, p2 - p1)[0] * d1
        quad = refined
    if np.abs(quad - original).max() > EDGE_MAX_SHIFT_PX:
        return original
    return quad


class TagDetector:
    """AprilTag 36h11 detector; `backend` "opencv" (default) or "pupil", `tag_ids` the ids to keep (None: all).

    `subpixel` False skips the corner refinement (opencv: `refine_corners`; pupil: its edge refinement).
    """

    def __init__(self, backend: str = "opencv", tag_ids: Iterable[int] | None = None, *, subpixel: bool = True) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        self.backend = backend
        self.tag_ids = None if tag_ids is None else frozenset(int(i) for i in tag_ids)
        self.subpixel = subpixel
        if backend == "opencv":
            parameters = cv2.aruco.DetectorParameters()
            parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # refine_corners does better
            parameters.perspectiveRemovePixelPerCell = ARUCO_PIXELS_PER_CELL
            parameters.perspectiveRemoveIgnoredMarginPerCell = ARUCO_IGNORED_MARGIN_PER_CELL
            self._opencv = cv2.aruco.ArucoDetector(dictionary(), parameters)
        else:
            try:
                pupil_apriltags = importlib.import_module("pupil_apriltags")
            except ImportError as error:
                raise ImportError(
                    'backend "pupil" needs the optional package pupil-apriltags: pip install pupil-apriltags '
                    '(or use backend="opencv", the default)'
                ) from error
            if subpixel not in _PUPIL_DETECTORS:
                _PUPIL_DETECTORS[subpixel] = pupil_apriltags.Detector(
                    families="tag36h11", nthreads=1, quad_decimate=PUPIL_QUAD_DECIMATE, refine_edges=int(subpixel)
                )
            self._pupil = _PUPIL_DETECTORS[subpixel]

    def detect(self, image: Any) -> list[Detection]:
        """Every decoded tag in `image` (grey or BGR uint8) whose id is expected, sorted by id."""
        grey = as_grey(image)
        if self.backend == "opencv":
            corners, ids, _ = self._opencv.detectMarkers(grey)
            found = [] if ids is None else [(int(i), c.reshape(4, 2).astype(float)) for i, c in zip(ids.ravel(), corners)]
            if self.subpixel and found:
                image = grey.astype(np.float32)
                found = [(i, refine_corners(image, c)) for i, c in found]
        else:
            found = [
                (int(r.tag_id), np.asarray(r.corners)[list(PUPIL_TO_UPRIGHT)] - PUPIL_PIXEL_OFFSET)
                for r in self._pupil.detect(grey)
            ]
        detections = [Detection(i, c) for i, c in found if self.tag_ids is None or i in self.tag_ids]
        return sorted(detections, key=lambda d: d.tag_id)
