"""Property tests of the command line (issue 14): no command line gives a traceback.

`softcbf run` and `python -m scenarios` take random scenario names, flags and values
(NaN, inf, huge, negative, empty, unicode, unknown flags) and random --out paths inside
a temporary folder that already holds a file, a folder with a user's file, an empty
folder, a run folder and a symbolic link. Every command must end with exit code 0, 2
(one "error: ..." line on stderr, besides --spawn's note) or 130, never with an exception, and must leave the
user's files alone and no folder of its own behind when it is refused.

In process, the scenarios' SummaryWriter is replaced by one that stops the run
(`Validated`): a command that gets there has passed every check, which is the point
where the first file is written, so the test checks the whole parse-and-validate layer
without simulating. A few real runs (tiny durations, extreme but valid values) go
through the installed console script and `python -m scenarios` in subprocesses.
"""

import contextlib
import io
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from unittest import mock

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

import scenarios.__main__
from scenarios import registry
from scenarios.run import INTERRUPTED, USAGE_ERROR
from softcbf.cli import main
from softcbf_mj.outputs.runio import RUN_MARKER

SCENARIOS = sorted(registry())
SCENARIO_MODULES = sorted({sys.modules[s.function.__module__] for s in registry().values()}, key=lambda m: m.__name__)
"""Every registered scenario's module: each writes its first file through its own `SummaryWriter`."""
PARAMETERS = sorted({name for s in registry().values() for name in s.parameters()})
WEIRD = ["nan", "NaN", "inf", "-inf", "1e308", "1e309", "-1e308", "1e6", "1e-300", "-1", "0", "-0", "", " ", "1_0",
         "0x10", "true", "maybe", "None", "None,Low", "High,,", "HW-Low", "paper", "reference", "board", "truth",
         "unit", "rk4", "daqp", "pupil", "ünïcødé", "☃", "9" * 400, "file", "full/keep.txt", "run.json"]
TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00\n\r"), max_size=12)
SEGMENT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00\n\r/"), min_size=1, max_size=12)
VALUES = st.one_of(st.sampled_from(WEIRD), st.floats().map(repr), st.integers(-10**30, 10**30).map(str), TEXT)
OUT_NAMES = ["file", "file/sub", "full", "empty", "empty/new/deeper", "runfolder", "link", "new", "ünï", "x" * 300]


class Validated(Exception):
    """Raised where a scenario writes its first file: every parameter has passed its checks. To the testbed it is
    an error of its own (not a validation error), so it propagates with the run folder kept as evidence."""


def _stop_at_first_write(*args, **kwargs):
    raise Validated


@st.composite
def command_lines(draw):
    """(entry point, argv, --out relative to the temp folder or None) for softcbf run / python -m scenarios."""
    odd_name = st.one_of(st.sampled_from(["nosuch", "", "päper_sim", "paper_sim "]), TEXT)
    name = draw(odd_name if draw(st.integers(0, 9)) == 0 else st.sampled_from(SCENARIOS))  # a tenth are odd
    known = registry()[name].parameters() if name in SCENARIOS else {}
    flags = draw(st.lists(st.one_of(st.sampled_from(sorted(known) or PARAMETERS), st.sampled_from(PARAMETERS), TEXT),
                          max_size=3))
    tokens = []
    for flag in flags:
        default = known[flag].default if flag in known else None
        plain = str(default).lower() if isinstance(default, bool) else str(default)
        value = draw(VALUES) if draw(st.integers(0, 2)) == 0 else plain  # a third of the values are odd
        tokens += [f"--{flag.replace('_', '-')}", value]
    if draw(st.booleans()):  # a short run unless the flags say otherwise
        tokens = ["--duration", "0.01", "--tunings", "None", "--progress", "false", *tokens]
    out = draw(st.one_of(st.none(), st.sampled_from(OUT_NAMES + ["", "."]),
                         st.lists(SEGMENT.filter(lambda t: t not in (".", "..")), min_size=1, max_size=2).map("/".join)))
    options = draw(st.lists(st.sampled_from(["--overwrite", "--spawn"]), unique=True))
    entry = draw(st.sampled_from(["softcbf", "scenarios"]))
    argv = ([name] if entry == "scenarios" else ["run", name]) + tokens + options
    return entry, argv, out


