"""Window tracking of AprilTags: the full-frame detector's ids and corners, fallback, no duplicates, inputs checked."""

import numpy as np
import pytest

from perception.detect import TagDetector
from perception.synthetic import arm_tag_poses, overhead_calibration, render_tags
from perception.tracking import TrackingTagDetector, merge_windows

TAG_SIZE = 0.03  # m, ≈ 42 px in the default camera
FRAME_DT = 1 / 12.8  # s, the hardware camera
H_IMG_FROM_PLANE = np.linalg.inv(overhead_calibration().H)
ARM_IDS = (0, 1, 2)
EXACT_PX = 1e-9  # stated tolerance for "the same corners" (measured: 0, bit for bit)


def frame(tags, blur=1.0, noise=3.0, seed=0):
    return render_tags(H_IMG_FROM_PLANE, tags, TAG_SIZE, blur_sigma_px=blur, noise_sigma=noise, rng=np.random.default_rng(seed))


def assert_same(tracked, full):
    assert [d.tag_id for d in tracked] == [d.tag_id for d in full]
    for a, b in zip(tracked, full):
        np.testing.assert_allclose(a.corners, b.corners, rtol=0, atol=EXACT_PX, err_msg=f"tag {a.tag_id}")


def tracker(**kwargs):
    return TrackingTagDetector(TagDetector(tag_ids=ARM_IDS), ARM_IDS, **kwargs)


def test_windows_give_the_full_frame_corners_on_an_arm_moving_at_1_rad_s():
    full, tracking = TagDetector(tag_ids=ARM_IDS), tracker()
    q, qd = np.array([0.5, -0.6]), np.array([1.0, -1.0])  # rad, rad/s: the real arm's upper bound
    for k in range(10):
        image = frame(arm_tag_poses(q + k * FRAME_DT * qd, 0.1), seed=k)
        expected = full.detect(image)
        assert [d.tag_id for d in expected] == list(ARM_IDS)
        assert_same(tracking.detect(image), expected)
    assert (tracking.full_frames, tracking.window_misses) == (1, 0)  # only the first frame was decoded whole
    assert 0 < sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in tracking.last_windows) < 0.25 * 1280 * 720


def test_windows_clipped_by_the_image_edges_give_the_full_frame_corners():
    full, tracking = TagDetector(tag_ids=ARM_IDS), tracker()
    for k in range(3):  # tags 0 and 2 moving towards the left and bottom-right image edges, ≈ 20 px from them
        tags = {0: (-0.2985 - 0.002 * k, 0.0, 0.3), 1: (0.1, 0.0, -0.2), 2: (0.543 + 0.002 * k, -0.22 - 0.002 * k, 1.0)}
        image = frame(tags, seed=k)
        assert_same(tracking.detect(image), full.detect(image))
    assert (tracking.full_frames, tracking.window_misses) == (1, 0)
    assert any(x0 == 0 for x0, *_ in tracking.last_windows) and any(x1 == 1280 for *_, x1, _ in tracking.last_windows)


def test_bgr_frames_give_the_grey_result():
    image = frame(arm_tag_poses(np.array([0.3, 0.2])))
    bgr = np.repeat(image[:, :, None], 3, axis=2)
    tracking = tracker()
    first = tracking.detect(bgr)
    assert_same(tracking.detect(bgr), first)
    assert tracking.full_frames == 1
    assert_same(first, TagDetector(tag_ids=ARM_IDS).detect(image))


def test_a_tag_that_jumps_out_of_its_window_is_found_by_the_full_frame():
    full, tracking = TagDetector(tag_ids=ARM_IDS), tracker()
    tags = arm_tag_poses(np.array([0.2, 0.3]))
    tracking.detect(frame(tags))
    jumped = dict(tags)
    jumped[2] = (tags[2][0] + 0.12, tags[2][1] - 0.1, tags[2][2])  # ≈ 220 px, far beyond the 40 px margin
    image = frame(jumped, seed=1)
    assert_same(tracking.detect(image), full.detect(image))
    assert (tracking.full_frames, tracking.window_misses) == (2, 1)
    image = frame(jumped, seed=2)
    assert_same(tracking.detect(image), full.detect(image))
    assert (tracking.full_frames, tracking.window_misses) == (2, 1)  # tracked again from its new place


def test_an_occluded_tag_is_searched_for_in_the_full_frame_until_it_returns():
    full, tracking = TagDetector(tag_ids=ARM_IDS), tracker()
    tags = arm_tag_poses(np.array([-0.3, 0.4]))
    occluded = {i: pose for i, pose in tags.items() if i != 1}
    sequence = [tags, occluded, occluded, tags, tags]
    counts = []
    for k, scene in enumerate(sequence):
        image = frame(scene, seed=k)
        result = tracking.detect(image)
        assert_same(result, full.detect(image))
        assert [d.tag_id for d in result] == sorted(scene)
        counts.append((tracking.full_frames, tracking.window_misses))
    # 1: windows miss tag 1 → full frame; 2: no corners for tag 1 → full frame only; 3: full frame finds it; 4: windows
    assert counts == [(1, 0), (2, 1), (3, 1), (4, 1), (4, 1)]


