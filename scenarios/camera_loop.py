"""Scenario `camera_loop`: the paper's hardware experiment (Table II) in MuJoCo, the controller fed by the camera.

The ground truth is `MujocoPlant` as in `mujoco_contact` (the discretised reference rod
and the paper's plate), by default with the coarser rod of the hardware emulator
(`CAMERA_LINKS_PER_SEGMENT` = 5 links at `CAMERA_PHYSICS_DT` = 0.2 ms; ≈ 1 mN of plate
force from the 10-link rod) and a plant tick of 2 ms (exposures, deliveries and the
controller fall on it; the time series are logged at it). The controller under test sees the arm only through the
overhead camera: MuJoCo's offscreen renders of the arm's AprilTags go through the
hardware's pipeline (`perception`: detection, image-to-plane map, angles from tag
orientations, q̇ by finite differences), with the hardware's timing
(`softcbf_mj.camera_loop`: 12.8 frames/s, a `latency` from exposure to estimate, the
CBF filter at 10 Hz with zero-order hold, and the hardware's safe action — hold, then
vent — when the estimate goes stale). Tunings default to the paper's hardware ones:
None, HW-Low (γ = 100) and HW-High (γ = 10).

Tags are detected in windows around their last positions (`perception.tracking`, the
same corners as a full-frame detection; `tracking=False` detects in the whole frame).
The image-to-plane map comes from `calibration`: "board" (default, as on the hardware:
the calibration scene's tag board is rendered once and `perception.plane.calibrate`
fits the map), "truth" (the exact map of MuJoCo's pinhole camera) or a JSON file
written by tools/calibrate_camera.py.

Per run, besides the SPEC §8 fields (ρ_meas from the plate's spring force) and the
contact figures of `mujoco_contact`, summary.json holds the perception figures: q error
of complete frames against the true q at exposure (RMS and max, rad), detection rate
(complete frames / frames taken), frames dropped, render, detection and estimation wall time per
frame (median, ms), and the loop latency: the age of the estimate at the controller's
calls (capture → command, mean and max, s). Time series: the tick-rate series of
`mujoco_contact` plus one per-frame series `<run>_frames.npz` (`FRAME_UNITS`); a few
frames with their detections go to frames/<run>/ (format: softcbf_mj.runio).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import cv2
import mujoco
import numpy as np

from controllers.filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.params import RobotParams, per_segment
from perception.detect import TagDetector
from perception.estimator import DEFAULT_MAX_HOLD_S, ArmAngleEstimator
from perception.plane import PlaneCalibration, calibrate
from perception.tracking import TrackingTagDetector
from perception.tags import arm_tag_ids
from scenarios import register
from scenarios.common import build_safe_set, initial_configuration, load_robot, parse_tunings, save_run, scene_record
from softcbf_mj.camera_loop import FRAME_UNITS, CameraTiming, run_camera_loop
from softcbf_mj.flexure import FlexureParams
from softcbf_mj.flexure_calibration import calibrate_flexure
from softcbf_mj.metrics import contact_figures, format_table, plate_figures
from softcbf_mj.model_builder import (
    CAMERA_LINKS_PER_SEGMENT, CAMERA_PHYSICS_DT, DEFAULT_TAU_P, ArmModelConfig, build_model, calibration_board,
)
from softcbf_mj.mujoco_plant import EXTRAS_UNITS, MujocoPlant
from softcbf_mj.progress import Progress
from softcbf_mj.render import OffscreenRenderer, ground_truth_calibration
from softcbf_mj.runio import SummaryWriter, frames_folder, safe_name, save_frames_index, save_timeseries


TABLE = (
    ("tuning", "tuning", ""),
    ("rho_pred", "rho_min_pred", ".4f"),
    ("rho_meas", "rho_min_meas", ".4f"),
    ("F_max [N]", "force_max_N", ".4f"),
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
    ("RTF", "realtime_factor", ".2f"),
)


def _calibration(spec: str, plant: MujocoPlant, config: ArmModelConfig, width: int, height: int,
                 backend: str) -> PlaneCalibration:
    """The image-to-plane map: "board" (fit from a render of the calibration board), "truth", or a JSON file."""
    if spec == "truth":
        return ground_truth_calibration(plant.model, plant.data, "overhead", width, height)
    if spec == "board":
        model = build_model(config, board=True)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        with OffscreenRenderer(model, "overhead", width, height) as renderer:
            image = renderer.render(data)
        return calibrate(TagDetector(backend).detect(image), calibration_board(config))
    path = Path(spec)
    if not path.is_file():
        raise ValueError(f"calibration must be 'board', 'truth' or a calibration JSON file, got {spec!r} (no such file)")
    return PlaneCalibration.load(path)


def scale_damping(robot: RobotParams, scale: float) -> RobotParams:
    """`robot` with every segment's damping d_i multiplied by `scale` (> 0): time constants d_i/k_i × scale."""
    return robot.replace(damping=tuple(scale * d for d in robot.damping)) if scale != 1.0 else robot


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


