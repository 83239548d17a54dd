"""A misspelt name is answered with the closest valid ones (controllers.registry.did_you_mean), wherever a name is
looked up: `softcbf` subcommands, scenarios, filters, nominal controllers, scenario parameters."""

import pytest

from controllers.registry import FILTERS, NOMINALS, did_you_mean, resolve
from scenarios import get
from scenarios.api import MujocoContact
from scenarios.run import USAGE_ERROR
from softcbf.cli import main


def test_the_closest_names_and_nothing_for_a_stranger():
    assert did_you_mean("c-egr", ["paper-cbf", "none", "qsg", "e-erg", "c-erg"]) == " (did you mean 'c-erg', 'e-erg'?)"
    assert did_you_mean("paper_sm", ["camera_loop", "mujoco_contact", "paper_sim"]) == " (did you mean 'paper_sim'?)"
    assert did_you_mean("zzz", ["camera_loop", "mujoco_contact", "paper_sim"]) == ""


def test_registry_lookups_say_did_you_mean():
    with pytest.raises(ValueError, match=r"unknown name 'c-egr' \(did you mean 'c-erg'"):
        resolve("c-egr", FILTERS)
    with pytest.raises(ValueError, match=r"unknown name 'sinusiod' \(did you mean 'sinusoid'\?\)"):
        resolve("sinusiod", NOMINALS)
    with pytest.raises(KeyError, match=r"unknown scenario 'mujoco_contat' \(did you mean 'mujoco_contact', 'pcc_contact'\?\)"):
        get("mujoco_contat")
    with pytest.raises(ValueError, match=r"no parameter 'amplitdue' \(did you mean 'amplitude'"):
        MujocoContact.from_flat({"amplitdue": 100.0})


@pytest.mark.parametrize("argv, suggestion", [
    (["rnu", "paper_sim"], "unknown command 'rnu' (did you mean 'run'?)"),
    (["run", "paper_sm"], "unknown scenario 'paper_sm' (did you mean 'paper_sim'?)"),
    (["run", "mujoco_contact", "--filter", "c-egr"], "unknown name 'c-egr' (did you mean 'c-erg', 'e-erg'?)"),
    (["run", "mujoco_contact", "--nominal", "sinusiod"], "unknown name 'sinusiod' (did you mean 'sinusoid'?)"),
    (["run", "mujoco_contact", "--amplitdue", "3"], "(did you mean '--amplitude'"),
])
def test_the_command_line_says_did_you_mean_in_one_line(argv, suggestion, capsys, tmp_path):
    assert main([*argv, "--out", str(tmp_path / "out")]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert suggestion in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()
