"""Scenario specs (scenarios.spec): typed, frozen sections derived from the vocabulary, checked once,
and everything a user sees derived from them (issue 25)."""

from __future__ import annotations

import dataclasses
import inspect
import json
import pickle

import pytest

import scenarios
from scenarios import register, registry, unregister
from scenarios.config_file import load_run_config
from scenarios.run import describe, scenario_parameters
from scenarios.spec import UNSET, Camera, Filter, Model, Nominal, Plate, Run, TrueArm, scenario_spec, section
from softcbf.cli import main as softcbf_main
from softcbf_mj.outputs.runio import SummaryWriter
from vocabulary import settings as vocabulary
from vocabulary.settings import Bound, Setting, SettingError, default, flat_form

SECTIONS = (Run, Filter, Nominal, Model, TrueArm, Plate, Camera)


def test_every_section_field_is_a_setting_with_its_type_and_no_default_of_its_own():
    for cls in SECTIONS:
        for f in dataclasses.fields(cls):
            declared = vocabulary.setting(f.metadata["setting"])
            assert f.type is declared.kind and f.default is UNSET, (cls.__name__, f.name)


def test_a_section_checks_its_values_when_built_and_is_frozen():
    plate = Plate(stiffness=12)
    assert plate.stiffness == 12.0 and type(plate.stiffness) is float and plate.kind is UNSET
    with pytest.raises(SettingError, match=r"plate_stiffness must be > 0 N/m, got -1.0"):
        Plate(stiffness=-1.0)
    with pytest.raises(SettingError, match="plate must be a str"):
        Plate(kind=3)
    with pytest.raises(dataclasses.FrozenInstanceError):
        plate.stiffness = 1.0


@pytest.mark.parametrize("name", ["paper_sim", "mujoco_contact", "camera_loop"])
def test_a_spec_takes_its_scenario_s_defaults_and_round_trips_its_flat_names(name):
    spec_cls = registry()[name].spec
    spec = spec_cls()
    assert spec.flat() == {key: flat_form(key, default(key, name)) for key in spec_cls.PATHS}
    assert spec_cls.from_flat(spec.flat()) == spec and pickle.loads(pickle.dumps(spec)) == spec
    with pytest.raises(ValueError, match=f"scenario '{name}' has no parameter 'no_such'; parameters: duration, "):
        spec_cls.from_flat({"no_such": 1})


def test_a_section_left_partly_unset_takes_the_scenario_s_defaults():
    camera = registry()["camera_loop"].spec(arm=TrueArm(tau_p=0.1))
    assert camera.arm.tau_p == 0.1 and camera.arm.links_per_segment == default("links_per_segment", "camera_loop") == 5
    contact = registry()["mujoco_contact"].spec(arm=TrueArm(tau_p=0.1))
    assert contact.arm.links_per_segment == default("links_per_segment", "mujoco_contact") == 10
    assert contact.replace_flat(plate_stiffness=12.0).plate.stiffness == 12.0
    with pytest.raises(TypeError, match="MujocoContact.plate must be a Plate"):
        registry()["mujoco_contact"].spec(plate=TrueArm())


def test_a_plug_in_s_parameters_are_keywords_of_its_section_checked_by_the_plug_in():
    contact = registry()["mujoco_contact"].spec
    spec = contact(filter=Filter("e-erg", contact_aware=True, kappa=2.0), plate=Plate(stiffness=12.0))
    assert spec.filter == Filter("e-erg", params={"contact_aware": True, "kappa": 2.0}, tunings=("None", "Low", "High"),
                                 qp_backend="native", pressure_limits=True, isolate=False)
    assert spec.flat()["filter_params"] == {"kappa": 2.0, "contact_aware": True} and spec.flat()["plate_stiffness"] == 12.0
    assert Nominal("sinusoid", phase=0.5).params == {"phase": 0.5}
    with pytest.raises(ValueError, match="unknown parameter.s. contact_awar for EnergyGovernor"):
        contact(filter=Filter("e-erg", contact_awar=True))
    with pytest.raises(ValueError, match=r"kappa must be in \[0, 1000\], got -1.0"):
        contact(filter=Filter("e-erg", kappa=-1.0))
    with pytest.raises(TypeError, match="not both"):
        Filter("e-erg", params={"kappa": 1.0}, margin_m=0.001)


