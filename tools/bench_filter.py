"""Time one CBF filter step (state → command) of the paper's scenario, N = 2, P = 1 (docs/model.md#control-barrier-function, docs/model.md#nominal-controller-and-the-papers-scenario).

For each tuning (Low, High) and pressure limits off/on, the paper's closed loop (sinusoid
into the facet, PCC plant, filter at 1 kHz) runs for `--duration` s; `--samples` states
(x, u_nom) are taken evenly along that trajectory, so the QP is active, inactive, infeasible
or recovering as often as in the real run (the action counts are printed). Each state is
then timed through `CBFFilter.__call__` (dynamics, barrier terms, Lie derivatives, QP when
needed), round-robin over the four filters and a bare `PCCPlant.step` from the same
states, so that drifting machine load biases none of them. The garbage collector is off
while timing (as in timeit); the default clock is this thread's CPU time (immune to other
processes on a shared machine; --clock wall for elapsed time).

Prints per configuration the median and p99 (µs), the ratio to the paper's average QP
solve (0.31 ms, MATLAB quadprog) and to the bare plant step, then one line of JSON. With
several --backends, every backend filters the same states, round-robin in one process,
and each row also says whether its actions equal the first backend's and how far its
commands are from them (hPa).

Usage: python tools/bench_filter.py [--samples 4000] [--duration 100] [--clock cpu|wall] [--backends native,daqp]
"""

from __future__ import annotations

import argparse
import gc
import math
import os
import platform
from collections import Counter

import numpy as np

from closedloop.step import ControlStep
from controllers.contract.safety_filter import FilterContext
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.cbf.qp import DEFAULT_BACKEND
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant
from timing import CLOCKS_NS, clock_ns, emit, summary_us

PAPER_QP_US = 310.0  # paper §VI: average QP solve time, MATLAB quadprog
FIGURES = ("median", "p99", "mean")


