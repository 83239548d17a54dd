"""The closed loop over B simulations at once (docs/safety-filter.md, docs/beyond-the-paper.md#batched-ground-truth): many samples of a study per call.

One `closedloop.step.BatchControlStep` runs the B simulations' control steps: row b is the
`ControlStep` (with its own safety monitor) that a serial run of sample b runs, so a
sample's commands, holds, vents and filter faults are those of a single run, bit for bit.
Each control step k (t_k = k·Δt), for all B simulations together:
    plant state (B) → estimates (the exact state: q, q̇, t_capture = t)
    → the batched step: nominal, filter, admission (clip, non-finite → hold then vent), monitor
    → commands (B, N) → plant step.
The filter is either one filter that declares batched (`filter_batch`, e.g. the paper's CBF through
`controllers.cbf.batch`), called once for all simulations whose step calls it this period
(an exception in it is a filter fault of each of those simulations), or one stateless filter
without it (called per simulation), or B instances, one per simulation (B histories).

A filter fault (closedloop.step) ends simulation b's run at the row of its vent, as it ends
a serial run: its figures stop there (`BatchRun.rows`), its row gains the fault's fields,
and the batch goes on for the others (b's plant is sent 0 hPa, the vent, until the end).

The loop keeps no time series: its figures are `softcbf_mj.outputs.metrics.RunningFigures`, the
accumulator whose definitions `softcbf_mj.outputs.metrics.run_figures` applies to a serial run's
rows, updated here one control period at a time over the same rows (the states at
t_0 … t_{T−1}, each with the command computed from it; the state after the last step is
not a row, as in `softcbf_mj.loops.loop.run_closed_loop`): rho_min_pred, rho_min_meas,
force_max_N, t_violation_s, infeasible_steps, u_peak_abs_hPa, and (batch only)
refused_steps, the rows the safety monitor did not RUN (a refused command or a filter
fault: HOLD or VENT). `record_commands=True` also returns the commands sent, (T, B, N)
hPa, e.g. to replay them open loop (tools/bench_batch.py measures the physics alone that way).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from closedloop.step import BatchControlStep, FilterFault
from controllers.contract.safety_filter import FilterContext, SafetyFilter
from softcbf_mj.outputs.metrics import RunningFigures, rho_meas
from softcbf_mj.physics.plant import BatchPlant

if TYPE_CHECKING:  # annotations only: the compiled model (numba) loads where a run starts, not for softcbf list
    from controllers.nominal import NominalController


@dataclass(frozen=True, eq=False)
class BatchRun:
    """Per-simulation figures of a batched run (module docstring).

    `figures`: the running figures of every simulation (`softcbf_mj.outputs.metrics.RunningFigures`,
    arrays of shape (B,): force_max_N, refused, rows, …), each over the rows it covers (`rows`:
    T, or fewer after a filter fault); `faults`: each simulation's filter fault (None: none).
    `commands`: the commands sent, (T, B, N) hPa, when recorded. `wall_s`: the run's wall
    time, shared by all simulations; `control_dt`: s, the control period.
    """

    figures: RunningFigures
    faults: tuple[FilterFault | None, ...]
    wall_s: float
    control_dt: float
    commands: np.ndarray | None = None

    @property
    def rows(self) -> np.ndarray:
        return self.figures.rows

    def run(self, b: int) -> dict[str, Any]:
        """Simulation b's figures under the docs/run-outputs.md names (`RunningFigures.figures`; sim_s
        the time its rows cover), refused_steps, and the fault's fields as a single run's row has them."""
        row = {**self.figures.figures(b), "refused_steps": int(self.figures.refused[b]),
               "sim_s": int(self.rows[b]) * self.control_dt}
        fault = self.faults[b]
        if fault is not None:
            row.update(fault.row_fields())
        return row


def run_batch_closed_loop(
    plant: BatchPlant,
    safety_filter: SafetyFilter | Sequence[SafetyFilter],
    nominal: NominalController | Sequence[NominalController],
    context: FilterContext,
    duration: float,
    q0: np.ndarray,
    record_commands: bool = False,
    progress: Callable[[float], None] | None = None,
) -> BatchRun:
    """Run all B simulations for `duration` s from rest at q0 (B, N) rad; return their figures.

    safety_filter: one filter for all (see the module docstring) or B instances, one per
    simulation; nominal: one nominal controller for all or B, one per simulation. `context`
    is the controllers' (its limits are what every step clips to, its safe set gives ρ_meas).
    The batched control step is reset first (the filters' `reset()`: a shared one's once; the monitors).
    `progress`, if given, is called after every control step with the fraction of the run done (k/T); it
    must be cheap (a study's worker forwards it to its driver at most twice a second).
    """
    n_steps = int(round(duration / plant.control_dt))
    if n_steps < 1:
        raise ValueError(f"duration must cover at least one control period ({plant.control_dt} s), got {duration}")
    n_sims = plant.n_sims
    step = BatchControlStep(safety_filter, nominal, context, n_sims)
    step.reset()
    safe_set = context.safe_set
    figures = RunningFigures(n_sims, plant.control_dt)
    active = np.ones(n_sims, dtype=bool)
    commands = np.zeros((n_steps, n_sims, plant.n_segments)) if record_commands else None
    start = time.perf_counter()
    state = plant.reset(q0)
    for k in range(n_steps):
        record = step(state.t, state.q, state.qd, rows=None if active.all() else active)
        figures.update(rho_meas(safe_set, state.contact_forces)[None], state.contact_forces[None], record.u[None],
                       record.rho_pred[None], record.infeasible[None], record.action[None],
                       None if active.all() else active[None])
        if commands is not None:
            commands[k] = record.u
        active &= ~step.stopped
        state = plant.step(record.u)  # a stopped simulation's row of u is 0 hPa: the vent
        if progress is not None:
            progress((k + 1) / n_steps)
    wall = time.perf_counter() - start
    return BatchRun(figures, tuple(step.faults), wall, plant.control_dt, commands)


def replay_commands(plant: BatchPlant, commands: np.ndarray, q0: np.ndarray) -> float:
    """Step the plant through recorded commands (T, B, N) hPa from rest at q0, no filter; return the wall time (s)."""
    start = time.perf_counter()
    plant.reset(q0)
    for u in commands:
        plant.step(u)
    return time.perf_counter() - start
