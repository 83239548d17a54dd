"""Parameters that explain themselves and configuration files with one vocabulary:
vocabulary.settings (every parameter documented; the hardware file's shared keys are
parameter names, its former spellings mapped onto them), `softcbf run NAME --help`, `softcbf run --config FILE.toml|config.json`
(overrides, bit-for-bit replay) and `softcbf study run FILE --set KEY=VALUE`."""

import importlib.util
import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from hardware.config import LEGACY_KEYS, SHARED_KEYS, default_values
from scenarios import registry
from scenarios.config_file import load_run_config
from scenarios.run import USAGE_ERROR
from softcbf.cli import main
from softcbf.study.definition import apply_settings, load_study, parse_setting
from softcbf_mj.outputs.runio import load_timeseries
from vocabulary.settings import SETTINGS, setting
from vocabulary.sections import joined

ROOT = Path(__file__).resolve().parents[1]
# --data-only: these tests read config.json and the time series, not the plots (tests/test_run_outputs.py)
SHORT = ["--duration", "0.3", "--tunings", "Low", "--amplitude", "150", "--frequency", "0.5", "--progress", "false",
         "--data-only"]
TIMING_COLUMNS = ("filter_us", "solve_us")  # wall-clock measurements, not outputs of the simulation
# Former hardware key suffix → the unit its setting must be documented in.
SUFFIX_UNITS = (("_N_per_m", "N/m"), ("_N", "N"), ("_s", "s"), ("_hz", "Hz"), ("_hPa", "hPa"))
# Hardware defaults that differ from camera_loop's (the MuJoCo twin of the hardware run) on purpose.
HARDWARE_DEFAULTS_DIFFER = {"width": "the real camera's 480 px vs the render's 1280", "height": "270 px vs 720",
                            "filter_params": "a table vs a string", "nominal_params": "a table vs a string",
                            "calibration": "a JSON file (none: the virtual camera's exact map) vs 'board'"}


def test_every_scenario_parameter_is_documented_and_every_entry_is_used():
    used = set()
    for scenario in registry().values():
        for name in scenario.parameters():
            doc = setting(name)
            assert doc.meaning and scenario.valid(name), (scenario.name, name)
            used.add(name)
    assert set(SETTINGS) == used


def test_bounded_parameters_are_documented_in_their_bound_s_unit():
    for scenario in registry().values():
        for name, bound in scenario.bounds.items():
            unit = setting(name).unit
            assert bound.unit.split(" ")[0] in ("", unit) or bound.unit.startswith("("), (scenario.name, name, bound.unit)
            assert scenario.valid(name) == str(bound)


def test_valid_values_come_from_the_scenario_s_narrower_bound_then_the_declaration():
    paper, camera = registry()["paper_sim"], registry()["camera_loop"]
    assert paper.valid("f_max") == "> 0 N" and paper.valid("q0_std") == "in [0, 3.14159] rad"
    assert paper.valid("integrator") == "ros2, rk4, euler"
    assert paper.valid("amplitude") == "finite, plausibly within ±3276.7 hPa"
    assert camera.valid("width") == "in [16, 1280] px" and setting("width").valid_values == ">= 8 px"
    with pytest.raises(KeyError, match="no_such"):
        setting("no_such")


# Scenario parameters whose bound value is valid only with another parameter set to suit it (a cross-parameter
# check, named in its own message): the control period must be a whole number of camera_loop's ticks, and
# table friction's explicit integration is stable only below 2 v_s / (g dt) (docs/parameters.md).
BOUND_COMPANIONS = {("camera_loop", "control_rate"): {"tick": 1e-4, "physics_dt": 1e-4},
                    ("camera_loop", "table_friction"): {"physics_dt": 1e-4}}
SINUSOID_CONTEXT = None