def summary(times_us: list[float]) -> dict[str, float]:
    return summary_us(times_us, FIGURES)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=4000, help="states per configuration")
    parser.add_argument("--duration", type=float, default=100.0, help="trajectory length (s); the paper's run is 100 s")
    parser.add_argument("--tunings", default="Low,High")
    parser.add_argument("--clock", choices=list(CLOCKS_NS), default="cpu")
    parser.add_argument("--backends", default=DEFAULT_BACKEND,
                        help="comma-separated QP backends (controllers.cbf.qp), timed round-robin with each other")
    args = parser.parse_args()
    clock = clock_ns(args.clock)
    robot, safe_set = reference_robot(), paper_safe_set()
    nominal = SinusoidNominal.paper(robot.n_segments)

    backends = args.backends.split(",")
    configs: dict[str, tuple[CBFFilter, list[tuple[np.ndarray, np.ndarray]]]] = {}
    reference: dict[str, str] = {}  # configuration → the same one with the first backend
    plant_cases: list[tuple[np.ndarray, np.ndarray]] = []
    for name in args.tunings.split(","):
        for limits in (False, True):
            tuning = get_tuning(name)
            step = ControlStep(CBFFilter(robot, safe_set, tuning, pressure_limits=limits), nominal,
                               FilterContext.for_robot(robot, safe_set, 1e-3, limits))
            log, _ = run_closed_loop(PCCPlant(robot, safe_set), step, safe_set, args.duration, np.zeros(robot.n_segments))
            picks = np.linspace(0, len(log["t"]) - 1, args.samples).round().astype(int)
            states = [(np.concatenate((log["q"][k], log["qd"][k])), log["u_nom"][k]) for k in picks]
            for backend in backends:
                label = f"{tuning.name} limits {'on' if limits else 'off'}" + (f" {backend}" if len(backends) > 1 else "")
                configs[label] = (CBFFilter(robot, safe_set, tuning, pressure_limits=limits, qp_backend=backend), states)
                reference[label] = reference.get(label.removesuffix(f" {backend}"), label)
                reference.setdefault(label.removesuffix(f" {backend}"), label)
            plant_cases += [(log["q"][k], log["qd"][k], log["u"][k]) for k in picks[:: 4]]

    plant = PCCPlant(robot, safe_set)
    times: dict[str, list[float]] = {key: [] for key in configs}
    plant_times: list[float] = []
    outputs = {key: [filt.step(x, u) for x, u in states] for key, (filt, states) in configs.items()}
    actions = {key: Counter(r.action for r in out) for key, out in outputs.items()}
    gc.disable()
    for k in range(args.samples):
        for key, (filt, states) in configs.items():
            x, u_nom = states[k]
            start = clock()
            filt.step(x, u_nom)
            times[key].append((clock() - start) / 1e3)
        if k < len(plant_cases):
            q, qd, u = plant_cases[k]
            plant.reset(q, qd)  # untimed: sets the state (and its model terms, as a previous step would)
            start = clock()
            plant.step(u)
            plant_times.append((clock() - start) / 1e3)
    gc.enable()

    plant_fig = summary(plant_times)
    results = {}
    for key in configs:
        fig = summary(times[key])
        fig["vs_paper_qp"] = round(fig["median_us"] / PAPER_QP_US, 4)
        fig["vs_plant_step"] = round(fig["median_us"] / plant_fig["median_us"], 3)
        fig["actions"] = dict(actions[key])
        solved = [t for t, r in zip(times[key], outputs[key]) if r.action != "nominal"]
        fig["qp_steps_median_us"] = round(float(np.median(solved)), 2) if solved else None
        ref = outputs[reference[key]]
        fig["same_actions_as_first_backend"] = all(r.action == s.action for r, s in zip(outputs[key], ref))
        fig["max_du_vs_first_backend_hPa"] = max(float(np.max(np.abs(r.u - s.u))) for r, s in zip(outputs[key], ref))
        results[key] = fig
    print(f"CBF filter step, QP backend(s) {args.backends}, {args.clock} time, N=2, P=1, {args.samples} states along a {args.duration:g} s paper_sim "
          f"trajectory per configuration ({platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, "
          f"numpy {np.__version__})")
    header = (f"{'configuration':28s}{'median':>9s}{'p99':>9s}{'mean':>9s}{'/0.31ms':>9s}{'/plant':>8s}"
              f"{'QP med':>8s}{'max|Δu|':>10s}  actions")
    print(header)
    print("-" * len(header))
    for key, fig in results.items():
        counts = ", ".join(f"{a} {c}" for a, c in sorted(fig["actions"].items()))
        print(f"{key:28s}{fig['median_us']:9.1f}{fig['p99_us']:9.1f}{fig['mean_us']:9.1f}"
              f"{fig['vs_paper_qp']:9.3f}{fig['vs_plant_step']:8.2f}{fig['qp_steps_median_us'] or math.nan:8.1f}"
              f"{fig['max_du_vs_first_backend_hPa']:10.1e}  {counts}"
              + ("" if fig["same_actions_as_first_backend"] else "  (actions differ from the first backend's)"))
    print(f"{'bare PCC plant step':28s}{plant_fig['median_us']:9.1f}{plant_fig['p99_us']:9.1f}{plant_fig['mean_us']:9.1f}"
          f"   (ROS2, 1 ms, {len(plant_times)} states)")
    print("(µs; /0.31ms: median over the paper's average QP solve; /plant: median over the plant step's median;"
          " QP med: median over the steps that solved a QP (action not 'nominal');"
          " max|Δu|: hPa, largest command difference from the first backend on the same states)")
    emit({"unit": "us", "clock": args.clock, "backends": args.backends.split(","), "samples": args.samples, "duration_s": args.duration,
          "paper_qp_us": PAPER_QP_US, "plant_step": plant_fig, "filter": results})


if __name__ == "__main__":
    main()
