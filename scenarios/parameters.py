"""What every scenario parameter means: one vocabulary, one entry per name.

A parameter name means the same quantity in every scenario that has it (`duration` is the
length of each run in s in paper_sim, mujoco_contact and camera_loop alike), so its
documentation is declared once, here, as `ParameterDoc(meaning, unit, valid)`:

- `meaning`: what it sets, in a phrase;
- `unit`: SI unit ("" for a dimensionless number, a name or a switch);
- `valid`: the values accepted. A scenario that bounds the parameter (its `bounds`,
  `scenarios.register`) states the range itself (`Bound.__str__`, e.g. "> 0 N");
  `valid` is then what the range does not say (e.g. "(0: ...)"), else the valid values.

`HARDWARE_KEYS` maps each key of the hardware configuration (`hardware.config`) that sets
the same quantity as a scenario parameter to that parameter (the hardware file keeps its
unit-suffixed spellings), so the command line, studies, run configuration files and the
hardware file share one set of names; `softcbf list`, `softcbf run NAME --help` and
docs/parameters.md (tools/parameter_table.py) show the table.

This module imports nothing beyond the standard library: the help texts cost nothing.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class ParameterDoc:
    """A scenario parameter's meaning, SI unit ("" if none) and valid values (module docstring)."""

    meaning: str
    unit: str = ""
    valid: str = ""


_SHEET = "flexure sheet (plate = 'flexure', docs/beyond-the-paper.md#flexure-plate): "
_TRUE_ARM = "the MuJoCo arm's "

DOCS: dict[str, ParameterDoc] = {
    # the run
    "duration": ParameterDoc("simulated time of each run (one per tuning)", "s"),
    "seed": ParameterDoc("random seed of the initial pose noise and the camera's noise and drops", ""),
    "q0_std": ParameterDoc("std of the Gaussian noise on the straight initial pose, per segment", "rad"),
    "progress": ParameterDoc("show a progress line on stderr", "", "true, false"),
    # the controller under test (scenarios.common, controllers.registry)
    "tunings": ParameterDoc("runs of paper-cbf: comma list of its presets, one run each", "",
                            "None, Low, High, HW-Low, HW-High, custom (a_E, b_E, gamma from filter_params)"),
    "filter": ParameterDoc("the safety filter under test", "",
                           "paper-cbf, none, qsg, e-erg, FILE.py:Factory, package.module:Factory (softcbf list)"),
    "filter_params": ParameterDoc("the filter's parameters, name=value;name=value (--filter-param NAME=VALUE)", "",
                                  "the filter's parameters (softcbf list)"),
    "nominal": ParameterDoc("the nominal controller", "", "sinusoid, tip-tracker, FILE.py:Factory, package.module:Factory"),
    "nominal_params": ParameterDoc("the nominal's parameters, name=value;name=value (--nominal-param NAME=VALUE)", "",
                                   "the nominal's parameters (softcbf list)"),
    "amplitude": ParameterDoc("sinusoid nominal: amplitude A of u_nom,j = A sin(2π f (t + t0))", "hPa", "finite"),
    "frequency": ParameterDoc("sinusoid nominal: frequency f", "Hz"),
    "t0": ParameterDoc("sinusoid nominal: time offset (> 0 starts later in the cycle)", "s", "finite"),
    "pressure_limits": ParameterDoc("the filter's QP holds the robot's pressure box", "", "true, false"),
    "qp_backend": ParameterDoc("QP solver of the filter", "", "native, daqp, qpsolvers:daqp, qpsolvers:quadprog, "
                                                               "qpsolvers:osqp (those installed)"),
    "control_rate": ParameterDoc("rate of the controller's calls (zero-order hold between)", "Hz", "> 0"),
    # the controller's model
    "robot": ParameterDoc("the controller's robot model", "",
                          "'reference', a preset of models/robots (hardware-like) or a robot JSON file (docs/file-formats.md#robot-json)"),
    "environment": ParameterDoc("the facets H r <= h of the free space", "",
                                "'paper' or an environment JSON file (docs/file-formats.md#environment-json)"),
    "f_max": ParameterDoc("force limit F_max per facet", "N"),
    "row_scaling": ParameterDoc("scaling of the rows of the force-safe set P", "", "paper, unit"),
    "assumed_plate_stiffness": ParameterDoc("the controller's plate spring ψ(n) = k n", "N/m"),
    # the plant (ground truth)
    "plate_stiffness": ParameterDoc("the true plate's spring (paper_sim: also the controller's ψ)", "N/m"),
    "integrator": ParameterDoc("integrator of the PCC plant", "", "ros2, rk4, euler"),
    "links_per_segment": ParameterDoc(_TRUE_ARM + "rigid links per segment", ""),
    "tau_p": ParameterDoc("valve pressure time constant of the MuJoCo actuators (first order)", "s"),
    "physics_dt": ParameterDoc("MuJoCo time step (divides the control or tick period)", "s"),
    "true_robot": ParameterDoc(_TRUE_ARM + "robot when it differs from the controller's", "",
                               "'' (the controller's robot) or a robot JSON file, same number of segments"),
    "true_stiffness_scale": ParameterDoc(_TRUE_ARM + "stiffness k as a multiple of the robot's", ""),
    "true_damping_scale": ParameterDoc(_TRUE_ARM + "damping d as a multiple of the robot's", ""),
    "damping_scale": ParameterDoc("damping d of both the controller's robot and the true arm, as a multiple of the "
                                  "robot's (the arm's time constants d/k scale with it; the controller knows it)", ""),
    "true_gain_scale": ParameterDoc(_TRUE_ARM + "actuator gain λ as a multiple of the robot's", ""),
    "true_length_scale": ParameterDoc(_TRUE_ARM + "segment lengths as a multiple of the robot's (inertias by its square)", ""),
    "facet_offset": ParameterDoc("the true plates moved along their outward normals (> 0: farther from the base)", "m"),
    "facet_angle": ParameterDoc("the true plates turned counter-clockwise about the foot of the perpendicular", "rad"),
    "gravity": ParameterDoc("gravity along -y (0: the arm lies on a table)", "m/s²"),
    "tip_friction": ParameterDoc("Coulomb friction coefficient μ between the arm and the plates", ""),
    "table_friction": ParameterDoc("Coulomb friction coefficient μ between the arm's links and the table it lies on "
                                   "(0: off; not with gravity)", ""),
    "plate": ParameterDoc("kind of true plate", "", "ideal (slide spring), flexure (clamped sheet in a force gauge)"),
    "sheet_clamp_at": ParameterDoc(_SHEET + "clamp position along the facet", "m", "finite"),
    "sheet_free_end_at": ParameterDoc(_SHEET + "free-end position along the facet", "m", "finite, != sheet_clamp_at"),
    "sheet_thickness": ParameterDoc(_SHEET + "thickness", "m", "> 0"),
    "sheet_width": ParameterDoc(_SHEET + "width", "m", "> 0"),
    "sheet_youngs_modulus": ParameterDoc(_SHEET + "Young's modulus", "Pa", "> 0"),
    "sheet_links": ParameterDoc(_SHEET + "rigid links of the sheet", "", ">= 1"),
    "sheet_calibration_fraction": ParameterDoc(_SHEET + "calibration point as a fraction of its length from the clamp",
                                               "", "in (0, 1]"),
    # the camera path (camera_loop)
    "tick": ParameterDoc("plant tick: exposures, deliveries and controller calls fall on it; the time series' step", "s"),
    "frame_rate": ParameterDoc("camera frame rate", "Hz", "> 0"),
    "latency": ParameterDoc("exposure → detections available to the controller", "s", ">= 0"),
    "drop_rate": ParameterDoc("fraction of frames lost (seeded)", "", "in [0, 1)"),
    "pixel_noise": ParameterDoc("std of the Gaussian image noise", "grey levels", ">= 0"),
    "hold_s": ParameterDoc("the safety monitor holds the last command this long before it vents", "s", ">= 0"),
    "max_hold_s": ParameterDoc("an estimate older than this is stale", "s"),
    "qd_filter_tau": ParameterDoc("first-order low pass of the estimated q̇ (0: raw finite differences)", "s"),
    "width": ParameterDoc("camera image width", "px"),
    "height": ParameterDoc("camera image height", "px"),
    "calibration": ParameterDoc("the image-to-plane map", "",
                                "board (fit from a render of the tag board), truth (MuJoCo's exact map), "
                                "or a calibration JSON file (tools/calibrate_camera.py)"),
    "detector": ParameterDoc("AprilTag detector backend", "", "opencv, pupil"),
    "tracking": ParameterDoc("detect tags in windows around their last positions (false: whole frame)", "", "true, false"),
    "saved_frames_hz": ParameterDoc("rate of camera frames saved to frames/<run>/ (0: none)", "Hz"),
}

