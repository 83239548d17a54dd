"""Which coordinates of a worst-case search's box lie beyond what the filter under test certifies.

The bench's worst case found (softcbf.bench.runner) searches the standard mismatch box for every filter alike;
a filter that certifies a narrower set of errors than the box may fail inside the box without failing its own
guarantee. bench.json's `beyond_certified` (per worst_found entry) names the box's coordinates where that is
so, and bench.md and the printed line then label the worst case "over a box wider than this filter
certifies", naming them.

What a filter certifies, per box coordinate (`CERTIFIED_BY`): an interval stated by two of its parameters,
each a multiple of the model's value —

| box coordinate     | the filter's parameters                   | certified values                                  |
|--------------------|-------------------------------------------|---------------------------------------------------|
| plate_stiffness    | stiffness_lo_ratio, stiffness_hi_ratio    | [lo, hi] × the assumed plate stiffness (N/m)      |
| true_gain_scale    | gain_lo_ratio, gain_hi_ratio              | [lo, hi] (1: the model's actuator gain)           |
| facet_offset       | plate_offset_lo_m, plate_offset_hi_m      | [lo, hi] (m along the facet's normal)             |
| true_stiffness_scale | arm_stiffness_lo_ratio, arm_stiffness_hi_ratio | [lo, hi] (1: the model's arm stiffness)    |
| true_damping_scale | damping_lo_ratio                          | [lo, ∞) (any damping above it)                    |
| tau_p              | actuator_tau_lo_s, actuator_tau_hi_s      | [lo, hi] (s; None: the model's lag alone)         |

(the energy governors' declarations: c-erg and e-erg; c-erg's certificates, controllers.governors.energy_governor). The
parameters' values are the filter's as the search runs it: the spec's (a preset's, `c-erg:standard-box`, included)
and the bench's per-case parameters converted by the registry (`typed_params`), the factory's signature defaults
for the rest. A filter without such parameters, and every other coordinate, is certified at the model's value
alone (a c-erg configured by `box=FILE` is read at its parameters, so it is reported as certifying less). Assumption: a filter's guarantee covers exactly the intervals its parameters state; one that
covers more without saying so is reported as certifying less (a conservative label, never a false pass).

A coordinate is beyond the certified set when its distribution's support is not inside the certified
interval: a uniform or log-uniform [low, high] not within [c_lo, c_hi] (relative tolerance `REL_TOL`, so
that the box's 8.928 N/m is 0.8 × 11.16 N/m; of the finite ends only: an interval open above, as the damping's,
would otherwise take in everything), a normal distribution always (unbounded), a choice when one
of its values lies outside.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Mapping
from typing import Any

from controllers.registry import FILTERS, resolve, typed_params
from scenarios import get as get_scenario
from softcbf.study.definition import Distribution, Study

CERTIFIED_BY: dict[str, tuple[str, str | None, str | None]] = {
    "plate_stiffness": ("stiffness_lo_ratio", "stiffness_hi_ratio", "assumed_plate_stiffness"),
    "true_gain_scale": ("gain_lo_ratio", "gain_hi_ratio", None),
    "facet_offset": ("plate_offset_lo_m", "plate_offset_hi_m", None),
    "true_stiffness_scale": ("arm_stiffness_lo_ratio", "arm_stiffness_hi_ratio", None),
    "true_damping_scale": ("damping_lo_ratio", None, None),
    "tau_p": ("actuator_tau_lo_s", "actuator_tau_hi_s", None),
}
"""box coordinate → (the filter's low end, its high end (None: unbounded above), the study parameter the ends
multiply; None: 1)."""
MODEL_VALUES = {"facet_offset": 0.0, "facet_angle": 0.0, "true_stiffness_scale": 1.0, "true_damping_scale": 1.0,
                "true_gain_scale": 1.0, "true_length_scale": 1.0}
"""The model's value of the box coordinates whose model value is fixed (others: the scenario's default)."""
REL_TOL = 1e-9


def filter_values(name: str, params: Mapping[str, str]) -> dict[str, Any]:
    """The filter `name`'s parameter values with `params` given: converted (`arguments`), defaults for the rest."""
    factory = resolve(name, FILTERS)
    defaults = {n: p.default for n, p in inspect.signature(factory).parameters.items()
                if p.default is not inspect.Parameter.empty}
    return {**defaults, **typed_params(name, params)}


def study_value(study: Study, parameter: str) -> float:
    """`parameter`'s value in `study`: its fixed value, else the scenario's default; ValueError when it has none."""
    value = study.fixed.get(parameter, get_scenario(study.scenario).defaults().get(parameter))
    if value is None:
        raise ValueError(f"study {study.name!r} has no value of {parameter}")
    return float(value)


def certified_interval(coordinate: str, values: Mapping[str, Any], study: Study) -> tuple[float, float] | None:
    """The values of box `coordinate` the filter (its parameter `values`) certifies, as [lo, hi] (module docstring);
    None when it certifies only the model's value and the study has none (nothing drawn can be inside then)."""
    if coordinate in CERTIFIED_BY:
        lo_name, hi_name, scale_name = CERTIFIED_BY[coordinate]
        lo, hi = values.get(lo_name), math.inf if hi_name is None else values.get(hi_name)
        if lo is not None and hi is not None:
            scale = 1.0 if scale_name is None else study_value(study, scale_name)
            return float(lo) * scale, float(hi) * scale
    model = MODEL_VALUES.get(coordinate)
    if model is None:
        reference = CERTIFIED_BY.get(coordinate, (None, None, coordinate))[2] or coordinate
        model = study.fixed.get(reference, get_scenario(study.scenario).defaults().get(reference))
    return None if model is None else (float(model), float(model))


def inside(distribution: Distribution, interval: tuple[float, float] | None) -> bool:
    """Whether every value `distribution` can draw lies in `interval` (within `REL_TOL`; None: nothing does)."""
    if interval is None or distribution.kind == "normal":
        return False
    lo, hi = interval
    slack = REL_TOL * max(1.0, *(abs(end) for end in interval if math.isfinite(end)))  # an open end adds none
    support = distribution.values if distribution.kind == "choice" else (distribution.low, distribution.high)
    return all(isinstance(v, (int, float)) and lo - slack <= float(v) <= hi + slack for v in support)


def beyond_certified(name: str, params: Mapping[str, str], study: Study) -> list[str]:
    """The coordinates of `study`'s box (its `vary`) beyond what the filter `name` with `params` certifies, in the
    box's order ([]: the filter certifies the whole box)."""
    values = filter_values(name, params)
    return [d.parameter for d in study.vary if not inside(d, certified_interval(d.parameter, values, study))]
