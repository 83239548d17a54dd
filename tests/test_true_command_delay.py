"""The ground truth's command delay (`command_delay`, softcbf_mj.physics.plant): a FIFO of whole control periods between
the controller's command and the valves, on the MuJoCo and PCC plants, single and batched; the filter is told
`assumed_command_delay`, never the true delay."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from scenarios import get as get_scenario
from scenarios import registry
from scenarios.mujoco_contact import contact_setup
from scenarios.pcc_contact import pcc_contact_setup
from scenarios.run import scenario_parameters
from scenarios.run_outputs import data_only

STEP = np.array([100.0, -60.0])  # hPa, the commanded step
K = 3  # periods of delay: 3 ms at the scenarios' 1 kHz


def spec_of(scenario: str, arguments: list[str]):
    """`scenario`'s checked spec for the command line `arguments`."""
    return registry()[scenario].spec.from_flat(scenario_parameters(registry()[scenario], arguments))


def responses(plant, commands: list[np.ndarray]) -> list:
    plant.reset(np.zeros(2))
    return [plant.step(u) for u in commands]


def assert_delayed_by(delayed, plain, k: int, periods: int = 15) -> None:
    """`delayed` given the step at period 0 moves exactly as `plain` given it at period k, bit for bit."""
    late = responses(delayed, [STEP] * periods)
    early = responses(plain, [np.zeros(2)] * k + [STEP] * (periods - k))
    for a, b in zip(late, early):
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.qd, b.qd)
        np.testing.assert_array_equal(a.u_applied, b.u_applied)
    assert np.all(late[k - 1].q == 0.0) and np.any(late[k].q != 0.0)  # at rest until the step arrives


def test_the_mujoco_arm_answers_a_step_exactly_k_periods_late():
    from softcbf_mj.physics.mjcf import build_model
    from softcbf_mj.physics.mujoco_plant import MujocoPlant

    config = contact_setup(spec_of("mujoco_contact", ["--command-delay", "0.003", "--links-per-segment", "2"])).truth.config
    assert config.command_delay == 0.003
    delayed = MujocoPlant(build_model(config), 1e-3)
    assert delayed.delay.periods == K
    assert_delayed_by(delayed, MujocoPlant(build_model(dataclasses.replace(config, command_delay=0.0)), 1e-3), K)


def test_the_pcc_arm_answers_a_step_exactly_k_periods_late():
    from softcbf_mj.physics.pcc_plant import PCCPlant

    spec = spec_of("pcc_contact", ["--command-delay", "0.003"])
    setup = pcc_contact_setup(spec)
    plant = {delay: PCCPlant(setup.robot, setup.plates, control_dt=1e-3, tau_p=spec.tau_p, command_delay=delay)
             for delay in (spec.command_delay, 0.0)}
    assert_delayed_by(plant[0.003], plant[0.0], K)


@pytest.mark.parametrize("scenario", ["mujoco_contact", "pcc_contact"])
def test_a_delay_between_two_control_periods_is_refused_in_one_line(scenario):
    with pytest.raises(ValueError, match=r"^command_delay \(0.0015 s\) must be a whole number of control periods "
                                         r"\(0.001 s\), e.g. 0.001 or 0.002 s$"):
        spec_of(scenario, ["--command-delay", "0.0015"])


@pytest.mark.parametrize("scenario, setup", [("mujoco_contact", contact_setup), ("pcc_contact", pcc_contact_setup)])
def test_the_true_delay_does_not_reach_the_filter(scenario, setup):
    assert setup(spec_of(scenario, ["--command-delay", "0.005"])).context.command_delay == 0.0
    told = setup(spec_of(scenario, ["--command-delay", "0.005", "--assumed-command-delay", "0.004"]))
    assert told.context.command_delay == 0.004


@pytest.mark.parametrize("scenario", ["mujoco_contact", "pcc_contact"])
def test_samples_with_different_delays_are_kept_apart_by_the_batch_key(scenario):
    form, defaults = get_scenario(scenario).batch, get_scenario(scenario).defaults()
    assert form.key({**defaults, "command_delay": 0.002}) != form.key({**defaults, "command_delay": 0.003})
    assert form.key({**defaults, "command_delay": 0.002}) == form.key({**defaults, "command_delay": 0.002,
                                                                         "true_gain_scale": 1.1})


def test_a_batched_mujoco_row_is_the_same_delayed_arm_alone():
    from softcbf_mj.physics.mjcf import build_model
    from softcbf_mj.physics.mujoco_batch_plant import MujocoBatchPlant
    from softcbf_mj.physics.mujoco_plant import MujocoPlant

    config = contact_setup(spec_of("mujoco_contact", ["--command-delay", "0.002", "--links-per-segment", "2"])).truth.config
    configs = [config, dataclasses.replace(config, plate_stiffness=14.0)]
    batch = MujocoBatchPlant.from_configs(configs, control_dt=1e-3)
    commands = [np.array([STEP, -STEP]) * (1 + 0.1 * j) for j in range(8)]
    batch.reset(np.zeros((2, 2)))
    rows = [batch.step(u) for u in commands]
    for b, row_config in enumerate(configs):
        alone = responses(MujocoPlant(build_model(row_config), 1e-3), [u[b] for u in commands])
        for state, single in zip(rows, alone):
            np.testing.assert_array_equal(state.q[b], single.q)
            np.testing.assert_array_equal(state.u_applied[b], single.u_applied)
    with pytest.raises(ValueError, match="must share one command_delay, got \\[0.0, 0.002\\] s"):
        MujocoBatchPlant.from_configs([config, dataclasses.replace(config, command_delay=0.0)], control_dt=1e-3)


def _run(tmp_path: Path, name: str, **params) -> dict:
    out = tmp_path / name
    out.mkdir()
    with data_only():  # the summary row, not the plots
        get_scenario("pcc_contact").run(out, **params)
    return json.loads((out / "summary.json").read_text())["runs"][0]


def test_a_batched_pcc_contact_sample_is_the_sample_run_alone(tmp_path):
    form = get_scenario("pcc_contact").batch
    base = {"duration": 0.3, "t0": 25.0, "tunings": "Low", "progress": False, "plate_stiffness": 14.0,
            "command_delay": 0.004}
    samples = [{**base, "true_gain_scale": 1.1}, {**base, "true_stiffness_scale": 0.9}]
    full = [{**get_scenario("pcc_contact").defaults(), **s} for s in samples]
    assert len({form.key(s) for s in full}) == 1
    batched = form.run(full, 1)
    undelayed = _run(tmp_path, "undelayed", **{**samples[0], "command_delay": 0.0})
    for i, sample in enumerate(samples):
        alone = _run(tmp_path, f"alone{i}", **sample)
        assert batched[i]["rho_min_meas"] == alone["rho_min_meas"]
        assert batched[i]["force_max_N"] == alone["force_max_N"]
    assert batched[0]["force_max_N"] != undelayed["force_max_N"]  # the delay acts