def _populate(root: Path) -> None:
    (root / "file").write_text("a user's file")
    (root / "full").mkdir()
    (root / "full" / "keep.txt").write_text("a user's data")
    (root / "empty").mkdir()
    (root / "runfolder").mkdir()
    (root / "runfolder" / RUN_MARKER).write_text("")
    (root / "runfolder" / "summary.json").write_text(json.dumps({"scenario": "paper_sim", "params": {}, "runs": []}))
    (root / "link").symlink_to(root / "runfolder")


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(command_lines())
def test_random_command_lines_are_checked_without_a_traceback(command):
    entry, argv, out = command
    with tempfile.TemporaryDirectory() as tmp, contextlib.chdir(tmp), contextlib.ExitStack() as stack:
        root = Path(tmp)
        _populate(root)
        before = sorted(p.name for p in root.iterdir())
        for module in SCENARIO_MODULES:
            stack.enter_context(mock.patch.object(module, "SummaryWriter", _stop_at_first_write))
        stack.enter_context(mock.patch.dict(os.environ, {"DISPLAY": "", "WAYLAND_DISPLAY": ""}))
        if out is not None:
            argv = [*argv, "--out", out if out in ("", ".") else str(root / out)]
        err = io.StringIO()
        validated = False
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = main(argv) if entry == "softcbf" else scenarios.__main__.main(argv)
        except Validated:
            code, validated = None, True
        except SystemExit as exc:  # argparse's own usage errors (python -m scenarios' parser)
            code = exc.code
            assert code == USAGE_ERROR, (argv, err.getvalue())
            code = None
        assert code in (None, 0, USAGE_ERROR, INTERRUPTED), (argv, code)
        event("validated" if code is None and "usage:" not in err.getvalue() else f"exit {code}")
        if code == USAGE_ERROR:  # one error line (after --spawn's note that no display is present)
            lines = [line for line in err.getvalue().rstrip("\n").split("\n") if not line.startswith("viewer not spawned")]
            assert len(lines) == 1 and lines[0].startswith("error: "), (argv, err.getvalue())
        if not validated:  # nothing of a refused run is left (a validated one stopped here keeps its run folder)
            assert sorted(p.name for p in root.iterdir()) == before, argv
            assert not [p for p in (root / "empty").iterdir()], argv
        assert (root / "file").read_text() == "a user's file" and (root / "full" / "keep.txt").is_file()


EXTREME_BUT_VALID = {
    "amplitude": st.sampled_from(["0", "-150", "1e4", "1e300"]),
    "frequency": st.sampled_from(["1e-9", "400", "1e6"]),
    "f_max": st.sampled_from(["1e-9", "1e3"]),
    "plate_stiffness": st.sampled_from(["1e-6", "1e9"]),
    "control_rate": st.sampled_from(["150", "1e5"]),
    "q0_std": st.sampled_from(["0", "1e-12", "3.14"]),
    "seed": st.sampled_from(["0", str(2**64)]),
    "tunings": st.sampled_from(["None", "High", "HW-High"]),
    "integrator": st.sampled_from(["ros2", "rk4", "euler"]),
    "pressure_limits": st.sampled_from(["true", "false"]),
}


@settings(max_examples=2, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(["softcbf", "scenarios"]), st.dictionaries(st.sampled_from(sorted(EXTREME_BUT_VALID)), st.just(None),
                                                                  max_size=4).flatmap(
    lambda keys: st.fixed_dictionaries({k: EXTREME_BUT_VALID[k] for k in keys})))
@pytest.mark.slow
def test_real_runs_with_extreme_values_end_without_a_traceback(entry, params):
    """paper_sim for 20 ms through the console script or `python -m scenarios`: exit 0 or 2, no traceback."""
    tokens = ["--duration", "0.02", "--tunings", "None", "--progress", "false"]
    for name, value in params.items():
        tokens += [f"--{name.replace('_', '-')}", value]
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "run"
        command = ([str(Path(sys.executable).with_name("softcbf")), "run"] if entry == "softcbf"
                   else [sys.executable, "-m", "scenarios"])
        res = subprocess.run([*command, "paper_sim", *tokens, "--out", str(out)], capture_output=True, text=True,
                             timeout=300, env={**os.environ, "DISPLAY": "", "WAYLAND_DISPLAY": ""})
        assert "Traceback" not in res.stderr, (tokens, res.stderr)
        assert res.returncode in (0, USAGE_ERROR), (tokens, res.returncode, res.stderr)
        event(f"exit {res.returncode}")
        if res.returncode == 0:
            assert json.loads((out / "summary.json").read_text())["runs"]
        else:
            assert res.stderr.startswith("error: ") and not out.exists(), (tokens, res.stderr)
