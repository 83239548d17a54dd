"""Every setting, declared once: its name, meaning, SI unit, valid values and plausibility bound.

A setting's name means the same quantity wherever it is given: `f_max` is the force limit
F_max per facet in N on the command line (`--f-max`), in a run configuration file
(`f_max = 0.16`), in a study (`fixed.f_max`, `vary.f_max`) and in the hardware file
(`f_max = 0.16`, top level). `SETTINGS[name]` is a `Setting`:

- `meaning`: what it sets, in a phrase; `unit`: SI unit ("" for a dimensionless number,
  a name or a switch);
- `kind`: float, int, bool, str or tuple (the value's type; an int is accepted for a float
  and becomes one; a tuple is a sequence of names, e.g. the tunings ("None", "High"), whose
  *flat form* on the command line, in a TOML file and in config.json is the comma list
  "None,High": `flat_form`, `Setting.flat_kind`; either form is accepted and becomes the tuple);
- `bound`: the valid range of a number (`Bound`, None for a non-number); a float outside
  it, or not finite, is refused;
- `plausible`: a plausibility bound |value| <= plausible in `unit` (None: none): a value
  beyond it is almost surely given in the wrong unit, and the refusal names the likely
  mistake (`LIKELY_MISTAKES`: seconds given in ms, hPa in Pa, m in mm, rad in degrees):
  "tau_p must be <= 5 s (a plausibility bound; a value in ms? 50 ms = 0.05 s), got 50.0";
- `valid`: the valid values a range does not say (names, files, switches);
- `default`: the value a run takes when none is given (of `kind`, within `bound`).

One home per default. `default(name, context)` is the default every configuration surface
takes: the scenario signatures (`plate_stiffness: float = default("plate_stiffness",
"mujoco_contact")`; the CLI, `softcbf list` and `--help` read `inspect.signature`), the
hardware file's fields (context "hardware"), the environment's keyword arguments
(softcbf_mj.env.ArmEnvConfig, context "environment") and softcbf bench's cases (the
scenario's context). Where a context needs another default (paper_sim runs without the
pressure box at 1 kHz, camera_loop and the hardware emulator on a coarser rod, the
environment without a filter), `DEFAULT_OVERRIDES` says so, the one table of such overrides; no other module types a
setting's default (tests/test_setting_defaults.py). The physical-constant classes above
(softcbf_mj.physics.mjcf's `ArmModelConfig` and its constants, softcbf_mj.physics.flexure's `FlexureParams`,
softcbf_mj.loops.camera_loop's `CameraTiming`) take their defaults from here; the paper's plate stiffness and
force limit, which the controller's `paper_safe_set` needs below this layer, are
`controllers.model.paper_experiment`'s constants, imported here. No other product module types a declared default as a literal
(tests/test_literal_defaults.py).

Ground truth. A setting with a `section` ("TrueArm": the true arm, the rod, the plates' pose,
gravity and friction; "Plate": the true plate) is a setting of the ground truth: it is the field
`field` (default: its own name) of that section (`vocabulary.run_sections`), which
`softcbf_mj.physics.ground_truth.build_truth`, the one builder of the ground truth, takes. Every surface
that builds a ground truth takes all of them by name (`ground_truth_settings()`): the MuJoCo
scenarios' specs, the environment's keywords and the hardware file's emulator keys; so a new
ground-truth setting is one entry here plus its use in `build_truth` (tests/test_one_surface.py).

`check_value(name, value)` is the one check of a setting's value, wherever it comes
from; it returns the value normalised (an int given for a float becomes a float) or
raises `SettingError` (a ValueError) whose message names the setting, the bound with its
unit and the value: "f_max must be > 0 N, got -1.0". `check_number` is the same check for
a number that is not a shared setting (a hardware-only key such as safety.watchdog_s).
`Bound`, `SettingError`, `check_number` and the plausibility hints live in
`controllers.core.bounds` (the built-in filters' parameters use them too, and the controller
under test imports nothing of the testbed); they are imported here under the same names.
A scenario may hold a setting to a narrower range of its own (`scenarios.register`'s
bounds, e.g. camera_loop's image size <= its render's); it checks that after this one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

from controllers.core.bounds import (  # noqa: F401  (re-exported: the settings' range and check)
    LIKELY_MISTAKES, Bound, SettingError, check_number, finite, non_negative, positive,
)
from controllers.contract.filter_parameters import Params
from controllers.model.paper_experiment import PAPER_F_MAX, PAPER_PLATE_STIFFNESS


@dataclass(frozen=True)
class Setting:
    """One setting's declaration (module docstring)."""

    meaning: str
    unit: str = ""
    kind: type = str
    bound: Bound | None = None
    plausible: float | None = None
    valid: str = ""
    default: Any = None
    section: str = ""
    field: str = ""

    @property
    def flat_kind(self) -> type:
        """The type of the setting's flat form (the command line, files): str for a tuple of names, else `kind`."""
        return str if self.kind is tuple else self.kind

    @property
    def valid_values(self) -> str:
        """The valid values in words: the range (and the plausibility bound), else `valid`."""
        if self.bound is None:
            return self.valid
        text = str(self.bound)
        if self.plausible is not None:
            one_sided = self.bound.low is not None and self.bound.low >= 0
            text += f", plausibly {'<= ' if one_sided else 'within ±'}{self.plausible:g}{' ' + self.unit if self.unit else ''}"
        return f"{text} {self.valid}" if self.valid else text


