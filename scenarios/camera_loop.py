"""Scenario `camera_loop`: the paper's hardware experiment (Table II) in MuJoCo, the controller fed by the camera.

The ground truth is `MujocoPlant` as in `mujoco_contact` (the discretised reference rod
and the paper's plate), by default with the coarser rod of the hardware emulator
(`CAMERA_LINKS_PER_SEGMENT` = 5 links at `CAMERA_PHYSICS_DT` = 0.2 ms; ≈ 1 mN of plate
force from the 10-link rod) and a plant tick of 2 ms (exposures, deliveries and the
controller fall on it; the time series are logged at it). The controller under test sees the arm only through the
overhead camera: MuJoCo's offscreen renders of the arm's AprilTags go through the
hardware's pipeline (`perception`: detection, image-to-plane map, angles from tag
orientations, q̇ by finite differences), with the hardware's timing
(`softcbf_mj.loops.camera_loop`: 12.8 frames/s, a `latency` from exposure to estimate, the
CBF filter at 10 Hz with zero-order hold, and the hardware's safe action — hold, then
vent — when the estimate goes stale). Tunings default to the paper's hardware ones:
None, HW-Low (γ = 100) and HW-High (γ = 10).

Tags are detected in windows around their last positions (`perception.tracking`, the
same corners as a full-frame detection; `tracking=False` detects in the whole frame).
The image-to-plane map comes from `calibration`: "board" (default, as on the hardware:
the calibration scene's tag board is rendered once and `perception.plane.calibrate`
fits the map), "truth" (the exact map of MuJoCo's pinhole camera) or a JSON file
written by tools/calibrate_camera.py.

Per run, besides the docs/run-outputs.md fields (ρ_meas from the plate's spring force) and the
contact figures of `mujoco_contact`, summary.json holds the perception figures: q error
of complete frames against the true q at exposure (RMS and max, rad), detection rate
(complete frames / frames taken), frames dropped, render, detection and estimation wall time per
frame (median, ms), and the loop latency: the age of the estimate at the controller's
calls (capture → command, mean and max, s). Time series: the tick-rate series of
`mujoco_contact` plus one per-frame series `<run>_frames.npz` (`FRAME_UNITS`); a few
frames with their detections go to frames/<run>/ (format: softcbf_mj.outputs.runio).

The spec (`CameraLoop`, scenarios.spec) holds `mujoco_contact`'s sections (`run`, `filter`,
`nominal`, `model`, `arm`, `plate`: the same ground truth, softcbf_mj.physics.ground_truth; `damping_scale`
multiplies the damping of both arms, so the arm's time constants d_i/k_i scale with it: the
operating-envelope study, studies/hardware_envelope.toml), the `camera` section and its own
`assumed_plate_stiffness` (N/m), `assumed_tau_p` (s) and `control_rate` (Hz).

Imports: MuJoCo, OpenCV and the perception pipeline are imported inside the functions that
check or run the scenario, not at load, so that registering it and reading its parameters
(`softcbf list`, `softcbf run NAME --help`) stay cheap (tests/test_cli_lazy.py). The
image size's bound is the render's resolution (`softcbf_mj.physics.mjcf.CAMERA_RESOLUTION`),
which is the scenario's default width and height (tests/test_setting_defaults.py holds them equal).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from controllers.model.safe_set import ForceSafeSet
from controllers.contract.safety_filter import FilterContext
from scenarios import register
from scenarios.common import (
    Controller, ControllerRun, check_choice, check_controller, control_step, controller_row, existing_file,
    filter_enabled, initial_configuration, live_run, read_parameter_file, save_run, scene_record, stop_after,
)
from scenarios.spec import Camera, Filter, Model, Nominal, Plate, Run, TrueArm, scenario_spec
from softcbf_mj.physics.ground_truth import Truth, build_truth, check_true_arm
from softcbf_mj.loops.loop import check_duration
from softcbf_mj.outputs.certified_truth import certified_truth_figures
from softcbf_mj.outputs.metrics import contact_figures, plate_figures, write_table
from softcbf_mj.physics.plant import steps_per_control
from softcbf_mj.outputs.progress import Progress
from softcbf_mj.outputs.runio import SummaryWriter, frames_folder, save_frames_index, save_timeseries
from vocabulary.settings import Bound, default

if TYPE_CHECKING:  # MuJoCo, OpenCV and perception are imported where they are used (module docstring: Imports)
    from perception.detect import TagDetector
    from perception.plane import PlaneCalibration
    from softcbf_mj.loops.camera_loop import CameraTiming
    from softcbf_mj.physics.mjcf import ArmModelConfig
    from softcbf_mj.physics.mujoco_plant import MujocoPlant
    from softcbf_mj.outputs.recording import LiveRun


BOUNDS = {"width": Bound(16, default("width", "camera_loop"), unit="px"),  # the render's resolution (module docstring)
          "height": Bound(16, default("height", "camera_loop"), unit="px")}

TABLE = (
    ("tuning", "tuning", ""),
    ("rho_pred", "rho_min_pred", ".4f"),
    ("rho_meas", "rho_min_meas", ".4f"),
    ("F peak [N]", "force_max_N", ".4f"),
    ("t_viol [s]", "t_violation_s", ".2f"),
    ("q err rms [deg]", "q_err_rms_rad", ".3f", 180 / math.pi),
    ("q err max [deg]", "q_err_max_rad", ".3f", 180 / math.pi),
    ("detected", "detection_rate", ".3f"),
    ("latency mean [s]", "loop_latency_mean_s", ".3f"),
    ("latency max [s]", "loop_latency_max_s", ".3f"),
    ("render [ms]", "render_ms_median", ".1f"),
    ("detect [ms]", "detect_ms_median", ".1f"),
    ("hold/vent", "safe_action_calls", "d"),
    ("infeasible", "infeasible_steps", "d"),
    ("chatter [1/s]", "chatter_per_s", ".1f"),
    ("u HF [%]", "u_hf_fraction", ".1f", 100.0),
    ("RTF", "realtime_factor", ".2f"),
)


def _calibration(spec: str, plant: MujocoPlant, config: ArmModelConfig, width: int, height: int,
                 backend: str) -> PlaneCalibration:
    """The image-to-plane map: "board" (fit from a render of the calibration board), "truth", or a JSON file."""
    # MuJoCo +1.3 s, softcbf_mj.physics.mjcf +2.5 s, softcbf_mj.camera.render +2.3 s, perception.plane +0.4 s, perception.detect
    # (OpenCV) +0.25 s to import: where a camera run is set up, never at `list` or `run camera_loop --help`
    import mujoco

    from perception.detect import TagDetector
    from perception.plane import PlaneCalibration, calibrate
    from softcbf_mj.physics.mjcf import build_model, calibration_board
    from softcbf_mj.camera.render import OffscreenRenderer, ground_truth_calibration

    if spec == "truth":
        return ground_truth_calibration(plant.model, plant.data, "overhead", width, height)
    if spec == "board":
        model = build_model(config, board=True)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        with OffscreenRenderer(model, "overhead", width, height) as renderer:
            image = renderer.render(data)
        return calibrate(TagDetector(backend).detect(image), calibration_board(config))
    path = existing_file("calibration", spec, "'board', 'truth' or a calibration JSON file")
    return read_parameter_file("calibration", path, PlaneCalibration.load)


def _perception_figures(frames: dict[str, np.ndarray], calls: dict[str, np.ndarray]) -> dict:
    taken = ~frames["dropped"]
    complete = frames["complete"]
    err = (frames["q_camera"] - frames["q_true"])[complete]
    ages = calls["age_s"][np.isfinite(calls["age_s"])]
    return {
        "frames": int(len(frames["t"])),
        "frames_dropped": int(np.count_nonzero(frames["dropped"])),
        "detection_rate": float(np.count_nonzero(complete) / max(1, np.count_nonzero(taken))),
        "q_err_rms_rad": float(np.sqrt(np.mean(err**2))) if err.size else None,
        "q_err_max_rad": float(np.max(np.abs(err))) if err.size else None,
        "render_ms_median": float(np.median(frames["render_ms"][taken])) if np.any(taken) else None,
        "detect_ms_median": float(np.median(frames["detect_ms"][taken])) if np.any(taken) else None,
        "estimate_ms_median": float(np.median(frames["estimate_ms"][taken])) if np.any(taken) else None,
        "loop_latency_mean_s": float(np.mean(ages)) if ages.size else None,
        "loop_latency_max_s": float(np.max(ages)) if ages.size else None,
        "safe_action_calls": int(np.count_nonzero(np.isin(calls["action"], ("hold", "vent")))),
    }


def check_spec(spec: CameraLoop) -> Controller:
    """The checks of a `camera_loop` spec beyond its values' (scenarios.spec): the controller, the camera's
    timing on the tick, the detector, the calibration file, the ground truth and the physics step; returns the
    controller it built (`spec.built`)."""
    from perception.detect import BACKENDS as DETECTOR_BACKENDS  # OpenCV: +0.25 s to import, where a spec is checked

    controller = check_controller(spec.filter, spec.nominal, spec.model, spec.assumed_plate_stiffness)
    camera_timing(spec).ticks_per_control(spec.camera.tick)
    check_choice("detector", spec.camera.detector, DETECTOR_BACKENDS)
    if spec.camera.calibration not in ("board", "truth") and not Path(spec.camera.calibration).is_file():
        raise ValueError(f"calibration must be 'board', 'truth' or a calibration JSON file, got "
                         f"{spec.camera.calibration!r} (no such file)")
    check_true_arm(spec.arm, spec.plate, controller.robot)
    steps_per_control(spec.camera.tick, spec.arm.physics_dt)
    return controller


CameraLoop = scenario_spec(
    "CameraLoop", "The spec of scenario `camera_loop` (module docstring): `mujoco_contact`'s sections, the camera "
                  "path and the controller's call rate.",
    "camera_loop", {"run": Run, "filter": Filter, "nominal": Nominal, "model": Model, "arm": TrueArm, "plate": Plate,
                    "camera": Camera},
    {"assumed_plate_stiffness": "assumed_plate_stiffness", "assumed_tau_p": "assumed_tau_p",
     "control_rate": "control_rate"}, BOUNDS, check_spec, __name__)


def camera_timing(spec: CameraLoop) -> CameraTiming:
    """The camera path's timing of `spec` (softcbf_mj.loops.camera_loop.CameraTiming, which checks it)."""
    from softcbf_mj.loops.camera_loop import CameraTiming  # MuJoCo: +2.4 s to import, where a spec is checked

    c = spec.camera
    return CameraTiming(c.frame_rate, spec.control_rate, c.latency, c.drop_rate, c.pixel_noise, c.hold_s)


