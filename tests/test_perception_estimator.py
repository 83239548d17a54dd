"""Arm angles from tags: q within tolerance on synthetic images, q̇, hold-then-stale timing, frame capture."""

import math

import cv2
import numpy as np
import pytest

from perception.capture import Frame, FrameSource, VideoCaptureSource
from perception.detect import Detection, TagDetector
from perception.estimator import DEFAULT_MAX_HOLD_S, ArmAngleEstimator, wrap_angle
from perception.plane import PlaneCalibration, tag_corners_on_plane
from perception.synthetic import arm_tag_poses, overhead_calibration, render_tags

TAG_SIZE = 0.03
CAL = overhead_calibration()
H_IMG_FROM_PLANE = np.linalg.inv(CAL.H)
FRAME_DT = 1 / 12.8  # hardware camera period, s
Q_MAX_DEG = 1.0  # the tolerance of q from images (blur σ 1 px, noise σ 3; measured max 0.12°)


def exact_detections(q, theta0=0.0, drop=()):
    return [
        Detection(i, CAL.map_to_image(tag_corners_on_plane(*pose, TAG_SIZE)))
        for i, pose in arm_tag_poses(q, theta0).items()
        if i not in drop
    ]


def test_q_from_images_of_random_poses_is_within_tolerance():
    rng = np.random.default_rng(5)
    detector = TagDetector(tag_ids=range(4))
    errors = []
    for n_segments in (2, 3):
        for _ in range(4):
            q = rng.uniform(-0.7, 0.7, n_segments)
            theta0 = rng.uniform(-0.3, 0.3)
            image = render_tags(H_IMG_FROM_PLANE, arm_tag_poses(q, theta0), TAG_SIZE, blur_sigma_px=1.0, noise_sigma=3.0, rng=rng)
            estimate = ArmAngleEstimator(n_segments, CAL, TAG_SIZE).update(0.0, detector.detect(image))
            assert estimate.valid and not estimate.stale and estimate.tags_seen == tuple(range(n_segments + 1))
            errors.extend(np.degrees(wrap_angle(estimate.q - q)))
            x, y, _ = arm_tag_poses(q, theta0)[n_segments]
            tip = estimate.tag_poses[n_segments]
            assert math.hypot(tip.x - x, tip.y - y) < 0.1e-3  # tag positions within 0.1 mm (measured 0.014 mm)
    assert np.abs(errors).max() <= Q_MAX_DEG, np.abs(errors).max()


def test_q_wraps_through_the_back_of_the_circle():
    q = np.array([0.5, -0.4])
    estimate = ArmAngleEstimator(2, CAL).update(0.0, exact_detections(q, theta0=math.radians(170)))
    np.testing.assert_allclose(estimate.q, q, atol=1e-9)


def test_qd_is_the_finite_difference_across_dropped_frames():
    w = np.array([0.8, -0.5])
    estimator = ArmAngleEstimator(2, CAL)
    first = estimator.update(0.0, exact_detections(np.zeros(2)))
    assert first.valid and not first.qd_valid and np.all(first.qd == 0)
    for k in (1, 3):  # frame 2 was dropped: the difference spans two periods
        estimate = estimator.update(k * FRAME_DT, exact_detections(w * k * FRAME_DT))
        assert estimate.qd_valid
        np.testing.assert_allclose(estimate.qd, w, atol=1e-7)


def test_qd_filter_is_a_first_order_lag_of_the_finite_difference():
    tau, w = 0.2, np.array([1.0, 2.0])
    estimator = ArmAngleEstimator(2, CAL, qd_filter_tau=tau, max_hold_s=1.0)
    estimator.update(0.0, exact_detections(np.zeros(2)))
    estimator.update(FRAME_DT, exact_detections(np.zeros(2)))  # at rest: the filter starts at 0
    for m in range(1, 6):  # ramp from frame 1 on: raw q̇ = w, filtered w·(1 − exp(−m·dt/τ))
        estimate = estimator.update((1 + m) * FRAME_DT, exact_detections(w * m * FRAME_DT))
        np.testing.assert_allclose(estimate.qd, w * (1 - math.exp(-m * FRAME_DT / tau)), rtol=1e-6)


