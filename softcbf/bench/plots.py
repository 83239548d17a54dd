"""The bench's figures: DIR/plots/bench.png (`write_plot`) and DIR/plots/force_budget.png (`write_force_plot`).

Both follow softcbf_mj.outputs.plot_style (text width 7.16 in, 8 pt text, the constrained layout, legends outside the
axes) and name each filter by `softcbf_mj.outputs.palette.plot_labels` of its label (the recommended filter's label
has about 140 characters; bench.md keeps the full ones), coloured by softcbf_mj.outputs.plot_style.distinct_colors.

bench.png: one panel per figure of `PLOTTED`, side by side, each x axis with its quantity and unit (ρ is
dimensionless, [1]); the cases along the shared y axis, one row each, top to bottom in the battery's order,
so that no case name overlaps another; one horizontal bar per filter in each row (a case that a filter did
not run, or a figure that is null, has no bar); ρ = 0 marked in the ρ panel, F_max in the force panel
(dashed), the compute time on a log axis. The legend lies below the panels.

force_budget.png: the contact tasks' delivered force against the asked force (both / F_max: the case's
`f_max_N`), one panel per plant of `PUSHES`, sharing the y axis. x is logarithmic with a tick at every
asked level (0.3, 0.6, 0.9, 1.2 F_max and the 150 hPa push, about 4 F_max), so the four constant pushes are
evenly spaced and the 150 hPa push fits; each filter's constant pushes are joined by a line (circles), its
force-target case (asked 0.59 F_max) is a cross of the same colour; the dashed line is min(asked, F_max),
what a perfect filter delivers; the dotted line is the goal of docs/beyond-the-paper.md#contact-tasks
(0.95 × asked below 0.8 F_max, 0.8 F_max beyond). A delivered force above `FORCE_PLOT_TOP` × F_max is drawn
at the top with its value beside it. The legend (the filters, then the marks' meanings) lies right of the
panels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.ticker import NullLocator

from softcbf.bench.cases import PUSH_PREFIX, PUSHES
from softcbf_mj.outputs.palette import LIMIT_COLOR, NEUTRAL_COLOR, plot_labels
from softcbf_mj.outputs.plot_style import GRID_ALPHA, TEXT_WIDTH_IN, distinct_colors, legend_outside, new_figure, save_figure, styled

DPI = 200
PLOTTED = (("rho_min_meas", "ρ_meas min [1]"), ("force_max_N", "F max [N]"), ("u_dev_rms_hPa", "|u − u_nom| RMS [hPa]"),
           ("filter_us_p99", "filter p99 [µs]"))
ROW_HEIGHT_IN = 0.2  # in: one case's row in bench.png (three filters' bars of 7 pt text height)
FORCE_PLOT_TOP = 1.5
GOAL_KNEE, GOAL_SLOPE = 0.8, 0.95  # the contact tasks' goal: 0.95 × asked below 0.8 F_max, 0.8 F_max beyond
MARKS = (("min(asked, F_max)", "k", "--", ""), ("goal", "k", ":", ""), ("force-target nominal", NEUTRAL_COLOR, "", "x"))


def write_plot(path: Path, bench: Mapping[str, Any], dpi: float = DPI) -> None:
    """bench.png of `bench` (module docstring)."""
    cases = [c for c in bench["battery"] if any(r["case"] == c for r in bench["results"])]
    filters, shown = bench["filters"], plot_labels(bench["filters"])
    height = max(1.0, len(cases)) * ROW_HEIGHT_IN * max(1.0, len(filters) / 3) + 1.2
    width = 0.8 / max(1, len(filters))
    with styled():
        fig = new_figure((TEXT_WIDTH_IN, height), dpi)
        axes = fig.subplots(1, len(PLOTTED), sharey=True)
        for ax, (key, title) in zip(axes, PLOTTED):
            for j, (name, label, colour) in enumerate(zip(filters, shown, distinct_colors(filters))):
                values = {r["case"]: r[key] for r in bench["results"] if r["filter"] == name and r[key] is not None}
                y = [i - 0.4 + (j + 0.5) * width for i, c in enumerate(cases) if c in values]
                ax.barh(y, [values[c] for c in cases if c in values], width, label=label, color=colour)
            _mark_panel(ax, key, bench["results"])
            ax.set_xlabel(title)
            ax.grid(axis="x", alpha=GRID_ALPHA)
        axes[0].set_yticks(range(len(cases)), cases)
        axes[0].set_ylim(len(cases) - 0.5, -0.5)
        legend_outside(fig, axes[:1], loc="outside lower center", ncols=min(3, len(filters)), title="filter")
        save_figure(fig, path, "png", dpi)


def _mark_panel(ax, key: str, results: Sequence[Mapping[str, Any]]) -> None:
    """ρ = 0 in the ρ panel, F_max in the force panel (one limit shared by the rows), a log axis for compute time."""
    if key == "rho_min_meas":
        ax.axvline(0.0, color=LIMIT_COLOR, lw=1.0)
    elif key == "force_max_N":
        limits = {r["f_max_N"] for r in results}
        if len(limits) == 1:
            ax.axvline(limits.pop(), color=LIMIT_COLOR, lw=1.0, ls="--")
    elif key == "filter_us_p99":
        ax.set_xscale("log")


def push_rows(bench: Mapping[str, Any], name: str, plant: str) -> list[Mapping[str, Any]]:
    """The filter `name`'s contact-task rows of `plant` (`PUSHES`: on the exact plate; the flexure sheet and the
    push draws are contact under error, in bench.md) that delivered a force, by asked force."""
    prefix = PUSH_PREFIX[plant] + "_"
    return sorted((r for r in bench["results"] if r["filter"] == name and r["case"].startswith(prefix)
                   and r["case"][len(prefix):] in PUSHES[plant] and r["force_delivered_N"] is not None),
                  key=lambda r: r["force_asked_N"])


def _draw_filter(ax, rows: Sequence[Mapping[str, Any]], label: str, colour: str) -> None:
    """A filter's constant pushes (circles joined) and force-target case (a cross); values beyond the top at it."""
    asked = np.array([r["force_asked_N"] / r["f_max_N"] for r in rows])
    delivered = np.array([r["force_delivered_N"] / r["f_max_N"] for r in rows])
    push = np.array(["_push_" in r["case"] for r in rows])
    shown = np.minimum(delivered, FORCE_PLOT_TOP)
    ax.plot(asked[push], shown[push], "o-", ms=3.5, color=colour, label=label)
    ax.plot(asked[~push], shown[~push], "x", ms=6, mew=1.5, color=colour)
    for x, y in zip(asked[delivered > FORCE_PLOT_TOP], delivered[delivered > FORCE_PLOT_TOP]):
        ax.annotate(f"{y:.2f}", (x, FORCE_PLOT_TOP), textcoords="offset points", xytext=(-4, -9), ha="right",
                    fontsize=6, color=colour)


