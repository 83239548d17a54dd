"""The safety-filter plug-in contract (docs/safety-filter.md): what a loop gives a filter and what it gets back.

A safety filter maps the controller's view of the state and a nominal command to the
command that is sent:

    filter(estimate: Estimate, u_nom: (N,) hPa) -> FilterOutput | (N,) array of hPa

- `Estimate`: t (s, the control time), q (N,) rad, qd (N,) rad/s and t_capture (s, when
  the measurement behind q and qd was taken; t_capture = t for the exact state, earlier
  for a camera). `t − t_capture` is the estimate's age, over which a filter may predict.
- A bare array return means "this is u"; the loop wraps it in `FilterOutput(u)` with the
  neutral defaults (action "user", not infeasible, no predicted margin, no diagnostics).
- `FilterOutput.diagnostics` is the place for everything specific to one filter (the
  CBF's b, B and active rows, a governor's certificate): a plain mapping, str key → a real
  number, a bool or a small array of them, with the same keys and shapes every call;
  `diagnostic_units` declares the unit of each key, and the recorder stores them as
  time-series columns. Nothing outside a filter's own module reads a filter-specific field
  by name. How they are laid out in a row is the recorder's business (`controllers.contract.diagnostics`).
- Filters may keep state (their own command history); `reset()`, when present, is
  called before each run (`reset_filter`).
- `FilterContext` is what a filter is told at construction (the registry passes it to
  factories that ask for a `context` argument): the robot model, the force-safe set,
  the pressure limits, the control period and, where known, the command's delay and
  the actuator's time constant; each plug-in is handed its own copy (`FilterContext.copy`).

Capabilities are declared, never guessed. Everything beyond `__call__` (and the optional `reset()`)
that a loop may use is declared by the filter's `capabilities`, a `Capabilities`
(`controllers.contract.capabilities`; a class attribute, or a property where it depends on the filter's parameters); a filter that declares none has the
minimal contract (the Protocol `SafetyFilter`), `Capabilities()`: it is called once per simulation,
whatever other methods it has. `filter_capabilities(f)` is the one reader, asked by every loop (the
control step, the batch form of a scenario, the vector environment, the isolated process) and by the
registry when it builds a filter; it checks that the filter implements what it declares and refuses
it otherwise with `CapabilityError`, one line, when the filter is built or the loop is set up, never
in the middle of a run:
- batched: `filter_batch(EstimateBatch, u_nom (B, N)) → BatchOutput` filters B states at once and
  gives the same commands as B calls of `__call__` on B independent copies of the filter (one
  per simulation: a stateful filter keeps B histories); a batched loop calls it once for all
  its simulations (`softcbf_mj.loops.batch_loop`);
- rows (with batched): the filter keeps one history per simulation, and `filter_batch(...,
  rows=ids)` is told the indices of the simulations it serves (`batch_history_ids`);
- reset_rows: `reset(rows=ids)` restarts those simulations' histories alone (the vector
  environment's autoreset of one arm); a shared filter without it is reset when all restart;
- passthrough: the filter passes u_nom through (the paper's None tuning); its call times are
  not reported as filter times.
A nominal controller (`controllers.nominal`) declares its capabilities the same way, read by the same
reader (`plugin_capabilities`; `nominal_capabilities(n)`, its `NOMINAL_CONTROLLER` kind): batched alone,
`nominal_batch(t (B,), q, qd) → (B, N)`, the rows of B calls bit for bit; one that declares nothing is
called once per simulation, whatever other methods it has.

Whatever a filter returns, the control step clips it to the limits and refuses
non-finite commands (`closedloop.step`); a filter need not repeat that.

What a loop accepts (the plug-in boundary is a trust boundary, docs/safety-filter.md#the-plug-in-boundary-is-a-trust-boundary). A filter is
somebody else's code, so the control step hands it copies it cannot make writable (`frozen`:
the estimate's q and q̇, u_nom; the context's limits are read-only copies) and converts its
return once (`OutputCheck`, every value read once into plain floats, the diagnostics too): a bare
return must be n real numbers (an ndarray, list or tuple; not bool, complex or object
values), a FilterOutput must have such a u, a str action, a bool infeasible, a real
rho_pred (NaN for none) and diagnostics of str keys and real values, at most
DIAGNOSTIC_FLOATS_MAX floats, with the same keys and shapes every call. Anything else
raises `FilterReturnError`, which the control step treats like an exception from the
filter: a filter fault (hold, then vent, and the run stops; `closedloop.step`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from copy import deepcopy
from dataclasses import dataclass, field, fields, replace
from typing import Protocol, runtime_checkable

import numpy as np

from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.model.params import RobotParams
from controllers.model.safe_set import ForceSafeSet

USER_ACTION = "user"  # the action label of a bare-array return


@dataclass(eq=False, slots=True)
class Estimate:
    """The controller's view of the state: t and t_capture (s), q (N,) rad, qd (N,) rad/s.
    Made every control call, so not frozen (cheaper to build); nothing modifies it once made."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    t_capture: float

    @property
    def age(self) -> float:
        """t − t_capture (s): how old the measurement behind q and qd is at the control time."""
        return self.t - self.t_capture


