"""The MuJoCo ground truth, built once by `build_truth`: the one builder for the scenarios, the environment and the emulator.

The settings are the vocabulary's ground-truth sections (`vocabulary.run_sections`: `TrueArm`
and `Plate`, every setting whose declaration names one of them; docs/parameters.md):

- the true arm: `true_robot` (a robot JSON with as many segments as the controller's, or a
  preset name; '': the controller's robot `model_robot`, its damping already scaled) with, per
  segment, L_i × `true_length_scale` (inertias I_i × its square, as for a rod), k_i ×
  `true_stiffness_scale`, d_i × `true_damping_scale` and λ_i × `true_gain_scale` (all 1: the
  robot itself); masses and pressure limits as given. A `true_robot` file's damping is scaled by
  the controller's `damping_scale` (> 0) as the controller's own robot is (`scale_damping`);
- the true plates: facet k of the controller's facets (H_k r <= h_k, m) moved by `facet_offset`
  (m) along its outward normal and turned by `facet_angle` (rad, counter-clockwise seen from +z)
  about the foot of the perpendicular from the base: H'_k = R(angle) H_k,
  h'_k = (h_k + offset ‖H_k‖) cos(angle), exact at 0 and 0;
- the rod and the plant: `links_per_segment`, `tau_p` (s), `physics_dt` (s), `gravity` (m/s²,
  along −y; 0: the arm on a table), `tip_friction` and `table_friction` (Coulomb μ), and
  `command_delay` (s: the commands reach the valves that much later, a FIFO of whole control
  periods, softcbf_mj.physics.plant; carried by the model, so every MuJoCo plant built from it delays);
- the plate: `plate` "ideal" (a slide spring of `plate_stiffness` N/m) or "flexure" (the clamped
  sheet of the `sheet_*` settings, softcbf_mj.physics.flexure), whose stiffness at its calibration point
  (`calibrate_flexure`, N/m) is the scene's plate stiffness.

Who builds it: the MuJoCo scenarios (scenarios.mujoco_contact, camera_loop: from their spec's
`arm` and `plate` sections), the environment (`softcbf_mj.env.ArmEnvConfig.plant`: from its
keywords of the same names) and the emulator (`softcbf_mj.emulator.emulate`: from the hardware file's
keys of the same names). `check_true_arm` checks the settings without building anything (a
scenario spec's check: building the truth there would refuse, at a setting's printed bound,
combinations that only the run can find out about, tests/test_config_files.py); `build_truth`
builds them, once per run: a `Truth` whose `config` (`ArmModelConfig`) the single run's
`MujocoPlant` and the batch's `MujocoBatchPlant` take.

Robot files: `load_robot` reads the robots every surface names ('reference', a preset of
`ROBOT_PRESETS`, a robot JSON file); a file that cannot be used is a ValueError naming the
setting and the file (`existing_file`, `read_parameter_file`).

Imports: MuJoCo (softcbf_mj.physics.flexure, flexure_calibration, mjcf) is imported inside the
functions that check or build a ground truth, not at load, so that registering the scenarios
and reading their parameters (`softcbf list`, `softcbf run NAME --help`) stay cheap
(tests/test_cli_lazy.py).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from controllers.model.params import RobotParams, reference_robot
from controllers.model.safe_set import Environment
from softcbf_mj.outputs.certified_truth import CertifiedTruth
from vocabulary.project_files import project_file
from vocabulary.run_sections import Plate, TrueArm

if TYPE_CHECKING:  # MuJoCo's modules are imported where they are used (module docstring: Imports)
    from softcbf_mj.physics.flexure import FlexureParams
    from softcbf_mj.physics.mjcf import ArmModelConfig

T = TypeVar("T")

# Named robot files (`load_robot`); each file's "about" says what its constants are and why.
ROBOT_PRESETS: dict[str, str] = {
    "hardware-like": "models/robots/hardware_like.json",
    "three-segment": "models/robots/three_segment.json",
}


def existing_file(name: str, spec: str, expected: str) -> Path:
    """The file a parameter names; ValueError "NAME must be EXPECTED, got SPEC (no such file)"
    when it is not one (also for names the OS refuses: too long, a NUL byte)."""
    path = Path(spec)
    try:
        found = path.is_file()
    except (OSError, ValueError):
        found = False
    if not found:
        raise ValueError(f"{name} must be {expected}, got {spec!r} (no such file)")
    return path


def read_parameter_file(name: str, path: Path, load: Callable[[Path], T]) -> T:
    """`load(path)` of the file a parameter named; any failure to read or parse it becomes
    a ValueError naming the parameter and the file."""
    try:
        return load(path)
    except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:  # JSON and format errors alike
        raise ValueError(f"{name} file {path} cannot be used: {exc}") from None


def load_robot(spec: str, name: str = "robot") -> RobotParams:
    """'' or 'reference' → the docs/model.md#rppr-dynamics reference arm; a name of
    `ROBOT_PRESETS` → that file; otherwise a JSON file written by RobotParams.save (`name`: the
    setting that names it, for the error)."""
    if spec in ("", "reference"):
        return reference_robot()
    if spec in ROBOT_PRESETS:
        return read_parameter_file(name, project_file(ROBOT_PRESETS[spec]), RobotParams.load)
    path = existing_file(name, spec, f"'reference', one of {', '.join(ROBOT_PRESETS)} or a robot JSON file")
    return read_parameter_file(name, path, RobotParams.load)


def scale_damping(robot: RobotParams, scale: float) -> RobotParams:
    """`robot` with every segment's damping d_i multiplied by `scale` (> 0): time constants d_i/k_i × scale."""
    return robot.replace(damping=tuple(scale * d for d in robot.damping)) if scale != 1.0 else robot


