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

Per run, besides the docs/run-outputs.md fields (ρ_meas from the plate's spring force) and the
contact figures of `mujoco_contact`, summary.json holds the perception figures: q error
of complete frames against the true q at exposure (RMS and max, rad), detection rate
(complete frames / frames taken), frames dropped, render, detection and estimation wall time per
frame (median, ms), and the loop latency: the age of the estimate at the controller's
calls (capture → command, mean and max, s). Time series: the tick-rate series of
`mujoco_contact` plus one per-frame series `<run>_frames.npz` (`FRAME_UNITS`); a few
frames with their detections go to frames/<run>/ (format: softcbf_mj.runio).

Imports: MuJoCo, OpenCV and the perception pipeline are imported inside the functions that
check or run the scenario, not at load, so that registering it and reading its parameters
(`softcbf list`, `softcbf run NAME --help`) stay cheap (issue 27; tests/test_cli_lazy.py). The
image size's bound is the render's resolution (`softcbf_mj.model_builder.CAMERA_RESOLUTION`),
which is the scenario's default width and height (tests/test_setting_defaults.py holds them equal).
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping

import numpy as np

from controllers.safety_filter import FilterContext
from scenarios import register
from scenarios.common import (
    build_safe_set, check_bounds, check_choice, check_controller_parameters, control_step,
    controller_row, controller_runs, existing_file, filter_enabled, initial_configuration,
    live_run, nominal_arguments, read_parameter_file, save_run, scene_record, stop_after,
)
from scenarios.ground_truth import GroundTruthSettings, build_truth, check_true_arm, controller_robot
from softcbf_mj.loop import check_duration
from softcbf_mj.metrics import contact_figures, format_table, plate_figures
from softcbf_mj.plant import steps_per_control
from softcbf_mj.progress import Progress
from softcbf_mj.runio import SummaryWriter, frames_folder, save_frames_index, save_timeseries
from vocabulary.settings import Bound, default

if TYPE_CHECKING:  # MuJoCo, OpenCV and perception are imported where they are used (module docstring: Imports)
    from perception.plane import PlaneCalibration
    from softcbf_mj.model_builder import ArmModelConfig
    from softcbf_mj.mujoco_plant import MujocoPlant


BOUNDS = {"width": Bound(16, default("width", "camera_loop"), unit="px"),  # the render's resolution (module docstring)
          "height": Bound(16, default("height", "camera_loop"), unit="px")}

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
    ("chatter [1/s]", "chatter_per_s", ".1f"),
    ("u HF [%]", "u_hf_fraction", ".1f", 100.0),
    ("RTF", "realtime_factor", ".2f"),
)


def _calibration(spec: str, plant: MujocoPlant, config: ArmModelConfig, width: int, height: int,
                 backend: str) -> PlaneCalibration:
    """The image-to-plane map: "board" (fit from a render of the calibration board), "truth", or a JSON file."""
    import mujoco

    from perception.detect import TagDetector
    from perception.plane import PlaneCalibration, calibrate
    from softcbf_mj.model_builder import build_model, calibration_board
    from softcbf_mj.render import OffscreenRenderer, ground_truth_calibration

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


def check_parameters(params: Mapping[str, Any]) -> None:
    """The checks `camera_loop` makes before it builds anything (`scenarios.Scenario.validate`)."""
    from perception.detect import BACKENDS as DETECTOR_BACKENDS
    from softcbf_mj.camera_loop import CameraTiming

    check_bounds(params, BOUNDS)
    model_robot = check_controller_parameters(params, "assumed_plate_stiffness")
    timing = CameraTiming(params["frame_rate"], params["control_rate"], params["latency"], params["drop_rate"],
                          params["pixel_noise"], params["hold_s"])
    timing.ticks_per_control(params["tick"])
    check_choice("detector", params["detector"], DETECTOR_BACKENDS)
    if params["calibration"] not in ("board", "truth") and not Path(params["calibration"]).is_file():
        raise ValueError(f"calibration must be 'board', 'truth' or a calibration JSON file, got {params['calibration']!r} "
                         "(no such file)")
    check_true_arm(GroundTruthSettings.of(params), model_robot)
    steps_per_control(params["tick"], params["physics_dt"])


@register("camera_loop", "the paper's hardware experiment in MuJoCo: controller fed by rendered AprilTags at 12.8 fps, 10 Hz loop",
          check_parameters, BOUNDS)
