"""The one control step shared by every loop (docs/safety-filter.md): the simulated loop, the camera loop, the batched loop, the environment and the hardware loop.

Each loop owns its clock and its I/O; at each control call it hands `ControlStep` the
controller's view of the state (`controllers.contract.safety_filter.Estimate`: t, t_capture in s,
q (N,) rad, qd (N,) rad/s) and what it observed (`SafetyFlags`), and sends the
`StepRecord.u` it gets back. In this order:

1. the plug-in boundary in: the estimate the nominal and the filter see has `frozen`
   copies of q and q̇ (read-only, and the flag cannot be set back), so nothing they do
   changes what the loop records;
2. nominal: u_nom = nominal(t, q, qd), (N,) hPa, converted once (`real_vector`, then
   `frozen`: the array recorded is the one the filter gets, which it cannot write);
3. filter (skipped while `perception_stale`: there is no estimate to filter):
   output = OutputCheck(filter(estimate, u_nom)), the call timed (`filter_us`, µs);
4. admission: a u_filter that is not finite is refused (the monitor's `command_nonfinite`
   flag: HOLD the last command, then VENT); a finite one is clipped to the pressure
   limits of the `FilterContext` (`context.limits`, tuples the filter cannot change; no
   clipping when they are None); a nominal controller or filter that raises
   `ControllerInputError` (a non-finite estimate or u_nom, a stale or backwards time) is
   refused the same way;
5. safety monitor (`closedloop.monitor.SafetyMonitor`): RUN (the admitted command, which
   the monitor is told is admitted: it keeps it without checking or copying it again), HOLD
   or VENT;
6. the record: what the filter returned (`output`, None when it was not called or
   raised), what was sent (`u`), the monitor's action and reasons, the filter's time.

Filter faults (docs/safety-filter.md#the-plug-in-boundary-is-a-trust-boundary). Anything
else the nominal, the filter or its `reset()` raises, `BaseException`s included (SystemExit,
GeneratorExit, a KeyboardInterrupt the code raises itself), anything the conversion of its
return raises (a hostile value's own `__float__`, a mapping's `items()`: every conversion
happens here, inside the boundary), and any return the contract refuses
(`FilterReturnError`), is a filter fault:
the step keeps the first one (`fault`, a `FilterFault` with its traceback), calls no user
code again, and raises the monitor's `filter_fault` flag on every later call: HOLD the last
admitted command for the monitor's hold, then VENT (at once if nothing was admitted yet).
`stopped` is True from that vent on: every loop ends its run there, keeping every row
recorded so far. A non-finite command is not a fault: it is refused and the step goes on
(HOLD, back to RUN if the filter recovers within the hold, else VENT).

Guarantees, whatever the filter does: u is finite; on RUN and HOLD it is a command the
step admitted, so within the limits when they are on; VENT sends 0 hPa (the valves' vent).
A real Ctrl-C is not a fault: its KeyboardInterrupt propagates to the loop
(`controllers.core.interrupts.is_interrupt`; the step calls `watch()` when it is built).

The batch axis: one step for one run and for B. `BatchControlStep` is this step for B runs at
once (a batched study's simulations, the vector environment's arms): state (B, N) arrays in,
`BatchStepRecord` of (B, ...) arrays out; `ControlStep` is its B = 1 case (`rows`, a
`BatchControlStep` of one row, whose helpers it calls: an `Estimate` in, a `StepRecord` out, no
(1, ...) record built). Written once for both:
- the user code, row by row (`nominal_row`, `filter_row`: the views, the call, the output check,
  the fault), or once for many rows (a shared nominal's `nominal_batch`, a shared filter's
  `filter_batch`: an exception or refused return is the fault of each row it was called for; a
  `ControllerInputError` from the call asks it again for each row alone, so that only the rows it
  refuses are refused, as in their runs);
  which of these a shared filter can do it declares (`controllers.contract.capabilities.filter_capabilities`,
  read once when the step is built, which refuses a filter that lacks what it declares): batched,
  its `filter_batch` is called; rows, it keeps a history per row and `filter_batch` is told the
  indices of the rows it is called for (`rows`, (k,) int, ascending); reset_rows, its `reset` is
  told the indices of the rows that restart when only some do (the vector environment's
  autoreset), so that row b's history is run b's wherever other rows skip a call or restart; a
  shared filter without reset_rows is reset only when every row restarts (a `reset()` would
  restart the rows that go on). A filter that declares nothing is called row by row, whatever
  methods it has; a nominal likewise declares batched (`nominal_capabilities`, read and checked
  when the step is built) or is called row by row;
- the admission and the monitor's RUN case, one compiled call over the batch axis
  (`closedloop.kernels.admit_and_run`: non-finite rows refused, the clip min(max(u, lo), hi) as
  Python's min and max, RUN for the admitted rows with nothing raised or latched), and every other
  row through `closedloop.monitor.decide`, the state machine's one definition.
One row's fault stops that row only. Cost per call, pass-through filter (`tools/bench_serial_loop.py`'s
`control_step_us`, docs/studies.md#batches): `ControlStep` 0.2–0.9 µs (3–10 %) more than the
hand-written scalar step it replaced (the compiled call's argument handling; numpy on (1, N)
arrays would cost 0.5–1 µs an operation). `BatchControlStep` at B = 1: 21.0–21.7 µs a call against
`ControlStep`'s 12.0–12.8 (load 14–19; 42.3–44.8 before its call took the all-rows case without a numpy
operation per row set and copied its fresh arrays from templates). What B = 1 still pays beyond
`ControlStep` is the (B, ...) record itself: five fresh arrays, the nominal matrix's `frozen` copy,
and a numpy write per row and field.
The `frozen` copies handed to user code cost about 8 % of the step (`control_step_us`
with `--against` the tree before them, on a loaded 2-core machine: 11.7 against 10.9 µs CPU a call;
the mujoco_contact loop 0.987×, its commands bit-identical).
"""

