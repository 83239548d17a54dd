"""The closed loop: plant → estimator → controller → command → plant (docs/model.md#nominal-controller-and-the-papers-scenario).

At each control step k (t_k = k·Δt): the estimator turns the plant's ground truth
into the controller's view of the state, the nominal controller proposes u_nom,
the safety filter returns u, and the plant holds u for one period. Everything that
happened is recorded at the control rate as arrays with first axis k.

The record is preallocated: T = round(duration / Δt) rows of F floats (F = 1 + 4N +
2(N + 1) + 3N + facets + 1 + P' + 1 for N segments and P' rows of the force-safe set)
and P' + 2 flags. Its peak, T (2 (8F + P' + 2) + 64) bytes (the rows, the columns cut
from them and 8 floats a step for the plant's extras; measured within 8 % above
tracemalloc's peak), is checked against the available memory before a run starts
(`check_duration`), together with a finite duration of at least one period.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from controllers.filter import CBFFilter, CBFResult
from controllers.nominal import NominalController
from controllers.safe_set import ForceSafeSet
from softcbf_mj.plant import Plant, PlantState
from softcbf_mj.progress import Progress


@dataclass(frozen=True)
class Estimate:
    """The controller's view of the state at time t: q, qd (N,), rad and rad/s."""

    t: float
    q: np.ndarray
    qd: np.ndarray


def exact_state(state: PlantState) -> Estimate:
    """Estimator that passes the plant's true state through (the paper's simulation)."""
    return Estimate(state.t, state.q, state.qd)


TIMESERIES_UNITS = {
    "t": "s",
    "q": "rad",
    "qd": "rad/s",
    "q_est": "rad",
    "qd_est": "rad/s",
    "tip": "m",
    "segment_ends": "m",
    "u_nom": "hPa",
    "u": "hPa",
    "u_applied": "hPa",
    "contact_force": "N",
    "rho_pred": "1",
    "rho_meas": "1",
    "b": "barrier units (row-scaled m)",
    "active": "bool",
    "infeasible": "bool",
    "recovery": "bool",
    "filter_us": "us",
}


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


def check_duration(duration: float, control_dt: float, n_segments: int, safe_set: ForceSafeSet) -> int:
    """The number of control steps of a run of `duration` s at period `control_dt` s,
    after checking it: duration finite and > 0, at least one period, and the time series
    (`LoopRecorder.bytes_needed`) within the available memory. Raises ValueError naming
    duration; call it before writing anything."""
    if not (math.isfinite(duration) and duration > 0):
        raise ValueError(f"duration must be finite and > 0 s, got {duration}")
    if not (math.isfinite(control_dt) and control_dt > 0):
        raise ValueError(f"the control period must be finite and > 0 s, got {control_dt}")
    n_steps = int(round(duration / control_dt))
    if n_steps < 1:
        raise ValueError(f"duration must cover at least one control period ({control_dt:g} s), got {duration} s")
    needed, available = LoopRecorder.bytes_needed(n_steps, n_segments, safe_set), available_memory_bytes()
    if needed > available:
        raise ValueError(f"duration {duration:g} s ({n_steps} steps of {control_dt:g} s) needs {needed / 2**30:.1f} GiB "
                         f"for its time series, more than the {available / 2**30:.1f} GiB of memory available; "
                         "shorten duration or lower the rate")
    return n_steps


