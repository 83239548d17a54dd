"""The physics of the arm environment: one physics step is one control period of the scenarios' loop.

`ArmPhysics` is a `dm_control.rl.control.Physics` over `MujocoPlant` (the MuJoCo ground
truth) and `closedloop.step.ControlStep` (the control step every loop shares). Its time
step is the control period Δ = `plant.control_dt` (s); `step(n)` runs n periods, each
exactly as `softcbf_mj.loops.loop.run_closed_loop` runs one:

    estimate  = estimator(state_k)                     (default: the exact state, t_capture = t)
    record    = control_step(estimate)                 nominal → filter → admission → monitor
    state_k+1 = plant.step(record.u)                   u (N,) hPa held for Δ (zero-order hold)

What does not depend on how the plant is stepped is `ArmControl` (ArmPhysics is one):
the control step, the estimate, the statistics below (`begin_step`, `end_period(record,
state)` per period, `end_step`) and the episode's reset. What the task reads of an arm is
`ArmArrays`, arrays with a leading axis of B arms: `ArmControl.arrays()` is one arm's (B = 1);
`softcbf_mj.env.vector` keeps the arrays of B arms stepped on one `MujocoBatchPlant` by
one `closedloop.step.BatchControlStep` (row b arm b's control step), its statistics
`BatchStepStats.of_figures` of a `softcbf_mj.outputs.metrics.RunningFigures` (the same definitions,
for all arms at once), so that the task (`softcbf_mj.env.task`) computes observations,
rewards, costs and terminations of one arm and of B arms with the same functions. (The
single environment keeps the per-period tally below: one `RunningFigures` update costs more
than a 1 ms env step's tally.)

The estimate of a state is made once, when the state is reached (`estimate()` returns it),
so the observation shows exactly what the filter is handed next. `NoisyState(q_std,
qd_std)` is the noisy-state estimator: the true q (rad) and q̇ (rad/s) plus independent
Gaussian noise N(0, q_std²), N(0, qd_std²) per segment, drawn from its generator
(`reseed(seed)`; the task reseeds it every episode); q_std = qd_std = 0 is `exact_state`.

The nominal controller of the control step is the policy's action: `set_control(u_nom)`
(N,) hPa sets the command that `HeldCommand` returns at every period until the next call,
so the filter still runs once per control period when the environment repeats an action
(dm_control's `n_sub_steps`, the environment's `action_repeat`). An action is converted once
(`action_array`): real numbers (float or int) of the action's shape; bool, complex, object or
string values and masked arrays (whose mask a conversion would drop, sending the masked
entries' stale data) are refused with a ValueError. A non-finite u_nom is not refused here:
the control step refuses it (HOLD, then VENT), as in every loop.

Per `step(n)` the physics keeps `StepStats` over its n periods, from the state at each
period's end: the number of periods with ρ_meas < 0 (ρ_meas = min over facets of the
safe set's `margin_from_force` of the plate's spring force, 1), the least ρ_meas, the
largest plate force (N), the mean force excess (1: the mean over the periods of
max_i max(0, F_i − F_max)/F_max, F_max the safe set's) and whether the safety monitor vented.
The filter is built once (`controllers.registry.build_filter`, by the environment); every `reset()` makes a new
`ControlStep` around it with a fresh `SafetyMonitor` (`hold_s`) and calls the filter's
`reset()` (the plug-in contract: called before each run).

The optional camera renders the model's `overhead` camera (`softcbf_mj.camera.render`) at
`image_size` (W, H) px; `tag_detections` runs `perception.detect.TagDetector` on that
image for the arm's tags 0..N. The renderer's GL context is freed by `close()`, or at the
latest when the physics is collected or the interpreter exits (`weakref.finalize`: freed
later, during interpreter shutdown, MuJoCo's OSMesa context raised an obscure ctypes error).
No usable OpenGL backend (MUJOCO_GL unset without OSMesa, or set to glfw without a display)
is a `softcbf_mj.camera.render.RenderBackendError` naming MUJOCO_GL=osmesa and MUJOCO_GL=egl.
"""

from __future__ import annotations

import math
import weakref
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple, Sequence

import numpy as np
from dm_control.rl import control

from closedloop.monitor import SafeAction, SafetyMonitor
from closedloop.step import ControlStep, FilterFault, StepRecord
from controllers.contract.safety_filter import Estimate, FilterContext, SafetyFilter
from perception.detect import Detection, TagDetector
from perception.tags import arm_tag_ids
from softcbf_mj.loops.loop import exact_state
from softcbf_mj.outputs.metrics import RunningFigures, rho_meas
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.physics.plant import PlantState
from softcbf_mj.camera.render import OffscreenRenderer
from vocabulary.settings import default


