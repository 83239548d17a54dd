"""Backup CBF (`backup-cbf`): keep a verified way back to a safe set, vent or hold, in reach at every call.

The backup-set method (Gurriet, Singletary, Reher, Ciarletta, Feron & Ames 2018; Chen, Jankovic, Santillo
& Ames 2021) in its switching form: a candidate command is sent only if the model, integrated from the
current state under that command for one control period and then under the backup controller, stays
inside P and reaches a backup set S_b, forward invariant under the backup controller and inside P, within
the horizon T_b. Shapes: N inputs (hPa), P' rows of P = {r | H' r ≤ h'}.

Backup controllers (`backup`): "vent" holds u_b = 0 (the valves open, the arm relaxes to its straight
rest shape); "hold" holds u_b = the command sent last (at the first call after `reset()`: 0).

Backup set. For a held command v with rest shape q_v = K⁻¹Λv (rad), the energy

    W_v(x) = ½ q̇ᵀ M(q) q̇ + ½ (q − q_v)ᵀ K (q − q_v)                    (J)

does not grow while v is held: Ẇ_v = −q̇ᵀ D q̇ ≤ 0 (Ṁ − 2C skew-symmetric; Λv = K q_v; no gravity;
ideal valve). To leave P the tip must cross P's boundary, where ½(q − q_v)ᵀK(q − q_v) ≥ Γ^∂(v) = min_j
min {½(q − q_v)ᵀK(q − q_v) : H'_j r(q) = h'_j}. Hence

    S_v = {x : tip inside P, W_v(x) < Γ̲(v)},   Γ̲(v) = min_j ½ δ_j(v)² ≤ Γ^∂(v)

is forward invariant under v held and lies inside P; Γ̲ is the grid-free lower bound of
`controllers.energy.escape_energy.BoundaryDistanceBound` (any N). For "vent" S_b = S_0; for "hold", the
candidate u itself is held after its period (the backup holds what was sent), S_b = S_u.

Each call, with ū = u_nom clipped to the box and u_b the backup command now (0, or the last command):
1. Candidates u_θ = u_b + θ (ū − u_b) for θ in 1, 1/2, …, 2^{−(levels−1)} and 0.
2. Each is rolled out on the filter's model with the PCC plant's integrator (`pcc_model.advance`,
   ROS2, steps of ≤ ROLLOUT_STEP_S, the candidates as one batch): u_θ for one period T, then the
   backup (0 for vent; u_θ itself for hold) until the state is in S_b or T + T_b (`horizon_s`) has
   passed. It is verified if b_i = h'_i − H'_i r ≥ 0 at every step and the state enters S_b.
3. The largest verified θ is sent ("nominal" for θ = 1, "blend" for 0 < θ < 1, "backup" for θ = 0).
   None verified: u_b is sent and `infeasible` flagged ("unverified").

Guarantee (by induction): if the command sent at t_k was verified, the backup from x_{k+1} follows
the verified trajectory's tail, which stays in P and enters the invariant S_b: the candidate θ = 0 at
t_{k+1} is verified again (its horizon shortens by T, but once in S_b it stays there), so from the
first verified call on, the tip never leaves P and some verified command always exists. Assumptions:
the model is the plant (M, C, D, K, Λ, kinematics; the PCC plant with the same integrator and step),
the state is exact and sampled every T = `context.control_dt` with the command held, the valve ideal
(no pressure lag: with one, W_v lacks the pressure's energy), b checked at the integrator's steps
(not between them), and the first call's state has some verified candidate (it is at rest inside
S_b, or the horizon reaches it). Cost: up to (levels + 1) rollouts of T + T_b per call, stopped as
soon as the first candidate (θ = 1) is verified or every candidate is decided.
Γ̲ is tight near P's boundary and loose far from it, so S_b is small around a rest shape far inside P
(Γ̲(0) = 0.057 J on the reference arm, 0.0038 J on models/robots/three_segment.json): holding a
command whose rest shape nears P is then not verified from rest and the filter blends (three
segments, from rest straight: +10 hPa is blended, +40 hPa gets the backup).
Measured on `softcbf run paper_sim --filter backup-cbf --filter-param backup=vent|hold --duration 5
--frequency 0.1` (PCC plant = model, 1 kHz, no limits): the tip rides P's boundary, ρ_min +2e-8 (vent) and
+1.0e-4 (hold), the force reaching F_max (0.160 N), u = u_nom for the first 1.6 s; vent switches
between candidates (328 sign changes of u − u_nom per second, a call's median 2.5 ms), hold does not
(0.8 /s, 0.2 ms). With `--robot three-segment`: +2.5e-7 and +2.9e-3, 7–8 ms a call. Riding the
boundary leaves no margin: any mismatch of model and plant is a violation.
Diagnostics: theta (the blend sent), verified (candidates verified), W − Γ̲ at the state (J, for the
backup command), b per row.
"""