@register("camera_loop", "the paper's hardware experiment in MuJoCo: controller fed by rendered AprilTags at 12.8 fps, 10 Hz loop")
def camera_loop(
    out_dir: Path,
    *,
    duration: float = 100.0,
    tunings: str = "None,HW-Low,HW-High",
    amplitude: float = 80.0,
    frequency: float = 0.01,
    t0: float = 0.0,
    pressure_limits: bool = True,
    robot: str = "reference",
    environment: str = "paper",
    links_per_segment: int = CAMERA_LINKS_PER_SEGMENT,
    tau_p: float = DEFAULT_TAU_P,
    physics_dt: float = CAMERA_PHYSICS_DT,
    plate_stiffness: float = 11.16,
    assumed_plate_stiffness: float = 11.16,
    f_max: float = 0.16,
    row_scaling: str = "paper",
    qp_backend: str = "native",
    tick: float = 2e-3,
    frame_rate: float = 12.8,
    control_rate: float = 10.0,
    latency: float = CameraTiming.latency,
    drop_rate: float = 0.0,
    pixel_noise: float = 0.0,
    hold_s: float = CameraTiming.hold_s,
    max_hold_s: float = DEFAULT_MAX_HOLD_S,
    qd_filter_tau: float = 0.0,
    width: int = 1280,
    height: int = 720,
    calibration: str = "board",
    detector: str = "opencv",
    tracking: bool = True,
    saved_frames_hz: float = 0.5,
    seed: int = 0,
    q0_std: float = 0.0,
    true_robot: str = "",
    damping_scale: float = 1.0,
    tip_friction: float = 0.0,
    plate: str = "ideal",
    sheet_clamp_at: float = FlexureParams.clamp_at,
    sheet_free_end_at: float = FlexureParams.free_end_at,
    sheet_thickness: float = FlexureParams.thickness,
    sheet_width: float = FlexureParams.width,
    sheet_youngs_modulus: float = FlexureParams.youngs_modulus,
    sheet_links: int = FlexureParams.links,
    sheet_calibration_fraction: float = FlexureParams.calibration_fraction,
    progress: bool = True,
) -> dict:
    """Run each tuning for `duration` s through the camera path; write summary.json, time series and frames.

    The MuJoCo arm is `robot`'s (any number of segments, tag i on the end of segment i) or
    `true_robot`'s when given (same number of segments); `damping_scale` multiplies every
    segment's damping d_i of both arms (the controller knows it), so the arm's time constant
    d_i/k_i scales with it (the operating-envelope study, studies/hardware_envelope.toml);
    `tip_friction`, `plate` and the `sheet_*` parameters as in `mujoco_contact` (a
    flexure's gauge gives ρ_meas)."""
    params = dict(locals())
    params.pop("out_dir")
    if not duration > 0:
        raise ValueError(f"duration must be > 0 s, got {duration}")
    if not (math.isfinite(saved_frames_hz) and saved_frames_hz >= 0):
        raise ValueError(f"saved_frames_hz must be finite and >= 0 Hz (0: none), got {saved_frames_hz}")
    if not (math.isfinite(damping_scale) and damping_scale > 0):
        raise ValueError(f"damping_scale must be finite and > 0, got {damping_scale}")
    timing = CameraTiming(frame_rate, control_rate, latency, drop_rate, pixel_noise, hold_s)
    timing.ticks_per_control(tick)
    model_robot = scale_damping(load_robot(robot), damping_scale)
    safe_set = build_safe_set(environment, assumed_plate_stiffness, f_max, row_scaling)
    env = safe_set.environment
    arm = scale_damping(load_robot(true_robot), damping_scale) if true_robot else model_robot
    if arm.n_segments != model_robot.n_segments:
        raise ValueError(f"true_robot has {arm.n_segments} segments, the controller's robot {model_robot.n_segments}; "
                         "they must have the same number")
    flexure = FlexureParams(clamp_at=sheet_clamp_at, free_end_at=sheet_free_end_at, thickness=sheet_thickness,
                            width=sheet_width, youngs_modulus=sheet_youngs_modulus, links=sheet_links,
            calibration_fraction=sheet_calibration_fraction)
    config = ArmModelConfig(robot=arm, H=tuple(map(tuple, env.H)), h=tuple(env.h), plate_stiffness=plate_stiffness,
                            links_per_segment=links_per_segment, tau_p=tau_p, physics_dt=physics_dt,
                            tip_friction=tip_friction, plate=plate, flexure=flexure)
    true_plate_stiffness = calibrate_flexure(config).stiffness_N_per_m if plate == "flexure" else plate_stiffness
    plant = MujocoPlant(build_model(config), tick)
    n = plant.n_segments
    tag_detector = TagDetector(detector, tag_ids=arm_tag_ids(n))
    plane = _calibration(calibration, plant, config, width, height, detector)
    nominal = SinusoidNominal(tuple(per_segment(amplitude, n, "amplitude")), frequency, (2 * math.pi * frequency * t0,) * n)
    q0 = initial_configuration(n, seed, q0_std)
    save_every = max(1, int(round(frame_rate / saved_frames_hz))) if saved_frames_hz > 0 else 0

    summary = SummaryWriter(out_dir, "camera_loop", params, scene=scene_record(arm, safe_set, true_plate_stiffness))
    with OffscreenRenderer(plant.model, "overhead", width, height) as renderer:
        for tuning in parse_tunings(tunings):
            label = tuning.name
            controller = CBFFilter(model_robot, safe_set, tuning, pressure_limits=pressure_limits, qp_backend=qp_backend)
            estimator = ArmAngleEstimator(n, plane, config.tag_size, max_hold_s=max_hold_s, qd_filter_tau=qd_filter_tau)
            frame_detector = TrackingTagDetector(tag_detector, arm_tag_ids(n)) if tracking else tag_detector
            saved: list[dict] = []
            folder = frames_folder(out_dir, label)

            def keep_frame(j: int, t: float, image: np.ndarray, detections: list) -> None:
                if not save_every or j % save_every:
                    return
                folder.mkdir(parents=True, exist_ok=True)
                name = f"frame_{j:06d}.jpg"
                cv2.imwrite(str(folder / name), cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
                saved.append({"t": t, "file": name,
                              "detections": [{"id": d.tag_id, "corners": d.corners.tolist()} for d in detections]})

            bar = Progress(f"camera_loop {label}", int(round(duration / tick)), enabled=progress, unit_s=tick)
            start = time.perf_counter()
            log, frames, calls = run_camera_loop(plant, lambda: renderer.render(plant.data), frame_detector, estimator,
                                                 controller, nominal, duration, q0, timing, seed, keep_frame, bar)
            wall = time.perf_counter() - start
            if saved:
                save_frames_index(out_dir, label, saved)
            frames_file = save_timeseries(out_dir, f"{label}_frames", frames, FRAME_UNITS)

            def figures(series: dict[str, np.ndarray]) -> dict:
                out = contact_figures(series, safe_set, tick)
                out.update(plate_figures(series))
                out.update(_perception_figures(frames, calls))
                out["frames_timeseries"] = str(frames_file.relative_to(out_dir))
                return out

            save_run(out_dir, summary, label, log, wall, tick, controller.enabled, figures, EXTRAS_UNITS)
    print(f"camera_loop: {duration:g} s, camera {width}x{height} at {frame_rate:g} fps, loop {control_rate:g} Hz, "
          f"latency {latency * 1e3:g} ms, drop rate {drop_rate:g}, pixel noise {pixel_noise:g}, calibration {calibration!r}, "
          f"F_max {f_max:g} N; outputs in {out_dir}")
    print(format_table(summary.data["runs"], TABLE))
    return summary.data
