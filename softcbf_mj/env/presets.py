"""Task presets of the arm environment: force regulation and tip reaching, each an `ArmEnvConfig`.

Both run the scene and the control step of `softcbf_mj.env.environment` with the filter
at the paper's 1 kHz (control_dt = 1e-3 s) and the policy at 10 Hz, the hardware loop's
rate (action_repeat = 100: one env step = 0.1 s), for EPISODE_STEPS = 100 env steps
(10 s), with the cost "violation" (`softcbf_mj.env.task`) and no reward penalty for
violations (violation_penalty = 0: the constraint is the cost's, as in safe RL):

| preset             | Gymnasium id                     | reward per env step (at its end)                         |
|--------------------|----------------------------------|----------------------------------------------------------|
| `force_regulation` | softcbf_mj/ForceRegulation-v0    | −|F − F_target| (N): F the largest plate force, F_target = FORCE_TARGET_FRACTION · F_max = 0.128 N |
| `tip_reaching`     | softcbf_mj/TipReaching-v0        | −‖tip − TIP_TARGET_M‖ (m): the true tip; the target lies in free space |

F_target = 0.8 F_max asks for contact within the force budget (pressing up to F_max is allowed): the unfiltered
+150 hPa push goes past F_max, so a policy that learns to push hard earns cost. Each
preset takes keyword changes of any `ArmEnvConfig` field (`force_regulation(filter="e-erg",
episode_steps=20)`); `PRESETS` maps the registered ids to them and `EPISODE_STEPS` is
also each id's `max_episode_steps` (give both `episode_steps=` and `max_episode_steps=` to
`gymnasium.make` to change an episode's length).
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any, Callable

from controllers.model.safe_set import paper_safe_set
from softcbf_mj.env.environment import ArmEnvConfig
from softcbf_mj.env.task import RewardConfig

EPISODE_STEPS = 100  # env steps of 0.1 s: 10 s
ACTION_REPEAT = 100  # control periods of 1 ms per env step (the policy at 10 Hz)
FORCE_TARGET_FRACTION = 0.8  # of F_max
TIP_TARGET_M = (0.22, 0.05)  # m, inside the free space of the paper's facet (0.36 x + y <= 0.15)


def force_regulation(**changes: Any) -> ArmEnvConfig:
    """Regulate the plate force to FORCE_TARGET_FRACTION · F_max (module docstring)."""
    target = FORCE_TARGET_FRACTION * changes.get("safe_set", paper_safe_set()).f_max
    reward = RewardConfig(target_force_N=target, force_weight=1.0, violation_penalty=0.0)
    return replace(ArmEnvConfig(action_repeat=ACTION_REPEAT, episode_steps=EPISODE_STEPS, reward=reward), **changes)


def tip_reaching(**changes: Any) -> ArmEnvConfig:
    """Bring the true tip to TIP_TARGET_M (module docstring)."""
    reward = RewardConfig(target_tip_m=TIP_TARGET_M, tracking_weight=1.0, violation_penalty=0.0)
    return replace(ArmEnvConfig(action_repeat=ACTION_REPEAT, episode_steps=EPISODE_STEPS, reward=reward), **changes)


PRESETS: dict[str, Callable[..., ArmEnvConfig]] = {
    "softcbf_mj/ForceRegulation-v0": force_regulation, "softcbf_mj/TipReaching-v0": tip_reaching,
}
