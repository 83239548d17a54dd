"""The typed sections of a run, settings only: one home for the scenarios, the environment and the hardware file.

A section is a frozen dataclass of settings (`vocabulary.sections.section`): each field is a
setting of `vocabulary.settings.SETTINGS`, typed by its `kind` and checked by `check_value`
when the section is built; a field left out holds `UNSET` ("the context's default"), which a
scenario's spec (`scenarios.spec`), the environment (`softcbf_mj.env.ArmEnvConfig`) or the
hardware file's emulator (`hardware.config`) resolves to `default(setting, context)`.

- `Run`: the run's length (s), seed, initial pose noise (rad) and progress line;
- `Model`: the controller's model: its robot (damping × damping_scale), facets, force limit (N)
  and the row scaling of its force-safe set;
- `TrueArm` and `Plate`: the ground truth (`softcbf_mj.physics.ground_truth.build_truth`, its one
  builder). Their fields are not listed here: they are every setting that declares the section
  (`Setting.section`, `vocabulary.settings.section_settings`), in declaration order, so that a
  new ground-truth setting is one entry of the vocabulary;
- `Camera`: the camera path (plant tick, frame rate, latency, drops, noise, the safety monitor's
  hold, the estimator, the image, calibration, detector, saved frames).

A surface that holds the settings flat, by their names (the environment's keywords, the hardware
file's top-level keys), makes the sections from them with `sections_of(values, *classes)`;
`ground_truth_values(values)` is the ground truth's pair (`TrueArm`, `Plate`) that `build_truth` takes.

The control rate (Hz) is a setting of its own (`control_rate`) that each loop takes beside these
sections; the controller under test (`Filter`, `Nominal`) has sections of its own in
`scenarios.spec`, which type its parameters by the plug-in's declarations.
"""

from __future__ import annotations

from typing import Any

from vocabulary.sections import section, setting_fields
from vocabulary.settings import section_settings

__all__ = ["Run", "Model", "TrueArm", "Plate", "Camera", "sections_of", "ground_truth_values"]

Run = section("Run", "The run: its length (s), seed, initial pose noise (rad) and progress line.",
              {"duration": "duration", "seed": "seed", "q0_std": "q0_std", "progress": "progress"}, __name__)
Model = section("Model", "The controller's model: its robot (damping × damping_scale), facets, force limit (N) "
                         "and row scaling of the force-safe set.",
                {"robot": "robot", "damping_scale": "damping_scale", "environment": "environment", "f_max": "f_max",
                 "row_scaling": "row_scaling"}, __name__)
TrueArm = section("TrueArm", "The true arm of the ground truth (softcbf_mj.physics.ground_truth): its robot and scale factors, "
                             "the rod, the true plates' pose, gravity and friction.", section_settings("TrueArm"), __name__)
Plate = section("Plate", "The true plate: ideal (a slide spring) or flexure (the clamped sheet of the sheet_* "
                         "settings).", section_settings("Plate"), __name__)
Camera = section("Camera", "The camera path: plant tick, frame rate, latency, drops, noise, the safety monitor's "
                           "hold, the estimator, the image, calibration, detector and saved frames.",
                 {"tick": "tick", "frame_rate": "frame_rate", "latency": "latency", "drop_rate": "drop_rate",
                  "pixel_noise": "pixel_noise", "hold_s": "hold_s", "max_hold_s": "max_hold_s",
                  "qd_filter_tau": "qd_filter_tau", "width": "width", "height": "height",
                  "calibration": "calibration", "detector": "detector", "tracking": "tracking",
                  "saved_frames_hz": "saved_frames_hz"}, __name__)


def sections_of(values: Any, *classes: type) -> tuple[Any, ...]:
    """One instance of each section class of `classes`, its fields read by their settings' names from `values`
    (an object with an attribute per setting, e.g. `ArmEnvConfig` or the hardware file's emulator section)."""
    return tuple(cls(**{f: getattr(values, key) for f, key in setting_fields(cls).items()}) for cls in classes)


def ground_truth_values(values: Any) -> tuple[Any, Any]:
    """The ground truth's sections (`TrueArm`, `Plate`) of `values` (`sections_of`)."""
    return sections_of(values, TrueArm, Plate)
