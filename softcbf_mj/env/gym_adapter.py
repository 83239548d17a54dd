"""A Gymnasium adapter of the arm's dm_control environment (`softcbf_mj.env.environment`).

`GymArmEnv(config=None, render_mode=None, **changes)` wraps `make_environment(config,
**changes)`:

- spaces: the action `Box(u_min, u_max, (N,), float64)` hPa; the observation a `Dict` of
  `Box`es with the dm_env specs' shapes, dtypes and bounds (unbounded where the spec is),
  keys and units as `softcbf_mj.env.task.OBSERVATION_UNITS`;
- `reset(seed=…)`: a seed re-seeds the task's initial states (q0 ~ N(0, q0_std²)) and
  `np_random`; `reset()` without one continues the generator;
- `step(u_nom)` → (observation, reward, terminated, truncated, info): dm_env's LAST with
  discount 0 is `terminated`, LAST with discount 1 (`episode_steps` reached) `truncated`;
  info holds the env step's `StepStats` (periods, violation_periods, rho_meas_min,
  force_max_N, vented), the time t (s), the safety monitor's last action and the filter's
  last action label ("" when it was not called) and `fault` (the filter fault that ended the
  episode, `closedloop.step.FilterFault.to_json`, or None). A step after the episode's end raises:
  call reset();
- `render()` (render_mode "rgb_array"): the overhead camera's frame (H, W, 3) uint8 RGB
  at the config's image_size.

Gymnasium's registry knows it as `ENV_ID` ("softcbf_mj/SoftArm-v0"), keywords as `GymArmEnv`'s.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import dm_env
import gymnasium
import numpy as np
from dm_env import specs
from gymnasium import spaces

from softcbf_mj.env.environment import ArmEnvConfig, make_environment
from softcbf_mj.env.physics import ArmPhysics
from softcbf_mj.env.task import ArmTask

ENV_ID = "softcbf_mj/SoftArm-v0"


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


class GymArmEnv(gymnasium.Env):
    """The arm environment through Gymnasium's API (module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(self, config: ArmEnvConfig | None = None, render_mode: str | None = None, **changes: Any) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.config = dataclasses.replace(config or ArmEnvConfig(), **changes)
        self.environment = make_environment(self.config)
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.config.env_dt}
        self.action_space = box(self.environment.action_spec())
        self.observation_space = spaces.Dict({key: box(spec) for key, spec in self.environment.observation_spec().items()})
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
        return dict(time_step.observation), self._info()

    def step(self, action: np.ndarray) -> tuple[dict[str, np.ndarray], float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError("the episode has ended (or never started): call reset() before step()")
        time_step = self.environment.step(np.asarray(action, dtype=float))
        terminated = time_step.step_type is dm_env.StepType.LAST and time_step.discount == 0.0
        truncated = time_step.step_type is dm_env.StepType.LAST and not terminated
        self._done = terminated or truncated
        return dict(time_step.observation), float(time_step.reward), terminated, truncated, self._info()

    def render(self) -> np.ndarray | None:
        """The overhead camera's frame (H, W, 3) uint8 RGB (render_mode "rgb_array"); None without a render mode."""
        if self.render_mode is None:
            return None
        return self.physics.render_image()

    def close(self) -> None:
        self.physics.close()

    def _info(self) -> dict[str, Any]:
        physics = self.physics
        record = physics.last_record
        return {
            **dataclasses.asdict(physics.stats),
            "t": physics.time(),
            "monitor_action": record.action.value if record is not None else "",
            "filter_action": record.output.action if record is not None and record.output is not None else "",
            "fault": physics.fault.to_json() if physics.fault is not None else None,
        }


gymnasium.register(ENV_ID, entry_point=GymArmEnv)
