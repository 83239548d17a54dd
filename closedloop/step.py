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
"""

from __future__ import annotations

import inspect
import math
import sysconfig
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from closedloop.columns import TIMESERIES_UNITS
from closedloop.monitor import NO_FLAGS, SafeAction, SafetyFlags, SafetyMonitor
from controllers.errors import ControllerInputError
from controllers.nominal import NominalController
from controllers.safety_filter import (Estimate, FilterContext, FilterOutput, FilterReturnError, OutputCheck,
                                       SafetyFilter, read_only, real_vector, reset_filter)

ACTION_CODES = {SafeAction.RUN: 0, SafeAction.HOLD: 1, SafeAction.VENT: 2}  # the time series' `action` column
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

    def prepare(self, estimate: Estimate, frozen: bool = False) -> tuple[Estimate | None, np.ndarray]:
        """Steps 1–2 of the module docstring: (the view of `estimate` the filter is to be called
        on, u_nom); the view is None when the filter is not to be called (a fault, now or before,
        or the nominal refused its input: u_nom is then NaN). `frozen`: the caller guarantees that
        estimate.q and estimate.qd are already read-only arrays that nothing writes afterwards (a
        batched loop's one copy of all its states), so they are handed on without another copy."""
        if self.fault is not None:
            return None, self._nan_n
        try:
            view = estimate if frozen else self.view(estimate)
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
               flags: SafetyFlags = NO_FLAGS, checked: bool = False) -> StepRecord:
        """Steps 3–6 of the module docstring for a filter's raw `result` (None: the filter was
        not called, raised or refused its input), computed by `__call__` or by a loop that
        called the filter for many states at once (`softcbf_mj.batch_loop`; `checked`: `result`
        is a FilterOutput that `checked_batch_outputs` made, converted already)."""
        output = command = None
        if result is not None and self.fault is None:
            try:
                output = result if checked else self.check(result)
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


def fault_log_name(label: str) -> str:
    """The file of a run folder that keeps the traceback of run `label`'s filter fault."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in label)
    return f"fault_{safe}.log"


def write_fault_log(folder: Path, label: str, fault: FilterFault) -> Path:
    """Write `fault`'s one line and traceback to `folder`/`fault_log_name(label)`; return the path."""
    path = Path(folder) / fault_log_name(label)
    path.write_text(f"{fault.line()}\n\n{fault.traceback}", encoding="utf-8")
    return path

