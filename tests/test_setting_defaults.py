"""Each setting's default has one home: `vocabulary.settings` (`Setting.default`, and
`DEFAULT_OVERRIDES` where a context needs another); the scenario signatures and the hardware
file derive theirs from it, and no other configuration module types a literal default."""

from __future__ import annotations

import ast
import dataclasses
import math
from pathlib import Path

import pytest

import scenarios
from hardware.config import SHARED_KEYS, default_values
from vocabulary.settings import DEFAULT_OVERRIDES, SETTINGS, check_value, default, flat_form

REPO = Path(__file__).resolve().parents[1]
# The modules that configure a run: none may type a setting's default (they take `default(name, context)`).
CONFIGURATION = sorted((REPO / "scenarios").glob("*.py")) + [REPO / "hardware" / "config.py"] + sorted(
    (REPO / "softcbf_mj" / "env").glob("*.py")) + [REPO / "softcbf" / name for name in ("cli.py", "hardware_cli.py")] + sorted(
    (REPO / "softcbf" / "bench").glob("*.py"))
# A value a module fixes on purpose, which is no default (nothing else takes it when it is not given):
# path → {(setting, value): why}. The scan finds it all the same; each entry must still be found.
FIXED_VALUES = {
    "softcbf/bench/cases.py": {
        ("progress", False): "the bench reports its own progress; the scenario runs of its cases are quiet",
        ("nominal", "step"): "the step case is the step nominal's case (module docstring), not a default of `nominal`",
    },
    # the filter's context: the delay the loop tells its filter, not the true arm's `command_delay`
    "scenarios/camera_loop.py": {("command_delay", 0.0): "the command acts at the tick after the call"},
    "scenarios/paper_sim.py": {("command_delay", 0.0): "the paper's loop has no command delay"},
}