from __future__ import annotations

import math

import numpy as np

from controllers.core.bounds import Bound
from controllers.model.dynamics import PCCDynamics
from controllers.core.errors import NonFiniteCommandError, NonFiniteStateError, as_vector
from controllers.energy.escape_energy import BoundaryDistanceBound
from controllers.contract.filter_parameters import FilterParameter, check_parameters, parameter_docs
from controllers.core.lazy_import import lazy_module
from controllers.contract.diagnostics import DiagnosticLayout, FlatDiagnostics
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import Estimate, FilterContext, FilterOutput

pcc_model = lazy_module("controllers.model.pcc_model")  # numba loads at the first rollout (controllers.core.lazy_import)

BACKUPS = ("vent", "hold")

PARAMETERS = {
    "backup": FilterParameter(f"backup controller ({', '.join(BACKUPS)}): u = 0, or the last command held", "", str),
    "horizon_s": FilterParameter("backup horizon T_b after the candidate's period", "s",
                                 bound=Bound(0.0, 10.0, unit="s")),
    "levels": FilterParameter("candidates between u_nom and the backup (theta = 1, 1/2, ..., 2^-(levels-1), 0)",
                              "1", int, bound=Bound(1, 20)),
}
"""The backup CBF's parameters, declared once (`controllers.contract.filter_parameters`)."""

ROLLOUT_STEP_S = 1e-3
"""Largest integrator step (s) of the rollouts: the PCC plant's default ROS2 step."""

BACKUP_DIAGNOSTIC_UNITS = {
    "theta": "1 (blend sent: u = u_b + theta (u_nom - u_b))",
    "verified": "1 (candidates verified this call)",
    "energy_gap": "J (W - Gamma of the backup command at the state; < 0: inside its backup set)",
    "b": "row-scaled m (barrier per row of P)",
}