@dataclass(frozen=True, eq=False)
class CameraSetup:
    """What a `camera_loop` run builds before its tunings: the ground truth's plant (ticking at the
    camera's tick) and model, the controller's safe set, runs, nominal parameters and context, q0 (N,) rad,
    the timing, the tag detector and the image-to-plane map."""

    plant: MujocoPlant
    truth: Truth
    safe_set: ForceSafeSet
    runs: tuple[ControllerRun, ...]
    nominal_kwargs: dict[str, object]
    context: FilterContext
    q0: np.ndarray
    timing: CameraTiming
    detector: TagDetector
    plane: PlaneCalibration


def camera_setup(spec: CameraLoop) -> CameraSetup:
    """The (checked) `spec`'s plant, controllers and camera pipeline (`CameraSetup`)."""
    camera, controller = spec.camera, spec.built
    model_robot, safe_set = controller.robot, controller.safe_set
    check_duration(spec.run.duration, camera.tick, model_robot.n_segments, safe_set)  # first: refused at once

    # OpenCV, MuJoCo: perception +0.2-0.4 s, softcbf_mj.physics.mjcf and mujoco_plant +2.5 s to import, after the checks
    from perception.detect import TagDetector
    from perception.tags import arm_tag_ids
    from softcbf_mj.physics.mjcf import build_model
    from softcbf_mj.physics.mujoco_plant import MujocoPlant

    truth = build_truth(spec.arm, spec.plate, model_robot, safe_set.environment, spec.model.damping_scale)
    plant = MujocoPlant(build_model(truth.config), camera.tick)
    n = plant.n_segments
    plane = _calibration(camera.calibration, plant, truth.config, camera.width, camera.height, camera.detector)
    # The filter's command takes effect at the next tick after the call; the estimate's own age is the rest.
    context = FilterContext.for_robot(model_robot, safe_set, 1.0 / spec.control_rate, spec.filter.pressure_limits,
                                      command_delay=0.0, actuator_tau=spec.assumed_tau_p)
    return CameraSetup(plant, truth, safe_set, controller.runs, controller.nominal_kwargs, context,
                       initial_configuration(n, spec.run.seed, spec.run.q0_std), camera_timing(spec),
                       TagDetector(camera.detector, tag_ids=arm_tag_ids(n)), plane)


