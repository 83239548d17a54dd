"""Scenario specs: typed, frozen configuration sections, derived from the vocabulary and checked once.

A *section* groups the settings one part of a run takes: `Run` (duration, seed, q0 noise,
progress line), `Filter` (the controller under test), `Nominal` (the nominal controller),
`Model` (the controller's robot and force-safe set), `TrueArm` and `Plate` (the MuJoCo
ground truth, `softcbf_mj.physics.ground_truth`) and `Camera` (the camera path). The settings-only
sections (`Run`, `Model`, `TrueArm`, `Plate`, `Camera`) are the vocabulary's
(`vocabulary.run_sections`, which the environment and the hardware file compose too) and are
importable from here as well; `Filter` and `Nominal` are this module's (`plugin_section`: they
type a plug-in's parameters by its declarations). Each is a frozen
dataclass made by `section(name, doc, {field: setting})` (`vocabulary.sections`, the one
machinery the hardware file's sections use too): a field per setting of
`vocabulary.settings.SETTINGS`, whose type is the setting's `kind` and whose value is
checked by `check_value` when the section is built (an int given for a float becomes
one; a bad value raises `SettingError` naming the setting, its bound and unit, and the
value). Fields left out hold `UNSET`, "the scenario's default". A filter's or nominal's
parameters (`Filter.params`, `Nominal.params`) are given as a mapping name → value (a TOML table, the
command line's --filter-param NAME=VALUE items) or as keywords of their own (`Filter("e-erg",
contact_aware=True)`: `plugin_section`), and held as the frozen mapping of their typed values
(`controllers.registry.typed_params`: each converted once by the plug-in's declared kind, in its
declaration order), which `flat()`, config.json and summary.json carry as they are.

A *spec* is one scenario's whole configuration: a frozen dataclass made by
`scenario_spec(name, doc, context, sections={attribute: Section}, own={field: setting})`,
holding one instance of each section it declares plus its own few settings. Building a
spec resolves every `UNSET` field to `default(setting, context)` (the scenario's default,
`vocabulary.settings.DEFAULT_OVERRIDES`), holds the scenario's narrower `bounds`, then
runs the scenario's `check(spec)` (files, names, the filter's parameters, cross-setting
rules). A spec that exists is therefore valid: nothing downstream checks it again. What the
check builds while it checks (the controller's robot, its force-safe set, the runs with their
parsed parameters and the nominal's: `scenarios.common.Controller`) it returns, and the spec keeps it as `spec.built` (not a setting: left out of `flat()`,
equality and repr), so that the scenario's setup takes it instead of building it again.

Flat names. Every field of a spec is a setting, and a setting appears at most once in a
spec, so the setting's name is the field's flat name: `--plate-stiffness` on the command
line, `plate_stiffness = 11.16` in a TOML file, `fixed.plate_stiffness` in a study and
config.json's "params" all address `spec.plate.stiffness`. `Spec.from_flat({name: value})`
builds a spec from flat names (unknown names are refused with the list of valid ones),
`spec.flat()` gives them back in declaration order, and `flat_parameters(Spec)` the
keyword parameters (annotation = the setting's kind, default = the scenario's) from which
`scenarios.register` builds the flat entry point `Scenario.run(out_dir, **flat)` and
the command line, `--help`, `softcbf list`, TOML files, replay and studies read theirs.
Adding a setting to a section therefore reaches every one of them with no other edit
(tests/test_spec_api.py); a ground-truth setting is one entry of the vocabulary (its `section`
names `TrueArm` or `Plate`) and reaches the environment and the hardware file too
(tests/test_one_surface.py).
"""

from __future__ import annotations

import dataclasses
import inspect
from collections.abc import Callable, Mapping
from typing import Any

from controllers.registry import FILTERS, NOMINALS, did_you_mean, is_builtin, typed_params
from vocabulary.sections import UNSET, check_settings, setting_field, setting_fields
from vocabulary.run_sections import Camera, Model, Plate, Run, TrueArm
from vocabulary.sections import section as vocabulary_section
from vocabulary.settings import Bound, SettingError, default, flat_form, setting

__all__ = ["UNSET", "Run", "Filter", "Nominal", "Model", "TrueArm", "Plate", "Camera", "section", "plugin_section",
           "scenario_spec", "flat_parameters"]


def section(name: str, doc: str, fields: Mapping[str, str]) -> type:
    """A frozen section class `name` of this module whose field `f` is setting `fields[f]`, `UNSET` until
    given (`vocabulary.sections.section`)."""
    return vocabulary_section(name, doc, fields, module=__name__)


