"""The valid range of a number and its one check: `Bound` and `check_number` (standard library only).

The settings' vocabulary (`vocabulary.settings`) and the built-in filters' parameter
declarations (`controllers.contract.filter_parameters`) both state ranges with `Bound` and check a
value with `check_number`, so a setting and a filter parameter are refused in the same words:
"kappa must be in [0, 1000], got -1.0". It lives at the bottom of the controllers so that the
controller under test imports nothing of the testbed; the vocabulary imports it from here.
A plausibility bound |value| <= plausible in a unit names the likely mistake of a value
beyond it (`LIKELY_MISTAKES`: seconds given in ms, hPa in Pa, m in mm, rad in degrees).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any


class SettingError(ValueError):
    """A setting's value is refused; the message names the setting, the bound with its unit and the value."""


@dataclass(frozen=True)
class Bound:
    """The valid range of a number: `low` <= value <= `high` (None: unbounded), `<` instead
    of `<=` where open; `unit` for the message. Floats must also be finite."""

    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    unit: str = ""

    def __contains__(self, value: float) -> bool:
        if isinstance(value, float) and not math.isfinite(value):
            return False
        if self.low is not None and (value <= self.low if self.low_open else value < self.low):
            return False
        return self.high is None or (value < self.high if self.high_open else value <= self.high)

    def __str__(self) -> str:
        unit = f" {self.unit}" if self.unit else ""
        if self.low is not None and self.high is not None:
            return f"in {'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}{unit}"
        if self.low is not None:
            return f"{'>' if self.low_open else '>='} {self.low:g}{unit}"
        if self.high is not None:
            return f"{'<' if self.high_open else '<='} {self.high:g}{unit}"
        return "finite"


def positive(unit: str = "") -> Bound:
    """> 0 (and finite)."""
    return Bound(0.0, low_open=True, unit=unit)


def non_negative(unit: str = "") -> Bound:
    """>= 0 (and finite)."""
    return Bound(0.0, unit=unit)


def finite(unit: str = "") -> Bound:
    """Any finite number."""
    return Bound(unit=unit)


LIKELY_MISTAKES = {"s": ("ms", 1e-3), "hPa": ("Pa", 1e-2), "m": ("mm", 1e-3), "rad": ("°", math.pi / 180)}


def _plausibility_hint(value: float, unit: str) -> str:
    if unit not in LIKELY_MISTAKES:
        return "a plausibility bound"
    wrong, factor = LIKELY_MISTAKES[unit]
    return f"a plausibility bound; a value in {wrong}? {value:g} {wrong} = {value * factor:.4g} {unit}"


def check_number(key: str, value: Any, bound: Bound, *, plausible: float | None = None, unit: str = "",
                 integer: bool = False) -> float | int:
    """`value` as a number within `bound` and, when given, |value| <= `plausible` (in `unit`):
    a float (an int given for it becomes one) or, with `integer`, an int; SettingError
    "KEY must be BOUND, got VALUE" (module docstring) naming `key` otherwise."""
    if integer:
        if isinstance(value, bool) or not isinstance(value, int):
            raise SettingError(f"{key} must be an integer {bound}, got {value!r}")
    else:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise SettingError(f"{key} must be a number {bound}, got {value!r}")
        if isinstance(value, int) and abs(value) > sys.float_info.max:
            raise SettingError(f"{key} must be a finite number {bound}, got an integer of {len(str(abs(value)))} digits")
        value = float(value)
        if not math.isfinite(value):
            described = str(bound)
            raise SettingError(f"{key} must be finite{'' if described == 'finite' else ' and ' + described}, got {value!r}")
    if value not in bound:
        raise SettingError(f"{key} must be {bound}, got {value!r}")
    if plausible is not None and abs(value) > plausible:
        one_sided = bound.low is not None and bound.low >= 0
        raise SettingError(f"{key} must be {'<= ' if one_sided else 'within ±'}{plausible:g} {unit} "
                           f"({_plausibility_hint(value, unit)}), got {value!r}")
    return value
