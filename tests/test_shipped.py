"""The shipped studies, hardware configurations and examples by name (softcbf.shipped), from any working folder:
`softcbf study run|falsify NAME`, `softcbf hardware NAME`, `softcbf examples DIR [--overwrite]`.

The installed wheel's layout (softcbf_files/) is the checkout's folders copied; tests/test_packaging.py runs the
same commands from a built wheel."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

import pytest

from softcbf import shipped
from softcbf.cli import main
from softcbf.shipped import UnknownShipped, copy_examples, resolve, shipped_files, shipped_names

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def elsewhere(tmp_path, monkeypatch):
    """A working folder outside the checkout (nothing of it under the repository's relative paths)."""
    work = tmp_path / "elsewhere"
    work.mkdir()
    monkeypatch.chdir(work)
    return work


def test_the_shipped_names_are_the_checkouts_studies_and_hardware_configurations():
    assert shipped_names("study") == {p.stem: p for p in sorted((ROOT / "studies").glob("*.toml"))}
    assert shipped_names("hardware") == {"hardware_emulated": ROOT / "examples" / "hardware_emulated.toml"}
    files = {p.as_posix() for p in shipped_files()}
    assert {"examples/clip_filter.py", "examples/shield_cem.py", "examples/hardware_slow_arm_robot.json",
            "studies/mismatch_box_contact.toml"} <= files
    assert not any("__pycache__" in f for f in files)


def test_a_name_or_the_repositorys_path_resolves_outside_the_checkout(elsewhere):
    box = ROOT / "studies" / "mismatch_box_contact.toml"
    assert resolve("study", "mismatch_box_contact") == box
    assert resolve("study", "mismatch_box_contact.toml") == box
    assert resolve("study", "studies/mismatch_box_contact.toml") == box  # the README's path, not in this folder
    assert resolve("hardware", "hardware_emulated") == ROOT / "examples" / "hardware_emulated.toml"
    assert resolve("hardware", Path("examples/hardware_emulated.toml")) == ROOT / "examples" / "hardware_emulated.toml"


def test_a_users_own_file_wins_over_the_shipped_one(elsewhere):
    own = elsewhere / "mismatch_box_contact"
    own.write_text("name = 'mine'\n", encoding="utf-8")
    assert resolve("study", "mismatch_box_contact") == Path("mismatch_box_contact")
    (elsewhere / "studies").mkdir()
    (elsewhere / "studies" / "paper_low_plate_corner.toml").write_text("name = 'mine'\n", encoding="utf-8")
    assert resolve("study", "studies/paper_low_plate_corner.toml") == Path("studies/paper_low_plate_corner.toml")


def test_an_unknown_name_is_one_line_with_the_closest_and_all_shipped_names(elsewhere):
    with pytest.raises(UnknownShipped) as error:
        resolve("study", "mismatch_box_contat")
    message = str(error.value)
    assert "\n" not in message and "'mismatch_box_contat'" in message
    assert "did you mean 'mismatch_box_contact'" in message
    assert all(name in message for name in shipped_names("study"))
    with pytest.raises(UnknownShipped, match="shipped study"):
        resolve("study", "hardware_emulated")  # a kind's names only: a hardware configuration is no study
    with pytest.raises(UnknownShipped, match="shipped hardware configuration"):
        resolve("hardware", "mismatch_box_contact")
    with pytest.raises(UnknownShipped):
        resolve("study", "elsewhere/mismatch_box_contact.toml")  # a path in another folder is not the repository's


def test_the_installed_wheels_files_are_preferred_to_a_folder_beside_the_packages(tmp_path, monkeypatch):
    installed = tmp_path / "softcbf_files"
    (installed / "studies").mkdir(parents=True)
    (installed / "examples").mkdir()
    (installed / "studies" / "only_installed.toml").write_text("name = 'x'\n", encoding="utf-8")
    (installed / "examples" / "hardware_board.toml").write_text("f_max = 0.1\n", encoding="utf-8")
    monkeypatch.setattr(shipped, "INSTALLED", installed)
    assert list(shipped_names("study")) == ["only_installed"]
    assert resolve("hardware", "hardware_board") == installed / "examples" / "hardware_board.toml"
    assert [p.as_posix() for p in shipped_files()] == ["examples/hardware_board.toml", "studies/only_installed.toml"]


@pytest.mark.parametrize("command", ["run", "falsify"])
def test_study_commands_take_a_shipped_name(command, elsewhere, capsys):
    """The shipped file is read (its error names it) and nothing is written: a key the scenario lacks stops it."""
    out = elsewhere / "out"
    assert main(["study", command, "mismatch_box_contact", "--out", str(out), "--set", "fixed.nosuch=1"]) == 2
    err = capsys.readouterr().err
    assert f"study file {ROOT / 'studies' / 'mismatch_box_contact.toml'}: " in err and "'nosuch'" in err
    assert not out.exists()
    assert main(["study", command, "mismatch_box_contat", "--out", str(out)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("error: study 'mismatch_box_contat' is neither") and "did you mean" in line
    assert not out.exists()


def test_hardware_takes_a_shipped_name(elsewhere, capsys):
    from softcbf.hardware_cli import add_arguments, configure

    parser = argparse.ArgumentParser()
    add_arguments(parser)
    config = configure(parser.parse_args(["hardware_emulated", "--duration", "1"]))
    assert config.base_dir == ROOT / "examples" and config.to_dict()["duration"] == 1.0  # its robot file beside it
    assert main(["hardware", "hardware_emulatd"]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert "did you mean 'hardware_emulated'" in line and "examples/hardware_emulated.toml" not in line
    assert not (elsewhere / "runs").exists()


def test_examples_copies_every_shipped_file_and_refuses_to_overwrite(elsewhere, capsys):
    dest = elsewhere / "mine"
    assert main(["examples", str(dest)]) == 0
    files = sorted(p.relative_to(dest) for p in dest.rglob("*") if p.is_file())
    assert files == shipped_files()
    for relative in files:
        assert (dest / relative).read_bytes() == (ROOT / relative).read_bytes()
    assert "softcbf hardware examples/hardware_emulated.toml" in capsys.readouterr().out
    edited = dest / "studies" / "mismatch_box_contact.toml"
    edited.write_text("name = 'edited'\n", encoding="utf-8")
    assert main(["examples", str(dest)]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith("error: ") and "--overwrite" in line
    assert edited.read_text(encoding="utf-8") == "name = 'edited'\n"  # refused before writing anything
    assert main(["examples", str(dest), "--overwrite"]) == 0
    assert edited.read_bytes() == (ROOT / "studies" / "mismatch_box_contact.toml").read_bytes()


def test_examples_refuses_a_file_as_its_folder(elsewhere, capsys):
    (elsewhere / "taken").write_text("x", encoding="utf-8")
    assert main(["examples", "taken"]) == 2
    assert len(capsys.readouterr().err.splitlines()) == 1


def test_copied_examples_run_from_their_folder(elsewhere):
    """From the copy, a study's files relative to the working folder (a FILE.py filter) are found."""
    from softcbf.study.definition import load_study

    copy_examples(elsewhere)
    study = load_study(resolve("study", "examples/clip_filter_study.toml"))
    assert study.name == "clip_filter_limit"
    shutil.rmtree(elsewhere / "examples")
    with pytest.raises(UnknownShipped):
        resolve("study", "examples/clip_filter_study.toml")  # not a study name: its filter path needs the copy