def _accepts(scenario, name: str, value) -> tuple[bool, str]:
    """Whether the checks a run makes before it runs accept parameter `name` = `value`: the scenario's own
    (`Scenario.validate`) and, where the scenario hands its sinusoid parameters to the nominal, the nominal's
    own check when it is built (the cause of issue 27: `--frequency 0` passed the first and failed the second)."""
    from controllers.model.params import reference_robot
    from controllers.registry import build_nominal
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import FilterContext
    from scenarios.common import nominal_arguments

    try:
        spec = scenario.build({**BOUND_COMPANIONS.get((scenario.name, name), {}), name: value})
        context = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)
        build_nominal(spec.nominal.name, nominal_arguments(spec.nominal), context)
    except ValueError as exc:
        return False, str(exc)
    return True, ""


def _printed_bound_values(scenario, name: str):
    """(value, accepted as printed) at each end of the bound `softcbf list` prints for the parameter, and just beyond."""
    bound = scenario.bounds.get(name) or setting(name).bound
    if bound is None:
        return
    assert str(bound) in scenario.valid(name)
    integer = setting(name).kind is int

    def beyond(value, direction):
        return value + direction if integer else float(np.nextafter(value, direction * np.inf))

    ends = [(bound.low, bound.low_open, -1), (bound.high, bound.high_open, +1)]
    plausible = setting(name).plausible if name not in scenario.bounds else None
    if plausible is not None:
        assert f"{plausible:g}" in scenario.valid(name)
        ends += [(plausible, False, +1)] + ([(-plausible, False, -1)] if bound.low is None or bound.low < 0 else [])
    for value, is_open, direction in ends:
        if value is None or (integer and value != int(value)):
            continue
        value = int(value) if integer else float(value)
        yield value, not is_open
        yield beyond(value, direction), False


@pytest.mark.parametrize("scenario_name", sorted(registry()))
def test_every_printed_bound_value_is_accepted_or_refused_exactly_as_printed(scenario_name):
    """Issue 27: `softcbf list` printed frequency ">= 0 Hz" and `--frequency 0` was refused. At each printed bound
    (and plausibility bound) the value itself is accepted where the bound is closed and refused where it is open,
    and the value just beyond it is refused, naming the parameter."""
    scenario = registry()[scenario_name]
    wrong, checked = [], 0
    for name in scenario.parameters():
        for value, expected in _printed_bound_values(scenario, name):
            accepted, message = _accepts(scenario, name, value)
            checked += 1
            if accepted != expected or (not accepted and name not in message):
                wrong.append(f"--{name.replace('_', '-')} {value!r}: printed '{scenario.valid(name)}', "
                             f"{'accepted' if accepted else 'refused: ' + message}")
    assert checked >= 20 and not wrong, "\n".join(wrong)


def _unit_of_suffix(key: str) -> str | None:
    return next((unit for suffix, unit in SUFFIX_UNITS if key.endswith(suffix)), None)


def test_the_hardware_file_spells_every_shared_setting_by_its_parameter_name():
    hardware_defaults = default_values()
    scenario_defaults = registry()["camera_loop"].defaults()
    # every key of the hardware file is a documented parameter name or a hardware-only "section.key"
    for key in hardware_defaults:
        assert key in SETTINGS or ("." in key and key.split(".")[1] not in SETTINGS), key
    assert set(SHARED_KEYS) == {key for key in hardware_defaults if key in SETTINGS}
    # no second spelling left but the table of former keys, which names a shared setting at most once (the
    # ground-truth settings the emulator gained with the one vocabulary never had another spelling)
    former = sorted(LEGACY_KEYS.values())
    assert not set(LEGACY_KEYS) & set(hardware_defaults) and set(former) <= set(SHARED_KEYS)
    assert len(set(former)) == len(former)
    for key, name in LEGACY_KEYS.items():
        unit = _unit_of_suffix(key)
        assert unit is None or SETTINGS[name].unit == unit, (key, name, SETTINGS[name].unit)
    for name in SHARED_KEYS:
        if name not in HARDWARE_DEFAULTS_DIFFER:
            assert hardware_defaults[name] == scenario_defaults[name], name