# The unit mistake a value beyond a plausibility bound most likely is: unit → (wrong unit, factor to the right one).
PRESSURE_RANGE_HPA = 3276.7  # hPa, the valve protocol's range (hardware.protocol; tests/test_vocabulary.py)


def _number(meaning: str, unit: str, bound: Bound, plausible: float | None = None, valid: str = "", *,
            default: float) -> Setting:
    return Setting(meaning, unit, float, bound, plausible, valid, default)


def _integer(meaning: str, unit: str, bound: Bound, *, default: int) -> Setting:
    return Setting(meaning, unit, int, bound, default=default)


def _switch(meaning: str, *, default: bool) -> Setting:
    return Setting(meaning, "", bool, valid="true, false", default=default)


def _text(meaning: str, valid: str, *, default: str) -> Setting:
    return Setting(meaning, "", str, valid=valid, default=default)


def _names(meaning: str, valid: str, *, default: tuple[str, ...]) -> Setting:
    return Setting(meaning, "", tuple, valid=valid, default=default)


GROUND_TRUTH_SECTIONS = ("TrueArm", "Plate")  # the sections of the ground truth (module docstring: Ground truth)


def _part(declared: Setting, section: str, field: str = "") -> Setting:
    """`declared` as a field of ground-truth section `section` (`field`: its name there, default the setting's)."""
    return replace(declared, section=section, field=field)


_SHEET = "flexure sheet (plate = 'flexure', docs/beyond-the-paper.md#flexure-plate): "
_TRUE_ARM = "the MuJoCo arm's "
_SCALE = Bound(1e-3, 1e3)  # a multiple of the robot's: beyond, the arm's numbers overflow

