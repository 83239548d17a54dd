"""A long command talks at once: its first line comes within FIRST_LINE_S of the command, once its parameters are
checked and before rerun and matplotlib are imported (scenarios.run: the progress bar's 0 % line, or the heartbeat
of a set-up that takes longer, softcbf_mj.outputs.progress; softcbf.demo), and numba's compile, when it happens, is announced
before it starts (softcbf_mj.loops.kernels.compile_notes), also on a cold cache (NUMBA_CACHE_DIR pointing at an empty
folder: every kernel compiles). The time to the first line is the command's elapsed time less the time it waited for
a core (tests/wall_clock.py): what it would take on an idle machine, also when other jobs load this one."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numba
import pytest

from softcbf_mj.loops.kernels import COMPILE_NOTE, compile_notes
from softcbf_mj.outputs.progress import Progress, heartbeat
from wall_clock import runqueue_wait_s

# Wall-clock deadlines: one at a time with the other real-time tests, on one pytest-xdist worker (the suite's addopts).
pytestmark = pytest.mark.xdist_group("realtime")

ROOT = Path(__file__).resolve().parents[1]
FIRST_LINE_S = 2.0
HEAVY = ("rerun", "matplotlib")  # seconds to import; numba and MuJoCo load in the parameter check (the true arm, the model)
# Runs `main(argv)` of MODULE with stderr wrapped: at its first write, it writes which HEAVY modules are loaded.
DRIVER = """
import importlib, sys
class First:
    def __init__(self, stream):
        self.stream, self.seen = stream, False
    def write(self, text):
        if not self.seen and text.strip():
            self.seen = True
            self.stream.write("HEAVY " + ",".join(m for m in {heavy!r} if m in sys.modules) + "\\n")
        return self.stream.write(text)
    def __getattr__(self, name):
        return getattr(self.stream, name)
sys.stderr = First(sys.stderr)
sys.exit(importlib.import_module(sys.argv[1]).main(sys.argv[2:]))
"""


def first_line(module: str, argv: list[str], cwd: Path) -> tuple[float, str, str]:
    """(seconds to the first line less the wait for a core, that line, everything) of `python -c DRIVER module
    argv...`, run to its end."""
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-c", DRIVER.format(heavy=HEAVY), module, *argv], cwd=cwd,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    line = process.stdout.readline()
    seconds = time.perf_counter() - start - runqueue_wait_s(process.pid)
    rest = process.stdout.read()  # not communicate(): it would skip what readline buffered
    assert process.wait(timeout=600) == 0, line + rest
    return seconds, line, line + rest


@pytest.mark.parametrize("module, argv", [
    ("softcbf.cli", ["run", "mujoco_contact", "--duration", "0.2", "--tunings", "Low"]),
    ("scenarios", ["paper_sim", "--duration", "0.2", "--tunings", "Low"]),
    ("softcbf.cli", ["demo", "--duration", "0.2"]),
])
def test_the_first_line_comes_within_two_seconds_before_anything_heavy(tmp_path, module, argv):
    seconds, line, text = first_line(module if module != "scenarios" else "scenarios.__main__",
                                     [*argv, "--out", str(tmp_path / "out")], tmp_path)
    assert line == "HEAVY \n", text  # nothing heavy imported at the first write
    assert seconds < FIRST_LINE_S, f"first line after {seconds:.2f} s: {text}"
    assert text.splitlines()[1].startswith(("[mujoco_contact Low] |", "mujoco_contact: setting up, 0.2 s per run",
                                            "[paper_sim Low] |", "paper_sim: setting up, 0.2 s per run",
                                            "softcbf demo: the paper's CBF and the recommended filter")), text


def test_on_a_cold_cache_the_compile_is_announced_after_the_first_line(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}  # empty: every kernel compiles
    start = time.perf_counter()
    process = subprocess.Popen([sys.executable, "-m", "scenarios", "paper_sim", "--out", str(tmp_path / "out")],
                               cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        lines = [process.stdout.readline()]
        seconds = time.perf_counter() - start - runqueue_wait_s(process.pid)
        while COMPILE_NOTE + "\n" not in lines and len(lines) < 3:
            lines.append(process.stdout.readline())
    finally:
        process.send_signal(signal.SIGINT)  # during the compile: nothing is kept
        rest = process.stdout.read()
        process.wait(timeout=300)
    assert lines[0].startswith(("paper_sim: setting up, 100 s per run into", "[paper_sim None] |", COMPILE_NOTE))
    assert seconds < FIRST_LINE_S and COMPILE_NOTE + "\n" in lines, (seconds, lines, rest)
    assert "nothing kept" in rest and not (tmp_path / "out").exists()


def test_a_compile_is_announced_before_it_starts_and_a_cache_hit_is_silent():
    notes = io.StringIO()
    seen_at_compile = []
    kernel = numba.njit(lambda x: x + 1)  # not cached: compiles in this process
    with compile_notes(notes):
        seen_at_compile.append(notes.getvalue())
        assert kernel(1) == 2
    assert notes.getvalue().startswith(COMPILE_NOTE + "\n") and "compiled 1 numba kernel(s) in" in notes.getvalue()
    again = io.StringIO()
    with compile_notes(again):
        assert kernel(2) == 3  # compiled already: no note
    assert again.getvalue() == ""


def test_the_heartbeat_speaks_once_after_silence_and_never_after_a_bar_or_its_end():
    quiet, spoke, after_bar, after_end = io.StringIO(), io.StringIO(), io.StringIO(), io.StringIO()
    with heartbeat("setting up", after_s=0.05, stream=spoke):
        time.sleep(0.3)
    assert spoke.getvalue() == "setting up\n"
    with heartbeat("setting up", after_s=0.05, stream=after_bar):
        Progress("run", 10, stream=quiet, unit_s=0.1)  # draws its 0 % line at once: the run has spoken
        time.sleep(0.3)
    assert after_bar.getvalue() == "" and quiet.getvalue().startswith("[run] |")
    with heartbeat("setting up", after_s=0.2, stream=after_end):
        pass  # refused at once: no second line after the error
    time.sleep(0.4)
    assert after_end.getvalue() == ""
