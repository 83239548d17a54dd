"""The paper's own simulation plant: the PCC model integrated in time (docs/model.md#rppr-dynamics, docs/model.md#nominal-controller-and-the-papers-scenario).

State x = [q; q̇] ∈ R^{2N}; ẋ = F(x, u) = [q̇; q̈(q, q̇, u)] with
q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q). The command u (hPa, (N,)) is held constant over
each control period (zero-order hold). Contact force per facet is ψ(n_i(r)) of the
true tip r: the environment does not push back in this plant, as in the paper.

Valves (`tau_p`, s; default 0, the paper's ideal valve): the pressure p acting on the
arm follows the command with a first-order lag, ṗ = (u − p)/τ_p, from p = 0 at `reset`.
Over each physics step of length h, p is advanced exactly,
p(h) = u + (p(0) − u) e^{−h/τ_p}, and the arm is integrated with p held at its exact
mean over the step, u + (p(0) − u)(τ_p/h)(1 − e^{−h/τ_p}), which keeps the integrator's
order (tests/test_pcc_plant.py compares it with a fine Euler reference).
`PlantState.u_applied` is p at the end of the period.

Command delay (`command_delay`, s; default 0): the command reaches the valves δ / control_dt
control periods later, a FIFO of whole periods filled with 0 at `reset` (`softcbf_mj.physics.plant`,
`CommandDelay`): the valves, and with `tau_p` = 0 the arm, see over period j the command of
period j − k; `u_applied` is then that command (or p).

Integrators (each a fixed step h = physics_dt dividing the control period):
- "ros2" (default): the two-stage, second-order, L-stable Rosenbrock method of
  Verwer et al. (1999), γ = 1 + 1/√2:
      k1 = W⁻¹ F(x_n),  k2 = W⁻¹ (F(x_n + h k1) − 2 k1),  x_{n+1} = x_n + h(3 k1 + k2)/2,
  with W = I − γ h J̃ and J̃ = [[0, I], [−M⁻¹K, −M⁻¹D]] at x_n, the part of ∂F/∂x that
  makes the model stiff (ROS2 keeps order 2 for any J̃, i.e. it is a W-method; the full
  analytic Jacobian costs 4× more and changed nothing measurable). L-stability matters:
  the reference robot has a fast mode near −3.7e3 s⁻¹ (docs/model.md#rppr-dynamics), faster than the 1 ms
  control period, which this method damps at h = 1 ms.
- "rk4": classical Runge–Kutta (stable for h ≲ 0.7 ms on the reference robot).
- "euler": forward Euler, the paper's reference at h = 1e-5 s.
Agreement with the reference is measured by tools/integrator_check.py and tested.

Every integrator runs inside the compiled kernel `controllers.model.pcc_model.advance` (one call per
control period, any N), the one implementation that `softcbf_mj.physics.pcc_batch_plant` runs for B
plants; `PeriodIntegrator` holds the constants both plants pass to it.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from controllers.model.dynamics import PCCDynamics
from controllers.model.params import RobotParams
from controllers.model.pcc_model import INTEGRATOR_CODES, ROS2_GAMMA, advance
from controllers.model.safe_set import ForceSafeSet
from softcbf_mj.physics.plant import CommandDelay, PlantState, delay_periods, steps_per_control

INTEGRATORS = tuple(INTEGRATOR_CODES)
DEFAULT_PHYSICS_DT = {"ros2": 1e-3, "rk4": 1e-4, "euler": 1e-5}
__all__ = ["DEFAULT_PHYSICS_DT", "INTEGRATORS", "PCCPlant", "PeriodIntegrator", "ROS2_GAMMA"]


class PeriodIntegrator:
    """One control period of B PCC states through `pcc_model.advance` (module docstring).

    integrator: "ros2", "rk4" or "euler"; physics_dt (s, None: the integrator's default) divides
    control_dt (s); tau_p: the valves' time constant (s, 0: ideal valve).
    """

    def __init__(self, integrator: str, control_dt: float, physics_dt: float | None, tau_p: float) -> None:
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {integrator!r}")
        if not (math.isfinite(tau_p) and tau_p >= 0):
            raise ValueError(f"tau_p must be finite and >= 0 s (0: ideal valve), got {tau_p}")
        self.integrator = integrator
        self.control_dt = float(control_dt)
        self.physics_dt = float(physics_dt if physics_dt is not None else DEFAULT_PHYSICS_DT[integrator])
        self.substeps = steps_per_control(self.control_dt, self.physics_dt)
        self.tau_p = float(tau_p)
        # Per physics step: p ← u + (p − u)·decay; the arm sees u + (p − u)·mean (exact mean over the step).
        h = self.physics_dt
        self.lag = (math.exp(-h / tau_p), tau_p / h * -math.expm1(-h / tau_p)) if tau_p > 0 else (-1.0, 0.0)
        self._method = INTEGRATOR_CODES[integrator]

    def run(self, x: np.ndarray, u: np.ndarray, pressure: np.ndarray, params: np.ndarray, kin: np.ndarray,
            dyn: np.ndarray, t: float) -> None:
        """Advance the states x (B, 2N) under the commands u (B, N) hPa held for one period, in place (with
        the acting pressures (B, N) and the model rows kin, dyn at x); t: the period's start (s), for the error.

        Raises FloatingPointError naming the simulations that left the finite numbers.
        """
        decay, mean = self.lag
        diverged = advance(self._method, x, u, pressure, params, kin, dyn, self.physics_dt, self.substeps, decay, mean)
        if diverged.any():
            raise FloatingPointError(
                f"PCC plant diverged at t={t:.4f} s in simulations {np.flatnonzero(diverged).tolist()} with integrator "
                f"{self.integrator!r} and physics_dt={self.physics_dt:g} s; use integrator='ros2' or a smaller physics_dt")


def segment_ends(ends: np.ndarray) -> np.ndarray:
    """Segment ends p_1..p_N as complex (..., N) → the (..., N+1, 2) array p_0 = 0, p_1, …, p_N (m)."""
    out = np.zeros(ends.shape[:-1] + (ends.shape[-1] + 1, 2))
    out[..., 1:, 0], out[..., 1:, 1] = ends.real, ends.imag
    return out


class PCCPlant:
    """PCC model as a plant: `reset(q0)`, then `step(u)` once per control period.

    One `pcc_model.advance` call per period (B = 1); `step` checks u once. The model terms at the
    current state come back from the kernel and serve its report (segment ends, contact force)
    and, kept in `self.dynamics` (`PCCDynamics.keep`), the next step.

    `self.dynamics` is the plant's physics: its `parameter_rows` are what the plant integrates.
    The scenarios never hand it to a plug-in (a filter builds its own model from the robot it is
    told, `controllers.contract.safety_filter.FilterContext`); sharing it, `CBFFilter(..., dynamics=plant.dynamics)`,
    saves one evaluation of the model per period and is for the testbed's own benchmarks and tests
    of its built-in filter only.
    """

    def __init__(
        self,
        params: RobotParams,
        safe_set: ForceSafeSet,
        control_dt: float = 1e-3,
        integrator: str = "ros2",
        physics_dt: float | None = None,
        tau_p: float = 0.0,
        command_delay: float = 0.0,
    ) -> None:
        self.period = PeriodIntegrator(integrator, control_dt, physics_dt, tau_p)
        periods = delay_periods(command_delay, self.period.control_dt)
        self.command_delay = float(command_delay)
        self.delay = CommandDelay(periods, (1, params.n_segments)) if periods else None
        self.params = params
        self.safe_set = safe_set
        self.dynamics = PCCDynamics(params)
        self.n_segments = params.n_segments
        self.control_dt, self.integrator = self.period.control_dt, integrator
        self.physics_dt, self.substeps, self.tau_p = self.period.physics_dt, self.period.substeps, self.period.tau_p
        self._x = np.zeros((1, 2 * self.n_segments))
        self._p = np.zeros((1, self.n_segments))
        self._kin = self._dyn = np.zeros((1, 0))
        self._t = 0.0
        self._k = 0

    def _state(self, u: np.ndarray) -> PlantState:
        n, x = self.n_segments, self._x[0]
        ends = self._kin[0, self.dynamics.layout.ends]
        tip = ends[-1]
        return PlantState(
            t=self._t,
            q=x[:n].copy(),
            qd=x[n:].copy(),
            segment_ends=segment_ends(ends),
            contact_forces=self.safe_set.force_at(tip.real, tip.imag),
            u_applied=u,
        )

    def _keep(self) -> None:
        """Keep the terms at the current state in `self.dynamics` (the next step starts from them)."""
        n, x = self.n_segments, self._x[0].tolist()
        self.dynamics.keep(x[:n], x[n:], self._kin[0], self._dyn[0])

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> PlantState:
        q0 = np.asarray(q0, dtype=float).reshape(-1)
        qd0 = np.zeros_like(q0) if qd0 is None else np.asarray(qd0, dtype=float).reshape(-1)
        if q0.shape != (self.n_segments,) or qd0.shape != (self.n_segments,):
            raise ValueError(f"q0 and qd0 must have shape ({self.n_segments},), got {q0.shape} and {qd0.shape}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError(f"q0 and qd0 must be finite, got q0={q0}, qd0={qd0}")
        self._x = np.concatenate((q0, qd0))[None, :]
        self._p = np.zeros((1, self.n_segments))
        core = self.dynamics.model_terms(q0.tolist(), qd0.tolist())
        self._kin, self._dyn = core.kin[None, :].copy(), core.dyn[None, :].copy()
        self._keep()
        self._t, self._k = 0.0, 0
        if self.delay is not None:
            self.delay.reset(np.zeros((1, self.n_segments)))
        return self._state(np.zeros(self.n_segments))

    def step(self, u: np.ndarray) -> PlantState:
        u = np.array(u, dtype=float).reshape(-1)
        if u.shape != (self.n_segments,) or not np.all(np.isfinite(u)):
            raise ValueError(f"u must be finite with shape ({self.n_segments},), got {u}")
        if self.delay is not None:
            u = self.delay.apply(u[None, :])[0]
        x, p, kin, dyn = self._x.copy(), self._p.copy(), self._kin.copy(), self._dyn.copy()
        self.period.run(x, u[None, :], p, self.dynamics.parameter_rows, kin, dyn, self._t)
        self._x, self._kin, self._dyn = x, kin, dyn
        self._keep()
        self._p = p if self.tau_p > 0 else u[None, :]
        self._k += 1
        self._t = self._k * self.control_dt
        return self._state(u if self.tau_p == 0 else self._p[0].copy())  # ideal valve: p = u