def test_list_and_run_help_show_meaning_unit_and_valid_values(capsys):
    assert main(["list"]) == 0
    listed = capsys.readouterr().out
    assert "    --f-max float (default 0.16) [N]: force limit F_max per facet; valid: > 0 N" in listed
    assert main(["run", "paper_sim", "--help"]) == 0
    out = capsys.readouterr().out
    assert "--config FILE" in out
    for name in registry()["paper_sim"].parameters():
        line = next(line for line in out.splitlines() if line.startswith(f"    --{name.replace('_', '-')} "))
        assert f": {SETTINGS[name].meaning}; valid: " in line
    assert "mujoco_contact" not in out
    assert main(["run", "--data-only", "--config", str(ROOT / "docs" / "examples" / "run.toml"), "--help"]) == 0
    out = capsys.readouterr().out
    assert "paper_sim: " in out and "mujoco_contact" not in out
    assert main(["run", "no_such", "--help"]) == USAGE_ERROR
    assert "unknown scenario 'no_such'" in capsys.readouterr().err


def test_toml_run_configuration_with_command_line_overrides(tmp_path, capsys):
    config = tmp_path / "run.toml"
    config.write_text('scenario = "paper_sim"\nduration = 0.2\ntunings = "None,Low"\nprogress = false\n'
                      'amplitude = 150\n[filter_params]\nslack_weight = 1e4\n', encoding="utf-8")
    loaded = load_run_config(config)
    assert loaded.scenario == "paper_sim"
    assert loaded.params == {"duration": 0.2, "tunings": "None,Low", "progress": False, "amplitude": 150,
                             "filter_params": {"slack_weight": 1e4}}
    out = tmp_path / "out"
    assert main(["run", "--data-only", "--config", str(config), "--tunings", "Low", "--filter-param", "recovery_margin=0.002",
                 "--out", str(out)]) == 0
    params = json.loads((out / "config.json").read_text(encoding="utf-8"))["params"]
    assert params["duration"] == 0.2 and params["amplitude"] == 150.0 and params["tunings"] == "Low"
    assert params["filter_params"] == {"recovery_margin": 0.002, "slack_weight": 1e4}
    assert [p.name for p in (out / "timeseries").iterdir()] == ["Low.npz"]


@pytest.mark.parametrize("text, message", [
    ('duration = 1.0\n', 'needs scenario = "NAME"'),
    ('scenario = "paper_sim"\nduration = "long"\n', "parameter 'duration' takes float values, got 'long'"),
    ('scenario = "paper_sim"\nno_such = 1\n', "has no parameter 'no_such'"),
    ('scenario = "paper_sim"\nduration = [1, 2]\n', "duration must be a single value"),
    ('scenario = "paper_sim"\nduration = \n', "is not valid TOML"),
])
def test_bad_run_configuration_is_a_usage_error_naming_the_key(tmp_path, capsys, text, message):
    config = tmp_path / "run.toml"
    config.write_text(text, encoding="utf-8")
    assert main(["run", "--config", str(config), "--out", str(tmp_path / "out")]) == USAGE_ERROR
    assert message in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_scenario_and_config_must_agree(tmp_path, capsys):
    config = tmp_path / "run.toml"
    config.write_text('scenario = "paper_sim"\n', encoding="utf-8")
    assert main(["run", "mujoco_contact", "--config", str(config)]) == USAGE_ERROR
    assert "is for 'paper_sim'" in capsys.readouterr().err
    assert main(["run", "--config", str(tmp_path / "missing.toml")]) == USAGE_ERROR
    assert "does not exist" in capsys.readouterr().err


@pytest.mark.slow
def test_replaying_a_run_folder_reproduces_its_time_series_bit_for_bit(tmp_path, capsys):
    first, replay = tmp_path / "first", tmp_path / "replay"
    assert main(["run", "paper_sim", *SHORT, "--seed", "3", "--q0-std", "0.05", "--out", str(first)]) == 0
    assert main(["run", "--data-only", "--config", str(first / "config.json"), "--out", str(replay)]) == 0
    configs = [json.loads((d / "config.json").read_text(encoding="utf-8")) for d in (first, replay)]
    assert configs[0]["params"] == configs[1]["params"] and configs[1]["params"]["seed"] == 3
    a, units_a = load_timeseries(first / "timeseries" / "Low.npz")
    b, units_b = load_timeseries(replay / "timeseries" / "Low.npz")
    assert set(a) == set(b) and units_a == units_b and set(TIMING_COLUMNS) <= set(a)
    assert np.any(a["q"][0] != 0.0)  # the seeded initial pose noise is part of what is replayed
    for name in sorted(set(a) - set(TIMING_COLUMNS)):
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    # a replay with an override is a different run
    other = tmp_path / "other"
    assert main(["run", "--data-only", "--config", str(first / "config.json"), "--seed", "4", "--out", str(other)]) == 0
    assert not np.array_equal(load_timeseries(other / "timeseries" / "Low.npz")[0]["q"], a["q"])


