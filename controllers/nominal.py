"""Nominal (unsafe) controllers whose commands the CBF filter makes safe.

A nominal controller is any callable `(t, q, qd) -> u_nom` with t in s, q and qd of
shape (N,) in rad and rad/s, and u_nom of shape (N,) in hPa. Scenarios pass one to
the closed loop; the filter never needs to know which one it is. `sinusoid` and
`tip_tracker` and `step` are the registry's factories ("sinusoid", "tip-tracker", "step").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from controllers.params import RobotParams, per_segment
from controllers.pcc import tip_jacobian, tip_position
from controllers.safety_filter import FilterContext


class NominalController(Protocol):
    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray: ...


@dataclass(frozen=True)
class SinusoidNominal:
    """The paper's open-loop command u_nom,j(t) = A_j sin(2π f t + φ_j) (docs/model.md#nominal-controller-and-the-papers-scenario).

    amplitude: (N,) hPa (paper: 80 for both segments); frequency: Hz (paper: 0.01);
    phase: (N,) rad (paper: 0).
    """

    amplitude: tuple[float, ...]
    frequency: float
    phase: tuple[float, ...]

    def __post_init__(self) -> None:
        if not (math.isfinite(self.frequency) and self.frequency > 0):
            raise ValueError(f"frequency must be > 0 Hz, got {self.frequency}")
        if len(self.amplitude) != len(self.phase):
            raise ValueError(f"amplitude and phase must have the same length, got {len(self.amplitude)} and {len(self.phase)}")
        for name in ("amplitude", "phase"):
            if not all(math.isfinite(v) for v in getattr(self, name)):
                raise ValueError(f"{name} must be finite, got {getattr(self, name)}")
        object.__setattr__(self, "_amp", np.array(self.amplitude, dtype=float))
        object.__setattr__(self, "_phase", np.array(self.phase, dtype=float))

    @classmethod
    def paper(cls, n_segments: int = 2, amplitude: float = 80.0, frequency: float = 0.01) -> "SinusoidNominal":
        amp = per_segment(amplitude, n_segments, "amplitude")
        return cls(tuple(amp), frequency, (0.0,) * n_segments)

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self._amp * np.sin(2.0 * math.pi * self.frequency * t + self._phase)


@dataclass(frozen=True)
class TipTracker:
    """Drive the tip along a target path r*(t) (m), e.g. straight into a wall.

    Quasi-static law: one damped-least-squares step of the PCC kinematics gives a
    target configuration q* = q + Jᵀ(J Jᵀ + μ²I)⁻¹ (r* − r(q)); the command is the
    pressure that holds q* at rest, Λ⁻¹ K q*, plus a damping term −Λ⁻¹ k_d q̇.
    No pressure limits are applied here (the filter or the plant applies them).
    """

    params: RobotParams
    target: Callable[[float], np.ndarray]
    damping_ratio_gain: float = 0.0
    mu: float = 1e-2

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        lengths = self.params.array("lengths")
        error = np.asarray(self.target(t), dtype=float) - tip_position(q, lengths)
        jac = tip_jacobian(q, lengths)
        step = jac.T @ np.linalg.solve(jac @ jac.T + self.mu**2 * np.eye(2), error)
        q_star = q + step
        k = self.params.array("stiffness")
        lam = self.params.array("gains")
        return (k * q_star - self.damping_ratio_gain * qd) / lam


def sinusoid(context: FilterContext, amplitude: float = 80.0, frequency: float = 0.01, t0: float = 0.0,
             phase: float = 0.0) -> SinusoidNominal:
    """The paper's sinusoid, u_nom,j = A_j sin(2π f (t + t0) + φ_j)."""
    n = context.robot.n_segments
    shift = 2 * math.pi * frequency * t0
    return SinusoidNominal(tuple(per_segment(amplitude, n, "amplitude")), frequency,
                           tuple(shift + p for p in per_segment(phase, n, "phase").tolist()))


sinusoid.parameter_docs = {"amplitude": "A_j, scalar or one per segment [hPa]", "frequency": "f [Hz]",
                           "t0": "time offset: t0 > 0 starts later in the cycle [s]",
                           "phase": "phi_j, scalar or one per segment [rad]"}


def tip_tracker(context: FilterContext, x_m: float = 0.2, y_m: float = 0.15, damping_ratio_gain: float = 0.0,
                mu: float = 1e-2) -> TipTracker:
    """Drive the tip towards a fixed point r* = (x_m, y_m) (default: into the paper's facet)."""
    target = np.array([x_m, y_m], dtype=float)
    if not np.isfinite(target).all():
        raise ValueError(f"x_m and y_m must be finite m, got {x_m}, {y_m}")
    return TipTracker(context.robot, lambda t: target, damping_ratio_gain, mu)


tip_tracker.parameter_docs = {"x_m": "target tip x [m]", "y_m": "target tip y [m]",
                              "damping_ratio_gain": "velocity damping k_d, u -= k_d qd / lambda [N m s/rad]",
                              "mu": "damped-least-squares damping [m]"}


@dataclass(frozen=True)
class StepNominal:
    """A step command: u_nom = 0 for t < t_step, then the constant `level` (N,) hPa."""

    level: tuple[float, ...]
    t_step: float = 0.0

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in self.level) or not math.isfinite(self.t_step):
            raise ValueError(f"level and t_step must be finite, got {self.level}, {self.t_step}")
        object.__setattr__(self, "_level", np.array(self.level, dtype=float))

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        return self._level.copy() if t >= self.t_step else np.zeros_like(self._level)


def step(context: FilterContext, seed: int = 0, low_hPa: float = 60.0, high_hPa: float = 300.0,
         t_step: float = 0.0) -> StepNominal:
    """A seeded step: one constant level per segment drawn from U(low_hPa, high_hPa) by
    numpy.random.default_rng(seed), held from t_step on (0 before)."""
    if not (math.isfinite(low_hPa) and math.isfinite(high_hPa) and low_hPa <= high_hPa):
        raise ValueError(f"low_hPa <= high_hPa (finite) required, got low_hPa={low_hPa}, high_hPa={high_hPa}")
    levels = np.random.default_rng(seed).uniform(low_hPa, high_hPa, context.robot.n_segments)
    return StepNominal(tuple(levels.tolist()), t_step)


step.parameter_docs = {"seed": "seed of the levels' generator [1]", "low_hPa": "lowest level [hPa]",
                       "high_hPa": "highest level [hPa]", "t_step": "time of the step [s]"}
