"""The one control step shared by the three clocks (docs/safety-filter.md): the simulated loop, the camera loop and the hardware loop.

Each loop owns its clock and its I/O; at each control call it hands `ControlStep` the
controller's view of the state (`controllers.safety_filter.Estimate`: t, t_capture in s,
q (N,) rad, qd (N,) rad/s) and what it observed (`SafetyFlags`), and sends the
`StepRecord.u` it gets back. In this order:

1. nominal: u_nom = nominal(t, q, qd), (N,) hPa;
2. filter (skipped while `perception_stale`: there is no estimate to filter):
   u_filter = as_output(filter(estimate, u_nom)).u, the call timed (`filter_us`, µs);
3. admission: a u_filter that is not finite is refused (the monitor's `command_nonfinite`
   flag: HOLD the last command, then VENT); a finite one is clipped to the pressure
   limits [u_min, u_max] of the `FilterContext` (no clipping when they are None);
   a nominal controller or filter that raises `ControllerInputError` (a non-finite
   estimate or u_nom) is refused the same way;
4. safety monitor (`closedloop.monitor.SafetyMonitor`): RUN (the admitted command, which
   the monitor is told is admitted: it keeps it without checking or copying it again), HOLD
   or VENT;
5. the record: what the filter returned (`output`, None when it was not called or
   raised), what was sent (`u`), the monitor's action and reasons, the filter's time.

Guarantees, whatever the filter does: u is finite; on RUN and HOLD it is a command the
step admitted, so within the limits when they are on; VENT sends 0 hPa (the valves' vent).
A u_filter of the wrong shape is a programming error of the filter: ValueError.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from closedloop.monitor import NO_FLAGS, SafeAction, SafetyFlags, SafetyMonitor
from controllers.errors import ControllerInputError
from controllers.nominal import NominalController
from controllers.safety_filter import Estimate, FilterContext, FilterOutput, SafetyFilter, as_output, reset_filter

ACTION_CODES = {SafeAction.RUN: 0, SafeAction.HOLD: 1, SafeAction.VENT: 2}  # the time series' `action` column


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

    `context` gives the pressure limits the command is clipped to and the number of
    segments; `monitor` defaults to a `SafetyMonitor` with its default hold; `clock`
    (s) times the filter call.
    """

    def __init__(self, safety_filter: SafetyFilter, nominal: NominalController, context: FilterContext,
                 monitor: SafetyMonitor | None = None, clock: Callable[[], float] = time.perf_counter) -> None:
        self.filter, self.nominal, self.context = safety_filter, nominal, context
        self.n = context.robot.n_segments
        self.monitor = SafetyMonitor(self.n) if monitor is None else monitor
        if self.monitor.n_segments != self.n:
            raise ValueError(f"monitor has {self.monitor.n_segments} segments, the robot {self.n}")
        self.clock = clock
        self._nan_n = np.full(self.n, math.nan)
        bounded = context.u_min is not None
        self._lo = context.u_min.tolist() if bounded else None
        self._hi = context.u_max.tolist() if bounded else None

    def reset(self) -> None:
        """Before a run: the filter's own `reset()`, when it has one, and the monitor's `restart()`
        (its clock, hold and latched vent start again)."""
        reset_filter(self.filter)
        self.monitor.restart()

    def __call__(self, estimate: Estimate, flags: SafetyFlags = NO_FLAGS) -> StepRecord:
        u_nom, output, command, filter_us = self._nan_n, None, None, math.nan
        try:
            u_nom = np.asarray(self.nominal(estimate.t, estimate.q, estimate.qd), dtype=float)
            if not flags.perception_stale:
                start = self.clock()
                output = as_output(self.filter(estimate, u_nom))
                filter_us = (self.clock() - start) * 1e6
                command = self.admit(output.u)
        except ControllerInputError:
            output = None
        decision = self.monitor.step(estimate.t, command, flags, admitted=True)
        return StepRecord(estimate, u_nom, output, decision.u, decision.action, decision.reasons, filter_us)

    def admit(self, u_filter: np.ndarray) -> np.ndarray | None:
        """u_filter (N,) hPa clipped to the limits, as a new float array (the monitor keeps it);
        None when it is not finite."""
        u = np.asarray(u_filter, dtype=float)
        if u.shape != (self.n,):
            raise ValueError(f"the filter returned a command of shape {u.shape}, expected ({self.n},) hPa")
        values = u.tolist()  # Python floats: faster than numpy for N ~ 2
        if not all(map(math.isfinite, values)):
            return None
        if self._lo is None:
            return u.copy()  # u may be the filter's own array
        return np.array([min(max(v, lo), hi) for v, lo, hi in zip(values, self._lo, self._hi)])

    def wait(self, estimate: Estimate) -> StepRecord:
        """A call before the loop has its first estimate (camera start-up): the filter and the
        monitor are not called; the valves vent (u = 0 hPa) without latching."""
        u_nom = np.asarray(self.nominal(estimate.t, estimate.q, estimate.qd), dtype=float)
        return StepRecord(estimate, u_nom, None, np.zeros(self.n), SafeAction.VENT, ("perception_stale",), math.nan)
