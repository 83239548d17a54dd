"""Run configuration files: a scenario and its parameters in one file (`softcbf run --config FILE`).

Two formats, told apart by the suffix:

- `.toml`: `scenario = "NAME"` and any of the scenario's parameters, by their names
  (docs/parameters.md); `filter_params` and `nominal_params` may be tables
  (`[filter_params]` with `tuning = "Low"`), whose values the plug-in types by its declarations
  (as the command line's --filter-param items; the old "name=value;..." text is read with a
  DeprecationWarning), `filter = "c-erg:recommended"` a preset, and `tunings` a list (`tunings = ["Low", "High"]`) or the comma list. Example
  (docs/file-formats.md#run-configuration-toml):

      scenario = "paper_sim"
      duration = 10.0
      tunings = "Low,High"
      [filter_params]
      slack_weight = 1e4

- `.json`: a run folder's config.json (softcbf_mj.outputs.runio: {"scenario", "params", ...}),
  whose "params" hold every parameter of the run (a plug-in's parameters as the object of their typed
  values): `softcbf run --config DIR/config.json`
  replays that run (same parameters, same seed, so the same time series on the same
  versions, which config.json also records).

Command-line parameters given with `--config` override the file's. `load_run_config`
checks the file's shape (unknown keys are the scenario's to refuse, with its list of
parameters, when the run checks them); errors are ValueErrors naming the file and the key.

A replay is bit-identical only with the recorded seed on the recorded versions (MuJoCo's
results, numpy's generators and the solvers change between releases). `replay_warnings`
says, one line each, where a replay departs from that: every version config.json records
(softcbf_mj, mujoco, python, numpy, ..., platform; `softcbf_mj.outputs.runio.versions`) that
differs from the running one, a config.json that records none, and a seed that the
command line changes.

A replay runs the same filter and nominal code, or refuses: config.json records, for a
`FILE.py:Factory` spec, the file's absolute path and SHA-256 ("sources",
controllers.registry.recorded_sources). `replay_sources` points the replay's spec at that
recorded file (not at whatever the relative path names in the folder the replay starts from)
and refuses, one line, when the file is missing or its content differs from the recorded
hash; `allow_changed` (`softcbf run --allow-changed-filter`) runs the changed file instead,
with a warning. A config.json written before the hash was recorded resolves the relative path
against its recorded working folder ("cwd") and warns that the file cannot be checked. A spec
that the command line replaces (`--filter other.py:F`) is not checked.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from controllers.registry import SPEC_SETTINGS, file_sha256, spec_file
from vocabulary.files import read_settings_file
from vocabulary.sections import TABLE_PARAMETERS, joined
from vocabulary.settings import SETTINGS, flat_form

SCENARIO_KEY = "scenario"


@dataclass(frozen=True)
class RunConfig:
    """A scenario's name and the parameters a configuration file gives it."""

    scenario: str
    params: dict[str, Any]
    versions: dict[str, Any] | None = None  # a run folder's config.json: the versions it recorded (None: a TOML file)
    path: Path | None = None
    sources: dict[str, dict[str, str]] | None = None  # config.json's "sources": setting → {"path", "sha256"}
    cwd: str | None = None  # config.json's "cwd": the working folder the recorded run started in


def _from_toml(path: Path, data: Mapping[str, Any]) -> RunConfig:
    params = {k: flat_form(k, joined(k, v)) if k in SETTINGS else v for k, v in data.items() if k != SCENARIO_KEY}
    for key, value in params.items():
        if isinstance(value, (Mapping, list)) and key not in TABLE_PARAMETERS:
            raise ValueError(f"run configuration {path}: {key} must be a single value, got {value!r}")
    return RunConfig(data[SCENARIO_KEY], params, path=path)


