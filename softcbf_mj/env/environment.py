"""The MuJoCo ground truth as a dm_control environment: `make_environment(ArmEnvConfig(...))`.

Three clocks, all explicit and validated:

    physics step  physics_dt      (s)   MuJoCo's integrator step (`ArmModelConfig.physics_dt`)
    control period control_dt     (s)   one filter call and one held command; an integer
                                        multiple of physics_dt (`softcbf_mj.plant.steps_per_control`)
    env step      action_repeat · control_dt (s)  one policy action, held for action_repeat
                                        control periods (`control.Environment.control_timestep()`)

An episode lasts `episode_steps` env steps, i.e. episode_steps · action_repeat · control_dt
seconds of simulated time. The scene is the one of `scenarios/mujoco_contact.py`: the
MuJoCo arm of `robot` (`MujocoPlant.from_config`), the plates on the facets of
`safe_set.environment` with spring stiffness `plate_stiffness` (N/m), and the control step
of the scenarios (`closedloop.step.ControlStep`: the filter `filter` with `filter_params`
built once per environment by `controllers.registry.build_filter`, told its own copy of
`FilterContext.for_robot(robot, safe_set, control_dt, pressure_limits, command_delay=0,
actuator_tau=tau_p)` (the step's limits and the safe set of ρ_meas are the environment's), and
reset before every episode; admission; a fresh `SafetyMonitor`
holding `hold_s` per episode). The filter sees the exact state (`exact_state`), or with
`state_noise_std` = (σ_q rad, σ_q̇ rad/s) ≠ 0 the noisy state (`physics.NoisyState`); the
observation's estimate keys are that same estimate.
Actions, observations (`observation`: "estimate" or "privileged"), reward, cost and seeds:
`softcbf_mj.env.task`; stepping: `softcbf_mj.env.physics`; the task presets:
`softcbf_mj.env.presets`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from dm_control.rl import control

from controllers.params import RobotParams, reference_robot
from controllers.registry import build_filter, typed_params
from controllers.safe_set import ForceSafeSet, paper_safe_set
from controllers.safety_filter import Estimate, FilterContext, SafetyFilter
from softcbf_mj.env.physics import ArmPhysics, NoisyState
from softcbf_mj.env.task import COSTS, OBSERVATIONS, ArmTask, RewardConfig
from softcbf_mj.loop import exact_state
from softcbf_mj.mjcf import CAMERA_RESOLUTION
from softcbf_mj.mujoco_plant import MujocoPlant
from softcbf_mj.plant import PlantState, steps_per_control
from vocabulary.settings import check_value, default

DEFAULT_CONTROL_DT = 1e-3  # s, the paper's 1 kHz (as scenarios/mujoco_contact.py)
VOCABULARY_FIELDS = ("plate_stiffness", "physics_dt", "links_per_segment", "tau_p", "filter", "pressure_limits", "hold_s",
                     "q0_std")  # ArmEnvConfig's fields that are settings of vocabulary.settings (checked by it)
MIN_IMAGE_PX = 8  # the tag detector's smallest image side


@dataclass(frozen=True)
class ArmEnvConfig:
    """Everything the environment depends on (units in the module docstring).

    A field named like a setting of `vocabulary.settings` (plate_stiffness, physics_dt,
    links_per_segment, tau_p, filter, pressure_limits, hold_s, q0_std) means that setting
    and takes its default from there: `default(name, "environment")`, the declared default or
    the context's override (filter "none": the environment is the unfiltered arm unless a
    filter is asked for), and its check: `vocabulary.settings.check_value`, the bounds the
    command line and the files hold it to (q0_std in [0, π] rad, tau_p <= 5 s, hold_s >= 0 s,
    links_per_segment in [1, 100], …), so the environment refuses what `softcbf run` refuses,
    with the same one-line error. The table shows their values (tests/test_setting_defaults.py
    holds it to them); control_dt, the other fields and their defaults are the environment's own.

    | field            | default              | unit | meaning                                                   |
    |------------------|----------------------|------|-----------------------------------------------------------|
    | robot            | reference_robot()    | —    | the true arm and the filter's model                       |
    | safe_set         | paper_safe_set()     | —    | the filter's P and ρ_meas; its facets place the plates    |
    | plate_stiffness  | 11.16                | N/m  | the true plates' springs                                  |
    | control_dt       | 1e-3                 | s    | control period                                            |
    | physics_dt       | 1e-4                 | s    | MuJoCo step                                               |
    | links_per_segment| 10                   | —    | rigid links per segment                                   |
    | tau_p            | 0.05                 | s    | pressure time constant                                    |
    | action_repeat    | 1                    | —    | control periods per env step                              |
    | episode_steps    | 1000                 | —    | env steps per episode                                     |
    | filter           | "none"               | —    | registry spec or preset ("c-erg:recommended")             |
    | filter_params    | {}                   | —    | its parameters, typed once (registry.typed_params)        |
    | pressure_limits  | True                 | —    | the control step clips to [u_min, u_max]                  |
    | hold_s           | 0.5                  | s    | the safety monitor's hold before it vents                 |
    | q0_std           | 0.0                  | rad  | initial bending angles ~ N(0, q0_std²)                    |
    | state_noise_std  | (0.0, 0.0)           | rad, rad/s | noise of the estimate's q and q̇ (0: exact state)   |
    | observation      | "estimate"           | —    | "estimate" (what the controller sees) or "privileged"     |
    | reward           | RewardConfig()       | —    | reward and termination (softcbf_mj.env.task)              |
    | cost             | "violation"          | —    | the cost's definition: "violation" or "force_excess"      |
    | camera           | False                | —    | observation "image"                                       |
    | tag_detections   | False                | —    | observations "tag_corners", "tag_seen"                    |
    | image_size       | (320, 180)           | px   | (W, H) of the camera's frames, <= 1280 × 720              |
    """

    robot: RobotParams = field(default_factory=reference_robot)
    safe_set: ForceSafeSet = field(default_factory=paper_safe_set)
    plate_stiffness: float = default("plate_stiffness", "environment")
    control_dt: float = DEFAULT_CONTROL_DT
    physics_dt: float = default("physics_dt", "environment")
    links_per_segment: int = default("links_per_segment", "environment")
    tau_p: float = default("tau_p", "environment")
    action_repeat: int = 1
    episode_steps: int = 1000
    filter: str = default("filter", "environment")
    filter_params: Mapping[str, object] = field(default_factory=dict)
    pressure_limits: bool = default("pressure_limits", "environment")
    hold_s: float = default("hold_s", "environment")
    q0_std: float = default("q0_std", "environment")
    state_noise_std: tuple[float, float] = (0.0, 0.0)
    observation: str = "estimate"
    reward: RewardConfig = field(default_factory=RewardConfig)
    cost: str = "violation"
    camera: bool = False
    tag_detections: bool = False
    image_size: tuple[int, int] = (320, 180)

    def __post_init__(self) -> None:
        for name in VOCABULARY_FIELDS:
            object.__setattr__(self, name, check_value(name, getattr(self, name)))
        steps_per_control(self.control_dt, self.physics_dt)
        for name in ("action_repeat", "episode_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
        if self.safe_set.environment.n_facets < 1:
            raise ValueError("safe_set must have at least one facet")
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
    def env_dt(self) -> float:
        """s, one env step: action_repeat · control_dt."""
        return self.action_repeat * self.control_dt

    def context(self) -> FilterContext:
        """What the filter is told (module docstring)."""
        return FilterContext.for_robot(self.robot, self.safe_set, self.control_dt, self.pressure_limits,
                                       command_delay=0.0, actuator_tau=self.tau_p)

    def plant(self) -> MujocoPlant:
        """The MuJoCo ground truth of this configuration."""
        env = self.safe_set.environment
        return MujocoPlant.from_config(control_dt=self.control_dt, robot=self.robot, H=env.H, h=env.h,
                                       plate_stiffness=self.plate_stiffness, links_per_segment=self.links_per_segment,
                                       tau_p=self.tau_p, physics_dt=self.physics_dt)

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
