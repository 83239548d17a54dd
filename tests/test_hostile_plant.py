"""The plant out of reach, the limits fixed before user code, and the environment's edge (docs/safety-filter.md,
docs/environment.md).

A filter or nominal factory is told a `FilterContext`. Found on the previous code: in paper_sim that context carried the
PCC plant's own evaluation object, whose parameter rows the plant integrates with (a factory scaling the actuator gains
in it turned a 4 F_max push into ρ 1.0); everywhere it carried the very safe set the verdict is computed with and the
very context the control step read its limits from after the factories ran (`object.__setattr__(context, "limits",
...)` sent 1e6 hPa with the pressure limits on). Each plug-in is now handed its own copy (`FilterContext.copy`), so
the tests below tamper with everything a factory is handed, in every loop, and expect the run the untampered loop
gives. Then the environment's edge: its settings checked by the vocabulary, its actions converted once, its info's
ground truth flagged; and duplicate tunings refused.
"""

from __future__ import annotations

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from scenarios.run import USAGE_ERROR, exit_code, run_scenario
from softcbf.study import Study, StudyStore, run_study
from softcbf_mj.outputs.runio import load_timeseries

REPO = Path(__file__).resolve().parents[1]
LIMIT = 150.0  # hPa, the reference robot's pressure limits
PUSH = ("--nominal", "step", "--nominal-param", "low_hPa=150", "--nominal-param", "high_hPa=150")  # 4 F_max at 0.2 s
JUDGED = ("rho_min_meas", "force_max_N", "t_violation_s", "u_peak_abs_hPa")

PLUGINS = textwrap.dedent('''
    import numpy as np

    def tamper(context):
        """Change everything the context leads to: the plant's model where one is handed, the robot, the safe set."""
        n = context.robot.n_segments
        dynamics = getattr(context, "dynamics", None)
        if dynamics is not None:
            dynamics.parameter_rows[:, 4 * n:5 * n] *= 0.01  # the actuator gains the PCC plant integrates with
        safe_set = context.safe_set
        object.__setattr__(safe_set, "n_max", 1e3)  # rho_meas = (n_max - penetration(F)) / n_max -> 1
        object.__setattr__(safe_set, "f_max", 1e3)
        object.__setattr__(safe_set.stiffness, "k", 1e-9)  # the plate's spring
        offsets = safe_set.environment.offsets
        offsets.setflags(write=True)
        offsets += 1.0  # the plates 1 m farther
        object.__setattr__(context.robot, "gains", tuple(0.01 * g for g in context.robot.gains))
        object.__setattr__(context.robot, "u_max", tuple(1e6 for _ in range(n)))

    def widen(context):
        """The step's limits, through the frozen context."""
        n = context.robot.n_segments
        object.__setattr__(context, "limits", ((-1e6,) * n, (1e6,) * n))

    class Tamper:  # passes u_nom through
        def __init__(self, context):
            tamper(context)
        def __call__(self, estimate, u_nom):
            return u_nom

    class TamperNominal:  # the push: 150 hPa on every segment
        def __init__(self, context):
            tamper(context)
        def __call__(self, t, q, qd):
            return np.full(len(q), 150.0)

    class Widen:  # asks for 1e6 hPa
        def __init__(self, context):
            widen(context)
        def __call__(self, estimate, u_nom):
            return np.full(len(u_nom), 1e6)

    class WidenNominal:  # a nominal asking for 1e6 hPa
        def __init__(self, context):
            widen(context)
        def __call__(self, t, q, qd):
            return np.full(len(q), 1e6)
''')


