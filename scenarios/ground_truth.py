"""Deprecated: the MuJoCo ground truth moved to `softcbf_mj.physics.ground_truth` (its one builder, which the
environment and the emulator take too). The names here (`build_truth`, `check_true_arm`, `Truth`,
`flexure`, `scaled_robot`, `moved_facets`) are read from there with a DeprecationWarning for one release;
`build_truth(arm, plate, model, model_robot, environment)` keeps its former signature (the new one takes
`model.damping_scale` instead of `model`)."""

from __future__ import annotations

import warnings
from typing import Any

from controllers.model.params import RobotParams
from controllers.model.safe_set import Environment
from softcbf_mj.physics import ground_truth
from vocabulary.run_sections import Model, Plate, TrueArm

MOVED = ("check_true_arm", "Truth", "flexure", "scaled_robot", "moved_facets")


def _moved(name: str) -> str:
    return (f"scenarios.ground_truth.{name} is deprecated and will be removed in the next release: "
            f"use softcbf_mj.physics.ground_truth.{name}")


def build_truth(arm: TrueArm, plate: Plate, model: Model, model_robot: RobotParams, environment: Environment
                ) -> ground_truth.Truth:
    """`softcbf_mj.physics.ground_truth.build_truth(arm, plate, model_robot, environment, model.damping_scale)`, with a
    DeprecationWarning."""
    warnings.warn(_moved("build_truth") + "(arm, plate, model_robot, environment, damping_scale)", DeprecationWarning,
                  stacklevel=2)
    return ground_truth.build_truth(arm, plate, model_robot, environment, model.damping_scale)


def __getattr__(name: str) -> Any:
    if name in MOVED:
        warnings.warn(_moved(name), DeprecationWarning, stacklevel=2)
        return getattr(ground_truth, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
