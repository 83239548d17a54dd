"""softcbf_mj.env.vector: make_vec on every id, equal to SyncVectorEnv of the single env, autoreset, seeds, faults."""

from __future__ import annotations

import textwrap

import gymnasium
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode, SyncVectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.wrappers.vector import RecordEpisodeStatistics

from closedloop.step import FilterFault
from softcbf_mj.env import ENV_ID, PRESETS, GymArmEnv, RewardConfig
from softcbf_mj.env.gym_adapter import scaled_observations, step_info, step_infos
from softcbf_mj.env.physics import ArmArrays, BatchStepStats
from softcbf_mj.env.vector import ArmVectorEnv

FAST = {"control_rate": 100.0, "physics_dt": 2e-4, "links_per_segment": 5}  # a coarse, quick arm (as tests/test_env.py)
INFO_KEYS = ("cost", "periods", "violation_periods", "rho_meas_min", "force_max_N", "force_excess", "vented", "clipped",
             "t", "monitor_action", "filter_action", "fault")


def _pair(num_envs: int, **kwargs) -> tuple[ArmVectorEnv, SyncVectorEnv]:
    """The vector env and SyncVectorEnv of the single env, both from gymnasium.make_vec on ENV_ID."""
    vector = gymnasium.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="vector_entry_point", **kwargs)
    sync = gymnasium.make_vec(ENV_ID, num_envs=num_envs, vectorization_mode="sync", **kwargs)
    return vector, sync


