"""The arm environment's task: actions, observations, reward, termination and seeds (a `dm_control.rl.control.Task`).

Action: u_nom (N,) float64 hPa in the robot's box [u_min, u_max] (`action_spec`), the
policy's nominal command; the environment's control step filters, clips and monitors it
every control period (`softcbf_mj.env.physics`). With the filter "none" the action is the
command sent, after the same clipping and monitoring.

Observations (`OBSERVATION_UNITS`; float64 unless said otherwise), after the env step's
last control period. Two modes (`observation`):

- "estimate" (the default): what the controller under test sees — the estimate it is
  handed (the exact state, or the noisy state of `state_noise_std`; the camera's frame and
  tag detections when asked for), the command sent and the model's predictions;
- "privileged": the same plus the ground truth the controller never sees (the true state,
  the true tip, the plate's force, ρ_meas) — for critics, reward shaping and analysis.

| key          | shape        | unit | mode       | what                                                            |
|--------------|--------------|------|------------|-----------------------------------------------------------------|
| q            | (N,)         | rad  | both       | the controller's estimate of the bending angles                 |
| qd           | (N,)         | rad/s| both       | the estimate of their rates                                     |
| u            | (N,)         | hPa  | both       | the command sent in the last control period (0 after reset)     |
| tip_pred     | (2,)         | m    | both       | the model's tip r(q̂): PCC kinematics of the estimate            |
| rho_pred     | (1,)         | 1    | both       | the model's margin: min over facets of ρ at tip_pred            |
| q_true       | (N,)         | rad  | privileged | the true bending angles (sums of each segment's hinge angles)   |
| qd_true      | (N,)         | rad/s| privileged | their true rates                                                |
| tip          | (2,)         | m    | privileged | the tip r (x, y), true (the MuJoCo tip sphere's centre)         |
| contact_force| (P,)         | N    | privileged | the plate's spring force per facet, measured                    |
| rho_meas     | (1,)         | 1    | privileged | ρ_meas = min over facets of the margin from contact_force       |
| image        | (H, W, 3)    | 0–255| both       | optional (`camera`): the overhead camera, uint8 RGB             |
| tag_corners  | (N+1, 4, 2)  | px   | both       | optional (`tag_detections`): corners of arm tags 0..N (0: unseen)|
| tag_seen     | (N+1,)       | 0/1  | both       | optional (`tag_detections`): uint8, tag i found in the image    |

`ArmTask.scales` gives each float key's scale for the Gymnasium adapter's normalised
option (observation / scale, clipped to [−1, 1]): q π rad, qd `QD_SCALE` rad/s, u the
largest |pressure limit|, tip and tip_pred the arm's length Σ L_i (never clipped: the tip
lies within it), ρ 1 (ρ < −1, a force above 2 F_max, saturates), contact_force 2 F_max;
tag corners by the image's width and height.

Reward per env step (`RewardConfig`), from the state at its end and its control periods:

    reward = − tracking_weight · ‖tip − target_tip_m‖            (when target_tip_m is set; m)
             − force_weight · |F − target_force_N|             (when target_force_N is set; F = max over facets of contact_force, N)
             − violation_penalty · (periods with ρ_meas < 0)

Cost per env step (`cost`, Safety-Gymnasium's convention: the Gymnasium adapter's
info["cost"], ≥ 0, 0 while force-safe), one of `COSTS`:

    "violation"     the fraction of the env step's control periods whose end state has
                    ρ_meas < 0 (a plate force above F_max): 0 or 1 with action_repeat 1;
                    Σ cost · env_dt over an episode is its time in violation (s);
    "force_excess"  the mean over those periods of max_i max(0, F_i − F_max)/F_max
                    (1: how far above the limit, 1 = twice F_max; 0 while F ≤ F_max).

Termination (dm_env: LAST with discount 0): a period with ρ_meas < 0 when
`terminate_on_violation`; a latched vent of the safety monitor when `terminate_on_vent`.
Truncation (LAST with discount 1): after `episode_steps` env steps.

One definition for one arm and for B: observations, reward, cost and termination are
`ArmTask.observations`, `rewards`, `costs` and `ends`, functions of `physics.ArmArrays` (every
array with a leading axis of B arms, numpy over it) that return (B, ...) arrays. The dm_control
methods (`get_observation`, `get_reward`, `get_termination`, `cost`) call them on the single
arm's arrays (B = 1, `ArmControl.arrays()`) and take row 0; the vector environment
(`softcbf_mj.env.vector`) calls them once per env step for all its arms. tip_pred is the PCC
kinematics of `controllers.model.pcc_model` (`kinematics_rows`, the one kernel, a row per arm),
rho_pred the safe set's `margin` at it, rho_meas `softcbf_mj.outputs.metrics.rho_meas`. Each row's
arithmetic is its own (elementwise, or a reduction over that row), so row b of B arms equals
the single arm's, bit for bit (tests/test_env_vector.py). The one product, the facets' n̂_i·r
of `margin`, is taken on a stack of B (1, 2) points ((B, 1, 2) @ (2, P)): numpy runs the same
BLAS call per point whatever B, where one (B, 2) @ (2, P) product takes a kernel that depends on
B and moves rho_pred by a few 1e-15.

Seeds: the initial bending angles are q0 ~ N(0, q0_std²) per segment (rad) from the
task's `numpy.random.Generator` (`seed(seed)`), then the estimator's noise generator is
seeded from it (when the estimator is a `NoisyState`); with q0_std = 0 and no noise the
arm starts straight and an episode depends on its actions only (MuJoCo and the filters
are deterministic).
"""