HARDWARE_KEYS: dict[str, str] = {
    "robot.params": "robot",
    "environment.stiffness_N_per_m": "assumed_plate_stiffness",
    "environment.f_max_N": "f_max",
    "environment.row_scaling": "row_scaling",
    "control.filter": "filter",
    "control.filter_params": "filter_params",
    "control.nominal": "nominal",
    "control.nominal_params": "nominal_params",
    "control.rate_hz": "control_rate",
    "control.pressure_limits": "pressure_limits",
    "control.qp_backend": "qp_backend",
    "control.amplitude_hPa": "amplitude",
    "control.frequency_hz": "frequency",
    "camera.detector": "detector",
    "camera.max_hold_s": "max_hold_s",
    "camera.qd_filter_tau_s": "qd_filter_tau",
    "camera.fps": "frame_rate",
    "camera.width": "width",
    "camera.height": "height",
    "safety.hold_s": "hold_s",
    "run.duration_s": "duration",
    "emulator.plate_stiffness_N_per_m": "plate_stiffness",
    "emulator.tau_p_s": "tau_p",
    "emulator.links_per_segment": "links_per_segment",
    "emulator.physics_dt_s": "physics_dt",
}
"""Hardware configuration key → the scenario parameter that sets the same quantity (module docstring)."""


def parameter_doc(name: str) -> ParameterDoc:
    """The documentation of scenario parameter `name`; KeyError naming it when none is declared."""
    if name not in DOCS:
        raise KeyError(f"scenario parameter {name!r} has no documentation in scenarios.parameters.DOCS")
    return DOCS[name]


def hardware_key(name: str) -> str | None:
    """The hardware configuration key that sets scenario parameter `name` (None when there is none)."""
    return next((key for key, parameter in HARDWARE_KEYS.items() if parameter == name), None)