def camera_loop(
    out_dir: Path,
    *,
    duration: float = default("duration", "camera_loop"),
    tunings: str = default("tunings", "camera_loop"),
    filter: str = default("filter", "camera_loop"),
    filter_params: str = default("filter_params", "camera_loop"),
    nominal: str = default("nominal", "camera_loop"),
    nominal_params: str = default("nominal_params", "camera_loop"),
    amplitude: float = default("amplitude", "camera_loop"),
    frequency: float = default("frequency", "camera_loop"),
    t0: float = default("t0", "camera_loop"),
    pressure_limits: bool = default("pressure_limits", "camera_loop"),
    robot: str = default("robot", "camera_loop"),
    environment: str = default("environment", "camera_loop"),
    links_per_segment: int = default("links_per_segment", "camera_loop"),
    tau_p: float = default("tau_p", "camera_loop"),
    physics_dt: float = default("physics_dt", "camera_loop"),
    plate_stiffness: float = default("plate_stiffness", "camera_loop"),
    assumed_plate_stiffness: float = default("assumed_plate_stiffness", "camera_loop"),
    f_max: float = default("f_max", "camera_loop"),
    row_scaling: str = default("row_scaling", "camera_loop"),
    qp_backend: str = default("qp_backend", "camera_loop"),
    tick: float = default("tick", "camera_loop"),
    frame_rate: float = default("frame_rate", "camera_loop"),
    control_rate: float = default("control_rate", "camera_loop"),
    latency: float = default("latency", "camera_loop"),
    drop_rate: float = default("drop_rate", "camera_loop"),
    pixel_noise: float = default("pixel_noise", "camera_loop"),
    hold_s: float = default("hold_s", "camera_loop"),
    max_hold_s: float = default("max_hold_s", "camera_loop"),
    qd_filter_tau: float = default("qd_filter_tau", "camera_loop"),
    width: int = default("width", "camera_loop"),
    height: int = default("height", "camera_loop"),
    calibration: str = default("calibration", "camera_loop"),
    detector: str = default("detector", "camera_loop"),
    tracking: bool = default("tracking", "camera_loop"),
    saved_frames_hz: float = default("saved_frames_hz", "camera_loop"),
    seed: int = default("seed", "camera_loop"),
    q0_std: float = default("q0_std", "camera_loop"),
    true_robot: str = default("true_robot", "camera_loop"),
    damping_scale: float = default("damping_scale", "camera_loop"),
    true_stiffness_scale: float = default("true_stiffness_scale", "camera_loop"),
    true_damping_scale: float = default("true_damping_scale", "camera_loop"),
    true_gain_scale: float = default("true_gain_scale", "camera_loop"),
    true_length_scale: float = default("true_length_scale", "camera_loop"),
    facet_offset: float = default("facet_offset", "camera_loop"),
    facet_angle: float = default("facet_angle", "camera_loop"),
    gravity: float = default("gravity", "camera_loop"),
    tip_friction: float = default("tip_friction", "camera_loop"),
    table_friction: float = default("table_friction", "camera_loop"),
    plate: str = default("plate", "camera_loop"),
    sheet_clamp_at: float = default("sheet_clamp_at", "camera_loop"),
    sheet_free_end_at: float = default("sheet_free_end_at", "camera_loop"),
    sheet_thickness: float = default("sheet_thickness", "camera_loop"),
    sheet_width: float = default("sheet_width", "camera_loop"),
    sheet_youngs_modulus: float = default("sheet_youngs_modulus", "camera_loop"),
    sheet_links: int = default("sheet_links", "camera_loop"),
    sheet_calibration_fraction: float = default("sheet_calibration_fraction", "camera_loop"),
    progress: bool = default("progress", "camera_loop"),
) -> dict:
    """Run each controller (tuning) for `duration` s through the camera path; write summary.json, time series and frames.

    The MuJoCo arm is `robot`'s (any number of segments, tag i on the end of segment i) or
    `true_robot`'s when given (same number of segments); `damping_scale` multiplies every
    segment's damping d_i of both arms (the controller knows it), so the arm's time constant
    d_i/k_i scales with it (the operating-envelope study, studies/hardware_envelope.toml).
    The ground truth's settings are `mujoco_contact`'s (`scenarios.ground_truth`): the
    `true_*_scale` factors of the arm, the true plates moved by `facet_offset` and turned by
    `facet_angle` (the controller keeping the unmoved facets), `gravity`, `tip_friction`,
    `table_friction`, `plate` and the `sheet_*` parameters (a flexure's gauge gives ρ_meas)."""
    params = dict(locals())  # the parameters: first, before any other local name
    params.pop("out_dir")
    import cv2  # MuJoCo, OpenCV and perception: imported when run (module docstring), after `params`

    from perception.detect import TagDetector
    from perception.estimator import ArmAngleEstimator
    from perception.tags import arm_tag_ids
    from perception.tracking import TrackingTagDetector
    from softcbf_mj.camera_loop import FRAME_UNITS, CameraTiming, run_camera_loop
    from softcbf_mj.model_builder import build_model
    from softcbf_mj.mujoco_plant import EXTRAS_UNITS, MujocoPlant
    from softcbf_mj.render import OffscreenRenderer

    check_parameters(params)
    timing = CameraTiming(frame_rate, control_rate, latency, drop_rate, pixel_noise, hold_s)
    model_robot = controller_robot(params)
    safe_set = build_safe_set(environment, assumed_plate_stiffness, f_max, row_scaling)
    check_duration(duration, tick, model_robot.n_segments, safe_set)
    truth = build_truth(GroundTruthSettings.of(params), model_robot, safe_set.environment)
    config = truth.config
    plant = MujocoPlant(build_model(config), tick)
    n = plant.n_segments
    tag_detector = TagDetector(detector, tag_ids=arm_tag_ids(n))
    plane = _calibration(calibration, plant, config, width, height, detector)
    runs = controller_runs(filter, filter_params, tunings, qp_backend)
    nominal_kwargs = nominal_arguments(nominal, nominal_params, amplitude=amplitude, frequency=frequency, t0=t0)
    # The filter's command takes effect at the next tick after the call; the estimate's own age is the rest.
    context = FilterContext.for_robot(model_robot, safe_set, 1.0 / control_rate, pressure_limits, command_delay=0.0,
                                      actuator_tau=tau_p)
    q0 = initial_configuration(n, seed, q0_std)
    save_every = max(1, int(round(frame_rate / saved_frames_hz))) if saved_frames_hz > 0 else 0

    with OffscreenRenderer(plant.model, "overhead", width, height) as renderer:
        summary = SummaryWriter(out_dir, "camera_loop", params,
                                scene=scene_record(truth.robot, safe_set, truth.plate_stiffness, truth.plates))
        for run in runs:
            label = run.label
            step = control_step(run, nominal, nominal_kwargs, context, timing.monitor(n))
            estimator = ArmAngleEstimator(n, plane, config.tag_size, max_hold_s=max_hold_s, qd_filter_tau=qd_filter_tau)
            frame_detector = TrackingTagDetector(tag_detector, arm_tag_ids(n)) if tracking else tag_detector
            saved: list[dict] = []
            folder = frames_folder(out_dir, label)
            live = live_run(summary, label, tick, camera=save_every > 0)

            def keep_frame(j: int, t: float, image: np.ndarray, detections: list) -> None:
                if not save_every or j % save_every:
                    return
                folder.mkdir(parents=True, exist_ok=True)
                name = f"frame_{j:06d}.jpg"
                _, jpeg = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 90])
                (folder / name).write_bytes(jpeg.tobytes())
                saved.append({"t": t, "file": name,
                              "detections": [{"id": d.tag_id, "corners": d.corners.tolist()} for d in detections]})
                if live is not None:
                    live.frame(t, jpeg.tobytes(), "image/jpeg", saved[-1]["detections"])

            bar = Progress(f"camera_loop {label}", int(round(duration / tick)), enabled=progress, unit_s=tick)
            start = time.perf_counter()
            series, frames, calls = run_camera_loop(plant, lambda: renderer.render(plant.data), frame_detector, estimator,
                                                    step, safe_set, duration, q0, timing, seed, keep_frame, bar, live)
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

            row = save_run(out_dir, summary, label, series, wall, tick, filter_enabled(step), figures, EXTRAS_UNITS,
                           controller_row(run, nominal, nominal_kwargs), step.fault)
            if stop_after(row):
                break
    print(f"camera_loop: {duration:g} s, camera {width}x{height} at {frame_rate:g} fps, loop {control_rate:g} Hz, "
          f"latency {latency * 1e3:g} ms, drop rate {drop_rate:g}, pixel noise {pixel_noise:g}, calibration {calibration!r}, "
          f"F_max {f_max:g} N; outputs in {out_dir}")
    print(format_table(summary.data["runs"], TABLE))
    return summary.data