class FrameSaver:
    """Saves every `every`-th camera frame of run `label` as JPEG with its detections into
    frames/<label>/ (format: softcbf_mj.outputs.runio) and streams it to `live` when given."""

    def __init__(self, out_dir: Path, label: str, every: int, live: LiveRun | None) -> None:
        self.out_dir, self.label, self.every, self.live = out_dir, label, every, live
        self.folder = frames_folder(out_dir, label)
        self.saved: list[dict] = []

    def __call__(self, j: int, t: float, image: np.ndarray, detections: list) -> None:
        import cv2  # +0.2 s to import: only where frames are saved

        if not self.every or j % self.every:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        name = f"frame_{j:06d}.jpg"
        _, jpeg = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
        (self.folder / name).write_bytes(jpeg.tobytes())
        self.saved.append({"t": t, "file": name,
                           "detections": [{"id": d.tag_id, "corners": d.corners.tolist()} for d in detections]})
        if self.live is not None:
            self.live.frame(t, jpeg.tobytes(), "image/jpeg", self.saved[-1]["detections"])

    def close(self) -> None:
        """Write the index of the saved frames (none: nothing)."""
        if self.saved:
            save_frames_index(self.out_dir, self.label, self.saved)


def run_camera_tuning(out_dir: Path, summary: SummaryWriter, spec: CameraLoop, setup: CameraSetup,
                      render: Callable[[], np.ndarray], run: ControllerRun) -> dict[str, Any]:
    """Run controller `run` through the camera path for the spec's duration and `save_run` it; return its row."""
    # perception +0.2-0.35 s, softcbf_mj.loops.camera_loop and mujoco_plant (MuJoCo) +2.4 s to import: where a run starts
    from perception.estimator import ArmAngleEstimator
    from perception.tags import arm_tag_ids
    from perception.tracking import TrackingTagDetector
    from softcbf_mj.loops.camera_loop import FRAME_UNITS, run_camera_loop
    from softcbf_mj.physics.mujoco_plant import EXTRAS_UNITS

    camera, n, tick = spec.camera, setup.plant.n_segments, spec.camera.tick
    step = control_step(run, spec.nominal.name, setup.nominal_kwargs, setup.context, setup.timing.monitor(n))
    estimator = ArmAngleEstimator(n, setup.plane, setup.truth.config.tag_size, max_hold_s=camera.max_hold_s,
                                  qd_filter_tau=camera.qd_filter_tau)
    detector = TrackingTagDetector(setup.detector, arm_tag_ids(n)) if camera.tracking else setup.detector
    every = max(1, int(round(camera.frame_rate / camera.saved_frames_hz))) if camera.saved_frames_hz > 0 else 0
    saver = FrameSaver(out_dir, run.label, every, live_run(summary, run.label, tick, camera=every > 0))
    bar = Progress(f"camera_loop {run.label}", int(round(spec.run.duration / tick)), enabled=spec.run.progress,
                   unit_s=tick)
    start = time.perf_counter()
    series, frames, calls = run_camera_loop(setup.plant, render, detector, estimator, step, setup.safe_set,
                                            spec.run.duration, setup.q0, setup.timing, spec.run.seed, saver, bar,
                                            saver.live)
    wall = time.perf_counter() - start
    saver.close()
    frames_file = save_timeseries(out_dir, f"{run.label}_frames", frames, FRAME_UNITS)

    def figures(series: dict[str, np.ndarray]) -> dict:
        out = contact_figures(series, setup.safe_set, tick)
        out.update(plate_figures(series))
        out.update(certified_truth_figures(series, setup.truth.certified(spec.built.robot, spec.assumed_plate_stiffness),
                                           tick))
        out.update(_perception_figures(frames, calls))
        out["frames_timeseries"] = str(frames_file.relative_to(out_dir))
        return out

    return save_run(out_dir, summary, run.label, series, wall, tick, filter_enabled(step), figures, EXTRAS_UNITS,
                    controller_row(run, spec.nominal.name, setup.nominal_kwargs), step.fault)


