"""Calibrate the overhead camera's image-to-plane map from images of a tag board.

    .venv/bin/python tools/calibrate_camera.py BOARD.json IMAGE [IMAGE ...] --out CALIBRATION.json

BOARD.json is a `perception.plane.TagBoard` ({"tag_size_m": s, "tags": [{"id", "x_m",
"y_m", "angle_rad"}, ...]}, the tags' true poses on the plane the arm's tags lie in).
The images come from the fixed camera; the corners of every board tag detected exactly
once in an image are pooled over all images and one homography is fitted to them
(`PlaneCalibration.fit`). Prints each image's tags (detected or missing), each tag's
residual and the reprojection error in px and mm, writes the calibration JSON
(`PlaneCalibration.load` reads it; the fit's figures are kept beside H), and ends with
one line of JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from perception.detect import BACKENDS, TagDetector
from perception.plane import PlaneCalibration, TagBoard, board_correspondences


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("board", type=Path, help="tag board JSON (perception.plane.TagBoard)")
    parser.add_argument("images", type=Path, nargs="+", help="images of the board from the fixed camera")
    parser.add_argument("--out", type=Path, required=True, help="calibration JSON to write")
    parser.add_argument("--backend", choices=BACKENDS, default="opencv", help="tag detector backend")
    parser.add_argument("--min-tags", type=int, default=2, help="distinct board tags needed over all images")
    args = parser.parse_args(argv)

    board = TagBoard.load(args.board)
    detector = TagDetector(args.backend, tag_ids=board.tags)
    image_points, plane_points, blocks = [], [], []  # blocks: (image, tag id) of each 4 corners
    for path in args.images:
        image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        if image is None:
            parser.error(f"cannot read image {path}: check the path and that it is a PNG/JPEG/BMP file")
        image_px, plane_m, ids = board_correspondences(detector.detect(image), board)
        missing = sorted(set(board.tags) - set(ids))
        print(f"{path}: {image.shape[1]}x{image.shape[0]} px, tags used {list(ids)}, missing or duplicated {missing}")
        image_points.append(image_px)
        plane_points.append(plane_m)
        blocks.extend((path.name, i) for i in ids)
    tags_used = {tag_id for _, tag_id in blocks}
    if len(tags_used) < args.min_tags:
        parser.error(f"only {len(tags_used)} board tags were detected ({sorted(tags_used)}), need --min-tags {args.min_tags}")
    image_px = np.concatenate(image_points)
    plane_m = np.concatenate(plane_points)
    calibration = PlaneCalibration.fit(image_px, plane_m)

    residual_mm = 1e3 * np.linalg.norm(calibration.map_points(image_px) - plane_m, axis=1)
    for k, (name, tag_id) in enumerate(blocks):
        corners_mm = residual_mm[4 * k : 4 * k + 4]
        print(f"  {name} tag {tag_id:3d}: corner residual mean {corners_mm.mean():.3f} mm, max {corners_mm.max():.3f} mm")
    error = calibration.reprojection_error(image_px, plane_m)
    print(
        f"reprojection error over {error.n_points} corners: rms {error.rms_px:.3f} px ({1e3 * error.rms_m:.3f} mm), "
        f"max {error.max_px:.3f} px ({1e3 * error.max_m:.3f} mm)"
    )
    figures = {
        "calibration": str(args.out),
        "images": len(args.images),
        "tags_used": sorted(tags_used),
        "n_points": error.n_points,
        "rms_px": error.rms_px,
        "max_px": error.max_px,
        "rms_mm": 1e3 * error.rms_m,
        "max_mm": 1e3 * error.max_m,
    }
    args.out.write_text(json.dumps({**calibration.to_dict(), "fit": figures}, indent=2) + "\n", encoding="utf-8")
    print(f"wrote {args.out}")
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
