"""Real-time factors of paper_sim and mujoco_contact through the scenario API, for paired
comparisons between two trees (e.g. before and after the control step became a plug-in).

Runs each scenario `--repeat` times (short: `--paper-s`, `--mujoco-s` simulated s, the
tunings Low and High, data only) and prints, per scenario and tuning, the best of the
repeats of the scenarios' own `realtime_factor` (simulated s over the loop's wall time),
of the CPU time of the whole scenario call per control step (`cpu_us_per_step`, µs,
set-up and saving included) and of the CPU time of the closed loop alone per control
step (`loop_cpu_us_per_step`, µs: `scenarios.common.run_closed_loop`, through which both
trees run the loop, is timed in place). The minimum is the least disturbed by other
processes on a shared machine. Uses only the scenario registry, so it runs on either tree:

    farm-bench -n 5 --vs "sh -c 'PYTHONPATH=OLD exec python tools/bench_loop_pair.py >>/tmp/B 2>&1'" \
        -- sh -c 'PYTHONPATH=NEW exec python tools/bench_loop_pair.py >>/tmp/A 2>&1'

Ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import tempfile
import time
from pathlib import Path

import scenarios.common
from scenarios import get
from scenarios.common import data_only
from timing import emit


class LoopTimer:
    """Wraps `scenarios.common.run_closed_loop` while in use, adding up its CPU time (s) in `cpu_s`."""

    def __init__(self) -> None:
        self.cpu_s = 0.0
        self.loop = scenarios.common.run_closed_loop

    def __enter__(self) -> "LoopTimer":
        def timed(*args, **kwargs):
            start = time.process_time()
            try:
                return self.loop(*args, **kwargs)
            finally:
                self.cpu_s += time.process_time() - start

        scenarios.common.run_closed_loop = timed
        return self

    def __exit__(self, *exc) -> None:
        scenarios.common.run_closed_loop = self.loop


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper-s", type=float, default=5.0, help="simulated s of paper_sim per tuning")
    parser.add_argument("--mujoco-s", type=float, default=3.0, help="simulated s of mujoco_contact per tuning")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each case; the best is reported")
    args = parser.parse_args()
    cases = {"paper_sim": dict(duration=args.paper_s, amplitude=150.0, frequency=0.5),
             "mujoco_contact": dict(duration=args.mujoco_s, amplitude=150.0, frequency=0.25, t0=1.0)}
    out: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp, data_only(), contextlib.redirect_stdout(io.StringIO()):
        for rep in range(args.repeat):
            for scenario, params in cases.items():
                for tuning in ("Low", "High"):
                    folder = Path(tmp) / f"{scenario}-{tuning}-{rep}"
                    folder.mkdir()
                    cpu = time.process_time()
                    with LoopTimer() as loop:
                        summary = get(scenario).run(folder, tunings=tuning, progress=False, **params)
                    cpu = time.process_time() - cpu
                    row = summary["runs"][0]
                    steps = round(row["sim_s"] / 1e-3)
                    best = out.setdefault(f"{scenario}/{tuning}", {"realtime_factor": 0.0, "cpu_us_per_step": math.inf,
                                                                   "loop_cpu_us_per_step": math.inf})
                    best["realtime_factor"] = max(best["realtime_factor"], row["realtime_factor"])
                    best["cpu_us_per_step"] = min(best["cpu_us_per_step"], cpu / steps * 1e6)
                    best["loop_cpu_us_per_step"] = min(best["loop_cpu_us_per_step"], loop.cpu_s / steps * 1e6)
    for key, best in out.items():
        print(f"{key:20s} RTF {best['realtime_factor']:.2f}  CPU {best['cpu_us_per_step']:.1f} us/step  "
              f"loop CPU {best['loop_cpu_us_per_step']:.1f} us/step")
    emit(out)


if __name__ == "__main__":
    main()