def test_tags_in_overlapping_windows_are_returned_once():
    full, tracking = TagDetector(tag_ids=ARM_IDS), tracker()
    tags = {0: (0.0, 0.0, 0.0), 1: (0.05, 0.01, 0.5), 2: (0.01, 0.055, -0.4)}  # 70–76 px apart: windows overlap
    for k in range(3):
        image = frame(tags, seed=k)
        result = tracking.detect(image)
        assert [d.tag_id for d in result] == list(ARM_IDS)
        assert_same(result, full.detect(image))
    assert len(tracking.last_windows) == 1 and (tracking.full_frames, tracking.window_misses) == (1, 0)


def test_a_second_copy_of_an_id_in_the_windows_falls_back_to_the_full_frame():
    full, tracking = TagDetector(tag_ids=ARM_IDS), tracker()
    tags = {0: (0.0, 0.0, 0.0), 1: (0.11, 0.0, 0.0), 2: (0.22, 0.0, 0.0)}
    tracking.detect(frame(tags))
    copy = {**tags, 3: (0.055, 0.025, 0.0)}  # a second tag 1 between tags 0 and 1, inside their merged window
    image = render_tags(H_IMG_FROM_PLANE, {0: tags[0], 1: tags[1], 2: tags[2]}, TAG_SIZE)
    image = np.minimum(image, render_tags(H_IMG_FROM_PLANE, {1: copy[3]}, TAG_SIZE, background=255))
    expected = full.detect(image)
    assert [d.tag_id for d in expected] == [0, 1, 1, 2]
    assert_same(tracking.detect(image), expected)
    assert (tracking.full_frames, tracking.window_misses) == (2, 1)
    tracking.detect(image)
    assert tracking.full_frames == 3  # id 1 is ambiguous, so it is not tracked


def test_full_frame_every_n_calls_and_after_reset_or_a_new_image_size():
    image = frame(arm_tag_poses(np.array([0.1, 0.1])))
    tracking = tracker(full_frame_every=3)
    for _ in range(7):
        tracking.detect(image)
    assert (tracking.calls, tracking.full_frames) == (7, 3)  # calls 0, 3, 6
    tracking = tracker()
    tracking.detect(image)
    tracking.reset()
    tracking.detect(image)
    tracking.detect(np.ascontiguousarray(image[:, :1200]))
    assert tracking.full_frames == 3


def test_merged_windows_cover_the_inputs_and_are_disjoint():
    windows = [(0, 0, 10, 10), (5, 5, 20, 20), (19, 0, 30, 8), (40, 40, 50, 50), (50, 0, 60, 40)]
    merged = merge_windows(windows)
    assert sorted(merged) == [(0, 0, 30, 20), (40, 40, 50, 50), (50, 0, 60, 40)]  # touching edges do not overlap


def test_pupil_windows_agree_with_its_full_frame_within_a_stated_tolerance():
    pytest.importorskip("pupil_apriltags")
    full = TagDetector("pupil", tag_ids=ARM_IDS)
    tracking = TrackingTagDetector(TagDetector("pupil", tag_ids=ARM_IDS), ARM_IDS)
    q, qd = np.array([0.5, -0.6]), np.array([1.0, -1.0])
    for k in range(4):
        image = frame(arm_tag_poses(q + k * FRAME_DT * qd, 0.1), seed=k)
        tracked, expected = tracking.detect(image), full.detect(image)
        assert [d.tag_id for d in tracked] == [d.tag_id for d in expected] == list(ARM_IDS)
        for a, b in zip(tracked, expected):
            assert np.abs(a.corners - b.corners).max() <= 0.25  # measured 0.15 px max
    assert tracking.full_frames == 1


def test_bad_arguments_are_refused_with_the_fix():
    detector = TagDetector(tag_ids=ARM_IDS)
    with pytest.raises(ValueError, match=r"expected_ids \[3\] are dropped by the detector's tag_ids"):
        TrackingTagDetector(detector, (0, 3))
    with pytest.raises(ValueError, match="distinct integers"):
        TrackingTagDetector(detector, (1, 1))
    with pytest.raises(ValueError, match="distinct integers"):
        TrackingTagDetector(detector, ())
    with pytest.raises(ValueError, match="window_margin_px must be finite and >= 0"):
        TrackingTagDetector(detector, ARM_IDS, window_margin_px=-1.0)
    with pytest.raises(ValueError, match="full_frame_every must be an integer >= 1"):
        TrackingTagDetector(detector, ARM_IDS, full_frame_every=0)
    with pytest.raises(TypeError, match="TagDetector"):
        TrackingTagDetector(object(), ARM_IDS)
    with pytest.raises(ValueError, match="uint8"):
        TrackingTagDetector(detector, ARM_IDS).detect(np.zeros((720, 1280), np.float32))
