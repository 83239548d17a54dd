"""The camera in the loop (docs/ground-truth.md, paper §VI): plant → camera → AprilTag pipeline → controller, each at its own rate.

Time runs on the plant's tick grid, Δ = `plant.control_dt` (s); the command is held
(zero-order hold) between controller calls, the physics steps at its own rate inside
each tick. At tick k (t = k·Δ), in this order:

1. Exposure: when t reaches the next exposure time j / `frame_rate` (so exposures lie
   within one tick after the ideal times), frame j is lost with probability
   `drop_rate` (seeded); otherwise the plant's current state is rendered, Gaussian
   noise of `pixel_noise` grey levels is added, and the tags are detected. The
   detections become available `latency` s after the exposure (the time the
   hardware's pipeline needs from exposure to estimate).
2. Delivery: detections that are available by t reach the estimator in capture order
   (`ArmAngleEstimator.update(t_capture, detections)`).
3. Control, every round(1 / (`control_rate` Δ)) ticks: the estimator's held estimate
   at t (`query(t)`) goes to the control step (`closedloop.step.ControlStep`: u_nom(t),
   the safety filter, admission, and the safety monitor shared with the hardware mode):
   RUN (the filter's u), HOLD (the last command, while the estimate is stale) or VENT
   (u = 0, latched, once the hold has lasted `hold_s`). Until the first valid estimate
   arrives the arm is vented without latching (start-up, as on the hardware:
   `ControlStep.wait`).
4. The plant holds the command for one tick.

The loop records one row per tick (`closedloop.record.Recorder`: q, q̂ in force, the
step in force — u_nom, u_filter, u, ρ_pred and the filter's diagnostics of the last
filter call —, forces, filter time on ticks with a call, NaN elsewhere)
and one row per frame (`FrameLog`: exposure time, whether it was dropped, the tags
seen, the true q at exposure and the q the frame gave, wall time of render, detection
and estimation).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from closedloop.monitor import SafetyFlags, SafetyMonitor
from closedloop.record import LiveRows, Recorder
from closedloop.step import ControlStep, StepRecord
from controllers.model.safe_set import ForceSafeSet
from controllers.contract.safety_filter import Estimate
from perception.detect import Detection, TagDetector
from perception.estimator import ArmAngleEstimator, ArmEstimate
from perception.tracking import TrackingTagDetector
from softcbf_mj.loops.loop import Series, plant_columns, plant_series, plant_values
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.outputs.progress import Progress
from vocabulary.settings import default

FRAME_UNITS = {
    "t": "s (exposure)",
    "dropped": "bool",
    "complete": "bool (every segment tag seen, the estimator took the frame)",
    "n_tags": "1",
    "q_true": "rad (at exposure)",
    "q_camera": "rad (NaN: incomplete frame)",
    "render_ms": "ms (wall)",
    "detect_ms": "ms (wall)",
    "estimate_ms": "ms (wall, the estimator's update on delivery)",
}


@dataclass(frozen=True)
class CameraTiming:
    """Rates and imperfections of the camera path (defaults: the paper's hardware, docs/ground-truth.md; each field is
    the setting of its name, whose default is the vocabulary's, `default(name, "camera_loop")`).

    frame_rate (Hz), control_rate (Hz), latency (s, exposure → detections available),
    drop_rate (fraction of frames lost, [0, 1)), pixel_noise (grey levels, std of
    Gaussian image noise), hold_s (s, how long the safety monitor holds the last
    command on a stale estimate before it vents).
    """

    frame_rate: float = default("frame_rate", "camera_loop")
    control_rate: float = default("control_rate", "camera_loop")
    latency: float = default("latency", "camera_loop")
    drop_rate: float = default("drop_rate", "camera_loop")
    pixel_noise: float = default("pixel_noise", "camera_loop")
    hold_s: float = default("hold_s", "camera_loop")

    def __post_init__(self) -> None:
        for name in ("frame_rate", "control_rate"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be finite and > 0 Hz, got {value}")
        if not (math.isfinite(self.latency) and self.latency >= 0):
            raise ValueError(f"latency must be finite and >= 0 s, got {self.latency}")
        if not 0 <= self.drop_rate < 1:
            raise ValueError(f"drop_rate must be in [0, 1), got {self.drop_rate}")
        if not (math.isfinite(self.pixel_noise) and self.pixel_noise >= 0):
            raise ValueError(f"pixel_noise must be finite and >= 0 grey levels, got {self.pixel_noise}")
        if not (math.isfinite(self.hold_s) and self.hold_s >= 0):
            raise ValueError(f"hold_s must be finite and >= 0 s, got {self.hold_s}")

    def monitor(self, n_segments: int) -> SafetyMonitor:
        """The safety monitor of this timing: it holds for `hold_s` before it vents."""
        return SafetyMonitor(n_segments, hold_s=self.hold_s)

    def ticks_per_control(self, tick: float) -> int:
        """Control period in plant ticks; refuses a period that is not a whole number of ticks."""
        ratio = 1.0 / (self.control_rate * tick)
        ticks = int(round(ratio))
        if ticks < 1 or abs(ratio - ticks) > 1e-9 * ratio:
            raise ValueError(
                f"the control period 1/{self.control_rate:g} Hz must be a whole number of plant ticks of {tick:g} s "
                f"(got {ratio:.6g}); choose a control_rate that divides 1/{tick:g} Hz or a smaller tick"
            )
        return ticks


class FrameLog:
    """Per-frame records (keys and units: FRAME_UNITS), appended as frames are taken."""

    def __init__(self, n_segments: int) -> None:
        self.n_segments = n_segments
        self._rows: list[dict] = []

    def add(self, t: float, q_true: np.ndarray, dropped: bool = False, n_tags: int = 0,
            render_ms: float = 0.0, detect_ms: float = 0.0) -> int:
        """Append a frame exposed at t (s); return its row."""
        self._rows.append({"t": t, "dropped": dropped, "complete": False, "n_tags": n_tags, "q_true": q_true.copy(),
                           "q_camera": np.full(self.n_segments, np.nan), "render_ms": render_ms, "detect_ms": detect_ms,
                           "estimate_ms": 0.0})
        return len(self._rows) - 1

    def delivered(self, row: int, estimate_ms: float, q_camera: np.ndarray | None) -> None:
        """Frame `row` reached the estimator, which took estimate_ms; q_camera (rad) if it was complete."""
        self._rows[row]["estimate_ms"] = estimate_ms
        if q_camera is not None:
            self._rows[row]["complete"] = True
            self._rows[row]["q_camera"] = np.array(q_camera, dtype=float)

    def columns(self) -> dict[str, np.ndarray]:
        n = self.n_segments
        shapes = {"q_true": (0, n), "q_camera": (0, n)}
        return {key: np.array([r[key] for r in self._rows]) if self._rows else np.zeros(shapes.get(key, (0,)))
                for key in FRAME_UNITS}


FrameHook = Callable[[int, float, np.ndarray, list[Detection]], None]


@dataclass
class CameraPath:
    """The camera path's state during a run: its timing and noise generator, the frames taken, the detections
    in flight (ready time s, capture time s, frame row, detections) in capture order, the next frame's index."""

    timing: CameraTiming
    rng: np.random.Generator
    frames: FrameLog
    pending: list[tuple[float, float, int, list[Detection]]] = field(default_factory=list)
    next_frame: int = 0


@dataclass
class ControlCalls:
    """The controller calls of a run: whether the loop has started (a valid, fresh estimate arrived) and
    (t s, age of the estimate used s, action) per call."""

    started: bool = False
    calls: list[tuple[float, float, str]] = field(default_factory=list)

    def log(self) -> dict[str, np.ndarray]:
        """The per-call log of `run_camera_loop`."""
        call_t, call_age, call_action = zip(*self.calls) if self.calls else ((), (), ())
        return {"t": np.array(call_t, dtype=float), "age_s": np.array(call_age, dtype=float),
                "action": np.array(call_action, dtype="U4")}


def expose(path: CameraPath, t: float, q: np.ndarray, tick: float, render: Callable[[], np.ndarray],
           detector: TagDetector | TrackingTagDetector, frame_hook: FrameHook | None) -> None:
    """Step 1 (module docstring): at tick time t (s), with the true q (rad), take the next frame if its exposure
    time has come: dropped with probability drop_rate, else rendered, noised, detected and put in flight."""
    timing, clock = path.timing, time.perf_counter
    if not t >= path.next_frame / timing.frame_rate - 1e-9 * tick:
        return
    j = path.next_frame
    path.next_frame += 1
    if timing.drop_rate > 0 and path.rng.random() < timing.drop_rate:
        path.frames.add(t, q, dropped=True)
        return
    c0 = clock()
    image = render()
    c1 = clock()
    if timing.pixel_noise > 0:
        noisy = image.astype(np.float32) + path.rng.normal(0.0, timing.pixel_noise, image.shape).astype(np.float32)
        image = np.clip(noisy, 0, 255).astype(np.uint8)
    detections = detector.detect(image)
    c2 = clock()
    row = path.frames.add(t, q, n_tags=len(detections), render_ms=(c1 - c0) * 1e3, detect_ms=(c2 - c1) * 1e3)
    path.pending.append((t + timing.latency, t, row, detections))
    if frame_hook is not None:
        frame_hook(j, t, image, detections)


def deliver(path: CameraPath, t: float, tick: float, estimator: ArmAngleEstimator) -> None:
    """Step 2 (module docstring): the detections available by t (s) reach the estimator, in capture order."""
    while path.pending and path.pending[0][0] <= t + 1e-9 * tick:
        _, t_capture, row, detections = path.pending.pop(0)
        c0 = time.perf_counter()
        est = estimator.update(t_capture, detections)
        complete = est.valid and est.t == t_capture and est.frames_missed == 0
        path.frames.delivered(row, (time.perf_counter() - c0) * 1e3, est.q if complete else None)


def control(calls: ControlCalls, step: ControlStep, est: ArmEstimate, t: float, n: int) -> StepRecord:
    """Step 3 (module docstring): one controller call at t (s) on the held estimate `est`: vented without
    latching until the first valid, fresh estimate (`ControlStep.wait`), then the control step."""
    calls.started = calls.started or (est.valid and not est.stale)
    if not calls.started:
        record = step.wait(Estimate(t, np.zeros(n), np.zeros(n), t))
        calls.calls.append((t, math.nan, "wait"))
        return record
    q_hat, qd_hat = (est.q, est.qd) if est.valid else (np.zeros(n), np.zeros(n))
    record = step(Estimate(t, q_hat, qd_hat, est.t), SafetyFlags(perception_stale=est.stale))
    calls.calls.append((t, est.age_s, record.action.value))
    return record


def run_camera_loop(
    plant: MujocoPlant,
    render: Callable[[], np.ndarray],
    detector: TagDetector | TrackingTagDetector,
    estimator: ArmAngleEstimator,
    step: ControlStep,
    safe_set: ForceSafeSet,
    duration: float,
    q0: np.ndarray,
    timing: CameraTiming = CameraTiming(),
    seed: int = 0,
    frame_hook: FrameHook | None = None,
    progress: Progress | None = None,
    live: LiveRows | None = None,
) -> tuple[Series, dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Run for `duration` s from rest at q0; return ((per-tick time series, units), per-frame log, per-call log).

    `step`'s monitor holds for `timing.hold_s` (`CameraTiming.monitor`); `safe_set` is the
    controller's (ρ_meas). The per-call log has, for each controller tick: `t` (s),
    `age_s` (age of the estimate used, s; NaN before the first) and `action` ("wait": no
    estimate yet, vented; "run", "hold", "vent": the safety monitor's decision).

    `render()` returns the camera image (H, W, 3) uint8 of the plant's current state;
    `frame_hook(j, t, image, detections)` sees every frame that was taken (e.g. to save
    some). The estimator must be fresh (no frame yet). `live` is sent the rows recorded so far
    as in `softcbf_mj.loops.loop.run_closed_loop`. Each tick runs `expose`, `deliver` and, on a
    controller tick, `control`, then the plant holds the command for the tick.
    """
    tick = plant.control_dt
    n_ticks = int(round(duration / tick))
    if n_ticks < 1:
        raise ValueError(f"duration must cover at least one plant tick ({tick} s), got {duration}")
    per_control = timing.ticks_per_control(tick)
    n = plant.n_segments
    recorder = Recorder(n_ticks, n, plant_columns(n, safe_set.n_facets))
    path = CameraPath(timing, np.random.default_rng(seed), FrameLog(n))
    calls = ControlCalls()
    record: StepRecord | None = None
    step.reset()
    state = plant.reset(q0)
    n_rows = n_ticks
    for k in range(n_ticks):
        t = state.t
        expose(path, t, state.q, tick, render, detector, frame_hook)
        deliver(path, t, tick, estimator)
        est = estimator.query(t)
        called = k % per_control == 0
        if called:
            record = control(calls, step, est, t, n)
        recorder.record(k, record, called, plant_values(state, np.asarray(est.q), np.asarray(est.qd)), extras=state.extras)
        if step.stopped:  # a filter fault has vented: the run ends on this tick (closedloop.step)
            n_rows = k + 1
            break
        state = plant.step(record.u)
        if progress is not None and k % 500 == 0:
            progress.update(k)
        if live is not None and k % live.period_steps == 0:
            live.send(recorder, k + 1)
    if live is not None:
        live.send(recorder, n_rows, force=True)
    if progress is not None:
        progress.close()
    return plant_series(recorder, safe_set, n_rows), path.frames.columns(), calls.log()