@register("camera_loop", "the paper's hardware experiment in MuJoCo: controller fed by rendered AprilTags at 12.8 fps, 10 Hz loop",
          CameraLoop)
def camera_loop(out_dir: Path, spec: CameraLoop) -> dict:
    """Run each controller (tuning) of `spec` for its duration through the camera path; write summary.json,
    time series and frames."""
    from softcbf_mj.camera.render import OffscreenRenderer  # MuJoCo: +2.3 s to import, when run (module docstring)

    setup = camera_setup(spec)
    camera = spec.camera
    with OffscreenRenderer(setup.plant.model, "overhead", camera.width, camera.height) as renderer:
        summary = SummaryWriter(out_dir, "camera_loop", spec.flat(),
                                scene=scene_record(setup.truth.robot, setup.safe_set, setup.truth.plate_stiffness,
                                                   setup.truth.plates))
        for run in setup.runs:
            row = run_camera_tuning(out_dir, summary, spec, setup, lambda: renderer.render(setup.plant.data), run)
            if stop_after(row):
                break
    print(f"camera_loop: {spec.run.duration:g} s, camera {camera.width}x{camera.height} at {camera.frame_rate:g} fps, "
          f"loop {spec.control_rate:g} Hz, latency {camera.latency * 1e3:g} ms, drop rate {camera.drop_rate:g}, "
          f"pixel noise {camera.pixel_noise:g}, calibration {camera.calibration!r}, F_max {spec.model.f_max:g} N; "
          f"outputs in {out_dir}")
    print(write_table(out_dir, summary.data["runs"], TABLE))
    return summary.data