def _actions(num_envs: int, steps: int, seed: int = 0) -> np.ndarray:
    """Pushes into the plate (segment 1 at +150 hPa, segment 2 random) mixed with random commands, (T, B, 2) hPa."""
    rng = np.random.default_rng(seed)
    actions = rng.uniform(-150.0, 150.0, (steps, num_envs, 2))
    actions[: steps // 2, :, 0] = 150.0
    return actions


def _assert_same_step(got, want, exact: bool, where: str) -> None:
    """Two vector steps' (or resets') results agree: bit for bit, or within 1e-9 (batched filter)."""
    compare = np.testing.assert_array_equal if exact else (lambda a, b, err_msg: np.testing.assert_allclose(
        a, b, rtol=1e-9, atol=1e-9, err_msg=err_msg))
    observation, want_observation = got[0], want[0]
    assert observation.keys() == want_observation.keys()
    for key in observation:
        compare(observation[key], want_observation[key], err_msg=f"{where}: observation {key}")
    infos, want_infos = got[-1], want[-1]
    if len(got) == 5:
        compare(got[1], want[1], err_msg=f"{where}: rewards")
        np.testing.assert_array_equal(got[2], want[2], err_msg=f"{where}: terminations")
        np.testing.assert_array_equal(got[3], want[3], err_msg=f"{where}: truncations")
    for key in INFO_KEYS:
        assert infos[f"_{key}"].all()
        if infos[key].dtype == object:
            assert list(infos[key]) == list(want_infos[key]), f"{where}: info {key}"
        else:
            compare(infos[key], want_infos[key], err_msg=f"{where}: info {key}")


@pytest.mark.parametrize("env_id", [ENV_ID, *PRESETS])
def test_make_vec_builds_the_vector_env_of_every_id(env_id):
    envs = gymnasium.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", normalise=True, **FAST)
    single = gymnasium.make(env_id, normalise=True, **FAST)
    assert isinstance(envs, ArmVectorEnv) and envs.num_envs == 2
    assert envs.metadata["autoreset_mode"] is AutoresetMode.NEXT_STEP
    assert envs.max_episode_steps == gymnasium.spec(env_id).max_episode_steps  # make_vec hands the spec's limit
    config, single_config = envs.config, single.unwrapped.config  # a preset's config, the keywords applied
    assert (config.reward, config.action_repeat, config.episode_steps, config.control_dt) == (
        single_config.reward, single_config.action_repeat, single_config.episode_steps, single_config.control_dt)
    assert envs.single_action_space == single.action_space and envs.single_observation_space == single.observation_space
    assert envs.action_space == batch_space(single.action_space, 2)
    assert envs.observation_space == batch_space(single.observation_space, 2)
    observations, _ = envs.reset(seed=0)
    assert envs.observation_space.contains(observations)
    observations, *_ = envs.step(envs.action_space.sample())
    assert envs.observation_space.contains(observations)
    assert isinstance(gymnasium.make_vec(env_id, num_envs=2, **FAST), ArmVectorEnv)  # the default mode


def _random_arms(rng: np.random.Generator, n_arms: int, n_facets: int, f_max: float) -> ArmArrays:
    """B arms' arrays spread over free space, contact and violations (forces up to 3 F_max), every flag mixed."""
    periods = rng.integers(0, 4, n_arms)
    stats = BatchStepStats(periods, rng.integers(0, periods + 1), rng.uniform(-2.0, 1.0, n_arms),
                           rng.uniform(0.0, 3.0 * f_max, n_arms), rng.uniform(0.0, 2.0, n_arms),
                           rng.random(n_arms) < 0.3)
    return ArmArrays(rng.normal(0.0, 0.6, (n_arms, 2)), rng.normal(0.0, 5.0, (n_arms, 2)),
                     rng.uniform(-150.0, 150.0, (n_arms, 2)), rng.uniform(0.0, 1.0, n_arms),
                     rng.normal(0.0, 0.6, (n_arms, 2)), rng.normal(0.0, 60.0, (n_arms, 2)),
                     rng.uniform(0.0, 0.3, (n_arms, 2)), rng.uniform(0.0, 3.0 * f_max, (n_arms, n_facets)), stats,
                     rng.random(n_arms) < 0.3, rng.random(n_arms) < 0.2)


@pytest.mark.parametrize("cost", ["violation", "force_excess"])
def test_b_arms_task_functions_equal_their_single_arm_calls_row_by_row(cost):
    """One definition for one arm and for B: the task's observations, rewards, costs, ends and the adapter's
    scaling and infos of B = 37 arms equal, bit for bit, the same calls at B = 1 (how the single env calls
    them) row by row, over free space, contact, violations, vents, faults and clipped observations."""
    reward = RewardConfig(target_tip_m=(0.2, 0.05), tracking_weight=2.0, target_force_N=0.1, force_weight=3.0,
                          violation_penalty=0.5, terminate_on_violation=True, terminate_on_vent=False)
    env = GymArmEnv(**FAST, observation="privileged", normalise=True, reward=reward, cost=cost, episode_steps=5)
    task, physics, scales = env.task, env.physics, env.scales
    rng = np.random.default_rng(11)
    n_arms = 37
    arms = _random_arms(rng, n_arms, physics.safe_set.n_facets, physics.safe_set.f_max)
    steps = rng.integers(0, 8, n_arms)
    monitor = np.array(rng.choice(["run", "hold", "vent", ""], n_arms), dtype=object)
    filtered = np.array(rng.choice(["nominal", "filtered", ""], n_arms), dtype=object)
    fault = FilterFault("RuntimeError", "boom", "filter", "x.py:1", 0.5, "")
    faults = [fault if flag else None for flag in arms.faulted]
    observations, clipped = scaled_observations(task.observations(arms, physics.safe_set, physics.lengths), scales)
    rewards, costs, (terminated, truncated) = task.rewards(arms), task.costs(arms), task.ends(arms, steps)
    infos = step_infos(task, arms, clipped, monitor, filtered, faults)
    assert any(clipped) and not all(clipped), "some arms, not all, must have clipped observations"
    assert terminated.any() and truncated.any() and not (terminated & truncated).any()
    assert rewards.shape == costs.shape == (n_arms,) and set(observations) == set(task.keys())
    for b in range(n_arms):
        row = ArmArrays(*(field[b:b + 1] for field in arms[:-3]), BatchStepStats(*(f[b:b + 1] for f in arms.stats)),
                        arms.vent_latched[b:b + 1], arms.faulted[b:b + 1])
        single, single_clipped = scaled_observations(task.observations(row, physics.safe_set, physics.lengths), scales)
        for key, value in single.items():
            np.testing.assert_array_equal(observations[key][b:b + 1], value, err_msg=f"arm {b}: {key}")
        assert clipped[b] == single_clipped[0]
        np.testing.assert_array_equal(rewards[b:b + 1], task.rewards(row))
        np.testing.assert_array_equal(costs[b:b + 1], task.costs(row))
        ends = task.ends(row, steps[b:b + 1])
        assert (terminated[b], truncated[b]) == (ends[0][0], ends[1][0])
        single_infos = step_infos(task, row, single_clipped, monitor[b:b + 1], filtered[b:b + 1], faults[b:b + 1])
        assert list(single_infos) == list(infos)
        for key, value in single_infos.items():
            assert list(value) == list(infos[key][b:b + 1]), f"arm {b}: info {key}"
    env.reset(seed=0)
    observation, reward, *_, info = env.step(np.array([1.0, 0.0]))  # the single env: the same functions at B = 1
    arms = physics.arrays()
    assert reward == task.rewards(arms)[0] and info == step_info(task, physics, info["clipped"])
    np.testing.assert_array_equal(observation["tip_pred"], np.clip(
        task.observations(arms, physics.safe_set, physics.lengths)["tip_pred"][0] / scales["tip_pred"], -1.0, 1.0))


@pytest.mark.parametrize("changes", [
    {"observation": "estimate"},
    {"observation": "privileged", "normalise": True, "state_noise_std": (0.01, 0.1), "cost": "force_excess"},
    {"filter": "qsg", "filter_params": {"rate_limit_hPa_per_s": 2000.0}},
])
def test_vector_env_equals_sync_vector_env_bit_for_bit_through_autoresets(changes):
    """Per-arm filters ("none": one instance per arm) or one shared qsg (filter_batch with a history per
    arm, each arm's reset alone at its autoreset), random initial shapes, seeds per sub-env, episodes of
    6 env steps of 2 control periods (truncated by the task): every observation, reward, flag and info
    equal to B single envs', autoresets included."""
    kwargs = {**FAST, "q0_std": 0.1, "episode_steps": 6, "action_repeat": 2, "filter": "none", **changes}
    vector, sync = _pair(3, **kwargs)
    assert (vector.shared_filter is not None) == (kwargs["filter"] == "qsg")
    _assert_same_step(vector.reset(seed=7), sync.reset(seed=7), True, "reset")
    ended = np.zeros(3, dtype=int)
    for k, actions in enumerate(_actions(3, 20)):
        got, want = vector.step(actions), sync.step(actions)
        _assert_same_step(got, want, True, f"step {k}")
        ended += got[2] | got[3]
    assert (ended >= 2).all(), "every sub-env must have been autoreset at least twice"
    _assert_same_step(vector.reset(seed=[3, None, 5]), sync.reset(seed=[3, None, 5]), True, "reset with a seed list")
    _assert_same_step(vector.step(actions), sync.step(actions), True, "after the reset")


def test_time_limit_truncates_as_gymnasiums():
    """max_episode_steps below episode_steps: truncated at it, as gymnasium.make's TimeLimit."""
    vector, sync = _pair(2, **FAST, episode_steps=50, max_episode_steps=3, q0_std=0.05)
    _assert_same_step(vector.reset(seed=1), sync.reset(seed=1), True, "reset")
    truncations = []
    for k, actions in enumerate(_actions(2, 8)):
        got = vector.step(actions)
        _assert_same_step(got, sync.step(actions), True, f"step {k}")
        truncations.append(got[3].copy())
    np.testing.assert_array_equal(np.array(truncations)[:, 0], [0, 0, 1, 0, 0, 0, 1, 0])


def test_termination_at_the_time_limit_is_also_truncated_as_gymnasiums():
    """An episode terminated (a violation) at the very step the time limit is reached: terminated and,
    as Gymnasium's TimeLimit says, truncated too."""
    kwargs = {**FAST, "reward": RewardConfig(terminate_on_violation=True), "episode_steps": 500}
    probe = GymArmEnv(**kwargs)
    probe.reset(seed=0)
    push = np.array([150.0, 150.0])
    for limit in range(1, 500):
        if probe.step(push)[2]:
            break
    vector, sync = _pair(2, **kwargs, max_episode_steps=limit)
    _assert_same_step(vector.reset(seed=0), sync.reset(seed=0), True, "reset")
    for k in range(limit):
        got = vector.step(np.tile(push, (2, 1)))
        _assert_same_step(got, sync.step(np.tile(push, (2, 1))), True, f"step {k}")
    assert got[2][0] and got[3][0], "terminated and truncated at the limit"


def test_next_step_autoreset_ignores_the_action_and_returns_the_reset():
    """The step after an episode's end: the reset's observation and info, reward 0, no flags, the action unused."""
    envs = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", **FAST, episode_steps=2,
                              q0_std=0.1)
    first, _ = envs.reset(seed=4)
    push = np.full((2, 2), 150.0)
    envs.step(push)
    _, _, terminated, truncated, _ = envs.step(push)
    assert truncated.all() and not terminated.any()
    observations, rewards, terminated, truncated, infos = envs.step(np.full((2, 2), np.nan))  # ignored
    np.testing.assert_array_equal(rewards, 0.0)
    assert not terminated.any() and not truncated.any()
    np.testing.assert_array_equal(infos["t"], 0.0)
    np.testing.assert_array_equal(infos["periods"], 0)
    np.testing.assert_array_equal(observations["u"], 0.0)
    assert not np.array_equal(observations["q"], first["q"]), "the second episode draws a new initial shape"
    reseeded, _ = envs.reset(seed=4)
    np.testing.assert_array_equal(reseeded["q"], first["q"])
    single = GymArmEnv(**FAST, episode_steps=2, q0_std=0.1)
    np.testing.assert_array_equal(single.reset(seed=5)[0]["q"], first["q"][1])  # sub-env b gets seed + b


