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

ArUco's adaptive threshold. ArUco thresholds the image once per window size w in
`ARUCO_THRESHOLD_WINDOWS_PX` (min, max, step; its default 3, 13, 23 px) and traces the
contours of each; that is most of its time. One 13 px window (2.5 cells of a 42 px tag)
finds every arm tag on sharp, blurred (σ 1 px, noise 3) and poor (σ 2 px, noise 8)
42 px frames and on MuJoCo renders at 1280 × 720 and 640 × 360 (21 px tags), at 0.3–0.6×
the time of the default three; it loses 1.7 % of the dense scene's tags at σ 2 px +
noise 8 (96.2 vs 97.9 %) and, on 21 px tags at σ 1 px + noise 3, 12 points (75 vs 87.5 %)
(measured, perception/README.md); `TagDetector(threshold_windows_px=(3, 23, 10))` restores
ArUco's default for small, blurred tags.

Windows (`detect_window`). The detector can decode a window image[y0:y1, x0:x1] and
report corners in full-image px. A tag whose corners keep g(s) = s·Q/8 + w_max + 4 px
(s: its side px, Q/8 its quiet zone, w_max the largest threshold window;
`window_guard_px`) from every window edge that is not an edge of the image gets exactly
the corners and id `detect(image)` gives it: every pixel whose threshold, contour or
decoding involves the tag lies inside the window, the window keeps the image's
contour-perimeter limits in px (ArUco's are rates of the image size), and
`refine_corners` samples the same pixels at the same float32 positions (`origin`).
Measured on synthetic frames: identical (0 px) with 18 px between a tag's quad and the
window edge, w_max = 13; nearer, tags are missed, the 4 px are slack. pupil-apriltags
(threshold reach 32 px at decimation 2) does not decode windows bit-for-bit: its corners
differ by up to 0.15 px (measured) from its full-frame ones.

Ids outside `tag_ids` (when given) are dropped. A tag id seen twice in one image is
returned twice; deciding which is real is the caller's job (the estimator and the
calibration ignore duplicated ids).
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from perception.tags import QUIET_CELLS, TAG_CELLS, dictionary

BACKENDS = ("opencv", "pupil")
# bit sampling of ArUco's decoder (defaults 4 and 0.13): 8 px per cell, reading only each cell's
# middle 40 %, decodes 97 % instead of 87 % of 42 px tags at blur σ 2 px + noise σ 8 (measured)
ARUCO_PIXELS_PER_CELL = 8
ARUCO_IGNORED_MARGIN_PER_CELL = 0.3
ARUCO_THRESHOLD_WINDOWS_PX = (13, 13, 10)  # adaptive threshold window sizes px: min, max, step (module docstring)
ARUCO_MIN_PERIMETER_RATE = 0.03  # ArUco's defaults: contour perimeters kept, × max(image width, height)
ARUCO_MAX_PERIMETER_RATE = 4.0
PUPIL_THRESHOLD_REACH_PX = 32  # AprilTag's threshold: 4 px tiles × 3 × 3 neighbours at decimation 2 = 24 px, + 8
WINDOW_GUARD_EXTRA_PX = 4  # beyond quiet zone + threshold reach (measured, module docstring)
EDGE_PROFILE_HALF_PX = 3.0  # samples across an edge reach this far on both sides, px
EDGE_PROFILE_STEP_PX = 0.25
EDGE_SAMPLE_SPACING_PX = 2.0  # along an edge
EDGE_SAMPLE_SPAN = (0.15, 0.85)  # fractions of the edge sampled (corners are rounded by blur)
EDGE_MIN_SAMPLES = 8
EDGE_ITERATIONS = 2
EDGE_MAX_SHIFT_PX = 3.0  # a refinement moving a corner further is rejected
_PROFILE_OFFSETS = np.arange(-EDGE_PROFILE_HALF_PX, EDGE_PROFILE_HALF_PX + 1e-9, EDGE_PROFILE_STEP_PX)
_PROFILE_MIDPOINTS = (_PROFILE_OFFSETS[:-1] + _PROFILE_OFFSETS[1:]) / 2
# index in pupil-apriltags' corners of the upright tag's top-left, top-right, bottom-right, bottom-left
PUPIL_TO_UPRIGHT = (1, 0, 3, 2)
PUPIL_PIXEL_OFFSET = 0.5  # pupil-apriltags' pixel centres sit at integer + 0.5, px
PUPIL_QUAD_DECIMATE = 2.0  # as accurate as 1.0 on 40 px tags and ~4x faster (measured)
# pupil-apriltags 1.0.4 can crash (SIGSEGV in apriltag_detector_destroy) when a Detector is
# freed after use (github.com/pupil-labs/apriltags/issues/46; measured: every time a second detector
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


