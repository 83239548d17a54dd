"""Safety filters and nominal controllers by name: the built-ins, and user code by `FILE.py:Factory` or `pkg.mod:Factory`.

A spec names a factory (a class or a function):
- a built-in's name (`FILTERS`, `NOMINALS`), e.g. "paper-cbf", "none", "qsg" (the
  quasi-static governor), "e-erg" (the energy-certified reference governor), "c-erg" (its
  contact certificate, recommended for contact tasks), "sinusoid",
  "tip-tracker", "step", "force-target";
- `path/to/file.py:Factory` (the file is imported as a module of its own; the path is
  relative to the working directory; `spec_file` tells such a spec apart, `source_record`
  gives its file's absolute path and SHA-256, which a run's config.json records so that a
  replay runs the same file: scenarios.config_file);
- `package.module:Factory` (imported from sys.path);
- a preset `NAME:PRESET` of a built-in (`PRESETS`, the one home of each): "c-erg:recommended" is
  c-erg with `controllers.governors.energy_governor.RECOMMENDED` and the plate stiffness interval
  [0.9, 1.1], "c-erg:standard-box" the same setting certified over the standard error box
  (`controllers.governors.energy_governor.box.STANDARD_BOX`), "c-erg:learn-plate" that setting learning the plate online
  on an exact state; parameters given with it override the preset's (`typed_params`), its run label is
  its name plus what was overridden (`label`), and an unknown preset of a built-in is refused
  with the closest names (`find_preset`).

The factory is called as `Factory(**params)`, plus `context=FilterContext(...)` when its
signature has a parameter named `context` (docs/safety-filter.md). A filter factory returns a safety
filter (`controllers.contract.safety_filter`); a nominal factory returns a callable
`(t, q, qd) -> u_nom` (N,) hPa. Parameters not given take the signature's defaults;
unknown names are refused with the list of valid ones. `typed_params(spec, params)` converts
the parameters an edge gives (the command line's text, a TOML table, a study's draw, Python
values) once, by each parameter's declared kind: its annotation (a built-in's is its
`controllers.contract.filter_parameters.FilterParameter` kind) or, without one, its default's type (bool:
true/false/yes/no/1/0/on/off; "none" for a parameter that allows None; an int given for a float
becomes one); a parameter with neither gets the value as given. The result, a frozen
`controllers.contract.filter_parameters.Params` in declaration order, is what every record stores and
what the label is made of. Built-in factories carry `parameter_docs`:
{name: "meaning [unit]"} (`parameters` returns it with every parameter's default) and
may carry `run_label(params) -> str`, a run's label (`label`; default
`Factory(name=value,...)`), and `check_arguments(arguments)`, the checks its construction
would make, run without building it (`check_filter`).

A misspelt name is answered with the closest valid ones (`did_you_mean`: difflib's ratio of matching
characters ≥ 0.6, at most three), the one helper of every name lookup (scenarios, filters, nominal
controllers, `softcbf` subcommands): "unknown name 'c-egr' (did you mean 'c-erg', 'e-erg'?)".
"""

from __future__ import annotations

import difflib
import hashlib
import importlib
import importlib.util
import inspect
import numbers
import sys
import traceback
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controllers.contract.filter_parameters import Params, parse_text, read_params, value_text
from controllers.core.interrupts import is_interrupt
from controllers.contract.capabilities import CapabilityError, filter_capabilities, nominal_capabilities
from controllers.contract.safety_filter import FilterContext, SafetyFilter

if typing.TYPE_CHECKING:
    from controllers.nominal import NominalController


class Factories(Mapping[str, Callable]):
    """The built-in factories by name, each imported from its "module:attribute" home at its first lookup.

    A read-only mapping (`in`, iteration and `len` import nothing), so that importing the
    registry, and commands that use one built-in, do not import every filter's module."""

    def __init__(self, homes: Mapping[str, str]) -> None:
        self._homes, self._loaded = dict(homes), {}

    def __getitem__(self, name: str) -> Callable:
        if name not in self._loaded:
            module, _, attribute = self._homes[name].partition(":")
            self._loaded[name] = getattr(importlib.import_module(module), attribute)
        return self._loaded[name]

    def __contains__(self, name: object) -> bool:
        return name in self._homes

    def __iter__(self) -> typing.Iterator[str]:
        return iter(self._homes)

    def __len__(self) -> int:
        return len(self._homes)