def test_a_spec_runs_its_scenario_s_checks_when_built():
    contact = registry()["mujoco_contact"].spec
    with pytest.raises(ValueError, match="integer multiple of the physics step"):  # it must divide the 1 ms period
        contact.from_flat({"physics_dt": 3e-4})
    with pytest.raises(ValueError, match="filter 'e-erg'"):  # the filter's own bounds (controllers.contract.filter_parameters)
        contact(filter=Filter(name="e-erg", params="kappa=-1"))
    with pytest.raises(ValueError, match="table_friction"):
        contact(arm=TrueArm(gravity=9.81, table_friction=0.5))


@pytest.mark.parametrize("name", ["paper_sim", "mujoco_contact", "camera_loop"])
def test_no_scenario_function_exceeds_15_parameters_or_60_lines(name):
    function = registry()[name].function
    lines, _ = inspect.getsourcelines(function)
    assert len(inspect.signature(function).parameters) <= 15
    assert len(lines) <= 60, f"{name}: {len(lines)} lines"


KNOB = Setting("a test's knob", "N", float, Bound(0.0, 2.0, unit="N"), default=0.25)


@pytest.fixture
def knob_scenario(monkeypatch):
    """A scenario with a setting the vocabulary gains in this fixture, and nothing else edited."""
    monkeypatch.setitem(vocabulary.SETTINGS, "test_knob", KNOB)
    monkeypatch.setitem(vocabulary.DEFAULT_OVERRIDES, "knob_demo", {})
    knob = section("Knob", "a test's section", {"level": "test_knob"})
    spec_cls = scenario_spec("KnobDemo", "a test's scenario", "knob_demo", {"run": Run, "knob": knob})

    @register("knob_demo", "a test's scenario with a knob", spec_cls)
    def knob_demo(out_dir, spec):
        return SummaryWriter(out_dir, "knob_demo", spec.flat()).data

    yield scenarios.get("knob_demo")
    unregister("knob_demo")


def test_a_setting_added_in_a_fixture_reaches_help_list_toml_and_replay(knob_scenario, tmp_path, capsys):
    assert "--test-knob float (default 0.25) [N]: a test's knob; valid: in [0, 2] N" in describe(knob_scenario)
    assert softcbf_main(["list"]) == 0 and "--test-knob float (default 0.25)" in capsys.readouterr().out
    assert softcbf_main(["run", "knob_demo", "--help"]) == 0 and "--test-knob" in capsys.readouterr().out
    assert knob_scenario.build(scenario_parameters(knob_scenario, ["--test-knob", "1.5"])).knob.level == 1.5
    toml = tmp_path / "knob.toml"
    toml.write_text('scenario = "knob_demo"\ntest_knob = 0.75\n', encoding="utf-8")
    config = load_run_config(toml)
    params = scenario_parameters(knob_scenario, [], config.params)
    assert params["test_knob"] == 0.75
    (tmp_path / "run").mkdir()
    knob_scenario.run(tmp_path / "run", **params)
    recorded = json.loads((tmp_path / "run" / "config.json").read_text(encoding="utf-8"))
    assert recorded["params"]["test_knob"] == 0.75
    replay = load_run_config(tmp_path / "run" / "config.json")
    assert knob_scenario.build(scenario_parameters(knob_scenario, [], replay.params)).knob.level == 0.75
    with pytest.raises(Exception, match=r"test_knob must be in \[0, 2\] N, got 3.0"):
        knob_scenario.validate({"test_knob": 3.0})


WALL_TIME = ("filter_us", "solve_us")  # measured times (µs): they differ between any two runs


