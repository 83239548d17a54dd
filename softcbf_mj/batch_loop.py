"""The closed loop over B simulations at once (docs/safety-filter.md, docs/beyond-the-paper.md#batched-ground-truth): many samples of a study per call.

Each control step k (t_k = k·Δt), for all B simulations together:
    plant state (B) → estimates (the exact state: q, q̇, t_capture = t) → nominal (B, N)
    → safety filter → command (non-finite rows refused, limits clipped) → plant step.
The filter runs as `controllers.safety_filter.filter_batch(filter, estimates, u_nom)`
(its own `filter_batch`, e.g. the paper's CBF through `controllers.cbf_batch`, or a
per-state loop over `__call__` for a stateless filter), or, for a stateful filter
without `filter_batch`, as B separate instances called once per simulation each.

The loop keeps no time series: it updates per-simulation running figures with the
definitions of `softcbf_mj.metrics.run_figures` over the same rows (the states at
t_0 … t_{T−1}, each with the command computed from it; the state after the last
step is not a row, as in `softcbf_mj.loop.run_closed_loop`):
- rho_min_pred: min over rows of the filter's ρ_pred (NaN rows skipped; None if all NaN);
- rho_min_meas: min over rows of ρ_meas = min over facets of ρ(F), F the plant's
  contact force, through the controller's force-safe set (`ForceSafeSet.margin_from_force`);
- force_max_N: max over rows and facets of F; t_violation_s: Δt · #rows with ρ_meas < 0;
- infeasible_steps: #rows whose filter call said infeasible; u_peak_abs_hPa: max |u|
  of the command sent (after the loop's clipping, as the serial log's `u`,
  `closedloop.record`);
- refused_steps (batch only): #rows whose command had a non-finite entry and was
  replaced by the safe action (0 hPa, clipped to the limits).
`record_commands=True` also returns the commands sent, (T, B, N) hPa, e.g. to replay
them open loop (tools/bench_batch.py measures the physics alone that way).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from controllers.nominal import NominalController
from controllers.safe_set import ForceSafeSet
from controllers.safety_filter import (BatchOutput, EstimateBatch, SafetyFilter, as_output, filter_batch,
                                       reset_filter)
from softcbf_mj.plant import BatchPlant

BatchNominal = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
"""Nominal commands of B simulations: (t (B,) s, q (B, N) rad, q̇ (B, N) rad/s) → u_nom (B, N) hPa."""


def broadcast_nominal(nominal: NominalController) -> BatchNominal:
    """A nominal controller whose formula is elementwise in t, q, q̇ (e.g. `SinusoidNominal`),
    evaluated for all B simulations in one call with t as a (B, 1) column."""
    return lambda t, q, qd: np.broadcast_to(nominal(t[:, None], q, qd), q.shape)


def per_simulation_nominal(nominals: Sequence[NominalController]) -> BatchNominal:
    """One nominal controller per simulation (B of them), each called on its own row."""
    return lambda t, q, qd: np.array([nominal(float(ti), qi, qdi) for nominal, ti, qi, qdi in zip(nominals, t, q, qd)])


@dataclass(frozen=True, eq=False)
class BatchRun:
    """Per-simulation figures of a batched run (module docstring); arrays of shape (B,).

    `commands`: the commands sent, (T, B, N) hPa, when recorded. `wall_s`: the run's wall
    time, shared by all simulations; `sim_s`: simulated time per simulation.
    """

    rho_min_pred: np.ndarray
    rho_min_meas: np.ndarray
    force_max_N: np.ndarray
    t_violation_s: np.ndarray
    infeasible_steps: np.ndarray
    u_peak_abs_hPa: np.ndarray
    refused_steps: np.ndarray
    wall_s: float
    sim_s: float
    commands: np.ndarray | None = None

    def run(self, b: int) -> dict[str, Any]:
        """Simulation b's figures under the docs/run-outputs.md names (rho_min_pred None when never predicted)."""
        rho_pred = float(self.rho_min_pred[b])
        return {
            "rho_min_pred": None if math.isnan(rho_pred) else rho_pred,
            "rho_min_meas": float(self.rho_min_meas[b]),
            "force_max_N": float(self.force_max_N[b]),
            "t_violation_s": float(self.t_violation_s[b]),
            "infeasible_steps": int(self.infeasible_steps[b]),
            "u_peak_abs_hPa": float(self.u_peak_abs_hPa[b]),
            "refused_steps": int(self.refused_steps[b]),
            "sim_s": self.sim_s,
        }


