"""The declared filter parameters (controllers.contract.filter_parameters): one check for check_arguments and
the constructors, through controllers.core.bounds.check_number, and the docs built from the same table."""

import json
import math
import pickle
from pathlib import Path

import numpy as np
import pytest

from controllers.governors.energy_governor import PARAMETERS as EERG
from controllers.cbf.paper_filter import PARAMETERS as PAPER_CBF
from controllers.contract.filter_parameters import FilterParameter, Params, check_parameters, parameter_docs, read_params
from controllers.governors.quasi_static_governor import PARAMETERS as QSG
from controllers.registry import FILTERS, label, parameters, typed_params
from scenarios import registry
from scenarios.config_file import load_run_config
from scenarios.run import scenario_parameters
from scenarios.spec import Filter
from softcbf.study.definition import fold_values
from softcbf_mj.env import ArmEnvConfig
from vocabulary.settings import Bound, SettingError

DELAY = FilterParameter("a delay", "s", bound=Bound(0.0, 1.0, unit="s"), optional=True)
STEPS = FilterParameter("halvings", "1", int, Bound(1, 52))


def test_values_are_checked_and_normalised():
    assert check_parameters({"d": DELAY, "n": STEPS}, {"d": 1, "n": np.int64(12), "other": "left alone"}) == {"d": 1.0, "n": 12}
    assert DELAY.check("d", np.float32(0.5)) == 0.5 and DELAY.check("d", None) is None
    for value, message in ((-0.01, "d must be in [0, 1] s, got -0.01"), (math.nan, "d must be finite and in [0, 1] s, got nan"),
                           (True, "d must be a number in [0, 1] s, got True"), ("0.1", "d must be a number in [0, 1] s, got '0.1'"),
                           (10**400, "d must be a finite number in [0, 1] s, got an integer of 401 digits")):
        with pytest.raises(SettingError) as info:
            DELAY.check("d", value)
        assert str(info.value) == message
    with pytest.raises(SettingError, match=r"^n must be an integer in \[1, 52\], got 2\.0$"):
        STEPS.check("n", 2.0)
    with pytest.raises(ValueError, match="needs a bound"):
        FilterParameter("x", "m")


def test_every_builtin_parameter_is_declared_once_with_its_bound_in_the_docs():
    """paper-cbf, qsg and e-erg declare every signature parameter (context aside) in their table, and
    `parameter_docs` (softcbf list, docs/parameters.md) is built from it: "meaning; range [unit]"."""
    tables = {"paper-cbf": PAPER_CBF, "qsg": QSG, "e-erg": EERG}
    for name, table in tables.items():
        factory = FILTERS[name]
        assert [p.name for p in parameters(factory)] == list(table), name
        assert factory.parameter_docs == parameter_docs(table)
        for key, declared in table.items():
            doc = factory.parameter_docs[key]
            assert doc.endswith("]") and (declared.bound is None or str(declared.bound) in doc), (name, key, doc)


# Typed parameters end to end: one frozen typed mapping from every edge to the record.

REPO = Path(__file__).resolve().parents[1]
TYPED = {"kappa": 1.0, "gain_estimate": True, "gain_noise_rad": 0.0015}  # c-erg's declaration order
TAGGED = '''
import numpy as np

class Tagged:
    def __init__(self, note: str = "", scale=1.0, free=None):
        self.note, self.scale, self.free = note, scale, free

    def __call__(self, estimate, u_nom):
        return np.asarray(u_nom)
'''


def test_filter_parameters_are_a_frozen_typed_mapping_in_declaration_order():
    params = Filter("c-erg", gain_noise_rad=1.5e-3, gain_estimate=True, kappa=1).params
    assert isinstance(params, Params) and params == TYPED and list(params) == list(TYPED)
    assert type(params["kappa"]) is float
    with pytest.raises(TypeError, match="frozen"):
        params["kappa"] = 2.0
    with pytest.raises(TypeError, match="frozen"):
        params.update(kappa=2.0)
    assert pickle.loads(pickle.dumps(params)) == params and hash(params) == hash(Params(dict(params)))
    assert json.loads(json.dumps(params)) == TYPED


