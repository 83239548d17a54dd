"""A Gymnasium adapter of the arm's dm_control environment (`softcbf_mj.env.environment`).

`GymArmEnv(config=None, render_mode=None, normalise=False, **changes)` wraps
`make_environment(config, **changes)`:

- spaces: the action `Box(u_min, u_max, (N,), float64)` hPa; the observation a `Dict` of
  `Box`es with the dm_env specs' shapes, dtypes and bounds (unbounded where the spec is),
  keys and units as `softcbf_mj.env.task.OBSERVATION_UNITS` (the mode, "estimate" or
  "privileged", is the config's `observation`);
- `normalise=True`: the action is a ∈ [−1, 1]^N, u_nom = u_min + (a + 1)/2 · (u_max − u_min)
  (a non-finite a stays non-finite: the control step refuses it); every float observation
  is divided by its scale (`task.ArmTask.scales`) and clipped to [−1, 1], its
  Box [−1, 1] (image and tag_seen keep their uint8 boxes); info["clipped"] names the keys
  that were clipped at this step (empty when none), so saturation is never silent. With it,
  Gymnasium's `check_env` passes without a warning;
- `reset(seed=…)`: a seed re-seeds the task's initial states (q0 ~ N(0, q0_std²), and the
  estimate's noise) and `np_random`; `reset()` without one continues the generator;
- `step(action)` → (observation, reward, terminated, truncated, info): dm_env's LAST with
  discount 0 is `terminated`, LAST with discount 1 (`episode_steps` reached) `truncated`;
  info holds the keys of `INFO_KEYS` (below). A step after the episode's end raises: call
  reset(). An action is converted once (`physics.action_array`): bool, complex, object or
  string values, masked arrays and other shapes are refused with a ValueError;
- `render()` (render_mode "rgb_array"): the overhead camera's frame (H, W, 3) uint8 RGB
  at the config's image_size.

The info of a step or a reset (`INFO_KEYS`, in this order; "truth": computed from the ground truth):

| key               | unit | truth | what                                                                     |
|-------------------|------|-------|--------------------------------------------------------------------------|
| cost              | 1    | yes   | the env step's cost (`softcbf_mj.env.task`), Safety-Gymnasium's info["cost"] |
| periods           | —    | no    | control periods in the env step                                          |
| violation_periods | —    | yes   | of them, periods whose end state has ρ_meas < 0                           |
| rho_meas_min      | 1    | yes   | the least ρ_meas over them (+inf before any period)                      |
| force_max_N       | N    | yes   | the largest measured plate force over them                               |
| force_excess      | 1    | yes   | the mean over them of max_i max(0, F_i − F_max)/F_max                    |
| vented            | —    | no    | the safety monitor sent VENT in one of them                              |
| clipped           | —    | no    | the observation keys clipped by `normalise` at this step                 |
| t                 | s    | no    | the time                                                                 |
| monitor_action    | —    | no    | the safety monitor's last action ("run", "hold", "vent")                 |
| filter_action     | —    | no    | the filter's last action label ("" when it was not called)               |
| fault             | —    | no    | the filter fault that ended the episode (`FilterFault.to_json`) or None   |

The ground-truth keys (`GROUND_TRUTH_INFO`) are in the info of both observation modes, flagged here
rather than moved: info is the training algorithm's and the log's channel, not the policy's input
(Gymnasium's convention), and a constrained learner trains on the cost, which is the ground truth's
by definition (Safety-Gymnasium's cost is the simulator's, as the reward is); removing rho_meas_min
from the "estimate" mode while keeping the cost (the violation cost is violation_periods / periods)
would hide nothing. What the "estimate" mode promises is its observation: only what the controller
under test sees. A policy or a filter evaluated in that mode must not read the flagged keys as input.

`SafetyGymnasiumStep(env)` is the other convention: its `step` returns Safety-Gymnasium's
6-tuple (observation, reward, cost, terminated, truncated, info), cost = info["cost"].

Gymnasium's registry knows `ENV_ID` ("softcbf_mj/SoftArm-v1": the bare task, reward only
from a `RewardConfig` target, max_episode_steps = ArmEnvConfig's episode_steps, 1000) and
the presets of `softcbf_mj.env.presets` ("softcbf_mj/ForceRegulation-v0",
"softcbf_mj/TipReaching-v0", max_episode_steps = presets.EPISODE_STEPS); keywords as
`GymArmEnv`'s. Each id's `vector_entry_point` is `softcbf_mj.env.vector.ArmVectorEnv`, B
arms on one batch plant: `gymnasium.make_vec(id, num_envs=B)` builds it (its default
vectorization mode when an id has one; vectorization_mode="sync" gives `SyncVectorEnv`).

Version history (a new id for changed behaviour, as Gymnasium versions its environments; only the current id is
registered):
- v1: the paper CBF filter's calls run its batched kernel (`controllers.cbf.paper_filter`), whose QP is exact to rounding
  where the scalar QP stopped at its tolerance: the commands of a run move by rounding, which a closed loop can
  carry further (2.2e-8 hPa at most in the reference loops of tests/references/loop_references.py; CHANGELOG.md).
- v0: the first release.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from typing import Any

import dm_env
import gymnasium
import numpy as np
from dm_env import specs
from gymnasium import spaces

from closedloop.step import FilterFault
from softcbf_mj.env.environment import ArmEnvConfig, make_environment
from softcbf_mj.env.physics import ArmArrays, ArmControl, ArmPhysics, action_array
from softcbf_mj.env.presets import EPISODE_STEPS, PRESETS
from softcbf_mj.env.task import ArmTask

ENV_ID = "softcbf_mj/SoftArm-v1"
INFO_KEYS = ("cost", "periods", "violation_periods", "rho_meas_min", "force_max_N", "force_excess", "vented", "clipped",
             "t", "monitor_action", "filter_action", "fault")  # the info's keys, in order (module docstring)
GROUND_TRUTH_INFO = ("cost", "violation_periods", "rho_meas_min", "force_max_N", "force_excess")
"""The info keys computed from the ground truth, in either observation mode (module docstring)."""


def box(spec: specs.Array) -> spaces.Box:
    """The Box of a dm_env array spec: its bounds for a BoundedArray, else unbounded (float specs only)."""
    dtype = np.dtype(spec.dtype)
    if isinstance(spec, specs.BoundedArray):
        low, high = np.broadcast_to(spec.minimum, spec.shape), np.broadcast_to(spec.maximum, spec.shape)
    elif np.issubdtype(dtype, np.floating):
        low, high = np.full(spec.shape, -np.inf), np.full(spec.shape, np.inf)
    else:
        raise ValueError(f"an unbounded spec must be of a float dtype, got {spec.name!r} of {dtype}")
    return spaces.Box(low.astype(dtype), high.astype(dtype), spec.shape, dtype)


def gym_spaces(task: ArmTask, physics: ArmControl, config: ArmEnvConfig, normalise: bool
               ) -> tuple[spaces.Box, spaces.Dict, dict[str, np.ndarray]]:
    """(action space, observation space, the observation keys' scales) of one arm (module
    docstring); the scales are empty unless `normalise`."""
    action = task.action_spec(physics)
    observation = task.observation_spec(physics)
    scales = task.scales(config.robot.array("lengths"), config.safe_set.f_max) if normalise else {}
    if normalise:
        return (spaces.Box(-1.0, 1.0, action.shape, np.float64),
                spaces.Dict({key: spaces.Box(-1.0, 1.0, spec.shape, np.float64) if key in scales else box(spec)
                             for key, spec in observation.items()}), scales)
    return box(action), spaces.Dict({key: box(spec) for key, spec in observation.items()}), scales


def nominal_command(action: np.ndarray, u_low: np.ndarray, u_high: np.ndarray, normalise: bool) -> np.ndarray:
    """The nominal command (..., N) hPa of `action`, a float array checked by `physics.action_array` (the action
    itself unless normalised; module docstring)."""
    return u_low + 0.5 * (action + 1.0) * (u_high - u_low) if normalise else action


def scaled_observations(observations: Mapping[str, np.ndarray], scales: Mapping[str, np.ndarray]
                        ) -> tuple[dict[str, np.ndarray], list[tuple[str, ...]]]:
    """(B arms' observations (B, ...) per key normalised and clipped by `scales` (each key's, of the single
    shape), per arm the keys that were clipped; module docstring). Without scales: the observations as they are."""
    out, flags = dict(observations), []
    for key, scale in scales.items():
        value = out[key] / scale
        flags.append(np.any(np.abs(value.reshape(len(value), -1)) > 1.0, axis=1))
        out[key] = np.clip(value, -1.0, 1.0)
    n_arms = len(next(iter(observations.values())))
    if not flags or not np.any(flags):
        return out, [()] * n_arms
    keys, clipped = list(scales), np.array(flags).T
    return out, [tuple(key for key, flag in zip(keys, row) if flag) for row in clipped.tolist()]


def object_array(values: Sequence[Any]) -> np.ndarray:
    """A (B,) object array of `values`, element by element (numpy would unpack equal-length tuples into 2-d)."""
    out = np.empty(len(values), dtype=object)
    for b, value in enumerate(values):
        out[b] = value
    return out


def step_infos(task: ArmTask, arms: ArmArrays, clipped: Sequence[tuple[str, ...]], monitor_action: Sequence[str],
               filter_action: Sequence[str], faults: Sequence[FilterFault | None]) -> dict[str, Any]:
    """The infos of B arms' env steps or resets (module docstring), key by key in order: the numbers as
    (B,) arrays (cost, the `StepStats` fields, t), the others as sequences of B values: `clipped` the
    observation keys clipped per arm; monitor_action, filter_action the labels ("" where none); fault
    each arm's episode fault as JSON (None: none)."""
    return {
        "cost": task.costs(arms),
        **arms.stats._asdict(),  # StepStats' fields in order
        "clipped": clipped,
        "t": arms.t,
        "monitor_action": monitor_action,
        "filter_action": filter_action,
        "fault": [fault.to_json() if fault is not None else None for fault in faults],
    }


