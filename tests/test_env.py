"""softcbf_mj.env: dm_env's conformance test, Gymnasium's checker, the clocks, the shared control step, reward, seeds, camera."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings

import dm_env
import gymnasium
import numpy as np
import pytest
from absl.testing import absltest
from dm_env import specs, test_utils
from gymnasium.utils.env_checker import check_env

from closedloop.step import ControlStep
from controllers.registry import FILTERS, build_filter
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.env import (
    ENV_ID, OBSERVATION_UNITS, OBSERVATIONS, PRESETS, ArmEnvConfig, GymArmEnv, RewardConfig, SafetyGymnasiumStep,
    force_regulation, make_environment, tip_reaching,
)
from controllers.model.pcc import tip_position
from softcbf_mj.env.gym_adapter import box
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.camera.render import camera_matrix, camera_pose_cv, project, tag_poses, tag_plane_z

FAST = {"control_rate": 100.0, "physics_dt": 2e-4, "links_per_segment": 5}  # a coarse, quick arm for the API tests
F_MAX = paper_safe_set().f_max


class PassThroughConformance(test_utils.EnvironmentTestMixin, absltest.TestCase):
    """dm_env's own conformance test, no filter; episodes of 5 env steps (LAST reached)."""

    def make_object_under_test(self):
        return make_environment(episode_steps=5, action_repeat=2, **FAST)

    def make_action_sequence(self):
        for _ in range(12):
            yield self.make_action()


class PaperFilterConformance(PassThroughConformance):
    """The same with the paper's CBF between policy and plant, and a random initial shape."""

    def make_object_under_test(self):
        return make_environment(episode_steps=5, filter="paper-cbf", filter_params={"tuning": "Low"}, q0_std=0.05, seed=1,
                                **FAST)


ADVISORY = ("we recommend using a symmetric and normalized space",  # u_nom in hPa (normalise=True: [-1, 1])
            "observation space minimum value is -infinity", "observation space maximum value is infinity")  # q, tip, ...
GYM_IDS = [ENV_ID, *PRESETS]


@pytest.mark.parametrize("env_id", GYM_IDS)
@pytest.mark.parametrize("observation", OBSERVATIONS)
def test_gymnasium_env_checker_passes_without_a_warning_when_normalised(env_id, observation):
    """check_env, its render check included (the registered id gives it a spec), on every registered id and mode."""
    env = gymnasium.make(env_id, episode_steps=5, action_repeat=2, image_size=(64, 36), normalise=True,
                         observation=observation, **FAST)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    env.close()
    assert [str(w.message) for w in caught] == []


def test_gymnasium_env_checker_in_physical_units_gives_only_the_advice_on_boxes():
    env = gymnasium.make(ENV_ID, episode_steps=5, image_size=(64, 36), **FAST)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    env.close()
    assert [str(w.message) for w in caught if not any(text in str(w.message) for text in ADVISORY)] == []


def test_the_changed_behaviour_has_a_new_id_and_the_old_one_is_gone():
    """Gymnasium's convention: changed behaviour gets a new version; only the current one is registered."""
    assert ENV_ID == "softcbf_mj/SoftArm-v1" and gymnasium.spec(ENV_ID).id == ENV_ID
    with pytest.raises(gymnasium.error.Error):
        gymnasium.spec("softcbf_mj/SoftArm-v0")


def test_registered_specs_carry_the_episode_length():
    assert gymnasium.spec(ENV_ID).max_episode_steps == ArmEnvConfig().episode_steps == 1000
    for env_id, preset in PRESETS.items():
        assert gymnasium.spec(env_id).max_episode_steps == preset().episode_steps == 100
        assert preset().env_dt == pytest.approx(0.1)  # the policy at 10 Hz, the filter at 1 kHz
    env = gymnasium.make("softcbf_mj/ForceRegulation-v0", **FAST)
    assert env.spec.max_episode_steps == 100 and env.unwrapped.config.reward.target_force_N == pytest.approx(0.8 * F_MAX)
    env.close()


