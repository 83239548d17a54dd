"""Hostile use of replay, save and the files around a run: a config.json replay runs the filter file the run
recorded or refuses (its SHA-256), `scenarios.api.save` writes inside its folder and all or nothing, duplicate
filter parameters are refused wherever they can be written, `softcbf list | head` exits quietly, and a hardware file
with absurd numbers is one line, exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from scenarios.run import USAGE_ERROR
from softcbf.cli import main

RUN = ["--duration", "0.05", "--progress", "false"]
CLIP = ("import numpy as np\n\n\nclass Clip:\n    def __init__(self, limit_hPa: float = 1.0):\n"
        "        self.limit = limit_hPa\n\n    def __call__(self, estimate, u_nom):\n"
        "        return np.clip(u_nom, -self.limit, self.limit)\n")


# --- replay (config.json): the recorded filter file, or a refusal ----------------------------------------------------


@pytest.fixture
def recorded(tmp_path, monkeypatch, capsys):
    """A paper_sim run of `filt.py:Clip` recorded from folder a/, and a folder b/ whose filt.py is another file."""
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir(), b.mkdir()
    (a / "filt.py").write_text(CLIP, encoding="utf-8")
    (b / "filt.py").write_text("raise RuntimeError('the file in b/ ran, not the recorded one')\n", encoding="utf-8")
    monkeypatch.chdir(a)
    assert main(["run", "paper_sim", "--filter", "filt.py:Clip", *RUN, "--out", str(tmp_path / "first")]) == 0
    monkeypatch.chdir(b)
    capsys.readouterr()
    return tmp_path / "first" / "config.json"


def test_config_json_records_the_filter_file_s_absolute_path_and_hash(recorded):
    import hashlib

    config = json.loads(recorded.read_text(encoding="utf-8"))
    source = config["sources"]["filter"]
    path = recorded.parent.parent / "a" / "filt.py"
    assert source == {"path": str(path), "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    assert "nominal" not in config["sources"]  # a built-in: nothing to record


def test_a_replay_from_another_folder_runs_the_recorded_file(recorded, tmp_path, capsys):
    assert main(["run", "--config", str(recorded), "--out", str(tmp_path / "replay")]) == 0, capsys.readouterr().err
    replayed = json.loads((tmp_path / "replay" / "config.json").read_text(encoding="utf-8"))
    assert replayed["params"]["filter"] == f"{tmp_path / 'a' / 'filt.py'}:Clip"
    assert "SHA-256" not in capsys.readouterr().err


def test_a_replay_of_a_changed_file_is_refused_in_one_line_unless_allowed_loudly(recorded, tmp_path, capsys):
    source = tmp_path / "a" / "filt.py"
    source.write_text(CLIP.replace("limit_hPa: float = 1.0", "limit_hPa: float = 1e6"), encoding="utf-8")
    assert main(["run", "--config", str(recorded), "--out", str(tmp_path / "refused")]) == USAGE_ERROR
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"the filter file {source} changed since the run was recorded" in err
    assert "--allow-changed-filter" in err and not (tmp_path / "refused").exists()
    assert main(["run", "--config", str(recorded), "--allow-changed-filter", "--out", str(tmp_path / "allowed")]) == 0
    assert "WARNING: --allow-changed-filter: the filter file" in capsys.readouterr().err


def test_a_missing_recorded_file_is_refused_and_an_override_is_not_checked(recorded, tmp_path, capsys):
    (tmp_path / "a" / "filt.py").unlink()
    assert main(["run", "--config", str(recorded), "--out", str(tmp_path / "missing")]) == USAGE_ERROR
    assert "no longer exists" in capsys.readouterr().err
    assert main(["run", "--config", str(recorded), "--filter", "none", "--out", str(tmp_path / "other")]) == 0


def test_a_config_json_without_hashes_resolves_against_its_recorded_working_folder(recorded, tmp_path, capsys):
    config = json.loads(recorded.read_text(encoding="utf-8"))
    del config["sources"]
    recorded.write_text(json.dumps(config), encoding="utf-8")
    assert main(["run", "--config", str(recorded), "--out", str(tmp_path / "old")]) == 0
    assert f"records no SHA-256 of the filter file {tmp_path / 'a' / 'filt.py'}" in capsys.readouterr().err


def test_allow_changed_filter_outside_a_replay_is_a_usage_error(capsys):
    assert main(["run", "paper_sim", "--allow-changed-filter", *RUN]) == USAGE_ERROR
    assert "applies to a replay" in capsys.readouterr().err


# --- scenarios.api.save: inside the folder, all or nothing ----------------------------------------------------------


@pytest.fixture(scope="module")
def result():
    from scenarios.api import Filter, PaperSim, Run, run

    return run(PaperSim(run=Run(duration=0.05, progress=False), filter=Filter(tunings=("High",))))


def with_files(result, **extra: bytes):
    import dataclasses

    return dataclasses.replace(result, files={**result.files, **extra})


@pytest.mark.parametrize("name", ["../x", "../../x", "a/../../x", "/tmp/softcbf-hostile-save", "", ".", "./x", "a//b",
                                  "a\\..\\x", ".softcbf-run"])
def test_save_refuses_a_file_outside_its_folder_and_writes_nothing(result, tmp_path, name):
    from scenarios.api import save

    bad = with_files(result)
    bad.files[name] = b"outside"
    with pytest.raises(ValueError, match="a saved file must be a path inside the run folder"):
        save(bad, tmp_path / "out" / "run")
    assert list(tmp_path.iterdir()) == [] and not Path("/tmp/softcbf-hostile-save").exists()


def test_a_failed_save_leaves_nothing_and_keeps_an_overwritten_folder(result, tmp_path, monkeypatch):
    from scenarios.api import save

    broken = with_files(result, **{"notes/a": b"1"})
    broken.files["notes/a/b"] = b"2"  # "notes/a" is a file: this one cannot be written
    with pytest.raises(OSError):
        save(broken, tmp_path / "new" / "run")
    assert list(tmp_path.iterdir()) == []
    first = save(result, tmp_path / "run")
    before = sorted(p.relative_to(first).as_posix() for p in first.rglob("*"))
    import softcbf_mj.outputs.report

    def fail(folder, **kwargs):
        raise RuntimeError("report failed")

    monkeypatch.setattr(softcbf_mj.outputs.report, "write_report", fail)
    with pytest.raises(RuntimeError, match="report failed"):
        save(with_files(result, extra=b"x"), first, overwrite=True)
    assert sorted(p.relative_to(first).as_posix() for p in first.rglob("*")) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no temporary folder left beside it


def test_save_writes_the_folder_it_names(result, tmp_path):
    from scenarios.api import save

    out = save(with_files(result, **{"notes/extra.txt": b"kept"}), tmp_path / "deep" / "run")
    assert (out / "notes" / "extra.txt").read_bytes() == b"kept" and (out / "report.md").is_file()
    assert out.name in (out / "report.md").read_text(encoding="utf-8").splitlines()[0]  # titled by its own name
    assert sorted(p.name for p in (tmp_path / "deep").iterdir()) == ["run"]


# --- duplicate filter parameters: refused wherever they are written -------------------------------------------------

TWICE = "slack_weight is given twice (slack_weight=10000.0, then slack_weight=100000.0); give it once"


def write_run_config(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize("name, text, message", [
    ("run.toml", 'scenario = "paper_sim"\nduration = 0.05\nfilter_params = "slack_weight=10000.0;slack_weight=100000.0"\n', TWICE),
    ("config.json", json.dumps({"scenario": "paper_sim", "params": {
        "duration": 0.05, "filter_params": "slack_weight=10000.0;slack_weight=100000.0"}}), TWICE),
    ("config.json", '{"scenario": "paper_sim", "params": {"duration": 0.05, "f_max": 0.16, "f_max": 1e6}}',
     "key 'f_max' is given twice in one object (0.16, then 1000000.0); give it once"),
    ("run.toml", 'scenario = "paper_sim"\n[filter_params]\nslack_weight = 1e4\nslack_weight = 1e5\n', "Cannot overwrite a value"),
])
def test_a_run_file_giving_a_parameter_twice_is_refused_in_one_line(tmp_path, capsys, name, text, message):
    config = write_run_config(tmp_path / name, text)
    assert main(["run", "--config", str(config), "--progress", "false", "--out", str(tmp_path / "out")]) == USAGE_ERROR
    err = [line for line in capsys.readouterr().err.strip().splitlines() if not line.startswith("warning: ")]
    assert len(err) == 1 and message in err[0] and not (tmp_path / "out").exists()  # (warning: records no versions)


def test_the_command_line_overrides_a_file_s_parameter_and_keeps_the_others():
    from scenarios import get
    from scenarios.run import scenario_parameters

    params = scenario_parameters(get("paper_sim"), ["--filter-param", "slack_weight=1e5"],
                                 {"filter_params": {"slack_weight": 1e4, "tuning": "Low"}})
    assert params["filter_params"] == {"slack_weight": "1e5", "tuning": "Low"}  # the filter types them (scenarios.spec)


def test_the_python_api_refuses_a_filter_parameter_twice():
    from scenarios.api import Filter, PaperSim

    with pytest.raises(ValueError, match="slack_weight is given twice"):
        PaperSim(filter=Filter("paper-cbf", params="slack_weight=1e4;slack_weight=1e5"))


STUDY = ('name = "twice"\nscenario = "paper_sim"\ntunings = ["High"]\ndraws = 1\n{filter_params}\n[fixed]\nduration = 0.05\n'
         '[vary.plate_stiffness]\ndist = "uniform"\nlow = 10.0\nhigh = 12.0\n{vary}')


@pytest.mark.parametrize("filter_params, vary, message", [
    ('filter_params = "slack_weight=1e4;slack_weight=1e5"', "", "filter_params: parameter slack_weight is given twice"),
    ('filter_params = "slack_weight=1e4"', '[vary."filter_param.slack_weight"]\ndist = "choice"\nvalues = [1e5]\n',
     "filter parameter(s) slack_weight are given twice (in filter_params and varied as filter_param.NAME)"),
])
def test_a_study_file_giving_a_filter_parameter_twice_is_refused(tmp_path, filter_params, vary, message):
    from softcbf.study.definition import load_study

    path = tmp_path / "study.toml"
    path.write_text(STUDY.format(filter_params=filter_params, vary=vary), encoding="utf-8")
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        load_study(path)


def test_a_hardware_json_file_giving_a_key_twice_is_refused(tmp_path):
    from hardware.config import ConfigError, HardwareConfig

    path = tmp_path / "hw.json"
    path.write_text('{"filter": "paper-cbf", "filter_params": {"slack_weight": 1e4, "slack_weight": 1e5}}', encoding="utf-8")
    with pytest.raises(ConfigError, match="key 'slack_weight' is given twice"):
        HardwareConfig.load(path)


# --- a closed stdout: `softcbf list | head` ends quietly -------------------------------------------------------------


@pytest.mark.parametrize("argv", [["-m", "softcbf.cli", "list"], ["-m", "softcbf.cli", "run", "--help"],
                                  ["-m", "softcbf.cli", "run", "paper_sim", "--help"], ["-m", "scenarios", "--list"]])
def test_a_command_whose_reader_has_gone_exits_141_without_a_traceback(argv):
    """A real pipe whose read end is closed before the command writes: every write fails with EPIPE, as after
    `| head` has read its lines."""
    import os
    import subprocess
    import sys

    read, write = os.pipe()
    os.close(read)
    try:
        result = subprocess.run([sys.executable, *argv], stdout=write, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert (result.returncode, result.stderr) == (141, "")


def test_head_reads_the_first_lines_of_softcbf_list_and_the_command_ends_quietly():
    import subprocess
    import sys

    result = subprocess.run(["bash", "-c", f"set -o pipefail; {sys.executable} -m softcbf.cli list | head -n 1; "
                                           "echo status ${PIPESTATUS[0]}"], capture_output=True, text=True, timeout=120)
    assert result.stdout.splitlines()[0] == "scenarios:" and "Traceback" not in result.stderr
    assert result.stdout.splitlines()[-1] in ("status 0", "status 141")  # 0 when the listing fit in the pipe's buffer


# --- a hardware file with absurd numbers: one line, exit 2 -----------------------------------------------------------


@pytest.mark.parametrize("change, message", [
    (("h = [0.15]", "h = [1e300]"), "environment.h[0] must put facet 0 within 10 m of the arm's base"),
    (("h = [0.15]", "h = [150.0]"), "a value in millimetres?"),
    (("width = 480 ", "width = 100000 "), "width must be <= 1280 px for the virtual camera"),
    (("height = 270 ", "height = 100000 "), "height must be <= 720 px for the virtual camera"),
])
def test_a_hardware_file_with_absurd_numbers_is_one_line_exit_2(tmp_path, capsys, change, message):
    import shutil

    from softcbf.hardware_cli import main as hardware_main

    examples = Path(__file__).resolve().parents[1] / "examples"
    text = (examples / "hardware_emulated.toml").read_text(encoding="utf-8")
    assert change[0] in text
    (tmp_path / "hw.toml").write_text(text.replace(change[0], change[1]), encoding="utf-8")
    shutil.copy(examples / "hardware_slow_arm_robot.json", tmp_path)
    assert hardware_main([str(tmp_path / "hw.toml"), "--out", str(tmp_path / "out")]) == USAGE_ERROR
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and not (tmp_path / "out").exists()