from __future__ import annotations

import inspect
import math
import sysconfig
import time
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from closedloop.columns import TIMESERIES_UNITS
from closedloop.monitor import (ACTION_CODES, ACTIONS, DEFAULT_HOLD_S, NO_FLAGS, BatchSafetyMonitor,
                                SafeAction, SafetyFlags, SafetyMonitor)
from controllers.core.errors import ControllerInputError
from controllers.core.interrupts import is_interrupt, watch
from controllers.core.lazy_import import lazy_module
from controllers.contract.capabilities import filter_capabilities, nominal_capabilities
from controllers.contract.safety_filter import (Estimate, EstimateBatch, FilterContext, FilterOutput, FilterReturnError,
                                       OutputCheck, SafetyFilter, checked_batch_arrays, frozen, real_vector,
                                       reset_filter)

if TYPE_CHECKING:  # annotations only: the compiled model (numba) loads where a run starts, not for softcbf list
    from controllers.nominal import NominalController

STEP_COLUMNS = frozenset({"u_nom", "u_filter", "u", "rho_pred", "infeasible", "filter_us", "action"})
RESERVED_COLUMNS = frozenset(TIMESERIES_UNITS) | STEP_COLUMNS  # names a filter's diagnostics may not take
kernels = lazy_module("closedloop.kernels")  # numba loads on the first step (controllers.core.lazy_import)
_LIBRARY_DIRS = tuple({sysconfig.get_paths()[key] for key in ("stdlib", "platstdlib", "purelib", "platlib")})


@dataclass(frozen=True)
class FilterFault:
    """The first filter fault of a run (module docstring).

    type: the exception's class name; message: its text (first line); where: "nominal",
    "filter", "filter return" (a return the contract refuses), "filter_batch" or "reset";
    location: "file:line" of the user code that raised (the deepest frame outside Python's
    and the installed packages' own files), or of the filter's class for a refused
    return; t: the control time (s) of the call; traceback: the full traceback text."""

    type: str
    message: str
    where: str
    location: str
    t: float
    traceback: str

    @classmethod
    def from_exception(cls, exc: BaseException, where: str, t: float, culprit: object = None) -> "FilterFault":
        """The fault of `exc`, raised (or, a FilterReturnError, refused) at control time t (s) in
        `where`; `culprit`: the filter whose return was refused. Reads nothing of `exc` that could
        raise again (an exception whose `__str__` raises gets a placeholder message)."""
        try:
            text = str(exc).strip().splitlines()
        except BaseException:  # noqa: BLE001 - user code's own __str__; the fault is recorded all the same
            text = [f"<{type(exc).__name__} whose message cannot be read>"]
        location = _source_location(culprit) if isinstance(exc, FilterReturnError) else _raise_location(exc)
        return cls(type(exc).__name__, text[0] if text else "", where, location, float(t),
                   "".join(traceback.format_exception(exc)))

    def row_fields(self) -> dict[str, Any]:
        """What a summary row of a run that ended on this fault gains: `fault` (`to_json`) and its
        scalars fault_type, fault_where, fault_message (the columns a study's table keeps)."""
        return {"fault": self.to_json(), "fault_type": self.type, "fault_where": self.where,
                "fault_message": self.message}

    def to_json(self) -> dict[str, Any]:
        """summary.json's `fault` (docs/run-outputs.md): type, message, where, location, t_s."""
        return {"type": self.type, "message": self.message, "where": self.where, "location": self.location,
                "t_s": self.t if math.isfinite(self.t) else None}

    def line(self) -> str:
        """One line for the command line: what failed, where and when (`describe_fault`)."""
        return describe_fault(self.to_json())