def test_specs_name_their_units_and_match_the_box():
    env = make_environment(**FAST)
    action = env.action_spec()
    assert action.name == "u_nom [hPa]" and action.shape == (2,)
    np.testing.assert_array_equal(action.minimum, [-150.0, -150.0])
    np.testing.assert_array_equal(action.maximum, [150.0, 150.0])
    spec = env.observation_spec()
    assert list(spec) == ["q", "qd", "u", "tip_pred", "rho_pred"]  # "estimate": no ground truth
    privileged = make_environment(observation="privileged", **FAST)
    assert list(privileged.observation_spec()) == ["q", "qd", "u", "tip_pred", "rho_pred", "q_true", "qd_true", "tip",
                                                   "contact_force", "rho_meas"]
    for key, array in privileged.observation_spec().items():
        assert array.name == f"{key} [{OBSERVATION_UNITS[key]}]"
    assert privileged.reset().observation["tip"] == pytest.approx([0.244, 0.0])  # the straight arm: L1 + L2 along x
    assert env.reset().observation["tip_pred"] == pytest.approx([0.244, 0.0])


@pytest.mark.parametrize("control_rate, action_repeat", [(100.0, 1), (100.0, 3), (500.0, 5)])
def test_clocks_one_env_step_is_action_repeat_control_periods(control_rate, action_repeat):
    env = make_environment(control_rate=control_rate, action_repeat=action_repeat, physics_dt=2e-4, links_per_segment=5)
    control_dt = 1.0 / control_rate
    assert env.control_timestep() == pytest.approx(control_dt * action_repeat, rel=1e-12)
    env.reset()
    for k in range(1, 4):
        env.step(np.array([50.0, -50.0]))
        assert env.physics.stats.periods == action_repeat
        assert env.physics.time() == pytest.approx(k * action_repeat * control_dt, rel=1e-9)
        assert env.physics.plant.data.time == pytest.approx(k * action_repeat * control_dt, rel=1e-9)


