"""Digests of the simulated loops' time series, to check that a change to the loop's machinery
(control step, recorder, monitor, filter packaging, plant I/O) leaves every recorded value
bit-identical.

Runs paper_sim (tunings None, Low, High; pressure limits off and on) and mujoco_contact
(None, Low, High; the ideal plate, and the flexure plate with tip friction) for short durations through the scenario API, loads each run's saved time
series and prints, per run, the SHA-256 of every column's bytes (dtype and shape included)
except the wall-time columns (`WALL_TIME_COLUMNS`: they differ between any two runs), and
the columns' units. Compare the JSON line of two trees:

    PYTHONPATH=OLD python tools/loop_digest.py > /tmp/old.json
    PYTHONPATH=NEW python tools/loop_digest.py > /tmp/new.json
    diff <(tail -1 /tmp/old.json) <(tail -1 /tmp/new.json) && echo bit-identical

Ends with one line of JSON: {"run": {"column": "sha256 dtype shape", ..., "units": "sha256"}}.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import tempfile
from pathlib import Path

from scenarios import get
from scenarios.common import data_only
from softcbf_mj.outputs.runio import load_timeseries

WALL_TIME_COLUMNS = ("filter_us", "solve_us")  # measured times (µs): not reproducible


def digests(folder: Path) -> dict[str, dict[str, str]]:
    """Per saved run under `folder`: column → 'sha256 dtype shape', and 'units' → sha256 of the units."""
    out = {}
    for path in sorted(folder.glob("timeseries/*.npz")):
        columns, units = load_timeseries(path)
        row = {key: f"{hashlib.sha256(value.tobytes()).hexdigest()[:16]} {value.dtype} {value.shape}"
               for key, value in sorted(columns.items()) if key not in WALL_TIME_COLUMNS}
        row["units"] = hashlib.sha256(json.dumps(units, sort_keys=True).encode()).hexdigest()[:16]
        out[path.stem] = row
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--paper-s", type=float, default=3.0, help="simulated s of paper_sim per tuning")
    parser.add_argument("--mujoco-s", type=float, default=1.5, help="simulated s of mujoco_contact per tuning")
    args = parser.parse_args()
    cases = {
        "paper_sim": dict(duration=args.paper_s, amplitude=150.0, frequency=0.5),
        "paper_sim-limits": dict(duration=args.paper_s, amplitude=150.0, frequency=0.5, pressure_limits=True),
        "mujoco_contact": dict(duration=args.mujoco_s, amplitude=150.0, frequency=0.25, t0=0.5),
        "mujoco_contact-flexure": dict(duration=args.mujoco_s, amplitude=150.0, frequency=0.25, t0=0.5, tip_friction=0.5,
                                       plate="flexure"),
    }
    result: dict[str, dict[str, str]] = {}
    with tempfile.TemporaryDirectory() as tmp, data_only(), contextlib.redirect_stdout(io.StringIO()):
        for case, params in cases.items():
            folder = Path(tmp) / case
            folder.mkdir()
            get(case.split("-")[0]).run(folder, tunings="None,Low,High", progress=False, **params)
            result.update({f"{case}/{run}": row for run, row in digests(folder).items()})
    for run, row in result.items():
        print(f"{run:28s} {len(row) - 1} columns")
    print(json.dumps(result, sort_keys=True))


if __name__ == "__main__":
    main()