def distinctive(value: object) -> bool:
    """A default that is hard to type by chance: a number whose mantissa has two or more
    significant digits (11.16, 0.16, 12.8, 1.23044e-3; not 0, 1, 0.5, 80, 1e-4)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value == 0:
        return False
    mantissa = f"{abs(value):.12e}".split("e")[0].rstrip("0").rstrip(".")
    return len(mantissa.replace(".", "")) >= 2


DISTINCTIVE = {float(s.default) for s in SETTINGS.values() if distinctive(s.default)} | {
    float(v) for overrides in DEFAULT_OVERRIDES.values() for v in overrides.values() if distinctive(v)}


def literal_defaults(source: str, path: str = "<source>") -> list[str]:
    """Where `source` types a setting's default as a literal: a parameter default or a
    class field named like a setting, a setting's keyword argument, or any number
    equal to a distinctive default (`DISTINCTIVE`); "PATH:LINE what" each."""
    found = []
    tree = ast.parse(source)
    for node in ast.walk(tree):
        pairs: list[tuple[str, ast.expr]] = []
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            a = node.args
            positional = a.posonlyargs + a.args
            pairs += [(arg.arg, d) for arg, d in zip(positional[len(positional) - len(a.defaults):], a.defaults)]
            pairs += [(arg.arg, d) for arg, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None]
        elif isinstance(node, ast.ClassDef):
            pairs += [(st.target.id, st.value) for st in node.body if isinstance(st, ast.AnnAssign)
                      and isinstance(st.target, ast.Name) and st.value is not None]
        elif isinstance(node, ast.Call):
            pairs += [(k.arg, k.value) for k in node.keywords if k.arg is not None]
        for name, value in pairs:
            if name in SETTINGS and isinstance(value, ast.Constant) and value.value is not None:
                found.append(f"{path}:{value.lineno} {name} = {value.value!r}")
        if (isinstance(node, ast.Constant) and not isinstance(node.value, bool) and isinstance(node.value, (int, float))
                and float(node.value) in DISTINCTIVE):
            found.append(f"{path}:{node.lineno} the literal {node.value!r}, a setting's default")
    return found


def test_the_scan_finds_literal_defaults():
    """The scan sees each way of typing a default (so the next test can fail)."""
    source = ("def run(out_dir, *, f_max: float = 0.5, duration=3.0, label='x'):\n    pass\n"
              "class Config:\n    tau_p: float = 0.02\n    other: float = 0.02\n"
              "build(plate_stiffness=9.0)\nK = 11.16\n")
    found = literal_defaults(source)
    assert [f.split(" ", 1)[1] for f in found] == [
        "f_max = 0.5", "duration = 3.0", "tau_p = 0.02", "plate_stiffness = 9.0", "the literal 11.16, a setting's default"]
    assert literal_defaults("def run(*, f_max: float = default('f_max', 'paper_sim')):\n    pass\n") == []


def _fixed(path: str, hit: str) -> tuple[str, object] | None:
    """The `FIXED_VALUES` entry (setting, value) that scan hit `hit` of module `path` is, else None."""
    what = hit.split(" ", 1)[1]
    return next((key for key in FIXED_VALUES.get(path, {}) if what == f"{key[0]} = {key[1]!r}"), None)


def test_no_configuration_module_types_a_literal_default():
    found, fixed = [], set()
    for path in CONFIGURATION:
        rel = path.relative_to(REPO).as_posix()
        for hit in literal_defaults(path.read_text(encoding="utf-8"), rel):
            key = _fixed(rel, hit)
            if key is None:
                found.append(hit)
            else:
                fixed.add((rel, key))
    assert found == [], "literal defaults (use vocabulary.settings.default(name, context)):\n" + "\n".join(found)
    stale = {(rel, key) for rel, keys in FIXED_VALUES.items() for key in keys} - fixed
    assert not stale, f"FIXED_VALUES entries no module holds any more (remove them): {sorted(stale, key=str)}"


@pytest.mark.parametrize("name", list(SETTINGS))
def test_every_setting_has_a_valid_default(name):
    declared = SETTINGS[name]
    assert declared.default is not None, f"{name} has no default"
    assert type(declared.default) is declared.kind, (name, declared.default)
    assert check_value(name, declared.default) == declared.default


def test_overrides_name_settings_and_differ_from_the_declared_default():
    assert set(DEFAULT_OVERRIDES) == set(scenarios.registry()) | {"hardware", "environment"}
    for context, overrides in DEFAULT_OVERRIDES.items():
        for name, value in overrides.items():
            assert name in SETTINGS, (context, name)
            assert value != SETTINGS[name].default, f"{context}.{name}: the override repeats the declared default"
            if value is not None:  # None: no default (the hardware's calibration is required for a real camera)
                assert check_value(name, value) == value, (context, name)
    with pytest.raises(KeyError, match="context 'paper-sim' is not a key"):
        default("f_max", "paper-sim")
    with pytest.raises(KeyError, match="setting 'f_maxx' is not declared"):
        default("f_maxx", "paper_sim")


@pytest.mark.parametrize("name", sorted(scenarios.registry()))
def test_scenario_defaults_are_the_vocabulary_s(name):
    """What the CLI, `softcbf list` and `--help` read (`inspect.signature`) is the vocabulary's default."""
    scenario = scenarios.get(name)
    defaults = scenario.defaults()
    assert set(defaults) <= set(SETTINGS)
    for param, value in defaults.items():
        expected = flat_form(param, default(param, name))  # the tunings' tuple as the comma list
        assert value == expected and type(value) is type(expected), (name, param, value, expected)


def test_spec_sections_hold_no_default_of_their_own():
    """A section's field is UNSET until a spec resolves it to `default(name, context)`: the spec of each
    scenario takes every default from the vocabulary, the one home."""
    from scenarios.spec import UNSET

    for name, scenario in scenarios.registry().items():
        spec = scenario.spec()
        for attribute, section in scenario.spec.SECTIONS.items():
            for field in dataclasses.fields(section):
                assert field.default is UNSET, (section.__name__, field.name)
                setting = field.metadata["setting"]
                assert getattr(getattr(spec, attribute), field.name) == default(setting, name), (name, setting)