def checked_image(image: Any) -> np.ndarray:
    """The image as an array, grey (h, w) or BGR (h, w, 3) uint8 with h, w >= 8 ((h, w, 1) becomes (h, w)); else ValueError."""
    array = np.asarray(image)
    if array.dtype != np.uint8:
        raise ValueError(f"image must be uint8, got dtype {array.dtype}; convert with np.clip(x, 0, 255).astype(np.uint8)")
    if array.ndim == 3 and array.shape[2] == 1:
        array = array[:, :, 0]
    if not (array.ndim == 2 or (array.ndim == 3 and array.shape[2] == 3)) or min(array.shape[:2]) < 8:
        raise ValueError(f"image must be grey (h, w) or BGR (h, w, 3) with h, w >= 8, got shape {array.shape}")
    return array


def as_grey(image: Any) -> np.ndarray:
    """The image as a contiguous grey uint8 (h, w) array; BGR (h, w, 3) is converted."""
    array = checked_image(image)
    if array.ndim == 3:
        return cv2.cvtColor(array, cv2.COLOR_BGR2GRAY)
    return np.ascontiguousarray(array)


def refine_corners(image: np.ndarray, corners: np.ndarray, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Corners (4, 2) px re-estimated from lines fitted to the quad's four edges (module docstring).

    `image` is the grey image as float32 (h, w) (converted once per frame by the caller), or
    a window of it whose pixel [0, 0] is the full image's pixel `origin` = (x0, y0)
    (integers); `corners` and the result are in full-image px either way. The sample
    positions are computed in full-image px, rounded to float32 and then shifted by the
    origin, a subtraction float32 does exactly, so a window that holds every sample gives
    bit-for-bit the full image's result.
    """
    original = np.asarray(corners, dtype=float)
    shift = np.array(origin, dtype=np.float32)
    if shift.shape != (2,) or not np.array_equal(shift, np.round(shift)):
        raise ValueError(f"origin must be two integers (x0, y0) px, got {origin!r}")
    quad = original
    for _ in range(EDGE_ITERATIONS):
        a, b = quad, np.roll(quad, -1, axis=0)  # edge k runs from corner k to corner k + 1
        d = b - a
        length = np.hypot(d[:, 0], d[:, 1])
        if length.min() < 1.0:
            return original
        n = np.column_stack([d[:, 1], -d[:, 0]]) / length[:, None]
        outward = np.einsum("ij,ij->i", n, (a + b) / 2 - quad.mean(axis=0)) >= 0
        n[~outward] *= -1.0  # point out of the tag: black border → white quiet zone
        counts = np.maximum(EDGE_MIN_SAMPLES, (length / EDGE_SAMPLE_SPACING_PX).astype(int))
        edge = np.repeat(np.arange(4), counts)
        fractions = np.concatenate([np.linspace(*EDGE_SAMPLE_SPAN, c) for c in counts])
        points = a[edge] + fractions[:, None] * d[edge]
        # all four edges' profiles in one remap: rows are sample points, columns the offsets across
        grid = (points[:, None, :] + _PROFILE_OFFSETS[None, :, None] * n[edge][:, None, :]).astype(np.float32) - shift
        profile = cv2.remap(image, grid[..., 0], grid[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        rise = np.clip(np.diff(profile.astype(float), axis=1), 0.0, None)
        weight = rise.sum(axis=1)
        usable = weight > 0
        if np.bincount(edge[usable], minlength=4).min() < 4:
            return original
        offset = np.where(usable, (rise @ _PROFILE_MIDPOINTS) / np.where(usable, weight, 1.0), 0.0)
        on_edge = points + offset[:, None] * n[edge]
        lines = []
        for k in range(4):  # total-least-squares line: the principal axis of the edge points' scatter
            pts = on_edge[(edge == k) & usable]
            mean = pts.mean(axis=0)
            c = pts - mean
            angle = 0.5 * np.arctan2(2 * (c[:, 0] @ c[:, 1]), c[:, 0] @ c[:, 0] - c[:, 1] @ c[:, 1])
            lines.append((mean, np.array([np.cos(angle), np.sin(angle)])))
        refined = np.empty((4, 2))
        for k in range(4):  # corner k: where edge k − 1 (into it) meets edge k (out of it)
            (p1, d1), (p2, d2) = lines[k - 1], lines[k]
            det = d2[0] * d1[1] - d1[0] * d2[1]
            if abs(det) < 1e-6:
                return original
            r = p2 - p1
            refined[k] = p1 + (d2[0] * r[1] - r[0] * d2[1]) / det * d1
        quad = refined
    if np.abs(quad - original).max() > EDGE_MAX_SHIFT_PX:
        return original
    return quad


class TagDetector:
    """AprilTag 36h11 detector; `backend` "opencv" (default) or "pupil", `tag_ids` the ids to keep (None: all).

    `subpixel` False skips the corner refinement (opencv: `refine_corners`; pupil: its edge refinement).
    `threshold_windows_px` (opencv): ArUco's adaptive threshold window sizes (min, max, step) px
    (module docstring; (3, 23, 10) for small, blurred tags).
    """

    def __init__(
        self,
        backend: str = "opencv",
        tag_ids: Iterable[int] | None = None,
        *,
        subpixel: bool = True,
        threshold_windows_px: tuple[int, int, int] = ARUCO_THRESHOLD_WINDOWS_PX,
    ) -> None:
        if backend not in BACKENDS:
            raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
        windows = tuple(threshold_windows_px)
        if not (
            len(windows) == 3
            and all(isinstance(v, int) and not isinstance(v, bool) for v in windows)
            and 3 <= windows[0] <= windows[1]
            and windows[0] % 2 == windows[1] % 2 == 1
            and windows[2] > 0
            and (windows[1] - windows[0]) % windows[2] == 0
        ):
            raise ValueError(
                "threshold_windows_px must be (min, max, step) px with odd 3 <= min <= max and step > 0 dividing "
                f"max - min, e.g. {ARUCO_THRESHOLD_WINDOWS_PX} or ArUco's default (3, 23, 10), got {threshold_windows_px!r}"
            )
        self.threshold_windows_px = windows
        self.backend = backend
        self.tag_ids = None if tag_ids is None else frozenset(int(i) for i in tag_ids)
        self.subpixel = subpixel
        if backend == "opencv":
            parameters = cv2.aruco.DetectorParameters()
            parameters.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_NONE  # refine_corners does better
            parameters.perspectiveRemovePixelPerCell = ARUCO_PIXELS_PER_CELL
            parameters.perspectiveRemoveIgnoredMarginPerCell = ARUCO_IGNORED_MARGIN_PER_CELL
            parameters.adaptiveThreshWinSizeMin, parameters.adaptiveThreshWinSizeMax, parameters.adaptiveThreshWinSizeStep = windows
            self._opencv_parameters = parameters
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
        array = checked_image(image)
        return self.detect_window(array, (0, 0, array.shape[1], array.shape[0]))

    def detect_window(self, image: Any, window: tuple[int, int, int, int]) -> list[Detection]:
        """`detect` on the window image[y0:y1, x0:x1], window = (x0, y0, x1, y1) px (x1, y1 exclusive); corners in full-image px.

        A tag whose corners keep `window_guard_px` from every window edge that is not an
        edge of the image gets the corners `detect(image)` gives it (module docstring,
        "Windows"); nearer such an edge it may be missed or its corners may differ.
        """
        array = checked_image(image)
        height, width = array.shape[:2]
        x0, y0, x1, y1 = (int(v) for v in window)
        if not (0 <= x0 and x1 <= width and 0 <= y0 and y1 <= height and x1 - x0 >= 8 and y1 - y0 >= 8):
            raise ValueError(
                f"window must be (x0, y0, x1, y1) px with 0 <= x0, x1 - x0 >= 8, x1 <= {width} and 0 <= y0, "
                f"y1 - y0 >= 8, y1 <= {height} (the image is {width} x {height}), got {tuple(window)}"
            )
        grey = as_grey(array[y0:y1, x0:x1])
        origin = np.array([x0, y0], dtype=float)
        if self.backend == "opencv":
            self._set_perimeter_limits(max(width, height), max(x1 - x0, y1 - y0))
            corners, ids, _ = self._opencv.detectMarkers(grey)
            found = [] if ids is None else [(int(i), c.reshape(4, 2) + origin) for i, c in zip(ids.ravel(), corners)]
            if self.subpixel and found:
                pixels = grey.astype(np.float32)
                found = [(i, refine_corners(pixels, c, (x0, y0))) for i, c in found]
        else:
            found = [
                (int(r.tag_id), np.asarray(r.corners)[list(PUPIL_TO_UPRIGHT)] - PUPIL_PIXEL_OFFSET + origin)
                for r in self._pupil.detect(grey)
            ]
        detections = [Detection(i, c) for i, c in found if self.tag_ids is None or i in self.tag_ids]
        return sorted(detections, key=lambda d: d.tag_id)

    def window_guard_px(self, tag_side_px: float) -> float:
        """Distance (px) a tag of black-square side `tag_side_px` must keep from a window's inner edges (module docstring)."""
        if not (math.isfinite(tag_side_px) and tag_side_px > 0):
            raise ValueError(f"tag_side_px must be finite and > 0 px, got {tag_side_px}")
        quiet_zone = tag_side_px * QUIET_CELLS / TAG_CELLS
        reach = self.threshold_windows_px[1] if self.backend == "opencv" else PUPIL_THRESHOLD_REACH_PX
        return quiet_zone + reach + WINDOW_GUARD_EXTRA_PX

    def _set_perimeter_limits(self, image_size: int, window_size: int) -> None:
        """Scale ArUco's perimeter rates so that a window keeps the full image's limits in px.

        ArUco keeps contours of perimeter int(rate · max(cols, rows)) px and above (below for
        the maximum); the rate (⌊rate_image · image_size⌋ + ½) / window_size gives the same
        whole number of px on the window as rate_image on the image.
        """
        parameters = self._opencv_parameters
        parameters.minMarkerPerimeterRate = (math.floor(ARUCO_MIN_PERIMETER_RATE * image_size) + 0.5) / window_size
        parameters.maxMarkerPerimeterRate = (math.floor(ARUCO_MAX_PERIMETER_RATE * image_size) + 0.5) / window_size
        self._opencv.setDetectorParameters(parameters)
