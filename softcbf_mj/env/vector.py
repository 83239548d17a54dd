"""The arm environment as a Gymnasium vector environment on the batch plant: B arms, one `mujoco.batch`.

    envs = gymnasium.make_vec("softcbf_mj/SoftArm-v1", num_envs=32, vectorization_mode="vector_entry_point",
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
  safety monitor row, bit for bit the `ControlStep` of b's single environment); the env
  step's statistics of all arms at once (`softcbf_mj.outputs.metrics.RunningFigures`,
  `physics.BatchStepStats.of_figures`);
- episode starts: an `ArmControl` (`softcbf_mj.env.physics`: b's estimator and reset) and an
  `ArmTask` (`softcbf_mj.env.task`: b's own generator of initial states), per arm;
- task: observation, reward, cost and termination of all B arms in one call each
  (`ArmTask.observations`, `rewards`, `costs`, `ends` on the arms' `physics.ArmArrays`, the
  very functions the single environment calls with B = 1), numpy over the arms;
- Gymnasium: the spaces, the (normalised) command, the scaled observations and the infos of
  `softcbf_mj.env.gym_adapter` (`scaled_observations`, `step_infos`, again those of B = 1).

So for the same seeds and actions the vector environment returns what B single
environments return (`tests/test_env_vector.py`: equal, bit for bit, with per-arm
filters; with a batched filter the commands are those of `filter_batch`, which
`controllers.cbf.paper_filter.CBFFilter` promises within 1e-9 hPa of B calls).

One env step, for every sub-environment that is not being reset ("running"):

    u_nom (B, N) = nominal_command(actions) of the running arms  hPa, held for the env step
    repeat action_repeat control periods, t_k = k Δ:
        record = the batched control step of the running arms at their estimates, with
                 u_nom as their nominal commands: a filter that declares batched
                 (`controllers.contract.capabilities.filter_capabilities`): one filter for all, one
                 call for the arms that call it; otherwise B filters, one per arm (built by
                 the registry), called in turn
        u (B, N) hPa = record.u: the running arms' commands, 0 hPa for the others
        state = plant.step(u)                                 one batch call for all B
        the period in every running arm's `StepStats` (one `RunningFigures` update) and the
        estimates of the new states (the exact state: the state's arrays; a noisy one: each
        arm's estimator, its own generator)
    an arm whose control step has stopped (a filter fault's vent, `closedloop.step`)
    stops for the rest of the env step: its episode ends (terminated, info["fault"]), as
    in the single environment; the others go on.

The vector environment keeps the arrays the task reads (`ArmArrays`: each arm's estimate,
last command, true state and statistics; an arm stopped by a fault keeps the state and
record of its stop); then, for all arms at once, as dm_control's `Environment.step` and
`GymArmEnv.step`: reward, observation, cost and termination (dm_env's discount 0:
terminated; 1: truncated at `episode_steps`), truncated also when an episode reaches
`max_episode_steps` env steps (Gymnasium's `TimeLimit`). Only episode starts and a noisy
estimator's draws (each arm's own generator) run arm by arm.

Autoreset (Gymnasium 1.x, `metadata["autoreset_mode"]` = `AutoresetMode.NEXT_STEP`, as
`SyncVectorEnv`): a sub-environment whose step ended its episode (terminated or
truncated) is reset by the next `step()`: its action is ignored, it returns the reset's
observation and info, reward 0, terminated = truncated = False. Its simulation is sent
0 hPa during that call's periods and reset after them (what it did in between is lost).

Seeds (as `SyncVectorEnv`): `reset(seed=s)` seeds sub-environment b's task with s + b, a
list seeds b with its b-th entry (None: not reseeded), `reset()` lets each continue its
generator. A filter shared by all arms (one that declares batched) is reset (its
`reset()`) by `reset()`; when one arm's episode restarts, only if it declares reset_rows
(a history per row: then `reset(rows=[b])`, as qsg), for otherwise its state spans all arms
(the `filter_batch` contract, `controllers.contract.safety_filter`): the batched step decides
(`closedloop.step.BatchControlStep.reset`); per-arm filters are reset at each of their
episodes, as in the single environment.

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
from gymnasium.vector.utils import batch_space

from closedloop.monitor import ACTIONS
from closedloop.step import BatchControlStep, BatchStepRecord, FilterFault
from controllers.contract.capabilities import filter_capabilities
from softcbf_mj.env.environment import ArmEnvConfig
from softcbf_mj.env.gym_adapter import gym_spaces, nominal_command, object_array, scaled_observations, step_infos
from softcbf_mj.env.physics import ArmArrays, ArmControl, BatchStepStats, StepStats, action_array
from softcbf_mj.env.task import ArmTask
from softcbf_mj.loops.loop import exact_state
from softcbf_mj.outputs.metrics import RunningFigures, rho_meas
from softcbf_mj.physics.mujoco_batch_plant import MujocoBatchPlant
from softcbf_mj.physics.plant import BatchPlantState, PlantState

MONITOR_LABELS = np.array([action.value for action in ACTIONS], dtype=object)  # by the monitor's action code


class BatchArm(ArmControl):
    """Sub-environment b's `ArmControl` for its episode starts (its estimator, its reset on simulation
    b), whose control step is row b of the vector environment's `BatchControlStep` (`control`):
    its fault and latched vent are that row's; the vector environment resets the row, runs the
    periods and keeps the arms' current state (`ArmVectorEnv`)."""

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
        self.shared_filter = first if filter_capabilities(first).batched else None
        filters = [first] + [first if self.shared_filter is not None else config.safety_filter(context)
                             for _ in range(self.num_envs - 1)]
        self.control = BatchControlStep(first if self.shared_filter is not None else filters, None, context,
                                        self.num_envs, config.hold_s)
        self.safe_set, self.lengths = context.safe_set, context.robot.array("lengths")
        n, p, b_all = layout.n_segments, layout.n_facets, self.num_envs
        # the arms' current arrays, by row (`ArmArrays`, module docstring): the estimates (what the next
        # period's control step reads), the last commands, the true states and their monitor and filter labels
        self._est_t, self._est_tc = np.zeros(b_all), np.zeros(b_all)
        self._est_q, self._est_qd = np.zeros((b_all, n)), np.zeros((b_all, n))
        self._u_nom, self._u = np.zeros((b_all, n)), np.zeros((b_all, n))
        self._t, self._q, self._qd = np.zeros(b_all), np.zeros((b_all, n)), np.zeros((b_all, n))
        self._tip, self._forces = np.zeros((b_all, 2)), np.zeros((b_all, p))
        self._monitor_action, self._filter_action = object_labels(b_all), object_labels(b_all)
        self._stats = BatchStepStats.of([StepStats()] * b_all)
        self._steps = np.zeros(b_all, dtype=int)
        self.arms = [BatchArm(self.control, b, n, p, f, context, config.hold_s, config.estimator(),
                              lambda q0, b=b: self._reset_simulation(b, q0)) for b, f in enumerate(filters)]
        self.exact = all(arm.estimator is exact_state for arm in self.arms)
        self.tasks: list[ArmTask] = [config.task(layout) for _ in range(self.num_envs)]
        self.task = self.tasks[0]  # every arm's task has the same definitions: the batched calls use the first's
        self.u_low, self.u_high = self.task.u_min, self.task.u_max
        self.single_action_space, self.single_observation_space, self.scales = gym_spaces(
            self.task, self.arms[0], config, normalise)
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
        for b in range(self.num_envs):
            self._reset_arm(b, seeds[b], reset_row=False)
        self._stats = BatchStepStats.of([StepStats()] * self.num_envs)
        self._autoreset[:] = False
        self._started = True
        observations, infos = self._observe()
        return observations, infos

    def _reset_arm(self, b: int, seed: int | None, reset_row: bool) -> None:
        """Sub-environment b's new episode, as dm_control's `Environment.reset` and `GymArmEnv.reset`, into
        row b of the arrays; `reset_row`: row b of the batched step too (an autoreset: its monitor and,
        for per-arm filters, its filter's `reset()`, for a shared one with a history per row its `reset(rows=[b])`)."""
        task, arm = self.tasks[b], self.arms[b]
        if seed is not None:
            task.seed(seed)
        if reset_row:
            self.control.reset(np.arange(self.num_envs) == b)
        arm.reset()
        task.initialize_episode(arm)
        arm.after_reset()
        estimate, state = arm.estimate(), arm.state
        self._est_t[b], self._est_tc[b] = estimate.t, estimate.t_capture
        self._est_q[b], self._est_qd[b] = estimate.q, estimate.qd
        self._t[b], self._q[b], self._qd[b] = state.t, state.q, state.qd
        self._tip[b], self._forces[b] = state.tip, state.contact_forces
        self._u_nom[b], self._u[b], self._monitor_action[b], self._filter_action[b] = 0.0, 0.0, "", ""
        self._steps[b] = task.steps

    def step(self, actions: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray, np.ndarray,
                                                  dict[str, Any]]:
        """One env step of every sub-environment (module docstring); autoresets those whose episode ended."""
        if not self._started:
            raise RuntimeError("call reset() before step()")
        actions = action_array(actions, (self.num_envs, self.plant.n_segments), "actions")
        resetting = self._autoreset.copy()
        running = ~resetting
        self._u_nom[running] = nominal_command(actions[running], self.u_low, self.u_high, self.normalise)
        self.run_periods(running)
        self._steps[running] += 1
        for b in np.flatnonzero(resetting).tolist():
            self._reset_arm(b, None, reset_row=True)
        arms = self.arrays()
        rewards = np.where(running, self.task.rewards(arms), 0.0)
        terminated, truncated = self.task.ends(arms, self._steps)
        if self.max_episode_steps is not None:  # Gymnasium's TimeLimit: truncated at the limit, terminated or not
            truncated |= self._steps >= self.max_episode_steps
        terminated &= running
        truncated &= running
        self._autoreset = terminated | truncated
        observations, infos = self._observe(arms)
        return observations, rewards, terminated, truncated, infos

    def arrays(self) -> ArmArrays:
        """The arms' current `ArmArrays` (views of this environment's rows)."""
        control = self.control
        return ArmArrays(self._est_q, self._est_qd, self._u, self._t, self._q, self._qd, self._tip, self._forces,
                         self._stats, control.monitor.latched.copy(), control.faulted.copy())

    def _observe(self, arms: ArmArrays | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
        """(observations, infos) of every arm from its arrays: the task's observations, scaled as the
        single environment's, in the single space's key order; Gymnasium's vector infos (per key a (B,)
        array and its all-True mask "_key")."""
        arms = self.arrays() if arms is None else arms
        observations, clipped = scaled_observations(self.task.observations(arms, self.safe_set, self.lengths),
                                                    self.scales)
        infos: dict[str, Any] = {}
        mask = np.ones(self.num_envs, dtype=bool)
        for key, value in step_infos(self.task, arms, clipped, self._monitor_action, self._filter_action,
                                     self.control.faults).items():
            infos[key] = np.array(value) if isinstance(value, np.ndarray) else object_array(value)  # fresh arrays
            infos[f"_{key}"] = mask.copy()
        return {key: observations[key] for key in self.single_observation_space.keys()}, infos

    def run_periods(self, running: np.ndarray) -> None:
        """The env step's control periods of the `running` arms ((B,) bool), all simulations stepped
        together (module docstring); then each running arm's row holds its end state, its estimate, the
        last command and labels, and the env step's statistics."""
        control, plant, n_sims = self.control, self.plant, self.num_envs
        active = running.copy()
        figures = RunningFigures(n_sims, plant.control_dt, f_max=self.safe_set.f_max, force_floor=0.0)
        ended: list[tuple[np.ndarray, BatchPlantState, BatchStepRecord]] = []  # arms stopped by a fault: where
        state = record = None
        for _ in range(self.config.action_repeat):
            if not active.any():
                break
            rows = None if active.all() else active
            record = control(self._est_t, self._est_q, self._est_qd, self._est_tc, rows=rows, u_nom=self._u_nom)
            state = plant.step(record.u)
            figures.update(rho_meas(self.safe_set, state.contact_forces)[None], state.contact_forces[None],
                           record.u[None], record.rho_pred[None], record.infeasible[None], record.action[None],
                           None if rows is None else rows[None])
            self._estimate_rows(state, active)
            stopped = control.stopped & active
            if stopped.any():  # a filter fault has vented: b's episode ends (closedloop.step)
                ended.append((stopped, state, record))
                active &= ~stopped
        self._stats = BatchStepStats.of_figures(figures)
        if state is None or record is None:
            return
        self._keep(running & ~np.logical_or.reduce([rows for rows, *_ in ended], initial=False), state, record)
        for rows, stop_state, stop_record in ended:
            self._keep(rows, stop_state, stop_record)

    def _keep(self, rows: np.ndarray, state: BatchPlantState, record: BatchStepRecord) -> None:
        """The rows `rows` ((B,) bool) of an env step's end `state` and last `record` into the arms' arrays."""
        self._t[rows], self._q[rows], self._qd[rows] = state.t[rows], state.q[rows], state.qd[rows]
        self._tip[rows], self._forces[rows] = state.segment_ends[rows, -1], state.contact_forces[rows]
        self._u[rows] = record.u[rows]
        self._monitor_action[rows] = MONITOR_LABELS[record.action[rows]]
        labels = np.array(record.filter_action, dtype=object)  # a label where the filter's output was taken
        labels[~record.output] = ""
        self._filter_action[rows] = labels[rows]

    def _estimate_rows(self, state: BatchPlantState, active: np.ndarray) -> None:
        """The estimates of the active arms' new states into the rows the next period's step reads and
        the observation shows (module docstring); a noisy estimator's from each arm's own generator."""
        if self.exact:
            self._est_t[active], self._est_tc[active] = state.t[active], state.t[active]
            self._est_q[active], self._est_qd[active] = state.q[active], state.qd[active]
            return
        for b in np.flatnonzero(active).tolist():
            estimate = self.arms[b].estimator(state.row(b))
            self._est_t[b], self._est_tc[b] = estimate.t, estimate.t_capture
            self._est_q[b], self._est_qd[b] = estimate.q, estimate.qd


def object_labels(n: int) -> np.ndarray:
    """(n,) object array of empty labels ""."""
    out = np.empty(n, dtype=object)
    out[:] = ""
    return out
