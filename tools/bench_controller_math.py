"""Time the controller maths of one filter step (no QP): model evaluation and barrier terms.

Usage: python tools/bench_controller_math.py [--segments 2] [--calls 20000]
Prints per-call medians and 99th percentiles (µs) over random states of the reference
arm (or a uniform arm of N segments), then one line of JSON with the same figures.
"""

from __future__ import annotations

import argparse

import numpy as np

from controllers.cbf.barrier import barrier_terms, get_tuning
from controllers.model.dynamics import PCCDynamics
from controllers.model.params import uniform_robot
from timing import calls_us, emit


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--segments", type=int, default=2)
    parser.add_argument("--calls", type=int, default=20000)
    args = parser.parse_args()
    dyn = PCCDynamics(uniform_robot(args.segments))
    n = dyn.n
    rng = np.random.default_rng(0)
    states = [(rng.uniform(-0.8, 0.8, n), rng.normal(0, 1, n)) for _ in range(args.calls)]
    u = np.full(n, 50.0)
    tuning = get_tuning("Low")
    facets = {p: (np.array([[0.36, 1.0], [1.0, 0.2], [-1.0, 0.3]][:p]), np.array([0.3, 0.35, 0.4][:p])) for p in (1, 3)}

    def step(q, qd, p):
        return barrier_terms(dyn.evaluate(q, qd), *facets[p], tuning)

    cases = {
        "evaluate": (dyn.evaluate, states),
        "filter_math_P1": (step, [(q, qd, 1) for q, qd in states]),
        "filter_math_P3": (step, [(q, qd, 3) for q, qd in states]),
        "acceleration": (dyn.acceleration, [(q, qd, u) for q, qd in states]),
        "acceleration_jacobian": (dyn.acceleration_jacobian, [(q, qd, u) for q, qd in states[: args.calls // 4]]),
    }
    figures = {"segments": n, "calls": args.calls}
    for name, (func, arg_list) in cases.items():
        calls_us(func, arg_list[:500])  # warm-up
        t = np.asarray(calls_us(func, arg_list))
        figures[f"{name}_us_median"] = round(float(np.median(t)), 2)
        figures[f"{name}_us_p99"] = round(float(np.percentile(t, 99)), 2)
        print(f"{name:24s} median {np.median(t):7.2f} µs   p99 {np.percentile(t, 99):7.2f} µs")
    emit(figures)


if __name__ == "__main__":
    main()
