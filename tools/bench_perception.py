"""Benchmark the perception pipeline on synthetic 1280 × 720 frames: detection + estimation.

    .venv/bin/python tools/bench_perception.py [--frames 30] [--backends opencv,pupil]

Each frame shows a two-segment arm in a random pose (q_i uniform in ±40°, base angle in
±10°, 30 mm tags, the default overhead camera of `perception.synthetic`), rendered
under three image conditions: sharp (as MuJoCo renders), blur σ 1 px + noise σ 3 grey
levels, and blur σ 2 px + noise σ 8 (a poor webcam). For every backend it prints the
detection rate, the corner error against the exact corners (rms and max px), the q error
(max degrees, over frames where every tag was found), and the time per frame of
`TagDetector.detect` and of `ArmAngleEstimator.update` (median and p90), and the dense
scene's detection rate and corner error. The pupil
backend is measured only when pupil-apriltags is installed. Ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import platform
import time

import cv2
import numpy as np

from perception.detect import BACKENDS, TagDetector
from perception.estimator import ArmAngleEstimator, wrap_angle
from perception.plane import PlaneCalibration, tag_corners_on_plane
from perception.synthetic import arm_tag_poses, overhead_calibration, render_tags
from timing import emit

TAG_SIZE = 0.03  # m
CONDITIONS = {"sharp": (0.0, 0.0), "blur1_noise3": (1.0, 3.0), "blur2_noise8": (2.0, 8.0)}
DENSE_TAGS = 8  # tags of the dense scene: a 4 × 2 grid over the view, jittered, at random angles


def dense_tags(rng: np.random.Generator) -> dict[int, tuple[float, float, float]]:
    return {
        i: (0.122 + 0.15 * (i % 4 - 1.5) + rng.uniform(-0.03, 0.03), 0.15 * (i // 4 - 0.5) + rng.uniform(-0.03, 0.03), rng.uniform(-math.pi, math.pi))
        for i in range(DENSE_TAGS)
    }


def detection_errors(detections: list, tags: dict, calibration: PlaneCalibration) -> list[float]:
    """Distances px of each detected corner from its exact image."""
    errors = []
    for d in detections:
        exact = calibration.map_to_image(tag_corners_on_plane(*tags[d.tag_id], TAG_SIZE))
        errors.extend(np.linalg.norm(d.corners - exact, axis=1))
    return errors


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=30, help="frames per condition")
    parser.add_argument("--backends", default=",".join(BACKENDS), help="comma-separated backends")
    args = parser.parse_args()
    backends = [b for b in args.backends.split(",") if b != "pupil" or importlib.util.find_spec("pupil_apriltags")]
    cv2.setNumThreads(1)
    calibration = overhead_calibration()
    H_img_from_plane = np.linalg.inv(calibration.H)
    rng = np.random.default_rng(0)
    results: dict[str, dict[str, dict[str, float]]] = {b: {} for b in backends}
    for condition, (blur, noise) in CONDITIONS.items():
        scenes = []
        for _ in range(args.frames):
            q, theta0 = rng.uniform(-0.7, 0.7, 2), rng.uniform(-0.17, 0.17)
            tags = arm_tag_poses(q, theta0)
            image = render_tags(H_img_from_plane, tags, TAG_SIZE, blur_sigma_px=blur, noise_sigma=noise, rng=rng)
            scenes.append((q, tags, image))
        dense = []
        for _ in range(args.frames):
            tags = dense_tags(rng)
            dense.append((tags, render_tags(H_img_from_plane, tags, TAG_SIZE, blur_sigma_px=blur, noise_sigma=noise, rng=rng)))
        for backend in backends:
            detector = TagDetector(backend, tag_ids=range(3))
            found = total = 0
            corner_errors, q_errors, detect_ms, update_us = [], [], [], []
            for k, (q, tags, image) in enumerate(scenes):
                estimator = ArmAngleEstimator(2, calibration, TAG_SIZE)
                start = time.perf_counter()
                detections = detector.detect(image)
                detect_ms.append(1e3 * (time.perf_counter() - start))
                start = time.perf_counter()
                estimate = estimator.update(float(k), detections)
                update_us.append(1e6 * (time.perf_counter() - start))
                total += len(tags)
                found += len(detections)
                corner_errors.extend(detection_errors(detections, tags, calibration))
                if estimate.valid:
                    q_errors.extend(np.abs(np.degrees(wrap_angle(estimate.q - q))))
            dense_detector = TagDetector(backend, tag_ids=range(DENSE_TAGS))
            dense_found, dense_errors = 0, []
            for tags, image in dense:
                detections = dense_detector.detect(image)
                dense_found += len(detections)
                dense_errors.extend(detection_errors(detections, tags, calibration))
            figures = {
                "detection_rate": found / total,
                "corner_rms_px": float(np.sqrt(np.mean(np.square(corner_errors)))),
                "corner_max_px": float(np.max(corner_errors)),
                "q_err_max_deg": float(np.max(q_errors)) if q_errors else math.nan,
                "detect_ms_median": float(np.median(detect_ms)),
                "detect_ms_p90": float(np.percentile(detect_ms, 90)),
                "update_us_median": float(np.median(update_us)),
                "update_us_p90": float(np.percentile(update_us, 90)),
                "dense_detection_rate": dense_found / (DENSE_TAGS * len(dense)),
                "dense_corner_rms_px": float(np.sqrt(np.mean(np.square(dense_errors)))),
            }
            results[backend][condition] = figures
            print(
                f"{backend:6s} {condition:13s} detected {100 * figures['detection_rate']:5.1f} %  "
                f"corner rms {figures['corner_rms_px']:.3f} max {figures['corner_max_px']:.3f} px  "
                f"q err max {figures['q_err_max_deg']:.3f} deg  detect {figures['detect_ms_median']:.1f} / "
                f"{figures['detect_ms_p90']:.1f} ms  update {figures['update_us_median']:.0f} / {figures['update_us_p90']:.0f} us  "
                f"dense: detected {100 * figures['dense_detection_rate']:5.1f} % corner rms {figures['dense_corner_rms_px']:.3f} px",
                flush=True,
            )
    emit({"frames": args.frames, "opencv": cv2.__version__, "machine": platform.machine(), "results": results})


if __name__ == "__main__":
    main()