from __future__ import annotations

import functools
import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from dm_control.rl import control
from dm_env import specs

from controllers.core.lazy_import import lazy_module
from controllers.model.safe_set import ForceSafeSet
from softcbf_mj.env.physics import ArmArrays, ArmControl, BatchStepStats, NoisyState, StepStats
from softcbf_mj.outputs.metrics import rho_meas
from vocabulary.settings import default

pcc_model = lazy_module("controllers.model.pcc_model")  # numba loads on the first observation (controllers.core.lazy_import)

OBSERVATION_UNITS = {
    "q": "rad (the controller's estimate)",
    "qd": "rad/s (the controller's estimate)",
    "u": "hPa (command sent in the last control period)",
    "tip_pred": "m (the model's tip x, y: PCC kinematics of the estimate)",
    "rho_pred": "1 (the model's margin at tip_pred, min over facets)",
    "q_true": "rad (true bending angles, privileged)",
    "qd_true": "rad/s (true rates, privileged)",
    "tip": "m (true tip x, y, privileged)",
    "contact_force": "N (plate spring force per facet, measured, privileged)",
    "rho_meas": "1 (min over facets of the margin from contact_force, privileged)",
    "image": "0-255 (overhead camera, RGB uint8)",
    "tag_corners": "px (arm tags 0..N, corners TL, TR, BR, BL; 0 when unseen)",
    "tag_seen": "0/1 (uint8: arm tag i found in the image)",
}
OBSERVATIONS = ("estimate", "privileged")
ESTIMATE_KEYS = ("q", "qd", "u", "tip_pred", "rho_pred")
PRIVILEGED_KEYS = ("q_true", "qd_true", "tip", "contact_force", "rho_meas")
COSTS = ("violation", "force_excess")
QD_SCALE = 50.0  # rad/s, the normalised option's scale of qd (module docstring)


def step_costs(stats: BatchStepStats, definition: str) -> np.ndarray:
    """The costs (B,) (>= 0) of B arms' env steps with `stats` under `definition` (one of COSTS; module docstring)."""
    if definition == "violation":  # violation_periods <= periods: 0 where periods = 0
        return stats.violation_periods / np.maximum(stats.periods, 1)
    if definition == "force_excess":
        return np.array(stats.force_excess, dtype=float)
    raise ValueError(f"cost must be one of {', '.join(COSTS)}, got {definition!r}")


