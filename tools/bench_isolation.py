"""The cost of isolation (closedloop.isolation): µs per control call, in-process against isolated.

    python tools/bench_isolation.py [--filter paper-cbf] [--tuning High] [--calls 3000] [--camera-calls 100]

One control call is `ControlStep.__call__` (nominal, filter, admission, monitor) on the paper's
PCC plant (paper_sim: the reference arm, its facet, the sinusoid nominal) with the filter under
test; the plant's own step is not timed. Two rates:
- 1 kHz (paper_sim's control rate): `--calls` calls back to back, the plant stepped between them
  (the simulated loop: no pause, the isolated process is woken at once);
- the camera rate (10 Hz): `--camera-calls` calls paced in real time, one per 100 ms (the
  camera loop on the hardware: the isolated process sleeps between calls, and waking it is part
  of the cost).
For each: the median and p99 (µs) of the call, in-process and isolated, and the added cost
(isolated − in-process, of the medians and of the p99s). The isolated process is started and
its first call (imports, compiled kernels) made before timing. Prints its figures, then one
JSON line. The figures depend on the machine's load (two processes must be scheduled each call).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np
from timing import emit


def timed_calls(isolated: bool, filter_spec: str, filter_params: dict, control_dt: float, calls: int,
                paced: bool) -> np.ndarray:
    """µs of each of `calls` control calls (module docstring) with the filter isolated or in-process."""
    from closedloop.isolation import isolate
    from closedloop.step import ControlStep
    from controllers.registry import build_filter, build_nominal
    from controllers.contract.safety_filter import Estimate, FilterContext
    from scenarios.common import build_safe_set
    from controllers.model.params import reference_robot
    from softcbf_mj.physics.pcc_plant import PCCPlant

    robot = reference_robot()
    safe_set = build_safe_set("paper", 11.16, 0.16, "paper")
    plant = PCCPlant(robot, safe_set, control_dt=control_dt)
    context = FilterContext.for_robot(robot, safe_set, control_dt, False, actuator_tau=0.0, command_delay=0.0)
    nominal = ("sinusoid", {"amplitude": 80.0, "frequency": 0.01 * 1e-3 / control_dt})
    if isolated:
        filters, nominals = isolate(context, [(filter_spec, filter_params)], [nominal])
        step = ControlStep(filters[0], nominals[0], context)
    else:
        step = ControlStep(build_filter(filter_spec, filter_params, context), build_nominal(*nominal, context), context)
    step.reset()
    state = plant.reset(np.zeros(robot.n_segments))
    step(Estimate(state.t, state.q, state.qd, state.t))  # the first call: imports, compiled kernels
    state = plant.reset(np.zeros(robot.n_segments))
    step.reset()
    out = np.empty(calls)
    clock = time.perf_counter
    for k in range(calls):
        if paced:
            time.sleep(max(0.0, control_dt - (clock() % control_dt)))
        estimate = Estimate(state.t, state.q, state.qd, state.t)
        start = clock()
        record = step(estimate)
        out[k] = (clock() - start) * 1e6
        state = plant.step(record.u)
    if step.fault is not None:
        raise RuntimeError(f"the filter faulted during the benchmark: {step.fault.line()}")
    return out


def figures(filter_spec: str, filter_params: dict, control_dt: float, calls: int, paced: bool) -> dict:
    """Median and p99 (µs) in-process and isolated, and the added cost, at one rate."""
    out: dict[str, float] = {}
    for mode, isolated in (("in_process", False), ("isolated", True)):
        times = timed_calls(isolated, filter_spec, filter_params, control_dt, calls, paced)
        out[f"{mode}_median_us"], out[f"{mode}_p99_us"] = float(np.median(times)), float(np.percentile(times, 99))
    out["added_median_us"] = out["isolated_median_us"] - out["in_process_median_us"]
    out["added_p99_us"] = out["isolated_p99_us"] - out["in_process_p99_us"]
    out["calls"] = calls
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--filter", default="paper-cbf", help="the filter under test (a registry spec)")
    parser.add_argument("--tuning", default="High", help="the paper filter's tuning (other filters: ignored)")
    parser.add_argument("--calls", type=int, default=3000, help="control calls at 1 kHz per mode")
    parser.add_argument("--camera-calls", type=int, default=100, help="control calls at 10 Hz per mode (paced)")
    args = parser.parse_args()
    params = {"tuning": args.tuning} if args.filter == "paper-cbf" else {}
    report = {"filter": args.filter, "filter_params": params, "machine": platform.processor() or platform.machine(),
              "python": platform.python_version()}
    for name, dt, calls, paced in (("1kHz", 1e-3, args.calls, False), ("10Hz", 0.1, args.camera_calls, True)):
        report[name] = result = figures(args.filter, params, dt, calls, paced)
        print(f"{name}: in-process median {result['in_process_median_us']:.1f} µs, p99 {result['in_process_p99_us']:.1f}; "
              f"isolated median {result['isolated_median_us']:.1f} µs, p99 {result['isolated_p99_us']:.1f}; "
              f"added median {result['added_median_us']:.1f} µs, p99 {result['added_p99_us']:.1f} ({calls} calls)")
    emit(report)


if __name__ == "__main__":
    main()
