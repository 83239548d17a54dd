"""The filter is told the valve lag the controller assumes (`assumed_tau_p`), never the true valves' (`tau_p`): a
study that varies the true lag as an error must not hand it to the filter under test through its context."""

from __future__ import annotations

import pytest

from scenarios import registry
from scenarios.camera_loop import camera_setup
from scenarios.mujoco_contact import contact_setup
from scenarios.pcc_contact import pcc_contact_setup
from scenarios.run import scenario_parameters

SETUPS = {"mujoco_contact": contact_setup, "camera_loop": camera_setup, "pcc_contact": pcc_contact_setup}


def told_lag(scenario: str, arguments: list[str]) -> float:
    """The valve lag (s) in the FilterContext that `scenario`'s setup gives its filter for the command line."""
    spec = registry()[scenario].spec.from_flat(scenario_parameters(registry()[scenario], arguments))
    return SETUPS[scenario](spec).context.actuator_tau


@pytest.mark.parametrize("scenario", sorted(SETUPS))
def test_the_true_valve_lag_does_not_reach_the_filter(scenario):
    assert told_lag(scenario, ["--tau-p", "0.1"]) == 0.05  # the default assumed lag, the model's
    assert told_lag(scenario, ["--tau-p", "0.1", "--assumed-tau-p", "0.08"]) == 0.08


def test_the_environment_tells_its_filter_what_it_assumes_not_the_true_arm():
    from softcbf_mj.env import ArmEnvConfig
    context = ArmEnvConfig(tau_p=0.1, command_delay=0.002).context()
    assert (context.actuator_tau, context.command_delay) == (0.05, 0.0)  # the defaults assumed, the model's
    context = ArmEnvConfig(tau_p=0.1, assumed_tau_p=0.08, assumed_command_delay=0.001).context()
    assert (context.actuator_tau, context.command_delay) == (0.08, 0.001)
