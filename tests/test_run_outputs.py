"""When a scenario draws its report and recording (scenarios.run_outputs): once at the end of `Scenario.run` and of
`softcbf run`, never with `softcbf run --data-only` (then `softcbf report DIR` draws them)."""

import shutil

import pytest

import softcbf_mj.outputs.report
from scenarios import get
from scenarios.run_outputs import data_only, once_at_end
from softcbf.cli import main
from softcbf_mj.outputs.recording import RECORDING_FILE
from softcbf_mj.outputs.report import FIGURE_SIZES_IN, PLOTS_DIR, REPORT_FILE

SHORT = dict(duration=0.05, tunings="None,Low", progress=False)
SHORT_ARGS = ["--duration", "0.05", "--tunings", "None,Low", "--progress", "false"]
PLOTS = {f"{name}.png" for name in FIGURE_SIZES_IN}


@pytest.fixture
def reports(monkeypatch):
    """The run folders `write_report` is called with, in order (the real one draws them)."""
    real, calls = softcbf_mj.outputs.report.write_report, []

    def counted(run_dir, *args, **kwargs):
        calls.append(run_dir)
        return real(run_dir, *args, **kwargs)

    monkeypatch.setattr(softcbf_mj.outputs.report, "write_report", counted)
    return calls


def test_a_scenario_of_two_tunings_draws_its_report_once_with_both(tmp_path, reports):
    """The report was drawn after every tuning: k tunings drew k reports (of 1, 2, …, k runs)."""
    get("paper_sim").run(tmp_path, **SHORT)
    assert reports == [tmp_path]
    text = (tmp_path / REPORT_FILE).read_text(encoding="utf-8")
    assert "| None |" in text and "| Low |" in text
    assert {p.name for p in (tmp_path / PLOTS_DIR).iterdir()} == PLOTS
    assert (tmp_path / RECORDING_FILE).is_file()


def test_the_command_line_draws_the_report_once(tmp_path, reports, capsys):
    assert main(["run", "paper_sim", *SHORT_ARGS, "--out", str(tmp_path / "run")]) == 0
    assert reports == [tmp_path / "run"]
    assert "plots/*.png, report.md" in capsys.readouterr().out


def test_data_only_writes_the_data_and_report_draws_the_rest_later(tmp_path, reports, capsys):
    out = tmp_path / "run"
    assert main(["run", "paper_sim", *SHORT_ARGS, "--out", str(out), "--data-only"]) == 0
    printed = capsys.readouterr().out
    assert reports == []
    assert not (out / PLOTS_DIR).exists() and not (out / REPORT_FILE).exists() and not (out / RECORDING_FILE).exists()
    assert f"no plots, report or recording (--data-only): draw them from the saved data: softcbf report {out}" in printed
    assert "recording.rrd" not in printed
    assert main(["report", str(out)]) == 0
    assert {p.name for p in (out / PLOTS_DIR).iterdir()} == PLOTS
    assert "| Low |" in (out / REPORT_FILE).read_text(encoding="utf-8") and (out / RECORDING_FILE).is_file()


def test_data_only_and_spawn_are_refused_together(tmp_path, capsys):
    assert main(["run", "paper_sim", *SHORT_ARGS, "--out", str(tmp_path / "run"), "--data-only", "--spawn"]) == 2
    assert "--spawn streams the runs to a viewer, --data-only draws nothing" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()


def _without_outputs(run_dir, tmp_path):
    """A copy of the short run folder without its report and recording."""
    folder = tmp_path / run_dir.name
    shutil.copytree(run_dir, folder)
    shutil.rmtree(folder / PLOTS_DIR)
    (folder / REPORT_FILE).unlink()
    (folder / RECORDING_FILE).unlink()
    return folder


def test_an_error_after_a_finished_run_still_draws_the_report_of_the_finished_runs(run_dir, tmp_path):
    folder = _without_outputs(run_dir, tmp_path)
    with pytest.raises(RuntimeError, match="a bug"), once_at_end(folder):
        raise RuntimeError("a bug")
    assert (folder / REPORT_FILE).is_file() and (folder / RECORDING_FILE).is_file()


def test_a_report_that_fails_after_an_error_goes_with_the_error_as_a_note(run_dir, tmp_path, monkeypatch):
    folder = _without_outputs(run_dir, tmp_path)

    def broken(run_dir, *args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(softcbf_mj.outputs.report, "write_report", broken)
    with pytest.raises(RuntimeError, match="a bug") as raised, once_at_end(folder):
        raise RuntimeError("a bug")
    assert raised.value.__notes__ == [f"the report and recording of the finished runs in {folder} were not drawn: "
                                      "OSError: disk full"]


def test_ctrl_c_and_data_only_draw_nothing(run_dir, tmp_path, reports):
    folder = _without_outputs(run_dir, tmp_path)
    with pytest.raises(KeyboardInterrupt), once_at_end(folder):
        raise KeyboardInterrupt
    with data_only(), once_at_end(folder):
        pass
    assert reports == [] and not (folder / REPORT_FILE).exists()


def test_the_command_line_inside_data_only_draws_nothing_and_says_so(tmp_path, reports, capsys):
    """A run of the command line inside `data_only()` (a study's or a test's) looked for the recording it had not
    drawn: FileNotFoundError after the run."""
    with data_only():
        assert main(["run", "paper_sim", *SHORT_ARGS, "--out", str(tmp_path / "run")]) == 0
    assert reports == [] and "no plots, report or recording (--data-only)" in capsys.readouterr().out
