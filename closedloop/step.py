"""The one control step shared by every loop (docs/safety-filter.md): the simulated loop, the camera loop, the batched loop, the environment and the hardware loop.

Each loop owns its clock and its I/O; at each control call it hands `ControlStep` the
controller's view of the state (`controllers.safety_filter.Estimate`: t, t_capture in s,
q (N,) rad, qd (N,) rad/s) and what it observed (`SafetyFlags`), and sends the
`StepRecord.u` it gets back. In this order:

1. the plug-in boundary in: the estimate the nominal and the filter see has read-only
   copies of q and q̇, so nothing they do changes what the loop records;
2. nominal: u_nom = nominal(t, q, qd), (N,) hPa, converted once (`real_vector`: a new
   read-only float array);
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

Filter faults (docs/safety-filter.md#the-plug-in-boundary-is-a-trust-boundary). Any other
exception from the nominal, the filter or its `reset()`, and any return the contract
refuses (`FilterReturnError`), is a filter fault:
the step keeps the first one (`fault`, a `FilterFault` with its traceback), calls no user
code again, and raises the monitor's `filter_fault` flag on every later call: HOLD the last
admitted command for the monitor's hold, then VENT (at once if nothing was admitted yet).
`stopped` is True from that vent on: every loop ends its run there, keeping every row
recorded so far. A non-finite command is not a fault: it is refused and the step goes on
(HOLD, back to RUN if the filter recovers within the hold, else VENT).

Guarantees, whatever the filter does: u is finite; on RUN and HOLD it is a command the
step admitted, so within the limits when they are on; VENT sends 0 hPa (the valves' vent).
Interrupts (KeyboardInterrupt) are not faults: they propagate to the loop.

The batch axis. `BatchControlStep` is this step for B runs at once (a batched study's
simulations, the vector environment's arms): state (B, N) arrays in, `BatchStepRecord` of
(B, ...) arrays out, row b exactly what `ControlStep` gives run b. What costs Python per
row in `ControlStep` is done once for all rows: the views (one read-only copy of all
states), the nominal (its `nominal_batch` when a shared nominal has one), the filter (its
`filter_batch` when a shared filter has one: one call; else each row's filter in turn, user
code being per sample), the output check (`checked_batch_arrays`), the admission (non-finite
rows refused, the clip `minimum(maximum(u, lo), hi)`, the same floats as the scalar clip)
and the monitor (`BatchSafetyMonitor`: the common RUN case in numpy, any other row through
`closedloop.monitor.decide`, the state machine's one definition). One row's fault stops that
row only; an exception from a call made for many rows (`filter_batch`, `nominal_batch`) is
the fault of each of them. `ControlStep` stays the serial loops' entry (the simulated,
camera and hardware loops, the single environment): at B = 1 the batched step costs more
numpy overhead than the whole scalar step (66 µs against 9 µs a call with a pass-through
filter: `tools/bench_batch.py`'s `step_us`, docs/studies.md#batches), and the serial loops must not
get slower; the two are held to the same decisions by tests (tests/test_monitor.py,
tests/test_trust_boundary.py, tests/test_batch_loop.py: bit-identical commands, rows and
faults).
"""

from __future__ import annotations

import inspect
import math
import sysconfig
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from closedloop.columns import TIMESERIES_UNITS
from closedloop.monitor import (ACTION_CODES, ACTIONS, DEFAULT_HOLD_S, NO_FLAGS, NOT_STEPPED, BatchSafetyMonitor,
                                SafeAction, SafetyFlags, SafetyMonitor)
from controllers.errors import ControllerInputError
from controllers.safety_filter import (Estimate, EstimateBatch, FilterContext, FilterOutput, FilterReturnError,
                                       OutputCheck, SafetyFilter, checked_batch_arrays, read_only, real_vector,
                                       reset_filter)

if TYPE_CHECKING:  # annotations only: the compiled model (numba) loads where a run starts, not for softcbf list
    from controllers.nominal import NominalController

