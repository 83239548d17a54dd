"""Instructions per control step of paper_sim / mujoco_contact through the scenario API, counted
by valgrind's callgrind: a figure that other processes on a shared machine do not disturb
(CPU times there scatter by ±10 %), for paired comparisons between two trees.

For each case it runs one scenario call of `--short` and one of `--long` simulated s (data
only, after a warm-up call in the same process, so imports and first-use caches are not
counted) under `valgrind --tool=callgrind --instr-atstart=no`, with the instrumentation on
for that call alone, and reports (I_long − I_short) / (steps_long − steps_short): the
instructions of one control step, saving of its row included, set-up excluded. Each call
takes minutes (valgrind runs Python ~50× slower); runs on either tree:

    PYTHONPATH=OLD python tools/loop_instructions.py paper_sim:Low
    PYTHONPATH=NEW python tools/loop_instructions.py paper_sim:Low

Instructions are not time (numpy and MuJoCo run more instructions per cycle than the
interpreter), but equal counts of the same work on two trees mean equal work.
Ends with one line of JSON: {"scenario/tuning": instructions per step}.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CONTROL_DT = 1e-3  # s: both scenarios' control period
PARAMS = {"paper_sim": dict(amplitude=150.0, frequency=0.5),
          "mujoco_contact": dict(amplitude=150.0, frequency=0.25, t0=1.0)}


def wait_for(path: Path, process: subprocess.Popen) -> None:
    """Until `path` exists; RuntimeError if `process` ends first."""
    while not path.exists():
        if process.poll() is not None:
            raise RuntimeError(f"the measured process ended (exit {process.returncode}) before {path.name}")
        time.sleep(0.2)


def measured_call(scenario: str, tuning: str, duration: float, handshake: Path) -> None:
    """In the measured process: warm up, signal `ready`, wait for `go`, run the call, signal `done`, wait for `end`."""
    from scenarios import get
    from scenarios.common import data_only

    def wait(name: str) -> None:
        while not (handshake / name).exists():
            time.sleep(0.05)

    with tempfile.TemporaryDirectory() as tmp, data_only(), contextlib.redirect_stdout(io.StringIO()):
        for folder, seconds in (("warm", 0.02), ("measured", duration)):
            (Path(tmp) / folder).mkdir()
            if folder == "measured":
                (handshake / "ready").touch()
                wait("go")
            get(scenario).run(Path(tmp) / folder, tunings=tuning, progress=False, duration=seconds, **PARAMS[scenario])
        (handshake / "done").touch()
        wait("end")


def instructions(scenario: str, tuning: str, duration: float) -> int:
    """Instructions (callgrind's Ir) of one scenario call of `duration` s."""
    with tempfile.TemporaryDirectory() as tmp:
        handshake, out = Path(tmp), Path(tmp) / "callgrind.out"
        process = subprocess.Popen(
            ["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}", sys.executable,
             __file__, "--measured", scenario, tuning, str(duration), str(handshake)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=os.environ.copy())
        try:
            wait_for(handshake / "ready", process)
            subprocess.run(["callgrind_control", "-i", "on", str(process.pid)], check=True, capture_output=True)
            (handshake / "go").touch()
            wait_for(handshake / "done", process)
            subprocess.run(["callgrind_control", "-i", "off", str(process.pid)], check=True, capture_output=True)
            (handshake / "end").touch()
            process.wait()
        finally:
            if process.poll() is None:
                process.kill()
        match = re.search(r"^totals:\s*(\d+)", out.read_text(), re.MULTILINE)
        if match is None:
            raise RuntimeError(f"no totals in {out.name}")
        return int(match.group(1))


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--measured":
        scenario, tuning, duration, handshake = sys.argv[2:6]
        measured_call(scenario, tuning, float(duration), Path(handshake))
        return
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("cases", nargs="+", help="scenario:tuning, e.g. paper_sim:Low mujoco_contact:Low")
    parser.add_argument("--short", type=float, default=0.1, help="simulated s of the short call")
    parser.add_argument("--long", type=float, default=0.5, help="simulated s of the long call")
    args = parser.parse_args()
    if not 0 < args.short < args.long:
        raise SystemExit(f"need 0 < --short < --long, got {args.short} and {args.long}")
    result = {}
    for case in args.cases:
        scenario, _, tuning = case.partition(":")
        if scenario not in PARAMS or not tuning:
            raise SystemExit(f"cases are scenario:tuning with scenario one of {sorted(PARAMS)}, got {case!r}")
        steps = round(args.long / CONTROL_DT) - round(args.short / CONTROL_DT)
        per_step = (instructions(scenario, tuning, args.long) - instructions(scenario, tuning, args.short)) / steps
        result[f"{scenario}/{tuning}"] = round(per_step)
        print(f"{scenario}/{tuning:6s} {per_step:12,.0f} instructions per control step")
    print(json.dumps(result))


if __name__ == "__main__":
    main()
