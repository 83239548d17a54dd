"""The closed loop over B simulations at once (docs/safety-filter.md, docs/beyond-the-paper.md#batched-ground-truth): many samples of a study per call.

Each simulation b has its own control step (`closedloop.step.ControlStep` with its own
`SafetyMonitor`), the one every serial loop runs, so a sample's commands, holds, vents and
filter faults are those of a single run. Each control step k (t_k = k·Δt), for all B
simulations together:
    plant state (B) → estimates (the exact state: q, q̇, t_capture = t)
    → step b: nominal, filter, admission (clip, non-finite → hold then vent), monitor
    → commands (B, N) → plant step.
The filter is either one filter with `filter_batch` (e.g. the paper's CBF through
`controllers.cbf_batch`), called once for all simulations whose step calls it this period
(`ControlStep.prepare`, then `ControlStep.finish` on each row of its `BatchOutput`; an
exception in it is a filter fault of each of those simulations), or one stateless filter
without it (called per simulation), or B instances, one per simulation (B histories).

A filter fault (closedloop.step) ends simulation b's run at the row of its vent, as it ends
a serial run: its figures stop there (`BatchRun.rows`), its row gains the fault's fields,
and the batch goes on for the others (b's plant is sent 0 hPa, the vent, until the end).

The loop keeps no time series: it updates per-simulation running figures with the
definitions of `softcbf_mj.metrics.run_figures` over the same rows (the states at
t_0 … t_{T−1}, each with the command computed from it; the state after the last
step is not a row, as in `softcbf_mj.loop.run_closed_loop`):
- rho_min_pred: min over rows of the filter's ρ_pred (NaN rows skipped; None if all NaN);
- rho_min_meas: min over rows of ρ_meas = min over facets of ρ(F), F the plant's
  contact force, through the controller's force-safe set (`ForceSafeSet.margin_from_force`);
- force_max_N: max over rows and facets of F; t_violation_s: Δt · #rows with ρ_meas < 0;
- infeasible_steps: #rows whose filter call said infeasible; u_peak_abs_hPa: max |u|
  of the command sent (after the step's clipping, as the serial log's `u`,
  `closedloop.record`);
- refused_steps (batch only): #rows the safety monitor did not RUN (a refused command or a
  filter fault: HOLD or VENT).
`record_commands=True` also returns the commands sent, (T, B, N) hPa, e.g. to replay
them open loop (tools/bench_batch.py measures the physics alone that way).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from closedloop.monitor import SafeAction, SafetyMonitor
from closedloop.step import ControlStep, FilterFault, StepRecord
from controllers.errors import ControllerInputError
from controllers.nominal import NominalController
from controllers.safety_filter import (Estimate, EstimateBatch, FilterContext, SafetyFilter, checked_batch_outputs,
                                       read_only)
from softcbf_mj.plant import BatchPlant


@dataclass(frozen=True, eq=False)
class BatchRun:
    """Per-simulation figures of a batched run (module docstring); arrays of shape (B,).

    `rows`: the rows each simulation's figures cover (T, or fewer after a filter fault);
    `faults`: each simulation's filter fault (None: none). `commands`: the commands sent,
    (T, B, N) hPa, when recorded. `wall_s`: the run's wall time, shared by all simulations;
    `control_dt`: s, the control period.
    """

    rho_min_pred: np.ndarray
    rho_min_meas: np.ndarray
    force_max_N: np.ndarray
    t_violation_s: np.ndarray
    infeasible_steps: np.ndarray
    u_peak_abs_hPa: np.ndarray
    refused_steps: np.ndarray
    rows: np.ndarray
    faults: tuple[FilterFault | None, ...]
    wall_s: float
    control_dt: float
    commands: np.ndarray | None = None

    def run(self, b: int) -> dict[str, Any]:
        """Simulation b's figures under the docs/run-outputs.md names (rho_min_pred None when never
        predicted; sim_s the time its rows cover), with the fault's fields as a single run's row has them."""
        rho_pred = float(self.rho_min_pred[b])
        row = {
            "rho_min_pred": None if math.isnan(rho_pred) else rho_pred,
            "rho_min_meas": float(self.rho_min_meas[b]),
            "force_max_N": float(self.force_max_N[b]),
            "t_violation_s": float(self.t_violation_s[b]),
            "infeasible_steps": int(self.infeasible_steps[b]),
            "u_peak_abs_hPa": float(self.u_peak_abs_hPa[b]),
            "refused_steps": int(self.refused_steps[b]),
            "sim_s": int(self.rows[b]) * self.control_dt,
        }
        fault = self.faults[b]
        if fault is not None:
            row.update(fault.row_fields())
        return row


def frozen_estimates(state: Any) -> list[Estimate]:
    """The exact-state estimates of a batch plant's state (t (B,), q, qd (B, N)): rows of one
    read-only copy of q and of q̇, made here and written by nothing (`ControlStep.prepare`'s `frozen`)."""
    q, qd = read_only(np.array(state.q, dtype=float)), read_only(np.array(state.qd, dtype=float))
    t = state.t.tolist()
    return [Estimate(t[b], q[b], qd[b], t[b]) for b in range(len(t))]


def batch_rows(steps: Sequence[ControlStep], safety_filter: SafetyFilter, estimates: list[Estimate],
               active: np.ndarray, frozen: bool = False) -> list[StepRecord | None]:
    """One control step of the active simulations (`active` (B,) bool; None for the others)
    through the shared filter's `filter_batch`, called once for those whose step calls it
    (`ControlStep.prepare`, then `ControlStep.finish` per row; module docstring). `frozen`: as
    `ControlStep.prepare`'s (`frozen_estimates`). Also the vector environment's
    (`softcbf_mj.env.vector`)."""
    prepared = [steps[b].prepare(estimates[b], frozen) if active[b] else (None, None) for b in range(len(steps))]
    called = [b for b, (view, _) in enumerate(prepared) if view is not None]
    results: dict[int, object] = {}
    filter_us = math.nan
    if called:
        views = [prepared[b][0] for b in called]
        batch = EstimateBatch(np.array([v.t for v in views]), np.array([v.q for v in views]),
                              np.array([v.qd for v in views]), np.array([v.t_capture for v in views]))
        start = time.perf_counter()
        where = "filter_batch"
        try:
            out = safety_filter.filter_batch(batch, np.array([prepared[b][1] for b in called]))
            filter_us = (time.perf_counter() - start) * 1e6 / len(called)
            where = "filter return"
            results = dict(zip(called, checked_batch_outputs(out, len(called), steps[called[0]].n)))
        except ControllerInputError:
            results = {}
        except Exception as exc:  # noqa: BLE001 - a filter fault of every simulation it was called for
            for b in called:
                steps[b].fault = FilterFault.from_exception(exc, where, estimates[b].t, safety_filter)
    return [steps[b].finish(estimates[b], prepared[b][1], results.get(b), filter_us if b in results else math.nan,
                            checked=True) if active[b] else None for b in range(len(steps))]


def run_batch_closed_loop(
    plant: BatchPlant,
    safety_filter: SafetyFilter | Sequence[SafetyFilter],
    nominal: NominalController | Sequence[NominalController],
    context: FilterContext,
    duration: float,
    q0: np.ndarray,
    record_commands: bool = False,
) -> BatchRun:
    """Run all B simulations for `duration` s from rest at q0 (B, N) rad; return their figures.

    safety_filter: one filter for all (see the module docstring) or B instances, one per
    simulation; nominal: one nominal controller for all or B, one per simulation. `context`
    is the controllers' (its limits are what every step clips to, its safe set gives ρ_meas).
    Each simulation's control step is reset first (its filter's `reset()`, its monitor).
    """
    n_steps = int(round(duration / plant.control_dt))
    if n_steps < 1:
        raise ValueError(f"duration must cover at least one control period ({plant.control_dt} s), got {duration}")
    n_sims, n = plant.n_sims, plant.n_segments
    per_sim_filters = isinstance(safety_filter, Sequence)
    filters = list(safety_filter) if per_sim_filters else [safety_filter] * n_sims
    nominals = list(nominal) if isinstance(nominal, Sequence) else [nominal] * n_sims
    if len(filters) != n_sims or len(nominals) != n_sims:
        raise ValueError(f"safety_filter and nominal must be one or n_sims = {n_sims} each, got {len(filters)} "
                         f"and {len(nominals)}")
    shared_batch = not per_sim_filters and callable(getattr(safety_filter, "filter_batch", None))
    steps = [ControlStep(f, nom, context, SafetyMonitor(n)) for f, nom in zip(filters, nominals)]
    if per_sim_filters:
        for step in steps:
            step.reset()
    else:  # one shared filter: its reset() once, every monitor anew
        steps[0].reset()
        for step in steps[1:]:
            step.monitor.restart()
            step.fault = steps[0].fault
    safe_set = context.safe_set
    rho_pred = np.full(n_sims, np.inf)
    rho_meas = np.full(n_sims, np.inf)
    force_max = np.full(n_sims, -np.inf)
    violations = np.zeros(n_sims, dtype=int)
    infeasible = np.zeros(n_sims, dtype=int)
    refused = np.zeros(n_sims, dtype=int)
    u_peak = np.zeros(n_sims)
    rows = np.zeros(n_sims, dtype=int)
    active = np.ones(n_sims, dtype=bool)
    commands = np.zeros((n_steps, n_sims, n)) if record_commands else None
    vented = np.zeros(n)  # a stopped simulation's plant: the vent
    start = time.perf_counter()
    state = plant.reset(q0)
    for k in range(n_steps):
        if shared_batch:
            records = batch_rows(steps, safety_filter, frozen_estimates(state), active, frozen=True)
        else:
            estimates = [Estimate(float(state.t[b]), state.q[b], state.qd[b], float(state.t[b])) for b in range(n_sims)]
            records = [steps[b](estimates[b]) if active[b] else None for b in range(n_sims)]
        margin = np.min(safe_set.margin_from_force(state.contact_forces), axis=1)
        force = np.max(state.contact_forces, axis=1)
        sent = np.array([vented if r is None else r.u for r in records])
        outputs = [None if r is None else r.output for r in records]
        rho_pred = np.fmin(rho_pred, [math.nan if o is None else o.rho_pred for o in outputs])
        infeasible += [o is not None and o.infeasible for o in outputs]
        refused += [r is not None and r.action is not SafeAction.RUN for r in records]
        rho_meas = np.where(active, np.minimum(rho_meas, margin), rho_meas)
        force_max = np.where(active, np.maximum(force_max, force), force_max)
        violations += active & (margin < 0.0)
        u_peak = np.where(active, np.fmax(u_peak, np.max(np.abs(sent), axis=1)), u_peak)
        rows += active
        if commands is not None:
            commands[k] = sent
        active &= ~np.array([step.stopped for step in steps])
        state = plant.step(sent)
    wall = time.perf_counter() - start
    rho_pred[np.isinf(rho_pred)] = np.nan  # never predicted
    return BatchRun(rho_pred, rho_meas, force_max, violations * plant.control_dt, infeasible, u_peak, refused, rows,
                    tuple(step.fault for step in steps), wall, plant.control_dt, commands)


def replay_commands(plant: BatchPlant, commands: np.ndarray, q0: np.ndarray) -> float:
    """Step the plant through recorded commands (T, B, N) hPa from rest at q0, no filter; return the wall time (s)."""
    start = time.perf_counter()
    plant.reset(q0)
    for u in commands:
        plant.step(u)
    return time.perf_counter() - start