FILTERS: Mapping[str, Callable[..., SafetyFilter]] = Factories({
    "paper-cbf": "controllers.cbf.paper_filter:paper_cbf", "none": "controllers.contract.safety_filter:PassThroughFilter",
    "qsg": "controllers.governors.quasi_static_governor:QuasiStaticGovernor", "e-erg": "controllers.governors.energy_governor:EnergyGovernor",
    "c-erg": "controllers.governors.energy_governor:ContactEnergyGovernor",
    "ecbf": "controllers.cbf.family:ecbf", "sdcbf": "controllers.cbf.family:sdcbf", "isscbf": "controllers.cbf.family:isscbf",
    "backup-cbf": "controllers.cbf.backup:BackupCBF",
})
NOMINALS: Mapping[str, Callable[..., NominalController]] = Factories({
    "sinusoid": "controllers.nominal:sinusoid", "tip-tracker": "controllers.nominal:tip_tracker", "step": "controllers.nominal:step",
    "force-target": "controllers.nominal:force_target",
})


@dataclass(frozen=True)
class Preset:
    """A named setting of a built-in filter (`FILTER:NAME`): the built-in `filter`, its parameters (the mapping at
    `home`, "module:attribute", read at first use, then `extra` over it) and a phrase saying what it is."""

    filter: str
    home: str
    extra: Mapping[str, object]
    doc: str

    @property
    def params(self) -> dict[str, object]:
        """The preset's parameters: the mapping at `home` with `extra` over it."""
        module, _, attribute = self.home.partition(":")
        return {**getattr(importlib.import_module(module), attribute), **self.extra}


