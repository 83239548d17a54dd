"""softcbf_mj.env: dm_env's conformance test, Gymnasium's checker, the clocks, the shared control step, reward, seeds, camera."""

from __future__ import annotations

import math
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
from controllers.safe_set import paper_safe_set
from softcbf_mj.env import ENV_ID, OBSERVATION_UNITS, ArmEnvConfig, GymArmEnv, RewardConfig, make_environment
from softcbf_mj.env.gym_adapter import box
from softcbf_mj.loop import run_closed_loop
from softcbf_mj.render import camera_matrix, camera_pose_cv, project, tag_poses, tag_plane_z

FAST = {"control_dt": 0.01, "physics_dt": 2e-4, "links_per_segment": 5}  # a coarse, quick arm for the API tests
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


ADVISORY = ("we recommend using a symmetric and normalized space",  # u_nom stays in hPa (RescaleAction wraps it)
            "observation space minimum value is -infinity", "observation space maximum value is infinity")  # q, tip, ...


def test_gymnasium_env_checker_passes_with_only_advisory_warnings():
    """check_env, its render check included (the registered id gives it a spec); only the advice on unbounded and
    unnormalised boxes remains."""
    env = gymnasium.make(ENV_ID, episode_steps=5, image_size=(64, 36), **FAST)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    env.close()
    assert [str(w.message) for w in caught if not any(text in str(w.message) for text in ADVISORY)] == []


def test_specs_name_their_units_and_match_the_box():
    env = make_environment(**FAST)
    action = env.action_spec()
    assert action.name == "u_nom [hPa]" and action.shape == (2,)
    np.testing.assert_array_equal(action.minimum, [-150.0, -150.0])
    np.testing.assert_array_equal(action.maximum, [150.0, 150.0])
    spec = env.observation_spec()
    assert list(spec) == ["q", "qd", "tip", "contact_force", "rho_meas", "u"]
    for key, array in spec.items():
        assert array.name == f"{key} [{OBSERVATION_UNITS[key]}]"
    assert env.reset().observation["tip"] == pytest.approx([0.244, 0.0])  # the straight arm: L1 + L2 along x


@pytest.mark.parametrize("control_dt, action_repeat", [(0.01, 1), (0.01, 3), (0.002, 5)])
def test_clocks_one_env_step_is_action_repeat_control_periods(control_dt, action_repeat):
    env = make_environment(control_dt=control_dt, action_repeat=action_repeat, physics_dt=2e-4, links_per_segment=5)
    assert env.control_timestep() == pytest.approx(control_dt * action_repeat, rel=1e-12)
    env.reset()
    for k in range(1, 4):
        env.step(np.array([50.0, -50.0]))
        assert env.physics.stats.periods == action_repeat
        assert env.physics.time() == pytest.approx(k * action_repeat * control_dt, rel=1e-9)
        assert env.physics.plant.data.time == pytest.approx(k * action_repeat * control_dt, rel=1e-9)


@pytest.mark.parametrize("changes, message", [
    ({"control_dt": 1.5e-4}, "integer multiple of the physics step"),
    ({"action_repeat": 0}, "action_repeat must be an integer >= 1, got 0"),
    ({"action_repeat": 2.0}, "action_repeat must be an integer >= 1, got 2.0"),
    ({"episode_steps": 0}, "episode_steps must be an integer >= 1, got 0"),
    ({"plate_stiffness": -1.0}, "plate_stiffness must be finite and > 0 N/m, got -1.0"),
    ({"image_size": (2000, 100)}, "image_size must be (W, H) integers in [8, 1280]"),
])
def test_invalid_configurations_are_refused(changes, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        ArmEnvConfig(**changes)


def test_reward_config_refuses_bad_values():
    with pytest.raises(ValueError, match="target_tip_m must be a finite"):
        RewardConfig(target_tip_m=(0.1, math.nan))
    with pytest.raises(ValueError, match="violation_penalty must be finite and >= 0, got -1"):
        RewardConfig(violation_penalty=-1.0)


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
    env = GymArmEnv(reward=reward_config, action_repeat=4, **FAST)
    env.reset(seed=0)
    for _ in range(25):
        observation, reward, _, _, info = env.step(np.array([150.0, 150.0]))
        distance = math.hypot(observation["tip"][0] - target[0], observation["tip"][1] - target[1])
        assert reward == pytest.approx(-3.0 * distance - 0.5 * info["violation_periods"], abs=1e-12)
    assert info["violation_periods"] > 0  # the penalty term was exercised


def test_terminate_on_violation_ends_the_episode_at_the_first_violation():
    env = GymArmEnv(reward=RewardConfig(terminate_on_violation=True), episode_steps=500, **FAST)
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