def _from_run_folder(path: Path, data: Mapping[str, Any]) -> RunConfig:
    params = data.get("params")
    if not isinstance(params, Mapping):
        raise ValueError(f"run configuration {path}: a run folder's config.json needs a \"params\" object "
                         f"(docs/run-outputs.md), got {params!r}")
    versions = data.get("versions", {})
    if not isinstance(versions, Mapping):
        raise ValueError(f"run configuration {path}: \"versions\" must be an object {{name: version}}, got {versions!r}")
    sources = data.get("sources", {})
    if not isinstance(sources, Mapping) or not all(
            isinstance(r, Mapping) and isinstance(r.get("path"), str) and isinstance(r.get("sha256"), str)
            for r in sources.values()):
        raise ValueError(f"run configuration {path}: \"sources\" must be an object {{setting: {{\"path\", \"sha256\"}}}}, "
                         f"got {sources!r}")
    cwd = data.get("cwd")
    return RunConfig(data[SCENARIO_KEY], dict(params), dict(versions), path, {k: dict(v) for k, v in sources.items()},
                     cwd if isinstance(cwd, str) else None)


def replay_sources(config: RunConfig, params: Mapping[str, Any], allow_changed: bool = False) -> tuple[dict[str, Any], list[str]]:
    """`config.params` with each filter or nominal `FILE.py:Factory` spec that the replay keeps (`params`: the final
    parameters) pointing at the recorded file, and the warnings, one line each (module docstring). ValueError, one
    line, when that file is missing or differs from the recorded SHA-256 (unless `allow_changed`)."""
    base, lines = dict(config.params), []
    for key in SPEC_SETTINGS:
        found = spec_file(config.params.get(key))
        if found is None or params.get(key) != config.params[key]:
            continue
        written, factory = found
        record = (config.sources or {}).get(key)
        if record is not None:
            path = Path(record["path"])
        elif config.cwd is not None and not written.is_absolute():
            path = Path(config.cwd) / written
        else:
            path = written
        if not path.is_file():
            raise ValueError(f"run configuration {config.path}: the {key} file {path} of the recorded run "
                             f"({config.params[key]}) no longer exists")
        if record is None:
            lines.append(f"warning: {config.path} records no SHA-256 of the {key} file {path}: the replay runs it as it "
                         "is now, which may not be the code of the recorded run")
        elif (now := file_sha256(path)) != record["sha256"]:
            if not allow_changed:
                raise ValueError(f"run configuration {config.path}: the {key} file {path} changed since the run was "
                                 f"recorded (SHA-256 {record['sha256'][:12]}... recorded, {now[:12]}... now); "
                                 "--allow-changed-filter replays it as it is now")
            lines.append(f"WARNING: --allow-changed-filter: the {key} file {path} changed since the run was recorded "
                         f"(SHA-256 {record['sha256'][:12]}... recorded, {now[:12]}... now): this replay is NOT the "
                         "recorded run")
        base[key] = f"{path}:{factory}"
    return base, lines


def replay_warnings(config: RunConfig, params: Mapping[str, Any], running: Mapping[str, Any]) -> list[str]:
    """The warnings of a replay of `config` (a run folder's config.json; none for a TOML file) with the final
    parameters `params` on the `running` versions (module docstring), one line each."""
    if config.versions is None:
        return []
    if not config.versions:
        return [f"warning: {config.path} records no versions: the replay may not be bit-identical to the recorded run"]
    lines = [f"warning: {config.path} was recorded with {name} {recorded}, this is {name} {running.get(name)}: "
             "the replay may not be bit-identical to the recorded run"
             for name, recorded in config.versions.items() if running.get(name) != recorded]
    if "seed" in config.params and params.get("seed") != config.params["seed"]:
        lines.append(f"warning: --seed {params.get('seed')} overrides the seed {config.params['seed']} recorded in "
                     f"{config.path}: the replay will not be bit-identical to the recorded run")
    return lines


def load_run_config(path: str | Path) -> RunConfig:
    """Read a run configuration file (module docstring); ValueError naming the file and the key."""
    path = Path(path)
    data = read_settings_file(path, "run configuration", missing_hint="a .toml file, or a run folder's config.json")
    if not isinstance(data.get(SCENARIO_KEY), str):
        raise ValueError(f"run configuration {path} needs scenario = \"NAME\" (softcbf list), got {data.get(SCENARIO_KEY)!r}")
    return (_from_toml if path.suffix == ".toml" else _from_run_folder)(path, data)