def describe_fault(fault: dict[str, Any]) -> str:
    """One line for a fault as summary.json records it (`FilterFault.to_json`)."""
    place = f" at {fault['location']}" if fault.get("location") else ""
    when = f" (t = {fault['t_s']:.4g} s)" if fault.get("t_s") is not None else ""
    return f"filter fault in the {fault['where']}{place}{when}: {fault['type']}: {fault['message']}"


def _raise_location(exc: BaseException) -> str:
    frames = traceback.extract_tb(exc.__traceback__)
    for frame in reversed(frames):
        if not frame.filename.startswith(_LIBRARY_DIRS):
            return f"{frame.filename}:{frame.lineno}"
    return f"{frames[-1].filename}:{frames[-1].lineno}" if frames else ""


def _source_location(culprit: object) -> str:
    try:
        target = culprit if inspect.isfunction(culprit) or inspect.isclass(culprit) else type(culprit)
        return f"{inspect.getsourcefile(target)}:{inspect.getsourcelines(target)[1]}"
    except (TypeError, OSError):
        return ""


@dataclass(eq=False, slots=True)
class StepRecord:
    """One control call: the estimate, u_nom (N,) hPa (NaN if the nominal raised), the
    filter's output (None: not called or raised), the command sent u (N,) hPa, the
    monitor's action and raised flags, and the filter's time filter_us (µs; NaN: not called).
    Not frozen (it is made every control call); nothing modifies it."""

    estimate: Estimate
    u_nom: np.ndarray
    output: FilterOutput | None
    u: np.ndarray
    action: SafeAction
    reasons: tuple[str, ...]
    filter_us: float