PRESETS: Mapping[str, Preset] = {
    "c-erg:recommended": Preset(
        "c-erg", "controllers.governors.energy_governor:RECOMMENDED", {"stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1},
        "the recommended filter for contact tasks: c-erg's recommended setting (controllers.governors.energy_governor."
        "RECOMMENDED) certified over plate stiffnesses of 0.9 to 1.1 times the assumed one"),
    "c-erg:standard-box": Preset(
        "c-erg", "controllers.governors.energy_governor.parameters:STANDARD_BOX_SETTING", {},
        "c-erg's recommended setting certified over the standard error box's physical errors (plate stiffness "
        "+-20 %, offset +-2 mm, actuator gain and arm stiffness +-10 %, damping from 0.7x, valve lag 0.02-0.1 s)"),
    "c-erg:learn-plate": Preset(
        "c-erg", "controllers.governors.energy_governor.parameters:LEARN_PLATE_SETTING", {},
        "c-erg:standard-box learning the plate's offset and stiffness online with certified bounds, for a state "
        "exact to 1e-4 rad (simulation at 1 kHz, motion capture; not a camera, whose error is larger)"),
}
"""The named presets (`--filter c-erg:recommended`), the one home of each: what the README, `softcbf list`,
`softcbf run`, the bench, the environment and the hardware file mean by the name (module docstring)."""

CONTEXT = "context"
SPEC_SETTINGS = ("filter", "nominal")  # the settings that hold a filter's or a nominal's spec
_TRUE, _FALSE = ("1", "true", "yes", "on"), ("0", "false", "no", "off")


@dataclass(frozen=True)
class Parameter:
    """A factory parameter: name, default (inspect.Parameter.empty: required), type name and "meaning [unit]"."""

    name: str
    default: object
    type_name: str
    doc: str


def did_you_mean(name: str, valid: Iterable[str]) -> str:
    """" (did you mean 'a', 'b'?)" naming up to three of `valid` closest to `name` (difflib.get_close_matches,
    cutoff 0.6), "" when none is close: the suffix of every "unknown name" message (module docstring)."""
    close = difflib.get_close_matches(name, list(valid), n=3, cutoff=0.6)
    return f" (did you mean {', '.join(repr(c) for c in close)}?)" if close else ""


def resolve(spec: str, builtins: Mapping[str, Callable]) -> Callable:
    """The factory named by `spec` (module docstring); ValueError naming the spec otherwise."""
    if not isinstance(spec, str) or not spec.strip():
        raise ValueError(f"a filter or nominal spec must be a name ({', '.join(builtins)}) or FILE.py:Factory or "
                         f"package.module:Factory, got {spec!r}")
    spec = spec.strip()
    if spec in builtins:
        return builtins[spec]
    preset = find_preset(spec, builtins)
    if preset is not None:
        return builtins[preset.filter]
    if ":" not in spec:
        raise ValueError(f"unknown name {spec!r}{did_you_mean(spec, builtins)}; built-ins: {', '.join(builtins)}; or FILE.py:Factory, package.module:Factory")
    where, _, name = spec.rpartition(":")
    module = _load_file(Path(where)) if spec_file(spec) is not None else _import(where)
    factory = getattr(module, name, None)
    if not callable(factory):
        raise ValueError(f"{where} has no callable {name!r} (spec {spec!r})")
    return factory


def find_preset(spec: str, builtins: Mapping[str, Callable] = FILTERS) -> Preset | None:
    """The preset `spec` names (`PRESETS`: "c-erg:recommended"), None when `spec` names no preset (its part
    before ':' is not a built-in); ValueError with the closest presets for a built-in's unknown preset."""
    spec = spec.strip()
    if spec in PRESETS and PRESETS[spec].filter in builtins:
        return PRESETS[spec]
    name, sep, _ = spec.partition(":")
    if not sep or name not in builtins:
        return None
    own = [key for key, preset in PRESETS.items() if preset.filter in builtins]
    raise ValueError(f"unknown preset {spec!r}{did_you_mean(spec, own)}; presets: {', '.join(own) or 'none'}")


def spec_file(spec: object) -> tuple[Path, str] | None:
    """(FILE, Factory) of a `FILE.py:Factory` spec (FILE as written: a name ending in .py or a path with a folder
    separator), None for a built-in's name, a `package.module:Factory` spec or anything not a string."""
    if not isinstance(spec, str):
        return None
    where, sep, name = spec.strip().rpartition(":")
    if not sep or not (where.endswith(".py") or "/" in where or "\\" in where):
        return None
    return Path(where), name


def file_sha256(path: Path) -> str:
    """The SHA-256 of the file's bytes, as 64 hexadecimal digits."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def source_record(spec: object) -> dict[str, str] | None:
    """{"path": absolute path, "sha256": content hash} of the file a `FILE.py:Factory` spec names (relative to the
    working directory), None for any other spec or a file that does not exist (the run refuses that spec anyway)."""
    found = spec_file(spec)
    if found is None or not found[0].is_file():
        return None
    path = found[0].absolute()
    return {"path": str(path), "sha256": file_sha256(path)}


def recorded_sources(params: Mapping[str, object]) -> dict[str, dict[str, str]]:
    """`source_record` of each of `params`' SPEC_SETTINGS that names a file: what a run's config.json records."""
    return {key: record for key in SPEC_SETTINGS if (record := source_record(params.get(key))) is not None}


class PluginLoadError(ValueError):
    """A filter or nominal controller cannot be loaded or built: its file or module does not
    import, its factory is not callable or raises, or its parameters are missing or unknown.
    The message is one line naming the spec and, where user code raised, file:line."""


def _where(exc: BaseException, path: Path | None = None) -> str:
    """"file:line: " of the user code behind `exc`: a SyntaxError's own position, else the deepest
    traceback frame in `path` (when given) or the deepest frame; "" when there is none."""
    if isinstance(exc, SyntaxError) and exc.filename:
        return f"{exc.filename}:{exc.lineno}: "
    frames = traceback.extract_tb(exc.__traceback__)
    if path is not None:
        inside = [f for f in frames if Path(f.filename) == path]
        frames = inside or frames
    return f"{frames[-1].filename}:{frames[-1].lineno}: " if frames else ""


def _load_error(what: str, exc: BaseException, path: Path | None = None) -> PluginLoadError:
    text = str(exc).strip().splitlines()
    return PluginLoadError(f"{what}: {_where(exc, path)}{type(exc).__name__}: {text[0] if text else ''}")


def _import(name: str) -> types.ModuleType:
    try:
        return importlib.import_module(name)
    except ImportError as exc:
        raise PluginLoadError(f"cannot import module {name!r}: {exc}") from None
    except BaseException as exc:  # noqa: BLE001 - the module's own code raised while it was imported (SystemExit too)
        if is_interrupt(exc):
            raise
        raise _load_error(f"module {name!r} raised while it was imported", exc) from None


def _load_file(path: Path) -> types.ModuleType:
    """Import the Python file `path` as a module named after its resolved path (imported once)."""
    if not path.is_file():
        raise ValueError(f"no such Python file {str(path)!r}")
    resolved = path.resolve()
    name = f"softcbf_user_{resolved.stem}_{hashlib.sha1(str(resolved).encode()).hexdigest()[:10]}"
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, resolved)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException as exc:  # noqa: BLE001 - syntax, import and any error of the file's own code (SystemExit too)
        del sys.modules[name]
        if is_interrupt(exc):
            raise
        raise _load_error(f"cannot load {str(path)!r}", exc, resolved) from None
    return module


def _signature(factory: Callable) -> inspect.Signature:
    try:
        return inspect.signature(factory)
    except (ValueError, TypeError) as exc:  # a builtin without a signature, a callable object without __call__'s
        raise PluginLoadError(f"{getattr(factory, '__name__', repr(factory))} cannot be a factory: its signature "
                              f"cannot be read ({exc})") from None


def _hints(factory: Callable) -> dict[str, object]:
    target = factory.__init__ if inspect.isclass(factory) else factory
    try:
        return typing.get_type_hints(target)
    except Exception:  # unresolvable annotations: fall back to the defaults' types
        return {}


def parameters(factory: Callable) -> list[Parameter]:
    """The factory's parameters (without `context`), with defaults, type names and docs."""
    docs = getattr(factory, "parameter_docs", {})
    hints = _hints(factory)
    out = []
    for name, p in _signature(factory).parameters.items():
        if name == CONTEXT or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        hint = hints.get(name, type(p.default) if p.default not in (p.empty, None) else p.empty)
        type_name = getattr(hint, "__name__", None) or str(hint).replace("typing.", "")
        out.append(Parameter(name, p.default, "" if hint is p.empty else type_name, docs.get(name, "")))
    return out


parse_params = parse_text
"""The old joined text "name=value;name=value" → {name: value} (`controllers.contract.filter_parameters.parse_text`)."""


def _kinds(hint: object, default: object) -> tuple[list[object], bool]:
    """The kinds a parameter declares (its annotation's members, else its default's type, else none) and
    whether None is one of its values."""
    union = typing.get_origin(hint) in (typing.Union, types.UnionType)
    kinds = [a for a in typing.get_args(hint) if a is not type(None)] if union else [hint]
    allows_none = (union and type(None) in typing.get_args(hint)) or default is None
    if kinds == [inspect.Parameter.empty] or kinds == [None]:
        kinds = [type(default)] if default not in (inspect.Parameter.empty, None) else []
    return kinds, allows_none


def _convert(name: str, value: object, hint: object, default: object) -> object:
    """`value` as the parameter's declared kind (module docstring): text converted, an int given for a float
    (or a numpy number) made the Python float or int; a value of a kind that is not declared as given."""
    kinds, allows_none = _kinds(hint, default)
    if not isinstance(value, str):
        if isinstance(value, numbers.Integral) and not isinstance(value, bool) and int in kinds:
            return int(value)
        if isinstance(value, numbers.Real) and not isinstance(value, bool) and float in kinds:
            return float(value)
        if isinstance(value, (bool, np.bool_)) and bool in kinds:
            return bool(value)
        return value
    if allows_none and value.strip().lower() == "none":
        return None
    if not kinds or str in kinds:
        return value
    for kind in kinds:
        try:
            if kind is bool:
                low = value.strip().lower()
                if low in _TRUE or low in _FALSE:
                    return low in _TRUE
                continue
            if kind in (int, float):
                return kind(value)
        except ValueError:
            continue
    if all(k in (bool, int, float, str) for k in kinds):
        expected = " or ".join(k.__name__ for k in kinds)
        raise ValueError(f"parameter {name} must be {expected}, got {value!r}")
    return value


def _converted(factory: Callable, params: Mapping[str, object]) -> dict[str, object]:
    """`params` checked against the factory's signature (unknown names refused with the valid ones) and each
    converted by its declared kind (`_convert`), in the signature's order (names that only a **kwargs takes
    after, as given)."""
    signature = _signature(factory)
    accepted = [n for n, p in signature.parameters.items() if n != CONTEXT and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
    open_kwargs = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
    unknown = sorted(set(params) - set(accepted)) if not open_kwargs else []
    if unknown:
        name = getattr(factory, "__name__", repr(factory))
        raise ValueError(f"unknown parameter(s) {', '.join(unknown)} for {name}; valid: {', '.join(sorted(accepted)) or 'none'}")
    hints = _hints(factory)
    order = [n for n in accepted if n in params] + [n for n in params if n not in accepted]
    return {key: _convert(key, params[key], hints.get(key, inspect.Parameter.empty),
                          signature.parameters[key].default if key in signature.parameters else inspect.Parameter.empty)
            for key in order}


def typed_params(spec: str, params: object = None, builtins: Mapping[str, Callable] = FILTERS) -> Params:
    """The parameters of the plug-in `spec` as every record holds them: `params` as given at an edge (a mapping,
    or the old joined text: `controllers.contract.filter_parameters.read_params`) over the preset's when `spec` names one
    (`PRESETS`), converted once by each parameter's declared kind (the factory's signature: a built-in's
    annotations are its `FilterParameter` kinds; a plug-in's its annotations, else its defaults' types, else the
    value as given), in declaration order (`Params`). Unknown names and unreadable values: ValueError. Imports
    the factory (a file's plug-in too); builds nothing."""
    given = read_params(params)
    preset = find_preset(spec, builtins) if isinstance(spec, str) else None
    merged = given if preset is None else {**preset.params, **given}
    return Params(_converted(resolve(spec, builtins), merged))


def arguments(factory: Callable, params: Mapping[str, object]) -> dict[str, object]:
    """`params` checked against the factory's signature (unknown names refused with the valid
    ones, required ones missing refused) and converted (`_converted`); `context` not included. Builds nothing."""
    signature = _signature(factory)
    missing = [n for n, p in signature.parameters.items()
               if n != CONTEXT and p.default is p.empty and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)
               and n not in params]
    kwargs = _converted(factory, params)
    if missing:
        raise PluginLoadError(f"missing required parameter(s) {', '.join(missing)} for "
                              f"{getattr(factory, '__name__', repr(factory))} "
                              f"(give them with --filter-param / --nominal-param NAME=VALUE)")
    return kwargs


def build(factory: Callable, params: Mapping[str, object], context: FilterContext | None) -> object:
    """Call `factory` with `params` (`arguments`) and `context` when it takes one."""
    kwargs = arguments(factory, params)
    if CONTEXT in _signature(factory).parameters:
        kwargs[CONTEXT] = context
    try:
        return factory(**kwargs)
    except BaseException as exc:  # noqa: BLE001 - the factory is user code: a load-time fault (exit 2), SystemExit too
        if is_interrupt(exc):
            raise
        raise _load_error(f"{getattr(factory, '__name__', repr(factory))}({', '.join(kwargs)}) raised", exc,
                          _source_file(factory)) from None


def _source_file(factory: Callable) -> Path | None:
    try:
        return Path(inspect.getsourcefile(factory)).resolve()
    except (TypeError, OSError):
        return None


def check_filter(spec: str, params: Mapping[str, object]) -> None:
    """ValueError unless `spec` resolves to a filter factory taking `params` (names and
    convertible values; nothing is built, so a study can check its runs cheaply), nor unless
    the factory's own `check_arguments(arguments)`, when it carries one, accepts them."""
    factory = resolve(spec, FILTERS)
    kwargs = arguments(factory, typed_params(spec, params))
    check = getattr(factory, "check_arguments", None)
    if callable(check):
        check(kwargs)


def check_nominal(spec: str, params: Mapping[str, object]) -> None:
    """`check_filter` for a nominal controller's spec and parameters."""
    arguments(resolve(spec, NOMINALS), params)


def build_filter(spec: str, params: Mapping[str, object], context: FilterContext) -> SafetyFilter:
    """The safety filter of `spec` with `params`, told `context`; PluginLoadError when it lacks a capability it
    declares (`controllers.contract.capabilities.filter_capabilities`)."""
    safety_filter = build(resolve(spec, FILTERS), typed_params(spec, params), context)
    if not callable(safety_filter):
        raise ValueError(f"filter {spec!r} must build a callable filter(estimate, u_nom), got {type(safety_filter).__name__}")
    try:
        filter_capabilities(safety_filter)
    except CapabilityError as exc:
        raise PluginLoadError(f"filter {spec!r}: {exc}") from None
    return safety_filter


def build_nominal(spec: str, params: Mapping[str, object], context: FilterContext) -> NominalController:
    """The nominal controller of `spec` with `params`, told `context` (its robot model and limits); PluginLoadError
    when it lacks a capability it declares (`controllers.contract.capabilities.nominal_capabilities`)."""
    nominal = build(resolve(spec, NOMINALS), params, context)
    if not callable(nominal):
        raise ValueError(f"nominal {spec!r} must build a callable (t, q, qd) -> u_nom, got {type(nominal).__name__}")
    try:
        nominal_capabilities(nominal)
    except CapabilityError as exc:
        raise PluginLoadError(f"nominal {spec!r}: {exc}") from None
    return nominal


def label(spec: str, params: object = None) -> str:
    """A run's label for the filter `spec` with `params`, from the typed values (`typed_params`) in declaration
    order, so that one setting has one label whichever surface gave it: a preset's name ("c-erg:recommended"),
    followed by the parameters that differ from it ("c-erg:recommended(gain_noise_rad=0.003)"); else the
    factory's `run_label(params)`, or `Factory(name=value,...)` (Factory: the built-in's name or the name after ':'; the
    values as the command line writes them, `controllers.contract.filter_parameters.value_text`)."""
    typed = typed_params(spec, params)
    preset = find_preset(spec, FILTERS)
    if preset is not None:
        own = typed_params(preset.filter, preset.params)
        changed = {k: v for k, v in typed.items() if k not in own or own[k] != v}
        name, typed = spec.strip(), Params(changed)
    else:
        run_label = getattr(resolve(spec, FILTERS), "run_label", None)
        if callable(run_label):
            return run_label(typed)
        name = spec.strip().rpartition(":")[2]
    args = ",".join(f"{k}={value_text(v)}" for k, v in typed.items())
    return f"{name}({args})" if args else name


def describe(name: str, factory: Callable) -> str:
    """`name`: the factory's first docstring line, then one line per parameter: meaning, unit, default."""
    doc = (inspect.getdoc(factory) or "").splitlines()
    lines = [f"{name}: {doc[0] if doc else ''}"]
    for p in parameters(factory):
        default = "required" if p.default is inspect.Parameter.empty else f"default {p.default!r}"
        meaning = f" — {p.doc}" if p.doc else ""
        lines.append(f"    {p.name} ({p.type_name or 'any'}, {default}){meaning}")
    return "\n".join(lines)


def describe_preset(name: str) -> str:
    """Preset `name` (`PRESETS`) for `softcbf list`: its phrase, then its parameters as --filter-param would
    give them (the typed values, `typed_params`)."""
    preset = PRESETS[name]
    values = " ".join(f"{k}={value_text(v)}" for k, v in typed_params(preset.filter, preset.params).items())
    return f"{name}: {preset.doc}\n    = --filter {preset.filter} with {values}"


def is_builtin(spec: object, builtins: Mapping[str, Callable] = FILTERS) -> bool:
    """Whether `spec` names a built-in or one of its presets (nothing of the user's is imported to use it);
    ValueError for a built-in's unknown preset (`find_preset`)."""
    if not isinstance(spec, str):
        return False
    return spec.strip() in builtins or find_preset(spec, builtins) is not None


def parameter_names(spec: str, builtins: Mapping[str, Callable] = FILTERS) -> frozenset[str]:
    """The names of the parameters the plug-in `spec` declares (`parameters`; a preset's built-in's)."""
    return frozenset(p.name for p in parameters(resolve(spec, builtins)))
