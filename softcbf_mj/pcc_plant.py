"""The paper's own simulation plant: the PCC model integrated in time (SPEC §3, §6).

State x = [q; q̇] ∈ R^{2N}; ẋ = F(x, u) = [q̇; q̈(q, q̇, u)] with
q̈ = M⁻¹(Λu − C q̇ − D q̇ − K q). The command u (hPa, (N,)) is held constant over
each control period (zero-order hold). Contact force per facet is ψ(n_i(r)) of the
true tip r: the environment does not push back in this plant, as in the paper.

Integrators (each a fixed step h = physics_dt dividing the control period):
- "ros2" (default): the two-stage, second-order, L-stable Rosenbrock method of
  Verwer et al. (1999), γ = 1 + 1/√2:
      k1 = W⁻¹ F(x_n),  k2 = W⁻¹ (F(x_n + h k1) − 2 k1),  x_{n+1} = x_n + h(3 k1 + k2)/2,
  with W = I − γ h J̃ and J̃ = [[0, I], [−M⁻¹K, −M⁻¹D]] at x_n, the part of ∂F/∂x that
  makes the model stiff (ROS2 keeps order 2 for any J̃, i.e. it is a W-method; the full
  analytic Jacobian costs 4× more and changed nothing measurable). L-stability matters:
  the reference robot has a fast mode near −3.7e3 s⁻¹ (SPEC §5), faster than the 1 ms
  control period, which this method damps at h = 1 ms.
- "rk4": classical Runge–Kutta (stable for h ≲ 0.7 ms on the reference robot).
- "euler": forward Euler, the paper's reference at h = 1e-5 s.
Agreement with the reference is measured by tools/integrator_check.py and tested.
"""

from __future__ import annotations

import math

import numpy as np

from controllers.dynamics import PCCDynamics
from controllers.params import RobotParams
from controllers.pcc import segment_ends
from controllers.safe_set import ForceSafeSet
from softcbf_mj.plant import PlantState, steps_per_control

INTEGRATORS = ("ros2", "rk4", "euler")
DEFAULT_PHYSICS_DT = {"ros2": 1e-3, "rk4": 1e-4, "euler": 1e-5}
_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


class PCCPlant:
    """PCC model as a plant: `reset(q0)`, then `step(u)` once per control period."""

    def __init__(
        self,
        params: RobotParams,
        safe_set: ForceSafeSet,
        control_dt: float = 1e-3,
        integrator: str = "ros2",
        physics_dt: float | None = None,
    ) -> None:
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {integrator!r}")
        self.params = params
        self.safe_set = safe_set
        self.dynamics = PCCDynamics(params)
        self.n_segments = params.n_segments
        self.control_dt = float(control_dt)
        self.integrator = integrator
        self.physics_dt = float(physics_dt if physics_dt is not None else DEFAULT_PHYSICS_DT[integrator])
        self.substeps = steps_per_control(self.control_dt, self.physics_dt)
        self._lengths = params.array("lengths")
        self._stiffness = params.array("stiffness")
        self._damping = params.array("damping")
        self._step_fn = {"ros2": self._ros2, "rk4": self._rk4, "euler": self._euler}[integrator]
        self._x = np.zeros(2 * self.n_segments)
        self._t = 0.0
        self._k = 0

    def _rhs(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        n = self.n_segments
        return np.concatenate((x[n:], self.dynamics.acceleration(x[:n], x[n:], u)))

    def _euler(self, x: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
        return x + h * self._rhs(x, u)

    def _rk4(self, x: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
        k1 = self._rhs(x, u)
        k2 = self._rhs(x + 0.5 * h * k1, u)
        k3 = self._rhs(x + 0.5 * h * k2, u)
        k4 = self._rhs(x + h * k3, u)
        return x + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)

    def _ros2(self, x: np.ndarray, u: np.ndarray, h: float) -> np.ndarray:
        # W k = r with W = [[I, −γhI], [γh M⁻¹K, I + γh M⁻¹D]] by block elimination:
        # (M + γh D + (γh)² K) k_v = M r_v − γh K r_q,  k_q = r_q + γh k_v.
        n = self.n_segments
        gh = _GAMMA * h
        qdd, mass = self.dynamics.acceleration_and_mass(x[:n], x[n:], u)
        schur_inv = np.linalg.inv(mass + np.diag(gh * self._damping + gh * gh * self._stiffness))

        def solve_w(r_q: np.ndarray, r_v: np.ndarray) -> np.ndarray:
            k_v = schur_inv @ (mass @ r_v - gh * self._stiffness * r_q)
            return np.concatenate((r_q + gh * k_v, k_v))

        k1 = solve_w(x[n:], qdd)
        f2 = self._rhs(x + h * k1, u)
        k2 = solve_w(f2[:n] - 2.0 * k1[:n], f2[n:] - 2.0 * k1[n:])
        return x + (0.5 * h) * (3.0 * k1 + k2)

    def _state(self, u: np.ndarray) -> PlantState:
        n = self.n_segments
        q, qd = self._x[:n].copy(), self._x[n:].copy()
        ends = segment_ends(q, self._lengths)
        return PlantState(
            t=self._t,
            q=q,
            qd=qd,
            segment_ends=ends,
            contact_forces=self.safe_set.force(ends[-1]),
            u_applied=u,
        )

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> PlantState:
        q0 = np.asarray(q0, dtype=float).reshape(-1)
        qd0 = np.zeros_like(q0) if qd0 is None else np.asarray(qd0, dtype=float).reshape(-1)
        if q0.shape != (self.n_segments,) or qd0.shape != (self.n_segments,):
            raise ValueError(f"q0 and qd0 must have shape ({self.n_segments},), got {q0.shape} and {qd0.shape}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError(f"q0 and qd0 must be finite, got q0={q0}, qd0={qd0}")
        self._x = np.concatenate((q0, qd0))
        self._t, self._k = 0.0, 0
        return self._state(np.zeros(self.n_segments))

    def step(self, u: np.ndarray) -> PlantState:
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape != (self.n_segments,) or not np.all(np.isfinite(u)):
            raise ValueError(f"u must be finite with shape ({self.n_segments},), got {u}")
        x, h = self._x, self.physics_dt
        for _ in range(self.substeps):
            x = self._step_fn(x, u, h)
        if not np.all(np.isfinite(x)):
            raise FloatingPointError(
                f"PCC plant diverged at t={self._t:.4f} s with integrator {self.integrator!r} and "
                f"physics_dt={h:g} s; use integrator='ros2' or a smaller physics_dt"
            )
        self._x = x
        self._k += 1
        self._t = self._k * self.control_dt
        return self._state(u.copy())