def plugin_section(name: str, doc: str, fields: Mapping[str, str], builtins: Mapping[str, Callable]) -> type:
    """A `section` for a plug-in (a filter, a nominal; `builtins`: its registry) whose field `params` holds its
    parameters: a keyword that is not a field is one of them, `Filter("e-erg", contact_aware=True)` =
    `Filter("e-erg", params={"contact_aware": True})`. A built-in's (or a preset's) parameters are typed when
    the section is built (`typed_params`: `Filter("c-erg", gain_noise_rad=1.5e-3).params` is the mapping
    {"gain_noise_rad": 0.0015}); a plug-in's from its file when the spec is built (`typed_plugins`)."""
    cls = section(name, doc, fields)
    generated, names = cls.__init__, {f.name for f in dataclasses.fields(cls)}

    def __init__(self: Any, *args: Any, **kwargs: Any) -> None:
        parameters = {k: kwargs.pop(k) for k in list(kwargs) if k not in names}
        if parameters:
            if kwargs.get("params", UNSET) is not UNSET:
                raise TypeError(f"{name}: give the parameters as params={{...}} or as keywords, not both")
            kwargs["params"] = parameters
        generated(self, *args, **kwargs)
        if is_builtin(self.name, builtins):  # a preset's parameters even when none are given
            given = None if self.params is UNSET else self.params
            object.__setattr__(self, "params", _typed(self.name, given, builtins, name.lower()))

    __init__.__doc__ = plugin_section.__doc__
    cls.__init__ = __init__
    cls.BUILTINS = builtins
    return cls


def _typed(spec: str, params: Any, builtins: Mapping[str, Callable], what: str) -> Any:
    """`typed_params`, its refusal naming the plug-in ("filter 'c-erg': ...")."""
    try:
        return typed_params(spec, params, builtins)
    except ValueError as exc:
        raise ValueError(f"{what} {spec.strip()!r}: {exc}") from None


def typed_plugins(spec: Any) -> None:
    """Set each plug-in section's `params` of the spec under construction (`spec.filter`, `spec.nominal`) to its
    typed parameters (`typed_params`), in place; a plug-in that runs isolated and is not a built-in keeps its
    parameters as given (its file is imported in its own process only, closedloop.isolation, which types them
    when it builds it)."""
    isolated = bool(getattr(getattr(spec, "filter", None), "isolate", False))
    for attribute, section_cls in type(spec).SECTIONS.items():
        builtins = getattr(section_cls, "BUILTINS", None)
        value = getattr(spec, attribute)
        if builtins is None or (isolated and not is_builtin(value.name, builtins)):
            continue
        object.__setattr__(spec, attribute, _copy(value, params=_typed(value.name, value.params, builtins, attribute)))


def _fill_unset(value: Any, context: str) -> None:
    """Set `value`'s `UNSET` setting fields to `context`'s defaults, in place (an object under construction,
    or a fresh copy)."""
    for f, key in setting_fields(type(value)).items():
        if getattr(value, f) is UNSET:
            object.__setattr__(value, f, default(key, context))


def _resolved(value: Any, context: str) -> Any:
    """A section with its `UNSET` fields set to `context`'s defaults (a copy; the given fields stay checked)."""
    if all(getattr(value, f) is not UNSET for f in setting_fields(type(value))):
        return value
    copy = _copy(value)
    _fill_unset(copy, context)
    return copy


def _copy(value: Any, **changes: Any) -> Any:
    """A copy of the frozen section `value` with the fields `changes` set, its checks not run again (its fields
    were checked when it was built; `changes` are the caller's checked values)."""
    copy = object.__new__(type(value))
    for f in dataclasses.fields(value):
        object.__setattr__(copy, f.name, changes.get(f.name, getattr(value, f.name)))
    return copy


def _build_spec(self: Any) -> None:
    """`__post_init__` of a spec (module docstring): sections typed and resolved, own settings checked
    and resolved, the scenario's bounds, then its check."""
    cls = type(self)
    for attribute, section_cls in cls.SECTIONS.items():
        value = getattr(self, attribute)
        if not isinstance(value, section_cls):
            raise TypeError(f"{cls.__name__}.{attribute} must be a {section_cls.__name__}, got {value!r}")
        object.__setattr__(self, attribute, _resolved(value, cls.CONTEXT))
    check_settings(self)
    _fill_unset(self, cls.CONTEXT)
    typed_plugins(self)
    flat = self.flat()
    for key, bound in cls.BOUNDS.items():
        if flat[key] not in bound:
            raise SettingError(f"{key} must be {bound}, got {flat[key]!r}")
    if cls.CHECK is not None:
        object.__setattr__(self, "built", cls.CHECK(self))