SETTINGS: dict[str, Setting] = {
    # the run
    "duration": _number("simulated time of each run (one per tuning); the hardware run's length after the first estimate",
                        "s", positive("s"), 86400.0, default=100.0),
    "seed": _integer("random seed of the initial pose noise and the camera's noise and drops", "", Bound(0), default=0),
    "q0_std": _number("std of the Gaussian noise on the straight initial pose, per segment", "rad",
                      Bound(0.0, math.pi, unit="rad"), default=0.0),
    "progress": _switch("show a progress line on stderr", default=True),
    # the controller under test (scenarios.common, controllers.registry)
    "tunings": _names("runs of paper-cbf: its presets, one run each (a comma list on the command line and in files)",
                      "None, Low, High, HW-Low, HW-High, custom (a_E, b_E, gamma from filter_params)",
                      default=("None", "Low", "High")),
    "filter": _text("the safety filter under test",
                    "a built-in filter (softcbf list: paper-cbf, none, c-erg, ...), a preset (c-erg:recommended), "
                    "FILE.py:Factory or package.module:Factory", default="paper-cbf"),
    "filter_params": Setting("the filter's parameters, typed by the filter's declarations (--filter-param NAME=VALUE, "
                             "repeatable; a table [filter_params] in a file)", "", Params,
                             valid="the filter's parameters (softcbf list)", default=Params()),
    "nominal": _text("the nominal controller", "sinusoid, tip-tracker, step, force-target, FILE.py:Factory, package.module:Factory",
                     default="sinusoid"),
    "nominal_params": Setting("the nominal's parameters, typed by the nominal's declarations (--nominal-param "
                              "NAME=VALUE, repeatable; a table [nominal_params] in a file)", "", Params,
                              valid="the nominal's parameters (softcbf list)", default=Params()),
    "amplitude": _number("sinusoid nominal: amplitude A of u_nom,j = A sin(2π f (t + t0))", "hPa",
                         finite("hPa"), PRESSURE_RANGE_HPA, default=80.0),
    "frequency": _number("sinusoid nominal: frequency f", "Hz", positive("Hz"), default=0.01),
    "t0": _number("sinusoid nominal: time offset (> 0 starts later in the cycle)", "s", finite("s"), default=0.0),
    "pressure_limits": _switch("the filter's QP holds the robot's pressure box", default=True),
    "isolate": _switch("run the filter and the nominal in a process of their own (closedloop.isolation: "
                       "protection against hostile code, at a cost per call; docs/safety-filter.md)", default=False),
    "qp_backend": _text("QP solver of the filter", "native, daqp, qpsolvers:daqp, qpsolvers:quadprog, "
                                                    "qpsolvers:osqp (those installed)", default="native"),
    "control_rate": _number("rate of the controller's calls (zero-order hold between)", "Hz", positive("Hz"), 1e4, default=10.0),
    # the controller's model
    "robot": _text("the controller's robot model",
                   "'reference', a preset of models/robots (hardware-like, three-segment) or a robot JSON file (docs/file-formats.md#robot-json)",
                   default="reference"),
    "environment": _text("the facets H r <= h of the free space",
                         "'paper' or an environment JSON file (docs/file-formats.md#environment-json)", default="paper"),
    "f_max": _number("force limit F_max per facet", "N", positive("N"), default=PAPER_F_MAX),
    "row_scaling": _text("scaling of the rows of the force-safe set P", "paper, unit", default="paper"),
    "assumed_plate_stiffness": _number("the controller's plate spring ψ(n) = k n", "N/m", positive("N/m"),
                                       default=PAPER_PLATE_STIFFNESS),
    "assumed_tau_p": _number("the controller's valve pressure time constant τ_p (its filter context's; the true "
                             "one is tau_p)", "s", non_negative("s"), 5.0, default=0.05),
    "assumed_command_delay": _number("the controller's command delay, call → command at the valves (its filter "
                                     "context's; the true one is command_delay)", "s", non_negative("s"), 5.0,
                                     default=0.0),
    # the plant (ground truth): the true arm (`TrueArm`), then the true plate (`Plate`); module docstring
    "integrator": _text("integrator of the PCC plant", "ros2, rk4, euler", default="ros2"),
    "damping_scale": _number("damping d of both the controller's robot and the true arm, as a multiple of the "
                             "robot's (the arm's time constants d/k scale with it; the controller knows it)", "", positive(),
                             default=1.0),
    "true_robot": _part(_text(_TRUE_ARM + "robot when it differs from the controller's",
                              "'' (the controller's robot) or a robot JSON file, same number of segments", default=""),
                        "TrueArm", "robot"),
    "true_stiffness_scale": _part(_number(_TRUE_ARM + "stiffness k as a multiple of the robot's", "", _SCALE, default=1.0),
                                  "TrueArm", "stiffness_scale"),
    "true_damping_scale": _part(_number(_TRUE_ARM + "damping d as a multiple of the robot's", "", _SCALE, default=1.0),
                                "TrueArm", "damping_scale"),
    "true_gain_scale": _part(_number(_TRUE_ARM + "actuator gain λ as a multiple of the robot's", "", _SCALE, default=1.0),
                             "TrueArm", "gain_scale"),
    "true_length_scale": _part(_number(_TRUE_ARM + "segment lengths as a multiple of the robot's (inertias by its square)",
                                       "", _SCALE, default=1.0), "TrueArm", "length_scale"),
    "links_per_segment": _part(_integer(_TRUE_ARM + "rigid links per segment", "", Bound(1, 100), default=10), "TrueArm"),
    "tau_p": _part(_number("valve pressure time constant of the MuJoCo actuators (first order)", "s", non_negative("s"),
                           5.0, default=0.05), "TrueArm"),
    "command_delay": _part(_number("time from the controller's command to the valves' input: a FIFO of commands, a "
                                   "whole number of the plant's control periods (softcbf_mj.physics.plant; the filter is told "
                                   "assumed_command_delay)", "s", non_negative("s"), 5.0, default=0.0), "TrueArm"),
    "physics_dt": _part(_number("MuJoCo time step (divides the control or tick period)", "s", Bound(1e-6, unit="s"), 1e-3,
                                default=1e-4), "TrueArm"),
    "facet_offset": _part(_number("the true plates moved along their outward normals (> 0: farther from the base)", "m",
                                  Bound(-1.0, 1.0, unit="m"), default=0.0), "TrueArm"),
    "facet_angle": _part(_number("the true plates turned counter-clockwise about the foot of the perpendicular", "rad",
                                 Bound(-math.pi / 2, math.pi / 2, low_open=True, high_open=True, unit="rad"), default=0.0),
                         "TrueArm"),
    "gravity": _part(_number("gravity along -y (0: the arm lies on a table)", "m/s²", non_negative("m/s²"), default=0.0),
                     "TrueArm"),
    "tip_friction": _part(_number("Coulomb friction coefficient μ between the arm and the plates", "", non_negative(),
                                  default=0.0), "TrueArm"),
    "table_friction": _part(_number("Coulomb friction coefficient μ between the arm's links and the table it lies on "
                                    "(0: off; not with gravity)", "", Bound(0.0, 2.0), default=0.0), "TrueArm"),
    "plate": _part(_text("kind of true plate", "ideal (slide spring), flexure (clamped sheet in a force gauge)",
                         default="ideal"), "Plate", "kind"),
    "plate_stiffness": _part(_number("the true plate's spring (paper_sim: also the controller's ψ)", "N/m", positive("N/m"),
                                     default=PAPER_PLATE_STIFFNESS), "Plate", "stiffness"),
    "sheet_clamp_at": _part(_number(_SHEET + "clamp position along the facet", "m", finite("m"), default=-0.055), "Plate"),
    "sheet_free_end_at": _part(_number(_SHEET + "free-end position along the facet", "m", finite("m"),
                                       valid="(!= sheet_clamp_at)", default=-0.205), "Plate"),
    "sheet_thickness": _part(_number(_SHEET + "thickness", "m", positive("m"), default=1.23044e-3), "Plate"),
    "sheet_width": _part(_number(_SHEET + "width", "m", positive("m"), default=0.04), "Plate"),
    "sheet_youngs_modulus": _part(_number(_SHEET + "Young's modulus", "Pa", positive("Pa"), default=2.0e9), "Plate"),
    "sheet_links": _part(_integer(_SHEET + "rigid links of the sheet", "", Bound(1), default=10), "Plate"),
    "sheet_calibration_fraction": _part(_number(_SHEET + "calibration point as a fraction of its length from the clamp",
                                                "", Bound(0.0, 1.0, low_open=True), default=1.0), "Plate"),
    # the camera path (camera_loop, the hardware's camera)
    "tick": _number("plant tick: exposures, deliveries and controller calls fall on it; the time series' step", "s",
                    positive("s"), default=2e-3),
    "frame_rate": _number("camera frame rate (hardware: the virtual camera's)", "Hz", positive("Hz"), 1000.0, default=12.8),
    "latency": _number("exposure → detections available to the controller", "s", non_negative("s"), default=0.03),
    "drop_rate": _number("fraction of frames lost (seeded)", "", Bound(0.0, 1.0, high_open=True), default=0.0),
    "pixel_noise": _number("std of the Gaussian image noise", "grey levels", non_negative("grey levels"), default=0.0),
    "hold_s": _number("the safety monitor holds the last command this long before it vents", "s", non_negative("s"), 10.0,
                      default=0.5),
    "max_hold_s": _number("an estimate older than this is stale", "s", positive("s"), 10.0, default=0.3),
    "qd_filter_tau": _number("first-order low pass of the estimated q̇ (0: raw finite differences)", "s",
                             non_negative("s"), 10.0, default=0.0),
    "width": _integer("camera image width (hardware: the virtual camera's)", "px", Bound(8, unit="px"), default=1280),
    "height": _integer("camera image height (hardware: the virtual camera's)", "px", Bound(8, unit="px"), default=720),
    "calibration": _text("the image-to-plane map",
                         "board (fit from a render of the tag board), truth (MuJoCo's exact map), "
                         "or a calibration JSON file (tools/calibrate_camera.py)", default="board"),
    "detector": _text("AprilTag detector backend", "opencv, pupil", default="opencv"),
    "tracking": _switch("detect tags in windows around their last positions (false: whole frame)", default=True),
    "saved_frames_hz": _number("rate of camera frames saved to frames/<run>/ (0: none)", "Hz", non_negative("Hz"), default=0.5),
}