def _filter_all(safety_filter: SafetyFilter | Sequence[SafetyFilter], estimates: EstimateBatch,
                u_nom: np.ndarray) -> BatchOutput:
    if not isinstance(safety_filter, Sequence):
        return filter_batch(safety_filter, estimates, u_nom)
    outputs = [as_output(f(estimates[b], u_nom[b])) for b, f in enumerate(safety_filter)]
    return BatchOutput(np.array([np.asarray(o.u, dtype=float) for o in outputs]).reshape(u_nom.shape),
                       np.array([o.action for o in outputs]), np.array([bool(o.infeasible) for o in outputs]),
                       np.array([float(o.rho_pred) for o in outputs]))


def run_batch_closed_loop(
    plant: BatchPlant,
    safety_filter: SafetyFilter | Sequence[SafetyFilter],
    nominal: BatchNominal,
    safe_set: ForceSafeSet,
    duration: float,
    q0: np.ndarray,
    u_min: np.ndarray | None = None,
    u_max: np.ndarray | None = None,
    record_commands: bool = False,
) -> BatchRun:
    """Run all B simulations for `duration` s from rest at q0 (B, N) rad; return their figures.

    safety_filter: one filter for all (see the module docstring) or B instances, one per
    simulation (each `reset()` first, if it has one). safe_set: the controller's, for
    ρ_meas. u_min, u_max: (N,) or (B, N) hPa limits the loop clips every command to
    (None: no clipping, as the paper's simulation).
    """
    n_steps = int(round(duration / plant.control_dt))
    if n_steps < 1:
        raise ValueError(f"duration must cover at least one control period ({plant.control_dt} s), got {duration}")
    if (u_min is None) != (u_max is None):
        raise ValueError("u_min and u_max must both be given or both be None")
    n_sims = plant.n_sims
    if isinstance(safety_filter, Sequence):
        if len(safety_filter) != n_sims:
            raise ValueError(f"safety_filter must be one filter or n_sims = {n_sims} instances, got {len(safety_filter)}")
        for f in safety_filter:
            reset_filter(f)
    else:
        reset_filter(safety_filter)
    safe_u = np.zeros((n_sims, plant.n_segments))
    if u_min is not None:
        safe_u = np.clip(safe_u, u_min, u_max)
    rho_pred = np.full(n_sims, np.inf)
    rho_meas = np.full(n_sims, np.inf)
    force_max = np.full(n_sims, -np.inf)
    violations = np.zeros(n_sims, dtype=int)
    infeasible = np.zeros(n_sims, dtype=int)
    refused = np.zeros(n_sims, dtype=int)
    u_peak = np.zeros(n_sims)
    commands = np.empty((n_steps, n_sims, plant.n_segments)) if record_commands else None
    start = time.perf_counter()
    state = plant.reset(q0)
    for k in range(n_steps):
        estimates = EstimateBatch(state.t, state.q, state.qd, state.t)
        u_nom = nominal(state.t, state.q, state.qd)
        out = _filter_all(safety_filter, estimates, u_nom)
        u = np.asarray(out.u, dtype=float)
        finite = np.all(np.isfinite(u), axis=1)
        sent = np.where(finite[:, None], u, safe_u)
        if u_min is not None:
            sent = np.clip(sent, u_min, u_max)
        rho_pred = np.fmin(rho_pred, out.rho_pred)
        margin = np.min(safe_set.margin_from_force(state.contact_forces), axis=1)
        rho_meas = np.minimum(rho_meas, margin)
        force_max = np.maximum(force_max, np.max(state.contact_forces, axis=1))
        violations += margin < 0.0
        infeasible += out.infeasible
        refused += ~finite
        u_peak = np.fmax(u_peak, np.max(np.abs(sent), axis=1))
        if commands is not None:
            commands[k] = sent
        state = plant.step(sent)
    wall = time.perf_counter() - start
    rho_pred[np.isinf(rho_pred)] = np.nan  # never predicted
    return BatchRun(rho_pred, rho_meas, force_max, violations * plant.control_dt, infeasible, u_peak, refused,
                    wall, n_steps * plant.control_dt, commands)


def replay_commands(plant: BatchPlant, commands: np.ndarray, q0: np.ndarray) -> float:
    """Step the plant through recorded commands (T, B, N) hPa from rest at q0, no filter; return the wall time (s)."""
    start = time.perf_counter()
    plant.reset(q0)
    for u in commands:
        plant.step(u)
    return time.perf_counter() - start
