"""Governors (docs/beyond-the-paper.md#filters-beyond-the-paper) on the PCC plant: per-call compute time and per-run figures.

Uses the tests' loop (tests/governor_loop.py: PCC plant at 1 ms ticks, zero-order hold,
the filter given the true state captured `age` s earlier, its command acting `delay` s
after the call, valve lag τ_p), so the figures are those of the tests' setting:
- 1 kHz, exact state, no delay, ideal valve: u_nom = 150 sin(2πt/8 s) hPa on both
  segments for 8 s (free far from the plate, governed near it): call time median/p99.
- 10 Hz camera timing (age 0.03–0.1 s, delay 20 ms, τ_p = 0.05 s): the same sinusoid
  (T = 8 s and 20 s, 1.5 T) and the worst step rest → (150, 150) hPa with τ_p = 0 and
  0.05 s (4 s): ρ_min, governor_figures.
Call times: wall (filter_us_*, what the loop records) and process CPU time (cpu_us_*, less
sensitive to other processes on a shared machine); the table build time is separate.
Prints one line per case and ends with one JSON line. Usage:
    PYTHONPATH=$PWD python tools/bench_governors.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from governor_loop import context, run_loop  # noqa: E402

from controllers.energy_governor import EnergyGovernor  # noqa: E402
from controllers.filter_metrics import governor_figures  # noqa: E402
from controllers.params import reference_robot  # noqa: E402
from controllers.quasi_static_governor import QuasiStaticGovernor  # noqa: E402
from controllers.safe_set import paper_safe_set  # noqa: E402

FACTORIES = {"qsg": QuasiStaticGovernor, "e-erg": EnergyGovernor}


def sinusoid(period_s: float):
    return lambda t: np.full(2, 150.0 * math.sin(2 * math.pi * t / period_s))


def case(name: str, factory, period: float, delay: float, age: tuple, tau: float, nominal, duration: float) -> dict:
    robot, safe = reference_robot(), paper_safe_set()
    t0 = time.perf_counter()
    gov = factory(context(robot, safe, period, delay, tau))
    build_s = time.perf_counter() - t0
    rec = run_loop(gov, robot, safe, nominal, duration, period, delay, age, tau_p=tau, seed=0)
    t = (np.array(rec.apply_ticks) - int(round(delay / 1e-3))) * 1e-3
    u_nom = np.array([nominal(s) for s in t])
    figures = governor_figures(t, np.array(rec.commands), u_nom, rec.call_us)
    cpu = {"cpu_us_median": float(np.median(rec.call_cpu_us)), "cpu_us_p99": float(np.percentile(rec.call_cpu_us, 99))}
    result = {"case": name, "rho_min": float(rec.rho.min()), "calls": len(rec.call_us), "build_s": build_s,
              "u_max_abs_hPa": float(np.max(np.abs(rec.u))), **figures, **cpu}
    print(f"{name:38s} ρ_min {result['rho_min']:+.3f}  calls {result['calls']:5d}  "
          f"wall median/p99 {figures['filter_us_median']:6.0f}/{figures['filter_us_p99']:6.0f} µs  "
          f"CPU {cpu['cpu_us_median']:6.0f}/{cpu['cpu_us_p99']:6.0f} µs  "
          f"blocked {figures['blocked_s']:.1f} s (longest {figures['blocked_longest_s']:.1f} s)  "
          f"dev rms {figures['u_dev_rms_hPa']:.1f} hPa  switches {figures['switches_per_s']:.2f}/s  build {build_s:.1f} s")
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (1 kHz: 2 s; sinusoids: T = 8 s only)")
    args = parser.parse_args()
    results = []
    for label, factory in FACTORIES.items():
        results.append(case(f"{label} 1 kHz sin T=8s", factory, 1e-3, 0.0, (0.0, 0.0), 0.0, sinusoid(8.0),
                            2.0 if args.quick else 8.0))
        for period_s in (8.0,) if args.quick else (8.0, 20.0):
            results.append(case(f"{label} 10 Hz camera sin T={period_s:g}s", factory, 0.1, 0.02, (0.03, 0.1), 0.05,
                                sinusoid(period_s), 1.5 * period_s))
        for tau in (0.0, 0.05):
            results.append(case(f"{label} 10 Hz camera step 150/150 τ={tau:g}", factory, 0.1, 0.02, (0.03, 0.1), tau,
                                lambda t: np.array([150.0, 150.0]), 4.0))
    print(json.dumps({"quick": args.quick, "results": results}))


if __name__ == "__main__":
    main()
