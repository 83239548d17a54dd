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
    import softcbf_mj.report

    def fail(folder, **kwargs):
        raise RuntimeError("report failed")

    monkeypatch.setattr(softcbf_mj.report, "write_report", fail)
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