STEP_COLUMNS = frozenset({"u_nom", "u_filter", "u", "rho_pred", "infeasible", "filter_us", "action"})
RESERVED_COLUMNS = frozenset(TIMESERIES_UNITS) | STEP_COLUMNS  # names a filter's diagnostics may not take
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
        text = str(exc).strip().splitlines()
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
    """estimate → nominal → filter → admission → monitor → command (module docstring).

    `context` gives the pressure limits the command is clipped to (`context.limits`) and the
    number of segments; `monitor` defaults to a `SafetyMonitor` with its default hold;
    `clock` (s) times the filter call. `fault` is the run's first filter fault (None: none).
    """

    def __init__(self, safety_filter: SafetyFilter, nominal: NominalController, context: FilterContext,
                 monitor: SafetyMonitor | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        self.filter, self.nominal, self.context = safety_filter, nominal, context
        self.n = context.robot.n_segments
        self.monitor = SafetyMonitor(self.n) if monitor is None else monitor
        if self.monitor.n_segments != self.n:
            raise ValueError(f"monitor has {self.monitor.n_segments} segments, the robot {self.n}")
        self.clock = clock
        self._nan_n = read_only(np.full(self.n, math.nan))
        limits = context.limits
        self._lo, self._hi = (None, None) if limits is None else (list(limits[0]), list(limits[1]))
        self.check = OutputCheck(self.n, RESERVED_COLUMNS)
        self.fault: FilterFault | None = None

    @property
    def stopped(self) -> bool:
        """A filter fault has led to the monitor's vent: the loop ends its run (module docstring)."""
        return self.fault is not None and self.monitor.vent_latched

    def reset(self) -> None:
        """Before a run: no fault, a fresh output check, the filter's own `reset()` (when it has one;
        if it raises, that is the run's filter fault) and the monitor's `restart()` (its clock,
        hold and latched vent start again)."""
        self.fault = None
        self.check = OutputCheck(self.n, RESERVED_COLUMNS)
        self.monitor.restart()
        try:
            reset_filter(self.filter)
        except Exception as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
            self.fault = FilterFault.from_exception(exc, "reset", math.nan)

    def view(self, estimate: Estimate) -> Estimate:
        """What user code sees of `estimate`: read-only copies of q and q̇ (the loop keeps its own)."""
        return Estimate(estimate.t, read_only(np.array(estimate.q, dtype=float)),
                        read_only(np.array(estimate.qd, dtype=float)), estimate.t_capture)

    def nominal_command(self, view: Estimate) -> np.ndarray:
        """u_nom of `view` as a new read-only float array (N,) hPa (FilterReturnError if the
        nominal's return is not N real numbers)."""
        return read_only(real_vector(self.nominal(view.t, view.q, view.qd), self.n, "the nominal command"))

    def prepare(self, estimate: Estimate) -> tuple[Estimate | None, np.ndarray]:
        """Steps 1–2 of the module docstring: (the view of `estimate` the filter is to be called
        on, u_nom); the view is None when the filter is not to be called (a fault, now or before,
        or the nominal refused its input: u_nom is then NaN)."""
        if self.fault is not None:
            return None, self._nan_n
        try:
            view = self.view(estimate)
            return view, self.nominal_command(view)
        except ControllerInputError:
            return None, self._nan_n
        except Exception as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
            self.fault = FilterFault.from_exception(exc, "nominal", estimate.t)
            return None, self._nan_n

    def __call__(self, estimate: Estimate, flags: SafetyFlags = NO_FLAGS) -> StepRecord:
        view, u_nom = self.prepare(estimate)
        result, filter_us = None, math.nan
        if view is not None and not flags.perception_stale:
            try:
                start = self.clock()
                result = self.filter(view, u_nom)
                filter_us = (self.clock() - start) * 1e6
            except ControllerInputError:
                result = None
            except Exception as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
                self.fault = FilterFault.from_exception(exc, "filter", estimate.t)
        return self.finish(estimate, u_nom, result, filter_us, flags)

    def finish(self, estimate: Estimate, u_nom: np.ndarray, result: object, filter_us: float,
               flags: SafetyFlags = NO_FLAGS) -> StepRecord:
        """Steps 3–6 of the module docstring for a filter's raw `result` (None: the filter was
        not called, raised or refused its input)."""
        output = command = None
        if result is not None and self.fault is None:
            try:
                output = self.check(result)
            except FilterReturnError as exc:
                self.fault = FilterFault.from_exception(exc, "filter return", estimate.t, self.filter)
            else:
                command = self.admit(output.u)
        if self.fault is not None:
            flags = replace(flags, filter_fault=True)
            output = None
        decision = self.monitor.step(estimate.t, command, flags, admitted=True)
        return StepRecord(estimate, u_nom, output, decision.u, decision.action, decision.reasons, filter_us)

    def admit(self, u_filter: np.ndarray) -> np.ndarray | None:
        """u_filter (N,) hPa, a float array the step owns (`OutputCheck` made it), clipped to the
        limits; None when it is not finite."""
        values = u_filter.tolist()  # Python floats: faster than numpy for N ~ 2
        if not all(map(math.isfinite, values)):
            return None
        if self._lo is None:
            return u_filter
        return np.array([min(max(v, lo), hi) for v, lo, hi in zip(values, self._lo, self._hi)])

    def wait(self, estimate: Estimate) -> StepRecord:
        """A call before the loop has its first estimate (camera start-up): the filter and the
        monitor are not called; the valves vent (u = 0 hPa) without latching. The nominal is
        evaluated for the record (NaN when it raises or returns what the contract refuses)."""
        try:
            u_nom = self.nominal_command(self.view(estimate)) if self.fault is None else self._nan_n
        except Exception:  # noqa: BLE001 - recorded as NaN; the fault surfaces at the first real call
            u_nom = self._nan_n
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
    """B control steps at once, row b the `ControlStep` of run b (module docstring), in numpy.

    safety_filter: one filter for all rows, or B, one per row; nominal: likewise (None: the loop
    hands every call its nominal commands, `u_nom`, e.g. the environment's actions). A shared filter
    with `filter_batch` (the plug-in contract, `controllers.safety_filter`) is called once per
    control call for all the rows whose step calls it; any other filter is called row by row
    (one shared filter without `filter_batch` must then be stateless). What each row's step does
    is `ControlStep`'s: the same views (read-only copies), the same admission (the output
    check, non-finite refused, the clip to `context.limits`), the same faults (a row's first,
    after which its user code is not called again; an exception or refused return of
    `filter_batch` is a fault of every row it was called for) and the same monitor
    (`BatchSafetyMonitor`, `hold_s`), so a row's commands, records and fault are, bit for bit,
    those of a `ControlStep` of that run alone with the same filter calls (tests/test_monitor.py,
    tests/test_trust_boundary.py). Vectorised: the admission, the monitor's common case, the
    figures; per row: the user code that has no batch form (nominal, filters without
    `filter_batch`) and the rows that hold or vent.
    """

    def __init__(self, safety_filter: SafetyFilter | Sequence[SafetyFilter],
                 nominal: NominalController | Sequence[NominalController] | None, context: FilterContext,
                 n_sims: int, hold_s: float = DEFAULT_HOLD_S, clock: Callable[[], float] = time.perf_counter) -> None:
        self.n_sims, self.n, self.context, self.clock = n_sims, context.robot.n_segments, context, clock
        self.per_row_filters = isinstance(safety_filter, Sequence)
        self.filters = list(safety_filter) if self.per_row_filters else [safety_filter] * n_sims
        self.nominals = list(nominal) if isinstance(nominal, Sequence) else [nominal] * n_sims
        if len(self.filters) != n_sims or len(self.nominals) != n_sims:
            raise ValueError(f"safety_filter and nominal must be one or n_sims = {n_sims} each, got "
                             f"{len(self.filters)} and {len(self.nominals)}")
        self.filter = None if self.per_row_filters else safety_filter
        shared_nominal = None if isinstance(nominal, Sequence) else nominal
        self.nominal_batch = getattr(shared_nominal, "nominal_batch", None)  # None: the nominal is called per row
        self.nominal_missing = any(nom is None for nom in self.nominals)
        self.batched = not self.per_row_filters and callable(getattr(safety_filter, "filter_batch", None))
        self.monitor = BatchSafetyMonitor(n_sims, self.n, hold_s)
        limits = context.limits
        self._lo, self._hi = (None, None) if limits is None else (np.array(limits[0]), np.array(limits[1]))
        self.faults: list[FilterFault | None] = [None] * n_sims
        self.faulted = np.zeros(n_sims, dtype=bool)
        self.checks = [OutputCheck(self.n, RESERVED_COLUMNS) for _ in range(n_sims)]

    @property
    def stopped(self) -> np.ndarray:
        """(B,) bool: the row's fault has led to its monitor's vent (`ControlStep.stopped`)."""
        return self.faulted & self.monitor.latched

    def reset(self, rows: np.ndarray | None = None, filters: bool = True) -> None:
        """`ControlStep.reset` of the rows in `rows` ((B,) bool; None: all): no fault, a fresh output
        check, the monitor's restart and, with `filters`, the filters' `reset()` (a shared
        filter's once, whose fault is then every row's)."""
        rows = np.ones(self.n_sims, dtype=bool) if rows is None else rows
        ids = np.flatnonzero(rows).tolist()
        self.monitor.restart(rows)
        self.faulted[rows] = False
        for b in ids:
            self.faults[b] = None
            self.checks[b] = OutputCheck(self.n, RESERVED_COLUMNS)
        if not filters:
            return
        for b in ids if self.per_row_filters else ids[:1]:
            try:
                reset_filter(self.filters[b])
            except Exception as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
                fault = FilterFault.from_exception(exc, "reset", math.nan)
                for row in ([b] if self.per_row_filters else ids):
                    self._fault(row, fault)

    def _fault(self, b: int, fault: FilterFault) -> None:
        if self.faults[b] is None:
            self.faults[b] = fault
            self.faulted[b] = True

    def __call__(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray, t_capture: np.ndarray | None = None,
                 rows: np.ndarray | None = None, u_nom: np.ndarray | None = None,
                 flags: list[SafetyFlags] | None = None) -> BatchStepRecord:
        """One control call of the rows in `rows` ((B,) bool; None: all) at their estimates: t,
        t_capture (B,) s (t_capture None: = t), q (B, N) rad, qd (B, N) rad/s (the loop's own
        arrays: the step copies what user code sees); `u_nom` (B, N) hPa: the nominal commands
        when the loop has them (the environment's held actions; the nominal is then not called),
        None: each row's nominal is called; `flags`: each row's flags (None: none raised)."""
        n_sims, n = self.n_sims, self.n
        t = np.asarray(t, dtype=float)
        t_capture = t if t_capture is None else np.asarray(t_capture, dtype=float)
        rows = np.ones(n_sims, dtype=bool) if rows is None else rows
        stale = np.zeros(n_sims, dtype=bool) if flags is None else np.array([f.perception_stale for f in flags])
        live = rows & ~self.faulted
        ts, tcs = t.tolist(), t_capture.tolist()
        q_view, qd_view = read_only(np.array(q, dtype=float)), read_only(np.array(qd, dtype=float))
        nominal_ok = live.copy()
        if u_nom is None:
            if self.nominal_missing:
                raise ValueError("u_nom must be given: this step was made without a nominal controller")
            nominal = np.full((n_sims, n), math.nan)
            if self.nominal_batch is not None and live.any():
                self._call_nominal_batch(live, ts, t, q_view, qd_view, nominal, nominal_ok)
            for b in (np.flatnonzero(live).tolist() if self.nominal_batch is None else ()):
                try:
                    nominal[b] = real_vector(self.nominals[b](ts[b], q_view[b], qd_view[b]), n, "the nominal command")
                except ControllerInputError:
                    nominal_ok[b] = False
                except Exception as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
                    self._fault(b, FilterFault.from_exception(exc, "nominal", ts[b]))
                    nominal_ok[b] = False
        else:
            nominal = np.array(u_nom, dtype=float)
        nominal[~nominal_ok] = math.nan
        read_only(nominal)
        called = nominal_ok & ~stale
        output = np.zeros(n_sims, dtype=bool)
        u_filter = np.full((n_sims, n), math.nan)
        rho_pred = np.full(n_sims, math.nan)
        infeasible = np.zeros(n_sims, dtype=bool)
        filter_action: list[str | None] = [None] * n_sims
        outputs: list[FilterOutput | None] = [None] * n_sims
        filter_us = np.full(n_sims, math.nan)
        ids = np.flatnonzero(called).tolist()
        if ids and self.batched:
            self._call_batch(ids, called, ts, t, t_capture, q_view, qd_view, nominal, output, u_filter, rho_pred, infeasible,
                             filter_action, filter_us)
        else:
            for b in ids:
                self._call_row(b, Estimate(ts[b], q_view[b], qd_view[b], tcs[b]), nominal[b], output, u_filter,
                               rho_pred, infeasible, filter_action, outputs, filter_us)
        faulted = self.faulted
        if faulted.any():  # a fault's row has no output (`ControlStep.finish`)
            output &= ~faulted
            u_filter[faulted], rho_pred[faulted], infeasible[faulted] = math.nan, math.nan, False
            for b in np.flatnonzero(faulted).tolist():
                filter_action[b] = outputs[b] = None
        admitted = output & np.all(np.isfinite(u_filter), axis=1)
        command = u_filter if self._lo is None else np.minimum(np.maximum(u_filter, self._lo), self._hi)
        decision = self.monitor.step(t, command, admitted, faulted, rows, flags)
        return BatchStepRecord(t, q_view, qd_view, t_capture, nominal, output, u_filter, rho_pred, infeasible,
                               filter_action, outputs, decision.u, decision.action, decision.reasons, filter_us)

    def _call_nominal_batch(self, live: np.ndarray, ts: list[float], t: np.ndarray, q: np.ndarray, qd: np.ndarray,
                            nominal: np.ndarray, nominal_ok: np.ndarray) -> None:
        """The shared nominal's `nominal_batch` on the `live` rows, once (`controllers.nominal`): an
        exception or a return that is not (rows, N) real numbers is a fault of each of those rows."""
        rows = int(np.count_nonzero(live))
        try:
            result = self.nominal_batch(read_only(t[live]), read_only(q[live]), read_only(qd[live]))
            values = np.asarray(result) if isinstance(result, (np.ndarray, list, tuple)) else None
            if values is None or values.dtype.kind not in "fiu" or values.shape != (rows, self.n):
                raise FilterReturnError(f"nominal_batch must return ({rows}, {self.n}) real numbers, got "
                                        f"{type(result).__name__} {getattr(values, 'dtype', '')} "
                                        f"{getattr(values, 'shape', '')}")
        except ControllerInputError:
            nominal_ok[live] = False
            return
        except Exception as exc:  # noqa: BLE001 - a filter fault of every row it was called for
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
        batch = EstimateBatch(read_only(t[called]), read_only(q[called]), read_only(qd[called]),
                              read_only(t_capture[called]))
        where = "filter_batch"
        try:
            start = self.clock()
            result = self.filter.filter_batch(batch, read_only(nominal[called]))
            per_row_us = (self.clock() - start) * 1e6 / len(ids)
            where = "filter return"
            u, actions, infeasible_rows, rho = checked_batch_arrays(result, len(ids), self.n)
        except ControllerInputError:
            return
        except Exception as exc:  # noqa: BLE001 - a filter fault of every row it was called for
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

    def _call_row(self, b: int, view: Estimate, u_nom: np.ndarray, output: np.ndarray, u_filter: np.ndarray,
                  rho_pred: np.ndarray, infeasible: np.ndarray, filter_action: list[str | None],
                  outputs: list[FilterOutput | None], filter_us: np.ndarray) -> None:
        """Row b's filter on its view, its output checked (`ControlStep.__call__` and `finish`) into the row arrays."""
        safety_filter = self.filters[b]
        try:
            start = self.clock()
            result = safety_filter(view, u_nom)
            filter_us[b] = (self.clock() - start) * 1e6
        except ControllerInputError:
            return
        except Exception as exc:  # noqa: BLE001 - a filter fault, recorded (module docstring)
            self._fault(b, FilterFault.from_exception(exc, "filter", view.t))
            return
        try:
            checked = self.checks[b](result)
        except FilterReturnError as exc:
            self._fault(b, FilterFault.from_exception(exc, "filter return", view.t, safety_filter))
            return
        output[b], outputs[b], filter_action[b] = True, checked, checked.action
        u_filter[b], rho_pred[b], infeasible[b] = checked.u, checked.rho_pred, checked.infeasible


def fault_log_name(label: str) -> str:
    """The file of a run folder that keeps the traceback of run `label`'s filter fault."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label)
    return f"fault_{safe}.log"


def write_fault_log(folder: Path, label: str, fault: FilterFault) -> Path:
    """Write `fault`'s one line and traceback to `folder`/`fault_log_name(label)`; return the path."""
    path = Path(folder) / fault_log_name(label)
    path.write_text(f"{fault.line()}\n\n{fault.traceback}", encoding="utf-8")
    return path

