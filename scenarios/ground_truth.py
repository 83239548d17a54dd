"""The MuJoCo ground truth of a scenario, built once for every MuJoCo scenario (`build_truth`).

The settings (vocabulary.settings; every MuJoCo scenario takes them all, docs/parameters.md):

- the controller's robot `robot` (docs/model.md#rppr-dynamics) with every segment's damping
  d_i × `damping_scale` (> 0; the controller knows it: `scenarios.common.controller_robot`);
- the true arm: `true_robot` (a robot JSON with as many segments; '': the controller's robot,
  damping scaled alike) with, per segment, L_i × `true_length_scale` (inertias I_i × its
  square, as for a rod), k_i × `true_stiffness_scale`, d_i × `true_damping_scale` and
  λ_i × `true_gain_scale` (all 1: the robot itself); masses and pressure limits as given;
- the true plates: facet k of the controller's environment (H_k r <= h_k, m) moved by
  `facet_offset` (m) along its outward normal and turned by `facet_angle` (rad,
  counter-clockwise seen from +z) about the foot of the perpendicular from the base:
  H'_k = R(angle) H_k, h'_k = (h_k + offset ‖H_k‖) cos(angle), exact at 0 and 0;
- the rod and the plant: `links_per_segment`, `tau_p` (s), `physics_dt` (s), `gravity`
  (m/s², along −y; 0: the arm on a table), `tip_friction` and `table_friction` (Coulomb μ);
- the plate: `plate` "ideal" (a slide spring of `plate_stiffness` N/m) or "flexure" (the
  clamped sheet of the `sheet_*` settings, softcbf_mj.flexure), whose stiffness at its
  calibration point (`calibrate_flexure`, N/m) is the scene's plate stiffness.

They are two sections of a MuJoCo scenario's spec (scenarios.spec): `TrueArm` (the arm, the
rod, the plates' pose, gravity and friction) and `Plate`, with `damping_scale` in the
controller's `Model`. `check_true_arm` checks them without building anything (the spec's
check: building the truth there would refuse, at a setting's printed bound, combinations that
only the run can find out about, tests/test_config_files.py); `build_truth` builds them, once
per run, from the controller the spec's check built (`spec.built`, scenarios.common.Controller): a `Truth` whose `config` (`ArmModelConfig`) both the single run's
`MujocoPlant` and the batch's `MujocoBatchPlant` take.

Imports: MuJoCo (softcbf_mj.flexure, flexure_calibration, mjcf) is imported inside
the functions that check or build a ground truth, not at load, so that registering the
scenarios and reading their parameters (`softcbf list`, `softcbf run NAME --help`) stay cheap
(tests/test_cli_lazy.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from controllers.params import RobotParams
from controllers.safe_set import Environment
from scenarios.common import check_choice, load_robot, scale_damping
from scenarios.spec import Model, Plate, TrueArm

if TYPE_CHECKING:  # MuJoCo's modules are imported where they are used (module docstring: Imports)
    from softcbf_mj.flexure import FlexureParams
    from softcbf_mj.mjcf import ArmModelConfig


def flexure(plate: Plate) -> FlexureParams:
    """The flexure sheet of `plate`'s `sheet_*` settings (checked by FlexureParams)."""
    from softcbf_mj.flexure import FlexureParams

    return FlexureParams(clamp_at=plate.sheet_clamp_at, free_end_at=plate.sheet_free_end_at,
                         thickness=plate.sheet_thickness, width=plate.sheet_width,
                         youngs_modulus=plate.sheet_youngs_modulus, links=plate.sheet_links,
                         calibration_fraction=plate.sheet_calibration_fraction)


def check_true_arm(arm: TrueArm, plate: Plate, model_robot: RobotParams) -> None:
    """The checks of a MuJoCo scenario's ground truth: plate kind, sheet, true robot (the same
    number of segments as the controller's) and the model settings (ArmModelConfig's checks, among
    them `table_friction` against `gravity` and the physics step)."""
    from softcbf_mj.mjcf import PLATE_KINDS, ArmModelConfig

    check_choice("plate", plate.kind, PLATE_KINDS)
    if arm.robot:
        true_robot = load_robot(arm.robot)
        if true_robot.n_segments != model_robot.n_segments:
            raise ValueError(f"true_robot has {true_robot.n_segments} segments, the controller's robot "
                             f"{model_robot.n_segments}; they must have the same number")
    ArmModelConfig(plate_stiffness=plate.stiffness, links_per_segment=arm.links_per_segment, tau_p=arm.tau_p,
                   physics_dt=arm.physics_dt, tip_friction=arm.tip_friction, plate=plate.kind, flexure=flexure(plate),
                   table_friction=arm.table_friction, gravity=(0.0, -arm.gravity, 0.0))


@dataclass(frozen=True, eq=False)
class Truth:
    """One sample's MuJoCo ground truth (module docstring).

    config: the true arm and plates' model (build it with `softcbf_mj.mjcf.build_model`);
    robot: the true arm (`config.robot`); plates: the true plates' facets at rest (m);
    plate_stiffness: the true plate's spring in N/m (the flexure's calibrated one).
    """

    config: ArmModelConfig
    plates: Environment
    plate_stiffness: float

    @property
    def robot(self) -> RobotParams:
        return self.config.robot


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


def build_truth(arm: TrueArm, plate: Plate, model: Model, model_robot: RobotParams, environment: Environment) -> Truth:
    """The ground truth of a MuJoCo scenario's checked `arm` and `plate` (module docstring), for the
    controller's `model`, its robot `model_robot` (`scenarios.common.controller_robot`) and facets `environment`."""
    from softcbf_mj.flexure_calibration import calibrate_flexure
    from softcbf_mj.mjcf import ArmModelConfig

    g = arm
    ref = scale_damping(load_robot(g.robot), model.damping_scale) if g.robot else model_robot
    true_arm = scaled_robot(ref, g.length_scale, g.stiffness_scale, g.damping_scale, g.gain_scale)
    moved = moved_facets(environment, g.facet_offset, g.facet_angle)
    true_H, true_h = moved.H, moved.h
    built: dict[str, Any] = dict(robot=true_arm, H=true_H, h=true_h, plate_stiffness=plate.stiffness,
                                 links_per_segment=g.links_per_segment, tau_p=g.tau_p, physics_dt=g.physics_dt,
                                 tip_friction=g.tip_friction, plate=plate.kind, flexure=flexure(plate),
                                 table_friction=g.table_friction)
    if g.gravity:  # else ArmModelConfig's (0, 0, 0), not (0, -0.0, 0)
        built["gravity"] = (0.0, -g.gravity, 0.0)
    config = ArmModelConfig(**built)
    stiffness = calibrate_flexure(config).stiffness_N_per_m if plate.kind == "flexure" else plate.stiffness
    return Truth(config, moved, stiffness)
