"""Study definition and sampling: a scenario, fixed parameters, distributions, tunings.

A study runs one registered scenario (`scenarios`, docs/run-outputs.md) many times. Its parts:

- `scenario`: the scenario's name; `fixed`: values for some of its keyword parameters;
- `vary`: one `Distribution` per varied keyword parameter of that scenario (model
  mismatches such as `plate_stiffness` or `facet_offset`, camera noise, latency, …:
  anything the scenario takes as a parameter);
- `tunings` and `tuning_parameter`: the scenario parameter that names the tuning (default
  `tunings`) and the tunings to compare;
- the controller under test: `filter` and a `[filter_params]` table go into `fixed` (the
  scenario's `filter` and `filter_params`, scenarios.common); `vary."filter_param.NAME"`
  varies one filter parameter (float unless dist = "choice"), folded into the sample's
  `filter_params` after the fixed ones; to compare filters, set `tuning_parameter =
  "filter"` and list the filter specs in `tunings` (each with its own defaults; fix
  the paper filter's `tunings` to one preset); `isolate = true` (top level, or in `fixed`)
  runs the filter and the nominal in a process of their own (closedloop.isolation);
- `sampling`: "monte_carlo" (`draws` seeded draws) or "grid" (the Cartesian product of
  every distribution's grid, the first parameter varying slowest); `seed`;
- `objective` (default "rho_min_meas"): the summary metric (a column of the rows) that
  `softcbf study falsify` minimises over the box of `vary`; "-NAME" maximises NAME
  (e.g. "-force_max_N"). A Monte Carlo or grid run ignores it.

Samples. One sample is one parameter draw run with one tuning, i.e. one run of the
scenario and one row of results. Sample index i ∈ [0, draws · T) with T tunings is
draw-major: draw d = i // T, tuning = tunings[i mod T], so every tuning meets the same
mismatches (paired comparison) and the first N·T samples are N whole draws. Draw d is a
pure function of (study, seed, d): its generator is
`numpy.random.default_rng(SeedSequence([seed, d]))`, which first draws `scenario_seed`
(an integer in [0, 2³¹), passed to the scenario's own `seed` parameter when it has one
and the study neither fixes nor varies it, e.g. the initial-pose or pixel noise) and then
one value per distribution in the order they are listed. Grid draws take the grid values
and the same `scenario_seed`.

Distributions (parameters of float type accept every kind; int, bool and str parameters
only `choice`):

| dist        | keys                      | Monte Carlo                 | grid (`points` ≥ 2)            |
|-------------|---------------------------|-----------------------------|--------------------------------|
| uniform     | low < high                | U(low, high)                | linspace(low, high, points)    |
| loguniform  | 0 < low < high            | exp U(ln low, ln high)      | geomspace(low, high, points)   |
| normal      | mean, std > 0             | N(mean, std²)               | — (refused)                    |
| choice      | values (non-empty list)   | uniform over values         | values                         |

Checked at load. A `Study` refuses, with one line naming the key or parameter, the
range and the value received: wrong types (a string for `tunings`, a list or table where
a value belongs), unknown keys and parameters, non-finite numbers, and the values the
scenario would refuse when a sample runs: the first draw with every tuning (so every
fixed value and every tuning), then both ends of every range, the mean of every normal
distribution and every choice value, each in the first sample, go through the scenario's
own checks (`scenarios.Scenario.validate`). A mistake thus stops the study before its
first sample instead of failing every sample. Draws of a normal distribution are
unbounded: one that the scenario refuses is a row with status "error" when it runs.
Sizes: draws × tunings ≤ 2⁶³ − 1 (sample indices are int64), grid `points` ≤
`MAX_GRID_POINTS`; nothing of the size of the sample count is ever built
(`softcbf.study.execute` streams the indices).

Study file (TOML, or the same tables as JSON; `load_study`, read by `vocabulary.files`):

    name = "plate_errors"
    scenario = "mujoco_contact"
    seed = 1
    sampling = "monte_carlo"        # or "grid"
    draws = 100                     # Monte Carlo only; grid: the product of the grid sizes
    tunings = ["None", "Low", "High"]
    [fixed]
    duration = 30.0
    [vary.plate_stiffness]          # N/m, the true plate (the controller assumes 11.16)
    dist = "uniform"
    low = 8.0
    high = 16.0

Settings from the command line (`load_study(path, settings)`, `softcbf study run FILE --set
KEY=VALUE`, repeatable): KEY is a dotted key into the file's tables (`fixed.duration`,
`vary.plate_stiffness.high`, `draws`, `filter_params.tuning`), VALUE a TOML value
(`10`, `"Low"`, `[1, 2]`; a bare word that is not one is a string). A setting replaces
the file's value or adds the key, before the study is checked, so it is checked as if the
file held it; a key through a value that is not a table is refused.
"""

