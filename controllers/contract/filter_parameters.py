"""Declared bounds of the built-in filters' parameters, and their one check.

Each built-in filter (paper-cbf, qsg, e-erg) declares every parameter once, in its own
module, as a `FilterParameter` (meaning, unit, kind, valid range, whether None is allowed)
in a dict `name → FilterParameter`. The same table serves three uses:

- `check_parameters(table, arguments)`: the filter's `check_arguments(arguments)`, which
  `controllers.registry.check_filter` runs before anything is built (a study's runs are
  refused before any sample runs), and the first lines of its constructor;
- `parameter_docs(table)`: the filter's `parameter_docs` ("meaning; valid range [unit]"),
  which `softcbf list` and docs/parameters.md show;
- each declaration's kind is the annotation of the filter's signature, by which
  `controllers.registry.typed_params` converts a value given at any edge once.

The values themselves travel as `Params`, a frozen mapping name → typed value in the filter's
declaration order (a `dict` whose mutators raise, so that JSON, `dict(...)` and equality work as
for a dict): what a scenario's spec, config.json, summary.json, the environment and the hardware
file hold. `read_params` reads what an edge gives before the kinds are known: a mapping (values as
given; a str may hold ';' and '='), or the old joined text "name=value;name=value" (`parse_text`,
with a DeprecationWarning for one release). `value_text` writes a typed value as the command line
does (a run's label): true/false, none, a float's shortest round-trip form.

A range is a `controllers.core.bounds.Bound` and the check is `controllers.core.bounds.check_number`
(the settings' own check): a refusal is a `SettingError` (a ValueError) naming the
parameter, the bound with its unit and the value received, e.g. "kappa must be in
[0, 1000], got -1.0". A bound is physical (a margin ≥ 0 m, a ratio > 0) or computational
(a halving count that still changes a double, a delay within the predictor's horizon, a
grid step whose table fits in memory); bounds that need the filter's context (the
pressure box, the robot) are checked by the constructor alone and documented with the
parameter. Cross-parameter rules (stiffness_lo_ratio ≤ stiffness_hi_ratio, a custom
tuning's three numbers) are the filter's own `check_arguments`.
"""

from __future__ import annotations

import numbers
import warnings
from collections.abc import Mapping
from dataclasses import dataclass

from controllers.core.bounds import Bound, SettingError, check_number


@dataclass(frozen=True)
class FilterParameter:
    """One filter parameter's declaration.

    meaning: a phrase; unit: "1" for a pure number, "" for a name or a switch; kind: float,
    int, bool or str; bound: the valid range of a number (None for bool and str);
    optional: None is a valid value (it then means what `meaning` says).
    """

    meaning: str
    unit: str
    kind: type = float
    bound: Bound | None = None
    optional: bool = False

    def __post_init__(self) -> None:
        if (self.bound is None) != (self.kind in (bool, str)):
            raise ValueError(f"a {self.kind.__name__} parameter {'has no' if self.kind in (bool, str) else 'needs a'} bound")

    @property
    def doc(self) -> str:
        """"meaning; valid range [unit]" (`parameter_docs`)."""
        valid = "" if self.bound is None else f"; {self.bound}{' (or None)' if self.optional else ''}"
        return f"{self.meaning}{valid} [{self.unit or '-'}]"

    def check(self, name: str, value: object) -> object:
        """`value` checked (module docstring) and normalised (an int given for a float becomes one)."""
        if value is None and self.optional:
            return None
        if self.kind is bool:
            if not isinstance(value, bool):
                raise SettingError(f"{name} must be true or false, got {value!r}")
            return value
        if self.kind is str:
            if not isinstance(value, str):
                raise SettingError(f"{name} must be a string, got {value!r}")
            return value
        if self.kind is int and isinstance(value, numbers.Integral) and not isinstance(value, bool):
            value = int(value)  # numpy integers too
        elif self.kind is float and isinstance(value, numbers.Real) and not isinstance(value, (bool, int)):
            value = float(value)  # numpy floats too
        return check_number(name, value, self.bound, integer=self.kind is int)


