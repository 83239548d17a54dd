"""The suite's two phases in .ci/run select by the `realtime` mark that tests/conftest.py derives from the xdist group
"realtime": `-m realtime` collects exactly the tests of that group and `-m "not realtime"` the others. Were the mark
missing, the first phase would run the real-time tests beside the wheel smoke and the second would find none."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FILE = "tests/test_live.py"  # real-time tests (xdist_group "realtime") beside others


def collected(marks: str) -> set[str]:
    done = subprocess.run([sys.executable, "-m", "pytest", FILE, "--collect-only", "-q", "-n", "0", "-p",
                           "no:cacheprovider", "-m", marks], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT),
                                                                                         os.environ.get("PYTHONPATH")]))})
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    return {line for line in done.stdout.splitlines() if line.startswith(FILE + "::")}


def test_the_realtime_mark_splits_the_suite_by_the_realtime_group():
    realtime, others = collected("realtime"), collected("not realtime")
    source = (ROOT / FILE).read_text(encoding="utf-8")
    grouped = source.count('@pytest.mark.xdist_group("realtime")')
    assert len(realtime) == grouped >= 1 and others and not realtime & others
    assert all(name.split("::")[1].split("[")[0] in source for name in realtime)
