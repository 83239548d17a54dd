"""Every command of the README's command blocks runs as written, in order, from a fresh working tree, and talks:
its first output comes within FIRST_LINE_S of its start (`in_time`, tests/test_progress_lines.py: wall time on an
idle machine, CPU time on a busy one).

The commands are the README's indented lines that start with `.venv/bin/` or `bash scripts/setup.sh && `
(inline commands in the prose are not run), and all of one family: `softcbf` (the examples and pytest aside). They
run in order in a folder that holds the checkout's files (symlinks to its top-level entries and to .venv, and no
runs/), so a command that reads what an earlier one wrote (`softcbf report runs/mc`) finds it. Each gets only shorter
settings appended (a later --duration overrides an earlier one), its progress left on: `OVERRIDES` maps the
command's start to them, and a README command without an entry fails the test, so a new command cannot be left
untested. Its output is read as it comes (bytes, not lines: pytest's dots end no line), unbuffered as on a terminal;
the first output is a progress bar, the set-up's heartbeat or a line saying what runs. Not run: the `bash
scripts/setup.sh &&` prefix (the suite runs after it; rerunning it in the folder would point the editable install
there); the pytest command runs one small test file, not the suite. No README command needs hardware or a viewer
(`softcbf hardware` runs the emulated board and virtual camera). The folder's .venv is the checkout's, or, where the
checkout has none (a worktree), the environment running this test. Under pytest-xdist the commands stay on one worker,
in order (`xdist_group`): a later one reads what an earlier one wrote in the same folder.

`SILENT` (strict xfail on the first-output check alone: the command must still succeed) names a command whose first
output is known to come late; none today (the report commands say what they rebuild before they import matplotlib).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_progress_lines import FIRST_LINE_S, cpu_seconds, in_time

pytestmark = [pytest.mark.xdist_group("readme_commands"), pytest.mark.slow]  # in order on one worker; a process each

ROOT = Path(__file__).resolve().parents[1]
SETUP = "bash scripts/setup.sh && "
SHORT_RUN = ["--duration", "0.3"]
FAMILY = (".venv/bin/softcbf ", ".venv/bin/python examples/", ".venv/bin/python -m pytest")
OVERRIDES = (  # (command start, appended arguments), first match wins
    (".venv/bin/python -m pytest", ["tests/test_layers.py", "-q", "-x", "-n", "0"]),
    (".venv/bin/softcbf run ", SHORT_RUN),
    (".venv/bin/softcbf demo", ["--duration", "0.3"]),
    (".venv/bin/softcbf report ", []),
    (".venv/bin/softcbf study run ", ["--samples", "2", "--set", "fixed.duration=0.3", "--workers", "1"]),
    (".venv/bin/softcbf study report ", []),
    (".venv/bin/softcbf hardware ", ["--duration", "1"]),
    (".venv/bin/python examples/random_policy_env.py", ["--episodes", "1", "--seconds", "0.5"]),
    (".venv/bin/python examples/shield_cem.py", ["--iterations", "1", "--population", "2", "--episode-steps", "2"]),
)
SILENT: dict[str, str] = {}  # command start → why its first output comes late (module docstring)


class LateFirstOutput(AssertionError):
    """A command's first output came after FIRST_LINE_S."""


def readme_commands() -> list[tuple[int, str]]:
    """(line number, command) of every command line of the README's blocks, trailing comments removed."""
    out = []
    for number, line in enumerate((ROOT / "README.md").read_text(encoding="utf-8").splitlines(), start=1):
        match = re.match(r"^    ((?:\.venv/bin/|bash scripts/setup\.sh && ).*)$", line)
        if match:
            out.append((number, re.sub(r"\s+#.*$", "", match.group(1)).strip()))
    return out


COMMANDS = readme_commands()


def test_the_readme_has_the_commands_it_should():
    heads = {command.removeprefix(SETUP).split(" --")[0] for _, command in COMMANDS}
    assert len(COMMANDS) >= 15
    assert ".venv/bin/python examples/shield_cem.py" in heads and ".venv/bin/softcbf study report runs/plate_errors" in heads
    assert not any(command.startswith("python ") for _, command in COMMANDS)  # Debian 12 has no `python`


def test_the_readme_s_commands_are_one_family():
    """softcbf for everything it does (the first command, which sets up and runs the main job, too); Python only for
    the example scripts and the test suite."""
    other = [(n, c) for n, c in COMMANDS if not c.removeprefix(SETUP).startswith(FAMILY)]
    assert other == []
    assert COMMANDS[0][1].startswith(SETUP + ".venv/bin/softcbf run ")


@pytest.fixture(scope="module")
def fresh_tree(tmp_path_factory):
    tree = tmp_path_factory.mktemp("clone")
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    for name in sorted({n.split("/")[0] for n in names}):
        if (ROOT / name).exists():
            (tree / name).symlink_to(ROOT / name)
    (tree / ".venv").symlink_to(ROOT / ".venv" if (ROOT / ".venv").is_dir() else Path(sys.prefix))  # a worktree's: ours
    return tree


def run_timed(argv: list[str], cwd: Path) -> tuple[int, tuple[float, float] | None, str]:
    """Run `argv` in `cwd` to its end (stdout and stderr merged, Python unbuffered); its exit code, the seconds from
    its start to its first output and the CPU time it had used then (None when it printed nothing), and its output."""
    environ = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    start = time.monotonic()
    proc = subprocess.Popen(argv, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            env={**environ, "PYTHONUNBUFFERED": "1"})
    first, chunks = None, []
    try:
        while chunk := os.read(proc.stdout.fileno(), 65536):
            first = (time.monotonic() - start, cpu_seconds(proc.pid)) if first is None else first
            chunks.append(chunk)
        code = proc.wait(timeout=600)
    finally:
        proc.kill()  # this test's own process, by its handle; a no-op once it has ended
        proc.wait()
        proc.stdout.close()
    return code, first, b"".join(chunks).decode("utf-8", "replace")


@pytest.mark.parametrize("number, command", [
    pytest.param(n, c, marks=[pytest.mark.xfail(raises=LateFirstOutput, strict=True, reason=reason)
                              for start, reason in SILENT.items() if c.startswith(start)])
    for n, c in COMMANDS], ids=[f"README:{n}" for n, _ in COMMANDS])
def test_readme_command_runs_and_talks_at_once(number, command, fresh_tree):
    command = command.removeprefix(SETUP)
    extra = next((args for start, args in OVERRIDES if command.startswith(start)), None)
    assert extra is not None, f"README line {number}: no short settings known for {command!r}; add them to OVERRIDES"
    argv = shlex.split(command) + extra
    code, first, output = run_timed(argv, fresh_tree)
    assert code == 0, f"README line {number}: {' '.join(argv)}\n{output[-5000:]}"
    assert first is not None, f"README line {number}: {' '.join(argv)} printed nothing"
    if not in_time(*first):
        raise LateFirstOutput(f"README line {number}: {' '.join(argv)}: first output after {first[0]:.2f} s, "
                              f"{first[1]:.2f} s of CPU (at most {FIRST_LINE_S} s)\n{output[:2000]}")