def check_parameters(table: Mapping[str, FilterParameter], arguments: Mapping[str, object]) -> dict[str, object]:
    """The declared parameters among `arguments`, each checked (`FilterParameter.check`):
    {name: normalised value}. Names the table does not declare are left to the caller."""
    return {name: table[name].check(name, value) for name, value in arguments.items() if name in table}


def parameter_docs(table: Mapping[str, FilterParameter]) -> dict[str, str]:
    """{name: "meaning; valid range [unit]"} for a filter's `parameter_docs`."""
    return {name: parameter.doc for name, parameter in table.items()}


class Params(dict):
    """A plug-in's parameters, typed and frozen: name → value, in the filter's declaration order.

    What every surface hands on and every record stores (`controllers.registry.typed_params` builds it
    from the CLI's, a TOML table's, a study's, the API's, the environment's or the hardware file's
    parameters): a `dict` (so `json.dumps`, `dict(params)` and equality with a plain dict work as for
    one) whose mutators raise TypeError, hashable while its values are, and picklable. Values are
    whatever the declared kinds made of them (float, int, bool, str, None; a plug-in's own types as
    given): a str may hold ';' or '=', nothing is joined or split after the edge.
    """

    __slots__ = ()

    def _frozen(self, *args: object, **kwargs: object) -> None:
        raise TypeError("filter parameters are frozen: build new ones, e.g. Params({**params, name: value})")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = __ior__ = _frozen  # type: ignore[assignment]

    def __hash__(self) -> int:  # type: ignore[override]
        return hash(tuple((name, repr(value)) for name, value in self.items()))

    def __reduce__(self) -> tuple[type, tuple[dict[str, object]]]:
        return Params, (dict(self),)

    def __or__(self, other: Mapping[str, object]) -> Params:  # type: ignore[override]
        return Params({**self, **other})

    def copy(self) -> Params:  # type: ignore[override]
        return self


OLD_TEXT_WARNING = ("parameters as one 'name=value;name=value' text are deprecated and will be refused in the next "
                    "release: give a mapping (a TOML table, {name: value}) or one --filter-param NAME=VALUE each")


def parse_text(text: str) -> dict[str, str]:
    """"name=value;name=value" (the old joined form: a file's, a study's, a record's or the API's text)
    → {name: value} (each value split at its first '='). ValueError for an item that is not name=value,
    and for a name given twice (the last would silently win)."""
    out: dict[str, str] = {}
    for item in (text or "").split(";"):
        if item.strip():
            add_pair(out, item, "parameter")
    return out


def add_pair(out: dict[str, str], item: str, what: str) -> None:
    """Add one "NAME=VALUE" `item` to `out` (its value everything after the first '=', both stripped); ValueError
    naming `what` (the option or "parameter") for an item that is not NAME=VALUE, or a NAME given twice (the last
    would silently win)."""
    name, sep, value = item.partition("=")
    if not sep or not name.strip():
        raise ValueError(f"{what} takes NAME=VALUE, got {item.strip()!r}")
    name, value = name.strip(), value.strip()
    if name in out:
        raise ValueError(f"{what} {name} is given twice ({name}={out[name]}, then {name}={value}); give it once")
    out[name] = value


def read_params(value: object) -> Params:
    """A plug-in's parameters as given at an edge, before their kinds are known: a mapping name → value
    (values as given), None or "" (none), or the old joined text "name=value;..." (read with
    `parse_text` and a DeprecationWarning, for one release). ValueError (a SettingError) for anything else."""
    if value is None or (isinstance(value, str) and not value.strip()):
        return Params()
    if isinstance(value, str):
        warnings.warn(OLD_TEXT_WARNING, DeprecationWarning, stacklevel=3)
        return Params(parse_text(value))
    if isinstance(value, Mapping) and all(isinstance(name, str) for name in value):
        return value if isinstance(value, Params) else Params(value)
    raise SettingError(f"parameters must be a table of name = value, got {value!r}")


def value_text(value: object) -> str:
    """A typed value as the command line writes it (a run's label, `NAME=VALUE`): true/false, none, a float's
    shortest round-trip form (0.0015, 2e-06; a whole number without its ".0", 100, which its declared kind
    reads back as the same float), anything else as str."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if value is None:
        return "none"
    if isinstance(value, float):
        return str(int(value)) if value.is_integer() and abs(value) < 1e15 else repr(value)
    return str(value)