def test_run_returns_the_outputs_in_memory_and_save_writes_softcbf_run_s_folder(tmp_path, capsys):
    from scenarios.api import PaperSim, run, save
    from softcbf_mj.outputs.runio import load_timeseries

    spec = PaperSim(run=Run(duration=0.3, progress=False), filter=Filter(tunings=("High",)),
                    nominal=Nominal(amplitude=150.0, frequency=0.25))
    result = run(spec)
    assert [row["tuning"] for row in result.runs] == ["High"] and result.summary["params"] == spec.flat()
    assert result.series["High"]["u"].shape == (300, 2) and result.units["High"]["u"].startswith("hPa")
    saved = save(result, tmp_path / "api")
    flags = ["--duration", "0.3", "--tunings", "High", "--amplitude", "150", "--frequency", "0.25", "--progress", "false"]
    assert softcbf_main(["run", "paper_sim", "--out", str(tmp_path / "cli"), *flags]) == 0
    capsys.readouterr()
    api_files = sorted(p.relative_to(saved).as_posix() for p in saved.rglob("*") if p.is_file())
    cli_files = sorted(p.relative_to(tmp_path / "cli").as_posix() for p in (tmp_path / "cli").rglob("*") if p.is_file())
    assert api_files == cli_files
    config = [json.loads((folder / "config.json").read_text(encoding="utf-8")) for folder in (saved, tmp_path / "cli")]
    assert config[0]["params"] == config[1]["params"] == spec.flat()
    columns = [load_timeseries(folder / "timeseries" / "High.npz") for folder in (saved, tmp_path / "cli")]
    assert columns[0][1] == columns[1][1] and columns[0][0].keys() == columns[1][0].keys()
    for key in columns[0][0]:
        if key not in WALL_TIME:
            assert (columns[0][0][key] == columns[1][0][key]).all(), key
    with pytest.raises(TypeError, match="run takes a scenario's spec"):
        run(Run())


def test_run_names_no_folder_that_is_gone_when_it_returns(capsys):
    """run(spec) works in a temporary folder that it deletes: what it prints names result.files, not that folder."""
    import tempfile

    from scenarios.api import PaperSim, run

    result = run(PaperSim(run=Run(duration=0.05, progress=False), filter=Filter(tunings=("High",))))
    out = capsys.readouterr().out
    assert tempfile.gettempdir() not in out, out
    assert "; outputs in result.files\n" in out, out
    for line in out.splitlines():
        if "(every column)" in line:
            assert line.endswith(": result.files['table.txt']") and "table.txt" in result.files, line


def test_the_tunings_are_a_tuple_of_names_in_python_and_a_comma_list_on_the_command_line_and_in_files(tmp_path):
    """The typed API takes a tuple of tuning names; the flat form (the command line, TOML, config.json, studies)
    stays the comma list, and every form gives the same spec (issue 25: no strings from Python)."""
    paper = registry()["paper_sim"]
    typed = paper.spec(filter=Filter(tunings=("None", "High")))
    assert typed.filter.tunings == ("None", "High") and typed.flat()["tunings"] == "None,High"
    assert paper.spec.from_flat({"tunings": "None, High"}) == typed == paper.build({"tunings": ["None", "High"]})
    assert paper.spec.from_flat(json.loads(json.dumps(typed.flat()))) == typed  # config.json round trip
    assert registry()["camera_loop"].spec().filter.tunings == ("None", "HW-Low", "HW-High")
    assert paper.defaults()["tunings"] == "None,Low,High" and inspect.signature(paper.run).parameters["tunings"].annotation is str
    toml = tmp_path / "run.toml"
    toml.write_text('scenario = "paper_sim"\ntunings = ["Low", "High"]\n', encoding="utf-8")
    assert load_run_config(toml).params["tunings"] == "Low,High"
    with pytest.raises(SettingError, match=r"tunings must be a sequence of names or a comma list .*got 3"):
        Filter(tunings=3)
    with pytest.raises(ValueError, match="unknown tuning 'Medium'"):
        paper.spec(filter=Filter(tunings=("None", "Medium")))


@pytest.mark.slow
def test_one_softcbf_run_reads_the_robot_builds_the_safe_set_and_parses_the_plug_in_parameters_once():
    """Parse once (tests/call_counts.py, printed by tools/parse_counts.py): the spec's check builds the controller (`spec.built`) and
    the run takes it; each setting is checked once."""
    from call_counts import counts

    found = counts("paper_sim", 0.02)
    assert found["ground_truth:load_robot"] == found["common:build_safe_set"] == 1
    assert found["settings:check_value"] == len(registry()["paper_sim"].spec.PATHS)
    assert found["registry:build_filter"] == found["registry:check_filter"] == 3  # one per tuning
