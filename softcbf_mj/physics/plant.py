"""The plant interface shared by the PCC simulation, the MuJoCo ground truth and hardware.

Data flows one way: plant → estimator → controller → command → plant. A plant takes
a pressure command u (hPa, shape (N,)) held constant for one control period
(zero-order hold) and reports the ground truth at the end of that period as a
`PlantState`. The controller never sees a plant object, only the estimator's output.

Command delay (the ground truth's `command_delay` δ, s): the time from the controller's command
to the valves' input, a transport delay (bus, valve driver). A plant steps at its control period
T and applies, over period j (from t_j = jT), the command u_{j−k} given k = δ/T periods earlier: a
FIFO of k commands (`CommandDelay`), one implementation for every plant (the MuJoCo and PCC
plants, single and batched). Before the first command the FIFO holds the reset pressure u0
(0 unless given): the valves had received u0 before t = 0. k must be a whole number (δ = kT
within 1e-9 relative, `delay_periods`): a delay between two periods is refused, not rounded,
since the same δ at another control rate would be a different delay. δ = 0 is the plant
without the FIFO (the command acts in its own period, as before). The MuJoCo plants read δ
from their model's custom numeric `command_delay` (`COMMAND_DELAY_NUMERIC`, absent: 0), so
every surface that builds a MuJoCo plant from a ground truth (`softcbf_mj.physics.ground_truth`)
delays its commands alike; the PCC plants take it as an argument. A filter is never told δ by
the plant (its context states what the controller assumes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass(eq=False, slots=True)
class PlantState:
    """Ground truth of a plant at time t. Made every control period, so not frozen (a frozen
    dataclass costs ~1 µs more to build); nothing modifies it once returned.

    t: s. q, qd: (N,) bending angles (rad) and rates (rad/s). segment_ends: (N+1, 2)
    positions (m), base first, tip last. contact_forces: (F,) contact force magnitude
    per environment facet (N) as the plant measures it (PCC plant: ψ(n) of the true
    tip; MuJoCo: the plate's spring). u_applied: (N,) pressure acting on the arm (hPa),
    after actuator dynamics. extras: plant-specific scalars or small arrays.
    """

    t: float
    q: np.ndarray
    qd: np.ndarray
    segment_ends: np.ndarray
    contact_forces: np.ndarray
    u_applied: np.ndarray
    extras: dict[str, float | np.ndarray] = field(default_factory=dict)

    @property
    def tip(self) -> np.ndarray:
        """Tip position r, shape (2,), m."""
        return self.segment_ends[-1]


@dataclass(frozen=True, eq=False)
class BatchPlantState:
    """Ground truth of B plants at once; row b is simulation b's `PlantState`.

    t: (B,) s. q, qd: (B, N) rad, rad/s. segment_ends: (B, N+1, 2) m. contact_forces:
    (B, P) N. u_applied: (B, N) hPa. extras: plant-specific arrays with first axis B.
    Every call of a batch plant returns fresh arrays (nothing is overwritten by its next `step`).
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    segment_ends: np.ndarray
    contact_forces: np.ndarray
    u_applied: np.ndarray
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.q.shape[0])

    def row(self, b: int) -> PlantState:
        """Simulation b's state as a `PlantState` (copies)."""
        return PlantState(float(self.t[b]), self.q[b].copy(), self.qd[b].copy(), self.segment_ends[b].copy(),
                          self.contact_forces[b].copy(), self.u_applied[b].copy(),
                          {key: np.array(value[b]) for key, value in self.extras.items()})


class Plant(Protocol):
    """What a closed loop needs from a plant."""

    control_dt: float  # s, the zero-order-hold period of the command
    n_segments: int

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> PlantState:
        """Start at rest (or with rates qd0) at bending angles q0 (rad); return the state at t = 0."""
        ...

    def step(self, u: np.ndarray) -> PlantState:
        """Hold the command u (hPa, (N,)) for one control period; return the state at its end."""
        ...


def steps_per_control(control_dt: float, physics_dt: float) -> int:
    """Physics steps per control period; raises if control_dt is not an integer multiple of physics_dt."""
    if not (control_dt > 0 and physics_dt > 0):
        raise ValueError(f"time steps must be > 0, got control_dt={control_dt}, physics_dt={physics_dt}")
    ratio = control_dt / physics_dt
    n = round(ratio)
    if n < 1 or abs(ratio - n) > 1e-9 * ratio:
        divisors = ", ".join(f"{control_dt / k:.6g}" for k in (1, 2, 4, 5, 10))
        raise ValueError(
            f"the control period ({control_dt:g} s) must be an integer multiple of the physics step "
            f"({physics_dt:g} s; ratio {ratio:.6g}); choose a physics step such as {divisors} s"
        )
    return n


COMMAND_DELAY_NUMERIC = "command_delay"  # the MuJoCo model's custom numeric carrying δ (s; absent: 0)


def delay_periods(command_delay: float, control_dt: float) -> int:
    """k = `command_delay` / `control_dt` (s, s), a whole number of control periods >= 0 (module docstring);
    ValueError otherwise."""
    if not (math.isfinite(command_delay) and command_delay >= 0):
        raise ValueError(f"command_delay must be finite and >= 0 s, got {command_delay}")
    ratio = command_delay / control_dt
    k = round(ratio)
    if abs(ratio - k) > 1e-9 * max(ratio, 1.0):
        raise ValueError(f"command_delay ({command_delay:g} s) must be a whole number of control periods "
                         f"({control_dt:g} s), e.g. {math.floor(ratio) * control_dt:g} or "
                         f"{math.ceil(ratio) * control_dt:g} s")
    return int(k)


class CommandDelay:
    """The FIFO of the module docstring for B rows of N commands: `reset(u0)` (B, N), then `apply(u)` once
    per control period returns the commands (B, N) that act in it, those given `periods` calls earlier."""

    def __init__(self, periods: int, shape: tuple[int, int]) -> None:
        self.periods = int(periods)
        self._queue = np.zeros((self.periods + 1, *shape))  # a ring: the newest command at `_head`
        self._head = 0

    def reset(self, u0: np.ndarray, rows: np.ndarray | None = None) -> None:
        """Fill the FIFO with u0 (B, N), or only rows `rows` (their u0 given in that order)."""
        if rows is None:
            self._queue[:] = u0
        else:
            self._queue[:, rows] = u0

    def apply(self, u: np.ndarray) -> np.ndarray:
        """Push u (B, N); return (a copy of) the command given `periods` calls ago, u itself at 0."""
        depth = self.periods + 1
        self._head = (self._head + 1) % depth
        self._queue[self._head] = u
        return self._queue[(self._head - self.periods) % depth].copy()


class BatchPlant(Protocol):
    """B plants stepped together (one control period each call); rows are simulations."""

    control_dt: float  # s
    n_segments: int
    n_sims: int

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> BatchPlantState:
        """Start every simulation b at q0[b] (rad, (B, N)), at rest or with rates qd0[b]."""
        ...

    def step(self, u: np.ndarray) -> BatchPlantState:
        """Hold u[b] (hPa, (B, N)) on simulation b for one control period; return the states at its end."""
        ...
