"""Declared bounds of the built-in filters' parameters, and their one check.

Each built-in filter (paper-cbf, qsg, e-erg) declares every parameter once, in its own
module, as a `FilterParameter` (meaning, unit, kind, valid range, whether None is allowed)
in a dict `name → FilterParameter`. The same table serves three uses:

- `check_parameters(table, arguments)`: the filter's `check_arguments(arguments)`, which
  `controllers.registry.check_filter` runs before anything is built (a study's runs are
  refused before any sample runs), and the first lines of its constructor;
- `parameter_docs(table)`: the filter's `parameter_docs` ("meaning; valid range [unit]"),
  which `softcbf list` and docs/parameters.md show.

A range is a `controllers.bounds.Bound` and the check is `controllers.bounds.check_number`
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
from collections.abc import Mapping
from dataclasses import dataclass

from controllers.bounds import Bound, SettingError, check_number


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