def action_array(action: object, shape: tuple[int, ...], name: str = "the action u_nom") -> np.ndarray:
    """`action` as a new float64 array of `shape` (hPa; module docstring): ValueError naming `name`, what is
    expected and what was received for a masked array, non-real values (bool, complex, object, str) or
    another shape. NaN and ±inf are kept: the control step refuses them as it refuses any nominal's."""
    if isinstance(action, np.ma.MaskedArray):
        raise ValueError(f"{name} must be a plain array of real numbers (hPa), got a masked array (its mask would be "
                         f"dropped): fill it first, e.g. np.ma.filled(action, 0.0)")
    try:
        array = np.asarray(action)
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{name} must be an array of real numbers of shape {shape} (hPa), got an unreadable "
                         f"{type(action).__name__}: {exc}") from None
    if array.dtype.kind not in "fiu":
        raise ValueError(f"{name} must hold real numbers (float or int) in hPa, got dtype {array.dtype}")
    if array.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
    return array.astype(float)


class HeldCommand:
    """The nominal controller of the environment: returns the policy's last action u_nom (N,) hPa."""

    def __init__(self, n_segments: int) -> None:
        self.u_nom = np.zeros(n_segments)

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.u_nom


class NoisyState:
    """The noisy-state estimator (module docstring): q + N(0, q_std²) rad, q̇ + N(0, qd_std²) rad/s, t_capture = t."""

    def __init__(self, q_std: float, qd_std: float, seed: int | None = None) -> None:
        for name, value, unit in (("q_std", q_std, "rad"), ("qd_std", qd_std, "rad/s")):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0 {unit}, got {value}")
        self.q_std, self.qd_std = float(q_std), float(qd_std)
        self.random = np.random.default_rng(seed)

    def reseed(self, seed: int | None) -> None:
        self.random = np.random.default_rng(seed)

    def __call__(self, state: PlantState) -> Estimate:
        n = len(state.q)
        return Estimate(state.t, state.q + self.random.normal(0.0, self.q_std, n),
                        state.qd + self.random.normal(0.0, self.qd_std, n), state.t)


@dataclass(frozen=True)
class StepStats:
    """What happened over the control periods of one `ArmPhysics.step(n)` (module docstring).

    periods: n; violation_periods: periods whose end state has ρ_meas < 0; rho_meas_min
    (1) and force_max_N (N) over their end states (+inf and 0 before any period);
    force_excess (1): the mean over them of max_i max(0, F_i − F_max)/F_max (0 before any
    period); vented: the safety monitor sent VENT in one of them.
    """

    periods: int = 0
    violation_periods: int = 0
    rho_meas_min: float = math.inf
    force_max_N: float = 0.0
    force_excess: float = 0.0
    vented: bool = False


class BatchStepStats(NamedTuple):
    """`StepStats` of B arms: the same fields in the same order, each a (B,) array (int64 periods and
    violation_periods, float64 rho_meas_min, force_max_N and force_excess, bool vented)."""

    periods: np.ndarray
    violation_periods: np.ndarray
    rho_meas_min: np.ndarray
    force_max_N: np.ndarray
    force_excess: np.ndarray
    vented: np.ndarray

    @staticmethod
    def of(stats: Sequence[StepStats]) -> "BatchStepStats":
        """The rows `stats` (one per arm)."""
        return BatchStepStats(np.array([s.periods for s in stats], dtype=np.int64),
                              np.array([s.violation_periods for s in stats], dtype=np.int64),
                              np.array([s.rho_meas_min for s in stats], dtype=float),
                              np.array([s.force_max_N for s in stats], dtype=float),
                              np.array([s.force_excess for s in stats], dtype=float),
                              np.array([s.vented for s in stats], dtype=bool))

    @staticmethod
    def of_figures(figures: RunningFigures) -> "BatchStepStats":
        """The statistics of an env step whose periods `figures` (made with f_max and force_floor 0 N)
        kept, run by run: force_excess their mean (0, as every other field's `StepStats` default, for a
        run with no period)."""
        periods = figures.rows.astype(np.int64)
        mean_excess = np.divide(figures.force_excess, periods, out=np.zeros(len(periods)), where=periods > 0)
        return BatchStepStats(periods, figures.violations.astype(np.int64), figures.rho_min_meas.copy(),
                              figures.force_max_N.copy(), mean_excess, figures.vented.copy())