def flexure(plate: Plate) -> FlexureParams:
    """The flexure sheet of `plate`'s `sheet_*` settings (checked by FlexureParams)."""
    from softcbf_mj.physics.flexure import FlexureParams

    return FlexureParams(clamp_at=plate.sheet_clamp_at, free_end_at=plate.sheet_free_end_at,
                         thickness=plate.sheet_thickness, width=plate.sheet_width,
                         youngs_modulus=plate.sheet_youngs_modulus, links=plate.sheet_links,
                         calibration_fraction=plate.sheet_calibration_fraction)


def _model_settings(arm: TrueArm, plate: Plate) -> dict[str, Any]:
    """The `ArmModelConfig` fields that `arm` and `plate` set directly (not the robot and the facets)."""
    built: dict[str, Any] = dict(plate_stiffness=plate.stiffness, links_per_segment=arm.links_per_segment, tau_p=arm.tau_p,
                                 physics_dt=arm.physics_dt, tip_friction=arm.tip_friction, plate=plate.kind,
                                 flexure=flexure(plate), table_friction=arm.table_friction,
                                 command_delay=arm.command_delay)
    if arm.gravity:  # else ArmModelConfig's (0, 0, 0), not (0, -0.0, 0)
        built["gravity"] = (0.0, -arm.gravity, 0.0)
    return built


def check_true_arm(arm: TrueArm, plate: Plate, model_robot: RobotParams) -> None:
    """The checks of a ground truth: plate kind, sheet, true robot (the same number of segments as the
    controller's) and the model settings (ArmModelConfig's checks, among them `table_friction` against
    `gravity` and the physics step)."""
    from softcbf_mj.physics.mjcf import PLATE_KINDS, ArmModelConfig

    if plate.kind not in PLATE_KINDS:
        raise ValueError(f"plate must be one of {', '.join(PLATE_KINDS)}, got {plate.kind!r}")
    if arm.robot:
        true_robot = load_robot(arm.robot, "true_robot")
        if true_robot.n_segments != model_robot.n_segments:
            raise ValueError(f"true_robot has {true_robot.n_segments} segments, the controller's robot "
                             f"{model_robot.n_segments}; they must have the same number")
    ArmModelConfig(**_model_settings(arm, plate))


