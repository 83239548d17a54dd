"""The `softcbf` CLI: list, run, report, --version, errors and exit codes, interrupted runs."""

import datetime
import json
import os
import shutil
import stat
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
import rerun as rr
from matplotlib.figure import Figure

import scenarios.common
import softcbf_mj
from scenarios import registry
from scenarios.run import INTERRUPTED, USAGE_ERROR
from softcbf.cli import main
from softcbf_mj.outputs.report import FIGURE_SIZES_IN
from softcbf_mj.outputs.runio import RUN_MARKER, load_timeseries, read_run_folder

ROOT = Path(__file__).resolve().parents[1]
SHORT = ["--duration", "0.5", "--tunings", "None,Low", "--amplitude", "150", "--frequency", "0.5", "--progress", "false"]
PLOTS = {f"{name}.png" for name in FIGURE_SIZES_IN}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    """A short paper_sim run with the default --out, from a fresh working folder, with --spawn and no display."""
    cwd = tmp_path_factory.mktemp("cwd")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(cwd)
        mp.delenv("DISPLAY", raising=False)
        mp.delenv("WAYLAND_DISPLAY", raising=False)
        assert main(["run", "paper_sim", *SHORT, "--spawn"]) == 0
    (out,) = (cwd / "runs").iterdir()
    return out


def test_softcbf_is_the_installed_entry_point():
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["scripts"]
    assert scripts == {"softcbf": "softcbf.cli:main"}
    (entry,) = metadata.entry_points(group="console_scripts", name="softcbf")
    assert entry.load() is main


def test_version(capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["--version"])
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith(f"softcbf {softcbf_mj.__version__} (MuJoCo ")


def test_list_names_every_scenario_with_description_and_parameters(capsys):
    assert main(["list"]) == 0
    out = capsys.readouterr().out
    for scenario in registry().values():
        assert f"{scenario.name}: {scenario.description}" in out
    assert "    --duration float (default 100.0)" in out and "    --pressure-limits bool (default False)" in out


def test_run_writes_one_complete_folder(run_dir, capsys):
    assert run_dir.name.startswith("paper_sim-")
    names = {p.relative_to(run_dir).as_posix() for p in run_dir.rglob("*")}
    assert {"config.json", "summary.json", "report.md", "recording.rrd", "timeseries/None.npz",
            "timeseries/Low.npz"} <= names
    assert {p.name for p in (run_dir / "plots").iterdir()} == PLOTS
    assert [n for n in names if Path(n).name.startswith(".")] == [RUN_MARKER]  # the marker, no temp files
    config = json.loads((run_dir / "config.json").read_text(encoding="utf-8"))
    defaults = registry()["paper_sim"].defaults()
    assert config["params"] == {**defaults, "duration": 0.5, "tunings": "None,Low", "amplitude": 150.0,
                                "frequency": 0.5, "progress": False}
    assert config["seed"] == 0 and config["scenario"] == "paper_sim"
    assert {"softcbf_mj", "mujoco", "python", "numpy", "rerun_sdk"} <= set(config["versions"])
    assert config["versions"]["softcbf_mj"] == softcbf_mj.__version__
    assert config["started"].endswith("+00:00") and config["command"]
    summary = read_run_folder(run_dir).summary
    assert summary["params"] == config["params"] and [r["tuning"] for r in summary["runs"]] == ["None", "Low"]
    assert summary["scene"]["f_max_N"] == 0.16


