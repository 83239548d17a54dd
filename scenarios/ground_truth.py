"""Parameters of a MuJoCo scenario's ground truth: the flexure sheet and the checks of the
true arm and plate (kept apart from `scenarios.common`, which imports no MuJoCo, so the
hardware mode can use it)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from controllers.params import RobotParams
from scenarios.common import check_choice, load_robot
from softcbf_mj.flexure import FlexureParams
from softcbf_mj.model_builder import PLATE_KINDS, ArmModelConfig


def flexure_params(params: Mapping[str, Any]) -> FlexureParams:
    """The flexure sheet of a scenario's `sheet_*` parameters (checked by FlexureParams)."""
    return FlexureParams(clamp_at=params["sheet_clamp_at"], free_end_at=params["sheet_free_end_at"],
                         thickness=params["sheet_thickness"], width=params["sheet_width"],
                         youngs_modulus=params["sheet_youngs_modulus"], links=params["sheet_links"],
                         calibration_fraction=params["sheet_calibration_fraction"])


def check_true_arm(params: Mapping[str, Any], model_robot: RobotParams) -> None:
    """The checks of a MuJoCo scenario's ground truth: plate kind, sheet, true robot (the same
    number of segments as the controller's) and the model settings (ArmModelConfig's checks, among
    them `table_friction` against `gravity` and the physics step; a scenario without `gravity` has
    the arm on the table)."""
    check_choice("plate", params["plate"], PLATE_KINDS)
    if params["true_robot"]:
        true_robot = load_robot(params["true_robot"])
        if true_robot.n_segments != model_robot.n_segments:
            raise ValueError(f"true_robot has {true_robot.n_segments} segments, the controller's robot "
                             f"{model_robot.n_segments}; they must have the same number")
    ArmModelConfig(plate_stiffness=params["plate_stiffness"], links_per_segment=params["links_per_segment"],
                   tau_p=params["tau_p"], physics_dt=params["physics_dt"], tip_friction=params["tip_friction"],
                   plate=params["plate"], flexure=flexure_params(params), table_friction=params["table_friction"],
                   gravity=(0.0, -params.get("gravity", 0.0), 0.0))
