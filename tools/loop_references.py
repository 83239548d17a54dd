"""Reference time series of the paper's filter through the three clocks (paper_sim,
mujoco_contact, camera_loop), for tests/test_loop_references.py.

Runs short scenarios (every paper tuning, the filter active: large, fast sinusoids or a
start at the sinusoid's peak) with the Python API and stores, per run, every
DECIMATE-th row of the columns that do not depend on wall time (timing columns such as
filter_us are left out) in one compressed .npz: key "<case>/<tuning>/<column>".
The stored file was generated from the tree before the control step became a plug-in (REV, the
commit its name ends with), with this script on the PYTHONPATH of a worktree of that commit:

    git worktree add --detach ../ref REV
    PYTHONPATH=../ref python tools/loop_references.py tests/data/loop_references_REV.npz

It uses only the scenario registry and the run-folder time series, which both commits share.
Prints the figures it stored and ends with one JSON line.
"""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np

DECIMATE = 10
COLUMNS = ("t", "q", "qd", "q_est", "qd_est", "u_nom", "u", "u_applied", "contact_force", "rho_pred", "rho_meas", "b",
           "active", "infeasible", "recovery")
CASES = {
    "paper_sim": ("paper_sim", dict(duration=1.0, tunings="None,Low,High", amplitude=150.0, frequency=0.5)),
    "paper_sim_limits": ("paper_sim", dict(duration=1.0, tunings="Low,High", amplitude=150.0, frequency=0.5,
                                           pressure_limits=True)),
    "mujoco_contact": ("mujoco_contact", dict(duration=1.0, tunings="None,Low,High,HW-Low,HW-High", amplitude=150.0,
                                              frequency=0.25, t0=1.0)),
    "camera_loop": ("camera_loop", dict(duration=1.5, tunings="None,HW-Low,HW-High", amplitude=150.0, frequency=0.25,
                                        t0=1.0, saved_frames_hz=0.0, width=640, height=360)),
}


def main(out: str) -> int:
    from scenarios import get
    from scenarios.common import data_only
    from softcbf_mj.runio import load_timeseries

    arrays: dict[str, np.ndarray] = {}
    figures: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp, data_only():
        for case, (scenario, params) in CASES.items():
            folder = Path(tmp) / case
            folder.mkdir()
            summary = get(scenario).run(folder, progress=False, **params)
            for run in summary["runs"]:
                series, _ = load_timeseries(folder / run["timeseries"])
                for column in COLUMNS:
                    arrays[f"{case}/{run['tuning']}/{column}"] = np.asarray(series[column])[::DECIMATE]
                figures[f"{case}/{run['tuning']}"] = {"active_steps": run["active_steps"],
                                                      "rho_min_meas": run["rho_min_meas"]}
                print(case, run["tuning"], figures[f"{case}/{run['tuning']}"])
    np.savez_compressed(out, **arrays)
    print(json.dumps({"file": out, "arrays": len(arrays), "runs": figures}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