class ArmArrays(NamedTuple):
    """What the task (`softcbf_mj.env.task`) reads of B arms after an env step or a reset, rows by arm.

    q, qd (B, N) rad, rad/s: the controller's estimates (what the filter sees next); u (B, N)
    hPa: the command sent in the last control period (0 after a reset); t (B,) s; q_true,
    qd_true (B, N): the true state; tip (B, 2) m: the true tip; contact_forces (B, P) N: the
    plates' forces; stats: the env step's `BatchStepStats`; vent_latched (B,) bool: the safety
    monitor has latched a vent; faulted (B,) bool: the episode's control step has a filter fault.
    """

    q: np.ndarray
    qd: np.ndarray
    u: np.ndarray
    t: np.ndarray
    q_true: np.ndarray
    qd_true: np.ndarray
    tip: np.ndarray
    contact_forces: np.ndarray
    stats: BatchStepStats
    vent_latched: np.ndarray
    faulted: np.ndarray


class ArmControl:
    """One arm's control step and its bookkeeping, whatever steps its plant (module docstring).

    The state the environment reads (`state`, `estimate()`, `last_record`, `stats`,
    `fault`, `vent_latched`, ρ_meas, ρ_pred) and what an env step does with it, for a plant
    of n_segments and n_facets that `reset_plant(q0)` (q0 (N,) rad) puts at rest and
    whose state after each control period is handed to `end_period`: `ArmPhysics` steps
    its own `MujocoPlant`; `softcbf_mj.env.vector` steps B of them on one batch plant.
    safety_filter: built for `context` (whose safe set gives ρ_meas and whose limits the
    control step clips to); hold_s: the safety monitor's hold (s).
    """

    def __init__(self, n_segments: int, n_facets: int, safety_filter: SafetyFilter, context: FilterContext,
                 hold_s: float, estimator: Callable[[PlantState], Estimate],
                 reset_plant: Callable[[np.ndarray], PlantState]) -> None:
        if context.safe_set.n_facets != n_facets:
            raise ValueError(f"the safe set has {context.safe_set.n_facets} facets, the MuJoCo scene {n_facets} plates")
        if context.robot.n_segments != n_segments:
            raise ValueError(f"the context's robot has {context.robot.n_segments} segments, the MuJoCo arm {n_segments}")
        self.n_segments, self.reset_plant = n_segments, reset_plant
        self.filter, self.context, self.estimator = safety_filter, context, estimator
        self.safe_set, self.hold_s = context.safe_set, hold_s
        self.command = HeldCommand(n_segments)
        self.control_step = self.new_control_step()
        self.lengths = context.robot.array("lengths")
        self.reset_state(np.zeros(n_segments))
        self.last_record: StepRecord | None = None
        self.stats = StepStats()
        self._tally = StepStats()

    def set_control(self, control: np.ndarray) -> None:
        """The policy's action u_nom (N,) hPa (`action_array`), held until the next call."""
        self.command.u_nom = action_array(control, (self.n_segments,))

    def reset(self, reset_filter: bool = True) -> None:
        """A new episode: a new control step (`reset_control`), u_nom = 0, the arm straight at rest."""
        self.command.u_nom = np.zeros(self.n_segments)
        self.reset_control(reset_filter)
        self.reset_state(np.zeros(self.n_segments))

    def reset_control(self, reset_filter: bool) -> None:
        """The episode's control step: a new one (a fresh monitor) and the filter's `reset()` unless
        `reset_filter` is False. (The vector environment resets its batched step's rows itself.)"""
        self.control_step = self.new_control_step()
        if reset_filter:
            self.control_step.reset()

    def after_reset(self) -> None:
        self.last_record, self._arrays = None, None
        self.stats = StepStats()

    def begin_step(self) -> None:
        """Before an env step's control periods: its `StepStats` start from none."""
        self._tally = StepStats()

    def end_period(self, record: StepRecord, state: PlantState) -> None:
        """The plant reached `state` under `record.u` (one control period): the estimate of
        `state`, and the period in the env step's `StepStats` (module docstring)."""
        self.state = state
        self._estimate = self.estimator(state)
        self.last_record, self._arrays = record, None
        rho = self.rho_meas()
        force = float(np.max(state.contact_forces, initial=0.0))
        tally = self._tally
        self._tally = StepStats(tally.periods + 1, tally.violation_periods + (rho < 0.0), min(tally.rho_meas_min, rho),
                                max(tally.force_max_N, force),
                                tally.force_excess + max(0.0, force - self.safe_set.f_max) / self.safe_set.f_max,
                                tally.vented or record.action is SafeAction.VENT)

    def end_step(self) -> None:
        """After an env step's periods: `stats` (force_excess their mean)."""
        tally = self._tally
        self.stats = replace(tally, force_excess=tally.force_excess / tally.periods) if tally.periods else tally
        self._arrays = None

    def new_control_step(self) -> ControlStep:
        """The control step of an episode: the filter, the held action as nominal, a fresh safety monitor."""
        return ControlStep(self.filter, self.command, self.context, SafetyMonitor(self.n_segments, self.hold_s))

    def reset_state(self, q0: np.ndarray) -> None:
        """Rest at bending angles q0 (N,) rad (`reset_plant`), and its estimate."""
        self.state = self.reset_plant(q0)
        self._estimate, self._arrays = self.estimator(self.state), None

    def estimate(self) -> Estimate:
        """The controller's view of the current state (what the filter sees next; made once per state)."""
        return self._estimate

    def arrays(self) -> ArmArrays:
        """This arm's `ArmArrays` (B = 1, views of the current state; made once per state and statistics)."""
        if self._arrays is None:
            state, estimate, record = self.state, self._estimate, self.last_record
            u = record.u if record is not None else np.zeros(self.n_segments)
            self._arrays = ArmArrays(estimate.q[None], estimate.qd[None], np.asarray(u, dtype=float)[None],
                                     np.array([state.t]), state.q[None], state.qd[None], state.tip[None],
                                     state.contact_forces[None], BatchStepStats.of([self.stats]),
                                     np.array([self.vent_latched]), np.array([self.fault is not None]))
        return self._arrays

    def rho_meas(self) -> float:
        """ρ_meas (1) of the current state: min over facets of the margin from the plate force (`metrics.rho_meas`)."""
        return float(rho_meas(self.safe_set, self.state.contact_forces))

    @property
    def fault(self) -> FilterFault | None:
        """The episode's filter fault (closedloop.step), None without one: the episode has ended."""
        return self.control_step.fault

    @property
    def vent_latched(self) -> bool:
        """The safety monitor has latched a vent (the episode cannot recover)."""
        return self.control_step.monitor.vent_latched


