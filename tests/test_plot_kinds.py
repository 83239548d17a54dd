"""Every plot kind the project writes outside a run's report is fit for a paper with the longest labels the project
produces: the bench's two figures (every case of the battery; the recommended filter's label, the longest, beside
the baselines and a parameterised paper-cbf), a study's distributions and sensitivities (tunings named by the
recommended filter's full label), a falsification's best-so-far curve. Each is rendered with warnings as errors (a
constrained-layout warning fails) and checked: every legend inside the figure and off every axes, its labels at
most softcbf_mj.outputs.palette.LABEL_LIMIT characters (plus a fixed suffix), every tick label clear of its neighbours,
every axis that shows a quantity labelled with words and a unit in brackets. The run plots: test_report_figures.py,
with the same checks (`check_figure`)."""

from __future__ import annotations

import re
import warnings
from itertools import combinations

import numpy as np
import pytest
from matplotlib.figure import Figure

import softcbf.bench.plots as bench_plots
import softcbf.study.report as study_report
from controllers.registry import label as run_label
from softcbf.bench import CASES, RECOMMENDED_FILTER, case_filter_params
from softcbf.bench.plots import PLOTTED, write_force_plot, write_plot
from controllers.governors.energy_governor.parameters import STANDARD_BOX_SETTING
from softcbf_mj.outputs.palette import LABEL_LIMIT

CASE = {c.name: c for c in CASES}
UNIT = re.compile(r"\[[^\]]+\]$")  # "quantity [unit]"
SYMBOLS = ("ρ_", "F_", "u_", "τ_")  # the maths of an axis label (ρ_meas, F_max, u_nom, τ_p), no column names
SUFFIXES = (r": first violation at \d+( \(a filter fault\))?$",)


LONGEST_FILTER = "c-erg(" + ",".join(f"{k}={v}" for k, v in STANDARD_BOX_SETTING.items()) + ")"
"""The longest filter label a bench gets: the standard-box setting typed out parameter by parameter (≈ 300 characters)."""


def full_bench() -> dict:
    """A bench.json of every case of the battery and `longest_filters()`, with faults and nulls where a run can have them."""
    filters = [LONGEST_FILTER, RECOMMENDED_FILTER.label, "e-erg", "paper-cbf", "paper-cbf(tuning=HW-High)", "none"]
    rng = np.random.default_rng(0)
    results = []
    for j, name in enumerate(filters):
        for i, case in enumerate(CASES):
            asked = case.asked_N
            delivered = None if asked is None else min(asked, 0.16) * rng.uniform(0.5, 1.0) * (3.0 if name == "none" else 1.0)
            results.append({
                "filter": name, "case": case.name, "rho_min_meas": float(rng.uniform(-3.0, 1.0)),
                "t_violation_s": 0.0, "force_max_N": float(rng.uniform(0.0, 1.2)), "u_dev_rms_hPa": float(rng.uniform(0, 300)),
                "filter_us_p99": float(10 ** rng.uniform(0.5, 4.7)), "nominal_acceptance": float(rng.uniform(0, 1)),
                "f_max_N": 0.16, "force_asked_N": asked, "force_delivered_N": delivered,
                "force_delivered_ratio": None if asked is None else delivered / min(asked, 0.16)})
    return {"battery": [c.name for c in CASES], "filters": filters, "results": results}


def assert_fit(fig: Figure, where: str) -> None:
    """The checks of the module docstring on a drawn figure."""
    renderer = fig.canvas.get_renderer()
    page = fig.bbox
    for legend in [*fig.legends, *(ax.get_legend() for ax in fig.axes if ax.get_legend() is not None)]:
        box = legend.get_window_extent(renderer)
        assert page.x0 - 1 <= box.x0 and box.x1 <= page.x1 + 1 and page.y0 - 1 <= box.y0 and box.y1 <= page.y1 + 1, where
        assert not any(box.overlaps(ax.get_window_extent(renderer)) for ax in fig.axes), f"{where}: legend over the data"
        for text in legend.get_texts():
            shown = text.get_text()
            for suffix in SUFFIXES:
                shown = re.sub(suffix, "", shown)
            assert len(shown) <= LABEL_LIMIT, f"{where}: legend label {text.get_text()!r} is too long"
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            labels = [t for t in axis.get_ticklabels() if t.get_visible() and t.get_text()]
            boxes = [t.get_window_extent(renderer) for t in labels]
            for (a, ta), (b, tb) in combinations(zip(boxes, labels), 2):
                assert not a.overlaps(b), f"{where}: tick labels {ta.get_text()!r} and {tb.get_text()!r} overlap"
        quantity = [label for label in (ax.get_xlabel(), ax.get_ylabel()) if label]
        assert quantity and all(UNIT.search(label) or label in ("tuning", "case") for label in quantity), \
            f"{where}: axis labels without a unit: {quantity}"
        names = [word for label in quantity for word in re.findall(r"\S*_\S*", label.split("[")[0])
                 if not word.lstrip("|(").startswith(SYMBOLS)]
        assert not names, f"{where}: internal column names as axis labels: {names} in {quantity}"