def _paths(cls: type) -> dict[str, tuple[str | None, str]]:
    """Flat name → (section attribute or None for an own setting, field) of spec class `cls`."""
    paths: dict[str, tuple[str | None, str]] = {}
    for attribute, section_cls in cls.SECTIONS.items():
        for f, key in setting_fields(section_cls).items():
            if key in paths:
                raise ValueError(f"{cls.__name__}: setting {key!r} is declared twice")
            paths[key] = (attribute, f)
    for f, key in setting_fields(cls).items():
        if key in paths:
            raise ValueError(f"{cls.__name__}: setting {key!r} is declared twice")
        paths[key] = (None, f)
    return paths


def _flat(self: Any) -> dict[str, Any]:
    """Every setting of the spec by its flat name, in declaration order (module docstring)."""
    return {key: flat_form(key, getattr(self if attribute is None else getattr(self, attribute), f))
            for key, (attribute, f) in type(self).PATHS.items()}


def _from_flat(cls: type, values: Mapping[str, Any]) -> Any:
    """The spec of flat `values` (the others: the scenario's defaults); ValueError for an unknown name."""
    unknown = [k for k in values if k not in cls.PATHS]
    if unknown:
        raise ValueError(f"scenario {cls.CONTEXT!r} has no parameter {unknown[0]!r}{did_you_mean(unknown[0], cls.PATHS)}; "
                         f"parameters: {', '.join(cls.PATHS)}")
    grouped: dict[str | None, dict[str, Any]] = {}
    for key, value in values.items():
        attribute, f = cls.PATHS[key]
        grouped.setdefault(attribute, {})[f] = value
    own = grouped.pop(None, {})
    return cls(**{attribute: cls.SECTIONS[attribute](**given) for attribute, given in grouped.items()}, **own)


def _replace_flat(self: Any, **values: Any) -> Any:
    """A new spec: this one with the flat settings `values` changed (checked as any spec)."""
    return type(self).from_flat({**self.flat(), **values})


def scenario_spec(name: str, doc: str, context: str, sections: Mapping[str, type], own: Mapping[str, str] | None = None,
                  bounds: Mapping[str, Bound] | None = None, check: Callable[[Any], None] | None = None,
                  module: str = __name__) -> type:
    """The spec class `name` of scenario `context` (module docstring): `sections` attribute → section
    class, `own` field → setting, `bounds` flat name → the scenario's narrower range, `check(spec)`;
    `module`: the module that binds the class to `name` (so that a spec pickles)."""
    spec = [(attribute, section_cls, dataclasses.field(default_factory=section_cls))
            for attribute, section_cls in sections.items()]
    spec += [(f, setting(key).kind, setting_field(key)) for f, key in (own or {}).items()]
    spec += [("built", Any, dataclasses.field(default=None, init=False, repr=False, compare=False))]
    namespace = {"__post_init__": _build_spec, "__doc__": doc, "__module__": module, "flat": _flat,
                 "from_flat": classmethod(_from_flat), "replace_flat": _replace_flat, "SECTIONS": dict(sections),
                 "CONTEXT": context, "BOUNDS": dict(bounds or {}), "CHECK": None if check is None else staticmethod(check)}
    cls = dataclasses.make_dataclass(name, spec, frozen=True, namespace=namespace)
    cls.PATHS = _paths(cls)
    return cls


def flat_parameters(spec_cls: type) -> dict[str, inspect.Parameter]:
    """The flat keyword parameters of spec class `spec_cls`: annotation = the type of the setting's flat
    form, default = the scenario's (`default(name, context)`) in that form (`vocabulary.settings.flat_form`:
    the tunings as the comma list), in declaration order."""
    return {key: inspect.Parameter(key, inspect.Parameter.KEYWORD_ONLY,
                                   default=flat_form(key, default(key, spec_cls.CONTEXT)),
                                   annotation=setting(key).flat_kind) for key in spec_cls.PATHS}


# The controller under test's sections (module docstring); the settings-only sections are the vocabulary's
# (vocabulary.run_sections: Run, Model, TrueArm, Plate, Camera), imported above.
Filter = plugin_section("Filter", "The controller under test: the filter, its parameters, the paper filter's tunings, "
                           "its QP backend, whether its QP holds the pressure box and whether it runs isolated "
                           "(with the nominal, in a process of its own: closedloop.isolation).",
                 {"name": "filter", "params": "filter_params", "tunings": "tunings", "qp_backend": "qp_backend",
                  "pressure_limits": "pressure_limits", "isolate": "isolate"}, FILTERS)
Nominal = plugin_section("Nominal", "The nominal controller, its parameters and the sinusoid's amplitude (hPa), "
                             "frequency (Hz) and time offset (s).",
                  {"name": "nominal", "params": "nominal_params", "amplitude": "amplitude", "frequency": "frequency",
                   "t0": "t0"}, NOMINALS)