class ArmPhysics(ArmControl, control.Physics):
    """MujocoPlant + ControlStep (`ArmControl`), stepped one control period at a time (module docstring).

    image_size (W, H) px sizes the camera's frames; the other arguments as `ArmControl`'s.
    """

    def __init__(self, plant: MujocoPlant, safety_filter: SafetyFilter, context: FilterContext,
                 hold_s: float = default("hold_s", "environment"),
                 estimator: Callable[[PlantState], Estimate] = exact_state, image_size: tuple[int, int] = (320, 180)) -> None:
        self.plant, self.image_size = plant, image_size
        super().__init__(plant.n_segments, plant.n_facets, safety_filter, context, hold_s, estimator, plant.reset)
        self._renderer: OffscreenRenderer | None = None
        self._free_renderer: weakref.finalize | None = None
        self._detector: TagDetector | None = None

    # -- dm_control Physics -------------------------------------------------------

    def timestep(self) -> float:
        """The control period Δ (s): one physics step of the environment."""
        return self.plant.control_dt

    def time(self) -> float:
        """The simulated time (s) since the episode's start."""
        return self.state.t

    def step(self, n_sub_steps: int = 1) -> None:
        """Run `n_sub_steps` control periods (module docstring); their `StepStats` in `stats`."""
        self.begin_step()
        for _ in range(n_sub_steps):
            record = self.control_step(self._estimate)
            self.end_period(record, self.plant.step(record.u))
            if self.control_step.stopped:  # a filter fault has vented: the episode ends (closedloop.step)
                break
        self.end_step()

    # -- the camera -------------------------------------------------------------------

    def render_image(self) -> np.ndarray:
        """The overhead camera's image (H, W, 3) uint8 RGB of the current state."""
        if self._renderer is None:
            self._renderer = OffscreenRenderer(self.plant.model, "overhead", *self.image_size)
            self._free_renderer = weakref.finalize(self, self._renderer.close)  # before interpreter shutdown
        return self._renderer.render(self.plant.data)

    def detect_tags(self, image: np.ndarray) -> list[Detection]:
        """The arm's tags (ids 0..N) found in `image` (RGB uint8)."""
        if self._detector is None:
            self._detector = TagDetector(tag_ids=arm_tag_ids(self.plant.n_segments))
        return self._detector.detect(np.ascontiguousarray(image[:, :, ::-1]))

    def close(self) -> None:
        """Free the renderer's GL context (rendering again makes a new one)."""
        if self._free_renderer is not None:
            self._free_renderer()  # OffscreenRenderer.close, once
            self._renderer = self._free_renderer = None
