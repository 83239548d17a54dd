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

A caller that has admitted u_cmd itself (the control step: a new finite (N,) float
array, clipped) says so with `admitted=True`; the monitor then keeps u_cmd as it is
instead of checking and copying it. What it decides is the same.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from enum import Enum

import numpy as np

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


class SafetyMonitor:
    """Run → hold → vent (see the module table). One instance per run."""

    def __init__(self, n_segments: int, hold_s: float = DEFAULT_HOLD_S) -> None:
        if not (isinstance(n_segments, int) and n_segments >= 1):
            raise ValueError(f"n_segments must be an int >= 1, got {n_segments!r}")
        if not (math.isfinite(hold_s) and hold_s >= 0.0):
            raise ValueError(f"hold_s must be a finite time >= 0 s (0 vents at once), got {hold_s}")
        self.n_segments = n_segments
        self._shape = (n_segments,)
        self.hold_s = float(hold_s)
        self._last_run: np.ndarray | None = None
        self._hold_since: float | None = None
        self._vent_reasons: tuple[str, ...] | None = None
        self._t = -math.inf

    @property
    def vent_latched(self) -> bool:
        return self._vent_reasons is not None

    def restart(self) -> None:
        """Before a new run: no command sent yet, no hold, no latched vent, and the clock
        starts again (t may go back to the new run's first time)."""
        self._last_run = None
        self._hold_since = None
        self._vent_reasons = None
        self._t = -math.inf

    def reset(self, flags: SafetyFlags = SafetyFlags()) -> None:
        """Clear a latched vent; refused (ValueError) while any of `flags` is raised."""
        if flags.raised():
            raise ValueError(f"cannot clear the vent while {', '.join(flags.raised())} is raised")
        self._vent_reasons = None
        self._hold_since = None

    def step(self, t: float, u_cmd: np.ndarray | None, flags: SafetyFlags = NO_FLAGS,
             admitted: bool = False) -> SafetyDecision:
        """The decision at time t (s) for the command u_cmd (module table). `admitted`: the
        caller guarantees that u_cmd, when not None, is a finite (N,) float array that
        nothing modifies afterwards (the monitor keeps it without a copy)."""
        if not (math.isfinite(t) and t >= self._t):
            raise ValueError(f"t must be finite and non-decreasing, got {t} after {self._t}")
        self._t = t
        if flags is NO_FLAGS and self._vent_reasons is None:  # the common case: RUN, nothing raised
            if admitted and u_cmd is not None:
                self._hold_since = None
                self._last_run = u_cmd
                return SafetyDecision(SafeAction.RUN, u_cmd, ())
            if type(u_cmd) is np.ndarray and u_cmd.shape == self._shape:
                u = u_cmd.astype(float)  # a copy: the monitor keeps it
                if all(map(math.isfinite, u.tolist())):
                    self._hold_since = None
                    self._last_run = u
                    return SafetyDecision(SafeAction.RUN, u, ())
        u = None if u_cmd is None else np.array(u_cmd, dtype=float)  # a copy: the monitor keeps it
        if u is not None and u.shape != (self.n_segments,):
            raise ValueError(f"u_cmd must have shape ({self.n_segments},), got {u.shape}")
        finite = u is not None and all(map(math.isfinite, u.tolist()))
        if not finite and not flags.command_nonfinite and not flags.filter_fault:
            flags = replace(flags, command_nonfinite=True)
        reasons = flags.raised()
        if flags.interrupted or flags.link_lost:
            return self._vent(reasons)
        if self._vent_reasons is not None:
            return SafetyDecision(SafeAction.VENT, np.zeros(self.n_segments), self._vent_reasons)
        if flags.perception_stale or flags.command_nonfinite or flags.filter_fault:
            if self._hold_since is None:
                self._hold_since = t
            if self._last_run is None or t - self._hold_since >= self.hold_s:
                return self._vent(reasons)
            return SafetyDecision(SafeAction.HOLD, self._last_run.copy(), reasons)
        self._hold_since = None
        self._last_run = u
        return SafetyDecision(SafeAction.RUN, u.copy(), reasons)

    def _vent(self, reasons: tuple[str, ...]) -> SafetyDecision:
        self._vent_reasons = reasons
        return SafetyDecision(SafeAction.VENT, np.zeros(self.n_segments), reasons)