DEFAULT_OVERRIDES: dict[str, dict[str, Any]] = {
    # the paper's simulation (§V): no pressure box, as in the paper; its 1 kHz controller
    "paper_sim": {"pressure_limits": False, "control_rate": 1000.0},
    "mujoco_contact": {},
    "pcc_contact": {},  # mujoco_contact's errors on the PCC plant (scenarios.pcc_contact)
    # the paper's hardware experiment in MuJoCo: the hardware tunings; a coarser rod for a 2 ms tick
    # (softcbf_mj.physics.mjcf.CAMERA_LINKS_PER_SEGMENT, CAMERA_PHYSICS_DT)
    "camera_loop": {"tunings": ("None", "HW-Low", "HW-High"), "links_per_segment": 5, "physics_dt": 2e-4},
    # the hardware file: the emulator's coarser rod (5 links at 0.2 ms run ≈ 9× real time), a smaller
    # virtual camera, and no calibration (None: required unless the camera is virtual)
    "hardware": {"links_per_segment": 5, "physics_dt": 2e-4, "width": 480, "height": 270, "calibration": None},
    # the environment (softcbf_mj.env's keyword arguments): the unfiltered arm, a policy's to learn on, at the
    # paper's 1 kHz
    "environment": {"filter": "none", "control_rate": 1000.0},
}
"""Where one context (a scenario's name, "hardware" for the hardware file, "environment" for
softcbf_mj.env's `ArmEnvConfig`) needs another default
than the declared one: context → {setting: default}. The one place a default differs by context."""


