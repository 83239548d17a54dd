"""A virtual overhead camera: MuJoCo renders of the emulated arm through the capture interface.

`VirtualCamera(emulator, fps, width, height)` is a `perception.capture.FrameSource`, as a
real camera's `VideoCaptureSource` is, so the hardware loop cannot tell them apart.
Frame slots fall at t_i = t_first + i / fps on the emulator's clock (t_first: the first
`read()`); `read()` waits for the next slot that has not passed, takes the emulator's
state then (`ValveEmulator.snapshot`: its clock time and qpos), renders the model's
`camera` (`softcbf_mj.camera.render.OffscreenRenderer`) and returns

    Frame(t = clock time of the rendered state (s), image = BGR uint8 (height, width, 3), index = i)

BGR, as OpenCV's VideoCapture delivers. The timestamp is the capture time, so the render
and detection times are latency the estimator sees, as with a camera. Slots missed while
the reader was busy are dropped (a gap in `index`; counted in `dropped`), as a camera
driver drops frames nobody reads.

`blackout = True` covers the lens: frames keep coming at the same times, all black (no
tags), until it is set back to False — the perception blackout of the tests.

Rendering is the costly part (OSMesa; the generated model already renders without
shadows and multisampling, see models/softcbf_arm/README.md "Rendering").
The GL context is made on the first `read()`, in the thread that reads.
`calibration()` is the camera's exact image-to-plane map (`render.ground_truth_calibration`).
"""

from __future__ import annotations

import math
import threading

import mujoco
import numpy as np

from perception.capture import Frame
from perception.plane import PlaneCalibration
from softcbf_mj.camera.render import OffscreenRenderer, ground_truth_calibration, image_size
from softcbf_mj.emulator.valve_emulator import ValveEmulator
from vocabulary.settings import setting

DEFAULT_FPS = setting("frame_rate").default  # docs/ground-truth.md: the hardware camera's ~12.8 frames/s (the vocabulary's)


class VirtualCamera:
    """Renders the emulator's arm at `fps` frames/s as `width` × `height` BGR frames (see the module docstring)."""

    def __init__(self, emulator: ValveEmulator, fps: float = DEFAULT_FPS, width: int | None = None,
                 height: int | None = None, camera: str = "overhead") -> None:
        if not (math.isfinite(fps) and fps > 0):
            raise ValueError(f"fps must be a finite frame rate > 0 /s, got {fps}")
        self.emulator = emulator
        self.model = emulator.plant.model
        self.camera = camera
        self.width, self.height = image_size(self.model, camera, width, height)
        self.fps = float(fps)
        self.blackout = False
        self.dropped = 0
        self._data = mujoco.MjData(self.model)
        self._renderer: OffscreenRenderer | None = None
        self._t_first: float | None = None
        self._next = 0
        self._closed = threading.Event()

    def calibration(self) -> PlaneCalibration:
        """The exact map from this camera's image pixels to the tags' plane (m)."""
        mujoco.mj_forward(self.model, self._data)
        return ground_truth_calibration(self.model, self._data, self.camera, self.width, self.height)

    def read(self) -> Frame | None:
        """The next frame (waits for its slot); None once closed."""
        if self._closed.is_set():
            return None
        clock = self.emulator.clock
        if self._t_first is None:
            self._t_first = clock()
        slot = max(self._next, math.ceil((clock() - self._t_first) * self.fps - 1e-9))
        self.dropped += slot - self._next
        if self._closed.wait(max(0.0, self._t_first + slot / self.fps - clock())):
            return None
        self._next = slot + 1
        t, qpos = self.emulator.snapshot()
        if self.blackout:
            return Frame(t, np.zeros((self.height, self.width, 3), dtype=np.uint8), slot)
        if self._renderer is None:
            self._renderer = OffscreenRenderer(self.model, self.camera, self.width, self.height)
        self._data.qpos[:] = qpos
        mujoco.mj_kinematics(self.model, self._data)
        mujoco.mj_camlight(self.model, self._data)
        return Frame(t, np.ascontiguousarray(self._renderer.render(self._data)[:, :, ::-1]), slot)

    def close(self) -> None:
        """Stop delivering frames (a waiting `read()` returns None) and free the GL context."""
        self._closed.set()
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
