"""The MuJoCo ground truth as a dm_control environment: `make_environment(ArmEnvConfig(...))`.

Three clocks, all explicit and validated:

    physics step  physics_dt      (s)   MuJoCo's integrator step (`ArmModelConfig.physics_dt`)
    control period control_dt = 1 / control_rate (s; control_rate in Hz)   one filter call and
                                        one held command; an integer multiple of physics_dt
                                        (`softcbf_mj.physics.plant.steps_per_control`)
    env step      action_repeat · control_dt (s)  one policy action, held for action_repeat
                                        control periods (`control.Environment.control_timestep()`)

An episode lasts `episode_steps` env steps, i.e. episode_steps · action_repeat · control_dt
seconds of simulated time. The scene is the one of `scenarios/mujoco_contact.py`, built by the
same builder (`softcbf_mj.physics.ground_truth.build_truth`) from the same settings: the MuJoCo arm of
`robot` (scaled by the true_* settings), the plates on the facets of `safe_set.environment`
(moved by facet_offset and facet_angle) with spring stiffness `plate_stiffness` (N/m) or the
flexure sheet, gravity and friction as set; and the control step
of the scenarios (`closedloop.step.ControlStep`: the filter `filter` with `filter_params`
built once per environment by `controllers.registry.build_filter`, told its own copy of
`FilterContext.for_robot(robot, safe_set, control_dt, pressure_limits,
command_delay=assumed_command_delay, actuator_tau=assumed_tau_p)`: what the filter assumes, never the true
`command_delay` and `tau_p` (the step's limits and the safe set of ρ_meas are the environment's), and
reset before every episode; admission; a fresh `SafetyMonitor`
holding `hold_s` per episode). The filter sees the exact state (`exact_state`), or with
`state_noise_std` = (σ_q rad, σ_q̇ rad/s) ≠ 0 the noisy state (`physics.NoisyState`); the
observation's estimate keys are that same estimate.
Actions, observations (`observation`: "estimate" or "privileged"), reward, cost and seeds:
`softcbf_mj.env.task`; stepping: `softcbf_mj.env.physics`; the task presets:
`softcbf_mj.env.presets`.
"""

from __future__ import annotations

import functools
import math
import warnings
from collections.abc import Callable, Mapping
from dataclasses import field, replace
from typing import Any

from dm_control.rl import control

from controllers.model.params import RobotParams, reference_robot
from controllers.registry import build_filter, typed_params
from controllers.model.safe_set import ForceSafeSet, paper_safe_set
from controllers.contract.safety_filter import Estimate, FilterContext, SafetyFilter
from softcbf_mj.env.physics import ArmPhysics, NoisyState
from softcbf_mj.env.task import COSTS, OBSERVATIONS, ArmTask, RewardConfig
from softcbf_mj.physics.ground_truth import Truth, build_truth, check_true_arm
from softcbf_mj.loops.loop import exact_state
from softcbf_mj.physics.mjcf import CAMERA_RESOLUTION
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.physics.plant import PlantState, steps_per_control
from vocabulary.run_sections import ground_truth_values
from vocabulary.sections import setting_section
from vocabulary.settings import check_number, default, ground_truth_settings, positive

MIN_IMAGE_PX = 8  # the tag detector's smallest image side


ENV_SETTINGS = ("control_rate", "filter", "pressure_limits", "hold_s", "q0_std", "assumed_tau_p",
                "assumed_command_delay") + ground_truth_settings()
"""ArmEnvConfig's keywords that are settings of the vocabulary (`vocabulary.settings`; every ground-truth setting)."""


def _with_deprecated_control_dt(cls: type) -> type:
    """`cls` whose constructor (and so `dataclasses.replace`) also reads the former keyword `control_dt` (s): as
    `control_rate` = 1 / control_dt (Hz), which it sets (over a control_rate given beside it: `replace(config,
    control_dt=...)` hands the old control_rate too), with a DeprecationWarning naming the new keyword, for one release."""
    generated = cls.__init__

    def __init__(self: Any, *args: Any, control_dt: float | None = None, **kwargs: Any) -> None:
        if control_dt is not None:
            kwargs["control_rate"] = 1.0 / check_number("control_dt", control_dt, positive("s"))
            warnings.warn("ArmEnvConfig's control_dt (s) is deprecated and will be removed in the next release: give "
                          f"control_rate (Hz) = 1 / control_dt, here control_rate={kwargs['control_rate']:g}",
                          DeprecationWarning, stacklevel=2)
        generated(self, *args, **kwargs)

    functools.update_wrapper(__init__, generated)  # the signature users see is the dataclass's
    __init__.__doc__ = _with_deprecated_control_dt.__doc__
    cls.__init__ = __init__
    return cls


