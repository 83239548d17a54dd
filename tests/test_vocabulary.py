"""One vocabulary of settings (vocabulary.settings, vocabulary.files): a setting given on the
command line, in a run configuration, in a study's fixed table or in the hardware file reaches
the same check with the same message; the hardware file's former spellings load to the same
configuration with one warning line; the file reader and the exit codes are shared."""

from __future__ import annotations

import argparse
import ast
import json
import math
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from hardware.config import LEGACY_KEYS, ConfigError, HardwareConfig
from hardware.protocol import PRESSURE_RANGE_HPA
from scenarios.run import INTERRUPTED, USAGE_ERROR, UsageError, exit_code
from softcbf.cli import main
from softcbf.study.definition import load_study
from vocabulary.files import read_settings_file
from vocabulary.settings import SETTINGS, Bound, SettingError, check_number, check_value
from controllers.contract.filter_parameters import Params

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "hardware_emulated.toml"
STUDY = 'name = "one"\nscenario = "{scenario}"\nsampling = "monte_carlo"\ndraws = 1\ntunings = ["Low"]\n'
# examples/hardware_emulated.toml as written before the one vocabulary (every shared key in its former spelling)
LEGACY_EXAMPLE = """\
[camera]
source = "virtual"
tag_size_m = 0.03
detector = "opencv"
max_hold_s = 0.3
fps = 12.8
width = 480
height = 270

[robot]
params = "hardware_slow_arm_robot.json"

[environment]
H = [[0.36, 1.0]]
h = [0.15]
stiffness_N_per_m = 11.16
f_max_N = 0.16
row_scaling = "paper"

[pressure]
u_min_hPa = -150.0
u_max_hPa = 150.0

[control]
tuning = "High"
rate_hz = 10.0
pressure_limits = true
amplitude_hPa = 80.0
frequency_hz = 0.05
phase_rad = 0.0

[safety]
hold_s = 0.5
watchdog_s = 0.15

[link]
port = "emulated"
ack_timeout_s = 0.02
retries = 2

[run]
duration_s = 8.0
dry_run = false

[emulator]
plate_stiffness_N_per_m = 11.16
tau_p_s = 0.05
q0_rad = 0.0
"""


def _hardware_file(folder: Path, lines: str) -> Path:
    """The emulated example with `lines` (top-level settings) put first, in `folder` with its robot file."""
    shutil.copy(EXAMPLE.parent / "hardware_slow_arm_robot.json", folder)
    text = EXAMPLE.read_text(encoding="utf-8")
    for name in SETTINGS:  # the example's own line for a setting `lines` gives
        if any(line.split("=")[0].strip() == name for line in lines.splitlines()):
            text = "\n".join(line for line in text.splitlines() if line.split("=")[0].strip() != name) + "\n"
    path = folder / "hw.toml"
    path.write_text(lines + text, encoding="utf-8")
    return path


@pytest.mark.parametrize(("name", "toml", "option", "scenario", "message"), [
    ("f_max", "-1", "-1", "paper_sim", "f_max must be > 0 N, got -1.0"),
    ("control_rate", "1e6", "1e6", "paper_sim",
     "control_rate must be <= 10000 Hz (a plausibility bound), got 1000000.0"),
    ("duration", "1e6", "1e6", "paper_sim",
     "duration must be <= 86400 s (a plausibility bound; a value in ms? 1e+06 ms = 1000 s), got 1000000.0"),
    ("tau_p", "50", "50", "mujoco_contact",
     "tau_p must be <= 5 s (a plausibility bound; a value in ms? 50 ms = 0.05 s), got 50.0"),
])
def test_a_setting_reaches_the_same_check_from_every_source(tmp_path, capsys, name, toml, option, scenario, message):
    # the vocabulary itself
    with pytest.raises(SettingError) as raised:
        check_value(name, tomllib.loads(f"v = {toml}")["v"])
    assert str(raised.value) == message
    # the command line
    assert main(["run", scenario, f"--{name.replace('_', '-')}", option, "--out", str(tmp_path / "cli")]) == USAGE_ERROR
    assert capsys.readouterr().err == f"error: {message}\n"
    # a run configuration
    run_toml = tmp_path / "run.toml"
    run_toml.write_text(f'scenario = "{scenario}"\n{name} = {toml}\n', encoding="utf-8")
    assert main(["run", "--config", str(run_toml), "--out", str(tmp_path / "file")]) == USAGE_ERROR
    assert capsys.readouterr().err == f"error: {message}\n"
    # a study's fixed table (the study names the sample it refuses, then the same message)
    study = tmp_path / "study.toml"
    study.write_text(STUDY.format(scenario=scenario), encoding="utf-8")
    with pytest.raises(ValueError) as raised:
        load_study(study, [f"fixed.{name}={toml}"])
    assert str(raised.value).endswith(f": {message}")
    # the hardware file and the hardware command line
    hardware = _hardware_file(tmp_path, f"{name} = {toml}\n")
    with pytest.raises(ConfigError) as raised:
        HardwareConfig.load(hardware)
    assert str(raised.value) == message
    assert main(["hardware", str(EXAMPLE), f"--{name.replace('_', '-')}", option, "--out", str(tmp_path / "hw")]) == USAGE_ERROR
    assert capsys.readouterr().err == f"error: {message}\n"
    assert not any((tmp_path / out).exists() for out in ("cli", "file", "hw"))