@pytest.fixture
def checked(monkeypatch):
    """Every figure saved while the test runs is checked (`assert_fit`) as it is drawn for its file."""
    seen: list[str] = []
    original = Figure.savefig

    def save(self, path, *args, **kwargs):
        result = original(self, path, *args, **kwargs)
        assert_fit(self, str(path))
        seen.append(str(path))
        return result

    monkeypatch.setattr(Figure, "savefig", save)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        yield seen


def test_the_bench_figures_fit_a_page_with_every_case_and_the_longest_labels(checked, tmp_path):
    bench = full_bench()
    assert max(len(f) for f in bench["filters"]) > 100  # the recommended filter's label
    write_plot(tmp_path / "bench.png", bench)
    write_force_plot(tmp_path / "force_budget.png", bench)
    assert len(checked) == 2
    assert {t for _, t in PLOTTED} == {"ρ_meas min [1]", "F max [N]", "|u − u_nom| RMS [hPa]", "filter p99 [µs]"}


def test_the_force_plot_ticks_every_asked_level_and_explains_its_marks(monkeypatch, tmp_path):
    """Was: a symlog axis with two ticks and unexplained markers; now a tick at each asked level (0.3, 0.6, 0.9,
    1.2 F_max and the 150 hPa push, ~4 F_max) and a legend entry for each mark (the reference lines, the cross)."""
    drawn = []
    monkeypatch.setattr(bench_plots, "save_figure", lambda fig, *args: drawn.append(fig))
    write_force_plot(tmp_path / "force_budget.png", full_bench())
    (fig,) = drawn
    fig.canvas.draw()
    for ax in fig.axes:
        ticks = [float(t.get_text()) for t in ax.get_xticklabels() if t.get_text()]
        assert ticks == [0.3, 0.6, 0.9, 1.2, pytest.approx(3.97, abs=0.02)], ticks
        assert "[" in ax.get_xlabel()
    (legend,) = fig.legends
    texts = [t.get_text() for t in legend.get_texts()]
    assert {"min(asked, F_max)", "goal", "force-target nominal"} <= set(texts)


def test_a_bench_with_the_contact_tasks_of_one_plant_draws_both_panels(checked, tmp_path):
    """`--cases mujoco_push_060`: the camera panel has no rows; it is drawn empty over the usual range."""
    bench = full_bench()
    bench["results"] = [r for r in bench["results"] if r["case"] == "mujoco_push_060"]
    write_force_plot(tmp_path / "force_budget.png", bench)
    assert len(checked) == 1


def study_rows(tunings: list[str]) -> list[dict]:
    rng = np.random.default_rng(1)
    rows = []
    for i in range(60):
        for tuning in tunings:
            k = rng.uniform(8.9, 13.4)
            rows.append({"sample": len(rows), "draw": i, "tuning": tuning, "status": "ok",
                         "rho_min_meas": float(11.16 - k + rng.normal(0, 0.5)), "force_max_N": float(rng.uniform(0.05, 0.3)),
                         "param.plate_stiffness": float(k), "param.facet_offset": float(rng.uniform(-2e-3, 2e-3)),
                         "param.tau_p": float(rng.uniform(0.02, 0.1))})
    return rows


def test_the_study_and_falsification_figures_fit_a_page_with_the_longest_labels(checked, tmp_path):
    recommended = run_label("c-erg", {**STANDARD_BOX_SETTING,  # the longest: the standard box's setting typed out
                                      **case_filter_params(RECOMMENDED_FILTER, CASE["mujoco_contact"])})
    tunings = [recommended, "Low", "HW-High", recommended.replace("0.9", "0.8")]
    rows = study_rows(tunings)
    study_report.distribution_plot(rows, tunings, "rho_min_meas", tmp_path / "rho.png", "png", 110, line=0.0)
    study_report.distribution_plot(rows, tunings, "force_max_N", tmp_path / "force.png", "png", 110, line=0.16)
    for parameter in ("plate_stiffness", "facet_offset", "tau_p"):
        study_report.sensitivity_plot(rows, tunings, parameter, 6, 0.05, 11.16 if parameter == "plate_stiffness" else None,
                                      tmp_path / f"violation_{parameter}.png", "png", 110)
    curves = {"search (cmaes)": rows[::4][:30], "uniform random": rows[1::4][:30]}
    study_report.best_so_far_plot(curves, "rho_min_meas", tmp_path / "best.png", "png", 110)
    study_report.best_so_far_plot(curves, "-force_max_N", tmp_path / "best_force.png", "png", 110)
    assert len(checked) == 7
