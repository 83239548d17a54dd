"""A 10 Hz zero-order-hold loop with camera timing around the PCC plant, for the governor tests.

The plant (`PCCPlant`, 1 ms ticks, ROS2 at 1 ms, valve lag `tau_p`) holds the command
between filter calls. A call every `period` s (t_k = k·period) gets the TRUE state
captured `age` s earlier (age drawn uniformly from `age_range`, seeded, rounded to
ticks: the camera's latency plus the estimate's age); the command it returns acts
from t_k + `delay` on. Records per tick: t, the command acting, u_nom, ρ of the true tip
(ψ(n) of the true state at every integration step: the plant's physics step is the tick),
the true state and pressure; per call: the command, its application tick, the
FilterOutput and the call's wall time.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from controllers.model.params import RobotParams
from controllers.model.pcc import kinematics
from controllers.model.safe_set import ForceSafeSet
from controllers.contract.safety_filter import Estimate, FilterContext, OutputCheck
from softcbf_mj.physics.pcc_plant import PCCPlant

TICK = 1e-3


@dataclass
class LoopRecord:
    t: np.ndarray  # (T,) s
    u: np.ndarray  # (T, N) hPa, the command acting during the tick that ends at t
    u_nom: np.ndarray  # (T, N) hPa, the latest u_nom given to the filter
    rho: np.ndarray  # (T,) margin of the true tip at t (from its penetration)
    force: np.ndarray  # (T, P) the plant's contact force per facet, N
    q: np.ndarray  # (T, N) rad, true, at t
    qd: np.ndarray  # (T, N) rad/s
    p: np.ndarray  # (T, N) hPa, acting pressure at t
    apply_ticks: list[int]  # tick index at whose start each call's command acts
    commands: list[np.ndarray]  # each call's command
    outputs: list  # each call's FilterOutput
    call_us: np.ndarray  # (calls,) wall time of each filter call, µs
    call_cpu_us: np.ndarray  # (calls,) process CPU time of each filter call, µs (less sensitive to a loaded machine)


def context(robot: RobotParams, safe_set: ForceSafeSet, period: float, delay: float, tau_p: float) -> FilterContext:
    return FilterContext(robot, safe_set, robot.array("u_min"), robot.array("u_max"), period, delay, tau_p)


def run_loop(safety_filter, robot: RobotParams, safe_set: ForceSafeSet, u_nom: Callable[[float], np.ndarray],
             duration: float, period: float = 0.1, delay: float = 0.02, age_range=(0.03, 0.1),
             tau_p: float = 0.05, seed: int = 0, plant=None) -> LoopRecord:
    """The loop above; `plant` (default: PCCPlant with τ_p = tau_p) must tick at TICK."""
    rng = np.random.default_rng(seed)
    plant = PCCPlant(robot, safe_set, control_dt=TICK, tau_p=tau_p) if plant is None else plant
    n = robot.n_segments
    check = OutputCheck(n)
    state = plant.reset(np.zeros(n))
    if hasattr(safety_filter, "reset"):
        safety_filter.reset()
    ticks, per_call, delay_ticks = int(round(duration / TICK)), int(round(period / TICK)), int(round(delay / TICK))
    history_q, history_qd = [state.q], [state.qd]
    acting, pending = np.zeros(n), []  # pending: (tick, u)
    rec = {k: [] for k in ("t", "u", "u_nom", "rho", "force", "q", "qd", "p")}
    apply_ticks, commands, outputs, call_us, call_cpu_us, last_nom = [], [], [], [], [], np.zeros(n)
    for k in range(ticks):
        if k % per_call == 0:
            age = int(round(rng.uniform(*age_range) / TICK))
            j = max(k - age, 0)
            last_nom = np.asarray(u_nom(k * TICK), dtype=float)
            est = Estimate(k * TICK, history_q[j], history_qd[j], j * TICK)
            t0, c0 = time.perf_counter(), time.process_time()
            out = check(safety_filter(est, last_nom))
            call_us.append((time.perf_counter() - t0) * 1e6)
            call_cpu_us.append((time.process_time() - c0) * 1e6)
            pending.append((k + delay_ticks, out.u))
            apply_ticks.append(k + delay_ticks)
            commands.append(np.array(out.u))
            outputs.append(out)
        while pending and pending[0][0] <= k:
            acting = pending.pop(0)[1]
        state = plant.step(acting)
        history_q.append(state.q)
        history_qd.append(state.qd)
        rec["t"].append(state.t)
        rec["u"].append(acting)
        rec["u_nom"].append(last_nom)
        rec["rho"].append(float(safe_set.margin(state.tip)))
        rec["force"].append(state.contact_forces)
        rec["q"].append(state.q)
        rec["qd"].append(state.qd)
        rec["p"].append(state.u_applied)
    arrays = {k: np.array(v) for k, v in rec.items()}
    return LoopRecord(**arrays, apply_ticks=apply_ticks, commands=commands, outputs=outputs, call_us=np.array(call_us),
                      call_cpu_us=np.array(call_cpu_us))


class PushingPlatePlant:
    """The PCC model whose plate pushes back (a test plant, independent of the governor's predictor).

    M q̈ + C q̇ + D q̇ + K q = Λ p − J_rᵀ Σ_i n̂_i k_true n_i(r), ṗ = (u − p)/τ_p; classical RK4
    at `physics_dt` (default 0.5 ms, stable: the fast mode ≈ −3.7e3 s⁻¹ needs h ≲ 0.7 ms) with p
    held at its exact mean over each step. Same interface as PCCPlant (reset, step, control_dt);
    PlantState.contact_forces is k_true n per facet.
    """

    def __init__(self, robot: RobotParams, safe_set: ForceSafeSet, k_true: float, tau_p: float,
                 control_dt: float = TICK, physics_dt: float = 5e-4) -> None:
        from controllers.model.dynamics import PCCDynamics

        self.dynamics, self.safe_set, self.k_true, self.tau_p = PCCDynamics(robot), safe_set, k_true, tau_p
        self.control_dt, self.n_segments = control_dt, robot.n_segments
        self.substeps = int(round(control_dt / physics_dt))
        self.h = control_dt / self.substeps
        self.lengths = robot.array("lengths")

    def _force(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        # The tip and its Jacobian from one first-order evaluation (tip_position and tip_jacobian would each
        # evaluate the kinematics: the plant's costliest part, eight times per tick).
        kin = kinematics(q, self.lengths, order=1)
        tip, jac = np.array((kin.points[-1].real, kin.points[-1].imag)), np.array((kin.jac[-1].real, kin.jac[-1].imag))
        forces = self.k_true * self.safe_set.penetration(tip)
        generalised = -(forces @ self.safe_set.environment.normals) @ jac
        return generalised, forces

    def _rhs(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        n = self.n_segments
        acc, mass = self.dynamics.acceleration_and_mass(x[:n], x[n:], p)
        return np.concatenate((x[n:], acc + np.linalg.solve(mass, self._force(x[:n])[0])))

    def _state(self):
        from softcbf_mj.physics.plant import PlantState
        from controllers.model.pcc import segment_ends

        n = self.n_segments
        q = self.x[:n]
        return PlantState(self.t, q.copy(), self.x[n:].copy(), segment_ends(q, self.lengths), self._force(q)[1], self.p.copy())

    def reset(self, q0: np.ndarray, qd0: np.ndarray | None = None):
        self.x = np.concatenate((q0, np.zeros_like(q0) if qd0 is None else qd0)).astype(float)
        self.p, self.t = np.zeros(self.n_segments), 0.0
        return self._state()

    def step(self, u: np.ndarray):
        h, u = self.h, np.asarray(u, dtype=float)
        decay = np.exp(-h / self.tau_p) if self.tau_p > 0 else 0.0
        mean = self.tau_p / h * -np.expm1(-h / self.tau_p) if self.tau_p > 0 else 0.0
        for _ in range(self.substeps):
            p = u + (self.p - u) * mean
            self.p = u + (self.p - u) * decay
            k1 = self._rhs(self.x, p)
            k2 = self._rhs(self.x + 0.5 * h * k1, p)
            k3 = self._rhs(self.x + 0.5 * h * k2, p)
            k4 = self._rhs(self.x + h * k3, p)
            self.x = self.x + h / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
        self.t += self.control_dt
        return self._state()
