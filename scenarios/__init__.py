"""Scenario registry: every scenario is a factory registered by name.

A scenario is a function `fn(out_dir: Path, *, param=default, ...) -> dict` whose
keyword parameters (with type annotations and defaults) are its parameters; it runs,
writes its outputs into `out_dir` (docs/run-outputs.md) and returns the summary it wrote.
`python -m scenarios --list` lists them; `python -m scenarios NAME --out DIR
[--param value ...]` runs one.
"""

from __future__ import annotations

import importlib
import inspect
from dataclasses import dataclass
from typing import Any, Callable

_MODULES = ("scenarios.paper_sim", "scenarios.mujoco_contact", "scenarios.camera_loop")


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    run: Callable[..., dict]

    def parameters(self) -> dict[str, inspect.Parameter]:
        """Keyword parameters of the scenario, by name (out_dir excluded)."""
        params = inspect.signature(self.run).parameters
        return {k: p for k, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY}

    def defaults(self) -> dict[str, Any]:
        return {k: p.default for k, p in self.parameters().items()}


_REGISTRY: dict[str, Scenario] = {}


def register(name: str, description: str) -> Callable[[Callable[..., dict]], Callable[..., dict]]:
    """Decorator: register `fn` as scenario `name` with a one-line description."""

    def wrap(fn: Callable[..., dict]) -> Callable[..., dict]:
        if name in _REGISTRY:
            raise ValueError(f"scenario {name!r} is registered twice")
        _REGISTRY[name] = Scenario(name, description, fn)
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
