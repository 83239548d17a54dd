"""AprilTag 36h11 markers: the family, tag images, and which tag sits where on the arm.

A 36h11 tag is an 8 × 8 grid of cells: 6 × 6 data cells inside a one-cell black
border. Its *size* (m) is the edge of that black square, the convention of the AprilTag
library; printed and textured tags add a white quiet zone of `QUIET_CELLS` cells on
every side, so a texture spans size · (8 + 2·QUIET_CELLS) / 8.

Layout on the arm (docs/ground-truth.md, as on the hardware): tag 0 on the base, tag i on the end of
segment i (i = 1..N). A tag's image x axis (left → right when the tag is upright) lies
along the body's x axis, its image "up" along the body's +y axis.
"""

from __future__ import annotations

import cv2
import numpy as np

DICTIONARY_ID = cv2.aruco.DICT_APRILTAG_36h11
TAG_CELLS = 8  # black square, in cells: 6 data + 2 border
QUIET_CELLS = 1  # white margin on each side of the black square, in cells
BASE_TAG_ID = 0


def dictionary() -> cv2.aruco.Dictionary:
    """OpenCV's AprilTag 36h11 dictionary (587 tags)."""
    return cv2.aruco.getPredefinedDictionary(DICTIONARY_ID)


def arm_tag_ids(n_segments: int) -> tuple[int, ...]:
    """Tag ids of the base and of each segment end: (0, 1, …, N)."""
    if n_segments < 1:
        raise ValueError(f"n_segments must be >= 1, got {n_segments}")
    return tuple(range(BASE_TAG_ID, BASE_TAG_ID + n_segments + 1))


def textured_size(tag_size: float) -> float:
    """Edge (m) of a tag's texture including the quiet zone, for a black square of `tag_size` m."""
    if not tag_size > 0:
        raise ValueError(f"tag_size must be > 0 m, got {tag_size}")
    return tag_size * (TAG_CELLS + 2 * QUIET_CELLS) / TAG_CELLS


def tag_image(tag_id: int, cell_px: int = 16) -> np.ndarray:
    """The tag with its white quiet zone as a uint8 grey image of (8 + 2·QUIET_CELLS)·cell_px square pixels."""
    n_tags = dictionary().bytesList.shape[0]
    if not 0 <= tag_id < n_tags:
        raise ValueError(f"tag_id must be in [0, {n_tags}) for 36h11, got {tag_id}")
    if cell_px < 1:
        raise ValueError(f"cell_px must be >= 1, got {cell_px}")
    marker = cv2.aruco.generateImageMarker(dictionary(), tag_id, TAG_CELLS * cell_px, borderBits=1)
    pad = QUIET_CELLS * cell_px
    return cv2.copyMakeBorder(marker, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
