"""How often one `softcbf run SCENARIO` parses, loads and checks its configuration ("parse once").

Runs `softcbf run SCENARIO --duration D --progress false` (default mujoco_contact, 0.02 s) through
`softcbf.cli.main` under cProfile (the run folder, its report and recording included, in a
temporary folder), and prints the call counts of the functions that turn the
command line into the objects a run needs: the vocabulary's value check, the robot file and
the force-safe set, the robot's and the MuJoCo model's checks, the plug-in parameter parser and
the registry's name resolution, the filter's check and its construction (tests/call_counts.py:
the counted functions and the count, which tests/test_spec_api.py checks). The closed loop's own
calls (one filter call per control step) are not counted: the figures depend on the run's
configuration, not on its length.

    PYTHONPATH=. python tools/parse_counts.py [--scenario mujoco_contact] [--duration 0.02]

Ends with one JSON line: {"scenario": ..., "counts": {"module:function": calls, ...}}.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from timing import emit

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from call_counts import counts  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="mujoco_contact")
    parser.add_argument("--duration", type=float, default=0.02, help="simulated seconds (s)")
    args = parser.parse_args()
    found = counts(args.scenario, args.duration)
    for key, value in found.items():
        print(f"{key:32s} {value:5d}")
    emit({"scenario": args.scenario, "duration_s": args.duration, "counts": found})


if __name__ == "__main__":
    main()
