"""The plant interface shared by the PCC simulation, the MuJoCo ground truth and hardware.

Data flows one way: plant → estimator → controller → command → plant. A plant takes
a pressure command u (hPa, shape (N,)) held constant for one control period
(zero-order hold) and reports the ground truth at the end of that period as a
`PlantState`. The controller never sees a plant object, only the estimator's output.
"""

from __future__ import annotations

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
