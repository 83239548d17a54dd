"""What a plug-in declares it can do beyond the minimal contract (docs/safety-filter.md, "Capabilities").

A safety filter (`controllers.contract.safety_filter`: called `filter(estimate, u_nom)`, optionally `reset()`) or a nominal
controller (`controllers.nominal`: called `nominal(t, q, qd)`) declares more with a `capabilities` attribute, a
frozen `Capabilities`: batched (one call for B states: a filter's `filter_batch`, a nominal's `nominal_batch`),
rows (a filter's history per simulation, told by `filter_batch(..., rows=ids)`), reset_rows (`reset(rows=ids)`) and
passthrough (u = u_nom: no filter times reported). A plug-in that declares nothing gets `MINIMAL` (all False) and is
called once per simulation, whatever methods it has: the loops never sniff methods or signatures to decide what a
plug-in can do. `plugin_capabilities` is the one reader; it checks a declaration against what the plug-in has
(`CapabilityError`, one line, when it is built or a loop is set up) and reads signatures only for that check.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass, fields


class CapabilityError(ValueError):
    """A plug-in's declared capabilities are not a `Capabilities`, or it lacks what it declares (module
    docstring: "Capabilities are declared"); raised when it is built or a loop is set up, one line."""


@dataclass(frozen=True)
class Capabilities:
    """What a filter or a nominal controller declares beyond the minimal contract (module docstring): batched
    (`filter_batch`; a nominal's `nominal_batch`), rows (a history per simulation, told by `filter_batch(...,
    rows=ids)`; with batched), reset_rows (`reset(rows=ids)`) and passthrough (u = u_nom: no filter times
    reported); a nominal controller may declare batched only (`NOMINAL_CONTROLLER`). All False: the minimal
    contract, called once per simulation."""

    batched: bool = False
    rows: bool = False
    reset_rows: bool = False
    passthrough: bool = False

    def __post_init__(self) -> None:
        for name in (f.name for f in fields(self)):
            value = getattr(self, name)
            if type(value) is not bool:
                raise CapabilityError(f"Capabilities.{name} must be True or False, got {value!r}")
        if self.rows and not self.batched:
            raise CapabilityError("Capabilities(rows=True) needs batched=True: the rows are told to filter_batch")


MINIMAL = Capabilities()  # what a plug-in that declares nothing can do: be called, and reset() when it has one


@dataclass(frozen=True)
class PluginKind:
    """A kind of plug-in whose `capabilities` `plugin_capabilities` reads: its name and call (for the messages),
    the method that `batched` promises, that method's arguments, and the capabilities the kind may declare."""

    noun: str
    call: str
    batch_method: str
    batch_arguments: str
    allowed: frozenset[str]


SAFETY_FILTER = PluginKind("safety filter", "filter(estimate, u_nom)", "filter_batch", "estimates, u_nom",
                           frozenset(f.name for f in fields(Capabilities)))
# a nominal controller (controllers.nominal) is called (t, q, qd) -> u_nom; batched: nominal_batch for B states at once
NOMINAL_CONTROLLER = PluginKind("nominal controller", "nominal(t, q, qd)", "nominal_batch", "t, q, qd",
                                frozenset({"batched"}))


def plugin_capabilities(plugin: object, kind: PluginKind) -> Capabilities:
    """The capabilities `plugin` of `kind` declares (its `capabilities`; `MINIMAL` when it declares none), checked
    against what it has: CapabilityError (one line) for a plug-in that is not callable, a declaration that is not
    a `Capabilities`, a capability its kind cannot have (a nominal's rows, reset_rows or passthrough), or one it
    does not implement (batched without the kind's batch method, rows without a `rows` keyword of it,
    reset_rows without `reset(rows=...)`). Signatures are read here only to check a declaration, never to
    decide what a plug-in can do."""
    name = getattr(plugin, "__name__", None) or type(plugin).__name__
    if not callable(plugin):
        raise CapabilityError(f"a {kind.noun} must be callable as {kind.call}, got {name}")
    try:
        declared = getattr(plugin, "capabilities", MINIMAL)
    except Exception as exc:  # noqa: BLE001 - a property of user code: refused in one line at setup
        raise CapabilityError(f"{name}.capabilities raised {type(exc).__name__}: {exc}") from None
    if type(declared) is not Capabilities:
        raise CapabilityError(f"{name}.capabilities must be a controllers.contract.capabilities.Capabilities, got "
                              f"{type(declared).__name__}")
    foreign = [f.name for f in fields(declared) if getattr(declared, f.name) and f.name not in kind.allowed]
    if foreign:
        raise CapabilityError(f"{name} declares {foreign[0]}=True, which a {kind.noun} cannot: it may declare "
                              f"{', '.join(sorted(kind.allowed))} only")
    batch = getattr(plugin, kind.batch_method, None)
    if declared.batched and not callable(batch):
        raise CapabilityError(f"{name} declares batched=True but has no method "
                              f"{kind.batch_method}({kind.batch_arguments})")
    if declared.rows and not takes_keyword(batch, "rows"):
        raise CapabilityError(f"{name} declares rows=True but its {kind.batch_method} takes no keyword rows")
    if declared.reset_rows and not takes_keyword(getattr(plugin, "reset", None), "rows"):
        raise CapabilityError(f"{name} declares reset_rows=True but has no method reset(rows=...)")
    return declared


def filter_capabilities(safety_filter: object) -> Capabilities:
    """What `safety_filter` declares, checked (`plugin_capabilities` of a `SAFETY_FILTER`)."""
    return plugin_capabilities(safety_filter, SAFETY_FILTER)


def nominal_capabilities(nominal: object) -> Capabilities:
    """What the nominal controller `nominal` declares, checked (`plugin_capabilities` of a `NOMINAL_CONTROLLER`):
    batched, or nothing (called once per simulation, whatever methods it has)."""
    return plugin_capabilities(nominal, NOMINAL_CONTROLLER)


def takes_keyword(function: object, name: str) -> bool:
    """Whether `function` (a method, or None) can be called with the keyword argument `name`."""
    if not callable(function):
        return False
    try:
        parameters = inspect.signature(function).parameters.values()
    except (TypeError, ValueError):  # no signature to read (a builtin): no such keyword to rely on
        return False
    return any(p.name == name and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) or p.kind == p.VAR_KEYWORD
               for p in parameters)