def test_gymnasiums_episode_statistics_wrapper_sees_the_same_episodes():
    """Gymnasium 1.4 has no checker for vector envs; its RecordEpisodeStatistics wrapper relies on
    next-step autoreset: the same episode returns and lengths as over SyncVectorEnv."""
    kwargs = {**FAST, "episode_steps": 3, "q0_std": 0.1, "reward": RewardConfig(target_tip_m=(0.2, 0.0))}
    episodes = {}
    for mode in ("vector_entry_point", "sync"):
        envs = RecordEpisodeStatistics(gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode=mode, **kwargs))
        envs.reset(seed=0)
        episodes[mode] = []
        for k, actions in enumerate(_actions(2, 8)):
            info = envs.step(actions)[-1]
            if "episode" in info:
                episodes[mode].append((k, info["episode"]["r"].tolist(), info["episode"]["l"].tolist()))
    assert [k for k, *_ in episodes["sync"]] == [2, 6]
    assert episodes["vector_entry_point"] == episodes["sync"]


def test_batched_filter_is_called_once_for_all_arms_and_matches_single_envs():
    """The paper's CBF has filter_batch: one filter shared by all arms, one call per control period;
    its commands are within 1e-9 hPa of single calls, so the vector env follows B single envs closely."""
    kwargs = {**FAST, "filter": "paper-cbf", "filter_params": {"tuning": "Low"}, "q0_std": 0.05, "episode_steps": 15}
    vector, sync = _pair(5, **kwargs)  # 5 >= controllers.cbf.batch.SCALAR_BELOW: batched
    assert vector.shared_filter is not None
    calls = []
    batch = vector.shared_filter.filter_batch
    vector.shared_filter.filter_batch = lambda estimates, u_nom: calls.append(len(estimates)) or batch(estimates, u_nom)
    _assert_same_step(vector.reset(seed=0), sync.reset(seed=0), False, "reset")
    actions_seen = set()
    for k, actions in enumerate(_actions(5, 20)):
        got = vector.step(actions)
        _assert_same_step(got, sync.step(actions), False, f"step {k}")
        actions_seen |= set(got[-1]["filter_action"])
    assert calls and max(calls) == 5 and len(calls) <= 20 * 2  # at most one call per control period
    assert actions_seen - {"nominal", ""}, f"the filter must act, saw only {actions_seen}"


