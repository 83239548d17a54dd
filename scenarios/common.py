"""Builders shared by scenarios: parameter checks, robot, environment, force-safe set, the
controller runs (filter, its parameters and tunings; the nominal controller), the scene
record, one run and the saving of a finished run (with its report and recording).

Every scenario takes the controller under test as its spec's `Filter` and `Nominal` sections
(scenarios.spec; flat names, docs/extending.md):
- `filter`: a registry spec (`controllers.registry`: "paper-cbf", "none", "qsg", "e-erg",
  "c-erg:recommended", a preset of `controllers.registry.PRESETS`, FILE.py:Factory,
  package.module:Factory); `filter_params`: its typed parameters (`controllers.contract.filter_parameters.Params`,
  the command line's repeated `--filter-param name=value`, a TOML table);
- `tunings`: for "paper-cbf", a tuple of its presets (("None", "High"); the comma list
  "None,High" on the command line and in files), or "custom" (a_E, b_E and gamma from
  filter_params): one run each, labelled by the preset (each named once) (a `tuning` in
  filter_params makes one run of that tuning); other filters make one run, labelled
  `Factory(name=value,...)` or by the preset's name (`controllers.registry.label`);
- `nominal`, `nominal_params`: likewise ("sinusoid", "tip-tracker", FILE.py:Factory);
  the sinusoid's amplitude, frequency and t0 default to the scenario's parameters.
summary.json's rows keep "tuning" as the run's label and add "filter", "filter_params",
"nominal" and "nominal_params".

A scenario's spec is checked when it is built (scenarios.spec: every value against the
vocabulary, then the scenario's check, built from `check_controller`, `check_choice` and the
loaders here, whose errors name the parameter and the file); the scenario adds
`softcbf_mj.loops.loop.check_duration` before it writes anything, so that a rejected command
leaves no output behind and a study refuses a bad file at load.

Parsed once. The check builds what it checks, and the spec keeps it (`spec.built`,
scenarios.spec): `check_controller` returns the `Controller` (the controller's robot, its
force-safe set, the runs with their parsed parameters, the nominal's parameters), which the
scenario's setup takes as it is; the robot file is read, the safe set built and the plug-in
parameters parsed once per spec.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import numpy as np

from closedloop.isolation import check_in_child, isolate
from closedloop.monitor import SafetyMonitor
from closedloop.step import ControlStep, FilterFault, write_fault_log
from controllers.model.params import RobotParams
from controllers.contract.filter_parameters import Params, read_params
from controllers.registry import (FILTERS, NOMINALS, build_filter, build_nominal, check_filter, check_nominal, is_builtin,
                                  label, typed_params)
from controllers.cbf.qp import available_backends
from controllers.model.safe_set import Environment, ForceSafeSet, LinearStiffness, paper_environment
from controllers.contract.capabilities import filter_capabilities
from controllers.contract.safety_filter import Estimate, FilterContext
from softcbf_mj.loops.loop import Series, exact_state, run_closed_loop
from softcbf_mj.outputs.metrics import run_figures
from softcbf_mj.physics.ground_truth import (  # noqa: F401  (scenarios take the robot files from the ground truth's module)
    ROBOT_PRESETS, existing_file, load_robot, read_parameter_file, scale_damping,
)
from softcbf_mj.physics.plant import Plant, PlantState
from softcbf_mj.outputs.progress import Progress
from softcbf_mj.outputs.runio import SummaryWriter, save_timeseries, stiffness_to_json
from scenarios.run_outputs import after_each_run, data_only, outputs_on, write_outputs  # noqa: F401  (data_only: here for its users)
from scenarios.spec import Filter, Model, Nominal

if TYPE_CHECKING:  # rerun takes seconds to import: softcbf_mj.outputs.recording is imported only when recording
    from softcbf_mj.outputs.recording import LiveRun


def check_choice(name: str, value: str, valid: Sequence[str]) -> None:
    """ValueError naming the parameter and the valid values unless `value` is one of them."""
    if value not in valid:
        raise ValueError(f"{name} must be one of {', '.join(valid)}, got {value!r}")


def load_environment(spec: str) -> Environment:
    """'paper' → the paper's facet; otherwise a JSON file {"H": [[a, b], ...], "h": [...]} (m)."""
    if spec == "paper":
        return paper_environment()
    path = existing_file("environment", spec, "'paper' or a JSON file with keys H and h")
    return read_parameter_file("environment", path, _read_environment)