def step_info(task: ArmTask, physics: ArmControl, clipped: tuple[str, ...]) -> dict[str, Any]:
    """The info of one arm's env step or reset: `step_infos` at B = 1, as Python values."""
    record = physics.last_record
    infos = step_infos(task, physics.arrays(), [clipped], [record.action.value if record is not None else ""],
                       [record.output.action if record is not None and record.output is not None else ""],
                       [physics.fault])
    return {key: value.item(0) if isinstance(value, np.ndarray) else value[0] for key, value in infos.items()}


class GymArmEnv(gymnasium.Env):
    """The arm environment through Gymnasium's API (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, config: ArmEnvConfig | None = None, render_mode: str | None = None, normalise: bool = False,
                 **changes: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if not isinstance(normalise, bool):
            raise ValueError(f"normalise must be True or False, got {normalise!r}")
        self.config = dataclasses.replace(config or ArmEnvConfig(), **changes)
        self.environment = make_environment(self.config)
        self.render_mode, self.normalise = render_mode, normalise
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.config.env_dt}
        self.u_low, self.u_high = self.task.u_min, self.task.u_max
        self.action_space, self.observation_space, self.scales = gym_spaces(self.task, self.physics, self.config, normalise)
        self._clipped: tuple[str, ...] = ()
        self._done = True

    @property
    def physics(self) -> ArmPhysics:
        return self.environment.physics

    @property
    def task(self) -> ArmTask:
        return self.environment.task

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        super().reset(seed=seed)
        if seed is not None:
            self.task.seed(seed)
        time_step = self.environment.reset()
        self._done = False
        return self._observe(time_step.observation), self._info()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError("the episode has ended (or never started): call reset() before step()")
        time_step = self.environment.step(self.u_nom(action))
        terminated = time_step.step_type is dm_env.StepType.LAST and time_step.discount == 0.0
        truncated = time_step.step_type is dm_env.StepType.LAST and not terminated
        self._done = terminated or truncated
        return self._observe(time_step.observation), float(time_step.reward), terminated, truncated, self._info()

    def u_nom(self, action: np.ndarray) -> np.ndarray:
        """The nominal command (N,) hPa of `action` (`nominal_command`)."""
        return nominal_command(action_array(action, self.u_low.shape), self.u_low, self.u_high, self.normalise)

    def _observe(self, observation: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The dm_env observation, normalised and clipped when asked (`scaled_observations` at B = 1); sets the
        clipped keys."""
        if not self.scales:  # nothing to scale (`scaled_observations` returns its input)
            self._clipped = ()
            return dict(observation)
        out, clipped = scaled_observations({key: value[None] for key, value in observation.items()}, self.scales)
        self._clipped = clipped[0]
        return {key: value[0] for key, value in out.items()}

    def render(self) -> np.ndarray | None:
        """The overhead camera's frame (H, W, 3) uint8 RGB (render_mode "rgb_array"); None without a render mode."""
        if self.render_mode is None:
            return None
        return self.physics.render_image()

    def close(self) -> None:
        self.physics.close()

    def _info(self) -> dict[str, Any]:
        return step_info(self.task, self.physics, self._clipped)


class SafetyGymnasiumStep(gymnasium.Wrapper):
    """Safety-Gymnasium's step convention: (observation, reward, cost, terminated, truncated, info), cost = info["cost"]."""

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, float, bool, bool, dict[str, Any]]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        return observation, reward, float(info["cost"]), terminated, truncated, info


VECTOR_ENTRY_POINT = "softcbf_mj.env.vector:ArmVectorEnv"  # imported by gymnasium.make_vec (it imports this module)
gymnasium.register(ENV_ID, entry_point=GymArmEnv, vector_entry_point=VECTOR_ENTRY_POINT,
                   max_episode_steps=ArmEnvConfig().episode_steps)
for preset_id, preset in PRESETS.items():
    gymnasium.register(preset_id, entry_point=GymArmEnv, vector_entry_point=VECTOR_ENTRY_POINT,
                       kwargs={"config": preset()}, max_episode_steps=EPISODE_STEPS)
