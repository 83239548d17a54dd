"""A study file is checked whole at load: one line naming the problem (exit 2), or a study whose
first sample the scenario accepts. Property-based over random study files (hypothesis)."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from scenarios import get as get_scenario
from softcbf.study import load_study

ROOT = Path(__file__).resolve().parents[1]
TUNING_NAMES = ["None", "Low", "High", "HW-Low", "HW-High"]
SCENARIOS = ["mujoco_contact", "paper_sim", "camera_loop"]

BASE = """
name = "checked"
scenario = "mujoco_contact"
seed = 3
draws = 4
tunings = ["None", "Low"]
[fixed]
t0 = 25.0
duration = 0.2
[vary.plate_stiffness]
dist = "uniform"
low = 9.0
high = 14.0
"""


def _write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "study.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(("old", "new", "message"), [
    # S2: a non-finite fixed value, a range the scenario refuses at one end, and at the other
    ("duration = 0.2", "duration = nan", r"fixed.duration: parameter 'duration' must be a finite number, got nan"),
    ("duration = 0.2", "duration = inf", r"fixed.duration: parameter 'duration' must be a finite number, got inf"),
    ("low = 9.0", "low = -2.0", r"vary.plate_stiffness: low = -2.0: plate_stiffness must be > 0 N/m, got -2.0"),
    ("high = 14.0", "high = inf", r"vary.plate_stiffness: high must be a finite number, got inf"),
    # S5: an unknown tuning, a negative duration, tunings as one string
    ('["None", "Low"]', '["None", "Lo"]', r"refuses sample 1 \(draw 0 with tuning 'Lo'.*unknown tuning 'Lo'; valid: None, Low"),
    ("duration = 0.2", "duration = -1", r"refuses sample 0 .*duration must be > 0 s, got -1.0"),
    ('tunings = ["None", "Low"]', 'tunings = "None,Low"',
     r"tunings must be a list of tuning names such as \[\"None\", \"Low\"\], got 'None,Low'"),
])
def test_a_study_is_refused_at_load_with_one_line_naming_the_parameter(tmp_path, old, new, message):
    assert old in BASE
    with pytest.raises(ValueError, match=message) as info:
        load_study(_write(tmp_path, BASE.replace(old, new)))
    assert "\n" not in str(info.value)


def test_a_range_end_the_scenario_refuses_is_named_with_its_key(tmp_path):
    text = BASE + '[vary.facet_angle]\ndist = "uniform"\nlow = 0.0\nhigh = 1.6\n'
    with pytest.raises(ValueError, match=r"vary.facet_angle: high = 1.6: facet_angle must be in \(-1.5708, 1.5708\) rad, got 1.6"):
        load_study(_write(tmp_path, text))
    choice = BASE + '[vary.physics_dt]\ndist = "choice"\nvalues = [1e-4, 3e-4]\n'
    with pytest.raises(ValueError, match=r"vary.physics_dt: values\[1\] = 0.0003: the control period .* integer multiple"):
        load_study(_write(tmp_path, choice))


@pytest.mark.parametrize("change", ['duration = -1', 'tunings = "None,Low"'])
def test_cli_refuses_a_bad_study_with_exit_2_one_line_and_no_folder(tmp_path, change):
    key = change.split(" = ")[0]
    text = re.sub(rf"^{key} = .*$", change, BASE, count=1, flags=re.M)
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "softcbf.study", "run", str(_write(tmp_path, text)), "--out", str(out),
                           "--no-progress"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.startswith("error: study file ") and proc.stderr.count("\n") == 1
    assert not out.exists()


def test_cli_refuses_an_out_of_bounds_filter_parameter_before_any_sample(tmp_path):
    """Issue 25: a filter's parameters are checked against its declared bounds when the study
    loads, so `softcbf study run` exits 2 with one line naming the parameter and runs nothing."""
    text = BASE.replace('tunings = ["None", "Low"]', 'filter = "e-erg"\ntunings = ["e-erg"]').replace(
        "duration = 0.2", 'duration = 0.2\nfilter_params = "kappa=-1"')
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-m", "softcbf.study", "run", str(_write(tmp_path, text)), "--out", str(out),
                           "--no-progress"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and proc.stdout == ""
    assert proc.stderr.count("\n") == 1 and "filter 'e-erg': kappa must be in [0, 1000], got -1.0" in proc.stderr
    assert not out.exists()


def test_a_billion_draws_load_at_once_and_a_sample_count_beyond_int64_is_refused(tmp_path):
    study = load_study(_write(tmp_path, BASE.replace("draws = 4", "draws = 1000000000000")))
    assert study.n_samples == 2 * 10**12 and study.sample(study.n_samples - 1).draw == 10**12 - 1
    with pytest.raises(ValueError, match=r"draws × tunings must be <= 2\*\*63 - 1"):
        load_study(_write(tmp_path, BASE.replace("draws = 4", f"draws = {2**63 - 1}")))


# -- property: random study files --------------------------------------------------
# Mostly well-formed files with a scenario's parameters at plausible values, each part
# replaced now and then by junk (wrong types, NaN, ±inf, huge integers, unknown names).

printable = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), max_size=10)
numbers = st.one_of(st.integers(), st.integers(min_value=-2**63, max_value=2**63 - 1),
                    st.floats(allow_nan=True, allow_infinity=True), st.floats(-20, 20))
scalars = st.one_of(st.booleans(), numbers, printable, st.sampled_from(TUNING_NAMES + ["None,Low", "reference", "paper"]))
junk = st.one_of(scalars, st.lists(scalars, max_size=3))


def mostly(good: st.SearchStrategy) -> st.SearchStrategy:
    """`good` about nine times in ten, junk otherwise."""
    return st.integers(0, 9).flatmap(lambda n: junk if n == 9 else good)


PARAMETERS = {name: (parameter.default, typing.get_type_hints(get_scenario(s).run)[name])
              for s in SCENARIOS for name, parameter in get_scenario(s).parameters().items()
              if name not in ("tunings", "progress")}


def plausible(name: str) -> st.SearchStrategy:
    default, kind = PARAMETERS[name]
    if kind is float:
        scale = abs(default) or 1.0
        return mostly(st.floats(-2 * scale, 3 * scale, allow_nan=False))
    if kind is int:
        return mostly(st.one_of(st.just(default), st.integers(-2, 20)))
    if kind is bool:
        return mostly(st.booleans())
    return mostly(st.one_of(st.just(default), printable))


def distribution(name: str) -> st.SearchStrategy:
    value = plausible(name)
    return mostly(st.one_of(
        st.fixed_dictionaries({"dist": st.just("uniform"), "low": value, "high": value}, optional={"points": st.integers(-1, 12)}),
        st.fixed_dictionaries({"dist": st.just("loguniform"), "low": value, "high": value}, optional={"points": numbers}),
        st.fixed_dictionaries({"dist": st.just("normal"), "mean": value, "std": value}),
        st.fixed_dictionaries({"dist": st.just("choice"), "values": st.lists(value, max_size=3)}),
        st.fixed_dictionaries({"dist": printable}, optional={"low": value, "spread": value})))


def study_table(scenario: str) -> st.SearchStrategy:
    """A study of `scenario`: its own parameters, now and then another scenario's or an unknown name."""
    own = sorted(p for p in get_scenario(scenario).parameters() if p in PARAMETERS)
    names = st.integers(0, 9).flatmap(lambda n: st.sampled_from(own) if n < 8 else st.one_of(
        st.sampled_from(sorted(PARAMETERS)), st.from_regex(r"[a-z_]{1,8}", fullmatch=True)))
    fixed = st.lists(names, unique=True, max_size=3).flatmap(
        lambda keys: st.fixed_dictionaries({k: plausible(k) if k in PARAMETERS else junk for k in keys}))
    vary = st.lists(names, unique=True, max_size=2).flatmap(
        lambda keys: st.fixed_dictionaries({k: distribution(k) if k in PARAMETERS else junk for k in keys}))
    table = st.fixed_dictionaries(
        {"name": mostly(st.just("random")), "scenario": mostly(st.just(scenario)),
         "tunings": mostly(st.lists(st.sampled_from(TUNING_NAMES + ["Lo"]), unique=True, min_size=1, max_size=3)),
         "draws": mostly(st.one_of(st.integers(1, 10), st.sampled_from([0, 10**9, 10**12, 2**62, 2**63 - 1])))},
        optional={"seed": mostly(st.integers(0, 2**40)), "sampling": mostly(st.just("monte_carlo")),
                  "tuning_parameter": mostly(st.just("tunings")), "fixed": mostly(fixed), "vary": mostly(vary)})
    grid = table.map(lambda t: {**{k: v for k, v in t.items() if k != "draws"}, "sampling": "grid"})
    with_unknown_key = table.flatmap(lambda t: numbers.map(lambda v: {**t, "draw": v}))
    return st.integers(0, 9).flatmap(lambda n: with_unknown_key if n == 9 else grid if n == 8 else table)