@dataclass(frozen=True, eq=False)
class EstimateBatch:
    """B estimates at once: t, t_capture (B,) s; q, qd (B, N) rad and rad/s."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    t_capture: np.ndarray

    def __len__(self) -> int:
        return int(self.q.shape[0])

    def __getitem__(self, i: int) -> Estimate:
        return Estimate(float(self.t[i]), self.q[i], self.qd[i], float(self.t_capture[i]))


@dataclass(eq=False, slots=True)
class FilterOutput:
    """One filter call's result. Made every control call, so not frozen (a frozen dataclass
    costs ~1 µs more to build); nothing modifies it once returned.

    u: (N,) hPa, the filter's command (before the loop's clipping).
    action: a short label of what the filter did ("user" for a bare array; the paper's
        CBF uses "disabled", "nominal", "qp", "recovery", "slack", "vent").
    infeasible: the filter could not satisfy its own constraints and says so.
    rho_pred: the margin (1) the filter predicts from its estimate and model, min over
        facets; NaN when the filter makes no prediction.
    diagnostics: filter-specific values by name (floats or small arrays, fixed shapes
        over a run); diagnostic_units: the unit of every key of diagnostics.
    """

    u: np.ndarray
    action: str = USER_ACTION
    infeasible: bool = False
    rho_pred: float = math.nan
    diagnostics: Mapping[str, object] = field(default_factory=dict)
    diagnostic_units: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        diagnostics = self.diagnostics
        if type(diagnostics) is FlatDiagnostics and diagnostics.layout.units is self.diagnostic_units:
            return  # the layout checked its units once
        if diagnostics and not diagnostics.keys() <= self.diagnostic_units.keys():
            missing = set(self.diagnostics) - set(self.diagnostic_units)
            raise ValueError(f"diagnostic_units must declare a unit for every diagnostic, missing {sorted(missing)}")


@dataclass(frozen=True, eq=False)
class BatchOutput:
    """B filter calls' results: u (B, N) hPa, action (B,) str, infeasible (B,) bool, rho_pred (B,)."""

    u: np.ndarray
    action: np.ndarray
    infeasible: np.ndarray
    rho_pred: np.ndarray


