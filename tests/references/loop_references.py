"""Reference time series of the paper's filter through the three clocks (paper_sim,
mujoco_contact, camera_loop), for tests/test_loop_references.py.

Runs short scenarios (every paper tuning, the filter active: large, fast sinusoids or a
start at the sinusoid's peak) with the Python API and stores, per run, every
DECIMATE-th row of the columns that do not depend on wall time (timing columns such as
filter_us are left out) in one compressed .npz: key "<case>/<tuning>/<column>".

The stored file is a result, not a pin on floats: a change that moves these series regenerates it once and says
in the CHANGELOG how far the figures moved (commands, ρ, force), measured with --compare before and after:

    python tests/references/loop_references.py /tmp/new.npz
    python tests/references/loop_references.py --compare tests/data/loop_references.npz /tmp/new.npz
    cp /tmp/new.npz tests/data/loop_references.npz

The test compares a fresh run with the file within RTOL and ATOL (each column's unit: hPa, rad, N, 1, ...),
boolean and integer columns exactly. Prints the figures it stored and ends with one JSON line.
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
REFERENCE_FILE = Path(__file__).resolve().parents[1] / "data" / "loop_references.npz"
RTOL, ATOL = 1e-9, 1e-6
"""The test's tolerance per column (relative, and absolute in the column's unit). The rounding of the filter's QP
moves these closed loops by ≈ 1e-8 hPa (the batched kernel replacing the scalar QP at one state moved u_applied by at
most 2.2e-8 hPa, ρ by 4e-10, the force by 6.4e-11 N): ATOL leaves a factor of about 50 above that, and is still far
below any figure the tests or the docs report (ρ to 1e-3, forces to 1e-3 N, commands to 0.1 hPa)."""


def run_cases() -> tuple[dict[str, np.ndarray], dict[str, dict]]:
    """Every case: the stored arrays ("<case>/<tuning>/<column>") and each run's figures."""
    from scenarios import get
    from scenarios.run_outputs import data_only
    from softcbf_mj.outputs.runio import load_timeseries

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
    return arrays, figures


def differences(old, new) -> dict[str, dict]:
    """Per column: the largest |new − old| over every run (float columns) or the count of differing entries
    (boolean and integer columns); ValueError when the keys or shapes differ."""
    if set(old) != set(new):
        raise ValueError(f"the files hold different series: {sorted(set(old) ^ set(new))[:5]}")
    result: dict[str, dict] = {}
    for key in sorted(old):
        a, b = np.asarray(old[key]), np.asarray(new[key])
        if a.shape != b.shape:
            raise ValueError(f"{key} has shape {a.shape} in one file and {b.shape} in the other")
        column = key.rsplit("/", 1)[1]
        entry = result.setdefault(column, {"max_abs": 0.0, "differing": 0})
        if a.dtype.kind in "biu":
            entry["differing"] += int(np.sum(a != b))
        elif a.size:
            entry["max_abs"] = max(entry["max_abs"], float(np.max(np.abs(a - b))))
    return result


def main(argv: list[str]) -> int:
    if len(argv) == 3 and argv[0] == "--compare":
        with np.load(argv[1]) as old, np.load(argv[2]) as new:
            result = differences(dict(old), dict(new))
        for column, entry in result.items():
            print(f"{column:14s} max |diff| {entry['max_abs']:.3g}  differing {entry['differing']}")
        print(json.dumps({"old": argv[1], "new": argv[2], "columns": result}))
        return 0
    if len(argv) != 1:
        print("usage: python tests/references/loop_references.py OUT.npz | --compare OLD.npz NEW.npz", file=sys.stderr)
        return 2
    arrays, figures = run_cases()
    np.savez_compressed(argv[0], **arrays)
    print(json.dumps({"file": argv[0], "arrays": len(arrays), "runs": figures}))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
