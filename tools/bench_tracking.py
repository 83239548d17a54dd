"""Benchmark window tracking against full-frame AprilTag detection on a moving arm, 1280 × 720 frames.

    .venv/bin/python tools/bench_tracking.py [--frames 60] [--seed 0]

Each condition (sharp, as MuJoCo renders; blur σ 1 px + noise σ 3 grey levels) is a
sequence of synthetic frames (`perception.synthetic`, default overhead camera, 30 mm
tags ≈ 42 px) of the two-segment arm at 12.8 frames/s, every segment turning at 1 rad/s
(the real arm's upper bound), each reversing direction with probability 0.1 per frame,
within ±60°; base angle random in ±10°. Per frame, interleaved so that machine load hits
all alike, it times (one OpenCV thread):

- full frame, ArUco's default threshold windows (3, 23, 10) px, with and without the
  edge refinement ("before" the tuning);
- full frame, the tuned default windows (`perception.detect.ARUCO_THRESHOLD_WINDOWS_PX`),
  with and without the refinement;
- `TrackingTagDetector` on the tuned detector (default margin, no periodic full frame).

It prints, per condition and detector, detection rate and median / p90 time per frame,
the refinement's share (refined − unrefined), the tracking's full-frame fraction and
window area, and the largest corner difference between tracking and the tuned full frame
(0 expected). Ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import math
import platform

import cv2
import numpy as np

from perception.detect import ARUCO_THRESHOLD_WINDOWS_PX, TagDetector
from perception.synthetic import arm_tag_poses, overhead_calibration, render_tags
from perception.tags import arm_tag_ids
from perception.tracking import DEFAULT_WINDOW_MARGIN_PX, TrackingTagDetector
from timing import call_us, emit

TAG_SIZE = 0.03  # m
FRAME_RATE = 12.8  # Hz
SEGMENT_RATE = 1.0  # rad/s per segment
Q_LIMIT = math.radians(60.0)
REVERSAL_PROBABILITY = 0.1  # per frame and segment
CONDITIONS = {"sharp": (0.0, 0.0), "blur1_noise3": (1.0, 3.0)}
ARUCO_DEFAULT_WINDOWS_PX = (3, 23, 10)
IDS = arm_tag_ids(2)


def arm_sequence(rng: np.random.Generator, frames: int) -> tuple[float, list[np.ndarray]]:
    """Base angle and q (2,) rad per frame of an arm whose segments turn at ±SEGMENT_RATE."""
    q = rng.uniform(-Q_LIMIT, Q_LIMIT, 2)
    direction = rng.choice([-1.0, 1.0], 2)
    sequence = []
    for _ in range(frames):
        sequence.append(q.copy())
        direction[rng.random(2) < REVERSAL_PROBABILITY] *= -1.0
        step = q + direction * SEGMENT_RATE / FRAME_RATE
        direction[np.abs(step) > Q_LIMIT] *= -1.0
        q = q + direction * SEGMENT_RATE / FRAME_RATE
    return rng.uniform(-0.17, 0.17), sequence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--frames", type=int, default=60, help="frames per condition")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    cv2.setNumThreads(1)
    H_img_from_plane = np.linalg.inv(overhead_calibration().H)
    rng = np.random.default_rng(args.seed)
    results: dict[str, dict] = {}
    for condition, (blur, noise) in CONDITIONS.items():
        base, sequence = arm_sequence(rng, args.frames)
        images = [
            render_tags(H_img_from_plane, arm_tag_poses(q, base), TAG_SIZE, blur_sigma_px=blur, noise_sigma=noise, rng=rng)
            for q in sequence
        ]
        before = {"threshold_windows_px": ARUCO_DEFAULT_WINDOWS_PX}
        detectors = {
            "full_aruco_default": TagDetector(tag_ids=IDS, **before).detect,
            "full_aruco_default_unrefined": TagDetector(tag_ids=IDS, subpixel=False, **before).detect,
            "full_tuned": TagDetector(tag_ids=IDS).detect,
            "full_tuned_unrefined": TagDetector(tag_ids=IDS, subpixel=False).detect,
        }
        tracking = TrackingTagDetector(TagDetector(tag_ids=IDS), IDS)
        detectors["tracking"] = tracking.detect
        times: dict[str, list[float]] = {name: [] for name in detectors}
        found = {name: 0 for name in detectors}
        corner_diff, window_px = 0.0, []
        for image in images:
            per_frame = {}
            for name, detect in detectors.items():
                per_frame[name], us = call_us(lambda: detect(image))
                ms = us / 1e3
                times[name].append(ms)
                found[name] += len({d.tag_id for d in per_frame[name]})
            window_px.append(sum((x1 - x0) * (y1 - y0) for x0, y0, x1, y1 in tracking.last_windows))
            reference = {d.tag_id: d.corners for d in per_frame["full_tuned"]}
            for d in per_frame["tracking"]:
                diff = float(np.abs(d.corners - reference[d.tag_id]).max()) if d.tag_id in reference else math.inf
                corner_diff = max(corner_diff, diff)
        figures = {
            name: {
                "detection_rate": found[name] / (len(IDS) * len(images)),
                "ms_median": float(np.median(times[name])),
                "ms_p90": float(np.percentile(times[name], 90)),
            }
            for name in detectors
        }
        figures["refine_ms_median"] = float(np.median(np.subtract(times["full_tuned"], times["full_tuned_unrefined"])))
        figures["tracking_full_frame_fraction"] = tracking.full_frames / tracking.calls
        figures["tracking_window_misses"] = tracking.window_misses
        figures["tracking_window_area_fraction_median"] = float(np.median(window_px)) / images[0].size
        figures["tracking_corner_diff_max_px"] = corner_diff
        figures["speedup_tracking_vs_full_aruco_default"] = figures["full_aruco_default"]["ms_median"] / figures["tracking"]["ms_median"]
        results[condition] = figures
        for name in detectors:
            f = figures[name]
            print(f"{condition:13s} {name:29s} detected {100 * f['detection_rate']:5.1f} %  {f['ms_median']:5.1f} / {f['ms_p90']:5.1f} ms (median / p90)")
        print(
            f"{condition:13s} refinement {figures['refine_ms_median']:.1f} ms/frame (median); tracking: full frames "
            f"{100 * figures['tracking_full_frame_fraction']:.1f} %, window misses {tracking.window_misses}, window area "
            f"{100 * figures['tracking_window_area_fraction_median']:.1f} % of the frame, corners vs full frame "
            f"{corner_diff:.3g} px max, {figures['speedup_tracking_vs_full_aruco_default']:.1f}x faster than before",
            flush=True,
        )
    emit({
        "frames": args.frames, "seed": args.seed, "frame_rate_hz": FRAME_RATE, "segment_rate_rad_s": SEGMENT_RATE,
        "window_margin_px": DEFAULT_WINDOW_MARGIN_PX, "threshold_windows_px": list(ARUCO_THRESHOLD_WINDOWS_PX),
        "opencv": cv2.__version__, "machine": platform.machine(), "results": results,
    })


if __name__ == "__main__":
    main()