@_with_deprecated_control_dt
@setting_section(settings={name: name for name in ENV_SETTINGS}, context="environment")
class ArmEnvConfig:
    """Everything the environment depends on (units in the module docstring).

    Settings. A keyword named like a setting of `vocabulary.settings` means that setting, takes
    its default from there (`default(name, "environment")`: the declared default, or the
    environment's override: filter "none", the unfiltered arm unless a filter is asked for, and
    control_rate 1000 Hz, the paper's 1 kHz) and its check (`check_value`, the bounds the command
    line and the files hold it to: q0_std in [0, π] rad, tau_p <= 5 s, hold_s >= 0 s, ...), so the
    environment refuses what `softcbf run` refuses, with the same one-line error. They are
    `control_rate` (Hz; the former `control_dt` in s is read for one release with a
    DeprecationWarning), `filter`, `pressure_limits`, `hold_s`, `q0_std`, what the filter is told
    (`assumed_tau_p`, `assumed_command_delay`) and every setting of the
    ground truth (`vocabulary.settings.ground_truth_settings`: plate_stiffness, links_per_segment,
    tau_p, physics_dt, the true_* scales, true_robot, facet_offset, facet_angle, gravity,
    tip_friction, table_friction, plate and the sheet_* settings), which `plant()` hands to the one
    builder of the ground truth (`softcbf_mj.physics.ground_truth.build_truth`); docs/parameters.md lists
    them with their units and ranges.

    The environment's own fields:

    | field            | default              | unit | meaning                                                   |
    |------------------|----------------------|------|-----------------------------------------------------------|
    | robot            | reference_robot()    | —    | the true arm's reference (true_*) and the filter's model  |
    | safe_set         | paper_safe_set()     | —    | the filter's P and ρ_meas; its facets place the plates    |
    | action_repeat    | 1                    | —    | control periods per env step                              |
    | episode_steps    | 1000                 | —    | env steps per episode                                     |
    | filter_params    | {}                   | —    | the filter's parameters, typed once (registry.typed_params) |
    | state_noise_std  | (0.0, 0.0)           | rad, rad/s | noise of the estimate's q and q̇ (0: exact state)   |
    | observation      | "estimate"           | —    | "estimate" (what the controller sees) or "privileged"     |
    | reward           | RewardConfig()       | —    | reward and termination (softcbf_mj.env.task)              |
    | cost             | "violation"          | —    | the cost's definition: "violation" or "force_excess"      |
    | camera           | False                | —    | observation "image"                                       |
    | tag_detections   | False                | —    | observations "tag_corners", "tag_seen"                    |
    | image_size       | (320, 180)           | px   | (W, H) of the camera's frames, <= the render's 1280 × 720 |
    """

    robot: RobotParams = field(default_factory=reference_robot)
    safe_set: ForceSafeSet = field(default_factory=paper_safe_set)
    action_repeat: int = 1
    episode_steps: int = 1000
    filter_params: Mapping[str, object] = field(default_factory=dict)
    state_noise_std: tuple[float, float] = (0.0, 0.0)
    observation: str = "estimate"
    reward: RewardConfig = field(default_factory=RewardConfig)
    cost: str = "violation"
    camera: bool = False
    tag_detections: bool = False
    image_size: tuple[int, int] = (320, 180)

    def check(self) -> None:
        """The environment's own fields and the rules that tie settings together (the settings are checked)."""
        steps_per_control(self.control_dt, self.physics_dt)
        for name in ("action_repeat", "episode_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.safe_set.environment.n_facets < 1:
            raise ValueError("safe_set must have at least one facet")
        check_true_arm(*ground_truth_values(self), self.robot)
        size = tuple(self.image_size)
        if not (len(size) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in size)
                and MIN_IMAGE_PX <= size[0] <= CAMERA_RESOLUTION[0] and MIN_IMAGE_PX <= size[1] <= CAMERA_RESOLUTION[1]):
            raise ValueError(f"image_size must be (W, H) integers in [{MIN_IMAGE_PX}, {CAMERA_RESOLUTION[0]}] × "
                             f"[{MIN_IMAGE_PX}, {CAMERA_RESOLUTION[1]}] px, got {self.image_size!r}")
        object.__setattr__(self, "image_size", size)
        object.__setattr__(self, "filter_params", typed_params(self.filter, self.filter_params))
        noise = tuple(float(v) for v in self.state_noise_std)
        if len(noise) != 2 or not all(math.isfinite(v) and v >= 0 for v in noise):
            raise ValueError(f"state_noise_std must be (q_std rad, qd_std rad/s), finite and >= 0, got {self.state_noise_std!r}")
        object.__setattr__(self, "state_noise_std", noise)
        if self.observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {self.observation!r}")
        if self.cost not in COSTS:
            raise ValueError(f"cost must be one of {', '.join(COSTS)}, got {self.cost!r}")

    @property
    def control_dt(self) -> float:
        """s, the control period: 1 / control_rate."""
        return 1.0 / self.control_rate

    @property
    def env_dt(self) -> float:
        """s, one env step: action_repeat · control_dt."""
        return self.action_repeat * self.control_dt

    def context(self) -> FilterContext:
        """What the filter is told (module docstring)."""
        return FilterContext.for_robot(self.robot, self.safe_set, self.control_dt, self.pressure_limits,
                                       command_delay=self.assumed_command_delay, actuator_tau=self.assumed_tau_p)

    def truth(self) -> Truth:
        """The ground truth of this configuration's ground-truth settings (`softcbf_mj.physics.ground_truth.build_truth`):
        the true arm from `robot`, the plates on `safe_set`'s facets."""
        return build_truth(*ground_truth_values(self), self.robot, self.safe_set.environment,
                           default("damping_scale", "environment"))

    def plant(self) -> MujocoPlant:
        """The MuJoCo ground truth of this configuration, stepped at its control rate."""
        return MujocoPlant.from_config(self.truth().config, self.control_dt)

    def estimator(self) -> Callable[[PlantState], Estimate]:
        """The controller's estimator: the exact state, or the noisy state of state_noise_std."""
        return NoisyState(*self.state_noise_std) if any(self.state_noise_std) else exact_state

    def task(self, plant: MujocoPlant, seed: int | None = None) -> ArmTask:
        """The task of this configuration on `plant`'s action box and plates; `seed` seeds its initial states."""
        return ArmTask(plant.u_min, plant.u_max, plant.n_facets, self.episode_steps, self.reward, self.q0_std,
                       self.camera, self.tag_detections, self.image_size, seed, self.observation, self.cost)

    def safety_filter(self, context: FilterContext) -> SafetyFilter:
        """The filter `filter` with `filter_params`, told its own copy of `context` (`FilterContext.copy`:
        the control step's limits and the safe set that gives ρ_meas stay `context`'s, out of the filter's reach)."""
        return build_filter(self.filter, self.filter_params, context.copy())


class ArmEnvironment(control.Environment):
    """dm_control's `control.Environment` whose `close()` frees the physics' renderer."""

    def close(self) -> None:
        self.physics.close()


def make_environment(config: ArmEnvConfig | None = None, seed: int | None = None, **changes: Any) -> ArmEnvironment:
    """The dm_control environment of `config` with `changes` applied to its fields (e.g.
    `make_environment(filter="paper-cbf", filter_params={"tuning": "Low"}, action_repeat=10)`);
    `seed` seeds the initial states (`ArmTask.seed`)."""
    config = replace(config or ArmEnvConfig(), **changes)
    plant = config.plant()
    context = config.context()
    physics = ArmPhysics(plant, config.safety_filter(context), context, config.hold_s, config.estimator(),
                         image_size=config.image_size)
    return ArmEnvironment(physics, config.task(plant, seed), n_sub_steps=config.action_repeat)