def default(name: str, context: str) -> Any:
    """Setting `name`'s default in `context` (a key of `DEFAULT_OVERRIDES`): the context's override,
    else the declared default (`Setting.default`); KeyError naming an undeclared setting or context."""
    declared = setting(name)
    if context not in DEFAULT_OVERRIDES:
        raise KeyError(f"context {context!r} is not a key of vocabulary.settings.DEFAULT_OVERRIDES "
                       f"({', '.join(DEFAULT_OVERRIDES)})")
    return DEFAULT_OVERRIDES[context].get(name, declared.default)

def section_settings(section: str) -> dict[str, str]:
    """Field name → setting name of the declared section `section` (`Setting.section`: "TrueArm", "Plate"), in
    declaration order; KeyError naming an undeclared section."""
    fields = {declared.field or name: name for name, declared in SETTINGS.items() if declared.section == section}
    if not fields:
        raise KeyError(f"no setting of vocabulary.settings.SETTINGS declares section {section!r}")
    return fields


def ground_truth_settings() -> tuple[str, ...]:
    """The names of the ground truth's settings (`GROUND_TRUTH_SECTIONS`), in declaration order: what every
    surface that builds a ground truth takes (the scenarios, the environment, the hardware file's emulator)."""
    return tuple(name for section in GROUND_TRUTH_SECTIONS for name in section_settings(section).values())


def setting(name: str) -> Setting:
    """The declaration of setting `name`; KeyError naming it when none is declared."""
    if name not in SETTINGS:
        raise KeyError(f"setting {name!r} is not declared in vocabulary.settings.SETTINGS")
    return SETTINGS[name]


def flat_form(name: str, value: Any) -> Any:
    """Setting `name`'s `value` in its flat form (the command line's, a file's; module docstring): a tuple
    of names as the comma list "None,High", any other value unchanged."""
    if setting(name).kind is tuple and isinstance(value, (tuple, list)):
        return ",".join(value)
    return value


def _names_value(key: str, declared: Setting, value: Any) -> tuple[str, ...]:
    """A tuple-of-names setting's value (a comma list, or a sequence of names) as the tuple of its names,
    stripped, empty ones left out; SettingError for anything else."""
    names = value.split(",") if isinstance(value, str) else value
    if not isinstance(names, (list, tuple)) or not all(isinstance(n, str) for n in names):
        raise SettingError(f"{key} must be a sequence of names or a comma list ({declared.valid}), got {value!r}")
    return tuple(n.strip() for n in names if n.strip())


def check_value(name: str, value: Any, key: str | None = None) -> Any:
    """Setting `name`'s `value` checked against its declaration (module docstring) and
    normalised; SettingError naming `key` (default `name`; e.g. "amplitude[1]" for one
    segment's value), the bound with its unit and the value."""
    declared = setting(name)
    key = name if key is None else key
    if declared.kind is tuple:
        return _names_value(key, declared, value)
    if declared.bound is not None:
        return check_number(key, value, declared.bound, plausible=declared.plausible, unit=declared.unit,
                            integer=declared.kind is int)
    if not isinstance(value, declared.kind) or (declared.kind is not bool and isinstance(value, bool)):
        raise SettingError(f"{key} must be {'true or false' if declared.kind is bool else 'a ' + declared.kind.__name__}"
                           f"{' (' + declared.valid + ')' if declared.valid and declared.kind is not bool else ''}, "
                           f"got {value!r}")
    return value
