"""Every plot kind of a run's report is fit for a paper with the longest run labels the project writes (the
recommended filter's: every parameter in its label; five paper-cbf presets at once): rendered with warnings as
errors (a constrained-layout warning fails), every legend inside the figure and off every axes, every legend
label at most softcbf_mj.outputs.palette.LABEL_LIMIT characters plus its suffix, every axes with a unit on its y label, no
tick label over its neighbour. The other plot kinds (bench, study, falsification): tests/test_plot_kinds.py."""

from __future__ import annotations

import warnings
from itertools import combinations

import pytest

import softcbf_mj.outputs.report as report
from controllers.governors.energy_governor import RECOMMENDED
from scenarios.api import Filter, MujocoContact, PaperSim, Run, run
from softcbf_mj.outputs.palette import LABEL_LIMIT, plot_labels, short_label
from softcbf_mj.outputs.runio import read_run_folder


def folder_of(result, path):
    for name, data in result.files.items():
        (path / name).parent.mkdir(parents=True, exist_ok=True)
        (path / name).write_bytes(data)
    return path


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A mujoco_contact run of the recommended filter (the longest built-in label) and paper_sim with five presets."""
    short = Run(duration=0.3, progress=False)
    contact = run(MujocoContact(run=short, filter=Filter("c-erg", params=RECOMMENDED)))
    paper = run(PaperSim(run=short, filter=Filter(tunings=("None", "Low", "High", "HW-Low", "HW-High"))))
    return [folder_of(contact, tmp_path_factory.mktemp("contact")), folder_of(paper, tmp_path_factory.mktemp("paper"))]


def check_figure(fig, path):
    """The figure's legends lie inside it and off its axes; their labels are short; its axes carry units."""
    renderer = fig.canvas.get_renderer()
    page = fig.bbox
    for legend in fig.legends:
        box = legend.get_window_extent(renderer)
        assert page.x0 - 1 <= box.x0 and box.x1 <= page.x1 + 1 and page.y0 - 1 <= box.y0 and box.y1 <= page.y1 + 1, path
        assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes), path
        assert all(len(text.get_text().split(" arm at")[0].removesuffix(" measured").removesuffix(" predicted")
                       .removesuffix(" tip").removesuffix(" u")) <= LABEL_LIMIT for text in legend.get_texts()), path
    for ax in fig.axes:
        assert "[" in ax.get_ylabel() and "]" in ax.get_ylabel(), (path, ax.get_ylabel())
        for axis in (ax.xaxis, ax.yaxis):  # tick labels clear of their neighbours (tests/test_plot_kinds.py)
            boxes = [t.get_window_extent(renderer) for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            assert not any(a.overlaps(b) for a, b in combinations(boxes, 2)), (path, "tick labels overlap")


@pytest.mark.parametrize("figure_format", ["png", "pdf"])
def test_every_plot_kind_renders_without_a_warning_legends_outside(folders, figure_format, monkeypatch):
    saved = []
    original = report.save_figure

    def save_and_check(fig, path, fmt, dpi):
        original(fig, path, fmt, dpi)
        check_figure(fig, path)
        saved.append(path.stem)

    monkeypatch.setattr(report, "save_figure", save_and_check)
    for folder in folders:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            report.write_report(folder, figure_format=figure_format)
    assert sorted(saved) == sorted(2 * list(report.FIGURE_SIZES_IN))
    text = (folders[0] / report.REPORT_FILE).read_text(encoding="utf-8")
    (full,) = read_run_folder(folders[0]).labels
    assert len(full) > LABEL_LIMIT and f"- {short_label(full)}: `{full}`" in text  # report.md keys the short label


def test_the_demo_figure_and_a_lone_force_plot_render_without_a_warning(folders, tmp_path):
    folder = read_run_folder(folders[1])
    runs = [(label, "#56B4E9", folder.timeseries(label)[0]) for label in folder.labels[:2]]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        report.plot_force(report.Scene.of(folder), runs, tmp_path / "force.png")
    assert (tmp_path / "force.png").read_bytes().startswith(b"\x89PNG")


def test_short_labels_are_distinct_and_within_the_limit():
    labels = ["None", "x" * 30 + "a", "x" * 30 + "b", "y" * LABEL_LIMIT]
    short = plot_labels(labels)
    assert short[0] == "None" and short[3] == labels[3] and len(set(short)) == 4
    assert all(len(s) <= LABEL_LIMIT for s in short) and short[1].endswith(" #2") and short[2].endswith(" #3")
    assert short_label("x" * 30) == "x" * (LABEL_LIMIT - 1) + "…"
    with pytest.raises(ValueError, match="limit must be >= 2 characters, got 1"):
        short_label("abc", 1)