def _force_axes(ax, asked: Sequence[float], plant: str) -> None:
    """The reference lines, the log x axis with a tick per asked level of the plant's constant pushes (`PUSHES`, so
    that both panels show every level whatever ran), the limits and the panel's title."""
    lo, hi = min(asked) / 1.3, max(asked) * 1.3
    x = np.geomspace(lo, hi, 200)
    ax.plot(x, np.minimum(x, 1.0), "k--", lw=0.8)
    ax.plot(x, np.where(x < GOAL_KNEE, GOAL_SLOPE * x, GOAL_KNEE), "k:", lw=0.8)
    ax.set_xscale("log")
    ax.set_xlim(lo, hi)
    ticks = sorted({round(a, 2) for a in asked})
    ax.set_xticks(ticks, [f"{t:g}" for t in ticks])
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_ylim(0.0, FORCE_PLOT_TOP * 1.04)
    ax.set_title(plant)
    ax.set_xlabel("asked / F_max [1]")
    ax.grid(alpha=GRID_ALPHA)


def write_force_plot(path: Path, bench: Mapping[str, Any], dpi: float = DPI) -> None:
    """force_budget.png of `bench` (module docstring)."""
    filters, shown = bench["filters"], plot_labels(bench["filters"])
    with styled():
        fig = new_figure((TEXT_WIDTH_IN, 2.8), dpi)
        axes = fig.subplots(1, len(PUSHES), sharey=True, squeeze=False)[0]
        for ax, plant in zip(axes, PUSHES):
            limit = None
            for name, label, colour in zip(filters, shown, distinct_colors(filters)):
                rows = push_rows(bench, name, plant)
                if rows:
                    _draw_filter(ax, rows, label, colour)
                    limit = rows[0]["f_max_N"]
            asked = [force / limit for suffix, (_, force) in PUSHES[plant].items() if suffix.startswith("push_")] \
                if limit else [0.3, 1.2]  # a plant without rows: an empty panel over the usual range
            _force_axes(ax, asked, plant)
        axes[0].set_ylabel("delivered / F_max [1]")
        for text, colour, style, marker in MARKS:
            axes[0].add_line(Line2D([], [], color=colour, ls=style or "none", marker=marker or None, lw=0.8,
                                    label=text))
        legend_outside(fig, axes)
        save_figure(fig, path, "png", dpi)
