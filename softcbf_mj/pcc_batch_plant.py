"""B PCC plants integrated together (numpy over the batch; docs/model.md#rppr-dynamics, docs/model.md#nominal-controller-and-the-papers-scenario, docs/beyond-the-paper.md#batched-ground-truth).

Simulation b is `PCCPlant(params[b], safe_set, control_dt, integrator, physics_dt)`:
the same model (`controllers.dynamics_batch.BatchDynamics`, the scalar per-step path's
operations applied elementwise to (B,) arrays), the same integrators written in the
same operation order as `PCCPlant` ("ros2": `PCCPlant._ros2_2`, the unrolled N = 2
Rosenbrock step; "rk4"; "euler"), the same zero-order hold and the same read-out
(segment ends, ψ(n) of the true tip per facet, u_applied = u). Its states therefore
equal those of B `PCCPlant`s bit for bit (tested), for N = 2 segments.

One control period is `substeps` integrator steps, each a few dozen numpy operations
on (B,) arrays: the cost per step is nearly independent of B up to a few hundred
simulations, which is where the batch's speed-up comes from.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from controllers.dynamics_batch import BatchDynamics, BatchTerms
from controllers.params import RobotParams
from controllers.safe_set import ForceSafeSet
from softcbf_mj.pcc_plant import DEFAULT_PHYSICS_DT, INTEGRATORS, ROS2_GAMMA
from softcbf_mj.plant import BatchPlantState, steps_per_control

State = list[np.ndarray]  # [q_1, q_2, q̇_1, q̇_2], each (B,)


class PCCBatchPlant:
    """B PCC plants (module docstring): `reset(q0)` with q0 (B, 2), then `step(u)` with u (B, 2) hPa.

    `params`: one `RobotParams` for all simulations or one per simulation (length B).
    """

    def __init__(
        self,
        params: RobotParams | Sequence[RobotParams],
        safe_set: ForceSafeSet,
        n_sims: int,
        control_dt: float = 1e-3,
        integrator: str = "ros2",
        physics_dt: float | None = None,
    ) -> None:
        if integrator not in INTEGRATORS:
            raise ValueError(f"integrator must be one of {', '.join(INTEGRATORS)}, got {integrator!r}")
        if int(n_sims) != n_sims or n_sims < 1:
            raise ValueError(f"n_sims must be an integer >= 1, got {n_sims}")
        if not isinstance(params, RobotParams) and len(params) != n_sims:
            raise ValueError(f"params must be one RobotParams or n_sims = {n_sims} of them, got {len(params)}")
        self.n_sims = int(n_sims)
        self.dynamics = BatchDynamics(params)
        self.safe_set = safe_set
        self.n_segments = 2
        self.control_dt = float(control_dt)
        self.integrator = integrator
        self.physics_dt = float(physics_dt if physics_dt is not None else DEFAULT_PHYSICS_DT[integrator])
        self.substeps = steps_per_control(self.control_dt, self.physics_dt)
        gh = ROS2_GAMMA * self.physics_dt
        (d0, d1), (k0, k1) = self.dynamics.damping, self.dynamics.stiffness
        self._gh, self._gh_stiffness = gh, (gh * k0, gh * k1)
        self._schur_diag = (gh * d0 + gh * gh * k0, gh * d1 + gh * gh * k1)
        self._step_fn = {"ros2": self._ros2, "rk4": self._rk4, "euler": self._euler}[integrator]
        normals, offsets = safe_set.environment.normals, safe_set.environment.offsets
        self._facets = [(float(nx), float(ny), float(d)) for (nx, ny), d in zip(normals, offsets)]
        self._x: State = []
        self._terms: BatchTerms | None = None
        self._k = 0

    def _at(self, x: State) -> BatchTerms:
        return self.dynamics.terms(np.column_stack(x[:2]), np.column_stack(x[2:]))

    def _rhs(self, x: State, terms: BatchTerms, u: np.ndarray) -> State:
        return [x[2], x[3], *self.dynamics.acceleration(terms, u)]

    def _euler(self, x: State, terms: BatchTerms, u: np.ndarray, h: float) -> State:
        return [xi + h * fi for xi, fi in zip(x, self._rhs(x, terms, u))]

    def _rk4(self, x: State, terms: BatchTerms, u: np.ndarray, h: float) -> State:
        k1 = self._rhs(x, terms, u)
        x2 = [xi + 0.5 * h * k for xi, k in zip(x, k1)]
        k2 = self._rhs(x2, self._at(x2), u)
        x3 = [xi + 0.5 * h * k for xi, k in zip(x, k2)]
        k3 = self._rhs(x3, self._at(x3), u)
        x4 = [xi + h * k for xi, k in zip(x, k3)]
        k4 = self._rhs(x4, self._at(x4), u)
        return [xi + (h / 6.0) * (a + 2.0 * b + 2.0 * c + d) for xi, a, b, c, d in zip(x, k1, k2, k3, k4)]

    def _ros2(self, x: State, terms: BatchTerms, u: np.ndarray, h: float) -> State:
        """`PCCPlant._ros2_2` over the batch: the same operations in the same order."""
        gh, (ghk0, ghk1), (sd0, sd1) = self._gh, self._gh_stiffness, self._schur_diag
        m00, m01, m11 = terms.mass
        a, b, c, d = m00 + sd0, m01, m01, m11 + sd1
        det = a * d - b * c
        s00, s01, s10, s11 = d / det, -b / det, -c / det, a / det
        q0, q1, v0, v1 = x

        def solve_w(rq0, rq1, rv0, rv1):
            r0 = m00 * rv0 + m01 * rv1 - ghk0 * rq0
            r1 = m01 * rv0 + m11 * rv1 - ghk1 * rq1
            kv0, kv1 = s00 * r0 + s01 * r1, s10 * r0 + s11 * r1
            return rq0 + gh * kv0, rq1 + gh * kv1, kv0, kv1

        acc0, acc1 = self.dynamics.acceleration(terms, u)
        k1 = solve_w(v0, v1, acc0, acc1)
        x2 = [q0 + h * k1[0], q1 + h * k1[1], v0 + h * k1[2], v1 + h * k1[3]]
        acc0, acc1 = self.dynamics.acceleration(self._at(x2), u)
        k2 = solve_w(x2[2] - 2.0 * k1[0], x2[3] - 2.0 * k1[1], acc0 - 2.0 * k1[2], acc1 - 2.0 * k1[3])
        return [xi + (0.5 * h) * (3.0 * k1i + k2i) for xi, k1i, k2i in zip(x, k1, k2)]

    def _state(self, u: np.ndarray) -> BatchPlantState:
        terms = self._terms
        (p1, tip) = terms.ends
        ends = np.zeros((self.n_sims, 3, 2))
        ends[:, 1, 0], ends[:, 1, 1], ends[:, 2, 0], ends[:, 2, 1] = p1[0], p1[1], tip[0], tip[1]
        penetration = np.column_stack([np.maximum(nx * tip[0] + ny * tip[1] - d, 0.0) for nx, ny, d in self._facets])
        return BatchPlantState(
            t=np.full(self.n_sims, self._k * self.control_dt),
            q=np.column_stack(self._x[:2]),
            qd=np.column_stack(self._x[2:]),
            segment_ends=ends,
            contact_forces=self.safe_set.stiffness.force(penetration),
            u_applied=u,
        )

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> BatchPlantState:
        """Every simulation b at q0[b] (rad), at rest or with rates qd0[b] (rad/s); (B, 2) each."""
        shape = (self.n_sims, 2)
        q0 = np.asarray(q0, dtype=float)
        qd0 = np.zeros(shape) if qd0 is None else np.asarray(qd0, dtype=float)
        if q0.shape != shape or qd0.shape != shape:
            raise ValueError(f"q0 and qd0 must have shape {shape}, got {q0.shape} and {qd0.shape}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError("q0 and qd0 must be finite")
        self._x = [q0[:, 0].copy(), q0[:, 1].copy(), qd0[:, 0].copy(), qd0[:, 1].copy()]
        self._terms = self._at(self._x)
        self._k = 0
        return self._state(np.zeros(shape))

    def step(self, u: np.ndarray) -> BatchPlantState:
        """Hold u[b] (hPa, (B, 2), finite) on simulation b for one control period."""
        u = np.array(u, dtype=float)
        if u.shape != (self.n_sims, 2) or not np.all(np.isfinite(u)):
            raise ValueError(f"u must be finite with shape ({self.n_sims}, 2), got shape {u.shape}")
        x, terms, h = self._x, self._terms, self.physics_dt
        with np.errstate(all="ignore"):  # a diverging simulation is reported below, by index
            for _ in range(self.substeps):
                x = self._step_fn(x, terms, u, h)
                finite = np.isfinite(x[0]) & np.isfinite(x[1]) & np.isfinite(x[2]) & np.isfinite(x[3])
                if not finite.all():
                    t = self._k * self.control_dt
                    raise FloatingPointError(
                        f"PCC plant diverged at t={t:.4f} s in simulations {np.flatnonzero(~finite).tolist()} with "
                        f"integrator {self.integrator!r} and physics_dt={h:g} s; use integrator='ros2' or a smaller physics_dt"
                    )
                terms = self._at(x)
        self._x, self._terms = x, terms
        self._k += 1
        return self._state(u)
