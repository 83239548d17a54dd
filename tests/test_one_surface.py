"""One configuration surface: a new ground-truth setting is one vocabulary entry plus its use in `build_truth`.

The fixture's script (run in a child process, so that the setting exists before any section,
spec or configuration class is made from the vocabulary, as a real entry would) declares the
setting `true_mass_scale` of section "TrueArm" and uses it in `softcbf_mj.physics.ground_truth.build_truth`
(the true arm's masses × the scale); nothing else is edited. It then gives the setting on every
surface and records what `build_truth` received: the command line (`softcbf run mujoco_contact
--true-mass-scale`), a TOML run file, a study's `vary`, the environment (`ArmEnvConfig`,
`make_environment`, `GymArmEnv` keywords), the hardware file and its emulator.

Also here: the environment's `control_rate` (Hz) and its former `control_dt` (s), read with a
DeprecationWarning that names the new keyword.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

SCRIPT = textwrap.dedent('''
    import dataclasses, json, sys
    from pathlib import Path

    from vocabulary import settings as vocabulary

    vocabulary.SETTINGS["true_mass_scale"] = vocabulary.Setting(
        "the MuJoCo arm's masses as a multiple of the robot's", "", float, vocabulary.Bound(1e-3, 1e3), default=1.0,
        section="TrueArm")

    from softcbf_mj.physics import ground_truth

    original = ground_truth.build_truth
    seen = []

    def build_truth(arm, plate, model_robot, environment, damping_scale):
        seen.append(arm.true_mass_scale)
        truth = original(arm, plate, model_robot, environment, damping_scale)
        robot = truth.config.robot
        heavier = robot.replace(masses=tuple(m * arm.true_mass_scale for m in robot.masses))
        return dataclasses.replace(truth, config=dataclasses.replace(truth.config, robot=heavier))

    ground_truth.build_truth = build_truth

    from hardware.config import HardwareConfig
    from softcbf.cli import main
    from softcbf.study.definition import load_study
    from softcbf.study.runner import run_sample
    from softcbf_mj.emulator.emulate import emulated_truth
    from softcbf_mj.env import ArmEnvConfig, GymArmEnv, make_environment

    tmp = Path(sys.argv[1])
    quick = ["--duration", "0.02", "--tunings", "None", "--progress", "false", "--links-per-segment", "2", "--data-only"]
    reached = {}

    results = {}

    def reach(surface, do):
        seen.clear()
        results[surface] = do()
        reached[surface] = list(seen)

    reach("cli", lambda: main(["run", "mujoco_contact", "--true-mass-scale", "1.5", *quick, "--out", str(tmp / "cli")]))
    (tmp / "run.toml").write_text('scenario = "mujoco_contact"\\ntrue_mass_scale = 1.25\\nduration = 0.02\\n'
                                  'tunings = "None"\\nprogress = false\\nlinks_per_segment = 2\\n', encoding="utf-8")
    reach("toml", lambda: main(["run", "--config", str(tmp / "run.toml"), "--out", str(tmp / "toml"), "--data-only"]))
    recorded = json.loads((tmp / "toml" / "config.json").read_text(encoding="utf-8"))["params"]["true_mass_scale"]
    (tmp / "study.toml").write_text('name = "surfaces"\\nscenario = "mujoco_contact"\\ntunings = ["None"]\\ndraws = 1\\n'
                                    '[fixed]\\nduration = 0.02\\nlinks_per_segment = 2\\n'
                                    '[vary.true_mass_scale]\\ndist = "choice"\\nvalues = [2.0]\\n',
                                    encoding="utf-8")
    study = load_study(tmp / "study.toml")
    reach("study", lambda: run_sample(study, 0))
    fast = dict(control_rate=100.0, physics_dt=2e-4, links_per_segment=2)
    config = ArmEnvConfig(true_mass_scale=0.5, **fast)
    reach("env", config.plant)
    reach("make_environment", lambda: make_environment(true_mass_scale=0.75, **fast))
    reach("gym", lambda: GymArmEnv(true_mass_scale=0.8, **fast).close())
    (tmp / "hardware.toml").write_text('true_mass_scale = 3.0\\n[link]\\nport = "emulated"\\n[camera]\\nsource = "virtual"\\n',
                                       encoding="utf-8")
    hardware = HardwareConfig.load(tmp / "hardware.toml")
    reach("emulator", lambda: emulated_truth(hardware))
    heavier = emulated_truth(hardware).robot.masses
    print(json.dumps({"reached": reached, "cli": results["cli"], "toml": results["toml"],
                      "study": results["study"]["status"], "recorded": recorded, "hardware_file": hardware.to_dict()["true_mass_scale"],
                      "env_field": config.true_mass_scale, "masses": list(heavier)}))
''')


@pytest.mark.slow
def test_a_new_ground_truth_setting_reaches_every_surface(tmp_path):
    script = tmp_path / "surfaces.py"
    script.write_text(SCRIPT, encoding="utf-8")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    result = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True, timeout=600,
                            cwd=tmp_path, env=env)
    assert result.returncode == 0, result.stderr[-3000:]
    out = json.loads(result.stdout.strip().splitlines()[-1])
    assert out["reached"] == {"cli": [1.5], "toml": [1.25], "study": [2.0], "env": [0.5], "make_environment": [0.75],
                              "gym": [0.8], "emulator": [3.0]}
    assert (out["cli"], out["toml"], out["study"]) == (0, 0, "ok")
    assert out["recorded"] == 1.25 and out["hardware_file"] == 3.0 and out["env_field"] == 0.5
    from controllers.model.params import reference_robot

    assert out["masses"] == pytest.approx([3.0 * m for m in reference_robot().masses])


def test_the_environment_takes_its_control_rate_in_hz():
    from softcbf_mj.env import ArmEnvConfig

    config = ArmEnvConfig(control_rate=100.0)
    assert config.control_rate == 100.0 and config.control_dt == 0.01
    assert ArmEnvConfig().control_rate == 1000.0 and ArmEnvConfig().control_dt == 1e-3  # the paper's 1 kHz
    with pytest.raises(ValueError, match=r"control_rate must be > 0 Hz, got -5.0"):
        ArmEnvConfig(control_rate=-5.0)


def test_the_environment_s_former_control_dt_is_read_with_a_deprecation_warning():
    import dataclasses

    from softcbf_mj.env import ArmEnvConfig

    with pytest.warns(DeprecationWarning, match=r"control_dt \(s\) is deprecated .* give control_rate \(Hz\)"):
        config = ArmEnvConfig(control_dt=0.01)
    assert config.control_rate == 100.0 and config.control_dt == 0.01
    with pytest.warns(DeprecationWarning, match="control_rate=500"):
        assert dataclasses.replace(config, control_dt=2e-3).control_rate == 500.0
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # refused before it warns
        with pytest.raises(ValueError, match=r"control_dt must be > 0 s, got -1.0"):
            ArmEnvConfig(control_dt=-1.0)


def test_the_former_ground_truth_module_reads_its_names_with_a_deprecation_warning():
    import scenarios.ground_truth as former
    from controllers.model.safe_set import paper_environment
    from softcbf_mj.physics import ground_truth
    from vocabulary.run_sections import Model, Plate, TrueArm

    with pytest.warns(DeprecationWarning, match="use softcbf_mj.physics.ground_truth.moved_facets"):
        assert former.moved_facets is ground_truth.moved_facets
    spec = __import__("scenarios").get("mujoco_contact").spec(arm=TrueArm(facet_offset=0.002), plate=Plate(stiffness=9.0),
                                                             model=Model(damping_scale=2.0))
    with pytest.warns(DeprecationWarning, match="scenarios.ground_truth.build_truth is deprecated"):
        truth = former.build_truth(spec.arm, spec.plate, spec.model, spec.built.robot, paper_environment())
    expected = ground_truth.build_truth(spec.arm, spec.plate, spec.built.robot, paper_environment(), 2.0)
    assert truth.config == expected.config and truth.plate_stiffness == expected.plate_stiffness == 9.0
    with pytest.raises(AttributeError, match="has no attribute 'nothing'"):
        former.nothing  # noqa: B018