@dataclass(frozen=True, eq=False)
class Truth:
    """One sample's MuJoCo ground truth (module docstring).

    config: the true arm and plates' model (build it with `softcbf_mj.physics.mjcf.build_model`);
    robot: the true arm (`config.robot`); plates: the true plates' facets at rest (m);
    plate_stiffness: the true plate's spring in N/m (the flexure's calibrated one); facet_offset (m) and
    facet_angle (rad): how the plates were moved (`moved_facets`).
    """

    config: ArmModelConfig
    plates: Environment
    plate_stiffness: float
    facet_offset: float = 0.0
    facet_angle: float = 0.0

    @property
    def robot(self) -> RobotParams:
        return self.config.robot

    def certified(self, model_robot: RobotParams, assumed_plate_stiffness: float) -> CertifiedTruth:
        """The true values of what a filter may certify online (`softcbf_mj.outputs.certified_truth`), against the
        controller's robot `model_robot` and plate stiffness `assumed_plate_stiffness` (N/m): each segment's
        (λ_i/λ̂_i)/(k_i/k̂_i); the ideal plate's stiffness ratio and, untilted, its offset (m)."""
        ratio = (self.robot.array("gains") / model_robot.array("gains")) / (
            self.robot.array("stiffness") / model_robot.array("stiffness"))
        ideal = self.config.plate == "ideal"
        return CertifiedTruth(tuple(float(r) for r in ratio),
                              self.plate_stiffness / assumed_plate_stiffness if ideal else None,
                              self.facet_offset if ideal and self.facet_angle == 0.0 else None)


def scaled_robot(ref: RobotParams, length_scale: float, stiffness_scale: float, damping_scale: float,
                 gain_scale: float) -> RobotParams:
    """The true arm of the module docstring: `ref` with L_i, k_i, d_i, λ_i scaled (I_i × length_scale²)."""
    return RobotParams(
        lengths=ref.array("lengths") * length_scale, masses=ref.masses,
        stiffness=ref.array("stiffness") * stiffness_scale, damping=ref.array("damping") * damping_scale,
        gains=ref.array("gains") * gain_scale, u_min=ref.u_min, u_max=ref.u_max,
        inertias=ref.array("inertias") * length_scale**2,
    )


def moved_facets(environment: Environment, offset: float, angle: float) -> Environment:
    """The true plates of the module docstring: every facet moved by `offset` (m) along its outward normal and
    turned by `angle` (rad) about the foot of the perpendicular from the base."""
    H, h = environment.H, environment.h
    cos_a, sin_a = math.cos(angle), math.sin(angle)
    return Environment(np.column_stack((H[:, 0] * cos_a - H[:, 1] * sin_a, H[:, 0] * sin_a + H[:, 1] * cos_a)),
                       (h + offset * np.hypot(H[:, 0], H[:, 1])) * cos_a)


def build_truth(arm: TrueArm, plate: Plate, model_robot: RobotParams, environment: Environment,
                damping_scale: float) -> Truth:
    """The ground truth of the checked sections `arm` and `plate` (module docstring), for the controller's robot
    `model_robot` (its damping scaled by `damping_scale` already), its facets `environment` and its
    `damping_scale` (applied to a `true_robot` file's damping)."""
    from softcbf_mj.physics.flexure_calibration import calibrate_flexure
    from softcbf_mj.physics.mjcf import ArmModelConfig

    ref = scale_damping(load_robot(arm.robot, "true_robot"), damping_scale) if arm.robot else model_robot
    true_arm = scaled_robot(ref, arm.length_scale, arm.stiffness_scale, arm.damping_scale, arm.gain_scale)
    moved = moved_facets(environment, arm.facet_offset, arm.facet_angle)
    config = ArmModelConfig(robot=true_arm, H=moved.H, h=moved.h, **_model_settings(arm, plate))
    stiffness = calibrate_flexure(config).stiffness_N_per_m if plate.kind == "flexure" else plate.stiffness
    return Truth(config, moved, stiffness, arm.facet_offset, arm.facet_angle)
