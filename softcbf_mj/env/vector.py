"""The arm environment as a Gymnasium vector environment on the batch plant: B arms, one `mujoco.batch`.

    envs = gymnasium.make_vec("softcbf_mj/SoftArm-v0", num_envs=32, vectorization_mode="vector_entry_point",
                              filter="paper-cbf", filter_params={"tuning": "Low"})

`ArmVectorEnv(num_envs, config=None, normalise=False, max_episode_steps=None, nthread=1,
**changes)` is B = num_envs copies of `GymArmEnv(config, normalise=normalise, **changes)`
under Gymnasium's time limit `max_episode_steps` (None: none; `gymnasium.make_vec` passes
the registered id's), in lock step. Sub-environment b shares every definition of the
single environment, none is copied here:

- physics: simulation b of one `MujocoBatchPlant` on the config's model (`nthread`
  threads; 0: all CPUs), bit-identical to b's own `MujocoPlant` (`mujoco.batch`), reset
  alone at b's episode start (`MujocoBatchPlant.reset(ids=[b])`);
- control: an `ArmControl` (`softcbf_mj.env.physics`: b's `closedloop.step.ControlStep`
  with its own `SafetyMonitor`, its estimator, its `StepStats`);
- task: an `ArmTask` (`softcbf_mj.env.task`: observation, reward, cost, termination and
  b's own generator of initial states);
- Gymnasium: the spaces, the (normalised) command, the scaled observation and the info of
  `softcbf_mj.env.gym_adapter`.

So for the same seeds and actions the vector environment returns what B single
environments return (`tests/test_env_vector.py`: equal, bit for bit, with per-arm
filters; with a batched filter the commands are those of `filter_batch`, which
`controllers.filter.CBFFilter` promises within 1e-9 hPa of B calls).

One env step, for every sub-environment that is not being reset ("running"):

    u_nom_b = nominal_command(action_b)                       (N,) hPa, held for the env step
    repeat action_repeat control periods, t_k = k Δ:
        records = the control step of each running arm at its estimate:
                  a filter with `filter_batch`: one filter for all, one call for the arms
                  that call it (`softcbf_mj.batch_loop.batch_rows`); otherwise B filters,
                  one per arm (built by the registry), called in turn
        u (B, N) hPa = record.u of the running arms, 0 hPa for the others
        state = plant.step(u)                                 one batch call for all B
        arm b ends its period at state row b (`ArmControl.end_period`)
    an arm whose control step has stopped (a filter fault's vent, `closedloop.step`)
    stops for the rest of the env step: its episode ends (terminated, info["fault"]), as
    in the single environment; the others go on.

Then per running arm, as dm_control's `Environment.step` and `GymArmEnv.step`: reward,
observation, cost and termination from its task (dm_env's discount 0: terminated; 1:
truncated at `episode_steps`), truncated also when its episode reaches
`max_episode_steps` env steps (Gymnasium's `TimeLimit`).

Autoreset (Gymnasium 1.x, `metadata["autoreset_mode"]` = `AutoresetMode.NEXT_STEP`, as
`SyncVectorEnv`): a sub-environment whose step ended its episode (terminated or
truncated) is reset by the next `step()`: its action is ignored, it returns the reset's
observation and info, reward 0, terminated = truncated = False. Its simulation is sent
0 hPa during that call's periods and reset after them (what it did in between is lost).

Seeds (as `SyncVectorEnv`): `reset(seed=s)` seeds sub-environment b's task with s + b, a
list seeds b with its b-th entry (None: not reseeded), `reset()` lets each continue its
generator. A filter shared by all arms (one with `filter_batch`) is reset (its `reset()`)
by `reset()` only, not when one arm's episode restarts: its state, if it keeps one, spans
all arms (the `filter_batch` contract, `controllers.safety_filter`); per-arm
filters are reset at each of their episodes, as in the single environment.

Returns: observations a Dict of (B, ...) arrays (`gymnasium.vector.utils.batch_space` of
the single space); rewards (B,) float64; terminations, truncations (B,) bool; infos the
single environment's keys, each a (B,) array (numbers as numbers, "clipped",
"monitor_action", "filter_action" and "fault" as objects) with its all-True mask
"_key", Gymnasium's vector convention. The vector environment has no camera: `camera`,
`tag_detections` and a render mode are refused.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array

from closedloop.step import FilterFault, StepRecord
from softcbf_mj.batch_loop import batch_rows
from softcbf_mj.env.environment import ArmEnvConfig
from softcbf_mj.env.gym_adapter import gym_spaces, nominal_command, scaled_observation, step_info
from softcbf_mj.env.physics import ArmControl
from softcbf_mj.env.task import ArmTask
from softcbf_mj.mujoco_batch_plant import MujocoBatchPlant
from softcbf_mj.plant import PlantState


class ArmVectorEnv(VectorEnv):
    """B arm environments on one batch plant (module docstring)."""

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": [], "render_fps": 30}

    def __init__(self, num_envs: int, config: ArmEnvConfig | None = None, normalise: bool = False,
                 max_episode_steps: int | None = None, nthread: int = 1, render_mode: str | None = None,
                 **changes: Any) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        if max_episode_steps is not None and (isinstance(max_episode_steps, bool)
                                              or not isinstance(max_episode_steps, (int, np.integer))
                                              or max_episode_steps < 1):
            raise ValueError(f"max_episode_steps must be None or an integer >= 1, got {max_episode_steps!r}")
        if not isinstance(normalise, bool):
            raise ValueError(f"normalise must be True or False, got {normalise!r}")
        if render_mode is not None:
            raise ValueError(f"render_mode must be None: the vector environment does not render, got {render_mode!r}")
        self.config = config = dataclasses.replace(config or ArmEnvConfig(), **changes)
        if config.camera or config.tag_detections:
            raise ValueError(f"camera and tag_detections must be False: the vector environment has no camera, got "
                             f"camera={config.camera}, tag_detections={config.tag_detections}")
        self.num_envs, self.normalise, self.max_episode_steps = int(num_envs), normalise, max_episode_steps
        self.metadata = {**self.metadata, "render_fps": 1.0 / config.env_dt}
        self.plant = MujocoBatchPlant(config.plant().model, self.num_envs, config.control_dt, nthread)
        layout = self.plant.layout
        context = config.context()
        first = config.safety_filter(context)
        self.shared_filter = first if callable(getattr(first, "filter_batch", None)) else None
        filters = [first] + [first if self.shared_filter is not None else config.safety_filter(context)
                             for _ in range(self.num_envs - 1)]
        self.arms = [ArmControl(layout.n_segments, layout.n_facets, f, context, config.hold_s, config.estimator(),
                                lambda q0, b=b: self._reset_simulation(b, q0)) for b, f in enumerate(filters)]
        self.tasks: list[ArmTask] = [config.task(layout) for _ in range(self.num_envs)]
        self.u_low, self.u_high = self.tasks[0].u_min, self.tasks[0].u_max
        self.single_action_space, self.single_observation_space, self.scales = gym_spaces(
            self.tasks[0], self.arms[0], config, normalise)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._started = False

    def _reset_simulation(self, b: int, q0: np.ndarray) -> PlantState:
        """Simulation b alone at rest at q0 (N,) rad (`ArmControl`'s reset_plant)."""
        return self.plant.reset(np.asarray(q0, dtype=float)[None, :], ids=[b]).row(b)

    def reset(self, *, seed: int | Sequence[int | None] | None = None,
              options: dict[str, Any] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Every sub-environment's new episode (module docstring: seeds); (observations, infos)."""
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + b for b in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed must be None, an integer or num_envs = {self.num_envs} seeds, got {len(seeds)}")
        super().reset(seed=seeds[0])
        shared = self.shared_filter is not None
        results = [self._reset_arm(0, seeds[0], reset_filter=True)]  # a shared filter's reset() once, for all arms
        fault = self.arms[0].control_step.fault if shared else None  # a fault of that reset is every arm's
        results += [self._reset_arm(b, seeds[b], reset_filter=not shared, fault=fault) for b in range(1, self.num_envs)]
        self._autoreset[:] = False
        self._started = True
        return self._batch([obs for obs, _ in results]), self._infos([info for _, info in results])

    def _reset_arm(self, b: int, seed: int | None, reset_filter: bool,
                   fault: FilterFault | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Sub-environment b's new episode, as dm_control's `Environment.reset` and `GymArmEnv.reset`: its
        filter's `reset()` when `reset_filter`; `fault`: the fault of a shared filter's reset, if any."""
        task, arm = self.tasks[b], self.arms[b]
        if seed is not None:
            task.seed(seed)
        arm.reset(reset_filter=reset_filter)
        if fault is not None:
            arm.control_step.fault = fault
        task.initialize_episode(arm)
        arm.after_reset()
        observation, clipped = scaled_observation(task.get_observation(arm), self.scales)
        return observation, step_info(task, arm, clipped)

    def step(self, actions: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray,
                                                  dict[str, Any]]:
        """One env step of every sub-environment (module docstring); autoresets those whose episode ended."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = np.asarray(actions, dtype=float)
        shape = (self.num_envs, self.plant.n_segments)
        if actions.shape != shape:
            raise ValueError(f"actions must have shape {shape}, got {actions.shape}")
        resetting = self._autoreset.copy()
        running = np.flatnonzero(~resetting)
        for b in running:
            self.tasks[b].before_step(nominal_command(actions[b], self.u_low, self.u_high, self.normalise), self.arms[b])
            self.arms[b].begin_step()
        self._periods(running)
        observations: list[dict[str, np.ndarray] | None] = [None] * self.num_envs
        infos: list[dict[str, Any] | None] = [None] * self.num_envs
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        for b in running:
            task, arm = self.tasks[b], self.arms[b]
            arm.end_step()
            task.after_step(arm)
            rewards[b] = task.get_reward(arm)
            observations[b], clipped = scaled_observation(task.get_observation(arm), self.scales)
            discount = task.get_termination(arm)
            terminated[b] = discount == 0.0
            truncated[b] = (discount is not None and not terminated[b]) or (
                self.max_episode_steps is not None and task.steps >= self.max_episode_steps)
            infos[b] = step_info(task, arm, clipped)
        for b in np.flatnonzero(resetting):
            observations[b], infos[b] = self._reset_arm(b, None, reset_filter=self.shared_filter is None)
        self._autoreset = terminated | truncated
        return self._batch(observations), rewards, terminated, truncated, self._infos(infos)

    def _periods(self, running: np.ndarray) -> None:
        """The env step's control periods of the running arms, all simulations stepped together (module docstring)."""
        arms, active = self.arms, np.zeros(self.num_envs, dtype=bool)
        active[running] = True
        u = np.zeros((self.num_envs, self.plant.n_segments))
        for _ in range(self.config.action_repeat):
            if not active.any():
                break
            estimates = [arm.estimate() for arm in arms]
            steps = [arm.control_step for arm in arms]
            records: list[StepRecord | None]
            if self.shared_filter is not None:
                records = batch_rows(steps, self.shared_filter, estimates, active)
            else:
                records = [steps[b](estimates[b]) if active[b] else None for b in range(self.num_envs)]
            u[:] = 0.0
            for b, record in enumerate(records):
                if record is not None:
                    u[b] = record.u
            state = self.plant.step(u)
            for b in np.flatnonzero(active):
                arms[b].end_period(records[b], state.row(b))
                if steps[b].stopped:  # a filter fault has vented: b's episode ends (closedloop.step)
                    active[b] = False

    def _batch(self, observations: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        """The (B, ...) observations, fresh arrays."""
        return concatenate(self.single_observation_space, observations,
                           create_empty_array(self.single_observation_space, self.num_envs))

    def _infos(self, infos: list[dict[str, Any]]) -> dict[str, Any]:
        """The single environment's infos as Gymnasium's vector infos: per key a (B,) array and its mask "_key"."""
        out: dict[str, Any] = {}
        for key, first in infos[0].items():
            values = [info[key] for info in infos]
            if isinstance(first, (bool, int, float, np.number)):
                out[key] = np.array(values, dtype=type(first))
            else:  # element by element: numpy would unpack tuples of equal length into a 2-d array
                out[key] = np.empty(self.num_envs, dtype=object)
                for b, value in enumerate(values):
                    out[key][b] = value
            out[f"_{key}"] = np.ones(self.num_envs, dtype=bool)
        return out
