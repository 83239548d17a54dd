"""The `softcbf` CLI: list, run, report, --version, errors and exit codes, interrupted runs."""

import json
import shutil
import subprocess
import sys
import tomllib
from importlib import metadata
from pathlib import Path

import pytest
import rerun as rr

import scenarios.common
import softcbf_mj
from scenarios import registry
from softcbf.cli import INTERRUPTED, USAGE_ERROR, main
from softcbf_mj.report import FIGURE_SIZES_IN
from softcbf_mj.runio import load_timeseries, read_run_folder

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
    assert not [n for n in names if Path(n).name.startswith(".")]  # no temp files left
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
        (["run", "paper_sim", "--speed", "3"], "unknown parameter(s) --speed 3 for scenario paper_sim; valid: --duration, "),
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
    (tmp_path / "keep.txt").write_text("data")
    assert main(["run", "paper_sim", "--out", str(tmp_path), "--duration", "0.01"]) == USAGE_ERROR
    err = capsys.readouterr().err
    assert f"{tmp_path} exists and is not empty; choose another --out or pass --overwrite" in err
    assert (tmp_path / "keep.txt").read_text() == "data"
    assert main(["run", "paper_sim", "--out", str(tmp_path), "--overwrite", "--duration", "0.01", "--tunings", "None",
                 "--progress", "false"]) == 0
    assert not (tmp_path / "keep.txt").exists() and (tmp_path / "summary.json").is_file()


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


def test_console_script_runs():
    """The installed `softcbf` (beside this Python) and `python -m scenarios` answer the same way."""
    script = Path(sys.executable).with_name("softcbf")
    res = subprocess.run([str(script), "run", "nosuch"], capture_output=True, text=True, timeout=120)
    assert res.returncode == USAGE_ERROR and "unknown scenario 'nosuch'" in res.stderr
    res = subprocess.run([sys.executable, "-m", "scenarios", "nosuch", "--out", "x"], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == USAGE_ERROR and "unknown scenario 'nosuch'" in res.stderr
