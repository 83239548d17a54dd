"""Run configuration files: a scenario and its parameters in one file (`softcbf run --config FILE`).

Two formats, told apart by the suffix:

- `.toml`: `scenario = "NAME"` and any of the scenario's parameters, by their names
  (docs/parameters.md); `filter_params` and `nominal_params` may be tables
  (`[filter_params]` with `tuning = "Low"`), joined to "name=value;..." as on the command
  line. Example (docs/file-formats.md#run-configuration-toml):

      scenario = "paper_sim"
      duration = 10.0
      tunings = "Low,High"
      [filter_params]
      slack_weight = 1e4

- `.json`: a run folder's config.json (softcbf_mj.runio: {"scenario", "params", ...}),
  whose "params" hold every parameter of the run: `softcbf run --config DIR/config.json`
  replays that run (same parameters, same seed, so the same time series on the same
  versions, which config.json also records).

Command-line parameters given with `--config` override the file's. `load_run_config`
checks the file's shape (unknown keys are the scenario's to refuse, with its list of
parameters, when the run checks them); errors are ValueErrors naming the file and the key.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vocabulary.files import read_settings_file

SCENARIO_KEY = "scenario"
TABLE_PARAMETERS = ("filter_params", "nominal_params")  # "name=value;..." strings, also given as tables


@dataclass(frozen=True)
class RunConfig:
    """A scenario's name and the parameters a configuration file gives it."""

    scenario: str
    params: dict[str, Any]


def joined(name: str, value: Any) -> Any:
    """A `filter_params` / `nominal_params` table as the "name=value;name=value" string the scenario takes."""
    if name in TABLE_PARAMETERS and isinstance(value, Mapping):
        return ";".join(f"{k}={v}" for k, v in value.items())
    return value


def _from_toml(path: Path, data: Mapping[str, Any]) -> RunConfig:
    params = {k: joined(k, v) for k, v in data.items() if k != SCENARIO_KEY}
    for key, value in params.items():
        if isinstance(value, (Mapping, list)):
            raise ValueError(f"run configuration {path}: {key} must be a single value, got {value!r}")
    return RunConfig(data[SCENARIO_KEY], params)


def _from_run_folder(path: Path, data: Mapping[str, Any]) -> RunConfig:
    params = data.get("params")
    if not isinstance(params, Mapping):
        raise ValueError(f"run configuration {path}: a run folder's config.json needs a \"params\" object "
                         f"(docs/run-outputs.md), got {params!r}")
    return RunConfig(data[SCENARIO_KEY], dict(params))


def load_run_config(path: str | Path) -> RunConfig:
    """Read a run configuration file (module docstring); ValueError naming the file and the key."""
    path = Path(path)
    data = read_settings_file(path, "run configuration", missing_hint="a .toml file, or a run folder's config.json")
    if not isinstance(data.get(SCENARIO_KEY), str):
        raise ValueError(f"run configuration {path} needs scenario = \"NAME\" (softcbf list), got {data.get(SCENARIO_KEY)!r}")
    return (_from_toml if path.suffix == ".toml" else _from_run_folder)(path, data)
