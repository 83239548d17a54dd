"""The safe-action state machine shared by every loop: run, hold, then vent.

The control step (`closedloop.step`) calls `SafetyMonitor.step(t, u_cmd, flags)` once per
control call of every loop — the simulated one, the camera loop and the hardware loop —
(t in s, non-decreasing; u_cmd the filter's command in hPa, shape (N,), or None when the
filter raised or returned a non-finite command) and the loop sends what the returned
`SafetyDecision` says, in the same cycle, so every safe action starts within one control
cycle of its cause:

| condition (highest first)                          | action                                                   |
|----------------------------------------------------|----------------------------------------------------------|
| `interrupted` (Ctrl-C)                             | VENT now, latched                                        |
| `link_lost`                                        | VENT now, latched (the board's watchdog vents as well)   |
| a vent is latched                                  | VENT until `reset()`                                     |
| `perception_stale`, `command_nonfinite` (or u_cmd None / non-finite) or `filter_fault` | HOLD the last command sent with RUN; VENT, latched, once the hold has lasted `hold_s` (at once if nothing was ever sent) |
| none                                               | RUN: u = u_cmd                                           |

A HOLD that ends (its flags clear) before `hold_s` returns to RUN; the next one gets a
full `hold_s` again. VENT means u = 0 hPa and the loop sends the protocol's VENT frame.
A latched vent clears only by `reset()`, which refuses while a flag is raised, or by
`restart()` before a new run (its clock starts again). The class does no I/O and reads
no clock, so it is tested exactly.

`BatchSafetyMonitor` is this machine for B runs at once (a batched loop's B simulations),
and `SafetyMonitor` is its B = 1 case: one implementation. Its state is (B, ...) arrays; the
common case (RUN: admitted, nothing raised, nothing latched) is decided for all rows in one
compiled call (`closedloop.kernels.run_plain`, about 1 µs at B = 1), every other row goes
through `decide`, the one definition of the table; so row b decides exactly what a
`SafetyMonitor` of b's run decides (tests/test_monitor.py).

A caller that has admitted u_cmd itself (the control step: a finite (N,) float array,
clipped) says so with `admitted=True`; the monitor then does not check it again. What it
decides is the same. The monitor keeps its own copy of the last command sent with RUN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from enum import Enum

import numpy as np

from closedloop.monitor_layout import CLOCK, HAS_RUN, HOLD_SINCE, LAST_RUN, LATCHED, NOT_STEPPED, PENDING
from controllers.core.lazy_import import lazy_module

kernels = lazy_module("closedloop.kernels")  # numba loads on the first step (controllers.core.lazy_import)

DEFAULT_HOLD_S = 0.5  # five cycles of the 10 Hz loop


class SafeAction(str, Enum):
    RUN = "run"
    HOLD = "hold"
    VENT = "vent"


@dataclass(frozen=True)
class SafetyFlags:
    """What the loop observed this cycle."""

    perception_stale: bool = False  # no valid state estimate for the configured staleness time
    link_lost: bool = False  # `ValveBoardLink.link_lost`
    command_nonfinite: bool = False  # the controller raised NonFiniteCommandError or gave NaN/inf
    interrupted: bool = False  # Ctrl-C or another stop request
    filter_fault: bool = False  # the filter or nominal raised or returned what the contract refuses (closedloop.step)

    def raised(self) -> tuple[str, ...]:
        """Names of the flags that are set, in field order."""
        return tuple(f.name for f in fields(self) if getattr(self, f.name))


NO_FLAGS = SafetyFlags()  # nothing raised


@dataclass(eq=False, slots=True)
class SafetyDecision:
    """What to send this cycle: the action, the pressures (hPa, (N,); zeros for VENT) and the raised flags.
    Made every control call (not frozen: cheaper); nothing modifies it."""

    action: SafeAction
    u: np.ndarray
    reasons: tuple[str, ...]


ACTION_CODES = {SafeAction.RUN: 0, SafeAction.HOLD: 1, SafeAction.VENT: 2}  # the time series' `action` column
ACTIONS = (SafeAction.RUN, SafeAction.HOLD, SafeAction.VENT)  # by code


def check_monitor_args(n_segments: int, hold_s: float) -> None:
    """ValueError unless n_segments is an int >= 1 and hold_s a finite time >= 0 s."""
    if not (isinstance(n_segments, int) and n_segments >= 1):
        raise ValueError(f"n_segments must be an int >= 1, got {n_segments!r}")
    if not (math.isfinite(hold_s) and hold_s >= 0.0):
        raise ValueError(f"hold_s must be a finite time >= 0 s (0 vents at once), got {hold_s}")


class SafetyMonitor:
    """Run → hold → vent (see the module table) for one run: the B = 1 case of
    `BatchSafetyMonitor` (`rows`, its one row), so one run and a batch decide through the same code."""

    def __init__(self, n_segments: int, hold_s: float = DEFAULT_HOLD_S) -> None:
        self.rows = BatchSafetyMonitor(1, n_segments, hold_s)
        self.n_segments, self.hold_s = n_segments, self.rows.hold_s
        self.all_rows = np.ones(1, dtype=bool)  # the `rows` argument of every call: the one row
        self.no_fault = np.zeros(1, dtype=bool)

    @property
    def vent_latched(self) -> bool:
        return bool(self.rows.latched[0])

    def restart(self) -> None:
        """Before a new run: no command sent yet, no hold, no latched vent, and the clock
        starts again (t may go back to the new run's first time)."""
        self.rows.restart()

    def reset(self, flags: SafetyFlags = SafetyFlags()) -> None:
        """Clear a latched vent; refused (ValueError) while any of `flags` is raised."""
        if flags.raised():
            raise ValueError(f"cannot clear the vent while {', '.join(flags.raised())} is raised")
        self.rows.clear_vent(self.all_rows)

    def step(self, t: float, u_cmd: np.ndarray | None, flags: SafetyFlags = NO_FLAGS,
             admitted: bool = False) -> SafetyDecision:
        """The decision at time t (s) for the command u_cmd (module table). `admitted`: the
        caller guarantees that u_cmd, when not None, is a finite (N,) float array (the step's
        admission); otherwise u_cmd is checked here: shape (N,) or ValueError, refused when
        not finite."""
        u = None if u_cmd is None else (u_cmd if admitted else np.array(u_cmd, dtype=float))
        if u is not None and u.shape != (self.n_segments,):
            raise ValueError(f"u_cmd must have shape ({self.n_segments},), got {u.shape}")
        ok = u is not None and (admitted or all(map(math.isfinite, u.tolist())))
        decision = self.rows.step(np.array([float(t)]), self.rows.zeros if u is None else u.reshape(1, -1),
                                  np.array([ok]), self.no_fault, self.all_rows, None if flags is NO_FLAGS else [flags])
        return SafetyDecision(ACTIONS[decision.action[0]], decision.u[0], decision.reasons[0])


def decide(t: float, u: np.ndarray | None, flags: SafetyFlags, last_run: np.ndarray | None, hold_since: float | None,
           vent_reasons: tuple[str, ...] | None, hold_s: float, n_segments: int
           ) -> tuple[SafetyDecision, np.ndarray | None, float | None, tuple[str, ...] | None]:
    """The module table for one run, the one definition of the state machine (`SafetyMonitor` and
    `BatchSafetyMonitor` both call it off their common RUN path): at time t (s), for the command u
    (a finite (N,) float array the monitor may keep, or None: refused), the raised `flags` and the
    run's state (the last command sent with RUN, None before any; when the current hold began, s,
    None when not holding; the latched vent's reasons, None when not latched), the decision and
    the new state (last_run, hold_since, vent_reasons)."""
    if u is None and not flags.command_nonfinite and not flags.filter_fault:
        flags = replace(flags, command_nonfinite=True)
    reasons = flags.raised()
    if flags.interrupted or flags.link_lost:
        return SafetyDecision(SafeAction.VENT, np.zeros(n_segments), reasons), last_run, hold_since, reasons
    if vent_reasons is not None:
        return SafetyDecision(SafeAction.VENT, np.zeros(n_segments), vent_reasons), last_run, hold_since, vent_reasons
    if flags.perception_stale or flags.command_nonfinite or flags.filter_fault:
        if hold_since is None:
            hold_since = t
        if last_run is None or t - hold_since >= hold_s:
            return SafetyDecision(SafeAction.VENT, np.zeros(n_segments), reasons), last_run, hold_since, reasons
        return SafetyDecision(SafeAction.HOLD, last_run.copy(), reasons), last_run, hold_since, None
    return SafetyDecision(SafeAction.RUN, u.copy(), reasons), u, None, None


@dataclass(eq=False, slots=True)
class BatchDecision:
    """What to send this cycle in each of B runs: action (B,) int8 codes (`ACTION_CODES`;
    NOT_STEPPED for rows not stepped), u (B, N) hPa (0 on VENT and on rows not stepped) and
    reasons, B tuples of the raised flags (() on rows not stepped)."""

    action: np.ndarray
    u: np.ndarray
    reasons: list[tuple[str, ...]]


class BatchSafetyMonitor:
    """B `SafetyMonitor`s in (B, ...) arrays (module docstring): row b is run b's monitor.

    State per row: last_run (B, N) hPa with has_run (B,) bool (a command was sent with RUN),
    hold_since (B,) s (NaN: not holding), vent_reasons (B tuples, None: not latched) and the
    row's clock (B,) s. The RUN case of every row is one compiled call (`closedloop.kernels.run_plain`),
    the other rows go through `decide`."""

    def __init__(self, n_sims: int, n_segments: int, hold_s: float = DEFAULT_HOLD_S) -> None:
        check_monitor_args(n_segments, hold_s)
        if not (isinstance(n_sims, int) and n_sims >= 1):
            raise ValueError(f"n_sims must be an int >= 1, got {n_sims!r}")
        self.n_sims, self.n_segments, self.hold_s = n_sims, n_segments, float(hold_s)
        self.state = np.zeros((n_sims, LAST_RUN + n_segments))  # packed for the compiled call (closedloop.kernels)
        self.t, self.hold_since, self.last_run = self.state[:, CLOCK], self.state[:, HOLD_SINCE], self.state[:, LAST_RUN:]
        self.t[:], self.hold_since[:] = -math.inf, math.nan
        self.bits = np.zeros((n_sims, 2), dtype=bool)
        self.has_run, self.latched = self.bits[:, HAS_RUN], self.bits[:, LATCHED]
        self.vent_reasons: list[tuple[str, ...] | None] = [None] * n_sims  # latched[b]: vent_reasons[b] is not None
        self.zeros = np.zeros((n_sims, n_segments))  # the commands of calls where none is admitted
        self.quiet = np.ones(n_sims, dtype=bool)  # no flag raised in any row

    def restart(self, rows: np.ndarray | None = None) -> None:
        """`SafetyMonitor.restart` of the rows in `rows` ((B,) bool; None: all)."""
        rows = np.ones(self.n_sims, dtype=bool) if rows is None else rows
        self.has_run[rows] = False
        self.t[rows] = -math.inf
        self.clear_vent(rows)

    def clear_vent(self, rows: np.ndarray) -> None:
        """No latched vent and no hold in the rows in `rows` ((B,) bool; `SafetyMonitor.reset`)."""
        self.hold_since[rows] = math.nan
        self.latched[rows] = False
        for b in np.flatnonzero(rows).tolist():
            self.vent_reasons[b] = None

    def step(self, t: np.ndarray, u: np.ndarray, admitted: np.ndarray, fault: np.ndarray, rows: np.ndarray,
             flags: list[SafetyFlags] | None = None) -> BatchDecision:
        """The decision of the runs in `rows` ((B,) bool) at their times t (B,) s: u (B, N) hPa
        the admitted commands (finite, nothing modifies them afterwards; read on the rows where
        `admitted` (B,) is True, refused elsewhere), `fault` (B,) bool the `filter_fault` flag
        and `flags` each row's other flags (None: none raised)."""
        sent, action = self.outputs()
        pending = kernels.run_plain(t, u, admitted, fault, rows, self.quiet_rows(flags), self.state, self.bits, sent,
                                    action)
        return self.settle(pending, t, u, admitted, fault, flags, sent, action)

    def outputs(self) -> tuple[np.ndarray, np.ndarray]:
        """New arrays for a call's decisions: sent (B, N) hPa, action (B,) int8."""
        return np.empty((self.n_sims, self.n_segments)), np.empty(self.n_sims, dtype=np.int8)

    def quiet_rows(self, flags: list[SafetyFlags] | None) -> np.ndarray:
        """(B,) bool: the rows with no flag raised (`flags`: each row's; None: none raised)."""
        return self.quiet if flags is None else np.array([f is NO_FLAGS or not f.raised() for f in flags])

    def settle(self, pending: int, t: np.ndarray, u: np.ndarray, admitted: np.ndarray, fault: np.ndarray,
               flags: list[SafetyFlags] | None, sent: np.ndarray, action: np.ndarray) -> BatchDecision:
        """The decision of a call after `kernels.run_plain` (arguments as `step`'s; pending its return,
        sent and action the arrays it wrote; u may be `sent`, whose pending rows then hold their
        admitted commands): the error of a bad t, or the pending rows through `decide`."""
        if pending < 0:
            b = -1 - pending
            raise ValueError(f"t must be finite and non-decreasing, got {t[b]} after {self.t[b]} "
                             f"(run {b})")
        reasons: list[tuple[str, ...]] = [()] * self.n_sims
        if not pending:  # the common case: every stepped row RUNs
            return BatchDecision(action, sent, reasons)
        for b in np.flatnonzero(action == PENDING).tolist():
            row_flags = NO_FLAGS if flags is None else flags[b]
            if fault[b]:
                row_flags = replace(row_flags, filter_fault=True)
            hold_since = float(self.hold_since[b])
            decision, last_run, hold, vent = decide(
                float(t[b]), u[b].copy() if admitted[b] else None, row_flags,
                self.last_run[b].copy() if self.has_run[b] else None, None if math.isnan(hold_since) else hold_since,
                self.vent_reasons[b], self.hold_s, self.n_segments)
            if last_run is not None:
                self.last_run[b] = last_run
                self.has_run[b] = True
            self.hold_since[b] = math.nan if hold is None else hold
            self.vent_reasons[b], self.latched[b] = vent, vent is not None
            sent[b] = decision.u
            action[b] = ACTION_CODES[decision.action]
            reasons[b] = decision.reasons
        return BatchDecision(action, sent, reasons)
