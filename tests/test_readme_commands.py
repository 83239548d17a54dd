"""Every command of the README's command blocks runs as written, in order, from a fresh working tree (issue 27).

The commands are the README's indented lines that start with `.venv/bin/` or `bash scripts/setup.sh && `
(inline commands in the prose are not run). They run in order in a folder that holds the checkout's files (symlinks
to its top-level entries and to .venv, and no runs/), so a command that reads what an earlier one wrote (`softcbf
report runs/mc`) finds it. Each gets only shorter settings appended (a later --duration overrides an earlier one):
`OVERRIDES` maps the command's start to them, and a README command without an entry fails the test, so a new command
cannot be left untested. Not run: the `bash scripts/setup.sh &&` prefix (the suite runs after it; rerunning it in the
folder would point the editable install there); the pytest command runs one small test file in its own process
(`-n 0`), not the suite. No README command needs hardware or a viewer (`softcbf hardware` runs the emulated board and
virtual camera). The folder's .venv is the checkout's, or, where the checkout has none (a worktree run with another
environment's interpreter), the environment running this test. Under pytest-xdist the commands stay on one worker, in
order (`xdist_group`): a later one reads what an earlier one wrote in the same folder.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SETUP = "bash scripts/setup.sh && "
SHORT_RUN = ["--duration", "0.3", "--progress", "false"]
OVERRIDES = (  # (command start, appended arguments), first match wins
    (".venv/bin/python -m scenarios ", SHORT_RUN),
    (".venv/bin/python -m pytest", ["tests/test_layers.py", "-q", "-x", "-n", "0"]),
    (".venv/bin/softcbf run ", SHORT_RUN),
    (".venv/bin/softcbf demo", ["--duration", "0.3"]),
    (".venv/bin/softcbf report ", []),
    (".venv/bin/softcbf study run ", ["--samples", "2", "--set", "fixed.duration=0.3", "--workers", "1", "--no-progress"]),
    (".venv/bin/softcbf study report ", []),
    (".venv/bin/softcbf hardware ", ["--duration", "1"]),
    (".venv/bin/python examples/random_policy_env.py", ["--episodes", "1", "--seconds", "0.5"]),
    (".venv/bin/python examples/shield_cem.py", ["--iterations", "1", "--population", "2", "--episode-steps", "2"]),
)


def readme_commands() -> list[tuple[int, str]]:
    """(line number, command) of every command line of the README's blocks, trailing comments removed."""
    out = []
    for number, line in enumerate((ROOT / "README.md").read_text(encoding="utf-8").splitlines(), start=1):
        match = re.match(r"^    ((?:\.venv/bin/|bash scripts/setup\.sh && ).*)$", line)
        if match:
            out.append((number, re.sub(r"\s+#.*$", "", match.group(1)).strip()))
    return out


COMMANDS = readme_commands()
pytestmark = [pytest.mark.xdist_group("readme_commands"), pytest.mark.slow]  # each command a process


def test_the_readme_has_the_commands_it_should():
    heads = {command.removeprefix(SETUP).split(" --")[0] for _, command in COMMANDS}
    assert len(COMMANDS) >= 15
    assert ".venv/bin/python examples/shield_cem.py" in heads and ".venv/bin/softcbf study report runs/plate_errors" in heads
    assert not any(command.startswith("python ") for _, command in COMMANDS)  # Debian 12 has no `python`


@pytest.fixture(scope="module")
def fresh_tree(tmp_path_factory):
    tree = tmp_path_factory.mktemp("clone")
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for name in sorted({n.split("/")[0] for n in names}):
        if (ROOT / name).exists():
            (tree / name).symlink_to(ROOT / name)
    (tree / ".venv").symlink_to(ROOT / ".venv" if (ROOT / ".venv").is_dir() else Path(sys.prefix))
    return tree


@pytest.mark.parametrize("number, command", COMMANDS, ids=[f"README:{n}" for n, _ in COMMANDS])
def test_readme_command_runs(number, command, fresh_tree):
    command = command.removeprefix(SETUP)
    extra = next((args for start, args in OVERRIDES if command.startswith(start)), None)
    assert extra is not None, f"README line {number}: no short settings known for {command!r}; add them to OVERRIDES"
    argv = shlex.split(command) + extra
    environ = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    result = subprocess.run(argv, cwd=fresh_tree, capture_output=True, text=True, timeout=600, env=environ)
    assert result.returncode == 0, f"README line {number}: {' '.join(argv)}\n{result.stdout[-2000:]}\n{result.stderr[-3000:]}"