def _read_environment(path: Path) -> Environment:
    data = json.loads(path.read_text(encoding="utf-8"))
    missing = {"H", "h"} - set(data) if isinstance(data, dict) else {"H", "h"}
    if missing:
        raise ValueError(f"it needs a JSON object with keys H and h (m), lacking {', '.join(sorted(missing))}")
    return Environment(np.asarray(data["H"], dtype=float), np.asarray(data["h"], dtype=float))


def controller_robot(model: Model) -> RobotParams:
    """The controller's robot model: `model.robot` with its damping × `model.damping_scale`
    (softcbf_mj.physics.ground_truth's module docstring)."""
    return scale_damping(load_robot(model.robot), model.damping_scale)


def build_safe_set(environment: str, plate_stiffness: float, f_max: float, row_scaling: str) -> ForceSafeSet:
    return ForceSafeSet(load_environment(environment), LinearStiffness(plate_stiffness), f_max, row_scaling=row_scaling)


PAPER_FILTER = "paper-cbf"


@dataclass(frozen=True)
class ControllerRun:
    """One run's controller under test: its label (summary.json's "tuning"), filter spec and parameters, and
    whether the filter and the nominal run isolated (`control_step`)."""

    label: str
    filter: str
    filter_params: Params
    isolate: bool


def controller_runs(spec: Filter, labels: Sequence[str] | None = None) -> list[ControllerRun]:
    """The runs of a scenario's controller under test `spec` (module docstring; its `qp_backend`
    is the paper filter's unless its parameters set it); errors name the parameter and the valid values.
    `labels`: the runs' labels as an isolated check found them (`check_controller`), else `label`'s."""
    params = read_params(spec.params)
    name = spec.name.strip()
    if name != PAPER_FILTER:
        return [ControllerRun(label(name, params) if labels is None else labels[0], name, params, spec.isolate)]
    names = [params["tuning"]] if "tuning" in params else list(spec.tunings)
    if not names:
        raise ValueError("tunings must name at least one tuning, e.g. None,Low,High (or custom with a_E, b_E, gamma)")
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:  # each run is labelled by its tuning and writes the time series of that label
        raise ValueError(f"tunings must name each tuning once (one run and one time series each), got "
                         f"{', '.join(repeated)} more than once in {','.join(names)}")
    runs = []
    for i, tuning in enumerate(names):
        run_params = typed_params(name, {"qp_backend": spec.qp_backend, **params, "tuning": tuning})
        runs.append(ControllerRun(label(name, run_params) if labels is None else labels[i], name, run_params,
                                  spec.isolate))
    return runs


def nominal_arguments(spec: Nominal) -> dict[str, object]:
    """The nominal controller's parameters: its `params` (typed, `scenarios.spec`), over the
    sinusoid's amplitude, frequency and t0 when the nominal is the sinusoid."""
    params = read_params(spec.params)
    if spec.name.strip() != "sinusoid":
        return params
    return {"amplitude": spec.amplitude, "frequency": spec.frequency, "t0": spec.t0, **params}


def control_step(run: ControllerRun, nominal: str, nominal_kwargs: dict[str, object], context: FilterContext,
                 monitor: SafetyMonitor | None = None) -> ControlStep:
    """The control step of `run`: its filter and the nominal controller, each told its own copy of `context`
    (`FilterContext.copy`; with `run.isolate`, built and called in a process of their own,
    `closedloop.isolation`, which ends with the step), so that the step's limits, read from `context` itself,
    are fixed before any plug-in code runs and nothing a plug-in does to what it was told reaches them."""
    if run.isolate:
        filters, nominals = isolate(context, [(run.filter, run.filter_params)], [(nominal, nominal_kwargs)])
        return ControlStep(filters[0], nominals[0], context, monitor)
    safety_filter = build_filter(run.filter, run.filter_params, context.copy())
    return ControlStep(safety_filter, build_nominal(nominal, nominal_kwargs, context.copy()), context, monitor)


def controller_row(run: ControllerRun, nominal: str, nominal_kwargs: dict[str, object]) -> dict[str, Any]:
    """summary.json's fields that name the controller under test."""
    return {"filter": run.filter, "filter_params": dict(run.filter_params), "nominal": nominal,
            "nominal_params": {k: v for k, v in nominal_kwargs.items()}}