STORED_RUNS = ROOT / "tests" / "data" / "replay"  # run folders written by an earlier release: config.json and the time series


@pytest.mark.parametrize("name", sorted(p.name for p in STORED_RUNS.iterdir()))
def test_a_stored_config_json_replays_to_its_stored_series(name, tmp_path, capsys):
    """config.json files written before the scenarios took specs (then paper_sim had neither t0 nor
    damping_scale) replay through `softcbf run --config` to the stored series: bit for bit on the recorded
    versions, to 1e-9 on others (where the replay warns that it may not be bit-identical)."""
    from softcbf_mj.outputs.runio import versions

    stored = STORED_RUNS / name
    replay = tmp_path / "replay"
    assert main(["run", "--data-only", "--config", str(stored / "config.json"), "--out", str(replay)]) == 0
    capsys.readouterr()
    recorded = json.loads((stored / "config.json").read_text(encoding="utf-8"))
    params = json.loads((replay / "config.json").read_text(encoding="utf-8"))["params"]
    old = {k: joined(k, v) for k, v in recorded["params"].items()}  # a plug-in's old "" text: no parameters
    assert {k: params[k] for k in recorded["params"]} == old  # the new settings take their defaults
    exact = recorded["versions"] == versions()
    files = sorted((stored / "timeseries").glob("*.npz"))
    assert files
    for path in files:
        a, units_a = load_timeseries(path)
        b, units_b = load_timeseries(replay / "timeseries" / path.name)
        assert set(a) == set(b) and units_a == units_b
        for column in sorted(set(a) - set(TIMING_COLUMNS)):
            if exact:
                np.testing.assert_array_equal(a[column], b[column], err_msg=column)
            else:
                np.testing.assert_allclose(a[column], b[column], rtol=1e-9, atol=1e-12, err_msg=column)


TINY = ["--duration", "0.01", "--tunings", "None", "--progress", "false", "--data-only"]


def _warnings(err: str) -> list[str]:
    return [line for line in err.splitlines() if line.startswith("warning: ")]


@pytest.mark.slow
def test_a_replay_on_other_versions_or_with_another_seed_warns_one_line_each(tmp_path, capsys):
    """N9: a config.json replay ignored a mismatched seed or version and promised a bit-identical run."""
    first = tmp_path / "first"
    assert main(["run", "paper_sim", *TINY, "--seed", "3", "--out", str(first)]) == 0
    config = first / "config.json"
    capsys.readouterr()
    assert main(["run", "--data-only", "--config", str(config), "--out", str(tmp_path / "same"), "--seed", "3"]) == 0
    assert _warnings(capsys.readouterr().err) == []  # the same versions, the recorded seed: a faithful replay
    recorded = json.loads(config.read_text(encoding="utf-8"))
    running = recorded["versions"]
    recorded["versions"] = {**running, "mujoco": "3.1.0", "numpy": "1.26.4"}
    config.write_text(json.dumps(recorded), encoding="utf-8")
    assert main(["run", "--data-only", "--config", str(config), "--out", str(tmp_path / "other"), "--seed", "4"]) == 0
    assert _warnings(capsys.readouterr().err) == [
        f"warning: {config} was recorded with mujoco 3.1.0, this is mujoco {running['mujoco']}: the replay may not be "
        "bit-identical to the recorded run",
        f"warning: {config} was recorded with numpy 1.26.4, this is numpy {running['numpy']}: the replay may not be "
        "bit-identical to the recorded run",
        f"warning: --seed 4 overrides the seed 3 recorded in {config}: the replay will not be bit-identical to the "
        "recorded run"]
    del recorded["versions"]
    config.write_text(json.dumps(recorded), encoding="utf-8")
    assert main(["run", "--data-only", "--config", str(config), "--out", str(tmp_path / "unknown")]) == 0
    assert _warnings(capsys.readouterr().err) == [
        f"warning: {config} records no versions: the replay may not be bit-identical to the recorded run"]
    recorded["versions"] = "4.0.0"
    config.write_text(json.dumps(recorded), encoding="utf-8")
    assert main(["run", "--config", str(config), "--out", str(tmp_path / "bad")]) == USAGE_ERROR
    assert '"versions" must be an object' in capsys.readouterr().err