from __future__ import annotations

import copy
import math
import tomllib
from collections.abc import Sequence
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from controllers.contract.filter_parameters import Params, read_params
from scenarios import get as get_scenario
from vocabulary.files import read_settings_file
from vocabulary.sections import joined

SAMPLINGS = ("monte_carlo", "grid")
KINDS = {"uniform": ("low", "high"), "loguniform": ("low", "high"), "normal": ("mean", "std"), "choice": ("values",)}
SEED_PARAMETER = "seed"  # the scenario parameter that receives scenario_seed
FILTER_PARAM_PREFIX = "filter_param."  # vary."filter_param.NAME": one parameter of the filter
FILTER_PARAMS = "filter_params"  # the scenario parameter they are folded into
_STUDY_KEYS = {"name", "scenario", "seed", "sampling", "draws", "tunings", "tuning_parameter", "fixed", "vary", "description",
               "filter", "filter_params", "isolate", "objective"}
DEFAULT_OBJECTIVE = "rho_min_meas"  # the summary metric `study falsify` minimises (softcbf.study.falsify)
MAX_SAMPLES = 2**63 - 1  # sample indices are int64 columns
MAX_GRID_POINTS = 1_000_000  # per distribution: its grid is held in memory


@dataclass(frozen=True)
class Distribution:
    """A distribution over one scenario parameter (keys per `kind`: module table)."""

    parameter: str
    kind: str
    low: float | None = None
    high: float | None = None
    mean: float | None = None
    std: float | None = None
    values: tuple[Any, ...] | None = None
    points: int | None = None

    def __post_init__(self) -> None:
        where = f"vary.{self.parameter}"
        if self.kind not in KINDS:
            raise ValueError(f"{where}: dist must be one of {', '.join(KINDS)}, got {self.kind!r}")
        given = {k for k in ("low", "high", "mean", "std", "values") if getattr(self, k) is not None}
        if given != set(KINDS[self.kind]):
            raise ValueError(f"{where}: dist {self.kind!r} takes exactly the keys {', '.join(KINDS[self.kind])} "
                             f"(and optionally points), got {', '.join(sorted(given)) or 'none'}")
        if self.kind == "choice":
            if not isinstance(self.values, (list, tuple)) or not self.values:
                raise ValueError(f"{where}: values must be a non-empty list, got {self.values!r}")
            object.__setattr__(self, "values", tuple(self.values))
        else:
            for key in KINDS[self.kind]:
                value = getattr(self, key)
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                    raise ValueError(f"{where}: {key} must be a finite number, got {value!r}")
                object.__setattr__(self, key, float(value))
        if self.kind in ("uniform", "loguniform") and not self.low < self.high:
            raise ValueError(f"{where}: low must be < high, got low={self.low}, high={self.high}")
        if self.kind == "uniform" and not math.isfinite(self.high - self.low):
            raise ValueError(f"{where}: high - low must be a finite number (its draws would be infinite), "
                             f"got low={self.low}, high={self.high}")
        if self.kind == "loguniform" and not self.low > 0:
            raise ValueError(f"{where}: loguniform needs low > 0, got {self.low}")
        if self.kind == "normal" and not self.std > 0:
            raise ValueError(f"{where}: std must be > 0, got {self.std}")
        if self.points is not None and (not isinstance(self.points, int) or isinstance(self.points, bool)
                                        or not 2 <= self.points <= MAX_GRID_POINTS):
            raise ValueError(f"{where}: points must be an integer in [2, {MAX_GRID_POINTS}], got {self.points!r}")

    def draw(self, rng: np.random.Generator) -> Any:
        """One Monte Carlo value."""
        if self.kind == "uniform":
            return float(rng.uniform(self.low, self.high))
        if self.kind == "loguniform":
            return float(math.exp(rng.uniform(math.log(self.low), math.log(self.high))))
        if self.kind == "normal":
            return float(rng.normal(self.mean, self.std))
        return self.values[int(rng.integers(len(self.values)))]

    def grid_size(self) -> int:
        """The number of grid values (refused for `normal`; uniform and loguniform need `points`)."""
        if self.kind == "choice":
            return len(self.values)
        if self.kind == "normal":
            raise ValueError(f"vary.{self.parameter}: a normal distribution has no grid; "
                             "use dist = 'uniform' with points, or sampling = 'monte_carlo'")
        if self.points is None:
            raise ValueError(f"vary.{self.parameter}: grid sampling needs points (>= 2) for dist {self.kind!r}")
        return self.points

    def grid_value(self, k: int) -> Any:
        """Grid value k of `grid_size()`: linspace or geomspace(low, high, points)[k], or values[k]."""
        if self.kind == "choice":
            return self.values[k]
        space = np.linspace if self.kind == "uniform" else np.geomspace
        return float(space(self.low, self.high, self.grid_size())[k])

    def ends(self) -> dict[str, Any]:
        """The values a study checks against its scenario at load, by key: both ends of a range,
        the mean of a normal, every choice value."""
        if self.kind == "choice":
            return {f"values[{i}]": v for i, v in enumerate(self.values)}
        if self.kind == "normal":
            return {"mean": self.mean}
        return {"low": self.low, "high": self.high}

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"dist": self.kind}
        for key in ("low", "high", "mean", "std", "values", "points"):
            value = getattr(self, key)
            if value is not None:
                out[key] = list(value) if key == "values" else value
        return out


