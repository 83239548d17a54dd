"""Scenario registry: every scenario is a function of its spec, registered by name.

A scenario is a function `fn(out_dir: Path, spec: Spec) -> dict` that runs, writes its
outputs into `out_dir` (docs/run-outputs.md) and returns the summary it wrote; `Spec` is its
typed, frozen configuration (`scenarios.spec.scenario_spec`: the sections it uses and its own
settings, checked when built). `register(name, description, Spec)` registers it; the
`Scenario` keeps the spec class and derives from it the flat entry point
`Scenario.run(out_dir, **params)` (keyword parameters by the settings' flat names, with
their types and the scenario's defaults: `inspect.signature(scenario.run)`), which the
command line, `--help`, `softcbf list`, run files, config.json replay and studies use.
`python -m scenarios --list` lists them; `python -m scenarios NAME --out DIR
[--param value ...]` runs one.

Checking without running. `Scenario.validate(params)` gives the full flat parameters
(the defaults updated with `params`) after every check a run makes first, without
building or running anything expensive: every name is a parameter; every value has its
type (an int is accepted for a float and becomes one); then the spec is built, which
checks every value against its declared range (`vocabulary.settings.check_value`), the
scenario's narrower bounds and its own check (files, names, the filter's parameters).
Errors are `ValueError`s that name the parameter, the valid range and the value received.

Documentation. Every parameter's meaning and unit are declared once for all scenarios
(`vocabulary.settings.SETTINGS`, shared with the hardware file and the studies), and so
is its valid range; a scenario's `bounds` (its spec's) narrow that range for it
(camera_loop's image size <= its render's), and `Scenario.valid` shows the scenario's
range, else the declared one.

Batch form (optional, studies: docs/studies.md#batches). `register(..., batch=BatchForm(key, run))`
lets a study run many samples of the scenario in one batched closed loop:
`key(kwargs)` is what samples must share to run in one batch (hashable; None: this
sample cannot be batched), `run(kwargs_list, nthread)` runs the validated flat parameters
of samples with one key together (optional third argument `progress`: called with the fraction
of the batch's run done, `softcbf_mj.loops.batch_loop.run_batch_closed_loop`) and returns one row of run figures per
sample (`softcbf_mj.loops.batch_loop.BatchRun.run`), equal to the single run's fields of the
same names.
"""

from __future__ import annotations

import importlib
import inspect
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Hashable, Mapping, Sequence

from controllers.contract.filter_parameters import Params, read_params
from controllers.registry import did_you_mean
from scenarios.run_outputs import once_at_end
from scenarios.spec import flat_parameters
from vocabulary.settings import setting

_MODULES = ("scenarios.paper_sim", "scenarios.mujoco_contact", "scenarios.camera_loop", "scenarios.pcc_contact")