class LoopRecorder:
    """The time series of a closed loop, one row per plant step (preallocated).

    Each `record` writes one row of floats and one row of flags (a single numpy call
    each); `columns` cuts the per-key arrays (TIMESERIES_UNITS + the plant's extras) from
    them. ρ_meas comes from the plant's measured contact force through the controller's
    force-safe set (its ψ and n_max), ρ_pred from the controller's own estimate.
    """

    def __init__(self, n_steps: int, n_segments: int, safe_set: ForceSafeSet) -> None:
        p = len(safe_set.H_prime)
        self.safe_set, self.n_steps, self._p = safe_set, n_steps, p
        self._float_shapes = self.float_shapes(n_segments, safe_set)
        self._floats = np.empty((n_steps, sum(math.prod(shape) for shape in self._float_shapes.values())))
        self._flags = np.empty((n_steps, p + 2), dtype=bool)  # active (P), infeasible, recovery
        self._extras: dict[str, np.ndarray] = {}

    @staticmethod
    def float_shapes(n_segments: int, safe_set: ForceSafeSet) -> dict[str, tuple[int, ...]]:
        """The per-step shape of every float column."""
        n, p = n_segments, len(safe_set.H_prime)
        return {"t": (), "q": (n,), "qd": (n,), "q_est": (n,), "qd_est": (n,), "segment_ends": (n + 1, 2),
                "u_nom": (n,), "u": (n,), "u_applied": (n,), "contact_force": (safe_set.n_facets,),
                "rho_pred": (), "b": (p,), "filter_us": ()}

    @classmethod
    def bytes_needed(cls, n_steps: int, n_segments: int, safe_set: ForceSafeSet) -> int:
        """Peak memory of a run's time series: the preallocated rows plus the columns cut
        from them (`columns` copies), i.e. twice the rows, plus 8 floats a step for the
        plant's extras."""
        floats = sum(math.prod(shape) for shape in cls.float_shapes(n_segments, safe_set).values())
        flags = len(safe_set.H_prime) + 2
        return n_steps * (2 * (8 * floats + flags) + 8 * 8)

    def record(self, k: int, state: PlantState, est: Estimate, result: CBFResult, filter_us: float) -> None:
        """Row k: the plant's state, the estimate and filter result in force, and the filter's time (µs).

        In a multi-rate loop the result is held between controller calls: pass
        filter_us = NaN on the rows without a call; `infeasible` and `recovery` are then
        recorded False, so their counts are counts of controller calls.
        """
        called = not math.isnan(filter_us)
        self._floats[k] = [state.t, *state.q.tolist(), *state.qd.tolist(), *est.q.tolist(), *est.qd.tolist(),
                           *state.segment_ends.ravel().tolist(), *result.u_nom.tolist(), *result.u.tolist(),
                           *state.u_applied.tolist(), *state.contact_forces.tolist(), result.rho_pred,
                           *result.b.tolist(), filter_us]
        self._flags[k] = [*result.active.tolist(), called and result.infeasible, called and result.recovery]
        for key, value in state.extras.items():
            if key not in self._extras:
                self._extras[key] = np.zeros((self.n_steps,) + np.shape(value))
            self._extras[key][k] = value

    def columns(self, n_rows: int | None = None) -> dict[str, np.ndarray]:
        """The first `n_rows` rows (default all) as arrays by key."""
        rows = self.n_steps if n_rows is None else n_rows
        columns, start = {}, 0
        for key, shape in self._float_shapes.items():
            size = math.prod(shape)
            columns[key] = self._floats[:rows, start : start + size].reshape((rows,) + shape).copy()
            start += size
        p = self._p
        columns["tip"] = columns["segment_ends"][:, -1].copy()
        columns["rho_meas"] = np.min(self.safe_set.margin_from_force(columns["contact_force"]), axis=-1)
        columns["active"] = self._flags[:rows, :p].copy()
        columns["infeasible"], columns["recovery"] = self._flags[:rows, p].copy(), self._flags[:rows, p + 1].copy()
        log = {key: columns[key] for key in TIMESERIES_UNITS}
        log.update({key: value[:rows].copy() for key, value in self._extras.items()})
        return log


def run_closed_loop(
    plant: Plant,
    controller: CBFFilter,
    nominal: NominalController,
    duration: float,
    q0: np.ndarray,
    estimator: Callable[[PlantState], Estimate] = exact_state,
    progress: Progress | None = None,
) -> dict[str, np.ndarray]:
    """Run for `duration` s from rest at q0; return the time series (`LoopRecorder.columns`)."""
    n_steps = check_duration(duration, plant.control_dt, plant.n_segments, controller.safe_set)
    recorder = LoopRecorder(n_steps, plant.n_segments, controller.safe_set)
    clock = time.perf_counter
    state = plant.reset(q0)
    for k in range(n_steps):
        est = estimator(state)
        u_nom = nominal(est.t, est.q, est.qd)
        t0 = clock()
        result: CBFResult = controller.step(np.concatenate((est.q, est.qd)), u_nom)
        filter_us = (clock() - t0) * 1e6
        recorder.record(k, state, est, result, filter_us)
        state = plant.step(result.u)
        if progress is not None and k % 500 == 0:
            progress.update(k)
    if progress is not None:
        progress.close()
    return recorder.columns()
