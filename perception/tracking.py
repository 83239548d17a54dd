"""AprilTag detection in small windows around the tags' last known corners, with full-frame fallback.

A camera loop sees the same few tags in every frame, each near where it was one frame
earlier. `TrackingTagDetector(detector, expected_ids).detect(image)` therefore decodes
only windows (regions of interest) of the image around each expected tag's corners from
the previous frame, and runs the full-frame `detector.detect(image)` only when it must.
It returns what `detector.detect(image)` would return for the expected ids: the same
`Detection`s (ids, corners in full-image px, same order and refinement), sorted by id.

Windows. For an expected tag with previous corners c_k = (x_k, y_k), k = 0..3 (px), and
black-square side s = mean edge length (px), the window is the corners' bounding box
grown on every side by

    grow = m + g(s),    g(s) = detector.window_guard_px(s) = s·Q/8 + r + e       [px]

m = `window_margin_px`: how far (px) a tag may move between two detector calls;
g(s): the guard a tag must keep from a window edge for the window's decoding to equal the
full image's (`perception.detect`, "Windows"): the quiet zone s·Q/8 (Q = 1 cell), the
reach r of the detector's adaptive threshold (opencv: its largest window, 13 px by default; pupil:
32 px) and e = 4 px measured slack. Windows are then widened to start at multiples of
8 px (pupil's decimation and threshold tiles stay aligned with the full image's; that
cuts its window-vs-full-frame corner difference from 0.43 to 0.11 px, measured),
clipped to the image, and windows that overlap are replaced by their bounding box until
none overlap. A window's detection is accepted only if its corners keep g(s) from each
window edge that is not an edge of the image; as windows are disjoint, no tag can be
accepted twice.

Equality with the full frame. Inside the guard a window holds every pixel that ArUco's
thresholding, contour tracing, decoding and `refine_corners` read for the tag, and
`TagDetector.detect_window` keeps the full image's contour-size limits in px and refines
with the window's integer origin; so an accepted tag's id and corners are those of
`detect(image)` bit for bit (opencv; tested to 0 px on synthetic frames, asserted to
1e-9 px). pupil-apriltags does not decode windows bit for bit: its corners come within
0.15 px of its full-frame ones (measured; tested <= 0.25 px where it is installed).

Fallback. The full frame is decoded instead when
- an expected tag has no previous corners (the first frame, after a frame that missed it,
  after `reset()`, or after a change of image size), or
- `full_frame_every` = n is given and this is call 0, n, 2n, … (finds tags that left and
  came back, and second copies of an id, which windows cannot see), or
- after the windows, an expected tag was not found exactly once (it moved further than
  m, is occluded or blurred, or two copies of its id lie in the windows).
A tag the full frame misses has no previous corners for the next call, so the next call
is a full frame too. Each call therefore costs the windows' decoding, or the full frame,
or (when the windows missed a tag) both.

Default margin. At 12.8 frames/s and |q̇_i| ≤ 1 rad/s per segment (an upper bound for
the real arm), the tip tag of the two-segment arm (chords 0.11 m) moves ≤ 0.11·(½ + 3/2)
= 0.22 m/s, 24 px per frame at the default camera's 1390 px/m, and its corners turn by
≤ 2 rad/s / 12.8 Hz = 0.16 rad about its centre, ≤ 5 px for a 42 px tag: ≤ 29 px per
frame. `DEFAULT_WINDOW_MARGIN_PX` = 40 px leaves a third in hand; a dropped frame doubles
the motion and falls back to the full frame.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np

from perception.detect import Detection, TagDetector, checked_image

DEFAULT_WINDOW_MARGIN_PX = 40.0
WINDOW_ALIGN_PX = 8  # window origins at multiples of this, px (pupil: decimation 2 × 4 px threshold tiles)

Window = tuple[int, int, int, int]  # (x0, y0, x1, y1) px, x1 and y1 exclusive


def tag_side_px(corners: np.ndarray) -> float:
    """Mean edge length (px) of the quad `corners` (4, 2)."""
    return float(np.linalg.norm(np.roll(corners, -1, axis=0) - corners, axis=1).mean())


def merge_windows(windows: Iterable[Window]) -> list[Window]:
    """Windows with every overlapping pair replaced by its bounding box, until none overlap."""
    merged = list(windows)
    changed = True
    while changed:
        changed = False
        for a in range(len(merged)):
            for b in range(a + 1, len(merged)):
                (ax0, ay0, ax1, ay1), (bx0, by0, bx1, by1) = merged[a], merged[b]
                if ax0 < bx1 and bx0 < ax1 and ay0 < by1 and by0 < ay1:
                    merged[a] = (min(ax0, bx0), min(ay0, by0), max(ax1, bx1), max(ay1, by1))
                    del merged[b]
                    changed = True
                    break
            if changed:
                break
    return merged


class TrackingTagDetector:
    """`detector.detect` restricted to windows around the expected tags' last corners (module docstring).

    detector: a `TagDetector` (its `tag_ids`, if any, must include `expected_ids`);
    expected_ids: the ids to track (e.g. `perception.tags.arm_tag_ids(N)`); only these are
    returned; window_margin_px: motion allowance m between calls, px (>= 0);
    full_frame_every: decode the full frame every n-th call (n >= 1), or None (only when
    needed).
    """

    def __init__(
        self,
        detector: TagDetector,
        expected_ids: Iterable[int],
        window_margin_px: float = DEFAULT_WINDOW_MARGIN_PX,
        full_frame_every: int | None = None,
    ) -> None:
        if not isinstance(detector, TagDetector):
            raise TypeError(f"detector must be a perception.detect.TagDetector, got {type(detector).__name__}")
        ids = [int(i) for i in expected_ids]
        if not ids or min(ids) < 0 or len(set(ids)) != len(ids):
            raise ValueError(f"expected_ids must be distinct integers >= 0, at least one, got {ids}")
        if detector.tag_ids is not None and not set(ids) <= detector.tag_ids:
            raise ValueError(
                f"expected_ids {sorted(set(ids) - detector.tag_ids)} are dropped by the detector's tag_ids "
                f"{sorted(detector.tag_ids)}; build the TagDetector with tag_ids including {sorted(ids)} (or None)"
            )
        if not (math.isfinite(window_margin_px) and window_margin_px >= 0):
            raise ValueError(f"window_margin_px must be finite and >= 0 px, got {window_margin_px}")
        if full_frame_every is not None and (
            isinstance(full_frame_every, bool) or not isinstance(full_frame_every, int) or full_frame_every < 1
        ):
            raise ValueError(f"full_frame_every must be an integer >= 1 or None, got {full_frame_every!r}")
        self.detector = detector
        self.expected_ids = tuple(sorted(ids))
        self.window_margin_px = float(window_margin_px)
        self.full_frame_every = full_frame_every
        self.calls = 0
        self.full_frames = 0  # calls that decoded the full frame
        self.window_misses = 0  # calls whose windows missed an expected tag (then decoded the full frame too)
        self.last_windows: list[Window] = []  # windows decoded in the latest call (empty: none)
        self._tracks: dict[int, np.ndarray] = {}
        self._image_shape: tuple[int, int] | None = None

    def reset(self) -> None:
        """Forget the tags' corners: the next call decodes the full frame. Counters are kept."""
        self._tracks = {}

    def windows(self, image_size: tuple[int, int]) -> list[Window]:
        """The disjoint windows (x0, y0, x1, y1) px around the tracked tags for an image of (width, height) px."""
        width, height = image_size
        boxes = []
        for corners in self._tracks.values():
            grow = self.window_margin_px + self.detector.window_guard_px(tag_side_px(corners))
            x0 = max(int(math.floor(corners[:, 0].min() - grow)) // WINDOW_ALIGN_PX * WINDOW_ALIGN_PX, 0)
            y0 = max(int(math.floor(corners[:, 1].min() - grow)) // WINDOW_ALIGN_PX * WINDOW_ALIGN_PX, 0)
            x1 = min(int(math.floor(corners[:, 0].max() + grow)) + 1, width)
            y1 = min(int(math.floor(corners[:, 1].max() + grow)) + 1, height)
            if x1 - x0 >= 8 and y1 - y0 >= 8:
                boxes.append((x0, y0, x1, y1))
        return merge_windows(boxes)

    def detect(self, image: Any) -> list[Detection]:
        """The expected tags in `image` (grey or BGR uint8), as `detector.detect(image)` finds them, sorted by id."""
        array = checked_image(image)
        height, width = array.shape[:2]
        if self._image_shape != (height, width):
            self._tracks = {}
            self._image_shape = (height, width)
        periodic = self.full_frame_every is not None and self.calls % self.full_frame_every == 0
        self.calls += 1
        self.last_windows = []
        detections = None
        if not periodic and all(i in self._tracks for i in self.expected_ids):
            self.last_windows = self.windows((width, height))
            found = [d for window in self.last_windows for d in self._accepted(array, window)]
            if sorted(d.tag_id for d in found) == list(self.expected_ids):
                detections = found
            else:
                self.window_misses += 1
        if detections is None:
            self.full_frames += 1
            detections = [d for d in self.detector.detect(array) if d.tag_id in self.expected_ids]
        detections.sort(key=lambda d: d.tag_id)
        ids = [d.tag_id for d in detections]
        self._tracks = {d.tag_id: d.corners for d in detections if ids.count(d.tag_id) == 1}
        return detections

    def _accepted(self, image: np.ndarray, window: Window) -> list[Detection]:
        """Expected tags decoded in `window` whose corners keep the guard from its edges inside the image."""
        height, width = image.shape[:2]
        x0, y0, x1, y1 = window
        accepted = []
        for d in self.detector.detect_window(image, window):
            if d.tag_id not in self.expected_ids:
                continue
            guard = self.detector.window_guard_px(tag_side_px(d.corners))
            (cx0, cy0), (cx1, cy1) = d.corners.min(axis=0), d.corners.max(axis=0)
            if (
                (x0 == 0 or cx0 >= x0 + guard)
                and (y0 == 0 or cy0 >= y0 + guard)
                and (x1 == width or cx1 <= x1 - 1 - guard)
                and (y1 == height or cy1 <= y1 - 1 - guard)
            ):
                accepted.append(d)
        return accepted
