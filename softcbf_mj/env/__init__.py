"""The MuJoCo ground truth as an RL environment: dm_control (dm_env API) and a Gymnasium adapter.

    from softcbf_mj.env import make_environment, GymArmEnv
    env = make_environment(filter="paper-cbf", filter_params={"tuning": "Low"}, action_repeat=10)  # dm_env
    gym_env = GymArmEnv(filter="none", episode_steps=200)                                      # Gymnasium
    task = gymnasium.make("softcbf_mj/ForceRegulation-v0", filter="e-erg", normalise=True)     # a preset
    envs = gymnasium.make_vec("softcbf_mj/SoftArm-v1", num_envs=32, filter="paper-cbf")      # B arms, one batch plant

The policy's action is the nominal command u_nom (N,) hPa; between the policy and the
plant runs the control step of every scenario (`closedloop.step.ControlStep`: the safety
filter named by `filter` from `controllers.registry`, clipping to the pressure limits,
refusal of non-finite commands, the safety monitor), once per control period. Every step
reports a cost (info["cost"]: control periods above F_max, or the force excess) beside the
reward; the observation is what the controller sees ("estimate") unless ground truth is
asked for ("privileged"). docs/environment.md is the guide.

Modules: `physics` (one physics step = one control period: estimate → control step →
MuJoCo), `task` (actions, observations and their units, reward, termination, seeds),
`environment` (`ArmEnvConfig`, `make_environment`: the clocks and the scene),
`presets` (force regulation, tip reaching), `gym_adapter` (`GymArmEnv`, registered as
"softcbf_mj/SoftArm-v1" and the presets' ids; `SafetyGymnasiumStep`, the 6-tuple),
`vector` (`ArmVectorEnv`: every id's vector entry point, B arms on one `MujocoBatchPlant`).
"""

from softcbf_mj.env.environment import ArmEnvConfig, ArmEnvironment, make_environment
from softcbf_mj.env.gym_adapter import ENV_ID, GymArmEnv, SafetyGymnasiumStep
from softcbf_mj.env.physics import ArmControl, ArmPhysics, NoisyState, StepStats
from softcbf_mj.env.presets import PRESETS, force_regulation, tip_reaching
from softcbf_mj.env.task import COSTS, OBSERVATION_UNITS, OBSERVATIONS, ArmTask, RewardConfig, step_cost
from softcbf_mj.env.vector import ArmVectorEnv

__all__ = ["ArmEnvConfig", "ArmEnvironment", "make_environment", "ENV_ID", "GymArmEnv", "SafetyGymnasiumStep", "ArmPhysics",
           "NoisyState", "StepStats", "PRESETS", "force_regulation", "tip_reaching", "COSTS", "OBSERVATION_UNITS",
           "OBSERVATIONS", "ArmTask", "RewardConfig", "step_cost", "ArmVectorEnv", "ArmControl"]
