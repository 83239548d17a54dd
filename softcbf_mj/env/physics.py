"""The physics of the arm environment: one physics step is one control period of the scenarios' loop.

`ArmPhysics` is a `dm_control.rl.control.Physics` over `MujocoPlant` (the MuJoCo ground
truth) and `closedloop.step.ControlStep` (the control step every loop shares). Its time
step is the control period Δ = `plant.control_dt` (s); `step(n)` runs n periods, each
exactly as `softcbf_mj.loop.run_closed_loop` runs one:

    estimate  = estimator(state_k)                     (default: the exact state, t_capture = t)
    record    = control_step(estimate)                 nominal → filter → admission → monitor
    state_k+1 = plant.step(record.u)                   u (N,) hPa held for Δ (zero-order hold)

The nominal controller of the control step is the policy's action: `set_control(u_nom)`
(N,) hPa sets the command that `HeldCommand` returns at every period until the next call,
so the filter still runs once per control period when the environment repeats an action
(dm_control's `n_sub_steps`, the environment's `action_repeat`). A non-finite u_nom is
not refused here: the control step refuses it (HOLD, then VENT), as in every loop.

Per `step(n)` the physics keeps `StepStats` over its n periods, from the state at each
period's end: the number of periods with ρ_meas < 0 (ρ_meas = min over facets of the
safe set's `margin_from_force` of the plate's spring force, 1), the least ρ_meas, the
largest plate force (N) and whether the safety monitor vented. The filter is built once
(`controllers.registry.build_filter`, by the environment); every `reset()` makes a new
`ControlStep` around it with a fresh `SafetyMonitor` (`hold_s`) and calls the filter's
`reset()` (the plug-in contract: called before each run).

The optional camera renders the model's `overhead` camera (`softcbf_mj.render`) at
`image_size` (W, H) px; `tag_detections` runs `perception.detect.TagDetector` on that
image for the arm's tags 0..N.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
from dm_control.rl import control

from closedloop.monitor import DEFAULT_HOLD_S, SafeAction, SafetyMonitor
from closedloop.step import ControlStep, FilterFault, StepRecord
from controllers.safety_filter import Estimate, FilterContext, SafetyFilter
from perception.detect import Detection, TagDetector
from perception.tags import arm_tag_ids
from softcbf_mj.loop import exact_state
from softcbf_mj.mujoco_plant import MujocoPlant
from softcbf_mj.plant import PlantState
from softcbf_mj.render import OffscreenRenderer


class HeldCommand:
    """The nominal controller of the environment: returns the policy's last action u_nom (N,) hPa."""

    def __init__(self, n_segments: int) -> None:
        self.u_nom = np.zeros(n_segments)

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self.u_nom


@dataclass(frozen=True)
class StepStats:
    """What happened over the control periods of one `ArmPhysics.step(n)` (module docstring).

    periods: n; violation_periods: periods whose end state has ρ_meas < 0; rho_meas_min
    (1) and force_max_N (N) over their end states (+inf and 0 before any period);
    vented: the safety monitor sent VENT in one of them.
    """

    periods: int = 0
    violation_periods: int = 0
    rho_meas_min: float = math.inf
    force_max_N: float = 0.0
    vented: bool = False


