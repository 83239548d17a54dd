"""B PCC plants integrated together (docs/model.md#rppr-dynamics, docs/model.md#one-implementation, docs/beyond-the-paper.md#batched-ground-truth).

Simulation b is `PCCPlant(params[b], safe_set, control_dt, integrator, physics_dt, tau_p, command_delay)`, for
any number of segments N: the same compiled kernel (`controllers.model.pcc_model.advance`, through
`softcbf_mj.physics.pcc_plant.PeriodIntegrator`) runs the period for every simulation, row by row in one
call, and a row's arithmetic does not depend on the others, so its states equal those of a
`PCCPlant` bit for bit (tested); the same zero-order hold, command delay (one δ for the batch, the
rows' FIFOs in one `CommandDelay`) and valve lag, and the same read-out
(segment ends, ψ(n) of the true tip per facet, u_applied = the acting pressure). The terms at
the reported states are kept in `self.dynamics` (`BatchDynamics.keep`), the plants' physics (what
they integrate): as `PCCPlant.dynamics`, the scenarios never hand it to a plug-in, and sharing it,
`CBFFilter(..., batch_dynamics=plant.dynamics)`, is for the testbed's own benchmarks of its built-in filter.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from controllers.model.dynamics_batch import BatchDynamics
from controllers.model.params import RobotParams
from controllers.model.safe_set import ForceSafeSet
from softcbf_mj.physics.pcc_plant import PeriodIntegrator, segment_ends
from softcbf_mj.physics.plant import BatchPlantState, CommandDelay, delay_periods


class PCCBatchPlant:
    """B PCC plants (module docstring): `reset(q0)` with q0 (B, N), then `step(u)` with u (B, N) hPa.

    `params`: one `RobotParams` for all simulations or one per simulation (length B, the same N).
    """

    def __init__(
        self,
        params: RobotParams | Sequence[RobotParams],
        safe_set: ForceSafeSet,
        n_sims: int,
        control_dt: float = 1e-3,
        integrator: str = "ros2",
        physics_dt: float | None = None,
        tau_p: float = 0.0,
        command_delay: float = 0.0,
    ) -> None:
        self.period = PeriodIntegrator(integrator, control_dt, physics_dt, tau_p)
        periods = delay_periods(command_delay, self.period.control_dt)
        self.command_delay = float(command_delay)
        if int(n_sims) != n_sims or n_sims < 1:
            raise ValueError(f"n_sims must be an integer >= 1, got {n_sims}")
        if not isinstance(params, RobotParams) and len(params) != n_sims:
            raise ValueError(f"params must be one RobotParams or n_sims = {n_sims} of them, got {len(params)}")
        self.n_sims = int(n_sims)
        self.params = params
        self.dynamics = BatchDynamics(params)  # the plants' physics and their terms at the reported states
        self.n_segments = n = self.dynamics.n
        self.delay = CommandDelay(periods, (self.n_sims, n)) if periods else None
        self.safe_set = safe_set
        self.control_dt, self.integrator = self.period.control_dt, integrator
        self.physics_dt, self.substeps, self.tau_p = self.period.physics_dt, self.period.substeps, self.period.tau_p
        normals, offsets = safe_set.environment.normals, safe_set.environment.offsets
        self._facets = list(zip(np.asarray(normals, dtype=float).tolist(), np.asarray(offsets, dtype=float).tolist()))
        self._x = np.zeros((self.n_sims, 2 * n))
        self._p = np.zeros((self.n_sims, n))
        self._kin = self._dyn = np.zeros((self.n_sims, 0))
        self._k = 0

    def _state(self, u: np.ndarray) -> BatchPlantState:
        n = self.n_segments
        ends = self._kin[:, self.dynamics.layout.ends]
        tip = ends[:, -1]
        x, y = tip.real, tip.imag
        penetration = np.column_stack([np.maximum(nx * x + ny * y - d, 0.0) for (nx, ny), d in self._facets])
        return BatchPlantState(
            t=np.full(self.n_sims, self._k * self.control_dt),
            q=self._x[:, :n].copy(),
            qd=self._x[:, n:].copy(),
            segment_ends=segment_ends(ends),
            contact_forces=self.safe_set.stiffness.force(penetration),
            u_applied=u,
        )

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None) -> BatchPlantState:
        """Every simulation b at q0[b] (rad), at rest or with rates qd0[b] (rad/s); (B, N) each."""
        shape = (self.n_sims, self.n_segments)
        q0 = np.asarray(q0, dtype=float)
        qd0 = np.zeros(shape) if qd0 is None else np.asarray(qd0, dtype=float)
        if q0.shape != shape or qd0.shape != shape:
            raise ValueError(f"q0 and qd0 must have shape {shape}, got {q0.shape} and {qd0.shape}")
        if not (np.all(np.isfinite(q0)) and np.all(np.isfinite(qd0))):
            raise ValueError("q0 and qd0 must be finite")
        self._x = np.ascontiguousarray(np.hstack((q0, qd0)))
        self._p = np.zeros(shape)
        terms = self.dynamics.terms(q0, qd0)
        self._kin, self._dyn = terms.kin.copy(), terms.dyn.copy()
        self._k = 0
        if self.delay is not None:
            self.delay.reset(np.zeros(shape))
        return self._state(np.zeros(shape))

    def step(self, u: np.ndarray) -> BatchPlantState:
        """Hold u[b] (hPa, (B, N), finite) on simulation b for one control period."""
        u = np.array(u, dtype=float)
        shape = (self.n_sims, self.n_segments)
        if u.shape != shape or not np.isfinite(u).all():
            raise ValueError(f"u must be finite with shape {shape}, got shape {u.shape}")
        if self.delay is not None:
            u = self.delay.apply(u)
        x, p, kin, dyn = self._x.copy(), self._p.copy(), self._kin.copy(), self._dyn.copy()
        self.period.run(x, u, p, self.dynamics.parameter_rows, kin, dyn, self._k * self.control_dt)
        self._x, self._kin, self._dyn = x, kin, dyn
        n = self.n_segments
        self.dynamics.keep(x[:, :n], x[:, n:], kin, dyn)
        self._p = p if self.tau_p > 0 else u
        self._k += 1
        return self._state(u if self.tau_p == 0 else self._p.copy())
