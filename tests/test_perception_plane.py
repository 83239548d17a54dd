"""The image-to-plane map: pinhole geometry, fitting, calibration from a tag board, files and errors."""

import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from perception.detect import Detection, TagDetector
from perception.plane import PlaneCalibration, TagBoard, calibrate, tag_corners_on_plane, tag_pose_on_plane
from perception.synthetic import CAMERA_POS, PLANE_Z, R_DOWN, overhead_calibration, pinhole_intrinsics, render_tags

ROOT = Path(__file__).parents[1]
K = pinhole_intrinsics()
CAL = overhead_calibration()
# a board of 8 tags spread over the view, 40 mm squares
BOARD = TagBoard(0.04, {10 + i: (-0.25 + 0.16 * (i % 4), -0.15 + 0.3 * (i // 4), 0.3 * i - 1.0) for i in range(8)})
IMAGE_GRID = np.stack(np.meshgrid(np.linspace(0, 1279, 9), np.linspace(0, 719, 7)), axis=-1).reshape(-1, 2)
CALIBRATION_MAX_MM = 0.1  # stated tolerance of the board calibration over the whole image, blur 1 px, noise 3 (measured 0.015 mm)


def board_image():
    return render_tags(np.linalg.inv(CAL.H), BOARD.tags, BOARD.tag_size, blur_sigma_px=1.0, noise_sigma=3.0, rng=np.random.default_rng(1))


def test_from_pinhole_agrees_with_opencv_projection():
    R = np.array(cv2.Rodrigues(np.array([0.2, -0.15, 0.1]))[0]) @ R_DOWN
    c = np.array([0.1, -0.05, 0.7])
    calibration = PlaneCalibration.from_pinhole(K, R, c, 0.02)
    plane = np.random.default_rng(2).uniform(-0.2, 0.2, (20, 2))
    world = np.column_stack([plane, np.full(20, 0.02)])
    rvec, _ = cv2.Rodrigues(R.T)
    image, _ = cv2.projectPoints(world, rvec, -R.T @ c, K, None)
    np.testing.assert_allclose(calibration.map_to_image(plane), image.reshape(-1, 2), atol=1e-8)
    np.testing.assert_allclose(calibration.map_points(image.reshape(-1, 2)), plane, atol=1e-12)


def test_default_camera_axes_and_scale():
    # image centre → below the camera; image right = +x, image up = +y; f / depth px per m
    np.testing.assert_allclose(CAL.map_points([639.5, 359.5])[0], CAMERA_POS[:2], atol=1e-12)
    metres_per_px = (CAMERA_POS[2] - PLANE_Z) / K[0, 0]
    np.testing.assert_allclose(CAL.map_points([739.5, 259.5])[0], np.add(CAMERA_POS[:2], [100 * metres_per_px, 100 * metres_per_px]), atol=1e-12)


def test_fit_recovers_a_known_homography():
    rng = np.random.default_rng(3)
    image = rng.uniform([0, 0], [1280, 720], (40, 2))
    plane = CAL.map_points(image)
    exact = PlaneCalibration.fit(image, plane)
    assert np.abs(exact.map_points(IMAGE_GRID) - CAL.map_points(IMAGE_GRID)).max() < 1e-7  # findHomography's LM tolerance
    noisy = PlaneCalibration.fit(image + rng.normal(0, 0.3, image.shape), plane)
    error_mm = 1e3 * np.linalg.norm(noisy.map_points(IMAGE_GRID) - CAL.map_points(IMAGE_GRID), axis=1)
    assert error_mm.max() < 0.5, error_mm.max()  # 0.3 px noise ≈ 0.22 mm per point, 40 points


def test_calibrate_from_a_board_image_recovers_the_camera_map():
    detections = TagDetector().detect(board_image())
    assert sorted(d.tag_id for d in detections) == sorted(BOARD.tags)
    calibration = calibrate(detections, BOARD)
    error_mm = 1e3 * np.linalg.norm(calibration.map_points(IMAGE_GRID) - CAL.map_points(IMAGE_GRID), axis=1)
    assert error_mm.max() <= CALIBRATION_MAX_MM, error_mm.max()
    image = np.concatenate([d.corners for d in detections])
    plane = np.concatenate([BOARD.corners(d.tag_id) for d in detections])
    residual = calibration.reprojection_error(image, plane)
    assert residual.n_points == 32 and residual.rms_px < 0.1 and residual.max_m < 0.1e-3  # measured 0.017 px, 0.023 mm


def test_calibrate_ignores_duplicated_and_unknown_ids_and_needs_enough_tags():
    exact = [Detection(i, CAL.map_to_image(BOARD.corners(i))) for i in BOARD.tags]
    shifted = Detection(10, exact[0].corners + 30.0)
    stray = Detection(99, exact[1].corners + 60.0)
    calibration = calibrate([*exact, shifted, stray], BOARD)  # tag 10 twice: both dropped
    assert np.abs(calibration.map_points(IMAGE_GRID) - CAL.map_points(IMAGE_GRID)).max() < 1e-7
    with pytest.raises(ValueError, match="at least 2 board tags"):
        calibrate([exact[0], stray], BOARD)


def test_tag_pose_of_the_board_corners_is_the_board_pose():
    for angle in np.radians(np.arange(-179.0, 180.0, 17.0)):
        pose = tag_pose_on_plane(tag_corners_on_plane(0.1, -0.2, angle, 0.03))
        assert (pose.x, pose.y, pose.size) == pytest.approx((0.1, -0.2, 0.03), abs=1e-15)
        assert math.remainder(pose.angle - angle, 2 * math.pi) == pytest.approx(0.0, abs=1e-12)


def test_files_round_trip(tmp_path):
    CAL.save(tmp_path / "cal.json")
    np.testing.assert_array_equal(PlaneCalibration.load(tmp_path / "cal.json").H, CAL.H)
    BOARD.save(tmp_path / "board.json")
    assert TagBoard.load(tmp_path / "board.json") == BOARD


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: PlaneCalibration(np.eye(2)), "3x3"),
        (lambda: PlaneCalibration(np.full((3, 3), np.nan)), "finite"),
        (lambda: PlaneCalibration(np.array([[1.0, 0, 0], [2, 0, 0], [0, 0, 1]])), "invertible"),
        (lambda: PlaneCalibration.fit(np.zeros((3, 2)), np.zeros((3, 2))), "at least 4"),
        (lambda: PlaneCalibration.fit(np.zeros((4, 2)), np.zeros((5, 2))), "pair up"),
        (lambda: PlaneCalibration.fit([[0, 0], [1, 1], [2, 2], [3, 3]], [[0, 0], [1, 1], [2, 2], [3, 3]]), "collinear"),
        (lambda: PlaneCalibration.fit([[0, 0], [1, 0], [0, 1], [np.inf, 1]], np.zeros((4, 2))), "finite"),
        (lambda: CAL.map_points(np.zeros((4, 3))), r"\(n, 2\)"),
        (lambda: PlaneCalibration.from_pinhole(K, np.eye(3) * 2, CAMERA_POS, PLANE_Z), "proper rotation"),
        (lambda: PlaneCalibration.from_pinhole(K, R_DOWN, (0, 0, -1.0), PLANE_Z), "in front"),
        (lambda: PlaneCalibration.from_pinhole(-K, R_DOWN, CAMERA_POS, PLANE_Z), "fx, fy > 0"),
        (lambda: PlaneCalibration.from_dict({"H": np.eye(3).tolist()}), "format_version"),
        (lambda: TagBoard(-0.03, {0: (0, 0, 0)}), "tag_size"),
        (lambda: TagBoard(0.03, {}), "at least one tag"),
        (lambda: TagBoard(0.03, {0: (0, math.nan, 0)}), "finite"),
        (lambda: TagBoard.from_dict({"tag_size_m": 0.03, "tags": [{"id": 0, "x": 0}]}), "tag board is"),
    ],
)
def test_bad_inputs_say_what_was_wrong(call, message):
    with pytest.raises(ValueError, match=message):
        call()


def test_calibrate_camera_tool_on_a_synthetic_image(tmp_path):
    cv2.imwrite(str(tmp_path / "board.png"), board_image())
    BOARD.save(tmp_path / "board.json")
    out = subprocess.run(
        [sys.executable, str(ROOT / "tools/calibrate_camera.py"), str(tmp_path / "board.json"), str(tmp_path / "board.png"), "--out", str(tmp_path / "cal.json")],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )
    figures = json.loads(out.stdout.strip().splitlines()[-1])
    assert figures["tags_used"] == sorted(BOARD.tags) and figures["n_points"] == 32
    assert figures["rms_px"] < 0.1 and figures["max_mm"] < 0.1
    calibration = PlaneCalibration.load(tmp_path / "cal.json")
    assert 1e3 * np.abs(calibration.map_points(IMAGE_GRID) - CAL.map_points(IMAGE_GRID)).max() <= CALIBRATION_MAX_MM
