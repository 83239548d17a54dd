"""Bending angles q and rates q̇ of the planar arm from tag detections, with hold-then-stale timing.

Angles. Each detection's four corners are mapped to the plane by the calibration and
give the tag's plane angle θ (both x edges summed, `perception.plane.tag_pose_on_plane`).
Tag 0 sits on the base (θ_0), tag i on the end of segment i (θ_i = θ_0 + q_1 + … + q_i),
so

    q_i = wrap(θ_i − θ_{i−1}),  i = 1..N,   wrap to (−π, π]   [rad]

Rates. q̇ is the finite difference between consecutive complete frames at capture
times t_prev < t,  q̇_raw = wrap(q − q_prev) / (t − t_prev)  [rad/s], optionally low-pass
filtered to first order with time constant τ = `qd_filter_tau` (exact for uneven steps):

    q̇ ← q̇ + (1 − exp(−(t − t_prev)/τ)) · (q̇_raw − q̇)      (τ = 0: q̇ = q̇_raw)

The first complete frame, and the first after the estimate went stale, has no
predecessor to difference against: it reports q̇ = 0 with `qd_valid` False and restarts
the filter, whose first value is then q̇_raw itself.

Missing tags and late frames. A frame is *complete* when every segment tag 1..N is
detected exactly once (a duplicated id counts as missing) with a plausible plane size
(within `size_tolerance` of `tag_size`, when that is given) and θ_0 is known. An
incomplete frame, or no frame at all, changes nothing: the last complete estimate is
held, its `t` stays the capture time it came from and `age_s` = now − t grows. When
age_s > max_hold_s the estimate is `stale` — the loop must take its safe action — and
stays stale until a complete frame arrives. Before the first complete frame the
estimate is stale, not `valid`, and q, q̇ are NaN.

Base tag. The base is clamped to the table, so θ_0 does not change while the arm moves:
a frame that sees the base tag uses (and remembers) its angle; a frame that misses it
uses the last seen angle, or `base_angle` (rad) given at construction if the base tag
has never been seen (then `base_from_memory` is True). Without either, frames stay
incomplete until the base tag has been seen once.

max_hold_s. Default 0.3 s: the hardware camera delivers a frame every 1/12.8 fps =
78 ms and the loop runs at 10 Hz, so two consecutive lost frames (an estimate up to
3 × 78 = 234 ms old, plus up to ~60 ms detection latency) are bridged, and a third
makes the estimate stale; the 10 Hz loop then sees it stale at most one period (0.1 s)
after the hold runs out.

Times are seconds on one monotonic clock (the capture clock); frames must be given in
capture order.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from perception.detect import Detection
from perception.plane import PlaneCalibration, TagPose, tag_pose_on_plane
from perception.tags import BASE_TAG_ID, arm_tag_ids

DEFAULT_MAX_HOLD_S = 0.3
DEFAULT_SIZE_TOLERANCE = 0.2


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to (−π, π]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2 * np.pi)


@dataclass(frozen=True, eq=False)
class ArmEstimate:
    """The arm's state as seen by the camera at time `now` (see the module docstring for the flags).

    t: capture time (s) of the frame q came from (NaN before the first complete frame);
    q, qd: (N,) rad, rad/s; valid: q, qd come from a complete frame; stale: no estimate
    or age_s > max_hold_s; age_s: now − t (inf before the first); qd_valid: qd is a
    finite difference (False on the first frame of a run of complete frames);
    frames_missed: incomplete frames processed since t; tags_seen: ids in the latest
    processed frame; tag_poses: their poses on the plane; base_from_memory: θ_0 at t
    was not seen in that frame.
    """

    t: float
    q: np.ndarray
    qd: np.ndarray
    valid: bool
    stale: bool
    age_s: float
    qd_valid: bool = False
    frames_missed: int = 0
    tags_seen: tuple[int, ...] = ()
    tag_poses: Mapping[int, TagPose] = field(default_factory=dict)
    base_from_memory: bool = False


@dataclass(frozen=True, eq=False)
class _Complete:
    """The last complete frame's estimate."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qd_valid: bool
    base_from_memory: bool