def test_missing_tag_holds_then_goes_stale_at_max_hold_then_recovers():
    q = np.array([0.3, -0.2])
    estimator = ArmAngleEstimator(2, CAL)
    assert estimator.query(0.0).stale and not estimator.query(0.0).valid and np.all(np.isnan(estimator.query(0.0).q))
    t_last = 0.5
    estimator.update(t_last - FRAME_DT, exact_detections(q))
    estimator.update(t_last, exact_detections(q))
    for k in (1, 2, 3):  # segment 2's tag missing in every later frame
        held = estimator.update(t_last + k * FRAME_DT, exact_detections(q + 0.3, drop=(2,)))
        assert held.t == t_last and held.frames_missed == k and held.tags_seen == (0, 1)
        np.testing.assert_allclose(held.q, q, atol=1e-9)
        assert held.stale == (k * FRAME_DT > DEFAULT_MAX_HOLD_S)
    assert not estimator.query(t_last + DEFAULT_MAX_HOLD_S - 1e-9).stale
    late = estimator.query(t_last + DEFAULT_MAX_HOLD_S + 1e-9)
    assert late.stale and late.valid and late.age_s == pytest.approx(DEFAULT_MAX_HOLD_S, abs=1e-8)
    back = estimator.update(t_last + 5 * FRAME_DT, exact_detections(q))
    assert not back.stale and back.age_s == 0 and back.frames_missed == 0 and not back.qd_valid
    again = estimator.update(t_last + 6 * FRAME_DT, exact_detections(q))
    assert again.qd_valid and np.abs(again.qd).max() < 1e-6


def test_no_frames_at_all_go_stale_at_max_hold():
    estimator = ArmAngleEstimator(2, CAL, max_hold_s=0.15)
    estimator.update(1.0, exact_detections(np.zeros(2)))
    assert [estimator.query(1.0 + dt).stale for dt in (0.1, 0.15, 0.16, 5.0)] == [False, False, True, True]


def test_an_occluded_tag_in_the_image_holds_the_estimate():
    q = np.array([0.4, 0.1])
    tags = arm_tag_poses(q)
    detector = TagDetector(tag_ids=range(3))
    estimator = ArmAngleEstimator(2, CAL, TAG_SIZE)
    assert estimator.update(0.0, detector.detect(render_tags(H_IMG_FROM_PLANE, tags, TAG_SIZE))).valid
    image = render_tags(H_IMG_FROM_PLANE, arm_tag_poses(q + 0.2), TAG_SIZE)
    u, v = np.rint(CAL.map_to_image(tags[1][:2])[0]).astype(int)
    cv2.rectangle(image, (u - 15, v - 15), (u + 15, v + 15), 40, thickness=-1)  # a finger over tag 1
    held = estimator.update(FRAME_DT, detector.detect(image))
    assert held.tags_seen == (0, 2) and held.t == 0.0 and held.frames_missed == 1
    assert np.abs(np.degrees(held.q - q)).max() < Q_MAX_DEG


def test_base_tag_missing_uses_its_last_angle_or_the_given_one():
    q, theta0 = np.array([0.2, 0.3]), 0.1
    assert not ArmAngleEstimator(2, CAL).update(0.0, exact_detections(q, theta0, drop=(0,))).valid
    given = ArmAngleEstimator(2, CAL, base_angle=theta0).update(0.0, exact_detections(q, theta0, drop=(0,)))
    assert given.valid and given.base_from_memory
    np.testing.assert_allclose(given.q, q, atol=1e-9)
    estimator = ArmAngleEstimator(2, CAL)
    assert not estimator.update(0.0, exact_detections(q, theta0)).base_from_memory
    remembered = estimator.update(FRAME_DT, exact_detections(q + 0.1, theta0, drop=(0,)))
    assert remembered.valid and remembered.base_from_memory and remembered.t == FRAME_DT
    np.testing.assert_allclose(remembered.q, q + 0.1, atol=1e-9)


