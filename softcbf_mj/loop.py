"""The closed loop: plant → estimator → controller → command → plant (SPEC §6).

At each control step k (t_k = k·Δt): the estimator turns the plant's ground truth
into the controller's view of the state, the nominal controller proposes u_nom,
the safety filter returns u, and the plant holds u for one period. Everything that
happened is recorded at the control rate as arrays with first axis k.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from controllers.filter import CBFFilter, FilterResult
from controllers.nominal import NominalController
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


def run_closed_loop(
    plant: Plant,
    controller: CBFFilter,
    nominal: NominalController,
    duration: float,
    q0: np.ndarray,
    estimator: Callable[[PlantState], Estimate] = exact_state,
    progress: Progress | None = None,
) -> dict[str, np.ndarray]:
    """Run for `duration` s from rest at q0; return the time series (keys: TIMESERIES_UNITS + plant extras).

    ρ_meas comes from the plant's measured contact force through the controller's
    force-safe set (its ψ and n_max), ρ_pred from the controller's own estimate.
    """
    n_steps = int(round(duration / plant.control_dt))
    if n_steps < 1:
        raise ValueError(f"duration must cover at least one control period ({plant.control_dt} s), got {duration}")
    safe_set = controller.safe_set
    n, p = plant.n_segments, len(controller.safe_set.H_prime)
    log = {
        "t": np.empty(n_steps),
        "q": np.empty((n_steps, n)),
        "qd": np.empty((n_steps, n)),
        "q_est": np.empty((n_steps, n)),
        "qd_est": np.empty((n_steps, n)),
        "tip": np.empty((n_steps, 2)),
        "segment_ends": np.empty((n_steps, n + 1, 2)),
        "u_nom": np.empty((n_steps, n)),
        "u": np.empty((n_steps, n)),
        "u_applied": np.empty((n_steps, n)),
        "contact_force": np.empty((n_steps, safe_set.n_facets)),
        "rho_pred": np.empty(n_steps),
        "rho_meas": np.empty(n_steps),
        "b": np.empty((n_steps, p)),
        "active": np.empty((n_steps, p), dtype=bool),
        "infeasible": np.empty(n_steps, dtype=bool),
        "recovery": np.empty(n_steps, dtype=bool),
        "filter_us": np.empty(n_steps),
    }
    extras: dict[str, np.ndarray] = {}
    state = plant.reset(q0)
    for k in range(n_steps):
        est = estimator(state)
        u_nom = nominal(est.t, est.q, est.qd)
        t0 = time.perf_counter()
        result: FilterResult = controller(np.concatenate((est.q, est.qd)), u_nom)
        filter_us = (time.perf_counter() - t0) * 1e6
        log["t"][k] = state.t
        log["q"][k], log["qd"][k] = state.q, state.qd
        log["q_est"][k], log["qd_est"][k] = est.q, est.qd
        log["tip"][k] = state.tip
        log["segment_ends"][k] = state.segment_ends
        log["u_nom"][k], log["u"][k] = result.u_nom, result.u
        log["u_applied"][k] = state.u_applied
        log["contact_force"][k] = state.contact_forces
        log["rho_pred"][k] = result.rho_pred
        log["rho_meas"][k] = np.min(safe_set.margin_from_force(state.contact_forces))
        log["b"][k] = result.b
        log["active"][k] = result.active
        log["infeasible"][k] = result.infeasible
        log["recovery"][k] = result.recovery
        log["filter_us"][k] = filter_us
        for key, value in state.extras.items():
            if key not in extras:
                extras[key] = np.empty((n_steps,) + np.shape(value))
            extras[key][k] = value
        state = plant.step(result.u)
        if progress is not None and k % 500 == 0:
            progress.update(k)
    if progress is not None:
        progress.close()
    log.update(extras)
    return log