@dataclass(frozen=True, eq=False)
class Controller:
    """A spec's controller, parsed once when the spec is built (`check_controller`).

    robot: the controller's robot (`controller_robot`: damping × damping_scale); safe_set: its
    force-safe set; runs: the controllers under test (`controller_runs`, parameters parsed);
    nominal_kwargs: the nominal's parameters (`nominal_arguments`).
    """

    robot: RobotParams
    safe_set: ForceSafeSet
    runs: tuple[ControllerRun, ...]
    nominal_kwargs: dict[str, object]


def check_controller(filter: Filter, nominal: Nominal, model: Model, assumed_stiffness: float) -> Controller:
    """The checks of a spec's controller shared by every scenario (its spec's `check`): the
    controller under test (the filter's spec resolves and takes its parameters, the tunings;
    nothing is built: `controllers.registry.check_filter`), the nominal and the parameters it
    will be built with, the controller's robot, its force-safe set (`model` and the plate
    stiffness the controller assumes, `assumed_stiffness` N/m) and the QP backend. Returns
    what it parsed and built (`Controller`), for the scenario's setup."""
    if filter.isolate and not (is_builtin(filter.name, FILTERS) and is_builtin(nominal.name, NOMINALS)):
        # the user's modules are imported in an isolated process only (closedloop.isolation)
        labels = check_in_child(plugin_labels, filter, nominal)
        runs, nominal_kwargs = tuple(controller_runs(filter, labels)), nominal_arguments(nominal)
    else:
        runs, nominal_kwargs = check_plugins(filter, nominal)
    robot = controller_robot(model)
    safe_set = model_safe_set(model, assumed_stiffness)
    check_choice("qp_backend", filter.qp_backend, available_backends())
    return Controller(robot, safe_set, runs, nominal_kwargs)


def check_plugins(filter: Filter, nominal: Nominal) -> tuple[tuple[ControllerRun, ...], dict[str, object]]:
    """`check_controller`'s checks of the filter's and the nominal's specs and parameters (each resolved, nothing
    built): the runs and the nominal's parameters; ValueError naming the filter or the nominal."""
    try:
        runs = tuple(controller_runs(filter))
        for run in runs:
            check_filter(run.filter, run.filter_params)
    except ValueError as exc:
        raise ValueError(f"filter {filter.name!r}: {exc}") from None
    try:
        nominal_kwargs = nominal_arguments(nominal)
        check_nominal(nominal.name, nominal_kwargs)
    except ValueError as exc:
        raise ValueError(f"nominal {nominal.name!r}: {exc}") from None
    return runs, nominal_kwargs


def plugin_labels(filter: Filter, nominal: Nominal) -> list[str]:
    """The run labels of `check_plugins` (what an isolated check sends back)."""
    return [run.label for run in check_plugins(filter, nominal)[0]]


def model_safe_set(model: Model, assumed_stiffness: float) -> ForceSafeSet:
    """The controller's force-safe set: `model`'s facets, F_max and row scaling, ψ(n) = `assumed_stiffness` · n."""
    return build_safe_set(model.environment, assumed_stiffness, model.f_max, model.row_scaling)


def initial_configuration(n_segments: int, seed: int, q0_std: float) -> np.ndarray:
    """Straight arm, plus seeded Gaussian noise of q0_std rad per segment."""
    if not (math.isfinite(q0_std) and 0 <= q0_std <= math.pi):
        raise ValueError(f"q0_std must be in [0, pi] rad, got {q0_std}")
    if seed < 0:  # numpy's generators take seeds >= 0
        raise ValueError(f"seed must be an integer >= 0, got {seed}")
    return np.random.default_rng(seed).normal(0.0, q0_std, n_segments) if q0_std > 0 else np.zeros(n_segments)


def scene_record(arm: RobotParams, safe_set: ForceSafeSet, plate_stiffness: float,
                 plates: Environment | None = None) -> dict[str, Any]:
    """summary.json's "scene" (format: softcbf_mj.outputs.runio): the true arm's segment lengths,
    the controller's facets, P, n_max, F_max and ψ (`safe_set`), the true plates' spring
    (`plate_stiffness`, N/m) and surfaces at rest (`plates`; default: the controller's facets)."""
    env = safe_set.environment
    plates = env if plates is None else plates
    return {
        "segment_lengths_m": list(arm.lengths),
        "facets": {"H": env.H, "h": env.h},
        "plates": {"H": plates.H, "h": plates.h},
        "force_safe_set": {"H_prime": safe_set.H_prime, "h_prime": safe_set.h_prime,
                           "is_vertex_correction": safe_set.is_vertex_correction, "row_scaling": safe_set.row_scaling},
        "n_max_m": safe_set.n_max,
        "f_max_N": safe_set.f_max,
        "stiffness": stiffness_to_json(safe_set.stiffness),
        "plate_stiffness_N_per_m": float(plate_stiffness),
    }


