"""The MuJoCo ground truth of a scenario, built once for every MuJoCo scenario (`build_truth`).

The settings (vocabulary.settings; every MuJoCo scenario takes them all, docs/parameters.md):

- the controller's robot `robot` (docs/model.md#rppr-dynamics) with every segment's damping
  d_i × `damping_scale` (> 0; the controller knows it: `controller_robot`);
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

`check_true_arm` checks these without building anything (`scenarios.Scenario.validate`);
`build_truth` builds them: a `Truth` whose `config` (`ArmModelConfig`) both the single run's
`MujocoPlant` and the batch's `MujocoBatchPlant` take.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from controllers.params import RobotParams
from controllers.safe_set import Environment
from scenarios.common import check_choice, load_robot
from softcbf_mj.flexure import FlexureParams
from softcbf_mj.flexure_calibration import calibrate_flexure
from softcbf_mj.model_builder import PLATE_KINDS, ArmModelConfig


def flexure_params(params: Mapping[str, Any]) -> FlexureParams:
    """The flexure sheet of a scenario's `sheet_*` parameters (checked by FlexureParams)."""
    return FlexureParams(clamp_at=params["sheet_clamp_at"], free_end_at=params["sheet_free_end_at"],
                         thickness=params["sheet_thickness"], width=params["sheet_width"],
                         youngs_modulus=params["sheet_youngs_modulus"], links=params["sheet_links"],
                         calibration_fraction=params["sheet_calibration_fraction"])


def scale_damping(robot: RobotParams, scale: float) -> RobotParams:
    """`robot` with every segment's damping d_i multiplied by `scale` (> 0): time constants d_i/k_i × scale."""
    return robot.replace(damping=tuple(scale * d for d in robot.damping)) if scale != 1.0 else robot


def controller_robot(params: Mapping[str, Any]) -> RobotParams:
    """The controller's robot model: `robot` with its damping × `damping_scale` (module docstring)."""
    return scale_damping(load_robot(params["robot"]), params["damping_scale"])


def check_true_arm(params: Mapping[str, Any], model_robot: RobotParams) -> None:
    """The checks of a MuJoCo scenario's ground truth: plate kind, sheet, true robot (the same
    number of segments as the controller's) and the model settings (ArmModelConfig's checks, among
    them `table_friction` against `gravity` and the physics step)."""
    check_choice("plate", params["plate"], PLATE_KINDS)
    if params["true_robot"]:
        true_robot = load_robot(params["true_robot"])
        if true_robot.n_segments != model_robot.n_segments:
            raise ValueError(f"true_robot has {true_robot.n_segments} segments, the controller's robot "
                             f"{model_robot.n_segments}; they must have the same number")
    ArmModelConfig(plate_stiffness=params["plate_stiffness"], links_per_segment=params["links_per_segment"],
                   tau_p=params["tau_p"], physics_dt=params["physics_dt"], tip_friction=params["tip_friction"],
                   plate=params["plate"], flexure=flexure_params(params), table_friction=params["table_friction"],
                   gravity=(0.0, -params["gravity"], 0.0))


@dataclass(frozen=True, eq=False)
class Truth:
    """One sample's MuJoCo ground truth (module docstring).

    config: the true arm and plates' model (build it with `softcbf_mj.model_builder.build_model`);
    robot: the true arm (`config.robot`); plates: the true plates' facets at rest (m);
    plate_stiffness: the true plate's spring in N/m (the flexure's calibrated one).
    """

    config: ArmModelConfig
    plates: Environment
    plate_stiffness: float

    @property
    def robot(self) -> RobotParams:
        return self.config.robot


def build_truth(params: Mapping[str, Any], model_robot: RobotParams, environment: Environment) -> Truth:
    """The ground truth of a MuJoCo scenario's checked `params` (module docstring), for the
    controller's robot `model_robot` (`controller_robot`) and facets `environment`."""
    ref = scale_damping(load_robot(params["true_robot"]), params["damping_scale"]) if params["true_robot"] else model_robot
    length_scale = params["true_length_scale"]
    arm = RobotParams(
        lengths=ref.array("lengths") * length_scale, masses=ref.masses,
        stiffness=ref.array("stiffness") * params["true_stiffness_scale"],
        damping=ref.array("damping") * params["true_damping_scale"],
        gains=ref.array("gains") * params["true_gain_scale"], u_min=ref.u_min, u_max=ref.u_max,
        inertias=ref.array("inertias") * length_scale**2,
    )
    H, h = environment.H, environment.h
    cos_a, sin_a = math.cos(params["facet_angle"]), math.sin(params["facet_angle"])
    true_H = np.column_stack((H[:, 0] * cos_a - H[:, 1] * sin_a, H[:, 0] * sin_a + H[:, 1] * cos_a))
    true_h = (h + params["facet_offset"] * np.hypot(H[:, 0], H[:, 1])) * cos_a
    model: dict[str, Any] = dict(robot=arm, H=true_H, h=true_h, plate_stiffness=params["plate_stiffness"],
                                 links_per_segment=params["links_per_segment"], tau_p=params["tau_p"],
                                 physics_dt=params["physics_dt"], tip_friction=params["tip_friction"],
                                 plate=params["plate"], flexure=flexure_params(params),
                                 table_friction=params["table_friction"])
    if params["gravity"]:  # else ArmModelConfig's (0, 0, 0), not (0, -0.0, 0)
        model["gravity"] = (0.0, -params["gravity"], 0.0)
    config = ArmModelConfig(**model)
    stiffness = calibrate_flexure(config).stiffness_N_per_m if params["plate"] == "flexure" else params["plate_stiffness"]
    return Truth(config, Environment(true_H, true_h), stiffness)
