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
- control: row b of one `closedloop.step.BatchControlStep` (b's control step with its own
  safety monitor row, bit for bit the `ControlStep` of b's single environment), and an
  `ArmControl` (`softcbf_mj.env.physics`: b's estimator, state and `StepStats`, the latter
  kept for all arms at once by `softcbf_mj.metrics.RunningFigures`);
- task: an `ArmTask` (`softcbf_mj.env.task`: observation, reward, cost, termination and
  b's own generator of initial states);
- Gymnasium: the spaces, the (normalised) command, the scaled observation and the info of
  `softcbf_mj.env.gym_adapter`.

So for the same seeds and actions the vector environment returns what B single
environments return (`tests/test_env_vector.py`: equal, bit for bit, with per-arm
filters; with a batched filter the commands are those of `filter_batch`, which
`controllers.filter.CBFFilter` promises within 1e-9 hPa of B calls).

One env step, for every sub-environment that is not being reset ("running"):

    u_nom (B, N) = nominal_command(action_b) per arm            hPa, held for the env step
    repeat action_repeat control periods, t_k = k Δ:
        record = the batched control step of the running arms at their estimates, with
                 u_nom as their nominal commands: a filter with `filter_batch`: one filter
                 for all, one call for the arms that call it; otherwise B filters, one per
                 arm (built by the registry), called in turn
        u (B, N) hPa = record.u: the running arms' commands, 0 hPa for the others
        state = plant.step(u)                                 one batch call for all B
        the period in every running arm's `StepStats` (one `RunningFigures` update) and the
        estimates of the new states (the exact state: the state's arrays; a noisy one: each
        arm's estimator, its own generator)
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

from closedloop.step import BatchControlStep, FilterFault, StepRecord
from controllers.safety_filter import Estimate
from softcbf_mj.env.environment import ArmEnvConfig
from softcbf_mj.env.gym_adapter import gym_spaces, nominal_command, scaled_observation, step_info
from softcbf_mj.env.physics import ArmControl, StepStats
from softcbf_mj.env.task import ArmTask
from softcbf_mj.loop import exact_state
from softcbf_mj.metrics import RunningFigures, rho_meas
from softcbf_mj.mujoco_batch_plant import MujocoBatchPlant
from softcbf_mj.plant import BatchPlantState, PlantState


class BatchArm(ArmControl):
    """Sub-environment b's `ArmControl` whose control step is row b of the vector environment's
    `BatchControlStep` (`control`): its fault and latched vent are that row's; the vector
    environment resets the row and runs the periods (`ArmControl.end_batched_step`)."""

    def __init__(self, control: BatchControlStep, b: int, *args: Any) -> None:
        self.batch_control, self.row = control, b
        super().__init__(*args)

    def new_control_step(self) -> None:  # type: ignore[override] - the batched step's row b is the control step
        return None

    def reset_control(self, reset_filter: bool) -> None:
        """Nothing here: the vector environment resets row b of its batched step (`ArmVectorEnv`)."""

    @property
    def fault(self) -> FilterFault | None:
        return self.batch_control.faults[self.row]

    @property
    def vent_latched(self) -> bool:
        return bool(self.batch_control.monitor.latched[self.row])


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
        self.control = BatchControlStep(first if self.shared_filter is not None else filters, None, context,
                                        self.num_envs, config.hold_s)
        self.safe_set = context.safe_set
        n, b_all = layout.n_segments, self.num_envs
        self._est_t, self._est_tc = np.zeros(b_all), np.zeros(b_all)  # the arms' current estimates, by row
        self._est_q, self._est_qd = np.zeros((b_all, n)), np.zeros((b_all, n))
        self.arms = [BatchArm(self.control, b, n, layout.n_facets, f, context, config.hold_s, config.estimator(),
                              lambda q0, b=b: self._reset_simulation(b, q0)) for b, f in enumerate(filters)]
        self.exact = all(arm.estimator is exact_state for arm in self.arms)
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
        self.control.reset()  # every row; a shared filter's reset() once, whose fault is every arm's
        results = [self._reset_arm(b, seeds[b], reset_row=False) for b in range(self.num_envs)]
        self._autoreset[:] = False
        self._started = True
        return self._batch([obs for obs, _ in results]), self._infos([info for _, info in results])

    def _reset_arm(self, b: int, seed: int | None, reset_row: bool) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """Sub-environment b's new episode, as dm_control's `Environment.reset` and `GymArmEnv.reset`;
        `reset_row`: row b of the batched step too (an autoreset: its monitor and, for per-arm
        filters, its filter's `reset()`; a shared filter is reset by `reset()` only)."""
        task, arm = self.tasks[b], self.arms[b]
        if seed is not None:
            task.seed(seed)
        if reset_row:
            self.control.reset(np.arange(self.num_envs) == b, filters=self.shared_filter is None)
        arm.reset()
        task.initialize_episode(arm)
        arm.after_reset()
        estimate = arm.estimate()
        self._est_t[b], self._est_tc[b] = estimate.t, estimate.t_capture
        self._est_q[b], self._est_qd[b] = estimate.q, estimate.qd
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
        self.run_periods(running)
        observations: list[dict[str, np.ndarray] | None] = [None] * self.num_envs
        infos: list[dict[str, Any] | None] = [None] * self.num_envs
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = np.zeros(self.num_envs, dtype=bool)
        for b in running:
            task, arm = self.tasks[b], self.arms[b]
            task.after_step(arm)
            rewards[b] = task.get_reward(arm)
            observations[b], clipped = scaled_observation(task.get_observation(arm), self.scales)
            discount = task.get_termination(arm)
            terminated[b] = discount == 0.0
            truncated[b] = (discount is not None and not terminated[b]) or (
                self.max_episode_steps is not None and task.steps >= self.max_episode_steps)
            infos[b] = step_info(task, arm, clipped)
        for b in np.flatnonzero(resetting):
            observations[b], infos[b] = self._reset_arm(b, None, reset_row=True)
        self._autoreset = terminated | truncated
        return self._batch(observations), rewards, terminated, truncated, self._infos(infos)

    def run_periods(self, running: np.ndarray) -> None:
        """The env step's control periods of the running arms, all simulations stepped together (module
        docstring); each running arm then holds its end state, its estimate, the last record and its `StepStats`."""
        arms, control, plant, n_sims = self.arms, self.control, self.plant, self.num_envs
        active = np.zeros(n_sims, dtype=bool)
        active[running] = True
        u_nom = np.array([arm.command.u_nom for arm in arms])
        figures = RunningFigures(n_sims, plant.control_dt, f_max=self.safe_set.f_max, force_floor=0.0)
        ended: dict[int, tuple[PlantState, StepRecord]] = {}  # arms stopped by a fault: where they stopped
        estimates: list[Estimate | None] = [None] * n_sims  # a noisy estimator's estimates of the last states
        for _ in range(self.config.action_repeat):
            if not active.any():
                break
            rows = None if active.all() else active
            record = control(self._est_t, self._est_q, self._est_qd, self._est_tc, rows=rows, u_nom=u_nom)
            state = plant.step(record.u)
            figures.update(rho_meas(self.safe_set, state.contact_forces)[None], state.contact_forces[None],
                           record.u[None], record.rho_pred[None], record.infeasible[None], record.action[None],
                           None if rows is None else rows[None])
            self._estimate_rows(state, active, estimates)
            stopped = control.stopped & active
            if stopped.any():  # a filter fault has vented: b's episode ends (closedloop.step)
                for b in np.flatnonzero(stopped).tolist():
                    ended[b] = state.row(b), record.row(b)
                active &= ~stopped
        for b in running.tolist():
            end_state, end_record = ended[b] if b in ended else (state.row(b), record.row(b))
            periods = int(figures.rows[b])
            stats = StepStats(periods, int(figures.violations[b]), float(figures.rho_min_meas[b]),
                              float(figures.force_max_N[b]), float(figures.force_excess[b]) / periods,
                              bool(figures.vented[b]))
            estimate = estimates[b] if estimates[b] is not None else exact_state(end_state)
            arms[b].end_batched_step(end_state, estimate, end_record, stats)

    def _estimate_rows(self, state: BatchPlantState, active: np.ndarray, estimates: list[Estimate | None]) -> None:
        """The estimates of the active arms' new states into the rows the next period's step reads (module
        docstring); a noisy estimator's also into `estimates` (their draws are the arm's)."""
        if self.exact:
            self._est_t[active], self._est_tc[active] = state.t[active], state.t[active]
            self._est_q[active], self._est_qd[active] = state.q[active], state.qd[active]
            return
        for b in np.flatnonzero(active).tolist():
            estimate = estimates[b] = self.arms[b].estimator(state.row(b))
            self._est_t[b], self._est_tc[b] = estimate.t, estimate.t_capture
            self._est_q[b], self._est_qd[b] = estimate.q, estimate.qd

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