@dataclass(frozen=True)
class BatchForm:
    """A scenario's batch form (module docstring): `key(kwargs) -> Hashable | None`,
    `run(kwargs_list, nthread, progress=None) -> list[dict]` (one row of run figures per sample)."""

    key: Callable[[Mapping[str, Any]], Hashable | None]
    run: Callable[..., list[dict[str, Any]]]


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    spec: type  # the scenario's spec class (scenarios.spec.scenario_spec)
    function: Callable[[Path, Any], dict]  # fn(out_dir, spec)
    batch: "BatchForm | None" = None
    run: Callable[..., dict] = field(init=False, repr=False, compare=False)  # the flat entry point (module docstring)

    def __post_init__(self) -> None:
        object.__setattr__(self, "run", flat_entry(self.function, self.spec))

    @property
    def bounds(self) -> Mapping[str, Any]:
        """Flat name → the scenario's narrower range (scenarios.common.Bound: str() says it)."""
        return self.spec.BOUNDS

    def parameters(self) -> dict[str, inspect.Parameter]:
        """Keyword parameters of the scenario, by name (out_dir excluded)."""
        return flat_parameters(self.spec)

    def defaults(self) -> dict[str, Any]:
        return {k: p.default for k, p in self.parameters().items()}

    def coerce(self, name: str, value: Any) -> Any:
        """`value` as parameter `name`'s type (int → float for floats; floats finite), else ValueError (its range
        is the spec's check)."""
        params = self.parameters()
        if name not in params:
            raise ValueError(f"scenario {self.name!r} has no parameter {name!r}; parameters: {', '.join(params)}")
        annotation = params[name].annotation
        if annotation is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ValueError(f"parameter {name!r} must be a finite number, got {value!r}")
            return float(value)
        if annotation is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if annotation in (bool, str) and isinstance(value, annotation):
            return value
        if annotation is Params:
            return read_params(value)  # a plug-in's parameters: a table (the old text with a DeprecationWarning)
        if setting(name).kind is tuple and isinstance(value, (list, tuple)):
            return value  # a sequence of names (the spec checks them): the flat form's comma list, as a list
        raise ValueError(f"parameter {name!r} takes {annotation.__name__} values, got {value!r}")

    def valid(self, name: str) -> str:
        """Parameter `name`'s valid values: the scenario's narrower bound, else the declared ones (vocabulary.settings)."""
        if name in self.bounds:
            return str(self.bounds[name])
        return setting(name).valid_values

    def build(self, params: Mapping[str, Any]) -> Any:
        """The scenario's spec of flat `params` (the others: its defaults), checked (module docstring)."""
        return self.spec.from_flat({name: self.coerce(name, value) for name, value in params.items()})

    def validate(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """The full flat parameters (defaults updated with `params`), checked without running (module docstring)."""
        return self.build(params).flat()


def flat_entry(function: Callable[[Path, Any], dict], spec_cls: type) -> Callable[..., dict]:
    """`run(out_dir, **params)`: `function(out_dir, spec_cls.from_flat(params))`, whose signature and
    annotations are the spec's flat parameters (`scenarios.spec.flat_parameters`); the run folder's report and
    recording are drawn once, at its end (`scenarios.run_outputs.once_at_end`)."""

    def run(out_dir: Path, **params: Any) -> dict:
        spec = spec_cls.from_flat(params)
        with once_at_end(Path(out_dir)):
            return function(Path(out_dir), spec)

    parameters = flat_parameters(spec_cls)
    out_dir = inspect.Parameter("out_dir", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=Path)
    run.__signature__ = inspect.Signature([out_dir, *parameters.values()], return_annotation=dict)  # type: ignore[attr-defined]
    run.__annotations__ = {"out_dir": Path, **{k: p.annotation for k, p in parameters.items()}, "return": dict}
    run.__name__ = run.__qualname__ = function.__name__
    run.__doc__ = function.__doc__
    return run


_REGISTRY: dict[str, Scenario] = {}


def register(name: str, description: str, spec: type,
             batch: BatchForm | None = None) -> Callable[[Callable[[Path, Any], dict]], Callable[[Path, Any], dict]]:
    """Decorator: register `fn(out_dir, spec)` as scenario `name` with a one-line description, its
    spec class `spec` (scenarios.spec.scenario_spec, whose context is `name`) and its batch form."""

    def wrap(fn: Callable[[Path, Any], dict]) -> Callable[[Path, Any], dict]:
        if name in _REGISTRY:
            raise ValueError(f"scenario {name!r} is registered twice")
        if spec.CONTEXT != name:
            raise ValueError(f"scenario {name!r} takes a spec of its own defaults' context, got {spec.CONTEXT!r}")
        _REGISTRY[name] = Scenario(name, description, spec, fn, batch)
        return fn

    return wrap


def unregister(name: str) -> None:
    """Remove scenario `name` (one a plug-in or a test registered); KeyError when none is registered."""
    if name not in _REGISTRY:
        raise KeyError(f"scenario {name!r} is not registered")
    del _REGISTRY[name]


def registry() -> dict[str, Scenario]:
    """All registered scenarios by name (imports the scenario modules on first use)."""
    for module in _MODULES:
        importlib.import_module(module)
    return dict(sorted(_REGISTRY.items()))


def get(name: str) -> Scenario:
    scenarios = registry()
    if name not in scenarios:
        raise KeyError(f"unknown scenario {name!r}{did_you_mean(name, scenarios)}; available: {', '.join(scenarios)}")
    return scenarios[name]