def test_a_toml_run_configuration_gives_no_replay_warning(tmp_path, capsys):
    config = tmp_path / "run.toml"
    config.write_text('scenario = "paper_sim"\nduration = 0.01\ntunings = "None"\nprogress = false\nseed = 1\n',
                      encoding="utf-8")
    assert main(["run", "--data-only", "--config", str(config), "--seed", "2", "--out", str(tmp_path / "run")]) == 0
    assert _warnings(capsys.readouterr().err) == []


def test_study_settings_set_dotted_keys_before_the_checks(tmp_path):
    path = ROOT / "studies" / "paper_tunings_plate_errors.toml"
    data = tomllib.loads(path.read_text(encoding="utf-8"))
    study = load_study(path, ["fixed.duration=10", "vary.plate_stiffness.high=20", "draws=3", 'name="short"'])
    assert study.fixed["duration"] == 10.0 and isinstance(study.fixed["duration"], float)
    assert study.n_draws == 3 and study.name == "short"
    (stiffness,) = [d for d in study.vary if d.parameter == "plate_stiffness"]
    assert stiffness.high == 20.0
    assert load_study(path).to_dict()["fixed"] == {k: float(v) if isinstance(v, int) else v
                                                   for k, v in data["fixed"].items()}
    assert apply_settings(data, ["fixed.tip_friction=0.2"])["fixed"]["tip_friction"] == 0.2
    assert "tip_friction" not in data["fixed"]  # the file's data is not changed
    assert parse_setting("filter_params.tuning=Low") == (["filter_params", "tuning"], "Low")
    assert parse_setting("tunings=[\"Low\", \"High\"]") == (["tunings"], ["Low", "High"])
    with pytest.raises(ValueError, match="fixed.duration must be > 0 s, got -1.0|duration must be > 0 s"):
        load_study(path, ["fixed.duration=-1"])
    with pytest.raises(ValueError, match="has no parameter 'no_such'"):
        load_study(path, ["fixed.no_such=1"])
    with pytest.raises(ValueError, match=re.escape("draws is not a table")):
        load_study(path, ["draws.x=1"])
    with pytest.raises(ValueError, match="KEY=VALUE"):
        load_study(path, ["fixed.duration"])


def test_the_parameter_page_is_the_one_the_tool_writes():
    spec = importlib.util.spec_from_file_location("parameter_table", ROOT / "tools" / "parameter_table.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    text = tool.page()
    assert (ROOT / "docs" / "parameters.md").read_text(encoding="utf-8") == text, \
        "docs/parameters.md is out of date: python tools/parameter_table.py"
    for scenario in registry().values():
        for name in scenario.parameters():
            assert f"| `{name}` | {SETTINGS[name].meaning}" in text.replace("\\|", "|")
    for key, name in LEGACY_KEYS.items():
        assert f"| `{key}` | `{name}` |" in text


def test_the_run_configuration_example_is_a_valid_run():
    config = load_run_config(ROOT / "docs" / "examples" / "run.toml")
    kwargs = registry()[config.scenario].validate(config.params)
    assert kwargs["filter_params"] == {"a_E": 5.0, "b_E": 5.0, "gamma": 5.0} and kwargs["tunings"] == "custom"