def run_tuning(
    out_dir: Path,
    summary: SummaryWriter,
    label: str,
    plant: Plant,
    step: ControlStep,
    safe_set: ForceSafeSet,
    duration: float,
    q0: np.ndarray,
    show_progress: bool,
    estimator: Callable[[PlantState], Estimate] = exact_state,
    extra_figures: Callable[[dict[str, np.ndarray]], dict[str, Any]] | None = None,
    extra_units: dict[str, str] | None = None,
    row: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run one controller in the closed loop and `save_run` it; return its summary row."""
    progress = Progress(f"{summary.data['scenario']} {label}", int(round(duration / plant.control_dt)), enabled=show_progress,
                        unit_s=plant.control_dt)
    start = time.perf_counter()
    series = run_closed_loop(plant, step, safe_set, duration, q0, estimator=estimator, progress=progress,
                             live=live_run(summary, label, plant.control_dt))
    wall = time.perf_counter() - start
    return save_run(out_dir, summary, label, series, wall, plant.control_dt, filter_enabled(step), extra_figures,
                    extra_units, row, step.fault)


def live_run(summary: SummaryWriter, label: str, control_dt: float, camera: bool = False) -> LiveRun | None:
    """The live stream of run `label` (softcbf_mj.outputs.recording.live_run: a viewer spawned by
    `--spawn`), or None: none is active, or the report and recording are off (`data_only`)."""
    if not outputs_on():
        return None
    from softcbf_mj.outputs.recording import live_run as recording_live_run  # rerun: +6.8 s to import, only when recording

    return recording_live_run(summary.data.get("scene"), label, len(summary.data["runs"]), control_dt, camera)


def stop_after(row: Mapping[str, Any]) -> bool:
    """True when the run of summary row `row` ended on a filter fault: the scenario runs no
    further tunings (docs/safety-filter.md: the run stops after the vent; the command exits 1)."""
    return bool(row.get("fault"))


def filter_enabled(step: ControlStep) -> bool:
    """False for a filter that declares passthrough (`controllers.contract.capabilities.Capabilities`): no filter times."""
    return not filter_capabilities(step.filter).passthrough


def save_run(
    out_dir: Path,
    summary: SummaryWriter,
    label: str,
    series: Series,
    wall_s: float,
    control_dt: float,
    filtered: bool,
    extra_figures: Callable[[dict[str, np.ndarray]], dict[str, Any]] | None = None,
    extra_units: dict[str, str] | None = None,
    row_fields: dict[str, Any] | None = None,
    fault: FilterFault | None = None,
) -> dict[str, Any]:
    """Save a finished run `label`: its figures (`run_figures` plus `extra_figures(log)`),
    its time series (`series`: columns and units, plus `extra_units` for the plant's
    extras) and its summary.json row (with `row_fields`, e.g. `controller_row`); then
    draw the report and the recording from the folder where `scenarios.run_outputs.after_each_run` (so an
    interrupted scenario leaves both for its finished runs; `Scenario.run` draws them once at its end, `data_only()`
    never). Returns the row.

    `fault`: the filter fault the run ended on (`ControlStep.fault`): the row gains `fault`
    (`FilterFault.to_json`) and its scalars `fault_type`, `fault_where`, `fault_message` (for
    study tables), and the traceback goes to the folder's `fault_LABEL.log`. A scenario
    stops after such a run (`stop_after`)."""
    log, units = series
    row: dict[str, Any] = {"tuning": label}
    row.update(row_fields or {})
    if fault is not None:
        row.update(fault.row_fields())
        write_fault_log(out_dir, label, fault)
    row.update(run_figures(log, control_dt, filtered, wall_s))
    if extra_figures is not None:
        row.update(extra_figures(log))
    if row.get("certified_truth_outside"):
        print(f"warning: run {label}: the filter's certified interval of {row['certified_truth_outside']} excluded "
              f"the true value for {row['certified_truth_outside_s']:.3g} s: this run is no evidence for its guarantee "
              f"(docs/run-outputs.md)", file=sys.stderr)
    units = dict(units)
    units.update(extra_units or {})
    row["timeseries"] = str(save_timeseries(out_dir, label, log, units).relative_to(out_dir))
    summary.add_run(row)
    if after_each_run():
        write_outputs(out_dir)
    return row
