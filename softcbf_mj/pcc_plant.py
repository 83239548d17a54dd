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
"""

from __future__ import annotations

import math
from operator import mul

import numpy as np

from controllers.dynamics import PCCDynamics, ModelTerms, spd_inverse
from controllers.params import RobotParams
from controllers.pcc import ends_array
from controllers.safe_set import ForceSafeSet
from softcbf_mj.plant import PlantState, steps_per_control

INTEGRATORS = ("ros2", "rk4", "euler")
DEFAULT_PHYSICS_DT = {"ros2": 1e-3, "rk4": 1e-4, "euler": 1e-5}
ROS2_GAMMA = 1.0 + 1.0 / math.sqrt(2.0)


class PCCPlant:
    """PCC model as a plant: `reset(q0)`, then `step(u)` once per control period.

    The integrators work on Python float lists through the unchecked per-step path of
    `PCCDynamics` (numpy's per-call overhead dominates at N ≈ 2; for N = 2 the ROS2 step
    is unrolled, giving the same floats); `step` checks u once. The model terms at the
    current state (`PCCDynamics.model_terms`) are computed once, when the state is reached, and serve its
    report (segment ends, contact force), the next step and, through `self.dynamics`, a
    filter built with `CBFFilter(..., dynamics=plant.dynamics)`.
    """

    def __init__(
        self,
        params: RobotParams,
        safe_set: ForceSafeSet,
        control_dt: float = 1e-3,
        integrator: str = "ros2",
        physics_dt: float | None = None,
        tau_p: float = 0.0,
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
        if not (math.isfinite(tau_p) and tau_p >= 0):
            raise ValueError(f"tau_p must be finite and >= 0 s (0: ideal valve), got {tau_p}")
        self.tau_p = float(tau_p)
        # Per physics step: p ← u + (p − u)·decay; the arm sees u + (p − u)·mean (exact mean over the step).
        self._lag = (math.exp(-self.physics_dt / tau_p), tau_p / self.physics_dt * -math.expm1(-self.physics_dt / tau_p)) if tau_p > 0 else None
        self._p: list[float] = []
        self._gh = gh = ROS2_GAMMA * self.physics_dt  # ROS2's γh and the W-solve's γh·k_i, γh·d_i + (γh)²·k_i
        self._gh_stiffness = [gh * k for k in params.stiffness]
        self._schur_diag = [gh * d + gh * gh * k for d, k in zip(params.damping, params.stiffness)]
        ros2 = self._ros2_2 if self.n_segments == 2 else self._ros2
        self._step_fn = {"ros2": ros2, "rk4": self._rk4, "euler": self._euler}[integrator]
        self._x: list[float] = []
        self._terms: ModelTerms | None = None  # the dynamics' terms at self._x
        self._t = 0.0
        self._k = 0

    def _at(self, x: list[float]) -> ModelTerms:
        """The dynamics' per-step terms at x (`PCCDynamics.model_terms`)."""
        n = self.n_segments
        return self.dynamics.model_terms(x[:n], x[n:])

    def _rhs(self, x: list[float], core: ModelTerms, u: list[float]) -> list[float]:
        """F(x, u) = [q̇; q̈] with `core` the terms at x."""
        return x[self.n_segments :] + self.dynamics.acceleration_from_terms(core, u)

    def _euler(self, x: list[float], core: ModelTerms, u: list[float], h: float) -> list[float]:
        return [xi + h * fi for xi, fi in zip(x, self._rhs(x, core, u))]

    def _rk4(self, x: list[float], core: ModelTerms, u: list[float], h: float) -> list[float]:
        k1 = self._rhs(x, core, u)
        x2 = [xi + 0.5 * h * k for xi, k in zip(x, k1)]
        k2 = self._rhs(x2, self._at(x2), u)
        x3 = [xi + 0.5 * h * k for xi, k in zip(x, k2)]
        k3 = self._rhs(x3, self._at(x3), u)
        x4 = [xi + h * k for xi, k in zip(x, k3)]
        k4 = self._rhs(x4, self._at(x4), u)
        return [xi + (h / 6.0) * (a + 2.0 * b + 2.0 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4)]

    def _ros2(self, x: list[float], core: ModelTerms, u: list[float], h: float) -> list[float]:
        # W k = r with W = [[I, −γhI], [γh M⁻¹K, I + γh M⁻¹D]] by block elimination:
        # (M + γh D + (γh)² K) k_v = M r_v − γh K r_q,  k_q = r_q + γh k_v  (h = physics_dt).
        n = self.n_segments
        mass = core.mass
        schur_inv = spd_inverse([[m + s if j == l else m for l, m in enumerate(row)]
                                  for j, (row, s) in enumerate(zip(mass, self._schur_diag))])
        k1 = self._solve_w(mass, schur_inv, x[n:], self.dynamics.acceleration_from_terms(core, u))
        x2 = [xi + h * k for xi, k in zip(x, k1)]
        r2 = [f - 2.0 * k for f, k in zip(self._rhs(x2, self._at(x2), u), k1)]
        k2 = self._solve_w(mass, schur_inv, r2[:n], r2[n:])
        return [xi + (0.5 * h) * (3.0 * a + b) for xi, a, b in zip(x, k1, k2)]

    def _solve_w(self, mass: list[list[float]], schur_inv: list[list[float]], r_q: list[float], r_v: list[float]) -> list[float]:
        """k = W⁻¹ [r_q; r_v] (see `_ros2`)."""
        rhs = [sum(map(mul, row, r_v)) - c * r for row, c, r in zip(mass, self._gh_stiffness, r_q)]
        k_v = [sum(map(mul, row, rhs)) for row in schur_inv]
        return [r + self._gh * k for r, k in zip(r_q, k_v)] + k_v

    def _ros2_2(self, x: list[float], core: ModelTerms, u: list[float], h: float) -> list[float]:
        """`_ros2` for N = 2 unrolled: the same operations in the same order (tested), a third of the cost."""
        gh, (ghk0, ghk1), (sd0, sd1) = self._gh, self._gh_stiffness, self._schur_diag
        g0, g1 = self.params.gains  # Λ
        (m00, m01), (m10, m11) = core.mass
        a, b, c, d = m00 + sd0, m01, m10, m11 + sd1  # Schur complement M + γhD + (γh)²K, inverted as `spd_inverse`
        det = a * d - b * c
        s00, s01, s10, s11 = d / det, -b / det, -c / det, a / det
        q0, q1, v0, v1 = x

        def solve_w(rq0: float, rq1: float, rv0: float, rv1: float) -> tuple[float, float, float, float]:
            r0 = m00 * rv0 + m01 * rv1 - ghk0 * rq0
            r1 = m10 * rv0 + m11 * rv1 - ghk1 * rq1
            kv0, kv1 = s00 * r0 + s01 * r1, s10 * r0 + s11 * r1
            return rq0 + gh * kv0, rq1 + gh * kv1, kv0, kv1

        ((n00, n01), (n10, n11)), (f0, f1) = core.mass_inv, core.force
        t0, t1 = g0 * u[0] - f0, g1 * u[1] - f1  # q̈ = M⁻¹(Λu − f) as `PCCDynamics.acceleration_from_terms`
        k1 = solve_w(v0, v1, n00 * t0 + n01 * t1, n10 * t0 + n11 * t1)
        x2 = [q0 + h * k1[0], q1 + h * k1[1], v0 + h * k1[2], v1 + h * k1[3]]
        core2 = self._at(x2)
        ((n00, n01), (n10, n11)), (f0, f1) = core2.mass_inv, core2.force
        t0, t1 = g0 * u[0] - f0, g1 * u[1] - f1
        k2 = solve_w(x2[2] - 2.0 * k1[0], x2[3] - 2.0 * k1[1],
                     n00 * t0 + n01 * t1 - 2.0 * k1[2], n10 * t0 + n11 * t1 - 2.0 * k1[3])
        return [xi + (0.5 * h) * (3.0 * k1i + k2i) for xi, k1i, k2i in zip(x, k1, k2)]

    def _state(self, u: np.ndarray) -> PlantState:
        n, x, tip = self.n_segments, self._x, self._terms.kin.ends[-1]
        return PlantState(
            t=self._t,
            q=np.array(x[:n]),
            qd=np.array(x[n:]),
            segment_ends=ends_array(self._terms.kin.ends),
            contact_forces=self.safe_set.force_at(tip.real, tip.imag),
            u_applied=u,
        )

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> PlantState:
        q0 = np.asarray(q0, dtype=float).reshape(-1)
        qd0 = np.zeros_like(q0) if qd0 is None else np.asarray(qd0, dtype=float).reshape(-1)
        if q0.shape != (self.n_segments,) or qd0.shape != (self.n_segments,):
            raise ValueError(f"q0 and qd0 must have shape ({self.n_segments},), got {q0.shape} and {qd0.shape}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError(f"q0 and qd0 must be finite, got q0={q0}, qd0={qd0}")
        self._x = q0.tolist() + qd0.tolist()
        self._p = [0.0] * self.n_segments
        self._terms = self._at(self._x)
        self._t, self._k = 0.0, 0
        return self._state(np.zeros(self.n_segments))

    def step(self, u: np.ndarray) -> PlantState:
        u = np.array(u, dtype=float).reshape(-1)
        u_list = u.tolist()
        if u.shape != (self.n_segments,) or not all(map(math.isfinite, u_list)):
            raise ValueError(f"u must be finite with shape ({self.n_segments},), got {u}")
        x, core, h, p = self._x, self._terms, self.physics_dt, self._p
        for _ in range(self.substeps):
            acting = u_list
            if self._lag is not None:
                decay, mean = self._lag
                acting = [v + (pi - v) * mean for v, pi in zip(u_list, p)]
                p = [v + (pi - v) * decay for v, pi in zip(u_list, p)]
            try:
                x = self._step_fn(x, core, acting, h)
            except (OverflowError, ValueError):  # math.sin or cmath.exp of ±inf inside a stage
                x = [math.nan]
            if not all(map(math.isfinite, x)):
                raise FloatingPointError(
                    f"PCC plant diverged at t={self._t:.4f} s with integrator {self.integrator!r} and "
                    f"physics_dt={h:g} s; use integrator='ros2' or a smaller physics_dt"
                )
            core = self._at(x)
        self._x, self._terms = x, core
        self._p = p if self._lag is not None else u_list
        self._k += 1
        self._t = self._k * self.control_dt
        return self._state(u if self._lag is None else np.array(self._p))  # ideal valve: p = u