def test_hardware_defaults_are_the_vocabulary_s():
    values = default_values()
    for name in SHARED_KEYS:
        if name in ("filter_params", "nominal_params"):  # tables: a plug-in's parameters (default {})
            assert values[name] == {}
            continue
        assert values[name] == default(name, "hardware"), name


def test_environment_defaults_are_the_vocabulary_s():
    """The environment's keyword arguments named like a setting are the settings of `ENV_SETTINGS` (the control
    rate, the filter, the monitor's hold, q0_std, what the filter assumes and every ground-truth setting) and take `default(name,
    "environment")`; its own `robot` (a RobotParams) and `filter_params` (a mapping) are no such keywords."""
    import inspect

    from softcbf_mj.env.environment import ENV_SETTINGS, ArmEnvConfig
    from softcbf_mj.env.physics import ArmPhysics
    from softcbf_mj.env.task import ArmTask
    from vocabulary.settings import ground_truth_settings

    shared = [f for f in dataclasses.fields(ArmEnvConfig) if f.name in SETTINGS and f.name not in ("robot", "filter_params")]
    assert {f.name for f in shared} == set(ENV_SETTINGS) == {"control_rate", "filter", "pressure_limits", "hold_s",
                                                             "q0_std", "assumed_tau_p", "assumed_command_delay",
                                                             *ground_truth_settings()}
    for f in shared:
        expected = default(f.name, "environment")
        assert f.default == expected and type(f.default) is type(expected), (f.name, f.default, expected)
    assert inspect.signature(ArmTask).parameters["q0_std"].default == default("q0_std", "environment")
    assert inspect.signature(ArmPhysics).parameters["hold_s"].default == default("hold_s", "environment")
    assert ArmEnvConfig().filter == "none"  # the environment is the unfiltered arm unless a filter is asked for


def test_physical_constant_modules_agree_with_the_vocabulary():
    """The physical-constant modules below the scenarios keep their documented constants; they
    must be the vocabulary's defaults (one value, two layers: follow-up to derive them)."""
    from perception.estimator import DEFAULT_MAX_HOLD_S
    from softcbf_mj.physics import mjcf
    from softcbf_mj.loops.camera_loop import CameraTiming
    from softcbf_mj.physics.flexure import FlexureParams

    sheet = FlexureParams()
    for field in ("clamp_at", "free_end_at", "thickness", "width", "youngs_modulus", "links", "calibration_fraction"):
        assert default(f"sheet_{field}", "mujoco_contact") == getattr(sheet, field), field
    assert default("plate_stiffness", "mujoco_contact") == mjcf.PAPER_PLATE_STIFFNESS
    assert default("links_per_segment", "mujoco_contact") == mjcf.DEFAULT_LINKS_PER_SEGMENT
    assert default("physics_dt", "mujoco_contact") == mjcf.DEFAULT_PHYSICS_DT
    assert default("tau_p", "mujoco_contact") == mjcf.DEFAULT_TAU_P
    assert default("links_per_segment", "camera_loop") == mjcf.CAMERA_LINKS_PER_SEGMENT
    assert default("physics_dt", "camera_loop") == mjcf.CAMERA_PHYSICS_DT
    assert (default("width", "camera_loop"), default("height", "camera_loop")) == mjcf.CAMERA_RESOLUTION
    assert default("max_hold_s", "camera_loop") == DEFAULT_MAX_HOLD_S
    timing = CameraTiming()
    for field in dataclasses.fields(CameraTiming):
        assert default(field.name, "camera_loop") == getattr(timing, field.name), field.name
    assert math.isclose(default("f_max", "paper_sim") / default("plate_stiffness", "paper_sim"), 0.16 / 11.16)
