"""Named filter presets (controllers.registry.PRESETS): `c-erg:recommended` means one setting on every surface
(the API, the command line, a TOML run file, the environment, the hardware file, `softcbf list`), an explicit
parameter overrides the preset's value, the run's label is the preset's short name, and an unknown preset is
refused in one line with the closest names."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import pytest

from controllers.governors.energy_governor import RECOMMENDED
from controllers.registry import FILTERS, PRESETS, label, typed_params
from hardware.config import HardwareConfig
from scenarios import registry
from scenarios.config_file import load_run_config
from scenarios.run import USAGE_ERROR, scenario_parameters
from scenarios.spec import Filter
from softcbf.cli import list_text, main
from softcbf_mj.env import ArmEnvConfig

REPO = Path(__file__).resolve().parents[1]
RECOMMENDED_FILTER = {**RECOMMENDED, "stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1}  # README, the bench's interval
TINY = ["--duration", "0.01", "--progress", "false", "--data-only"]


def test_the_recommended_preset_is_the_readme_setting_with_the_bench_plate_interval_on_every_surface(tmp_path):
    api = Filter("c-erg:recommended").params
    assert api == RECOMMENDED_FILTER and list(api) == [k for k in typed_params("c-erg", RECOMMENDED_FILTER)]
    assert label("c-erg:recommended", api) == label("c-erg:recommended") == "c-erg:recommended"
    contact = registry()["mujoco_contact"]
    cli = contact.spec.from_flat(scenario_parameters(contact, ["--filter", "c-erg:recommended"]))
    run_file = tmp_path / "run.toml"
    run_file.write_text('scenario = "mujoco_contact"\nfilter = "c-erg:recommended"\n', encoding="utf-8")
    toml = contact.spec.from_flat(load_run_config(run_file).params)
    assert cli.filter.params == toml.filter.params == api
    assert [run.label for run in cli.built.runs] == [run.label for run in toml.built.runs] == ["c-erg:recommended"]
    assert ArmEnvConfig(filter="c-erg:recommended").filter_params == api
    data = tomllib.loads((REPO / "examples" / "hardware_emulated.toml").read_text(encoding="utf-8"))
    data["robot"] = str(REPO / "examples" / data["robot"])
    hardware = HardwareConfig.from_dict({**data, "filter": "c-erg:recommended"}, REPO / "examples")
    assert hardware.control.filter_arguments() == api
    text = list_text()
    assert "c-erg:recommended: " in text and "gain_noise_rad=0.0015" in text and "stiffness_lo_ratio=0.9" in text


def test_an_explicit_parameter_overrides_the_preset_and_the_label_names_only_the_change():
    contact = registry()["mujoco_contact"]
    cli = contact.spec.from_flat(scenario_parameters(contact, ["--filter", "c-erg:recommended",
                                                               "--filter-param", "gain_noise_rad=3e-3"]))
    api = Filter("c-erg:recommended", gain_noise_rad=0.003).params
    assert cli.filter.params == api == {**RECOMMENDED_FILTER, "gain_noise_rad": 0.003}
    assert [run.label for run in cli.built.runs] == ["c-erg:recommended(gain_noise_rad=0.003)"]
    assert ArmEnvConfig(filter="c-erg:recommended", filter_params={"gain_noise_rad": 3e-3}).filter_params == api


def test_a_preset_runs_under_its_short_label_and_replays_to_it(tmp_path, capsys):
    out, replay = tmp_path / "run", tmp_path / "replay"
    assert main(["run", "paper_sim", "--filter", "c-erg:recommended", *TINY, "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert [run["tuning"] for run in summary["runs"]] == ["c-erg:recommended"]
    assert summary["runs"][0]["filter"] == "c-erg:recommended" and summary["runs"][0]["filter_params"] == RECOMMENDED_FILTER
    assert [p.name for p in (out / "timeseries").iterdir()] == ["c-erg_recommended.npz"]
    assert main(["run", "--config", str(out / "config.json"), "--out", str(replay), "--data-only"]) == 0
    again = json.loads((replay / "summary.json").read_text(encoding="utf-8"))
    assert again["params"]["filter_params"] == summary["params"]["filter_params"] == RECOMMENDED_FILTER
    assert [run["tuning"] for run in again["runs"]] == ["c-erg:recommended"]


@pytest.mark.parametrize("spec", ["c-erg:recomended", "c-erg:recommend"])
def test_an_unknown_preset_is_refused_in_one_line_with_the_closest_names(tmp_path, capsys, spec):
    assert main(["run", "paper_sim", "--filter", spec, *TINY, "--out", str(tmp_path / "run")]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"unknown preset {spec!r} (did you mean 'c-erg:recommended'?)" in err, err
    assert not (tmp_path / "run").exists()
    with pytest.raises(ValueError, match="did you mean 'c-erg:recommended'"):
        Filter(spec)


def test_every_preset_names_a_builtin_and_takes_its_declared_parameters():
    for name, preset in PRESETS.items():
        assert preset.filter in FILTERS and name.startswith(f"{preset.filter}:")
        assert typed_params(name) == typed_params(preset.filter, preset.params)


def test_the_learning_preset_is_the_standard_box_setting_learning_the_plate_on_an_exact_state():
    """c-erg:learn-plate differs from c-erg:standard-box only in learning the plate and trusting the state to 1e-4
    rad (docs/beyond-the-paper.md: a camera's Δ reads the force too loosely to learn)."""
    box, learning = Filter("c-erg:standard-box").params, Filter("c-erg:learn-plate").params
    changed = {k: learning[k] for k in learning if k not in box or learning[k] != box[k]}
    assert changed == {"plate_estimate": True, "gain_noise_rad": 1e-4} and set(box) <= set(learning)
    assert box["gain_noise_rad"] == 1.5e-3 and "plate_estimate" not in box  # off: its declared default