def test_run_prints_the_table_and_where_everything_is(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = tmp_path / "one"
    assert main(["run", "paper_sim", *SHORT[:2], "--tunings", "Low", "--progress", "false", "--out", str(out),
                 "--spawn"]) == 0
    captured = capsys.readouterr()
    assert "viewer not spawned: no display" in captured.err
    assert "rho_min" in captured.out and f"outputs in {out}:" in captured.out
    assert f"rerun {out / 'recording.rrd'}" in captured.out and f"softcbf report {out}" in captured.out
    viewer = captured.out.split("view it with: ")[1].split()[0]  # a program that exists here, not a bare 'rerun'
    assert shutil.which(viewer) is not None


def test_report_rebuilds_from_saved_data_only(run_dir, capsys, monkeypatch):
    data = {p: p.read_bytes() for p in (run_dir / "summary.json", run_dir / "timeseries" / "Low.npz")}
    for path in [run_dir / "report.md", run_dir / "recording.rrd", *(run_dir / "plots").iterdir()]:
        path.unlink()

    def no_simulation(*args, **kwargs):
        raise AssertionError("softcbf report must not simulate")

    monkeypatch.setattr(scenarios.common, "run_closed_loop", no_simulation)
    assert main(["report", str(run_dir)]) == 0
    out = capsys.readouterr().out
    assert "report (" in out and "recording (" in out
    assert {p.name for p in (run_dir / "plots").iterdir()} == PLOTS
    assert (run_dir / "report.md").is_file() and (run_dir / "recording.rrd").stat().st_size > 0
    assert all(p.read_bytes() == content for p, content in data.items())
    (run_dir / "recording.rrd").unlink()
    assert main(["report", str(run_dir), "--no-recording"]) == 0
    assert not (run_dir / "recording.rrd").exists()
    assert main(["report", str(run_dir)]) == 0
    assert main(["report", str(run_dir), "--no-recording", "--figure-format", "svg", "--dpi", "80"]) == 0
    assert {f"{name}.svg" for name in FIGURE_SIZES_IN} <= {p.name for p in (run_dir / "plots").iterdir()}
    assert "plots/rho.svg" in (run_dir / "report.md").read_text(encoding="utf-8")


@pytest.mark.parametrize(
    "args, message",
    [
        (["run", "nosuch"], "unknown scenario 'nosuch'; available: camera_loop, mujoco_contact, paper_sim"),
        (["run", "paper_sim", "--speed", "3"], "unknown parameter(s) --speed 3 for scenario paper_sim (did you mean '--seed'?); valid: --duration, "),
        (["run", "paper_sim", "--dur", "3"], "unknown parameter(s) --dur 3"),  # no abbreviations
        (["run", "paper_sim", "--duration", "abc"], "--duration: expected float, got 'abc'"),
        (["run", "paper_sim", "--seed", "1.5"], "--seed: expected int, got '1.5'"),
        (["run", "paper_sim", "--pressure-limits", "maybe"],
         "--pressure-limits: expected one of 1, true, yes, on, 0, false, no, off, got 'maybe'"),
        (["run", "paper_sim", "--duration"], "--duration: expected one argument"),
        (["run", "paper_sim", "--tunings", "Medium"], "unknown tuning 'Medium'; valid: None, Low, High, HW-Low, HW-High"),
        (["run", "paper_sim", "--duration", "-1"], "duration must be > 0 s, got -1.0"),
        (["run", "paper_sim", "--integrator", "leapfrog"], "integrator must be one of ros2, rk4, euler"),
        (["report", "{tmp}"], "is not a run folder: it has no summary.json"),
        (["report", "{tmp}", "--speed", "3"], "softcbf report: unrecognised arguments: --speed 3"),
        (["list", "extra"], "softcbf list: unrecognised arguments: extra"),
    ],
)
def test_bad_arguments_exit_2_naming_the_parameter_and_valid_values(tmp_path, capsys, args, message):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    if args[0] == "run":
        args += ["--out", str(tmp_path / "o")]
    assert main(args) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err, err
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").iterdir())


def test_existing_folder_is_refused_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "run"
    tiny = ["--duration", "0.01", "--tunings", "None", "--progress", "false"]
    assert main(["run", "paper_sim", "--out", str(out), *tiny]) == 0
    assert main(["run", "paper_sim", "--out", str(out), *tiny]) == USAGE_ERROR
    assert f"{out} exists and is not empty; choose another --out or pass --overwrite" in capsys.readouterr().err
    (out / "keep.txt").write_text("data")
    assert main(["run", "paper_sim", "--out", str(out), "--overwrite", *tiny]) == 0
    assert not (out / "keep.txt").exists() and (out / "summary.json").is_file()


@pytest.mark.parametrize("out", ["{tmp}", ".", ""])
def test_overwrite_never_deletes_a_folder_softcbf_did_not_write(tmp_path, capsys, monkeypatch, out):
    """L1: `--out . --overwrite` (or --out "") deleted keep.txt, then crashed."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "keep.txt").write_text("data")
    args = ["run", "paper_sim", "--duration", ".5", "--tunings", "None", "--out", out.replace("{tmp}", str(tmp_path)),
            "--overwrite"]
    assert main(args) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "is not a run folder" in err or "--out must name a folder, got ''" in err
    assert [p.name for p in tmp_path.iterdir()] == ["keep.txt"] and (tmp_path / "keep.txt").read_text() == "data"


def test_a_run_folder_in_use_is_refused(tmp_path, capsys):
    """L2: a second run into the --out of a running one succeeded and mixed the two runs' files."""
    out = tmp_path / "run"
    holder = subprocess.Popen([sys.executable, "-c", "import sys, time; from softcbf_mj.outputs.runio import prepare_out_dir\n"
                               "prepare_out_dir(sys.argv[1]); print('locked', flush=True); time.sleep(600)", str(out)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        assert main(["run", "paper_sim", "--out", str(out), "--duration", "0.01", "--tunings", "None"]) == USAGE_ERROR
        assert f"{out} is in use by another run (process {holder.pid})" in capsys.readouterr().err
        assert [p.name for p in out.iterdir()] == [RUN_MARKER]
    finally:
        holder.kill()
        holder.wait()


def test_default_folders_of_runs_started_in_the_same_second_differ(tmp_path, monkeypatch):
    """L2: runs/<scenario>-<YYYYmmdd-HHMMSS> collided for runs started in the same second."""
    monkeypatch.chdir(tmp_path)
    now = datetime.datetime.now()
    for seconds in range(4):  # the folder the clock would name, now and in the next seconds, is taken
        taken = tmp_path / "runs" / f"paper_sim-{now + datetime.timedelta(seconds=seconds):%Y%m%d-%H%M%S}"
        taken.mkdir(parents=True)
        (taken / "summary.json").write_text("{}")
    assert main(["run", "paper_sim", "--duration", "0.01", "--tunings", "None", "--progress", "false"]) == 0
    (new,) = [p for p in (tmp_path / "runs").iterdir() if (p / "config.json").is_file()]
    assert new.name.startswith("paper_sim-") and new.name.rsplit("-", 1)[1] == "2"


@pytest.mark.parametrize(
    "args, message",
    [
        (["paper_sim", "--duration", "inf"], "duration must be finite and > 0 s, got inf"),
        (["mujoco_contact", "--duration", "inf"], "duration must be finite and > 0 s, got inf"),
        (["camera_loop", "--duration", "inf"], "duration must be finite and > 0 s, got inf"),
        (["paper_sim", "--duration", "8e4", "--control-rate", "1e4"],
         "duration 80000 s (800000000 steps of 0.0001 s) needs 453.0 GiB for its time series"),
        (["mujoco_contact", "--duration", "1e6"], "duration must be <= 86400 s (a plausibility bound; a value in ms? "
                                                  "1e+06 ms = 1000 s), got 1000000.0"),
        (["camera_loop", "--duration", "8e4", "--tick", "1e-4", "--physics-dt", "1e-4"],
         "duration 80000 s (800000000 steps of 0.0001 s) needs"),
        (["paper_sim", "--q0-std", "nan"], "q0_std must be finite and in [0, 3.14159] rad, got nan"),  # L5
        (["paper_sim", "--control-rate", "1e-3", "--duration", ".5"],
         "duration must cover at least one control period (1000 s), got 0.5 s"),  # L6
        (["paper_sim", "--control-rate", "inf"], "control_rate must be finite and > 0 Hz, got inf"),  # L6
        (["paper_sim", "--seed", "-1", "--q0-std", ".1"], "seed must be >= 0, got -1"),  # L6
        (["paper_sim", "--environment", "{tmp}/env.json"], "environment file {tmp}/env.json cannot be used: "),  # L6
        (["mujoco_contact", "--links-per-segment", "0"], "links_per_segment must be in [1, 100], got 0"),
        (["camera_loop", "--width", "100000"], "width must be in [16, 1280] px, got 100000"),
        # found by tests/test_cli_properties.py: OverflowError (int to float) and OSError (file name too long)
        (["paper_sim", "--seed", "9" * 400, "--q0-std", "-1"], "q0_std must be in [0, 3.14159] rad, got -1.0"),
        (["camera_loop", "--width", "9" * 400], "width must be in [16, 1280] px, got 999"),
        (["paper_sim", "--environment", "9" * 400], "environment must be 'paper' or a JSON file with keys H and h, got '999"),
    ],
)
def test_bad_values_are_refused_naming_the_parameter_before_anything_is_written(tmp_path, capsys, args, message):
    """L3, L5, L6: tracebacks (OverflowError, MemoryError), accepted NaN and messages that did not name the
    parameter; the crashes left config.json and summary.json behind, which blocked the corrected command."""
    (tmp_path / "env.json").write_text('{"H": [1', encoding="utf-8")
    out = tmp_path / "o"
    args = ["run", *[a.replace("{tmp}", str(tmp_path)) for a in args], "--out", str(out)]
    assert main(args) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message.replace("{tmp}", str(tmp_path)) in err, err
    assert not out.exists()


@pytest.mark.parametrize("out", ["/proc/x", "{tmp}/file/sub", "{tmp}/dangling", "{tmp}/" + "x" * 300])
def test_unusable_out_folders_are_one_line_errors(tmp_path, capsys, out):
    """L3: --out /proc/x, --out FILE/sub (and a dangling link) raised OSError tracebacks."""
    (tmp_path / "file").write_text("x")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    out = out.replace("{tmp}", str(tmp_path))
    assert main(["run", "paper_sim", "--duration", ".5", "--out", out]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.startswith(f"error: cannot write the run folder {out}: ") and err.count("\n") == 1, err


@pytest.fixture
def immutable_folder(tmp_path):
    """An empty folder nobody may write into, root included (chattr +i); skipped where chattr cannot do that."""
    folder = tmp_path / "immutable"
    folder.mkdir()
    if shutil.which("chattr") is None or subprocess.run(["chattr", "+i", str(folder)], capture_output=True).returncode:
        pytest.skip("chattr +i is not available here (needs root and a file system with the immutable flag)")
    yield folder
    subprocess.run(["chattr", "-i", str(folder)], check=True)


def test_an_immutable_out_folder_is_a_one_line_error(immutable_folder, capsys):
    """L3: an empty folder that cannot be written passed the checks, then raised PermissionError from
    summary.json's temp file."""
    assert main(["run", "paper_sim", "--duration", ".5", "--out", str(immutable_folder)]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err == f"error: cannot write the run folder {immutable_folder}: Operation not permitted\n"
    assert list(immutable_folder.iterdir()) == []


def test_overwrite_through_a_symlink_replaces_the_run_folder_it_points_to(tmp_path, capsys):
    """L3: a symlink with --overwrite raised OSError (rmtree of a symlink) after its checks."""
    tiny = ["--duration", "0.01", "--tunings", "None", "--progress", "false"]
    target, link = tmp_path / "run", tmp_path / "link"
    assert main(["run", "paper_sim", "--out", str(target), *tiny]) == 0
    link.symlink_to(target)
    (target / "old.txt").write_text("x")
    assert main(["run", "paper_sim", "--out", str(link), "--overwrite", *tiny]) == 0
    assert link.is_symlink() and (target / "summary.json").is_file() and not (target / "old.txt").exists()


def test_report_of_a_truncated_timeseries_is_a_one_line_error(run_dir, tmp_path, capsys):
    """L4: `softcbf report` on a truncated .npz raised zipfile.BadZipFile."""
    folder = tmp_path / "copy"
    shutil.copytree(run_dir, folder)
    npz = folder / "timeseries" / "Low.npz"
    npz.write_bytes(npz.read_bytes()[: npz.stat().st_size // 2])
    assert main(["report", str(folder), "--no-recording"]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.startswith(f"error: time series {npz} cannot be read (") and err.count("\n") == 1, err
    assert not [p for p in folder.rglob(".*") if p.name != RUN_MARKER]


def test_run_outputs_get_the_mode_umask_gives_new_files(run_dir):
    """L8: config.json and summary.json were written 0600, every other output 0644 (umask 022 here)."""
    umask = os.umask(0o022)
    os.umask(umask)
    modes = {p.relative_to(run_dir).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in run_dir.rglob("*") if p.is_file()}
    assert set(modes.values()) == {0o666 & ~umask}, modes


def test_interrupted_run_leaves_its_finished_tunings_readable(tmp_path, capsys, monkeypatch):
    calls = []
    real = scenarios.common.run_closed_loop

    def interrupt_second(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(scenarios.common, "run_closed_loop", interrupt_second)
    out = tmp_path / "run"
    assert main(["run", "paper_sim", "--out", str(out), *SHORT]) == INTERRUPTED
    assert "interrupted: 1 finished run(s) (None) are in" in capsys.readouterr().err
    folder = read_run_folder(out)
    assert folder.labels == ["None"]
    arrays, _ = load_timeseries(out / "timeseries" / "None.npz")
    assert len(arrays["t"]) == 500
    assert {p.name for p in (out / "plots").iterdir()} == PLOTS
    assert "| None |" in (out / "report.md").read_text(encoding="utf-8")
    paths = rr.chunk.RrdReader(out / "recording.rrd").stream().collect().schema().entity_paths()
    assert "/runs/None/rho" in paths and not any(p.startswith("/runs/Low") for p in paths)


def _main_catching_interrupts(args):
    """main(args), failing the test (not the session) when a KeyboardInterrupt escapes it."""
    try:
        return main(args)
    except KeyboardInterrupt:
        pytest.fail("KeyboardInterrupt escaped main: a traceback for the user")


def _interrupt_savefig_call(monkeypatch, number):
    """Ctrl-C in the middle of writing the `number`-th plot file (a torn temp file on disk)."""
    real, calls = Figure.savefig, []

    def savefig(self, fname, *args, **kwargs):
        calls.append(fname)
        if len(calls) == number:
            Path(fname).write_bytes(b"\x89PNG torn")
            raise KeyboardInterrupt
        return real(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return calls


def test_interrupt_during_the_first_report_leaves_a_complete_folder_and_says_so(tmp_path, capsys, monkeypatch):
    """L7: Ctrl-C while the first report was built said "with their report and recording" though neither
    existed, and left plots/.force.tmp.png."""
    _interrupt_savefig_call(monkeypatch, 3)  # rho, tip_path, then force
    out = tmp_path / "run"
    assert _main_catching_interrupts(["run", "paper_sim", "--out", str(out), *SHORT[:2], "--tunings", "None",
                                      "--progress", "false"]) == INTERRUPTED
    err = capsys.readouterr().err
    assert "rebuilding report.md and recording.rrd for the 1 finished run(s) (None)" in err
    assert "interrupted: 1 finished run(s) (None) are in" in err and "with their report and recording" in err
    assert not [p for p in out.rglob(".*") if p.name != RUN_MARKER]
    assert {p.name for p in (out / "plots").iterdir()} == PLOTS
    assert "| None |" in (out / "report.md").read_text(encoding="utf-8")
    paths = rr.chunk.RrdReader(out / "recording.rrd").stream().collect().schema().entity_paths()
    assert "/runs/None/rho" in paths


@pytest.mark.slow
def test_interrupt_during_the_last_report_still_reports_every_finished_run(tmp_path, capsys, monkeypatch):
    """L7: Ctrl-C while the report of the last tuning was built left a report without that tuning."""
    _interrupt_savefig_call(monkeypatch, 3)  # the report's tip_path: drawn once, after both runs (scenarios.run_outputs)
    out = tmp_path / "run"
    assert _main_catching_interrupts(["run", "paper_sim", "--out", str(out), *SHORT]) == INTERRUPTED
    assert "interrupted: 2 finished run(s) (None, Low) are in" in capsys.readouterr().err
    report = (out / "report.md").read_text(encoding="utf-8")
    assert "| None |" in report and "| Low |" in report
    paths = rr.chunk.RrdReader(out / "recording.rrd").stream().collect().schema().entity_paths()
    assert "/runs/Low/rho" in paths
    assert not [p for p in out.rglob(".*") if p.name != RUN_MARKER]


def test_a_second_interrupt_skips_the_rebuild_and_says_what_is_missing(tmp_path, capsys, monkeypatch):
    import softcbf_mj.outputs.report

    calls = []

    def interrupt(run_dir):  # the report at the end of the runs, then the rebuild after Ctrl-C
        calls.append(run_dir)
        raise KeyboardInterrupt

    monkeypatch.setattr(softcbf_mj.outputs.report, "write_report", interrupt)
    out = tmp_path / "run"
    assert _main_catching_interrupts(["run", "paper_sim", "--out", str(out), *SHORT]) == INTERRUPTED
    err = capsys.readouterr().err
    assert len(calls) == 2
    assert err.endswith(f"interrupted again: the 2 finished run(s) (None, Low) are in {out}; report.md and "
                        f"recording.rrd may not show them all: rebuild with: softcbf report {out}\n"), err


@pytest.mark.parametrize("when", ["import", "scenario"])
def test_interrupt_at_start_up_exits_130_with_one_line_and_no_folder(tmp_path, capsys, monkeypatch, when):
    """L7: Ctrl-C at start-up (importing rerun, building the scenario) gave a KeyboardInterrupt traceback
    or "0 finished run(s) ... with their report and recording", and left an empty folder."""
    import types

    import scenarios.paper_sim

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    if when == "import":
        module = types.ModuleType("softcbf_mj.outputs.recording")
        module.__getattr__ = lambda name: interrupt()
        monkeypatch.setitem(sys.modules, "softcbf_mj.outputs.recording", module)
    else:
        monkeypatch.setattr(scenarios.paper_sim, "initial_configuration", interrupt)
    out = tmp_path / "new" / "run"
    spawn = ["--spawn"] if when == "import" else []  # rerun is imported at start-up for the viewer only
    assert _main_catching_interrupts(["run", "paper_sim", "--out", str(out), *SHORT, *spawn]) == INTERRUPTED
    err = capsys.readouterr().err
    assert err.strip() == f"interrupted before the first run finished; nothing kept in {out}"
    assert list(tmp_path.iterdir()) == []


def test_console_script_runs():
    """The installed `softcbf` (beside this Python) and `python -m scenarios` answer the same way."""
    script = Path(sys.executable).with_name("softcbf")
    res = subprocess.run([str(script), "run", "nosuch"], capture_output=True, text=True, timeout=120)
    assert res.returncode == USAGE_ERROR and "unknown scenario 'nosuch'" in res.stderr
    res = subprocess.run([sys.executable, "-m", "scenarios", "nosuch", "--out", "x"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == USAGE_ERROR and "unknown scenario 'nosuch'" in res.stderr


DUPLICATES = [  # N8: the same NAME twice silently took the last value
    (["--filter-param", "slack_weight=1e4", "--filter-param", "slack_weight=1e5"],
     "--filter-param slack_weight is given twice (slack_weight=1e4, then slack_weight=1e5); give it once"),
    (["--filter-param", "slack_weight=1e4;slack_weight=1e5"], "--filter-param slack_weight is given twice"),
    (["--filter-params", "slack_weight=1e4", "--filter-param", "slack_weight=1e5"], "slack_weight is given twice"),
    (["--tuning", "Low", "--filter-param", "tuning=High"], "--filter-param tuning is given twice (tuning=Low, then tuning=High)"),
    (["--tuning", "Low", "--tuning", "High"], "tuning is given twice"),
    (["--nominal-param", "frequency=0.1", "--nominal-param", "frequency=0.2"],
     "--nominal-param frequency is given twice (frequency=0.1, then frequency=0.2)"),
]


@pytest.mark.parametrize("entry", ["softcbf", "scenarios"])
@pytest.mark.parametrize("tokens, message", DUPLICATES)
def test_a_plugin_parameter_given_twice_is_refused_naming_it(tmp_path, capsys, entry, tokens, message):
    import scenarios.__main__

    out = tmp_path / "run"
    argv = ["paper_sim", "--duration", "0.01", "--tunings", "None", "--progress", "false", *tokens, "--out", str(out)]
    assert (main(["run", *argv]) if entry == "softcbf" else scenarios.__main__.main(argv)) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and message in err, err
    assert not out.exists()


def test_a_config_file_s_plugin_parameters_are_overridden_not_duplicates(tmp_path, capsys):
    """A parameter of the run configuration file and the same one on the command line: the command line wins."""
    config = tmp_path / "run.toml"
    config.write_text('scenario = "paper_sim"\nduration = 0.01\ntunings = "None"\nprogress = false\n'
                      '[filter_params]\nslack_weight = 1e4\n', encoding="utf-8")
    out = tmp_path / "run"
    assert main(["run", "--config", str(config), "--filter-param", "slack_weight=1e5", "--out", str(out)]) == 0
    assert read_run_folder(out).summary["params"]["filter_params"] == {"slack_weight": 1e5}  # a merge: replayable, typed
    assert read_run_folder(out).runs[0]["filter_params"]["slack_weight"] == 1e5


def test_hardware_refuses_a_plugin_parameter_given_twice(tmp_path, capsys):
    out = tmp_path / "hw"
    assert main(["hardware", str(ROOT / "examples" / "hardware_emulated.toml"), "--port", "emulated", "--camera", "virtual",
                 "--filter", "paper-cbf", "--filter-param", "slack_weight=1e4", "--filter-param", "slack_weight=1e5",
                 "--duration", "0.5", "--dry-run", "--out", str(out)]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--filter-param slack_weight is given twice" in err, err
    assert not out.exists()