def step_cost(stats: StepStats, definition: str) -> float:
    """The cost (>= 0) of one env step with `stats` under `definition`: `step_costs` at B = 1."""
    return float(step_costs(BatchStepStats.of([stats]), definition)[0])


def predicted_tips(q: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The model's tips r(q̂) (B, 2) m of B estimates q (B, N) rad, segment lengths (N,) m: the PCC
    kinematics of `controllers.model.pcc_model.kinematics_rows` (the tip needs no rates: q̇ = 0)."""
    q = np.ascontiguousarray(q, dtype=float)
    kin = pcc_model.kinematics_rows(q, np.zeros_like(q), np.ascontiguousarray(lengths, dtype=float))
    tip = np.ascontiguousarray(kin[:, tip_column(q.shape[1])])  # x + i·y per arm
    return tip.view(np.float64).reshape(len(q), 2)


@functools.cache
def tip_column(n_segments: int) -> int:
    """The column of the tip r in `pcc_model`'s `kin` rows of N segments (its `ModelLayout`)."""
    return pcc_model.ModelLayout.of(n_segments).tip_terms.start


@dataclass(frozen=True)
class RewardConfig:
    """The reward and termination of the task (module docstring).

    target_tip_m: (x, y) m or None (no tracking term); tracking_weight: reward per m of
    tip distance (1/m, >= 0); target_force_N: the plate force to regulate (N, >= 0) or
    None (no force term); force_weight: reward per N of force error (1/N, >= 0);
    violation_penalty: per control period with ρ_meas < 0 (>= 0); terminate_on_violation,
    terminate_on_vent: end the episode (discount 0).
    """

    target_tip_m: tuple[float, float] | None = None
    tracking_weight: float = 1.0
    target_force_N: float | None = None
    force_weight: float = 1.0
    violation_penalty: float = 1.0
    terminate_on_violation: bool = False
    terminate_on_vent: bool = True

    def __post_init__(self) -> None:
        if self.target_tip_m is not None:
            target = tuple(float(v) for v in self.target_tip_m)
            if len(target) != 2 or not all(map(math.isfinite, target)):
                raise ValueError(f"target_tip_m must be a finite (x, y) in m or None, got {self.target_tip_m!r}")
            object.__setattr__(self, "target_tip_m", target)
        if self.target_force_N is not None and not (math.isfinite(self.target_force_N) and self.target_force_N >= 0):
            raise ValueError(f"target_force_N must be finite and >= 0 N or None, got {self.target_force_N}")
        for name in ("tracking_weight", "force_weight", "violation_penalty"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


class ArmTask(control.Task):
    """Actions, observations, reward, cost and termination of the arm (module docstring).

    u_min, u_max: (N,) hPa, the action box; episode_steps: env steps per episode (>= 1);
    q0_std: rad (>= 0); observation: one of OBSERVATIONS; cost: one of COSTS; camera,
    tag_detections: the optional observations; seed: the initial generator's seed (None:
    from the operating system). The methods read an `ArmControl` (the single env's
    `ArmPhysics`, or one arm of the vector env); the camera's observations need an
    `ArmPhysics` (its renderer).
    """

    def __init__(self, u_min: np.ndarray, u_max: np.ndarray, n_facets: int, episode_steps: int,
                 reward: RewardConfig = RewardConfig(), q0_std: float = default("q0_std", "environment"),
                 camera: bool = False, tag_detections: bool = False, image_size: tuple[int, int] = (320, 180),
                 seed: int | None = None, observation: str = "estimate", cost: str = "violation") -> None:
        if isinstance(episode_steps, bool) or not isinstance(episode_steps, (int, np.integer)) or episode_steps < 1:
            raise ValueError(f"episode_steps must be an integer >= 1, got {episode_steps!r}")
        if not (math.isfinite(q0_std) and q0_std >= 0):
            raise ValueError(f"q0_std must be finite and >= 0 rad, got {q0_std}")
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {', '.join(OBSERVATIONS)}, got {observation!r}")
        if cost not in COSTS:
            raise ValueError(f"cost must be one of {', '.join(COSTS)}, got {cost!r}")
        self.u_min, self.u_max = np.array(u_min, dtype=float), np.array(u_max, dtype=float)
        self.n_segments, self.n_facets = len(self.u_min), int(n_facets)
        self.episode_steps, self.reward, self.q0_std = int(episode_steps), reward, float(q0_std)
        self.camera, self.tag_detections, self.image_size = camera, tag_detections, image_size
        self.observation, self.cost_definition = observation, cost
        self.random = np.random.default_rng(seed)
        self.steps = 0

    def seed(self, seed: int | None) -> None:
        """A new generator for the initial states (and the estimate's noise) of the following episodes."""
        self.random = np.random.default_rng(seed)

    def keys(self) -> tuple[str, ...]:
        """The float observation keys of this mode, in order (module docstring)."""
        return ESTIMATE_KEYS + (PRIVILEGED_KEYS if self.observation == "privileged" else ())

    def scales(self, lengths: np.ndarray, f_max: float) -> dict[str, np.ndarray]:
        """Each observation key's scale for the normalised option (module docstring), broadcast to its shape."""
        u = float(np.max(np.maximum(np.abs(self.u_min), np.abs(self.u_max))))
        reach = float(np.sum(lengths))
        scale = {"q": math.pi, "qd": QD_SCALE, "u": u, "tip_pred": reach, "rho_pred": 1.0, "q_true": math.pi,
                 "qd_true": QD_SCALE, "tip": reach, "contact_force": 2.0 * f_max, "rho_meas": 1.0}
        width, height = self.image_size
        shapes = self.shapes()
        out = {key: np.full(shapes[key], scale[key]) for key in self.keys()}
        if self.tag_detections:
            out["tag_corners"] = np.broadcast_to(np.array([float(width), float(height)]), shapes["tag_corners"]).copy()
        return out

    def shapes(self) -> dict[str, tuple[int, ...]]:
        n, p = self.n_segments, self.n_facets
        return {"q": (n,), "qd": (n,), "u": (n,), "tip_pred": (2,), "rho_pred": (1,), "q_true": (n,), "qd_true": (n,),
                "tip": (2,), "contact_force": (p,), "rho_meas": (1,), "tag_corners": (n + 1, 4, 2), "tag_seen": (n + 1,)}

    # -- B arms at once (module docstring) -----------------------------------------------

    def observations(self, arms: ArmArrays, safe_set: ForceSafeSet, lengths: np.ndarray) -> OrderedDict[str, np.ndarray]:
        """The float observations of this mode (`keys`) of B arms: each key (B, *shape), fresh arrays;
        `safe_set`: the filter's (ρ_pred, ρ_meas); lengths (N,) m: the model's segments (tip_pred)."""
        tip_pred = predicted_tips(arms.q, lengths)
        observation = OrderedDict(q=np.array(arms.q, dtype=float), qd=np.array(arms.qd, dtype=float),
                                  u=np.array(arms.u, dtype=float), tip_pred=tip_pred,
                                  rho_pred=np.asarray(safe_set.margin(tip_pred[:, None, :]), dtype=float))
        if self.observation == "privileged":
            observation.update(q_true=np.array(arms.q_true, dtype=float), qd_true=np.array(arms.qd_true, dtype=float),
                               tip=np.array(arms.tip, dtype=float), contact_force=np.array(arms.contact_forces, dtype=float),
                               rho_meas=np.asarray(rho_meas(safe_set, arms.contact_forces), dtype=float)[:, None])
        return observation

    def rewards(self, arms: ArmArrays) -> np.ndarray:
        """The rewards (B,) of B arms' env steps (module docstring: from the state at their end)."""
        config = self.reward
        reward = np.zeros(len(arms.t))
        if config.target_tip_m is not None:
            target_x, target_y = config.target_tip_m
            reward -= config.tracking_weight * np.hypot(arms.tip[:, 0] - target_x, arms.tip[:, 1] - target_y)
        if config.target_force_N is not None:
            force = np.max(arms.contact_forces, axis=1, initial=0.0)
            reward -= config.force_weight * np.abs(force - config.target_force_N)
        return reward - config.violation_penalty * arms.stats.violation_periods

    def costs(self, arms: ArmArrays) -> np.ndarray:
        """The costs (B,) of B arms' env steps (`step_costs` of this task's definition)."""
        return step_costs(arms.stats, self.cost_definition)

    def ends(self, arms: ArmArrays, steps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(terminated, truncated), each (B,) bool, of B arms after `steps` (B,) env steps of their episodes
        (module docstring: dm_env's discount 0 and 1). A filter fault always ends the episode at its vent."""
        terminated = arms.vent_latched & (self.reward.terminate_on_vent | arms.faulted)
        if self.reward.terminate_on_violation:
            terminated = terminated | (arms.stats.violation_periods > 0)
        return terminated, ~terminated & (np.asarray(steps) >= self.episode_steps)

    def cost(self, physics: ArmControl) -> float:
        """The last env step's cost (`costs` at B = 1)."""
        return float(self.costs(physics.arrays())[0])

    # -- dm_control Task --------------------------------------------------------------

    def initialize_episode(self, physics: ArmControl) -> None:
        self.steps = 0
        q0 = self.random.normal(0.0, self.q0_std, self.n_segments) if self.q0_std > 0 else np.zeros(self.n_segments)
        if isinstance(physics.estimator, NoisyState):
            physics.estimator.reseed(int(self.random.integers(2**63)))
        physics.reset_state(q0)

    def before_step(self, action: np.ndarray, physics: ArmControl) -> None:
        physics.set_control(action)

    def after_step(self, physics: ArmControl) -> None:
        self.steps += 1

    def action_spec(self, physics: ArmControl) -> specs.BoundedArray:
        return specs.BoundedArray((self.n_segments,), np.float64, self.u_min, self.u_max, name="u_nom [hPa]")

    def observation_spec(self, physics: ArmControl) -> OrderedDict[str, specs.Array]:
        shapes = self.shapes()
        spec: OrderedDict[str, specs.Array] = OrderedDict(
            (key, specs.Array(shapes[key], np.float64, name=f"{key} [{OBSERVATION_UNITS[key]}]")) for key in self.keys()
        )
        width, height = self.image_size
        if self.camera:
            spec["image"] = specs.BoundedArray((height, width, 3), np.uint8, 0, 255, name=f"image [{OBSERVATION_UNITS['image']}]")
        if self.tag_detections:
            spec["tag_corners"] = specs.Array(shapes["tag_corners"], np.float64, name=f"tag_corners [{OBSERVATION_UNITS['tag_corners']}]")
            spec["tag_seen"] = specs.BoundedArray(shapes["tag_seen"], np.uint8, 0, 1, name=f"tag_seen [{OBSERVATION_UNITS['tag_seen']}]")
        return spec

    def get_observation(self, physics: ArmControl) -> OrderedDict[str, np.ndarray]:
        batch = self.observations(physics.arrays(), physics.safe_set, physics.lengths)
        observation = OrderedDict((key, value[0]) for key, value in batch.items())
        if self.camera or self.tag_detections:
            image = physics.render_image()
            if self.camera:
                observation["image"] = image
            if self.tag_detections:
                corners, seen = np.zeros((self.n_segments + 1, 4, 2)), np.zeros(self.n_segments + 1, dtype=np.uint8)
                for detection in physics.detect_tags(image):
                    corners[detection.tag_id], seen[detection.tag_id] = detection.corners, 1
                observation["tag_corners"], observation["tag_seen"] = corners, seen
        return observation

    def get_reward(self, physics: ArmControl) -> float:
        return float(self.rewards(physics.arrays())[0])

    def get_termination(self, physics: ArmControl) -> float | None:
        terminated, truncated = self.ends(physics.arrays(), np.array([self.steps]))
        return 0.0 if terminated[0] else 1.0 if truncated[0] else None