@pytest.fixture(scope="module")
def plugins(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("plugins") / "hostile_plant.py"
    path.write_text(PLUGINS, encoding="utf-8")
    return path


def _paper_sim(out: Path, *tokens: str, scenario: str = "paper_sim") -> tuple[int, dict]:
    """Run `scenario` for 0.2 s; (exit code, its one row)."""
    code = exit_code(lambda: run_scenario(scenario, ["--duration", "0.2", "--progress", "false", *tokens], out))
    return code, json.loads((out / "summary.json").read_text())["runs"][0]


def _study(out: Path, filter_spec: str, **fixed: object) -> list[dict]:
    """A batched mujoco_contact study (2 draws of the true plate, one batch) of the full push from t0 = 25 s."""
    study = Study("hostile", "mujoco_contact", ("Low",), draws=2, seed=3,
                  fixed={"t0": 25.0, "duration": 0.3, "amplitude": 150.0, "filter": filter_spec, **fixed},
                  vary=())
    run_study(study, out, workers=1, progress=False)
    rows = StudyStore.open(out).load_rows()
    assert [r["batch_size"] for r in rows] == [2, 2]
    return rows


# --- the plant out of reach --------------------------------------------------------------------------------------


def test_a_filter_cannot_change_the_pcc_plant_or_the_verdict_of_paper_sim(tmp_path, plugins):
    code, benign = _paper_sim(tmp_path / "none", "--filter", "none", *PUSH)
    assert code == 0 and benign["rho_min_meas"] < -3.0  # the push: 4 F_max
    code, hostile = _paper_sim(tmp_path / "tamper", "--filter", f"{plugins}:Tamper", *PUSH)
    assert code == 0
    assert {k: hostile[k] for k in JUDGED} == {k: benign[k] for k in JUDGED}


@pytest.mark.slow
def test_a_nominal_cannot_change_the_pcc_plant_either(tmp_path, plugins):
    code, benign = _paper_sim(tmp_path / "none", "--filter", "none", *PUSH)
    code, hostile = _paper_sim(tmp_path / "tamper", "--filter", "none", "--nominal", f"{plugins}:TamperNominal")
    assert code == 0
    assert {k: hostile[k] for k in JUDGED} == {k: benign[k] for k in JUDGED}


def test_a_filter_cannot_change_the_verdict_of_a_batched_mujoco_study(tmp_path, plugins):
    benign = _study(tmp_path / "none", "none")
    hostile = _study(tmp_path / "tamper", f"{plugins}:Tamper")
    assert all(r["rho_min_meas"] < 0 for r in benign)  # both draws push through F_max
    for one, other in zip(benign, hostile):
        assert {k: other[k] for k in JUDGED} == {k: one[k] for k in JUDGED}


def _env_run(filter_spec: str) -> list[dict]:
    from softcbf_mj.env.gym_adapter import GymArmEnv

    env = GymArmEnv(filter=filter_spec, action_repeat=100, episode_steps=3)
    env.reset(seed=0)
    infos = [env.step(np.array([150.0, 150.0]))[4] for _ in range(3)]
    env.close()
    return infos


def test_a_filter_cannot_change_the_environments_cost_or_info(plugins):
    benign, hostile = _env_run("none"), _env_run(f"{plugins}:Tamper")
    assert min(info["rho_meas_min"] for info in benign) < 0
    keys = ("cost", "violation_periods", "rho_meas_min", "force_max_N", "force_excess")
    assert [{k: i[k] for k in keys} for i in hostile] == [{k: i[k] for k in keys} for i in benign]


def test_a_vector_environments_filters_are_told_copies(plugins):
    from softcbf_mj.env.vector import ArmVectorEnv

    envs = ArmVectorEnv(2, filter=f"{plugins}:Tamper")
    assert envs.safe_set.n_max < 1.0 and envs.control.limits[1].tolist() == [LIMIT, LIMIT]
    assert all(arm.context.robot.u_max == (LIMIT, LIMIT) for arm in envs.arms)
    envs.close()


def test_the_hardware_configs_robot_and_safe_set_are_out_of_a_factorys_reach(plugins):
    from hardware.config import HardwareConfig
    from hardware.runner import controller_context
    from softcbf.hardware_cli import check_controller

    config = HardwareConfig.load(REPO / "examples" / "hardware_emulated.toml").with_overrides(
        {"filter": f"{plugins}:Tamper", "nominal": f"{plugins}:WidenNominal"})
    robot, safe_set = config.robot_params(), config.safe_set()
    gains, u_max, n_max = robot.gains, robot.u_max, safe_set.n_max
    check_controller(config)  # builds the filter and the nominal once, as `softcbf hardware` does at load
    assert (robot.gains, robot.u_max, safe_set.n_max) == (gains, u_max, n_max)
    context = controller_context(config)
    assert context.robot is not robot and context.safe_set is not safe_set and context.robot == robot


# --- the limits fixed before user code runs ---------------------------------------------------------------------


@pytest.mark.parametrize("scenario, who", [("paper_sim", "filter"), ("paper_sim", "nominal"),
                                           ("mujoco_contact", "filter")])
def test_object_setattr_on_the_context_limits_cannot_widen_the_clip_in_a_run(tmp_path, plugins, scenario, who):
    tokens = (("--filter", f"{plugins}:Widen", *PUSH) if who == "filter"
              else ("--filter", "none", "--nominal", f"{plugins}:WidenNominal"))
    code, row = _paper_sim(tmp_path / who, "--pressure-limits", "true", *tokens, scenario=scenario)
    assert code == 0 and row["u_peak_abs_hPa"] == LIMIT
    series, _ = load_timeseries(tmp_path / who / row["timeseries"])
    assert np.all(series["u"] == LIMIT)


def test_object_setattr_on_the_context_limits_cannot_widen_the_clip_in_a_batched_mujoco_study(tmp_path, plugins):
    rows = _study(tmp_path / "widen", f"{plugins}:Widen", pressure_limits=True)
    assert [r["u_peak_abs_hPa"] for r in rows] == [LIMIT, LIMIT]


# --- the environment's edge -------------------------------------------------------------------------------------


@pytest.mark.parametrize("change, message", [
    ({"q0_std": 100.0}, r"^q0_std must be in \[0, 3.14159\] rad, got 100.0$"),
    ({"tau_p": 50.0}, r"^tau_p must be <= 5 s \(a plausibility bound; a value in ms\? .*got 50.0$"),
    ({"hold_s": -1.0}, r"^hold_s must be >= 0 s, got -1.0$"),
    ({"links_per_segment": 0}, r"^links_per_segment must be in \[1, 100\], got 0$"),
    ({"pressure_limits": 1}, r"^pressure_limits must be true or false, got 1$"),
])
def test_the_environment_refuses_what_the_vocabulary_refuses(change, message):
    from softcbf_mj.env import make_environment

    with pytest.raises(ValueError, match=message):
        make_environment(**change)


BAD_ACTIONS = {
    "bool": np.array([True, False]),
    "complex": np.array([150.0 + 1j, 0.0]),
    "masked": np.ma.masked_array([150.0, 0.0], mask=[False, True]),
    "object": np.array([150.0, None], dtype=object),
    "str": ["150", "0"],
}


@pytest.fixture(scope="module")
def gym_env():
    from softcbf_mj.env.gym_adapter import GymArmEnv

    env = GymArmEnv(episode_steps=100)
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.parametrize("what", sorted(BAD_ACTIONS))
def test_bad_actions_are_refused_by_every_form_of_the_environment(gym_env, what):
    action = BAD_ACTIONS[what]
    with pytest.raises(ValueError, match=r"^the action u_nom must "):
        gym_env.step(action)
    with pytest.raises(ValueError, match=r"^the action u_nom must "):
        gym_env.environment.step(action)  # dm_env's form
    gym_env.step(np.array([10.0, 10.0]))  # the episode goes on


@pytest.mark.parametrize("what", ["bool", "complex", "masked"])
def test_bad_actions_are_refused_by_the_vector_environment(what):
    from softcbf_mj.env.vector import ArmVectorEnv

    envs = ArmVectorEnv(2)
    envs.reset(seed=0)
    action = BAD_ACTIONS[what]
    actions = np.ma.vstack([action, action]) if what == "masked" else np.stack([action, action])
    with pytest.raises(ValueError, match=r"^actions must "):
        envs.step(actions)
    envs.close()


def test_the_environments_info_keys_are_the_documented_ones_with_the_ground_truth_flagged(gym_env):
    from softcbf_mj.env.gym_adapter import GROUND_TRUTH_INFO, INFO_KEYS

    info = gym_env.step(np.array([10.0, 10.0]))[4]
    assert tuple(info) == INFO_KEYS and set(GROUND_TRUTH_INFO) < set(INFO_KEYS)
    doc = (REPO / "docs" / "environment.md").read_text(encoding="utf-8")
    assert all(f"`{key}`" in doc for key in GROUND_TRUTH_INFO)


# --- duplicate tunings -------------------------------------------------------------------------------------------


def test_duplicate_tunings_are_refused_with_one_line(tmp_path, capsys):
    out = tmp_path / "dup"
    code = exit_code(lambda: run_scenario("paper_sim", ["--tunings", "None,Low,None", "--duration", "0.01",
                                                        "--progress", "false"], out))
    err = capsys.readouterr().err.strip()
    assert code == USAGE_ERROR and not out.exists()
    assert err.count("\n") == 0 and "tunings must name each tuning once" in err and "None more than once" in err


def test_a_context_copy_shares_no_object_with_the_loops_context():
    from controllers.model.params import reference_robot
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import FilterContext

    context = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3, actuator_tau=0.05)
    own = context.copy()
    assert own.robot == context.robot and own.limits == context.limits and own.actuator_tau == 0.05
    pairs = [(own.robot, context.robot), (own.safe_set, context.safe_set), (own.u_max, context.u_max),
             (own.safe_set.environment, context.safe_set.environment),
             (own.safe_set.stiffness, context.safe_set.stiffness), (own.safe_set.H_prime, context.safe_set.H_prime)]
    assert all(a is not b for a, b in pairs)
    assert np.array_equal(own.safe_set.h_prime, context.safe_set.h_prime) and own.safe_set.n_max == context.safe_set.n_max
    assert not (own.u_max.flags.writeable or own.safe_set.environment.offsets.flags.writeable)