def test_duplicated_or_wrong_sized_tags_count_as_missing():
    q = np.array([0.2, 0.3])
    detections = exact_detections(q)
    duplicated = [*detections, Detection(2, detections[2].corners + 50.0)]
    assert ArmAngleEstimator(2, CAL).update(0.0, duplicated).tags_seen == (0, 1)
    corners = detections[1].corners
    doubled = [detections[0], Detection(1, 2 * corners - corners.mean(axis=0)), detections[2]]
    assert not ArmAngleEstimator(2, CAL, TAG_SIZE).update(0.0, doubled).valid
    assert ArmAngleEstimator(2, CAL).update(0.0, doubled).valid  # without tag_size no size check


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"n_segments": 0}, "n_segments"),
        ({"calibration": np.eye(3)}, "PlaneCalibration"),
        ({"tag_size": -0.03}, "tag_size"),
        ({"max_hold_s": 0.0}, "max_hold_s"),
        ({"qd_filter_tau": math.nan}, "qd_filter_tau"),
        ({"base_angle": math.inf}, "base_angle"),
        ({"size_tolerance": 1.5}, "size_tolerance"),
    ],
)
def test_bad_settings_are_refused(kwargs, message):
    settings = {"n_segments": 2, "calibration": CAL, **kwargs}
    with pytest.raises((ValueError, TypeError), match=message):
        ArmAngleEstimator(**settings)


def test_bad_times_and_detections_are_refused():
    estimator = ArmAngleEstimator(2, CAL)
    estimator.update(1.0, exact_detections(np.zeros(2)))
    with pytest.raises(ValueError, match="capture order"):
        estimator.update(1.0, exact_detections(np.zeros(2)))
    with pytest.raises(ValueError, match="finite"):
        estimator.update(math.nan, [])
    with pytest.raises(ValueError, match="before the latest frame"):
        estimator.query(0.5)
    with pytest.raises(TypeError, match="Detection"):
        estimator.update(2.0, [(1, np.zeros((4, 2)))])


def test_video_capture_source_timestamps_from_the_injected_clock(tmp_path):
    path = str(tmp_path / "clip.avi")
    writer = cv2.VideoWriter(path, cv2.VideoWriter_fourcc(*"MJPG"), 12.8, (160, 120))
    for k in range(3):
        writer.write(np.full((120, 160, 3), 60 * k, np.uint8))
    writer.release()
    ticks = iter([10.0, 10.1, 10.2])
    with VideoCaptureSource(path, clock=lambda: next(ticks)) as source:
        assert isinstance(source, FrameSource)
        frames = [source.read() for _ in range(4)]
    assert [(f.t, f.index, f.image.shape) for f in frames[:3]] == [(10.0 + 0.1 * k, k, (120, 160, 3)) for k in range(3)]
    assert frames[3] is None


def test_capture_errors_are_clear(tmp_path):
    with pytest.raises(OSError, match="could not open"):
        VideoCaptureSource(str(tmp_path / "missing.avi"))
    with pytest.raises(ValueError, match="finite"):
        Frame(math.inf, np.zeros((4, 4), np.uint8), 0)
    with pytest.raises(ValueError, match="uint8"):
        Frame(0.0, np.zeros((4, 4)), 0)
    with pytest.raises(ValueError, match="index"):
        Frame(0.0, np.zeros((4, 4), np.uint8), -1)


def test_the_estimate_needs_only_the_calibration_file(tmp_path):
    CAL.save(tmp_path / "cal.json")
    q = np.array([-0.6, 0.45])
    estimate = ArmAngleEstimator(2, PlaneCalibration.load(tmp_path / "cal.json")).update(0.0, exact_detections(q))
    np.testing.assert_allclose(estimate.q, q, atol=1e-9)
