"""`softcbf demo`: the paper's CBF against the recommended filter on the MuJoCo plate, one figure, with progress
(softcbf.demo; short duration here: the full 5 s demo is timed in docs/command-line.md)."""

from __future__ import annotations

import io
import json

import pytest
from matplotlib.image import imread

from controllers.registry import PRESETS
from scenarios.run import USAGE_ERROR
from softcbf.cli import main
from softcbf.demo import FIGURE_FILE, demo_runs, run_demo
from softcbf_mj.outputs.report import DPI, FIGURE_SIZES_IN


@pytest.mark.slow
def test_the_demo_writes_the_figure_and_both_runs_and_says_where(tmp_path, capsys):
    log = io.StringIO()
    figure = run_demo(tmp_path / "demo", duration=0.3, stream=log)
    assert figure == tmp_path / "demo" / FIGURE_FILE
    width, height = FIGURE_SIZES_IN["force"]
    assert imread(figure).shape[:2] == (round(height * DPI), round(width * DPI))
    captured = capsys.readouterr()
    assert captured.out == f"figure: {figure}\n"
    assert "[mujoco_contact Low] |" in captured.err and "[mujoco_contact c-erg:recommended" in captured.err  # progress, stderr
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("softcbf demo: the paper's CBF and the recommended filter, 0.3 s each")
    for k, run in enumerate(demo_runs(), start=1):
        summary = json.loads((tmp_path / "demo" / run.folder / "summary.json").read_text(encoding="utf-8"))
        assert summary["scenario"] == "mujoco_contact" and summary["params"]["filter"] == run.filter
        row = summary["runs"][0]
        assert f"[{k}/2] {run.label}: peak force {row['force_max_N']:.3f} N" in log.getvalue()
    contact = json.loads((tmp_path / "demo" / "c-erg-recommended" / "summary.json").read_text(encoding="utf-8"))
    preset = PRESETS["c-erg:recommended"]
    assert all(contact["params"]["filter_params"][k] == v for k, v in preset.params.items())  # typed values
    paper = json.loads((tmp_path / "demo" / "paper-cbf-low" / "summary.json").read_text(encoding="utf-8"))
    assert paper["runs"][0]["tuning"] == "Low"
    run_demo(tmp_path / "demo", duration=0.3, stream=io.StringIO())  # again into the same folder: replaced


def test_bad_demo_input_is_one_line_and_exit_2(tmp_path, capsys):
    assert main(["demo", "--duration", "0", "--out", str(tmp_path / "d")]) == USAGE_ERROR
    assert capsys.readouterr().err == "error: --duration must be > 0 s, got 0\n"
    (tmp_path / "plain").mkdir()
    (tmp_path / "plain" / "paper-cbf-low").mkdir()
    (tmp_path / "plain" / "paper-cbf-low" / "notes.txt").write_text("mine", encoding="utf-8")
    assert main(["demo", "--duration", "0.2", "--out", str(tmp_path / "plain")]) == USAGE_ERROR
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith("error: ") and (tmp_path / "plain" / "paper-cbf-low" / "notes.txt").is_file()