def test_the_same_setting_gets_the_same_typed_values_and_label_from_every_surface(tmp_path):
    contact = registry()["mujoco_contact"]
    api = contact.spec(filter=Filter("c-erg", gain_noise_rad=1.5e-3, gain_estimate=True, kappa=1))
    cli = contact.spec.from_flat(scenario_parameters(contact, [
        "--filter", "c-erg", "--filter-param", "gain_noise_rad=1.5e-3", "--filter-param", "gain_estimate=yes",
        "--filter-param", "kappa=1"]))
    run_file = tmp_path / "run.toml"
    run_file.write_text('scenario = "mujoco_contact"\nfilter = "c-erg"\n[filter_params]\n'
                        'gain_noise_rad = 1.5e-3\ngain_estimate = true\nkappa = 1\n', encoding="utf-8")
    toml = contact.spec.from_flat(load_run_config(run_file).params)
    study = contact.spec.from_flat(fold_values({"filter": "c-erg", "filter_params": {"gain_noise_rad": 1.5e-3}},
                                               {"filter_param.kappa": 1, "filter_param.gain_estimate": True}))
    specs = (api, cli, toml, study)
    for spec in specs:
        assert spec.filter.params == TYPED and list(spec.filter.params) == list(TYPED), spec.filter.params
        assert type(spec.filter.params["kappa"]) is float and spec.flat()["filter_params"] == TYPED
    assert len({spec.built.runs[0].label for spec in specs}) == 1
    assert api.built.runs[0].label == label("c-erg", {"gain_noise_rad": "1.5e-3", "kappa": "1", "gain_estimate": "on"}) \
        == "c-erg(kappa=1,gain_estimate=true,gain_noise_rad=0.0015)"
    env = ArmEnvConfig(filter="c-erg", filter_params={"gain_noise_rad": "1.5e-3", "gain_estimate": "true", "kappa": 1})
    assert env.filter_params == TYPED and type(env.filter_params["kappa"]) is float


def test_a_value_with_semicolons_and_equals_signs_passes_to_the_plug_in(tmp_path):
    plugin = tmp_path / "tagged.py"
    plugin.write_text(TAGGED, encoding="utf-8")
    spec = f"{plugin}:Tagged"
    sim = registry()["paper_sim"]
    cli = sim.spec.from_flat(scenario_parameters(sim, ["--filter", spec, "--filter-param", "note=a;b=c",
                                                       "--filter-param", "scale=2", "--filter-param", "free=x;y"]))
    assert cli.filter.params == {"note": "a;b=c", "scale": 2.0, "free": "x;y"}  # annotation, default's type, as given
    assert cli.built.runs[0].label == "Tagged(note=a;b=c,scale=2,free=x;y)"
    assert sim.spec(filter=Filter(spec, note="a;b=c", scale=2, free="x;y")).filter.params == cli.filter.params
    assert typed_params(f"{REPO / 'examples' / 'clip_filter.py'}:ClipFilter", {"limit_hPa": "80"}) == {"limit_hPa": 80.0}


def test_the_old_joined_text_is_read_with_a_deprecation_warning():
    with pytest.warns(DeprecationWarning, match="deprecated"):
        old = Filter("c-erg", params="gain_noise_rad=1.5e-3;gain_estimate=true;kappa=1")
    assert old.params == TYPED
    contact = registry()["mujoco_contact"]
    with pytest.warns(DeprecationWarning, match="--filter-param"):
        given = scenario_parameters(contact, ["--filter", "c-erg", "--filter-param",
                                              "gain_noise_rad=1.5e-3;gain_estimate=true;kappa=1"])
    assert contact.spec.from_flat(given).filter.params == TYPED
    with pytest.warns(DeprecationWarning):
        assert read_params("a=1;b=x") == {"a": "1", "b": "x"}
