"""The arm environment's task: actions, observations, reward, termination and seeds (a `dm_control.rl.control.Task`).

Action: u_nom (N,) float64 hPa in the robot's box [u_min, u_max] (`action_spec`), the
policy's nominal command; the environment's control step filters, clips and monitors it
every control period (`softcbf_mj.env.physics`). With the filter "none" the action is the
command sent, after the same clipping and monitoring.

Observations (`OBSERVATION_UNITS`; float64 unless said otherwise), after the env step's
last control period:

| key          | shape        | unit | what                                                            |
|--------------|--------------|------|-----------------------------------------------------------------|
| q            | (N,)         | rad  | the controller's estimate of the bending angles                 |
| qd           | (N,)         | rad/s| the estimate of their rates                                     |
| tip          | (2,)         | m    | the tip r (x, y), true (the MuJoCo tip sphere's centre)         |
| contact_force| (P,)         | N    | the plate's spring force per facet, measured                    |
| rho_meas     | (1,)         | 1    | ρ_meas = min over facets of the margin from contact_force       |
| u            | (N,)         | hPa  | the command sent in the last control period (0 after reset)     |
| image        | (H, W, 3)    | 0–255| optional (`camera`): the overhead camera, uint8 RGB             |
| tag_corners  | (N+1, 4, 2)  | px   | optional (`tag_detections`): corners of arm tags 0..N (0: unseen)|
| tag_seen     | (N+1,)       | 0/1  | optional (`tag_detections`): uint8, tag i found in the image    |

Reward per env step (`RewardConfig`), from the state at its end and its control periods:

    reward = − tracking_weight · ‖tip − target_tip_m‖  − violation_penalty · (periods with ρ_meas < 0)

(the tracking term only when `target_tip_m` is set). Termination (dm_env: LAST with
discount 0): a period with ρ_meas < 0 when `terminate_on_violation`; a latched vent of
the safety monitor when `terminate_on_vent`. Truncation (LAST with discount 1): after
`episode_steps` env steps.

Seeds: the initial bending angles are q0 ~ N(0, q0_std²) per segment (rad) from the
task's `numpy.random.Generator` (`seed(seed)`); with q0_std = 0 the arm starts straight
and an episode depends on its actions only (MuJoCo and the filters are deterministic).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np
from dm_control.rl import control
from dm_env import specs

from softcbf_mj.env.physics import ArmPhysics

OBSERVATION_UNITS = {
    "q": "rad (the controller's estimate)",
    "qd": "rad/s (the controller's estimate)",
    "tip": "m (true tip x, y)",
    "contact_force": "N (plate spring force per facet, measured)",
    "rho_meas": "1 (min over facets of the margin from contact_force)",
    "u": "hPa (command sent in the last control period)",
    "image": "0-255 (overhead camera, RGB uint8)",
    "tag_corners": "px (arm tags 0..N, corners TL, TR, BR, BL; 0 when unseen)",
    "tag_seen": "0/1 (uint8: arm tag i found in the image)",
}


@dataclass(frozen=True)
class RewardConfig:
    """The reward and termination of the task (module docstring).

    target_tip_m: (x, y) m or None (no tracking term); tracking_weight: reward per m of
    tip distance (1/m, >= 0); violation_penalty: per control period with ρ_meas < 0
    (>= 0); terminate_on_violation, terminate_on_vent: end the episode (discount 0).
    """

    target_tip_m: tuple[float, float] | None = None
    tracking_weight: float = 1.0
    violation_penalty: float = 1.0
    terminate_on_violation: bool = False
    terminate_on_vent: bool = True

    def __post_init__(self) -> None:
        if self.target_tip_m is not None:
            target = tuple(float(v) for v in self.target_tip_m)
            if len(target) != 2 or not all(map(math.isfinite, target)):
                raise ValueError(f"target_tip_m must be a finite (x, y) in m or None, got {self.target_tip_m!r}")
            object.__setattr__(self, "target_tip_m", target)
        for name in ("tracking_weight", "violation_penalty"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0, got {value}")


class ArmTask(control.Task):
    """Actions, observations, reward and termination of the arm (module docstring).

    u_min, u_max: (N,) hPa, the action box; episode_steps: env steps per episode (>= 1);
    q0_std: rad (>= 0); camera, tag_detections: the optional observations; seed: the
    initial generator's seed (None: from the operating system).
    """

    def __init__(self, u_min: np.ndarray, u_max: np.ndarray, n_facets: int, episode_steps: int,
                 reward: RewardConfig = RewardConfig(), q0_std: float = 0.0, camera: bool = False,
                 tag_detections: bool = False, image_size: tuple[int, int] = (320, 180), seed: int | None = None) -> None:
        if isinstance(episode_steps, bool) or not isinstance(episode_steps, (int, np.integer)) or episode_steps < 1:
            raise ValueError(f"episode_steps must be an integer >= 1, got {episode_steps!r}")
        if not (math.isfinite(q0_std) and q0_std >= 0):
            raise ValueError(f"q0_std must be finite and >= 0 rad, got {q0_std}")
        self.u_min, self.u_max = np.array(u_min, dtype=float), np.array(u_max, dtype=float)
        self.n_segments, self.n_facets = len(self.u_min), int(n_facets)
        self.episode_steps, self.reward, self.q0_std = int(episode_steps), reward, float(q0_std)
        self.camera, self.tag_detections, self.image_size = camera, tag_detections, image_size
        self.random = np.random.default_rng(seed)
        self.steps = 0

    def seed(self, seed: int | None) -> None:
        """A new generator for the initial states of the following episodes."""
        self.random = np.random.default_rng(seed)

    # -- dm_control Task --------------------------------------------------------------

    def initialize_episode(self, physics: ArmPhysics) -> None:
        self.steps = 0
        q0 = self.random.normal(0.0, self.q0_std, self.n_segments) if self.q0_std > 0 else np.zeros(self.n_segments)
        physics.reset_state(q0)

    def before_step(self, action: np.ndarray, physics: ArmPhysics) -> None:
        physics.set_control(action)

    def after_step(self, physics: ArmPhysics) -> None:
        self.steps += 1

    def action_spec(self, physics: ArmPhysics) -> specs.BoundedArray:
        return specs.BoundedArray((self.n_segments,), np.float64, self.u_min, self.u_max, name="u_nom [hPa]")

    def observation_spec(self, physics: ArmPhysics) -> OrderedDict[str, specs.Array]:
        n, p = self.n_segments, self.n_facets
        shapes = OrderedDict(q=(n,), qd=(n,), tip=(2,), contact_force=(p,), rho_meas=(1,), u=(n,))
        spec: OrderedDict[str, specs.Array] = OrderedDict(
            (key, specs.Array(shape, np.float64, name=f"{key} [{OBSERVATION_UNITS[key]}]")) for key, shape in shapes.items()
        )
        width, height = self.image_size
        if self.camera:
            spec["image"] = specs.BoundedArray((height, width, 3), np.uint8, 0, 255, name=f"image [{OBSERVATION_UNITS['image']}]")
        if self.tag_detections:
            spec["tag_corners"] = specs.Array((n + 1, 4, 2), np.float64, name=f"tag_corners [{OBSERVATION_UNITS['tag_corners']}]")
            spec["tag_seen"] = specs.BoundedArray((n + 1,), np.uint8, 0, 1, name=f"tag_seen [{OBSERVATION_UNITS['tag_seen']}]")
        return spec

    def get_observation(self, physics: ArmPhysics) -> OrderedDict[str, np.ndarray]:
        estimate, state = physics.estimate(), physics.state
        u = physics.last_record.u if physics.last_record is not None else np.zeros(self.n_segments)
        observation = OrderedDict(
            q=np.array(estimate.q, dtype=float), qd=np.array(estimate.qd, dtype=float), tip=np.array(state.tip, dtype=float),
            contact_force=np.array(state.contact_forces, dtype=float), rho_meas=np.array([physics.rho_meas()]),
            u=np.array(u, dtype=float),
        )
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

    def get_reward(self, physics: ArmPhysics) -> float:
        config, reward = self.reward, 0.0
        if config.target_tip_m is not None:
            reward -= config.tracking_weight * float(np.hypot(*(physics.state.tip - np.array(config.target_tip_m))))
        return reward - config.violation_penalty * physics.stats.violation_periods

    def get_termination(self, physics: ArmPhysics) -> float | None:
        if self.reward.terminate_on_violation and physics.stats.violation_periods > 0:
            return 0.0
        if physics.vent_latched and (self.reward.terminate_on_vent or physics.fault is not None):
            return 0.0  # a filter fault always ends the episode at its vent
        if self.steps >= self.episode_steps:
            return 1.0
        return None
