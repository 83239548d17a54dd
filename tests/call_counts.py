"""Call counts of the functions that turn a `softcbf run` command line into the objects a run needs ("parse once"):
the vocabulary's value check, the robot file and the force-safe set, the robot's and the MuJoCo model's checks, the
plug-in parameter parser and the registry's name resolution, the filter's check and its construction.

One `softcbf run SCENARIO --duration D --progress false` runs through `softcbf.cli.main` under cProfile (the run
folder, its report and recording included, in a temporary folder). The closed loop's own calls (one filter call per
control step) are not among the counted functions: the figures depend on the run's configuration, not on its length.
Used by tests/test_spec_api.py and by tools/parse_counts.py (which prints them).
"""

from __future__ import annotations

import contextlib
import cProfile
import io
import pstats
import tempfile
from pathlib import Path

from softcbf.cli import main

COUNTED = (
    ("vocabulary/settings.py", "check_value"),
    ("softcbf_mj/physics/ground_truth.py", "load_robot"),
    ("scenarios/common.py", "build_safe_set"),
    ("controllers/model/params.py", "__post_init__"),
    ("softcbf_mj/physics/mjcf/config.py", "__post_init__"),
    ("controllers/registry.py", "parse_params"),
    ("controllers/registry.py", "resolve"),
    ("controllers/registry.py", "check_filter"),
    ("controllers/registry.py", "build_filter"),
    ("controllers/registry.py", "build_nominal"),
)


def counts(scenario: str, duration: float) -> dict[str, int]:
    """Calls of each `COUNTED` function in one `softcbf run` of `scenario` (module docstring)."""
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