def test_former_hardware_keys_load_to_the_same_configuration_with_one_warning(tmp_path, capsys):
    shutil.copy(EXAMPLE.parent / "hardware_slow_arm_robot.json", tmp_path)
    legacy = tmp_path / "legacy.toml"
    legacy.write_text(LEGACY_EXAMPLE, encoding="utf-8")
    current = HardwareConfig.load(EXAMPLE)
    assert capsys.readouterr().err == ""
    old = HardwareConfig.load(legacy)
    err = capsys.readouterr().err
    assert old.to_dict() == current.to_dict()
    assert err.count("\n") == 1 and err.startswith(f"warning: hardware configuration {legacy}: former key(s) ")
    for key, name in LEGACY_KEYS.items():
        if f"\n{key.split('.')[1]} = " in LEGACY_EXAMPLE:
            assert f"{key} -> {name}" in err
    assert "environment.f_max_N -> f_max" in err and "control.rate_hz -> control_rate" in err
    # the former spelling is checked as the setting
    legacy.write_text(LEGACY_EXAMPLE.replace("f_max_N = 0.16", "f_max_N = -1"), encoding="utf-8")
    with pytest.raises(ConfigError, match=r"^f_max must be > 0 N, got -1.0$"):
        HardwareConfig.load(legacy)
    # both spellings of one setting: refused, naming both
    with pytest.raises(ConfigError, match=r"f_max is given twice: as f_max and as its former spelling environment.f_max_N"):
        HardwareConfig.from_dict({"f_max": 0.2, "environment": {"f_max_N": 0.16}}, tmp_path)


def test_the_hardware_command_line_overrides_the_shared_settings_of_the_file(tmp_path):
    from softcbf.hardware_cli import add_arguments, configure

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    args = parser.parse_args([str(EXAMPLE), "--f-max", "0.2", "--control-rate", "12.5", "--duration", "3",
                              "--frame-rate", "25", "--tau-p", "0.1", "--pressure-limits", "false",
                              "--filter", "e-erg", "--filter-param", "margin_m=0.001", "--robot", "reference"])
    config = configure(args)
    file = HardwareConfig.load(EXAMPLE)
    assert (config.environment.f_max, config.control.control_rate, config.run.duration) == (0.2, 12.5, 3.0)
    assert (config.camera.frame_rate, config.emulator.tau_p, config.control.pressure_limits) == (25.0, 0.1, False)
    assert config.control.filter == "e-erg" and config.control.filter_params == {"margin_m": "0.001"}
    assert config.robot.robot == "reference" and file.robot.robot == "hardware_slow_arm_robot.json"
    # what the command line does not name keeps the file's value
    assert (config.environment.assumed_plate_stiffness, config.control.frequency, config.control.tuning) == (
        file.environment.assumed_plate_stiffness, file.control.frequency, file.control.tuning)


def test_check_value_normalises_and_refuses_by_kind():
    assert check_value("f_max", 1) == 1.0 and isinstance(check_value("f_max", 1), float)
    assert check_value("seed", 10**30) == 10**30  # ints stay exact
    assert check_value("filter", "e-erg") == "e-erg" and check_value("progress", False) is False
    for name, value, message in [
        ("f_max", True, "f_max must be a number > 0 N, got True"),
        ("f_max", "0.1", "f_max must be a number > 0 N, got '0.1'"),
        ("f_max", math.inf, "f_max must be finite and > 0 N, got inf"),
        ("t0", math.nan, "t0 must be finite, got nan"),
        ("seed", 1.0, "seed must be an integer >= 0, got 1.0"),
        ("seed", -1, "seed must be >= 0, got -1"),
        ("progress", "yes", "progress must be true or false, got 'yes'"),
        ("filter", 3, "filter must be a str (a built-in filter (softcbf list: paper-cbf, none, c-erg, ...), "
                      "a preset (c-erg:recommended), FILE.py:Factory or package.module:Factory), got 3"),
        ("amplitude", -5000, "amplitude must be within ±3276.7 hPa (a plausibility bound; a value in Pa? "
                             "-5000 Pa = -50 hPa), got -5000.0"),
        ("drop_rate", 1.0, "drop_rate must be in [0, 1), got 1.0"),
    ]:
        with pytest.raises(SettingError) as raised:
            check_value(name, value)
        assert str(raised.value) == message, name
    with pytest.raises(SettingError, match=r"^amplitude\[1\] must be"):
        check_value("amplitude", 4000.0, "amplitude[1]")
    with pytest.raises(KeyError, match="no_such"):
        check_value("no_such", 1.0)
    # the check for hardware-only numbers is the same code
    assert check_number("x", 2, Bound(0.0, low_open=True, unit="s"), plausible=5.0, unit="s") == 2.0
    with pytest.raises(SettingError, match=r"^x must be <= 5 s \(a plausibility bound; a value in ms\? 150 ms = 0.15 s\), got 150.0$"):
        check_number("x", 150, Bound(0.0, low_open=True, unit="s"), plausible=5.0, unit="s")