@dataclass(frozen=True)
class Sample:
    """One sample: its index, draw, tuning, the drawn values and the scenario's full keyword arguments."""

    index: int
    draw: int
    tuning: str
    scenario_seed: int
    values: dict[str, Any]
    kwargs: dict[str, Any]


def fold_values(fixed: dict[str, Any], values: dict[str, Any]) -> dict[str, Any]:
    """The scenario keyword arguments of `fixed` and the drawn `values`, each varied
    filter_param.NAME folded into the mapping filter_params as NAME: value (the filter types it)."""
    kwargs = dict(fixed)
    kwargs.update({k: v for k, v in values.items() if not k.startswith(FILTER_PARAM_PREFIX)})
    varied = {k.removeprefix(FILTER_PARAM_PREFIX): v for k, v in values.items() if k.startswith(FILTER_PARAM_PREFIX)}
    if varied:
        kwargs[FILTER_PARAMS] = Params({**read_params(kwargs.get(FILTER_PARAMS)), **varied})
    return kwargs


def draw_generator(seed: int, draw: int) -> tuple[np.random.Generator, int]:
    """Draw `draw`'s generator, `numpy.random.default_rng(SeedSequence([seed, draw]))`, after it drew the
    draw's `scenario_seed` (an integer in [0, 2**31)), and that seed (module docstring)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, draw]))
    return rng, int(rng.integers(2**31))


def _named(where: str, check: Callable[..., Any], *args: Any) -> Any:
    """`check(*args)`, with a ValueError's message prefixed by `where` (the study key it came from)."""
    try:
        return check(*args)
    except ValueError as exc:
        raise ValueError(f"{where}: {exc}") from None