FAULTY = textwrap.dedent('''
    import numpy as np
    from controllers.contract.capabilities import Capabilities

    class Faulty:
        """Raises once the first bending angle passes q_limit rad."""

        def __init__(self, q_limit: float = 0.05):
            self.q_limit = q_limit

        def __call__(self, estimate, u_nom):
            if estimate.q[0] > self.q_limit:
                raise RuntimeError("q beyond the limit")
            return u_nom

    class FaultyBatch(Faulty):
        capabilities = Capabilities(batched=True)

        def filter_batch(self, estimates, u_nom):
            raise RuntimeError("the batch call fails")
''')


def test_a_filter_fault_ends_only_that_sub_envs_episode(tmp_path):
    path = tmp_path / "faulty.py"
    path.write_text(FAULTY, encoding="utf-8")
    kwargs = {**FAST, "filter": f"{path}:Faulty", "hold_s": 0.05, "episode_steps": 40, "action_repeat": 3}
    vector = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    single = gymnasium.make(ENV_ID, **kwargs)
    actions = np.array([[150.0, 0.0], [0.0, 0.0]])  # sub-env 0 bends past the limit, sub-env 1 stays straight
    vector.reset(seed=0)
    single.reset(seed=0)
    for k in range(40):
        got = vector.step(actions)
        want = single.step(actions[0])
        assert got[2][0] == want[2] and got[-1]["fault"][0] == want[-1]["fault"], f"step {k}"
        np.testing.assert_array_equal(got[0]["q"][0], want[0]["q"])
        assert got[-1]["periods"][0] == want[-1]["periods"], f"step {k}"  # the vent ends the env step's periods
        if want[2]:
            break
    assert want[2], "the single env must end its episode on the fault"
    fault = got[-1]["fault"][0]
    assert fault["type"] == "RuntimeError" and fault["where"] == "filter" and got[-1]["monitor_action"][0] == "vent"
    assert not got[2][1] and got[-1]["fault"][1] is None and got[-1]["monitor_action"][1] == "run"
    got = vector.step(actions)  # sub-env 0 autoresets: a fresh control step, no fault; sub-env 1 goes on
    assert got[-1]["fault"][0] is None and got[-1]["t"][0] == 0.0 and got[-1]["t"][1] > 0.0

    shared = gymnasium.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point",
                                **{**kwargs, "filter": f"{path}:FaultyBatch"})
    shared.reset(seed=0)
    got = shared.step(actions)  # the shared filter's batch call raises: a fault of every arm it was called for
    assert [f["where"] for f in got[-1]["fault"]] == ["filter_batch", "filter_batch"]


