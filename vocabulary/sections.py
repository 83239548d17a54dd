"""Sections: frozen dataclasses whose fields are settings, declared once and checked once.

A *section* groups settings (`vocabulary.settings.SETTINGS`) that one part of a run takes.
`setting_section(cls, settings={field: setting}, context=...)` turns a class into a frozen
dataclass with one field per entry of `settings`:

- the field's type is the setting's `kind` (`kind | None` where the context's default is
  None: "none configured"; a `dict` for a plug-in's parameter table, `tables`; the kind or a
  tuple of them for a per-segment value, `per_segment`);
- its default is `default(setting, context)` (`vocabulary.settings`, the one home of a
  default), or `UNSET` ("the scenario's default", resolved later by the scenario's spec)
  when `context` is None;
- the field's metadata names its setting (`SETTING`), so a field's name may differ from its
  setting's (`Plate.stiffness` is `plate_stiffness`); `setting_fields(cls)` lists them.

The class body may hold further fields of its own (plain annotations with defaults: the
hardware file's `camera.source`) and methods; a method `check(self)` runs after the settings
are checked, for the rules that tie fields together. When a section is built
(`__post_init__`), every given setting field is checked by `check_value` and stored
normalised (an int given for a float becomes one); a bad value raises `error` (default
`SettingError`, a ValueError) naming the setting, its bound with its unit and the value:

- a list or tuple is one value per segment where the field is `per_segment` (each element
  checked, named "amplitude[1]"), the value itself for a setting of kind tuple (the tunings:
  a sequence of names, `vocabulary.settings`), and refused elsewhere ("f_max must be a single
  value");
- a plug-in's parameters (`filter_params`, `nominal_params`; `TABLE_PARAMETERS`) given as a
  mapping name → value: held as a frozen mapping (`controllers.contract.filter_parameters.Params`; the
  plug-in types and checks the names and values), the old "name=value;..." text read with a
  DeprecationWarning (`joined`).

`section(name, doc, settings)` makes such a class from nothing but its fields (the scenarios'
sections, `scenarios.spec`); the hardware file's sections (`hardware.config`) use the
decorator form with their own fields and checks. This module is the one implementation of
both: standard library, `vocabulary.settings` and `controllers.contract.filter_parameters` only, so the hardware layer may import it
(tests/test_layers.py).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection, Mapping
from typing import Any

from controllers.contract.filter_parameters import read_params
from vocabulary.settings import SettingError, check_value, default, setting

SETTING = "setting"  # the dataclass field metadata key that names a field's setting
TABLE_PARAMETERS = ("filter_params", "nominal_params")  # a plug-in's parameters: a frozen mapping


class _Unset:
    """The value of a section field left out: the scenario's default (`default(setting, context)`)."""

    _instance: _Unset | None = None

    def __new__(cls) -> _Unset:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "<scenario default>"

    def __reduce__(self) -> str:
        return "UNSET"


UNSET: Any = _Unset()


def joined(name: str, value: Any) -> Any:
    """A `filter_params` / `nominal_params` value as the frozen mapping the scenarios take
    (`controllers.contract.filter_parameters.read_params`: a table as given, the old "name=value;..." text with a
    DeprecationWarning; the plug-in types the values), any other value unchanged."""
    return read_params(value) if name in TABLE_PARAMETERS else value


def setting_fields(cls: type) -> dict[str, str]:
    """Field name → setting name of a section's (or a spec's own) setting fields, in declaration order."""
    return {f.name: f.metadata[SETTING] for f in dataclasses.fields(cls) if SETTING in f.metadata}


def setting_field(name: str, context: str | None = None, *, table: bool = False, per_segment: bool = False) -> Any:
    """A dataclass field of setting `name` whose default is `default(name, context)` (`UNSET` when
    `context` is None; an empty table for a `table` field; `per_segment`: a list is one value per segment)."""
    metadata = {SETTING: name, "table": table, "per_segment": per_segment}
    if table:
        return dataclasses.field(default_factory=dict, metadata=metadata)
    return dataclasses.field(default=UNSET if context is None else default(name, context), metadata=metadata)


def _checked(f: dataclasses.Field, value: Any) -> Any:
    """Field `f`'s `value` checked and normalised (module docstring); SettingError."""
    key = f.metadata[SETTING]
    if f.metadata["table"]:
        if not (isinstance(value, Mapping) and all(isinstance(k, str) for k in value)):
            raise SettingError(f"{key} must be a table of name = value, got {value!r}")
        return read_params(value)
    if isinstance(value, (list, tuple)) and setting(key).kind is not tuple:
        if not f.metadata["per_segment"]:
            raise SettingError(f"{key} must be a single value, got {value!r}")
        if not value:
            raise SettingError(f"{key} must be a number or a non-empty list of numbers, got {value!r}")
        return tuple(check_value(key, v, f"{key}[{i}]") for i, v in enumerate(value))
    return check_value(key, joined(key, value))


def check_settings(section: Any) -> None:
    """Every given setting field of `section` checked and stored normalised (module docstring); `UNSET`
    stays, and None stays where it is the field's default (none configured). SettingError."""
    for f in dataclasses.fields(section):
        if SETTING not in f.metadata:
            continue
        value = getattr(section, f.name)
        if value is UNSET or (value is None and f.default is None):
            continue
        object.__setattr__(section, f.name, _checked(f, value))


def setting_section(cls: type | None = None, *, settings: Mapping[str, str], context: str | None = None,
                    per_segment: Collection[str] = (), tables: Collection[str] = (),
                    error: Callable[[str], Exception] = SettingError) -> Any:
    """Make `cls` a frozen section whose fields `settings` (field → setting) follow its own (module
    docstring): defaults of `context`, `per_segment` fields take one value per segment, `tables` fields a
    plug-in's parameter table; a bad value raises `error(message)`. Usable as a decorator with keywords."""

    def make(cls: type) -> type:
        annotations = dict(cls.__dict__.get("__annotations__", {}))
        for f, key in settings.items():
            declared = setting(key)
            kind: Any = declared.kind
            if f in tables:
                kind = dict
            elif f in per_segment:
                kind = kind | tuple[kind, ...]
            if context is not None and default(key, context) is None:
                kind = kind | None
            annotations[f] = kind
            setattr(cls, f, setting_field(key, context, table=f in tables, per_segment=f in per_segment))
        cls.__annotations__ = annotations
        own_check = cls.__dict__.get("check")

        def __post_init__(self: Any) -> None:
            try:
                check_settings(self)
            except SettingError as exc:
                if error is SettingError:
                    raise
                raise error(str(exc)) from None
            if own_check is not None:
                own_check(self)

        __post_init__.__doc__ = "The settings checked (`vocabulary.sections.check_settings`), then the section's own `check`."
        cls.__post_init__ = __post_init__
        return dataclasses.dataclass(frozen=True)(cls)

    return make if cls is None else make(cls)


def section(name: str, doc: str, settings: Mapping[str, str], module: str = __name__) -> type:
    """A frozen section class `name` with only setting fields (field → setting), `UNSET` until given
    (module docstring); `module`: the module that binds the class to `name` (so that it pickles)."""
    cls = type(name, (), {"__doc__": doc, "__module__": module, "__qualname__": name})
    return setting_section(cls, settings=settings)