@dataclass(frozen=True)
class Study:
    """A validated study (module docstring): checks every name against the scenario's parameters."""

    name: str
    scenario: str
    tunings: tuple[str, ...]
    vary: tuple[Distribution, ...] = ()
    fixed: dict[str, Any] = field(default_factory=dict)
    sampling: str = "monte_carlo"
    draws: int | None = None
    seed: int = 0
    tuning_parameter: str = "tunings"
    description: str = ""
    objective: str = DEFAULT_OBJECTIVE

    def __post_init__(self) -> None:
        for key in ("name", "scenario", "tuning_parameter", "description", "objective"):
            if not isinstance(getattr(self, key), str):
                raise ValueError(f"{key} must be a string, got {getattr(self, key)!r}")
        if not self.name:
            raise ValueError("a study needs a name")
        if not self.objective.removeprefix("-"):
            raise ValueError(f'objective must name a summary metric such as "rho_min_meas" (minimised) or '
                             f'"-force_max_N" (maximised), got {self.objective!r}')
        try:
            scenario = get_scenario(self.scenario)
        except KeyError as exc:
            raise ValueError(exc.args[0]) from None
        params = scenario.parameters()
        hints = typing.get_type_hints(scenario.run)
        if isinstance(self.tunings, str) or not isinstance(self.tunings, (list, tuple)):
            raise ValueError(f'tunings must be a list of tuning names such as ["None", "Low"], got {self.tunings!r}')
        if not isinstance(self.vary, (list, tuple)) or not all(isinstance(d, Distribution) for d in self.vary):
            raise ValueError(f"vary must be a list of Distribution, got {self.vary!r}")
        if not isinstance(self.fixed, dict):
            raise ValueError(f"fixed must be a table of scenario parameters and values, got {self.fixed!r}")
        object.__setattr__(self, "tunings", tuple(self.tunings))
        object.__setattr__(self, "vary", tuple(self.vary))
        if not self.tunings or not all(isinstance(t, str) and t for t in self.tunings):
            raise ValueError(f"tunings must be a non-empty list of tuning names, got {list(self.tunings)!r}")
        if len(set(self.tunings)) != len(self.tunings):
            raise ValueError(f"tunings must not repeat, got {list(self.tunings)}")
        if self.tuning_parameter not in params or hints[self.tuning_parameter] is not str:
            raise ValueError(f"tuning_parameter must be a str parameter of scenario {self.scenario!r}, "
                             f"got {self.tuning_parameter!r}; parameters: {', '.join(params)}")
        varied = [d.parameter for d in self.vary]
        if len(set(varied)) != len(varied):
            raise ValueError(f"each parameter may be varied once, got {varied}")
        for name in [*self.fixed, *varied]:
            if name.startswith(FILTER_PARAM_PREFIX) and FILTER_PARAMS in params and name != FILTER_PARAM_PREFIX:
                continue
            if name not in params:
                raise ValueError(f"scenario {self.scenario!r} has no parameter {name!r}; parameters: {', '.join(params)}")
        clash = ({self.tuning_parameter} & (set(self.fixed) | set(varied))) | (set(self.fixed) & set(varied))
        if clash:
            raise ValueError(f"parameter(s) {sorted(clash)} are given more than once (fixed, vary or tuning_parameter)")
        object.__setattr__(self, "fixed", {k: _named(f"fixed.{k}", scenario.coerce, k, v) for k, v in self.fixed.items()})
        if set(self.fixed) & {d.parameter for d in self.vary if d.parameter.startswith(FILTER_PARAM_PREFIX)}:
            raise ValueError("filter_param.NAME may only be varied (fixed filter parameters go in filter_params)")
        fixed_params = _named(FILTER_PARAMS, read_params, self.fixed.get(FILTER_PARAMS))
        twice = sorted(set(fixed_params) & {d.parameter.removeprefix(FILTER_PARAM_PREFIX) for d in self.vary
                                            if d.parameter.startswith(FILTER_PARAM_PREFIX)})
        if twice:
            raise ValueError(f"filter parameter(s) {', '.join(twice)} are given twice (in filter_params and varied as "
                             f"filter_param.NAME); give each once")
        for dist in self.vary:
            if dist.parameter.startswith(FILTER_PARAM_PREFIX):
                continue  # the filter checks its own parameters when it is built
            if hints[dist.parameter] is not float and dist.kind != "choice":
                raise ValueError(f"parameter {dist.parameter!r} takes {hints[dist.parameter].__name__} values: "
                                 f"use dist = 'choice' with a list of values, not {dist.kind!r}")
            if dist.kind == "choice":
                object.__setattr__(dist, "values", tuple(_named(f"vary.{dist.parameter}", scenario.coerce, dist.parameter, v)
                                                         for v in dist.values))
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"sampling must be one of {', '.join(SAMPLINGS)}, got {self.sampling!r}")
        if self.sampling == "monte_carlo":
            if isinstance(self.draws, bool) or not isinstance(self.draws, int) or self.draws < 1:
                raise ValueError(f"Monte Carlo sampling needs draws, an integer >= 1, got {self.draws!r}")
        else:
            if self.draws is not None:
                raise ValueError("grid sampling takes no draws (the grid fixes their number); remove draws")
            for dist in self.vary:
                dist.grid_size()  # raises for grids that are not defined
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ValueError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.n_samples > MAX_SAMPLES:
            raise ValueError(f"draws × tunings must be <= 2**63 - 1 (sample indices are int64), got "
                             f"{self.n_draws} × {len(self.tunings)} = {self.n_samples}")
        self._check_against_scenario(scenario)

    def _check_against_scenario(self, scenario: Any) -> None:
        """The first draw with every tuning, then every distribution end, through the scenario's checks."""
        for t in range(len(self.tunings)):
            sample = self.sample(t)
            drawn = ", ".join(f"{k} = {v!r}" for k, v in sample.values.items()) or "nothing varied"
            _named(f"scenario {self.scenario!r} refuses sample {t} (draw 0 with tuning {sample.tuning!r}: the fixed values "
                   f"and {drawn})", scenario.validate, sample.kwargs)
        first = self.sample(0)
        for dist in self.vary:
            for key, value in dist.ends().items():
                kwargs = {**first.kwargs, **fold_values(self.fixed, {**first.values, dist.parameter: value})}
                _named(f"vary.{dist.parameter}: {key} = {value!r}", scenario.validate, kwargs)

    @property
    def n_draws(self) -> int:
        if self.sampling == "grid":
            return math.prod(d.grid_size() for d in self.vary)
        return int(self.draws)

    @property
    def n_samples(self) -> int:
        return self.n_draws * len(self.tunings)

    def sample(self, index: int) -> Sample:
        """Sample `index` (module docstring): a pure function of the study and the index."""
        if not 0 <= index < self.n_samples:
            raise IndexError(f"sample index must lie in [0, {self.n_samples}), got {index}")
        draw, t = divmod(index, len(self.tunings))
        rng, scenario_seed = draw_generator(self.seed, draw)
        if self.sampling == "grid":
            values, rest = {}, draw
            for d in reversed(self.vary):  # the first parameter varies slowest
                rest, k = divmod(rest, d.grid_size())
                values[d.parameter] = d.grid_value(k)
            values = {d.parameter: values[d.parameter] for d in self.vary}
        else:
            values = {d.parameter: d.draw(rng) for d in self.vary}
        return self.sample_of(index, draw, self.tunings[t], scenario_seed, values)

    def sample_of(self, index: int, draw: int, tuning: str, scenario_seed: int, values: dict[str, Any]) -> Sample:
        """Sample `index` that runs the drawn `values` with `tuning` and `scenario_seed`: the scenario's keyword
        arguments are the fixed values, `values` (filter_param.NAME folded in), the tuning, the seed (where the
        scenario has one and the study neither fixes nor varies it) and progress off."""
        kwargs = fold_values(self.fixed, values)
        kwargs[self.tuning_parameter] = tuning
        parameters = get_scenario(self.scenario).parameters()
        if SEED_PARAMETER in parameters and SEED_PARAMETER not in kwargs:
            kwargs[SEED_PARAMETER] = scenario_seed
        if "progress" in parameters:
            kwargs["progress"] = False
        return Sample(index, draw, tuning, scenario_seed, values, kwargs)

    def to_dict(self) -> dict[str, Any]:
        """The study as its file's keys (JSON/TOML-able); `from_dict` reads it back."""
        out: dict[str, Any] = {"name": self.name, "description": self.description, "scenario": self.scenario,
                               "seed": self.seed, "sampling": self.sampling, "tunings": list(self.tunings),
                               "tuning_parameter": self.tuning_parameter, "fixed": dict(self.fixed),
                               "vary": {d.parameter: d.to_dict() for d in self.vary}, "objective": self.objective}
        if self.draws is not None:
            out["draws"] = self.draws
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "Study":
        unknown = set(data) - _STUDY_KEYS
        if unknown:
            raise ValueError(f"unknown study key(s) {sorted(unknown)}; valid: {', '.join(sorted(_STUDY_KEYS))}")
        for key in ("name", "scenario", "tunings"):
            if key not in data:
                raise ValueError(f"a study needs the key {key!r}")
        for key in ("fixed", "vary"):
            if not isinstance(data.get(key, {}), dict):
                raise ValueError(f"{key} must be a table ([{key}]), got {data[key]!r}")
        vary = distributions_of(data.get("vary", {}))
        fixed = dict(data.get("fixed", {}))
        for key in ("filter", FILTER_PARAMS, "isolate"):  # isolate: the filter and nominal in their own process
            if key in data:
                if key in fixed:
                    raise ValueError(f"{key} is given twice (top level and fixed)")
                value = data[key]
                fixed[key] = _named(key, joined, key, value)
        return cls(name=data["name"], scenario=data["scenario"], tunings=data["tunings"], vary=tuple(vary),
                   fixed=fixed, sampling=data.get("sampling", "monte_carlo"),
                   draws=data.get("draws"), seed=data.get("seed", 0),
                   tuning_parameter=data.get("tuning_parameter", "tunings"), description=data.get("description", ""),
                   objective=data.get("objective", DEFAULT_OBJECTIVE))


