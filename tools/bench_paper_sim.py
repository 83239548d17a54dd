"""Real-time factor of the `paper_sim` scenario per tuning (simulated s per wall s; docs/model.md#nominal-controller-and-the-papers-scenario).

Runs `paper_sim` (PCC plant, filter at 1 kHz) once per tuning for `--duration` s with
outputs in a temporary folder, and reports per tuning the scenario's own figure
(`realtime_factor`: simulated time over the closed loop's wall time, output writing
excluded) and, for reference, simulated time over the process CPU time of the whole run
(less sensitive to other processes on a shared machine; output writing included).
Ends with one line of JSON.

Usage: python tools/bench_paper_sim.py [--duration 100] [--tunings None,Low,High] [--pressure-limits]
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
from pathlib import Path

from scenarios import get
from timing import emit, timed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=100.0, help="simulated seconds per tuning")
    parser.add_argument("--tunings", default="None,Low,High")
    parser.add_argument("--pressure-limits", action="store_true")
    args = parser.parse_args()
    scenario = get("paper_sim")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.tunings.split(","):
            out_dir = Path(tmp) / name
            out_dir.mkdir()
            summary, took = timed(lambda: scenario.run(out_dir, duration=args.duration, tunings=name,
                                                       pressure_limits=args.pressure_limits, progress=False))
            cpu = took.cpu
            run = summary["runs"][0]
            results[name] = {"realtime_factor": round(run["realtime_factor"], 2), "wall_s": round(run["wall_s"], 2),
                             "cpu_realtime_factor": round(run["sim_s"] / cpu, 2), "cpu_s": round(cpu, 2),
                             "filter_us_median": run["filter_us_median"], "rho_min": run["rho_min_meas"]}
    print(f"\npaper_sim real-time factor, {args.duration:g} s per tuning, pressure limits "
          f"{'on' if args.pressure_limits else 'off'} ({platform.machine()}, {os.cpu_count()} CPUs, "
          f"Python {platform.python_version()})")
    print(f"{'tuning':8s}{'RTF (wall)':>12s}{'wall [s]':>10s}{'RTF (cpu)':>11s}{'cpu [s]':>9s}")
    for name, r in results.items():
        print(f"{name:8s}{r['realtime_factor']:12.1f}{r['wall_s']:10.1f}{r['cpu_realtime_factor']:11.1f}{r['cpu_s']:9.1f}")
    emit({"duration_s": args.duration, "pressure_limits": args.pressure_limits, "tunings": results})


if __name__ == "__main__":
    main()