@dataclass(frozen=True, eq=False)
class FilterContext:
    """What a filter is told at construction.

    robot: the controller's model of the arm; safe_set: the force-safe set P it must keep
    the tip in; u_min, u_max: (N,) hPa, the pressure limits (None: unbounded, the paper's
    simulation); control_dt: s, the period between filter calls; command_delay: s, the
    time from the filter's call to the command taking effect at the valves, beyond the
    estimate's own age (None: unknown); actuator_tau: s, the pressure's first-order time
    constant (0: ideal valve; None: unknown).

    The context is handed to code the testbed did not write. A loop keeps its own context
    (the one its control step reads its limits from) and hands each plug-in `copy()`: its
    own robot, safe set and limits, so nothing a plug-in does to what it was handed (in
    place, or by `object.__setattr__` on these frozen objects) reaches the loop's context,
    the plant or the verdict; the controller's model of the dynamics is the plug-in's own,
    built from `robot` (never an object a plant integrates with). u_min and u_max are
    read-only copies (an in-place change raises ValueError), and `limits` holds the same
    limits as tuples of floats, which is what the control step clips to (`closedloop.step`).
    """

    robot: RobotParams
    safe_set: ForceSafeSet
    u_min: np.ndarray | None
    u_max: np.ndarray | None
    control_dt: float
    command_delay: float | None = None
    actuator_tau: float | None = None
    limits: tuple[tuple[float, ...], tuple[float, ...]] | None = field(default=None, init=False, repr=False)

    @classmethod
    def for_robot(cls, robot: RobotParams, safe_set: ForceSafeSet, control_dt: float, pressure_limits: bool = True,
                  **known: object) -> "FilterContext":
        """The context of `robot` with its own limits u_min, u_max when `pressure_limits`
        (None otherwise); `known`: command_delay, actuator_tau."""
        limits = (np.array(robot.u_min, dtype=float), np.array(robot.u_max, dtype=float)) if pressure_limits else (None, None)
        return cls(robot, safe_set, *limits, control_dt, **known)

    def __post_init__(self) -> None:
        if (self.u_min is None) != (self.u_max is None):
            raise ValueError("u_min and u_max must both be given or both be None")
        if self.u_min is not None:
            n = self.robot.n_segments
            lo, hi = np.asarray(self.u_min, dtype=float), np.asarray(self.u_max, dtype=float)
            if lo.shape != (n,) or hi.shape != (n,) or not (np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()):
                raise ValueError(f"u_min < u_max must be finite arrays of shape ({n},) hPa, got {self.u_min} and {self.u_max}")
            object.__setattr__(self, "u_min", read_only(lo.copy()))
            object.__setattr__(self, "u_max", read_only(hi.copy()))
            object.__setattr__(self, "limits", (tuple(lo.tolist()), tuple(hi.tolist())))
        if not (math.isfinite(self.control_dt) and self.control_dt > 0):
            raise ValueError(f"control_dt must be finite and > 0 s, got {self.control_dt}")
        for name in ("command_delay", "actuator_tau"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be finite and >= 0 s (or None: unknown), got {value}")

    def copy(self) -> "FilterContext":
        """An independent copy for one plug-in (class docstring): the robot, the safe set (its
        environment and stiffness law) and the limits rebuilt, each checked and read-only again as
        at construction; nothing in it is an object of this context."""
        safe_set = self.safe_set
        own_set = replace(safe_set, environment=replace(safe_set.environment), stiffness=deepcopy(safe_set.stiffness))
        return replace(self, robot=replace(self.robot), safe_set=own_set)

    @property
    def bounded(self) -> bool:
        """True when the pressure limits are on."""
        return self.u_min is not None


@runtime_checkable
class SafetyFilter(Protocol):
    """The minimal contract: callable as `filter(estimate, u_nom)`, returning a FilterOutput or a bare (N,)
    array; optionally `reset()`. A filter declares more with a `capabilities` attribute (`Capabilities`)."""

    def __call__(self, estimate: Estimate, u_nom: np.ndarray) -> FilterOutput | np.ndarray: ...


class PassThroughFilter:
    """No filter: u = u_nom (the loop still clips it to the limits)."""

    parameter_docs: dict[str, str] = {}

    def __call__(self, estimate: Estimate, u_nom: np.ndarray) -> np.ndarray:
        return u_nom


class FilterReturnError(TypeError):
    """A filter or nominal controller returned something the contract does not allow (module
    docstring: "What a loop accepts"); the control step treats it as a filter fault."""


DIAGNOSTIC_FLOATS_MAX = 256  # floats of diagnostics one call may return (the recorder keeps them every row)
_INT_MAX = 2**1023  # a Python int beyond this is no float
# numpy's real scalar types (not bool), exactly: their float() is numpy's own, no user code
_NUMPY_REALS = frozenset(np.dtype(code).type for code in np.typecodes["Float"] + np.typecodes["AllInteger"])
_PLAIN = frozenset({float, bool, np.float64, np.bool_})  # flat diagnostic values kept as they are


def read_only(values: np.ndarray) -> np.ndarray:
    """`values`, a new array its caller owns, made read-only (an in-place change raises
    ValueError) and returned. Its owner can set the flag back: what user code is handed is `frozen`."""
    values.setflags(write=False)  # as `flags.writeable = False`, without building a flags object
    return values


def frozen(values: object, dtype: type = float) -> np.ndarray:
    """A read-only copy of `values` as `dtype` whose flag cannot be set back: its memory is an
    immutable bytes object, so `setflags(write=True)` raises ValueError on it, on its views and on
    its `.base` alike. What the control step hands user code (an estimate's q and q̇, u_nom, the
    rows of a batch): nothing a filter does to it reaches what the step records."""
    array = np.asarray(values, dtype=dtype)
    copy = np.frombuffer(array.tobytes(), dtype)  # (tobytes: C order, whatever the strides)
    return copy[:] if array.ndim == 1 else copy.reshape(array.shape)  # a view of it, as a batch's rows are


def real_vector(value: object, n: int, what: str, freeze: bool = False) -> np.ndarray:
    """`value` as a new float array of shape (n,) (with `freeze`: `frozen`, one copy): an ndarray,
    list or tuple of n real numbers (int or float; not bool, complex, object or str);
    FilterReturnError naming `what` otherwise. Non-finite entries are kept (the control step
    refuses them as commands). Whatever the conversion of a hostile value raises propagates (the
    control step's fault boundary)."""
    if type(value) is np.ndarray:
        array = value
    elif isinstance(value, (np.ndarray, list, tuple)):
        try:
            array = np.asarray(value)
        except (ValueError, TypeError, OverflowError) as exc:
            raise FilterReturnError(f"{what} must be {n} real numbers, got an unreadable {type(value).__name__}: "
                                    f"{exc}") from None
    else:
        raise FilterReturnError(f"{what} must be an array of {n} real numbers (hPa), got {type(value).__name__}")
    if array.dtype.kind not in "fiu":
        raise FilterReturnError(f"{what} must hold real numbers (float or int), got dtype {array.dtype}")
    if array.shape != (n,):
        raise FilterReturnError(f"{what} must have shape ({n},), got {array.shape}")
    return frozen(array) if freeze else np.array(array, dtype=float)  # a base ndarray of its own (a subclass's too)


def real_scalar(value: object, what: str, booleans: bool = False) -> float | bool:
    """`value` as a plain float (or, with `booleans`, a bool as a plain bool): a float, an int
    within ±2**1023, a numpy real, or an instance of a subclass of float or int, converted by its own
    `__float__` (whatever that raises propagates: the control step's fault boundary);
    FilterReturnError naming `what` for anything else (a bool without `booleans`, complex, str, ...)."""
    kind = type(value)
    if kind is float:
        return value
    if kind is bool or kind is np.bool_:
        if booleans:
            return bool(value)
        raise FilterReturnError(f"{what} must be a real number, got a bool")
    if kind is int:
        if not -_INT_MAX < value < _INT_MAX:
            raise FilterReturnError(f"{what} must be a real number a float can hold, got an int of "
                                    f"{len(str(abs(value)))} digits")
        return float(value)
    if kind in _NUMPY_REALS:
        return float(value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)  # a subclass: its own __float__, called here once
    raise FilterReturnError(f"{what} must be a real number, got {kind.__name__}")


class OutputCheck:
    """The one conversion of a filter's return, at the plug-in boundary (module docstring,
    "What a loop accepts"): `check(result)` is a new FilterOutput of plain values only, or raises
    FilterReturnError (or whatever a hostile value's own conversion raises: the control step calls
    it inside its fault boundary).

    - a bare return must be `real_vector`;
    - a FilterOutput: u likewise; action a str; infeasible a bool; rho_pred a `real_scalar`
      (NaN: no prediction; not ±inf); diagnostics a mapping of str keys to real numbers (or bools)
      or arrays of them, at most DIAGNOSTIC_FLOATS_MAX floats in all, whose keys and shapes stay
      those of the first output with diagnostics (the recorder's columns; an output without any,
      e.g. a bare return, is allowed and records NaN), and none of whose keys is in `reserved`
      (the loop's own column names); diagnostic_units a str unit for each of the first output's keys.

    Every value is read once: each attribute of the output, the diagnostics' `items()` once (or a
    `FlatDiagnostics`' values once), each value converted once into a plain float or bool. The
    checked output's diagnostics are a `FlatDiagnostics` of those plain values in the check's own
    `layout` (made from the first output with diagnostics, units included), so whoever reads them
    afterwards (the recorder) reads that copy, never the filter's objects again.

    One instance per run (it remembers the first diagnostics' layout)."""

    def __init__(self, n_segments: int, reserved: frozenset[str] = frozenset()) -> None:
        self.n, self.reserved = n_segments, reserved
        self.layout: DiagnosticLayout | None = None  # the diagnostics' layout, from the first output with them
        self._source_layout: DiagnosticLayout | None = None  # the filter's FlatDiagnostics layout of `layout`

    @property
    def shapes(self) -> dict[str, tuple[int, ...]] | None:
        """The diagnostics' keys and shapes (None before the first output with diagnostics)."""
        return None if self.layout is None else self.layout.shapes

    def __call__(self, result: object) -> FilterOutput:
        if type(result) is not FilterOutput:
            if isinstance(result, FilterOutput):
                raise FilterReturnError(f"a filter must return FilterOutput itself, not a subclass "
                                        f"({type(result).__name__})")
            return FilterOutput(real_vector(result, self.n, "the filter's command"))
        u = real_vector(result.u, self.n, "FilterOutput.u")
        action, infeasible = result.action, result.infeasible
        if type(action) is not str:
            raise FilterReturnError(f"FilterOutput.action must be a str, got {type(action).__name__}")
        if type(infeasible) not in (bool, np.bool_):
            raise FilterReturnError(f"FilterOutput.infeasible must be a bool, got {type(infeasible).__name__}")
        rho = real_scalar(result.rho_pred, "FilterOutput.rho_pred (NaN: no prediction)")
        if math.isinf(rho):
            raise FilterReturnError(f"FilterOutput.rho_pred must be a real number or NaN (no prediction), got {rho!r}")
        values = self._diagnostics(result.diagnostics, result.diagnostic_units)
        if values is None:
            return FilterOutput(u, action, bool(infeasible), rho)
        return FilterOutput(u, action, bool(infeasible), rho, FlatDiagnostics(self.layout, values), self.layout.units)

    def _diagnostics(self, diagnostics: object, units: object) -> list | None:
        """The diagnostics' values, plain and flat in the check's layout (None: none this call)."""
        if type(diagnostics) is dict and not diagnostics:  # the common case of a plain output: none
            return None
        if type(diagnostics) is FlatDiagnostics:
            return self._flat_values(diagnostics)
        if not isinstance(diagnostics, Mapping):
            raise FilterReturnError(f"FilterOutput.diagnostics must be a mapping, got {type(diagnostics).__name__}")
        items = list(diagnostics.items())  # read once
        if not items:  # none this call (as a bare return): the recorder keeps NaN
            return None
        shapes: dict[str, tuple[int, ...]] = {}
        booleans, flat = set(), []
        for key, value in items:
            if type(key) is not str:
                raise FilterReturnError(f"diagnostic keys must be str, got {type(key).__name__}")
            if key in shapes:
                raise FilterReturnError(f"diagnostic {key!r} is given twice")
            if isinstance(value, (np.ndarray, list, tuple)):
                try:
                    array = np.array(value)
                except (ValueError, TypeError, OverflowError):
                    raise FilterReturnError(f"diagnostic {key!r} must be a real number or an array of them") from None
                if array.dtype.kind not in "fiub":
                    raise FilterReturnError(f"diagnostic {key!r} must hold real numbers or bools, got dtype "
                                            f"{array.dtype}")
                if array.dtype.kind == "b":
                    booleans.add(key)
                    flat += array.ravel().tolist()
                else:
                    flat += array.astype(float).ravel().tolist()
                shapes[key] = array.shape
                continue
            try:
                scalar = real_scalar(value, f"diagnostic {key!r}", booleans=True)
            except FilterReturnError:
                raise FilterReturnError(f"diagnostic {key!r} must be a real number or an array of them, got "
                                        f"{type(value).__name__}") from None
            if type(scalar) is bool:
                booleans.add(key)
            shapes[key] = ()
            flat.append(scalar)
        if self.layout is None:
            self._new_layout(shapes, units, frozenset(booleans))
        elif shapes != self.layout.shapes:
            raise FilterReturnError(f"filter diagnostics must keep their keys and shapes over a run: first "
                                    f"{sorted(self.layout.shapes.items())}, now {sorted(shapes.items())}")
        return flat

    def _flat_values(self, diagnostics: FlatDiagnostics) -> list:
        """A FlatDiagnostics' values, copied once and plain (its layout read once per run)."""
        source = diagnostics.layout
        if source is not self._source_layout:
            if type(source) is not DiagnosticLayout:
                raise FilterReturnError(f"FlatDiagnostics.layout must be a DiagnosticLayout, got {type(source).__name__}")
            shapes = {key: tuple(int(d) for d in shape) for key, shape in dict(source.shapes).items()}
            if self.layout is None:
                self._new_layout(shapes, source.units, frozenset(source.booleans) & shapes.keys())
            elif shapes != self.layout.shapes:
                raise FilterReturnError(f"filter diagnostics must keep their keys and shapes over a run: first "
                                        f"{sorted(self.layout.shapes.items())}, now {sorted(shapes.items())}")
            self._source_layout = source
        values = diagnostics.values
        values = values.copy() if type(values) is list else list(values)
        if len(values) != self.layout.size:
            raise FilterReturnError(f"FlatDiagnostics.values must be {self.layout.size} real numbers, got {len(values)}")
        if not set(map(type, values)) <= _PLAIN:
            values = [real_scalar(v, "a FlatDiagnostics value", booleans=True) for v in values]
        return values

    def _new_layout(self, shapes: dict[str, tuple[int, ...]], units: object, booleans: frozenset[str]) -> None:
        """The run's diagnostics layout, from its first output with diagnostics: their keys (none a
        loop column's), shapes (at most DIAGNOSTIC_FLOATS_MAX floats) and units, copied."""
        clash = sorted(set(shapes) & self.reserved)
        if clash:
            raise FilterReturnError(f"filter diagnostics must not reuse the loop's column names, got {clash}")
        size = sum(math.prod(shape) for shape in shapes.values())
        if size > DIAGNOSTIC_FLOATS_MAX:
            raise FilterReturnError(f"filter diagnostics hold {size} floats a call, more than the "
                                    f"{DIAGNOSTIC_FLOATS_MAX} a time-series row may keep")
        if not isinstance(units, Mapping):
            raise FilterReturnError(f"FilterOutput.diagnostic_units must be a mapping, got {type(units).__name__}")
        copied = {}
        for key in shapes:
            unit = units.get(key)
            if type(unit) is not str:
                raise FilterReturnError(f"diagnostic_units must give a str unit for diagnostic {key!r}, got "
                                        f"{type(unit).__name__}")
            copied[key] = unit
        self.layout = DiagnosticLayout(shapes, copied, booleans)


def checked_batch_arrays(result: object, n_states: int, n: int) -> tuple[np.ndarray, list[str], np.ndarray, np.ndarray]:
    """A `filter_batch` return converted once, as `OutputCheck` converts one call's: a BatchOutput
    whose u is (n_states, n) real numbers, action n_states str, infeasible n_states bools and
    rho_pred n_states real numbers (NaN: none; not ±inf), as (u a new (n_states, n) float array,
    the actions as a list of str, infeasible a new (n_states,) bool array, rho_pred a new
    (n_states,) float array). FilterReturnError otherwise."""
    if type(result) is not BatchOutput:
        raise FilterReturnError(f"filter_batch must return a BatchOutput, got {type(result).__name__}")
    u = np.asarray(result.u) if isinstance(result.u, (np.ndarray, list, tuple)) else None
    if u is None or u.dtype.kind not in "fiu" or u.shape != (n_states, n):
        raise FilterReturnError(f"BatchOutput.u must be ({n_states}, {n}) real numbers, got "
                                f"{type(result.u).__name__} {getattr(u, 'dtype', '')} {getattr(u, 'shape', '')}")
    action = result.action
    if type(action) is np.ndarray and action.dtype.kind == "U" and action.shape == (n_states,):
        actions = action.tolist()  # str already, converted in C
    else:
        actions = list(action) if isinstance(action, (np.ndarray, list, tuple)) else []
        if len(actions) != n_states or not all(isinstance(a, str) for a in actions):
            raise FilterReturnError(f"BatchOutput.action must be {n_states} str")
        actions = [str(a) for a in actions]
    infeasible = np.asarray(result.infeasible)
    rho = np.asarray(result.rho_pred)
    if infeasible.dtype != bool or infeasible.shape != (n_states,):
        raise FilterReturnError(f"BatchOutput.infeasible must be {n_states} bools, got {infeasible.dtype} {infeasible.shape}")
    if rho.dtype.kind not in "fiu" or rho.shape != (n_states,) or np.isinf(rho).any():
        raise FilterReturnError(f"BatchOutput.rho_pred must be {n_states} real numbers or NaN")
    return u.astype(float), actions, infeasible.copy(), rho.astype(float)


def batch_history_ids(rows, count: int | None = None, held: int = 0) -> np.ndarray:
    """The histories served by a `filter_batch(..., rows=rows)` call of `count` rows (or by `reset(rows=rows)`,
    count None) of a filter that keeps one history per simulation (the plug-in contract's `rows`): `rows` as
    distinct integer indices ≥ 0, (count,) when count is given, else ValueError; rows None (a call): 0..count − 1,
    refused (ValueError) when the filter holds more than count histories (`held`: which is which would be a guess)."""
    if rows is None:
        if count is None or held > count:
            raise ValueError(f"filter_batch keeps one history per row: it holds {held} and was called with "
                             f"{count} rows without saying which (rows=); reset() starts afresh")
        return np.arange(count, dtype=np.intp)
    ids = np.asarray(rows)
    if ids.ndim != 1 or (count is not None and len(ids) != count) or (len(ids) and ids.dtype.kind not in "iu"):
        raise ValueError(f"rows must be {'' if count is None else f'{count} '}integer indices, got {rows!r}")
    if len(ids) and (ids.min() < 0 or len(np.unique(ids)) != len(ids)):
        raise ValueError(f"rows must be distinct indices >= 0, got {ids.tolist()}")
    return ids.astype(np.intp)


def reset_filter(safety_filter: SafetyFilter) -> None:
    """Call the filter's optional `reset()` (the minimal contract's one optional method)."""
    reset = getattr(safety_filter, "reset", None)
    if callable(reset):
        reset()