class ArmPhysics(control.Physics):
    """MujocoPlant + ControlStep, stepped one control period at a time (module docstring).

    safety_filter: built for `context` (whose safe set gives ρ_meas and whose limits the
    control step clips to); hold_s: the safety monitor's hold (s); image_size (W, H) px
    sizes the camera's frames.
    """

    def __init__(self, plant: MujocoPlant, safety_filter: SafetyFilter, context: FilterContext,
                 hold_s: float = DEFAULT_HOLD_S, estimator: Callable[[PlantState], Estimate] = exact_state,
                 image_size: tuple[int, int] = (320, 180)) -> None:
        if context.safe_set.n_facets != plant.n_facets:
            raise ValueError(f"the safe set has {context.safe_set.n_facets} facets, the MuJoCo scene {plant.n_facets} plates")
        if context.robot.n_segments != plant.n_segments:
            raise ValueError(f"the context's robot has {context.robot.n_segments} segments, the MuJoCo arm {plant.n_segments}")
        self.plant, self.filter, self.context, self.estimator = plant, safety_filter, context, estimator
        self.safe_set, self.hold_s, self.image_size = context.safe_set, hold_s, image_size
        self.command = HeldCommand(plant.n_segments)
        self.control_step = self.new_control_step()
        self.state = plant.reset(np.zeros(plant.n_segments))
        self.last_record: StepRecord | None = None
        self.stats = StepStats()
        self._renderer: OffscreenRenderer | None = None
        self._detector: TagDetector | None = None

    # -- dm_control Physics -------------------------------------------------------

    def timestep(self) -> float:
        """The control period Δ (s): one physics step of the environment."""
        return self.plant.control_dt

    def time(self) -> float:
        """The simulated time (s) since the episode's start."""
        return self.state.t

    def set_control(self, control: np.ndarray) -> None:
        """The policy's action u_nom (N,) hPa, held until the next call."""
        u_nom = np.array(control, dtype=float)
        if u_nom.shape != (self.plant.n_segments,):
            raise ValueError(f"the action u_nom must have shape ({self.plant.n_segments},) hPa, got {u_nom.shape}")
        self.command.u_nom = u_nom

    def reset(self) -> None:
        """A new episode: a new control step (the filter reset, a fresh monitor), u_nom = 0, the arm straight at rest."""
        self.command.u_nom = np.zeros(self.plant.n_segments)
        self.control_step = self.new_control_step()
        self.control_step.reset()
        self.reset_state(np.zeros(self.plant.n_segments))

    def after_reset(self) -> None:
        self.last_record = None
        self.stats = StepStats()

    def step(self, n_sub_steps: int = 1) -> None:
        """Run `n_sub_steps` control periods (module docstring); their `StepStats` in `stats`."""
        periods = violations = 0
        rho_min, force_max, vented = math.inf, 0.0, False
        for _ in range(n_sub_steps):
            record = self.control_step(self.estimator(self.state))
            self.state = self.plant.step(record.u)
            self.last_record = record
            rho = self.rho_meas()
            periods += 1
            violations += rho < 0.0
            rho_min = min(rho_min, rho)
            force_max = max(force_max, float(np.max(self.state.contact_forces, initial=0.0)))
            vented = vented or record.action is SafeAction.VENT
            if self.control_step.stopped:  # a filter fault has vented: the episode ends (closedloop.step)
                break
        self.stats = StepStats(periods, violations, rho_min, force_max, vented)

    # -- the environment's view -------------------------------------------------------

    def new_control_step(self) -> ControlStep:
        """The control step of an episode: the filter, the held action as nominal, a fresh safety monitor."""
        return ControlStep(self.filter, self.command, self.context, SafetyMonitor(self.plant.n_segments, self.hold_s))

    def reset_state(self, q0: np.ndarray) -> None:
        """Rest at bending angles q0 (N,) rad (the plant's `reset`)."""
        self.state = self.plant.reset(q0)

    def estimate(self) -> Estimate:
        """The controller's view of the current state (what the filter sees next)."""
        return self.estimator(self.state)

    def rho_meas(self) -> float:
        """ρ_meas (1) of the current state: min over facets of the margin from the plate force."""
        return float(np.min(self.safe_set.margin_from_force(self.state.contact_forces)))

    @property
    def fault(self) -> FilterFault | None:
        """The episode's filter fault (closedloop.step), None without one: the episode has ended."""
        return self.control_step.fault

    @property
    def vent_latched(self) -> bool:
        """The safety monitor has latched a vent (the episode cannot recover)."""
        return self.control_step.monitor.vent_latched

    def render_image(self) -> np.ndarray:
        """The overhead camera's image (H, W, 3) uint8 RGB of the current state."""
        if self._renderer is None:
            self._renderer = OffscreenRenderer(self.plant.model, "overhead", *self.image_size)
        return self._renderer.render(self.plant.data)

    def detect_tags(self, image: np.ndarray) -> list[Detection]:
        """The arm's tags (ids 0..N) found in `image` (RGB uint8)."""
        if self._detector is None:
            self._detector = TagDetector(tag_ids=arm_tag_ids(self.plant.n_segments))
        return self._detector.detect(np.ascontiguousarray(image[:, :, ::-1]))

    def close(self) -> None:
        """Free the renderer's GL context (rendering again makes a new one)."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