COUNTING = textwrap.dedent('''
    import numpy as np
    from controllers.contract.capabilities import Capabilities
    from controllers.contract.safety_filter import BatchOutput

    class Counting:
        """Passes u_nom through; counts its instances' reset() calls."""

        resets = 0

        def reset(self):
            type(self).resets += 1

        def __call__(self, estimate, u_nom):
            return u_nom

    class CountingBatch(Counting):
        capabilities = Capabilities(batched=True)
        resets = 0

        def filter_batch(self, estimates, u_nom):
            n = len(u_nom)
            return BatchOutput(np.array(u_nom), np.array(["nominal"] * n), np.zeros(n, dtype=bool), np.full(n, np.nan))
''')


def test_per_arm_filters_reset_every_episode_a_shared_one_at_reset_only(tmp_path):
    path = tmp_path / "counting.py"
    path.write_text(COUNTING, encoding="utf-8")
    for name, after_reset, after_autoreset in (("Counting", 2, 4), ("CountingBatch", 1, 1)):
        envs = ArmVectorEnv(2, filter=f"{path}:{name}", episode_steps=2, **FAST)
        counter = type(envs.arms[0].filter)
        assert (envs.shared_filter is not None) == (name == "CountingBatch")
        counter.resets = 0
        envs.reset(seed=0)
        assert counter.resets == after_reset, name
        for _ in range(3):  # the episodes end at step 2, both arms autoreset at step 3
            envs.step(np.zeros((2, 2)))
        assert counter.resets == after_autoreset, name
        envs.reset()
        assert counter.resets == after_autoreset + after_reset, name


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="num_envs must be an integer >= 1, got 0"):
        ArmVectorEnv(0, **FAST)
    with pytest.raises(ValueError, match="max_episode_steps must be None or an integer >= 1, got 0"):
        ArmVectorEnv(2, max_episode_steps=0, **FAST)
    with pytest.raises(ValueError, match="camera and tag_detections must be False"):
        ArmVectorEnv(2, camera=True, **FAST)
    with pytest.raises(ValueError, match="render_mode must be None"):
        ArmVectorEnv(2, render_mode="rgb_array", **FAST)
    with pytest.raises(ValueError, match="nthread must be an integer >= 0"):
        ArmVectorEnv(2, nthread=-1, **FAST)
    envs = ArmVectorEnv(2, **FAST)
    with pytest.raises(RuntimeError, match=r"call reset\(\) before step\(\)"):
        envs.step(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="seed must be None, an integer or num_envs = 2 seeds, got 3"):
        envs.reset(seed=[1, 2, 3])
    envs.reset(seed=0)
    with pytest.raises(ValueError, match=r"actions must have shape \(2, 2\), got \(2,\)"):
        envs.step(np.zeros(2))