class BackupCBF:
    """The backup CBF of the module docstring on the PCC model `context.robot` (the filter's own model)."""

    capabilities = Capabilities()  # the minimal contract: one instance per simulation

    def __init__(self, context: FilterContext, backup: str = "vent", horizon_s: float = 0.5, levels: int = 3) -> None:
        checked = check_backup_cbf({"backup": backup, "horizon_s": horizon_s, "levels": levels})
        self.backup, self.horizon_s, self.levels = checked["backup"], checked["horizon_s"], checked["levels"]
        self.n = context.robot.n_segments
        self.safe_set = context.safe_set
        self.dynamics = PCCDynamics(context.robot)
        self.bound = BoundaryDistanceBound(context.robot, context.safe_set)
        self.period = float(context.control_dt)
        self.substeps = max(1, math.ceil(self.period / ROLLOUT_STEP_S - 1e-9))
        self.step_s = self.period / self.substeps
        self.horizon_steps = math.ceil(self.horizon_s / self.step_s - 1e-9)
        self._H = np.array(context.safe_set.H_prime, dtype=float)
        self._h = np.array(context.safe_set.h_prime, dtype=float)
        self._stiffness = context.robot.array("stiffness")
        self._static_gain = context.robot.array("gains") / self._stiffness  # K⁻¹Λ, rad/hPa
        self._lb = None if context.limits is None else np.array(context.limits[0])
        self._ub = None if context.limits is None else np.array(context.limits[1])
        self.thetas = [2.0 ** -k for k in range(self.levels)] + [0.0]
        self._last = np.zeros(self.n)
        p = len(self._h)
        self.diagnostic_layout = DiagnosticLayout({"theta": (), "verified": (), "energy_gap": (), "b": (p,)},
                                                  BACKUP_DIAGNOSTIC_UNITS)

    def reset(self) -> None:
        """Forget the last command (the hold backup's command is 0 again)."""
        self._last = np.zeros(self.n)

    def energy(self, kin: np.ndarray, dyn: np.ndarray, x: np.ndarray, held: np.ndarray) -> np.ndarray:
        """W_v per row (J): x (B, 2N), held commands v (B, N), model rows kin, dyn (B, ·) at x."""
        n = self.n
        q, qd = x[:, :n], x[:, n:]
        mass = dyn[:, self.dynamics.layout.mass].reshape(-1, n, n)
        elastic = q - held * self._static_gain
        return 0.5 * np.einsum("bi,bij,bj->b", qd, mass, qd) + 0.5 * (elastic * elastic * self._stiffness).sum(axis=1)

    def barrier(self, kin: np.ndarray) -> np.ndarray:
        """b per row of P at the states of kin (B, ·): (B, P')."""
        tip = kin[:, self.dynamics.layout.tip_terms.start]
        return self._h[None, :] - (tip.real[:, None] * self._H[None, :, 0] + tip.imag[:, None] * self._H[None, :, 1])

    def escape(self, held: np.ndarray) -> np.ndarray:
        """Γ̲(v) = min_j ½ δ_j(v)² per held command (J)."""
        return np.array([min(self.bound.values(v)) for v in held])

    def verify(self, q: list[float], qd: list[float], candidates: np.ndarray, backup: np.ndarray) -> np.ndarray:
        """Which candidates (K, N) are verified (module docstring, step 2); `backup` (K, N): the command held
        after each candidate's period. Stops once the first candidate is verified or all are decided."""
        count = len(candidates)
        core = self.dynamics.model_terms(q, qd)
        x = np.tile(np.array(q + qd), (count, 1))
        kin, dyn = np.tile(core.kin, (count, 1)), np.tile(core.dyn, (count, 1))
        pressure = np.zeros((count, self.n))
        gamma = self.escape(backup)
        undecided, verified = np.ones(count, dtype=bool), np.zeros(count, dtype=bool)
        method = pcc_model.INTEGRATOR_CODES["ros2"]
        for step in range(self.substeps + self.horizon_steps):
            u = candidates if step < self.substeps else backup
            if pcc_model.advance(method, x, u, pressure, self.dynamics.parameter_rows, kin, dyn, self.step_s, 1,
                                 -1.0, 0.0).any():
                raise FloatingPointError("the backup CBF's rollout left the finite numbers")
            inside = (self.barrier(kin) >= 0.0).all(axis=1)
            undecided &= inside
            if step + 1 >= self.substeps:
                arrived = undecided & (self.energy(kin, dyn, x, backup) < gamma)
                verified |= arrived
                undecided &= ~arrived
            if verified[0] or not undecided.any():
                break
        return verified

    def __call__(self, estimate: Estimate, u_nom) -> FilterOutput:
        """The largest verified blend of u_nom and the backup (module docstring, step 3)."""
        q = as_vector("q", estimate.q, self.n, NonFiniteStateError)
        qd = as_vector("qd", estimate.qd, self.n, NonFiniteStateError)
        u_bar = as_vector("u_nom", u_nom, self.n, NonFiniteCommandError)
        if self._lb is not None:
            u_bar = np.clip(u_bar, self._lb, self._ub)
        u_b = np.zeros(self.n) if self.backup == "vent" else self._last
        candidates = np.array([u_b + theta * (u_bar - u_b) for theta in self.thetas])
        backup = np.zeros_like(candidates) if self.backup == "vent" else candidates
        verified = self.verify(q.tolist(), qd.tolist(), candidates, backup)
        chosen = int(np.argmax(verified)) if verified.any() else len(self.thetas) - 1
        theta = self.thetas[chosen]
        u = u_bar.copy() if theta == 1.0 else candidates[chosen]
        action = "nominal" if theta == 1.0 else "blend" if theta > 0.0 else "backup"
        if not verified.any():
            action = "unverified"
        self._last = u.copy()
        core = self.dynamics.model_terms(q.tolist(), qd.tolist())
        x = np.concatenate((q, qd))[None, :]
        held = u_b[None, :]
        gap = float(self.energy(core.kin[None, :], core.dyn[None, :], x, held)[0] - self.escape(held)[0])
        b = self.barrier(core.kin[None, :])[0]
        tip = core.kin[self.dynamics.layout.tip_terms.start]
        values = [theta, float(verified.sum()), gap, *b.tolist()]
        return FilterOutput(u, action, not verified.any(), self.safe_set.margin_at(tip.real, tip.imag),
                            FlatDiagnostics(self.diagnostic_layout, values), BACKUP_DIAGNOSTIC_UNITS)


def check_backup_cbf(arguments: dict[str, object]) -> dict[str, object]:
    """What `BackupCBF` would refuse of its (converted) arguments, checked without building it; the checked values."""
    checked = check_parameters(PARAMETERS, arguments)
    if "backup" in checked and checked["backup"] not in BACKUPS:
        raise ValueError(f"backup must be one of {', '.join(BACKUPS)}, got {checked['backup']!r}")
    return checked


BackupCBF.check_arguments = staticmethod(check_backup_cbf)
BackupCBF.parameter_docs = parameter_docs(PARAMETERS)
