"""How often one `softcbf run SCENARIO` parses, loads and checks its configuration ("parse once").

Runs `softcbf run SCENARIO --duration D --progress false` (default mujoco_contact, 0.02 s) through
`softcbf.cli.main` under cProfile (the run folder, its report and recording included, in a
temporary folder), and prints the call counts of the functions that turn the
command line into the objects a run needs: the vocabulary's value check, the robot file and
the force-safe set, the robot's and the MuJoCo model's checks, the plug-in parameter parser and
the registry's name resolution, the filter's check and its construction. The closed loop's own
calls (one filter call per control step) are not counted: the figures depend on the run's
configuration, not on its length.

    PYTHONPATH=. python tools/parse_counts.py [--scenario mujoco_contact] [--duration 0.02]

Ends with one JSON line: {"scenario": ..., "counts": {"module:function": calls, ...}}.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import io
import json
import pstats
import tempfile
from pathlib import Path

COUNTED = (
    ("vocabulary/settings.py", "check_value"),
    ("scenarios/common.py", "load_robot"),
    ("scenarios/common.py", "build_safe_set"),
    ("controllers/params.py", "__post_init__"),
    ("softcbf_mj/model_builder.py", "__post_init__"),
    ("controllers/registry.py", "parse_params"),
    ("controllers/registry.py", "resolve"),
    ("controllers/registry.py", "check_filter"),
    ("controllers/registry.py", "build_filter"),
    ("controllers/registry.py", "build_nominal"),
)


def counts(scenario: str, duration: float) -> dict[str, int]:
    """Calls of each `COUNTED` function in one `softcbf run` of `scenario` (module docstring)."""
    from softcbf.cli import main

    profile = cProfile.Profile()
    with tempfile.TemporaryDirectory() as tmp, contextlib.redirect_stdout(io.StringIO()):
        profile.enable()
        code = main(["run", scenario, "--out", str(Path(tmp) / "run"), "--duration", str(duration),
                     "--progress", "false"])
        profile.disable()
    if code != 0:
        raise SystemExit(f"softcbf run {scenario} exited {code}")
    found = {f"{Path(path).name.removesuffix('.py')}:{name}": 0 for path, name in COUNTED}
    for (path, _, name), (_, calls, *_rest) in pstats.Stats(profile).stats.items():
        for suffix, counted in COUNTED:
            if path.replace("\\", "/").endswith(suffix) and name == counted:
                found[f"{Path(suffix).name.removesuffix('.py')}:{name}"] += calls
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="mujoco_contact")
    parser.add_argument("--duration", type=float, default=0.02, help="simulated seconds (s)")
    args = parser.parse_args()
    found = counts(args.scenario, args.duration)
    for key, value in found.items():
        print(f"{key:32s} {value:5d}")
    print(json.dumps({"scenario": args.scenario, "duration_s": args.duration, "counts": found}))


if __name__ == "__main__":
    main()