def distributions_of(tables: dict[str, Any], table: str = "vary", prefix: str = "") -> tuple[Distribution, ...]:
    """The distributions of a file's `[vary]` tables (or another `table` of the same form, e.g. a tune file's
    `[tune]`), each named `prefix` + its key; errors name `table`.KEY."""
    out = []
    for name, spec in tables.items():
        if not isinstance(spec, dict):
            raise ValueError(f"{table}.{name} must be a table ([{table}.{name}] with dist = ...), got {spec!r}")
        spec = dict(spec)
        if "dist" not in spec:
            raise ValueError(f"{table}.{name} needs dist = one of {', '.join(KINDS)}")
        extra = set(spec) - {"dist", "low", "high", "mean", "std", "values", "points"}
        if extra:
            raise ValueError(f"{table}.{name}: unknown key(s) {sorted(extra)}")
        kind = spec.pop("dist")
        try:
            out.append(Distribution(prefix + name, kind, **spec))
        except ValueError as exc:  # Distribution names vary.PARAMETER: the file's table and key instead
            raise ValueError(str(exc).replace(f"vary.{prefix}{name}", f"{table}.{name}", 1)) from None
    return tuple(out)


def parse_setting(text: str) -> tuple[list[str], Any]:
    """"a.b.c=VALUE" → (["a", "b", "c"], the TOML value of VALUE, or VALUE itself when it is not one)."""
    key, sep, value = text.partition("=")
    path = [part.strip() for part in key.split(".")]
    if not sep or not all(path):
        raise ValueError(f"--set takes KEY=VALUE with a dotted KEY such as fixed.duration=10, got {text!r}")
    try:
        parsed = tomllib.loads(f"value = {value.strip()}")["value"]
    except tomllib.TOMLDecodeError:
        parsed = value.strip()
    return path, parsed


def apply_settings(data: dict[str, Any], settings: Sequence[str]) -> dict[str, Any]:
    """A copy of a study file's `data` with each "dotted.key=VALUE" of `settings` set (module docstring)."""
    out = copy.deepcopy(data)
    for text in settings:
        path, value = parse_setting(text)
        table = out
        for depth, part in enumerate(path[:-1]):
            table = table.setdefault(part, {})
            if not isinstance(table, dict):
                raise ValueError(f"--set {text}: {'.'.join(path[:depth + 1])} is not a table, got {table!r}")
        table[path[-1]] = value
    return out


def load_study(path: str | Path, settings: Sequence[str] = ()) -> Study:
    """Read a study file (TOML, module docstring) with the command line's `settings`
    ("dotted.key=VALUE", applied before the checks); errors name the file."""
    path = Path(path)
    data = read_settings_file(path, "study file")
    try:
        return Study.from_dict(apply_settings(data, settings))
    except ValueError as exc:
        raise ValueError(f"study file {path}: {exc}") from None