@pytest.mark.parametrize("changes, message", [
    ({"control_rate": 1e4 / 1.5}, "integer multiple of the physics step"),
    ({"control_rate": 0.0}, "control_rate must be > 0 Hz, got 0.0"),
    ({"action_repeat": 0}, "action_repeat must be an integer >= 1, got 0"),
    ({"action_repeat": 2.0}, "action_repeat must be an integer >= 1, got 2.0"),
    ({"episode_steps": 0}, "episode_steps must be an integer >= 1, got 0"),
    ({"plate_stiffness": -1.0}, "plate_stiffness must be > 0 N/m, got -1.0"),
    ({"image_size": (2000, 100)}, "image_size must be (W, H) integers in [8, 1280]"),
    ({"observation": "truth"}, "observation must be one of estimate, privileged, got 'truth'"),
    ({"cost": "force"}, "cost must be one of violation, force_excess, got 'force'"),
    ({"state_noise_std": (0.01, -1.0)}, "state_noise_std must be (q_std rad, qd_std rad/s), finite and >= 0, got (0.01, -1.0)"),
])
def test_invalid_configurations_are_refused(changes, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        ArmEnvConfig(**changes)


def test_reward_config_refuses_bad_values():
    with pytest.raises(ValueError, match="target_tip_m must be a finite"):
        RewardConfig(target_tip_m=(0.1, math.nan))
    with pytest.raises(ValueError, match="violation_penalty must be finite and >= 0, got -1"):
        RewardConfig(violation_penalty=-1.0)
    with pytest.raises(ValueError, match="target_force_N must be finite and >= 0 N or None, got -0.1"):
        RewardConfig(target_force_N=-0.1)
    with pytest.raises(ValueError, match="normalise must be True or False, got 1"):
        GymArmEnv(normalise=1, **FAST)


class ConstantNominal:
    def __init__(self, u):
        self.u = np.array(u, dtype=float)

    def __call__(self, t, q, qd):
        return self.u


def test_env_runs_exactly_the_scenarios_control_step():
    """A held action through the env equals run_closed_loop with a constant nominal: the same q, u and filter output."""
    u_nom, n_steps = [150.0, 150.0], 60
    config = ArmEnvConfig(filter="paper-cbf", filter_params={"tuning": "Low"}, episode_steps=n_steps, **FAST)
    env = make_environment(config)
    env.reset()
    q, u, rho = [], [], []
    for _ in range(n_steps):
        time_step = env.step(np.array(u_nom))
        q.append(time_step.observation["q"])
        u.append(time_step.observation["u"])
        rho.append(env.physics.last_record.output.rho_pred)
    assert time_step.last()
    context = config.context()
    step = ControlStep(build_filter("paper-cbf", {"tuning": "Low"}, context), ConstantNominal(u_nom), context)
    series, _ = run_closed_loop(config.plant(), step, config.safe_set, n_steps * config.control_dt, np.zeros(2))
    np.testing.assert_array_equal(np.array(u), series["u"])
    np.testing.assert_array_equal(np.array(q)[:-1], series["q"][1:])  # the loop records the state at the period's start
    np.testing.assert_array_equal(np.array(rho), series["rho_pred"])


def test_every_episode_starts_afresh():
    """The filter is built once and reset per episode, the monitor is new: the same actions give the same episode."""
    env = make_environment(filter="paper-cbf", filter_params={"tuning": "Low"}, episode_steps=40, hold_s=0.02, **FAST)
    actions = np.random.default_rng(0).uniform(-150.0, 150.0, (40, 2))
    actions[5] = math.nan  # a refused command: HOLD
    episodes = []
    for _ in range(2):
        env.reset()
        episodes.append([(env.step(a).observation["q"], env.physics.last_record.u) for a in actions])
    for (q1, u1), (q2, u2) in zip(*episodes):
        np.testing.assert_array_equal(q1, q2)
        np.testing.assert_array_equal(u1, u2)


def test_the_filter_changes_what_the_plant_gets_and_the_unfiltered_push_violates():
    """u_nom = +150 hPa into the plate: unfiltered, ρ_meas < 0 within 1 s; the paper's filter sends less pressure."""
    results = {}
    for spec, params in (("none", {}), ("paper-cbf", {"tuning": "Low"})):
        env = make_environment(filter=spec, filter_params=params, episode_steps=100, **FAST)
        env.reset()
        violations, force, sent = 0, 0.0, []
        for _ in range(100):
            env.step(np.array([150.0, 150.0]))
            violations += env.physics.stats.violation_periods
            force = max(force, env.physics.stats.force_max_N)
            sent.append(env.physics.last_record.u)
        results[spec] = violations, force, np.array(sent)
    violations, force, sent = results["none"]
    assert violations > 0 and force > F_MAX
    np.testing.assert_array_equal(sent, 150.0)  # no filter: the action is the command
    filtered_violations, filtered_force, filtered_sent = results["paper-cbf"]
    assert filtered_force < force and filtered_violations < violations
    assert np.all(filtered_sent <= 150.0) and np.any(filtered_sent < 150.0)


PUSH_THEN_RANDOM = np.vstack((np.full((50, 2), 150.0), np.random.default_rng(0).uniform(-150.0, 150.0, (50, 2))))


def violations_and_force(spec: str, params: dict) -> tuple[int, float]:
    """Control periods with ρ_meas < 0 and the largest plate force (N) of PUSH_THEN_RANDOM (1 s) through `spec`."""
    env = make_environment(filter=spec, filter_params=params, episode_steps=len(PUSH_THEN_RANDOM), **FAST)
    env.reset()
    violations, force = 0, 0.0
    for action in PUSH_THEN_RANDOM:
        env.step(action)
        violations += env.physics.stats.violation_periods
        force = max(force, env.physics.stats.force_max_N)
    return violations, force


@pytest.mark.skipif("e-erg" not in FILTERS, reason="this checkout's registry has no energy governor (e-erg)")
@pytest.mark.parametrize("params", [{}, {"contact_aware": "true"}])
def test_energy_governor_removes_the_violations_of_the_unfiltered_policy(params):
    unfiltered = violations_and_force("none", {})
    assert unfiltered[0] > 0 and unfiltered[1] > F_MAX
    violations, force = violations_and_force("e-erg", params)
    assert violations == 0 and force <= F_MAX


def test_non_finite_action_holds_then_vents_and_terminates():
    env = GymArmEnv(hold_s=0.05, **FAST)
    env.reset(seed=0)
    env.step(np.array([40.0, 40.0]))
    _, _, terminated, _, info = env.step(np.array([math.nan, 40.0]))
    assert info["monitor_action"] == "hold" and not terminated
    np.testing.assert_array_equal(env.physics.last_record.u, [40.0, 40.0])  # the last command sent with RUN
    held = 1
    while not terminated and held < 10:
        observation, _, terminated, truncated, info = env.step(np.array([math.nan, 40.0]))
        held += 1
    assert held in (6, 7)  # VENT once the hold has lasted hold_s = 5 control periods (± one for the float clock)
    assert terminated and not truncated and info["monitor_action"] == "vent" and info["vented"]
    np.testing.assert_array_equal(observation["u"], [0.0, 0.0])
    with pytest.raises(RuntimeError, match="call reset"):
        env.step(np.zeros(2))


def test_reward_tracking_and_violation_terms():
    target = (0.2, 0.05)
    reward_config = RewardConfig(target_tip_m=target, tracking_weight=3.0, violation_penalty=0.5)
    env = GymArmEnv(reward=reward_config, action_repeat=4, observation="privileged", **FAST)
    env.reset(seed=0)
    for _ in range(25):
        observation, reward, _, _, info = env.step(np.array([150.0, 150.0]))
        distance = math.hypot(observation["tip"][0] - target[0], observation["tip"][1] - target[1])
        assert reward == pytest.approx(-3.0 * distance - 0.5 * info["violation_periods"], abs=1e-12)
    assert info["violation_periods"] > 0  # the penalty term was exercised


def test_terminate_on_violation_ends_the_episode_at_the_first_violation():
    env = GymArmEnv(reward=RewardConfig(terminate_on_violation=True), episode_steps=500, observation="privileged", **FAST)
    env.reset(seed=0)
    steps = 0
    while True:
        observation, _, terminated, truncated, info = env.step(np.array([150.0, 150.0]))
        steps += 1
        if terminated or truncated:
            break
    assert terminated and not truncated and info["violation_periods"] == 1 and observation["rho_meas"][0] < 0
    assert steps < 500


def test_truncation_after_episode_steps():
    env = GymArmEnv(episode_steps=3, **FAST)
    env.reset(seed=0)
    flags = [env.step(np.zeros(2))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_seeds_draw_the_initial_shape():
    env = GymArmEnv(q0_std=0.1, **FAST)
    first, _ = env.reset(seed=3)
    again, _ = env.reset(seed=3)
    other, _ = env.reset(seed=4)
    np.testing.assert_allclose(first["q"], np.random.default_rng(3).normal(0.0, 0.1, 2), atol=1e-9)
    np.testing.assert_array_equal(first["q"], again["q"])
    assert not np.allclose(first["q"], other["q"])
    straight, _ = GymArmEnv(**FAST).reset(seed=3)
    np.testing.assert_array_equal(straight["q"], [0.0, 0.0])


def test_camera_and_tag_detections():
    """The camera observation is the rendered frame; the detected tags lie where the camera projects them (< 1 px)."""
    width, height = 640, 360
    env = GymArmEnv(camera=True, tag_detections=True, image_size=(width, height), render_mode="rgb_array", **FAST)
    try:
        observation, _ = env.reset(seed=0)
        observation, *_ = env.step(np.array([60.0, -30.0]))
        image = observation["image"]
        assert image.shape == (height, width, 3) and image.dtype == np.uint8 and image.std() > 10
        np.testing.assert_array_equal(env.render(), image)
        assert env.observation_space.contains(observation)
        np.testing.assert_array_equal(observation["tag_seen"], [1, 1, 1])
        model, data = env.physics.plant.model, env.physics.plant.data
        R, position = camera_pose_cv(model, data)
        z = tag_plane_z(model, data)
        centres = np.array([[pose.x, pose.y, z] for tag, pose in tag_poses(model, data).items() if tag <= 2])
        projected = project(camera_matrix(model, width=width, height=height), R, position, centres)
        detected = observation["tag_corners"].mean(axis=1)
        assert np.max(np.abs(detected - projected)) < 1.0
    finally:
        env.close()


def test_dm_env_time_step_types_and_discounts():
    env = make_environment(episode_steps=2, **FAST)
    steps = [env.reset()] + [env.step(np.zeros(2)) for _ in range(3)]
    assert [s.step_type for s in steps] == [dm_env.StepType.FIRST, dm_env.StepType.MID, dm_env.StepType.LAST,
                                            dm_env.StepType.FIRST]
    assert steps[2].discount == 1.0  # truncation, not termination


def test_gym_spaces_follow_the_dm_env_specs():
    env = GymArmEnv(camera=True, tag_detections=True, image_size=(32, 18), **FAST)
    assert env.action_space.dtype == np.float64
    np.testing.assert_array_equal(env.action_space.low, [-150.0, -150.0])
    np.testing.assert_array_equal(env.action_space.high, [150.0, 150.0])
    image = env.observation_space["image"]
    assert image.shape == (18, 32, 3) and image.dtype == np.uint8 and image.low.min() == 0 and image.high.max() == 255
    assert env.observation_space["tag_corners"].shape == (3, 4, 2) and env.observation_space["tag_seen"].high.max() == 1
    assert np.all(np.isinf(env.observation_space["q"].low))
    assert env.metadata["render_fps"] == pytest.approx(100.0)  # one env step = 10 ms
    with pytest.raises(ValueError, match="an unbounded spec must be of a float dtype"):
        box(specs.Array((2,), np.int32, name="count"))
    env.close()


def push_episode(steps: int, **changes) -> list[tuple[dict, float, dict]]:
    """(observation, reward, info) of `steps` env steps of u_nom = +150 hPa into the plate (privileged observations)."""
    env = GymArmEnv(observation="privileged", episode_steps=steps, **{**FAST, **changes})
    env.reset(seed=0)
    out = []
    for _ in range(steps):
        observation, reward, _, _, info = env.step(np.array([150.0, 150.0]))
        out.append((observation, reward, info))
    env.close()
    return out


def test_cost_violation_is_the_fraction_of_periods_above_f_max_and_sums_to_the_time_in_violation():
    """action_repeat 4: cost = violation_periods / 4 per env step; Σ cost · env_dt = the periods above F_max · control_dt;
    with action_repeat 1 the cost is the 0/1 indicator of F > F_max at the step's end (the force observed)."""
    steps = push_episode(40, action_repeat=4)
    costs = np.array([info["cost"] for _, _, info in steps])
    assert np.all(costs == np.array([info["violation_periods"] / 4 for _, _, info in steps]))
    assert costs.sum() > 0 and np.all((costs >= 0) & (costs <= 1))
    env_dt = 4 * (1.0 / FAST["control_rate"])
    assert costs.sum() * env_dt == pytest.approx(sum(info["violation_periods"] for _, _, info in steps) * (1.0 / FAST["control_rate"]))
    for observation, _, info in push_episode(60):
        assert info["cost"] == float(observation["contact_force"][0] > F_MAX)
        assert info["cost"] == float(observation["rho_meas"][0] < 0)


def test_cost_force_excess_is_the_relative_force_above_f_max():
    steps = push_episode(60, cost="force_excess")
    excess = [max(0.0, observation["contact_force"][0] - F_MAX) / F_MAX for observation, _, _ in steps]
    np.testing.assert_allclose([info["cost"] for _, _, info in steps], excess, rtol=1e-12, atol=0)
    assert max(excess) > 0.1


def test_safety_gymnasium_six_tuple_carries_the_cost():
    env = SafetyGymnasiumStep(GymArmEnv(episode_steps=60, **FAST))
    env.reset(seed=0)
    costs = []
    for _ in range(60):
        result = env.step(np.array([150.0, 150.0]))
        assert len(result) == 6
        observation, reward, cost, terminated, truncated, info = result
        assert isinstance(cost, float) and cost == info["cost"] and observation.keys() == env.observation_space.keys()
        costs.append(cost)
    assert sum(costs) > 0 and truncated and not terminated


def test_a_safe_step_costs_nothing():
    env = GymArmEnv(episode_steps=5, cost="force_excess", **FAST)
    _, info = env.reset(seed=0)
    assert info["cost"] == 0.0
    assert env.step(np.zeros(2))[4]["cost"] == 0.0


class RecordingFilter:
    """A pass-through plug-in that keeps every estimate it is handed (q, qd)."""

    def __init__(self):
        self.seen = []

    def __call__(self, estimate, u_nom):
        self.seen.append((np.array(estimate.q), np.array(estimate.qd)))
        return u_nom


def test_estimate_observation_is_what_the_filter_sees_and_privileged_adds_the_truth():
    """With state noise (0.01 rad, 0.5 rad/s): the observed q, qd are the estimate the filter gets next, not the truth;
    the noise has the configured spread; tip_pred and rho_pred are the model's (PCC) of that estimate."""
    env = GymArmEnv(observation="privileged", state_noise_std=(0.01, 0.5), episode_steps=200, **FAST)
    recorder = RecordingFilter()
    env.physics.filter = recorder
    env.physics.control_step.filter = recorder
    observation, _ = env.reset(seed=5)
    errors_q, errors_qd = [], []
    lengths = env.config.robot.array("lengths")
    safe_set = env.config.safe_set
    for k in range(200):
        before = len(recorder.seen)
        next_observation, *_ = env.step(np.array([60.0, 30.0]))
        q_seen, qd_seen = recorder.seen[before]
        np.testing.assert_array_equal(q_seen, observation["q"])
        np.testing.assert_array_equal(qd_seen, observation["qd"])
        np.testing.assert_allclose(observation["tip_pred"], tip_position(observation["q"], lengths), atol=1e-15)
        assert observation["rho_pred"][0] == pytest.approx(float(safe_set.margin(observation["tip_pred"])), abs=1e-12)
        errors_q.append(observation["q"] - observation["q_true"])
        errors_qd.append(observation["qd"] - observation["qd_true"])
        observation = next_observation
    assert np.std(errors_q) == pytest.approx(0.01, rel=0.15) and np.std(errors_qd) == pytest.approx(0.5, rel=0.15)
    again = GymArmEnv(observation="privileged", state_noise_std=(0.01, 0.5), **FAST)
    first, _ = again.reset(seed=5)
    np.testing.assert_array_equal(first["q"], env.reset(seed=5)[0]["q"])  # the noise is seeded by reset(seed=...)


def test_force_regulation_and_tip_reaching_rewards():
    target = 0.8 * F_MAX
    env = GymArmEnv(force_regulation(observation="privileged", action_repeat=5, episode_steps=30, **FAST))
    env.reset(seed=0)
    rewards = []
    for _ in range(30):
        observation, reward, _, _, info = env.step(np.array([150.0, 150.0]))
        assert reward == pytest.approx(-abs(observation["contact_force"][0] - target), abs=1e-12)
        rewards.append(reward)
    assert max(rewards) > -target  # it touched the plate
    env = GymArmEnv(tip_reaching(observation="privileged", action_repeat=5, episode_steps=10, **FAST))
    env.reset(seed=0)
    for _ in range(10):
        observation, reward, *_ = env.step(np.array([40.0, 20.0]))
        assert reward == pytest.approx(-math.hypot(*(observation["tip"] - np.array((0.22, 0.05)))), abs=1e-12)


def test_normalised_action_maps_onto_the_pressure_box_and_clipping_is_reported():
    env = GymArmEnv(normalise=True, observation="privileged", episode_steps=100, **FAST)
    env.reset(seed=0)
    for action, u in (([-1.0, 1.0], [-150.0, 150.0]), ([0.0, 0.5], [0.0, 75.0])):
        observation, *_, info = env.step(np.array(action))
        np.testing.assert_allclose(env.physics.last_record.u, u, atol=1e-12)
        np.testing.assert_allclose(observation["u"], np.array(u) / 150.0, atol=1e-12)
    clipped = set()
    for _ in range(98):
        observation, *_, info = env.step(np.ones(2))
        assert all(np.all(np.abs(v) <= 1.0) for k, v in observation.items())
        assert env.observation_space.contains(observation)
        clipped.update(info["clipped"])
        if "contact_force" in info["clipped"]:
            assert observation["contact_force"][0] == 1.0 and info["force_max_N"] >= 2 * F_MAX
    assert {"contact_force", "rho_meas"} <= clipped  # the unfiltered push goes past 2 F_max, and says so
    assert "tip" not in clipped and "q" not in clipped


def test_render_without_a_backend_names_the_fix():
    """MUJOCO_GL=glfw without a display (MuJoCo's choice when MUJOCO_GL is unset and no OSMesa is found): one clear
    error naming MUJOCO_GL=osmesa and MUJOCO_GL=egl (in a subprocess: PyOpenGL binds one platform per process)."""
    code = ("from softcbf_mj.env import GymArmEnv\nfrom softcbf_mj.camera.render import RenderBackendError\n"
            "env = GymArmEnv(render_mode='rgb_array', control_rate=100.0, physics_dt=2e-4, links_per_segment=5)\n"
            "env.reset(seed=0)\ntry:\n    env.render()\nexcept RenderBackendError as error:\n    print(error)\n")
    environ = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                            env={**environ, "MUJOCO_GL": "glfw"})
    assert result.returncode == 0, result.stderr
    assert "MUJOCO_GL=osmesa" in result.stdout and "MUJOCO_GL=egl" in result.stdout, result.stdout


def test_an_unclosed_renderer_is_freed_before_the_interpreter_exits():
    """Without close(), MuJoCo's OSMesa context used to be freed during interpreter shutdown: an obscure ctypes error."""
    code = ("from softcbf_mj.env import GymArmEnv\n"
            "env = GymArmEnv(render_mode='rgb_array', control_rate=100.0, physics_dt=2e-4, links_per_segment=5)\n"
            "env.reset(seed=0)\nprint(env.render().shape)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and result.stdout.strip() == "(180, 320, 3)"
    assert "Exception ignored" not in result.stderr and "ctypes" not in result.stderr, result.stderr
