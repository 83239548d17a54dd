"""Frame capture: the interface the hardware camera and the simulation's virtual camera share.

A `Frame` is an image with its capture time t (s, on the source's clock) and its
index (0, 1, 2, … in capture order; a gap in the indices of consecutive frames read is
a dropped frame). A `FrameSource` has `read() -> Frame | None` (None: no frame is
available, e.g. the stream ended or the camera delivered nothing) and `close()`.

`VideoCaptureSource` wraps `cv2.VideoCapture` (a device index, a video file or a stream
URL). Its timestamps come from an injectable clock (default `time.monotonic`), read
right after `cv2.VideoCapture.read` returns the frame, so they include the camera's
and the driver's latency; the indices count frames read from the stream.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import cv2
import numpy as np


@dataclass(frozen=True, eq=False)
class Frame:
    """An image (h, w) or (h, w, 3) uint8 captured at time `t` (s), the `index`-th of its source."""

    t: float
    image: np.ndarray
    index: int

    def __post_init__(self) -> None:
        if not math.isfinite(self.t):
            raise ValueError(f"t must be a finite capture time (s), got {self.t}")
        if isinstance(self.index, bool) or not isinstance(self.index, (int, np.integer)) or self.index < 0:
            raise ValueError(f"index must be an integer >= 0, got {self.index!r}")
        image = np.asarray(self.image)
        if image.dtype != np.uint8 or image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3)):
            raise ValueError(f"image must be uint8 (h, w) or (h, w, 3), got dtype {image.dtype} shape {image.shape}")
        object.__setattr__(self, "image", image)


@runtime_checkable
class FrameSource(Protocol):
    """Anything that delivers frames in capture order."""

    def read(self) -> Frame | None: ...

    def close(self) -> None: ...


class VideoCaptureSource:
    """Frames from `cv2.VideoCapture(source)`: a device index, a video file path or a stream URL."""

    def __init__(self, source: int | str, clock: Callable[[], float] = time.monotonic, api: int = cv2.CAP_ANY) -> None:
        self.source = source
        self.clock = clock
        self._capture = cv2.VideoCapture(source, api)
        if not self._capture.isOpened():
            self._capture.release()
            raise OSError(
                f"cv2.VideoCapture could not open {source!r}: check the device index (ls /dev/video*), "
                "the file path or the stream URL, and that no other program holds the camera"
            )
        self._index = 0
        self._t_last = -math.inf

    def read(self) -> Frame | None:
        """The next frame, or None when the source delivered none (end of file, camera error)."""
        ok, image = self._capture.read()
        if not ok or image is None:
            return None
        t = float(self.clock())
        if not t > self._t_last:
            raise RuntimeError(f"the clock went backwards or stood still: {t} s after {self._t_last} s; use a monotonic clock")
        self._t_last = t
        frame = Frame(t, image, self._index)
        self._index += 1
        return frame

    def close(self) -> None:
        self._capture.release()

    def __enter__(self) -> VideoCaptureSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