study_tables = st.sampled_from(SCENARIOS).flatmap(study_table)


def _toml_key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf") if math.isinf(value) else repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, str):
        return json.dumps(value)
    return "[" + ", ".join(_toml_value(v) for v in value) + "]"


def to_toml(data: dict, prefix: str = "") -> str:
    """TOML text of `data` (nested dicts become [tables])."""
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, v in data.items():
        if isinstance(v, dict):
            name = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)
            lines += ["", f"[{name}]", to_toml(v, name)]
    return "\n".join(lines)


@pytest.fixture(scope="module")
def study_path(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("random") / "study.toml"


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=study_tables)
def test_random_study_files_are_refused_in_one_line_or_give_a_valid_first_sample(study_path, data):
    study_path.write_text(to_toml(data), encoding="utf-8")
    try:
        study = load_study(study_path)
    except ValueError as exc:
        message = str(exc)
        assert message.startswith(f"study file {study_path}") and "\n" not in message
        event("refused: " + message.split(": ", 1)[1][:60])
        return
    event("loaded")
    first = study.sample(0)
    get_scenario(study.scenario).validate(first.kwargs)  # the scenario accepts the first sample
    assert 1 <= study.n_samples <= 2**63 - 1
    assert study.sample(study.n_samples - 1).index == study.n_samples - 1
