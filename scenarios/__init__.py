"""Scenario registry: every scenario is a factory registered by name.

A scenario is a function `fn(out_dir: Path, *, param=default, ...) -> dict` whose
keyword parameters (with type annotations and defaults) are its parameters; it runs,
writes its outputs into `out_dir` (docs/run-outputs.md) and returns the summary it wrote.
`python -m scenarios --list` lists them; `python -m scenarios NAME --out DIR
[--param value ...]` runs one.

Checking without running. `Scenario.validate(params)` gives the full keyword arguments
(the defaults updated with `params`) after the checks a run would make first, without
building or running anything expensive: every name is a parameter; every value has its
annotated type (an int is accepted for a float and becomes one); every float is finite;
then the scenario's own `check(kwargs)` (given to `register`), which the scenario's run
also calls first, checks the ranges and the files and names it refers to. Errors are
`ValueError`s that name the parameter, the valid range and the value received.

Documentation. Every parameter's meaning and unit are declared once for all scenarios
(`vocabulary.settings.SETTINGS`, shared with the hardware file and the studies), and so
is its valid range, which `check_bounds` (scenarios.common) holds every value to; a
scenario's `bounds` (given to `register`) narrow that range for it (camera_loop's image
size <= its render's), and `Scenario.valid` shows the scenario's range, else the declared one.

Batch form (optional, studies: docs/studies.md#batches). `register(..., batch=BatchForm(key, run))`
lets a study run many samples of the scenario in one batched closed loop:
`key(kwargs)` is what samples must share to run in one batch (hashable; None: this
sample cannot be batched), `run(kwargs_list, nthread)` runs the validated keyword
arguments of samples with one key together and returns one row of run figures per
sample (`softcbf_mj.batch_loop.BatchRun.run`), equal to the single run's fields of the
same names.
"""

from __future__ import annotations

import importlib
import inspect
import math
import typing
from dataclasses import dataclass, field
from typing import Any, Callable, Hashable, Mapping, Sequence

from vocabulary.settings import setting

_MODULES = ("scenarios.paper_sim", "scenarios.mujoco_contact", "scenarios.camera_loop")


@dataclass(frozen=True)
class BatchForm:
    """A scenario's batch form (module docstring): `key(kwargs) -> Hashable | None`,
    `run(kwargs_list, nthread) -> list[dict]` (one row of run figures per sample)."""

    key: Callable[[Mapping[str, Any]], Hashable | None]
    run: Callable[[Sequence[Mapping[str, Any]], int], list[dict[str, Any]]]


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    run: Callable[..., dict]
    check: Callable[[Mapping[str, Any]], None] | None = None
    bounds: Mapping[str, Any] = field(default_factory=dict)  # name → range (scenarios.common.Bound: str() says it)
    batch: "BatchForm | None" = None

    def parameters(self) -> dict[str, inspect.Parameter]:
        """Keyword parameters of the scenario, by name (out_dir excluded)."""
        params = inspect.signature(self.run).parameters
        return {k: p for k, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}

    def defaults(self) -> dict[str, Any]:
        return {k: p.default for k, p in self.parameters().items()}

    def coerce(self, name: str, value: Any) -> Any:
        """`value` as parameter `name`'s annotated type (int → float for floats; floats finite), else ValueError."""
        params = self.parameters()
        if name not in params:
            raise ValueError(f"scenario {self.name!r} has no parameter {name!r}; parameters: {', '.join(params)}")
        annotation = typing.get_type_hints(self.run)[name]
        if annotation is float and isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value):
                raise ValueError(f"parameter {name!r} must be a finite number, got {value!r}")
            return float(value)
        if annotation is int and isinstance(value, int) and not isinstance(value, bool):
            return value
        if annotation in (bool, str) and isinstance(value, annotation):
            return value
        raise ValueError(f"parameter {name!r} takes {annotation.__name__} values, got {value!r}")

    def valid(self, name: str) -> str:
        """Parameter `name`'s valid values: the scenario's narrower bound, else the declared ones (vocabulary.settings)."""
        if name in self.bounds:
            return str(self.bounds[name])
        return setting(name).valid_values

    def validate(self, params: Mapping[str, Any]) -> dict[str, Any]:
        """The full keyword arguments (defaults updated with `params`), checked without running (module docstring)."""
        kwargs = self.defaults()
        kwargs.update({name: self.coerce(name, value) for name, value in params.items()})
        if self.check is not None:
            self.check(kwargs)
        return kwargs


_REGISTRY: dict[str, Scenario] = {}


def register(name: str, description: str, check: Callable[[Mapping[str, Any]], None] | None = None,
             bounds: Mapping[str, Any] | None = None,
             batch: BatchForm | None = None) -> Callable[[Callable[..., dict]], Callable[..., dict]]:
    """Decorator: register `fn` as scenario `name` with a one-line description, its
    parameter check `check(kwargs)` (raises ValueError; `Scenario.validate`), the ranges
    that check holds its numeric parameters to (`bounds`, for the documentation) and its
    batch form."""

    def wrap(fn: Callable[..., dict]) -> Callable[..., dict]:
        if name in _REGISTRY:
            raise ValueError(f"scenario {name!r} is registered twice")
        _REGISTRY[name] = Scenario(name, description, fn, check, dict(bounds or {}), batch)
        return fn

    return wrap


def registry() -> dict[str, Scenario]:
    """All registered scenarios by name (imports the scenario modules on first use)."""
    for module in _MODULES:
        importlib.import_module(module)
    return dict(sorted(_REGISTRY.items()))


def get(name: str) -> Scenario:
    scenarios = registry()
    if name not in scenarios:
        raise KeyError(f"unknown scenario {name!r}; available: {', '.join(scenarios)}")
    return scenarios[name]