def test_every_setting_is_declared_completely():
    for name, declared in SETTINGS.items():
        assert declared.meaning and declared.kind in (float, int, bool, str, tuple, Params), name  # Params: a plug-in's
        assert declared.flat_kind in (float, int, bool, str, Params), name  # what the command line and files take
        assert check_value(name, declared.default) == declared.default or declared.default is None, name
        assert (declared.bound is not None) == (declared.kind in (float, int)), name
        assert declared.valid_values, name
        assert declared.plausible is None or declared.plausible > 0, name
        if declared.bound is not None and declared.bound.unit:
            assert declared.bound.unit == declared.unit, name
    assert SETTINGS["amplitude"].plausible == PRESSURE_RANGE_HPA  # the valve protocol's range


def test_the_vocabulary_needs_only_the_standard_library():
    """The vocabulary and the modules of the controllers it takes from (controllers.core.bounds, its ranges;
    controllers.contract.filter_parameters, a plug-in's parameters as a typed mapping;
    controllers.model.paper_experiment, the paper's plate stiffness and force limit; and their rooms' `__init__`)
    import the standard library only (and the latter the former), and importing it loads no third-party module."""
    from_controllers = ("controllers.core.bounds", "controllers.contract.filter_parameters",
                        "controllers.model.paper_experiment")
    modules = [ROOT.joinpath(*m.split(".")).with_suffix(".py") for m in from_controllers]
    rooms = [ROOT.joinpath(*m.split(".")[:2], "__init__.py") for m in from_controllers]
    for path in (*(ROOT / "vocabulary").glob("*.py"), *modules, *rooms):
        for line in path.read_text(encoding="utf-8").splitlines():
            if line.startswith(("import ", "from ")):
                module = line.split()[1]
                top = module.split(".")[0]
                assert top in sys.stdlib_module_names or top in ("__future__", "vocabulary") or \
                    (path.stem != "bounds" and module in from_controllers), (path.name, line)
    loaded = subprocess.run([sys.executable, "-c", "import sys; before = set(sys.modules); "
                             "import vocabulary.settings, vocabulary.files; print(sorted({m.split('.')[0] for m in "
                             "set(sys.modules) - before} - set(sys.stdlib_module_names)))"],
                            cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert set(ast.literal_eval(loaded)) <= {"vocabulary", "controllers"}, loaded


def test_one_reader_for_every_settings_file(tmp_path):
    class MyError(ValueError):
        pass

    (tmp_path / "a.toml").write_text("x = 1\n[t]\ny = 2\n", encoding="utf-8")
    (tmp_path / "a.json").write_text(json.dumps({"x": 1, "t": {"y": 2}}), encoding="utf-8")
    assert read_settings_file(tmp_path / "a.toml", "thing") == read_settings_file(tmp_path / "a.json", "thing")
    cases = [("missing.toml", None, f"thing {tmp_path / 'missing.toml'} does not exist (hint)"),
             ("a.yaml", "x: 1", f"thing {tmp_path / 'a.yaml'} must end in .toml or .json, got '.yaml'"),
             ("bad.toml", "x = ", f"thing {tmp_path / 'bad.toml'} is not valid TOML: "),
             ("bad.json", "{", f"thing {tmp_path / 'bad.json'} is not valid JSON: "),
             ("list.json", "[1, 2]", f"thing {tmp_path / 'list.json'} must hold a table of settings at its top level, got list")]
    for name, text, message in cases:
        if text is not None:
            (tmp_path / name).write_text(text, encoding="utf-8")
        with pytest.raises(MyError) as raised:
            read_settings_file(tmp_path / name, "thing", MyError, missing_hint="hint")
        assert str(raised.value).startswith(message), name
    # the run configuration, the hardware configuration and the study file read through it
    for command in (["run", "--config", str(tmp_path / "bad.toml")], ["hardware", str(tmp_path / "bad.toml")],
                    ["study", "run", str(tmp_path / "bad.toml")]):
        assert main(command) == USAGE_ERROR


def test_one_exit_code_wrapper(tmp_path, capsys):
    def usage() -> int:
        raise UsageError("bad --x")

    def interrupted() -> int:
        raise KeyboardInterrupt

    assert exit_code(lambda: 0) == 0 and capsys.readouterr().err == ""
    assert exit_code(usage) == USAGE_ERROR and capsys.readouterr().err == "error: bad --x\n"
    assert exit_code(interrupted) == INTERRUPTED and capsys.readouterr().err == "\ninterrupted\n"
    from scenarios.__main__ import main as scenarios_main

    assert scenarios_main(["paper_sim", "--f-max", "-1", "--out", str(tmp_path / "out")]) == USAGE_ERROR
    assert capsys.readouterr().err == "error: f_max must be > 0 N, got -1.0\n" and not (tmp_path / "out").exists()


def test_one_section_machinery_for_the_scenarios_and_the_hardware_file():
    """vocabulary.sections makes both the scenarios' sections and the hardware file's: each shared setting of
    a hardware section is a setting field (its type the vocabulary's kind, its default the hardware's)."""
    import dataclasses

    from hardware import config as hardware
    from vocabulary.sections import SETTING, setting_fields
    from vocabulary.settings import default

    for name, cls in {"camera": hardware.CameraConfig, "control": hardware.ControlConfig,
                      "emulator": hardware.EmulatorConfig, "environment": hardware.EnvironmentConfig}.items():
        fields = {f.name: f for f in dataclasses.fields(cls)}
        for field_name, key in setting_fields(cls).items():
            assert hardware.SHARED_KEYS[key] == name and fields[field_name].metadata[SETTING] == key
            if fields[field_name].metadata["table"]:
                assert fields[field_name].default_factory() == {}
            else:
                assert fields[field_name].default == default(key, "hardware"), key
    assert set(hardware.SHARED_KEYS) == {key for cls in (hardware.CameraConfig, hardware.RobotConfig,
                                                          hardware.EnvironmentConfig, hardware.ControlConfig,
                                                          hardware.SafetyConfig, hardware.RunConfig,
                                                          hardware.EmulatorConfig)
                                          for key in setting_fields(cls).values()}


def test_a_section_checks_single_per_segment_table_and_unconfigured_values():
    import dataclasses

    from vocabulary.sections import UNSET, setting_section

    class Bad(ValueError):
        pass

    @setting_section(settings={"f_max": "f_max", "amplitude": "amplitude", "filter_params": "filter_params",
                               "calibration": "calibration"},
                     context="hardware", per_segment=("amplitude",), tables=("filter_params",), error=Bad)
    class Part:
        label: str = "x"

        def check(self) -> None:
            if self.label == "":
                raise Bad("label must not be empty")

    part = Part(f_max=1, amplitude=[10, 20.5], filter_params={"kappa": 2.0})
    assert part.f_max == 1.0 and type(part.f_max) is float and part.amplitude == (10.0, 20.5)
    assert part.filter_params == {"kappa": 2.0} and part.calibration is None and part.label == "x"
    assert [f.name for f in dataclasses.fields(Part)] == ["label", "f_max", "amplitude", "filter_params", "calibration"]
    with pytest.raises(Bad, match=r"f_max must be a single value, got \[1.0, 2.0\]"):
        Part(f_max=[1.0, 2.0])
    with pytest.raises(Bad, match=r"amplitude\[1\] must be within"):
        Part(amplitude=[1.0, 1e6])
    with pytest.raises(Bad, match="amplitude must be a number or a non-empty list of numbers, got \\[\\]"):
        Part(amplitude=[])
    with pytest.raises(Bad, match="filter_params must be a table of name = value"):
        Part(filter_params="kappa=2")
    with pytest.raises(Bad, match="label must not be empty"):
        Part(label="")
    with pytest.raises(dataclasses.FrozenInstanceError):
        part.f_max = 2.0

    @setting_section(settings={"params": "filter_params", "f_max": "f_max"})
    class Scenario:
        pass

    given = Scenario(params={"kappa": 2.0})
    assert given.params == {"kappa": 2.0} and given.f_max is UNSET  # a plug-in's parameters: a frozen mapping
    with pytest.raises(SettingError, match="calibration must be a str"):
        setting_section(type("NoNone", (), {}), settings={"calibration": "calibration"})(calibration=None)