class ControlStep:
    """estimate → nominal → filter → admission → monitor → command (module docstring) for one run:
    the B = 1 case of `BatchControlStep` (`rows`, its one row).

    `context` gives the pressure limits the command is clipped to (`context.limits`) and the
    number of segments; `monitor` defaults to a `SafetyMonitor` with its default hold (its
    `rows` are the step's monitor); `clock` (s) times the filter call. `fault` is the run's
    first filter fault (None: none); `filter` the filter (it may be replaced between runs).
    """

    def __init__(self, safety_filter: SafetyFilter, nominal: NominalController, context: FilterContext,
                 monitor: SafetyMonitor | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        self.context, self.n, self.clock = context, context.robot.n_segments, clock
        self.monitor = SafetyMonitor(self.n) if monitor is None else monitor
        if self.monitor.n_segments != self.n:
            raise ValueError(f"monitor has {self.monitor.n_segments} segments, the robot {self.n}")
        self.rows = BatchControlStep([safety_filter], [nominal], context, 1, self.monitor.hold_s, clock,
                                     monitor=self.monitor.rows)
        # work arrays of a call (B = 1): u_filter without an output (refused), t, the admission, the action
        self.no_output = np.full((1, self.n), math.nan)
        self.t, self.admitted, self.action = np.empty(1), np.empty(1, dtype=bool), np.empty(1, dtype=np.int8)

    @property
    def filter(self) -> SafetyFilter:
        return self.rows.filters[0]

    @filter.setter
    def filter(self, safety_filter: SafetyFilter) -> None:
        self.rows.filters[0] = safety_filter

    @property
    def nominal(self) -> NominalController:
        return self.rows.nominals[0]

    @property
    def fault(self) -> FilterFault | None:
        """The run's first filter fault (None: none)."""
        return self.rows.faults[0]

    @property
    def stopped(self) -> bool:
        """A filter fault has led to the monitor's vent: the loop ends its run (module docstring)."""
        return self.rows.faults[0] is not None and self.monitor.vent_latched  # `BatchControlStep.stopped` of its row

    def reset(self) -> None:
        """Before a run: no fault, a fresh output check, the filter's own `reset()` (when it has one;
        if it raises, that is the run's filter fault) and the monitor's `restart()` (its clock,
        hold and latched vent start again)."""
        self.rows.reset()

    def __call__(self, estimate: Estimate, flags: SafetyFlags = NO_FLAGS) -> StepRecord:
        """The step at `estimate` with `flags`: `BatchControlStep.__call__` for its one row, through the
        same row helpers, admission and monitor, with the row's own objects in and out (the estimate,
        its FilterOutput) instead of (1, ...) arrays."""
        rows = self.rows
        output, u_nom, filter_us = None, rows.nan_row, math.nan
        faults = rows.faults
        if faults[0] is None:
            q, qd = rows.views(estimate.q, estimate.qd)
            value = rows.nominal_row(0, estimate.t, q, qd)
            if value is not None:
                u_nom = value
                if not flags.perception_stale:
                    output, filter_us = rows.filter_row(0, Estimate(estimate.t, q, qd, estimate.t_capture), value)
            if faults[0] is not None:  # a fault's row has no output
                output = None
        t = self.t
        t[0] = estimate.t
        sent, action = np.empty((1, self.n)), self.action  # sent: the record's u; action read only here
        reasons = rows.decide(t, self.no_output if output is None else output.u.reshape(1, self.n), rows.all_rows,
                              None if flags is NO_FLAGS else [flags], sent, self.admitted, action)
        if reasons is None:  # the one row RUNs
            return StepRecord(estimate, u_nom, output, sent[0], SafeAction.RUN, (), filter_us)
        return StepRecord(estimate, u_nom, output, sent[0], ACTIONS[action[0]], reasons[0], filter_us)

    def wait(self, estimate: Estimate) -> StepRecord:
        """A call before the loop has its first estimate (camera start-up): the filter and the
        monitor are not called; the valves vent (u = 0 hPa) without latching. The nominal is
        evaluated for the record (NaN when it raises or returns what the contract refuses)."""
        u_nom = self.rows.nan_row
        if self.fault is None:
            try:
                u_nom = self.rows.nominal_value(0, estimate.t, *self.rows.views(estimate.q, estimate.qd))
            except BaseException as exc:  # noqa: BLE001 - recorded as NaN; the fault surfaces at the first real call
                if is_interrupt(exc):
                    raise
                u_nom = self.rows.nan_row
        return StepRecord(estimate, u_nom, None, np.zeros(self.n), SafeAction.VENT, ("perception_stale",), math.nan)


@dataclass(eq=False, slots=True)
class BatchStepRecord:
    """One control call of B runs (`BatchControlStep`), by row: t (B,) s; u_nom (B, N) hPa (NaN
    where the nominal raised, refused its input or the run has a fault); u (B, N) hPa, the command
    sent (0 on rows not stepped); action (B,) int8 (`ACTION_CODES`, `NOT_STEPPED`) with reasons (B
    tuples of raised flags); output (B,) bool, the filter returned an output the step accepted (its
    u_filter (B, N) hPa, rho_pred (B,) 1, infeasible (B,) bool, filter_action (B str); NaN, NaN,
    False, None elsewhere); filter_us (B,) µs (NaN: not called); outputs, each row's FilterOutput
    when the filter is called row by row (None rows elsewhere: `row` makes one from the arrays).
    Not frozen (made every control call); nothing modifies it."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    t_capture: np.ndarray
    u_nom: np.ndarray
    output: np.ndarray
    u_filter: np.ndarray
    rho_pred: np.ndarray
    infeasible: np.ndarray
    filter_action: list[str | None]
    outputs: list[FilterOutput | None]
    u: np.ndarray
    action: np.ndarray
    reasons: list[tuple[str, ...]]
    filter_us: np.ndarray

    def row(self, b: int) -> StepRecord:
        """Row b as the `StepRecord` of b's own `ControlStep` (the same values)."""
        output = self.outputs[b]
        if output is None and self.output[b]:
            output = FilterOutput(self.u_filter[b], self.filter_action[b], bool(self.infeasible[b]),
                                  float(self.rho_pred[b]))
        estimate = Estimate(float(self.t[b]), self.q[b], self.qd[b], float(self.t_capture[b]))
        return StepRecord(estimate, self.u_nom[b], output, self.u[b], ACTIONS[self.action[b]], self.reasons[b],
                          float(self.filter_us[b]))


class BatchControlStep:
    """B control steps at once, row b the control step of run b (module docstring); `ControlStep` is B = 1.

    safety_filter: one filter for all rows, or B, one per row; nominal: likewise (None: the loop
    hands every call its nominal commands, `u_nom`, e.g. the environment's actions). A shared filter
    that declares batched (`controllers.contract.capabilities.filter_capabilities`, checked here for every
    filter) has its `filter_batch` called once per control call for all the rows whose step calls it;
    any other filter is called row by row (one shared filter that does not declare batched must then
    be stateless). Each row has its views
    (read-only copies), its output check, its first fault (after which its user code is not
    called again; an exception or refused return of `filter_batch` is a fault of every row it
    was called for) and its monitor row (`BatchSafetyMonitor`, `hold_s`; or `monitor`, given).
    Written once for every B: the user code row by row (`nominal_row`, `filter_row`) or batched,
    the admission and the monitor's RUN case in one compiled call each over the batch axis
    (`closedloop.kernels`), the rows that hold or vent through `closedloop.monitor.decide`.
    `__call__` takes and returns arrays with the batch axis; `ControlStep` calls the same helpers
    for its one row with an `Estimate` in and a `StepRecord` out, without a (1, ...) record.
    """

    def __init__(self, safety_filter: SafetyFilter | Sequence[SafetyFilter],
                 nominal: NominalController | Sequence[NominalController] | None, context: FilterContext,
                 n_sims: int, hold_s: float = DEFAULT_HOLD_S, clock: Callable[[], float] = time.perf_counter,
                 monitor: BatchSafetyMonitor | None = None) -> None:
        self.n_sims, self.n, self.context, self.clock = n_sims, context.robot.n_segments, context, clock
        self.per_row_filters = isinstance(safety_filter, Sequence)
        self.filters = list(safety_filter) if self.per_row_filters else [safety_filter] * n_sims
        self.nominals = list(nominal) if isinstance(nominal, Sequence) else [nominal] * n_sims
        if len(self.filters) != n_sims or len(self.nominals) != n_sims:
            raise ValueError(f"safety_filter and nominal must be one or n_sims = {n_sims} each, got "
                             f"{len(self.filters)} and {len(self.nominals)}")
        self.filter = None if self.per_row_filters else safety_filter
        # what each nominal declares, checked now as the filters' below; a shared one that declares batched has its
        # nominal_batch called once for all rows, any other nominal is called per row
        distinct_nominals = {id(nom): nom for nom in self.nominals if nom is not None}.values()
        nominals = [nominal_capabilities(nom) for nom in distinct_nominals]
        self.nominal_batched = not isinstance(nominal, Sequence) and nominal is not None and nominals[0].batched
        self.nominal_missing = any(nom is None for nom in self.nominals)
        # what each filter declares, checked now (a declared capability it lacks is refused here, not mid-run);
        # only a shared filter's are used (module docstring): per-row filters are called row by row
        distinct = {id(f): f for f in self.filters}.values()
        declared = [filter_capabilities(f) for f in distinct]
        shared = None if self.per_row_filters else declared[0]
        self.batched = shared is not None and shared.batched
        self.batch_rows = self.batched and shared.rows  # told which rows it serves
        self.reset_rows = shared is not None and shared.reset_rows
        self.monitor = BatchSafetyMonitor(n_sims, self.n, hold_s) if monitor is None else monitor
        if (self.monitor.n_sims, self.monitor.n_segments) != (n_sims, self.n):
            raise ValueError(f"monitor has {self.monitor.n_sims} runs of {self.monitor.n_segments} segments, "
                             f"the step {n_sims} of {self.n}")
        limits = context.limits
        # (2, N) hPa: lo, hi; without limits ±inf, with which the clip keeps every float (closedloop.kernels)
        self.limits = np.array([[-math.inf] * self.n, [math.inf] * self.n] if limits is None else [limits[0], limits[1]],
                               dtype=float)
        watch()  # a filter's own KeyboardInterrupt is a fault, a real Ctrl-C an interrupt (controllers.core.interrupts)
        self.faults: list[FilterFault | None] = [None] * n_sims
        self.faulted = np.zeros(n_sims, dtype=bool)
        self.checks = [OutputCheck(self.n, RESERVED_COLUMNS) for _ in range(n_sims)]
        self.all_rows = np.ones(n_sims, dtype=bool)
        self.all_ids = list(range(n_sims))
        self.nan_row = frozen(np.full(self.n, math.nan))  # u_nom of a row whose nominal was not called or refused
        # a call's fresh arrays are copies of these (a copy costs a third of np.full or np.zeros), and its work array
        self.nan_rows, self.nan_column = np.full((n_sims, self.n), math.nan), np.full(n_sims, math.nan)
        self.false_column, self.admitted = np.zeros(n_sims, dtype=bool), np.empty(n_sims, dtype=bool)

    @property
    def stopped(self) -> np.ndarray:
        """(B,) bool: the row's fault has led to its monitor's vent (`ControlStep.stopped`)."""
        return self.faulted & self.monitor.latched

    def reset(self, rows: np.ndarray | None = None) -> None:
        """Before a run of the rows in `rows` ((B,) bool; None: all): no fault, a fresh output check,
        the monitor's restart and the filters' resets: each restarting row's own
        filter's `reset()`; a shared filter's `reset()` once when every row restarts (its fault then
        every row's), `reset(rows=ids)` with the restarting rows' indices when only some do and it
        declares reset_rows, and nothing when only some do and it does not: its state spans the rows
        that go on, which a `reset()` would restart in the middle of their runs (a row's run is its
        own, whatever the other rows do; a filter that keeps a history per row declares reset_rows)."""
        rows = self.all_rows if rows is None else rows
        ids = np.flatnonzero(rows).tolist()
        self.monitor.restart(rows)
        self.faulted[rows] = False
        for b in ids:
            self.faults[b] = None
            self.checks[b] = OutputCheck(self.n, RESERVED_COLUMNS)
        some = not self.per_row_filters and len(ids) < self.n_sims
        if some and not self.reset_rows:
            return
        for b in ids if self.per_row_filters else ids[:1]:
            try:
                if some:
                    self.filter.reset(rows=frozen(ids, np.intp))
                else:
                    reset_filter(self.filters[b])
            except BaseException as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
                if is_interrupt(exc):
                    raise
                fault = FilterFault.from_exception(exc, "reset", math.nan)
                for row in ([b] if self.per_row_filters else ids):
                    self._fault(row, fault)

    def _fault(self, b: int, fault: FilterFault) -> None:
        if self.faults[b] is None:
            self.faults[b] = fault
            self.faulted[b] = True

    @staticmethod
    def views(q: np.ndarray, qd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """What user code sees of q and q̇ (any shape): `frozen` copies (the loop keeps its own)."""
        return frozen(q), frozen(qd)

    def nominal_value(self, b: int, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Row b's nominal at (t s, q rad, q̇ rad/s: frozen views) as a new `frozen` float array
        (N,) hPa; what it raises propagates (FilterReturnError: not N real numbers)."""
        return real_vector(self.nominals[b](t, q, qd), self.n, "the nominal command", freeze=True)

    def nominal_row(self, b: int, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray | None:
        """`nominal_value`, or None when the nominal refused its input (ControllerInputError) or
        faulted (anything else it or its return's conversion raised but a real Ctrl-C: row b's fault)."""
        try:
            return self.nominal_value(b, t, q, qd)
        except ControllerInputError:
            return None
        except BaseException as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
            if is_interrupt(exc):
                raise
            self._fault(b, FilterFault.from_exception(exc, "nominal", t))
            return None

    def filter_row(self, b: int, view: Estimate, u_nom: np.ndarray) -> tuple[FilterOutput | None, float]:
        """Row b's filter on its view and u_nom, timed: (its output through row b's output check,
        None when it refused its input, raised or returned what the contract refuses (the last two
        row b's fault: anything the call or its return's conversion raises but a real Ctrl-C); the
        call's µs, NaN when it raised)."""
        safety_filter = self.filters[b]
        try:
            start = self.clock()
            result = safety_filter(view, u_nom)
            filter_us = (self.clock() - start) * 1e6
        except ControllerInputError:
            return None, math.nan
        except BaseException as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
            if is_interrupt(exc):
                raise
            self._fault(b, FilterFault.from_exception(exc, "filter", view.t))
            return None, math.nan
        try:
            return self.checks[b](result), filter_us
        except BaseException as exc:  # noqa: BLE001 - a refused return, or its conversion raised: a fault
            if is_interrupt(exc):
                raise
            self._fault(b, FilterFault.from_exception(exc, "filter return", view.t, safety_filter))
            return None, filter_us

    def decide(self, t: np.ndarray, u_filter: np.ndarray, rows: np.ndarray, flags: list[SafetyFlags] | None,
               sent: np.ndarray, admitted: np.ndarray, action: np.ndarray) -> list[tuple[str, ...]] | None:
        """Admission and monitor of the rows in `rows` at t (B,) s: u_filter (B, N) hPa what the filters
        returned (NaN in a row without an output: refused), admitted (`admitted` (B,), a work array)
        and decided in one compiled call (`kernels.admit_and_run`), the rows that hold or vent by the
        monitor (`BatchSafetyMonitor.settle`). Writes the command sent (B, N) hPa and the action codes
        (B,) into `sent` and `action`; returns each row's reasons, None when every stepped row RUNs."""
        monitor = self.monitor
        pending = kernels.admit_and_run(u_filter, self.limits, t, self.faulted, rows,
                                        monitor.quiet if flags is None else monitor.quiet_rows(flags), monitor.state,
                                        monitor.bits, sent, admitted, action)
        if pending:  # a bad time, or rows that hold or vent
            return monitor.settle(pending, t, sent, admitted, self.faulted, flags, sent, action).reasons
        return None

    def __call__(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray, t_capture: np.ndarray | None = None,
                 rows: np.ndarray | None = None, u_nom: np.ndarray | None = None,
                 flags: list[SafetyFlags] | None = None) -> BatchStepRecord:
        """One control call of the rows in `rows` ((B,) bool; None: all) at their estimates: t,
        t_capture (B,) s (t_capture None: = t), q (B, N) rad, qd (B, N) rad/s (the loop's own
        arrays: the step copies what user code sees); `u_nom` (B, N) hPa: the nominal commands
        when the loop has them (the environment's held actions; the nominal is then not called),
        None: each row's nominal is called; `flags`: each row's flags (None: none raised)."""
        n_sims, faults = self.n_sims, self.faults
        t = np.asarray(t, dtype=float)
        t_capture = t if t_capture is None else np.asarray(t_capture, dtype=float)
        # every row stepped and none faulted (the common case): the row sets below are all rows,
        # without a numpy operation for each
        every = rows is None and faults.count(None) == n_sims
        rows = self.all_rows if rows is None else rows
        live = rows if every else rows & ~self.faulted
        live_ids = self.all_ids if every else np.flatnonzero(live).tolist()
        ts = t.tolist()
        tcs = ts if t_capture is t else t_capture.tolist()
        q_view, qd_view = self.views(q, qd)
        nominal_ok, refused = live, False  # nominal_ok: copied before a row of it is refused
        if u_nom is None:
            if self.nominal_missing:
                raise ValueError("u_nom must be given: this step was made without a nominal controller")
            nominal = self.nan_rows.copy()  # NaN on every row the nominal is not called for or refuses
            if self.nominal_batched:
                if live_ids:
                    nominal_ok = live.copy()
                    self._call_nominal_batch(live, ts, t, q_view, qd_view, nominal, nominal_ok)
            else:
                for b in live_ids:
                    value = self.nominal_row(b, ts[b], q_view[b], qd_view[b])
                    if value is None:
                        if not refused:
                            nominal_ok, refused = live.copy(), True
                        nominal_ok[b] = False
                    else:
                        nominal[b] = value
        else:
            nominal = np.array(u_nom, dtype=float)
            if not every:
                nominal[~live] = math.nan
        nominal = frozen(nominal)  # recorded; user code sees its rows, which it cannot make writable
        called = nominal_ok if flags is None else nominal_ok & ~np.array([f.perception_stale for f in flags])
        output = self.false_column.copy()
        u_filter = self.nan_rows.copy()
        rho_pred = self.nan_column.copy()
        infeasible = self.false_column.copy()
        filter_action: list[str | None] = [None] * n_sims
        outputs: list[FilterOutput | None] = [None] * n_sims
        filter_us = self.nan_column.copy()
        ids = live_ids if called is live else np.flatnonzero(called).tolist()
        if ids and self.batched:
            self._call_batch(ids, called, ts, t, t_capture, q_view, qd_view, nominal, output, u_filter, rho_pred, infeasible,
                             filter_action, filter_us)
        else:
            for b in ids:
                checked, filter_us[b] = self.filter_row(b, Estimate(ts[b], q_view[b], qd_view[b], tcs[b]), nominal[b])
                if checked is not None:
                    output[b], outputs[b], filter_action[b] = True, checked, checked.action
                    u_filter[b], rho_pred[b], infeasible[b] = checked.u, checked.rho_pred, checked.infeasible
        faulted = self.faulted
        if faults.count(None) < n_sims:  # a fault's row has no output
            output &= ~faulted
            u_filter[faulted], rho_pred[faulted], infeasible[faulted] = math.nan, math.nan, False
            for b in np.flatnonzero(faulted).tolist():
                filter_action[b] = outputs[b] = None
        sent, action = self.monitor.outputs()
        reasons = self.decide(t, u_filter, rows, flags, sent, self.admitted, action)
        return BatchStepRecord(t, q_view, qd_view, t_capture, nominal, output, u_filter, rho_pred, infeasible,
                               filter_action, outputs, sent, action, [()] * n_sims if reasons is None else reasons,
                               filter_us)

    def _call_nominal_batch(self, live: np.ndarray, ts: list[float], t: np.ndarray, q: np.ndarray, qd: np.ndarray,
                            nominal: np.ndarray, nominal_ok: np.ndarray) -> None:
        """The shared nominal's `nominal_batch` on the `live` rows, once (it declares batched,
        `controllers.contract.capabilities.nominal_capabilities`): an
        exception or a return that is not (rows, N) real numbers is a fault of each of those rows."""
        rows = int(np.count_nonzero(live))
        try:
            result = self.nominals[0].nominal_batch(frozen(t[live]), frozen(q[live]), frozen(qd[live]))
            values = np.asarray(result) if isinstance(result, (np.ndarray, list, tuple)) else None
            if values is None or values.dtype.kind not in "fiu" or values.shape != (rows, self.n):
                raise FilterReturnError(f"nominal_batch must return ({rows}, {self.n}) real numbers, got "
                                        f"{type(result).__name__} {getattr(values, 'dtype', '')} "
                                        f"{getattr(values, 'shape', '')}")
        except ControllerInputError:
            nominal_ok[live] = False
            return
        except BaseException as exc:  # noqa: BLE001 - a filter fault of every row it was called for
            if is_interrupt(exc):
                raise
            for b in np.flatnonzero(live).tolist():
                self._fault(b, FilterFault.from_exception(exc, "nominal", ts[b]))
            nominal_ok[live] = False
            return
        nominal[live] = values

    def _call_batch(self, ids: list[int], called: np.ndarray, ts: list[float], t: np.ndarray, t_capture: np.ndarray,
                    q: np.ndarray,
                    qd: np.ndarray, nominal: np.ndarray, output: np.ndarray, u_filter: np.ndarray,
                    rho_pred: np.ndarray, infeasible: np.ndarray, filter_action: list[str | None],
                    filter_us: np.ndarray) -> None:
        """The shared filter's `filter_batch` on the rows `ids`, once; its outputs into the row arrays."""
        batch = EstimateBatch(frozen(t[called]), frozen(q[called]), frozen(qd[called]), frozen(t_capture[called]))
        where = "filter_batch"
        try:
            start = self.clock()
            if self.batch_rows:
                result = self.filter.filter_batch(batch, frozen(nominal[called]), rows=frozen(ids, np.intp))
            else:
                result = self.filter.filter_batch(batch, frozen(nominal[called]))
            per_row_us = (self.clock() - start) * 1e6 / len(ids)
            where = "filter return"
            u, actions, infeasible_rows, rho = checked_batch_arrays(result, len(ids), self.n)
        except BaseException as exc:  # noqa: BLE001 - a filter fault of every row it was called for
            if is_interrupt(exc):
                raise
            if isinstance(exc, ControllerInputError) and where == "filter_batch":  # it refuses its input
                if len(ids) > 1:  # which rows it refuses: each alone (module docstring)
                    for b in ids:
                        alone = np.zeros_like(called)
                        alone[b] = True
                        self._call_batch([b], alone, ts, t, t_capture, q, qd, nominal, output, u_filter, rho_pred,
                                         infeasible, filter_action, filter_us)
                return
            for b in ids:
                self._fault(b, FilterFault.from_exception(exc, where, ts[b], self.filter))
            return
        output[called], u_filter[called], rho_pred[called], infeasible[called] = True, u, rho, infeasible_rows
        filter_us[called] = per_row_us
        if len(ids) == self.n_sims:
            filter_action[:] = actions
        else:
            for b, action in zip(ids, actions):
                filter_action[b] = action


def fault_log_name(label: str) -> str:
    """The file of a run folder that keeps the traceback of run `label`'s filter fault."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label)
    return f"fault_{safe}.log"


def write_fault_log(folder: Path, label: str, fault: FilterFault) -> Path:
    """Write `fault`'s one line and traceback to `folder`/`fault_log_name(label)`; return the path."""
    path = Path(folder) / fault_log_name(label)
    path.write_text(f"{fault.line()}\n\n{fault.traceback}", encoding="utf-8")
    return path

