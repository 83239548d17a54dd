"""The simulated closed loop: plant → estimator → control step → plant (docs/model.md#nominal-controller-and-the-papers-scenario).

At each control step k (t_k = k·Δt): the estimator turns the plant's ground truth into
the controller's view of the state (`controllers.contract.safety_filter.Estimate`), the control
step (`closedloop.step.ControlStep`: nominal, filter, admission, safety monitor) gives
the command, and the plant holds it for one period. This module owns only the clock
and the plant's I/O; everything is recorded at the control rate by `closedloop.record`
(the plant's columns: `plant_columns`, `plant_values`, `plant_series`).

The record is preallocated (`closedloop.record.Recorder`): T = round(duration / Δt) rows of
F floats. Its peak (`series_bytes_needed`: the rows, the columns cut from them, the filter's
diagnostics and the plant's extras) is checked against the available memory before a run
starts (`check_duration`), together with a finite duration of at least one period.
"""

from __future__ import annotations

import math
import os
from typing import Callable

import numpy as np

from closedloop.record import TIMESERIES_UNITS, LiveRows, Recorder
from closedloop.step import ControlStep
from controllers.core.bounds import SettingError
from controllers.model.safe_set import ForceSafeSet
from controllers.contract.safety_filter import Estimate
from softcbf_mj.physics.plant import Plant, PlantState
from softcbf_mj.outputs.progress import Progress

Series = tuple[dict[str, np.ndarray], dict[str, str]]  # time series by key, and their units


def exact_state(state: PlantState) -> Estimate:
    """Estimator that passes the plant's true state through (the paper's simulation): t_capture = t."""
    return Estimate(state.t, state.q, state.qd, state.t)


def plant_columns(n_segments: int, n_facets: int) -> dict[str, tuple[int, ...]]:
    """The simulated loops' own float columns and shapes, in the order of `plant_values`."""
    n = n_segments
    return {"t": (), "q": (n,), "qd": (n,), "q_est": (n,), "qd_est": (n,), "segment_ends": (n + 1, 2),
            "u_applied": (n,), "contact_force": (n_facets,)}


def plant_values(state: PlantState, q_est: np.ndarray, qd_est: np.ndarray) -> list[float]:
    """One row of `plant_columns`: the plant's state and the estimate in force."""
    return [state.t, *state.q.tolist(), *state.qd.tolist(), *q_est.tolist(), *qd_est.tolist(),
            *state.segment_ends.ravel().tolist(), *state.u_applied.tolist(), *state.contact_forces.tolist()]


def available_memory_bytes() -> int:
    """Memory a new allocation can get without swapping: MemAvailable of /proc/meminfo
    (Linux), else the machine's physical memory."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def series_bytes_needed(n_steps: int, n_segments: int, safe_set: ForceSafeSet) -> int:
    """Peak memory of a simulated run's time series (`Recorder.bytes_needed` of `plant_columns`),
    with room for the paper CBF's diagnostics (b and active: P' each, a few scalars) and
    8 floats a step of the plant's extras."""
    p = len(safe_set.H_prime)
    return Recorder.bytes_needed(n_steps, n_segments, plant_columns(n_segments, safe_set.n_facets),
                                 diagnostic_floats=2 * p + 4, extra_floats=8)


def check_duration(duration: float, control_dt: float, n_segments: int, safe_set: ForceSafeSet) -> int:
    """The number of control steps of a run of `duration` s at period `control_dt` s,
    after checking it: duration finite and > 0, at least one period, and the time series
    (`series_bytes_needed`) within the available memory. Raises SettingError (a ValueError)
    naming duration, a validation error of the command line; call it before writing anything."""
    if not (math.isfinite(duration) and duration > 0):
        raise SettingError(f"duration must be finite and > 0 s, got {duration}")
    if not (math.isfinite(control_dt) and control_dt > 0):
        raise SettingError(f"the control period must be finite and > 0 s, got {control_dt}")
    n_steps = int(round(duration / control_dt))
    if n_steps < 1:
        raise SettingError(f"duration must cover at least one control period ({control_dt:g} s), got {duration} s")
    needed, available = series_bytes_needed(n_steps, n_segments, safe_set), available_memory_bytes()
    if needed > available:
        raise SettingError(f"duration {duration:g} s ({n_steps} steps of {control_dt:g} s) needs {needed / 2**30:.1f} GiB "
                         f"for its time series, more than the {available / 2**30:.1f} GiB of memory available; "
                         "shorten duration or lower the rate")
    return n_steps


def plant_series(recorder: Recorder, safe_set: ForceSafeSet, n_rows: int | None = None) -> Series:
    """The recorder's columns plus tip (m) and ρ_meas (1, from the measured contact force through
    the controller's force-safe set: its ψ and n_max), and their units (the plant's extras not included)."""
    columns = recorder.columns(n_rows)
    columns["tip"] = columns["segment_ends"][:, -1].copy()
    columns["rho_meas"] = np.min(safe_set.margin_from_force(columns["contact_force"]), axis=-1)
    units = recorder.units()
    units.update({key: TIMESERIES_UNITS[key] for key in ("tip", "rho_meas")})
    return columns, units


def run_closed_loop(
    plant: Plant,
    step: ControlStep,
    safe_set: ForceSafeSet,
    duration: float,
    q0: np.ndarray,
    estimator: Callable[[PlantState], Estimate] = exact_state,
    progress: Progress | None = None,
    live: LiveRows | None = None,
) -> Series:
    """Run for `duration` s from rest at q0; return the time series and their units (`plant_series`).

    `safe_set` is the controller's (ρ_meas uses its ψ and n_max). A filter fault ends the
    run at the row of its vent (`ControlStep.stopped`; the series then have fewer rows and
    `step.fault` says why). `live` (e.g.
    softcbf_mj.outputs.recording.LiveRun) is sent the rows recorded so far every `live.period_steps`
    steps and at the end (it decides what to send when).
    """
    n_steps = check_duration(duration, plant.control_dt, plant.n_segments, safe_set)
    recorder = Recorder(n_steps, plant.n_segments, plant_columns(plant.n_segments, safe_set.n_facets))
    step.reset()
    state = plant.reset(q0)
    n_rows = n_steps
    for k in range(n_steps):
        est = estimator(state)
        record = step(est)
        recorder.record(k, record, True, plant_values(state, est.q, est.qd), extras=state.extras)
        if step.stopped:  # a filter fault has vented: the run ends on this row (closedloop.step)
            n_rows = k + 1
            break
        state = plant.step(record.u)
        if progress is not None and k % 500 == 0:
            progress.update(k)
        if live is not None and k % live.period_steps == 0:
            live.send(recorder, k + 1)
    if live is not None:
        live.send(recorder, n_rows, force=True)
    if progress is not None:
        progress.close()
    return plant_series(recorder, safe_set, n_rows)
