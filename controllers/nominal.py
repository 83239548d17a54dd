"""Nominal (unsafe) controllers whose commands the CBF filter makes safe.

A nominal controller is any callable `(t, q, qd) -> u_nom` with t in s, q and qd of
shape (N,) in rad and rad/s, and u_nom of shape (N,) in hPa. Scenarios pass one to
the closed loop; the filter never needs to know which one it is. What a nominal can do beyond
the call it declares, as a filter does, with a `capabilities` attribute holding a
`controllers.contract.capabilities.Capabilities` (read and checked by `nominal_capabilities`, the filter's
reader with the nominal's kind): batched, it has `nominal_batch(t, q, qd) -> u_nom` for B states
at once (t (B,) s, q and qd (B, N), u_nom (B, N) hPa), which must return, bit for bit, the rows of
B calls, and a batched loop that shares it calls that once for all its simulations
(`closedloop.step.BatchControlStep`); one that declares nothing (`Capabilities()`, the default) is
called once per simulation, whatever other methods it has; one that declares a capability it lacks
(or a filter's rows, reset_rows, passthrough) is refused when it is built or the loop is set up.
Here `SinusoidNominal` declares batched, the others nothing. `sinusoid` and
`tip_tracker`, `step` and `force_target` are the registry's factories ("sinusoid", "tip-tracker",
"step", "force-target").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from controllers.model.params import RobotParams, per_segment
from controllers.model.pcc import tip_jacobian, tip_position
from controllers.model.safe_set import ForceSafeSet
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import FilterContext


class NominalController(Protocol):
    """The minimal contract: callable as `nominal(t, q, qd) -> u_nom`; more is declared with a `capabilities`
    attribute (module docstring)."""

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
    capabilities = Capabilities(batched=True)  # nominal_batch: one call for B states (module docstring)

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

    def nominal_batch(self, t: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """B calls at once: t (B,) s → (B, N) hPa, the same arithmetic element by element."""
        return self._amp * np.sin((2.0 * math.pi * self.frequency * np.asarray(t, dtype=float))[:, None] + self._phase)


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
    capabilities = Capabilities()  # the minimal contract: called once per simulation

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
    capabilities = Capabilities()  # the minimal contract: called once per simulation

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


class ForceTargetNominal:
    """Regulate the model's predicted contact force to a target, as a lab would write it: a PI law
    through the pressure (docs/beyond-the-paper.md#contact-tasks).

    The predicted force is F̂ = max_j ψ(n_j(r(q̂))) (N), the largest facet force of the controller's
    model at the estimate q̂ (N,) rad (ψ, the facets and the PCC tip r from `safe_set` and the
    lengths (N,) m). With e = target_N − F̂ (N) and I = ∫ e dt (N·s, rectangle rule on the call
    times; the first call integrates nothing),

        u_nom = clip(k_p e + k_i I, u_lo, u_hi) · 1   (hPa on every segment),

    with I clamped after each step to [(u_lo − k_p e)/k_i, (u_hi − k_p e)/k_i] (anti-windup: the
    integral holds no more than the limits need, so a sign change of e moves u at once). Before contact F̂ = 0, so the integral ramps the pressure at k_i·target_N hPa/s
    until the tip presses; at steady state F̂ = target_N. Gains: the reference arm's measured
    steady gain on the paper plate is ≈ 8.4 mN/hPa beyond first contact (tools/force_levels.py: 0.048 N
    at 57.0 hPa, 0.192 N at 74.0 hPa on both segments), so k_i = 300 hPa/(N·s) closes the integral loop
    at ≈ 2.5 rad/s, a decade below the arm's ≈ 20 rad/s first mode and below the camera loop's 10 Hz,
    and k_p = 50 hPa/N adds ≈ 0.4 of proportional gain. Measured (tools/force_levels.py, unfiltered,
    target 0.096 N): the measured force settles at 0.094 N on mujoco_contact and camera_loop within 6 s. Stateful (the integral, the last call's time); a new run builds a new one.
    """

    capabilities = Capabilities()  # the minimal contract: one instance per simulation, called once per call

    def __init__(self, safe_set: ForceSafeSet, lengths: np.ndarray, n_segments: int, target_N: float,
                 kp: float, ki: float, u_lo: float, u_hi: float) -> None:
        for name, value in (("target_N", target_N), ("kp", kp), ("ki", ki)):
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
        if not (math.isfinite(u_lo) and math.isfinite(u_hi) and u_lo < u_hi):
            raise ValueError(f"the pressure range must be finite with u_lo < u_hi, got {u_lo!r}, {u_hi!r} hPa")
        self.safe_set, self.lengths, self.n = safe_set, np.asarray(lengths, dtype=float), n_segments
        self.target, self.kp, self.ki, self.lo, self.hi = float(target_N), float(kp), float(ki), float(u_lo), float(u_hi)
        self.integral, self.t_prev = 0.0, None

    def predicted_force(self, q: np.ndarray) -> float:
        """F̂ = max_j ψ(n_j(r(q))) (N)."""
        x, y = tip_position(np.asarray(q, dtype=float), self.lengths).tolist()
        return float(np.max(self.safe_set.force_at(x, y)))

    def __call__(self, t: float, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        error = self.target - self.predicted_force(q)
        dt = 0.0 if self.t_prev is None else max(float(t) - self.t_prev, 0.0)
        self.t_prev = float(t)
        self.integral += error * dt
        if self.ki > 0.0:  # clamping: the integral holds no more than the limits need
            proportional = self.kp * error
            self.integral = min(max(self.integral, (self.lo - proportional) / self.ki), (self.hi - proportional) / self.ki)
        u = min(max(self.kp * error + self.ki * self.integral, self.lo), self.hi)
        return np.full(self.n, u)


def force_target(context: FilterContext, target_N: float = 0.1, kp: float = 50.0, ki: float = 300.0) -> ForceTargetNominal:
    """Regulate the model's predicted force ψ(n(q̂)) to target_N by a PI law on the pressure (`ForceTargetNominal`);
    the same pressure on every segment, within the context's pressure limits (±150 hPa when it has none)."""
    lo = -150.0 if context.u_min is None else float(np.max(context.u_min))
    hi = 150.0 if context.u_max is None else float(np.min(context.u_max))
    return ForceTargetNominal(context.safe_set, context.robot.array("lengths"), context.robot.n_segments, target_N, kp, ki,
                              lo, hi)


force_target.parameter_docs = {"target_N": "target of the predicted force max_j psi(n_j); >= 0 [N]",
                               "kp": "proportional gain; >= 0 [hPa/N]", "ki": "integral gain; >= 0 [hPa/(N s)]"}