class ArmAngleEstimator:
    """Tag detections → q, q̇ of an N-segment arm; hold the last estimate for `max_hold_s`, then flag it stale."""

    def __init__(
        self,
        n_segments: int,
        calibration: PlaneCalibration,
        tag_size: float | None = None,
        *,
        max_hold_s: float = DEFAULT_MAX_HOLD_S,
        qd_filter_tau: float = 0.0,
        base_angle: float | None = None,
        size_tolerance: float = DEFAULT_SIZE_TOLERANCE,
    ) -> None:
        self.tag_ids = arm_tag_ids(n_segments)
        if not isinstance(calibration, PlaneCalibration):
            raise TypeError(f"calibration must be a PlaneCalibration, got {type(calibration).__name__}")
        if tag_size is not None and not (math.isfinite(tag_size) and tag_size > 0):
            raise ValueError(f"tag_size must be None or a finite size > 0 m, got {tag_size}")
        if not (math.isfinite(max_hold_s) and max_hold_s > 0):
            raise ValueError(f"max_hold_s must be finite and > 0 s, got {max_hold_s}")
        if not (math.isfinite(qd_filter_tau) and qd_filter_tau >= 0):
            raise ValueError(f"qd_filter_tau must be finite and >= 0 s (0: no filter), got {qd_filter_tau}")
        if base_angle is not None and not math.isfinite(base_angle):
            raise ValueError(f"base_angle must be None or finite (rad), got {base_angle}")
        if not 0 < size_tolerance < 1:
            raise ValueError(f"size_tolerance must be in (0, 1) (a fraction of tag_size), got {size_tolerance}")
        self.n_segments = n_segments
        self.calibration = calibration
        self.tag_size = tag_size
        self.max_hold_s = float(max_hold_s)
        self.qd_filter_tau = float(qd_filter_tau)
        self.size_tolerance = float(size_tolerance)
        self._base_angle = None if base_angle is None else float(base_angle)
        self._last: _Complete | None = None
        self._t_frame = -math.inf
        self._frames_missed = 0
        self._tag_poses: dict[int, TagPose] = {}

    def _poses(self, detections: Iterable[Detection]) -> dict[int, TagPose]:
        """Plane poses of the tags detected exactly once with a plausible size."""
        by_id: dict[int, list[Detection]] = {}
        for detection in detections:
            if not isinstance(detection, Detection):
                raise TypeError(f"detections must be Detection objects, got {type(detection).__name__}")
            by_id.setdefault(detection.tag_id, []).append(detection)
        poses = {}
        for tag_id, found in sorted(by_id.items()):
            if len(found) != 1:
                continue
            pose = tag_pose_on_plane(self.calibration.map_points(found[0].corners))
            if not all(math.isfinite(v) for v in (pose.x, pose.y, pose.angle, pose.size)):
                continue
            if self.tag_size is not None and abs(pose.size - self.tag_size) > self.size_tolerance * self.tag_size:
                continue
            poses[tag_id] = pose
        return poses

    def update(self, t_capture: float, detections: Iterable[Detection]) -> ArmEstimate:
        """Process the detections of the frame captured at `t_capture` (s); return the estimate at that time."""
        if not math.isfinite(t_capture):
            raise ValueError(f"t_capture must be finite (s), got {t_capture}")
        if t_capture <= self._t_frame:
            raise ValueError(
                f"frames must come in capture order: t_capture {t_capture} s is not after the previous frame's "
                f"{self._t_frame} s; drop late or repeated frames before update()"
            )
        poses = self._poses(detections)
        self._t_frame = float(t_capture)
        self._tag_poses = poses
        base_seen = BASE_TAG_ID in poses
        if base_seen:
            self._base_angle = poses[BASE_TAG_ID].angle
        segment_ids = self.tag_ids[1:]
        if self._base_angle is None or not all(i in poses for i in segment_ids):
            self._frames_missed += 1
            return self.query(t_capture)
        theta = np.array([self._base_angle] + [poses[i].angle for i in segment_ids])
        q = wrap_angle(np.diff(theta))
        previous = self._last
        if previous is not None and t_capture - previous.t <= self.max_hold_s:
            dt = t_capture - previous.t
            qd_raw = wrap_angle(q - previous.q) / dt
            if self.qd_filter_tau > 0 and previous.qd_valid:
                qd = previous.qd + (1.0 - math.exp(-dt / self.qd_filter_tau)) * (qd_raw - previous.qd)
            else:
                qd = qd_raw
            qd_valid = True
        else:
            qd, qd_valid = np.zeros(self.n_segments), False
        q.setflags(write=False)
        qd.setflags(write=False)
        self._last = _Complete(float(t_capture), q, qd, qd_valid, not base_seen)
        self._frames_missed = 0
        return self.query(t_capture)

    def query(self, now: float) -> ArmEstimate:
        """The held estimate at time `now` (s): its age and whether it is stale."""
        if not math.isfinite(now):
            raise ValueError(f"now must be finite (s), got {now}")
        if now < self._t_frame:
            raise ValueError(f"now {now} s is before the latest frame's capture time {self._t_frame} s; use one monotonic clock")
        seen = tuple(sorted(self._tag_poses))
        last = self._last
        if last is None:
            nan = np.full(self.n_segments, np.nan)
            return ArmEstimate(
                math.nan, nan, nan.copy(), valid=False, stale=True, age_s=math.inf,
                frames_missed=self._frames_missed, tags_seen=seen, tag_poses=dict(self._tag_poses),
            )
        age = float(now) - last.t
        return ArmEstimate(
            last.t, last.q, last.qd, valid=True, stale=age > self.max_hold_s, age_s=age, qd_valid=last.qd_valid,
            frames_missed=self._frames_missed, tags_seen=seen, tag_poses=dict(self._tag_poses),
            base_from_memory=last.base_from_memory,
        )
