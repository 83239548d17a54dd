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

from controllers.params import RobotParams
from controllers.safe_set import ForceSafeSet
from controllers.safety_filter import Estimate, FilterContext, as_output
from softcbf_mj.pcc_plant import PCCPlant

TICK = 1e-3


@dataclass
class LoopRecord:
    t: np.ndarray  # (T,) s
    u: np.ndarray  # (T, N) hPa, the command acting during the tick that ends at t
    u_nom: np.ndarray  # (T, N) hPa, the latest u_nom given to the filter
    rho: np.ndarray  # (T,) margin of the true tip at t
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
             tau_p: float = 0.05, seed: int = 0) -> LoopRecord:
    rng = np.random.default_rng(seed)
    plant = PCCPlant(robot, safe_set, control_dt=TICK, tau_p=tau_p)
    n = robot.n_segments
    state = plant.reset(np.zeros(n))
    if hasattr(safety_filter, "reset"):
        safety_filter.reset()
    ticks, per_call, delay_ticks = int(round(duration / TICK)), int(round(period / TICK)), int(round(delay / TICK))
    history_q, history_qd = [state.q], [state.qd]
    acting, pending = np.zeros(n), []  # pending: (tick, u)
    rec = {k: [] for k in ("t", "u", "u_nom", "rho", "q", "qd", "p")}
    apply_ticks, commands, outputs, call_us, call_cpu_us, last_nom = [], [], [], [], [], np.zeros(n)
    for k in range(ticks):
        if k % per_call == 0:
            age = int(round(rng.uniform(*age_range) / TICK))
            j = max(k - age, 0)
            last_nom = np.asarray(u_nom(k * TICK), dtype=float)
            est = Estimate(k * TICK, history_q[j], history_qd[j], j * TICK)
            t0, c0 = time.perf_counter(), time.process_time()
            out = as_output(safety_filter(est, last_nom))
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
        rec["q"].append(state.q)
        rec["qd"].append(state.qd)
        rec["p"].append(state.u_applied)
    arrays = {k: np.array(v) for k, v in rec.items()}
    return LoopRecord(**arrays, apply_ticks=apply_ticks, commands=commands, outputs=outputs, call_us=np.array(call_us),
                      call_cpu_us=np.array(call_cpu_us))
