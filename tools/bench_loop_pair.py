"""Real-time factors of paper_sim and mujoco_contact through the scenario API, for paired
comparisons between two trees (e.g. before and after the control step became a plug-in).

Runs each scenario once per repetition (short: `--paper-s`, `--mujoco-s` simulated s, the
tunings Low and High, data only) and prints, per scenario and tuning, the scenarios' own
`realtime_factor` (simulated s over the loop's wall time) and the CPU time of the run per
control step (µs; less sensitive to other processes on a shared machine). Uses only the
scenario registry, so it runs on either tree:

    farm-bench -n 5 --vs "sh -c 'PYTHONPATH=OLD exec python tools/bench_loop_pair.py >>/tmp/B 2>&1'" \
        -- sh -c 'PYTHONPATH=NEW exec python tools/bench_loop_pair.py >>/tmp/A 2>&1'

Ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from scenarios import get
from scenarios.common import data_only


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper-s", type=float, default=5.0, help="simulated s of paper_sim per tuning")
    parser.add_argument("--mujoco-s", type=float, default=2.0, help="simulated s of mujoco_contact per tuning")
    args = parser.parse_args()
    cases = {"paper_sim": dict(duration=args.paper_s, amplitude=150.0, frequency=0.5),
             "mujoco_contact": dict(duration=args.mujoco_s, amplitude=150.0, frequency=0.25, t0=1.0)}
    out: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp, data_only():
        for scenario, params in cases.items():
            for tuning in ("Low", "High"):
                folder = Path(tmp) / f"{scenario}-{tuning}"
                folder.mkdir()
                cpu = time.process_time()
                summary = get(scenario).run(folder, tunings=tuning, progress=False, **params)
                cpu = time.process_time() - cpu
                row = summary["runs"][0]
                steps = round(row["sim_s"] / 1e-3)
                out[f"{scenario}/{tuning}"] = {"realtime_factor": row["realtime_factor"],
                                               "cpu_us_per_step": cpu / steps * 1e6}
                print(f"{scenario:15s} {tuning:5s} RTF {row['realtime_factor']:.2f}  CPU {cpu / steps * 1e6:.1f} us/step")
    print(json.dumps(out))


if __name__ == "__main__":
    main()
