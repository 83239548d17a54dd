"""The one style of every figure the project writes (run reports, study and falsification reports, the bench).

Sizes are a journal's (IEEE's two-column layout): `COLUMN_WIDTH_IN` = 3.5 in for one column,
`TEXT_WIDTH_IN` = 7.16 in for the full text width, so that a figure is placed at 100 % and its text
(`STYLE`: 8 pt, ticks and legends 7 pt) reads as the paper's own. Colours: softcbf_mj.outputs.palette (Okabe–Ito);
labels of runs and filters: softcbf_mj.outputs.palette.plot_labels (at most LABEL_LIMIT characters, kept distinct); colours
of several labels in one figure: `distinct_colors` (a paper tuning its own colour, every other label the next
colour of palette.RUN_CYCLE that no label of the figure has yet, so "Low" and a filter never share sky blue).

Figures use matplotlib's Agg canvas directly (`new_figure`: `matplotlib.figure.Figure`, no pyplot, no global
backend change) in the constrained layout, which warns where it cannot fit the axes; the rc parameters of
`STYLE` apply inside `styled()` (matplotlib.rc_context, nothing global). Legends sit outside the axes, each
entry once (`legend_outside`). `save_figure` writes a file atomically (temp file + rename) in one of
`FIGURE_FORMATS`, without a creation date in svg/pdf (a rebuild gives the same bytes).

tests/test_plot_kinds.py and tests/test_report_figures.py render every plot kind with the longest labels the
project writes, with warnings as errors.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

import matplotlib
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from softcbf_mj.outputs.palette import RUN_CYCLE, TUNING_COLORS
from softcbf_mj.outputs.runio import atomic_path

COLUMN_WIDTH_IN, TEXT_WIDTH_IN = 3.5, 7.16  # IEEE two-column: one column, the full text width
FIGURE_FORMATS = ("png", "svg", "pdf")
STYLE = {"font.size": 8, "axes.titlesize": 8, "axes.labelsize": 8, "xtick.labelsize": 7, "ytick.labelsize": 7,
         "legend.fontsize": 7, "legend.title_fontsize": 7, "lines.linewidth": 1.0,
         "figure.constrained_layout.h_pad": 0.03, "figure.constrained_layout.w_pad": 0.03}
GRID_ALPHA = 0.3


def distinct_colors(labels: Iterable[str]) -> list[str]:
    """A colour per label (module docstring): TUNING_COLORS for a paper tuning, else the run cycle's next free one."""
    labels = list(labels)
    taken = {TUNING_COLORS[label] for label in labels if label in TUNING_COLORS}
    free = [c for c in RUN_CYCLE if c not in taken] or list(RUN_CYCLE)
    out, k = [], 0
    for label in labels:
        if label in TUNING_COLORS:
            out.append(TUNING_COLORS[label])
        else:
            out.append(free[k % len(free)])
            k += 1
    return out


@contextmanager
def styled() -> Iterator[None]:
    """The rc parameters of `STYLE` inside the block (drawing and saving must both happen inside it)."""
    with matplotlib.rc_context(STYLE):
        yield


def new_figure(size_in: tuple[float, float], dpi: float) -> Figure:
    """A figure of `size_in` (inches) at `dpi` on its own Agg canvas, in the constrained layout."""
    fig = Figure(figsize=size_in, dpi=dpi, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def legend_outside(fig: Figure, axes: Iterable, loc: str = "outside right upper", ncols: int = 1,
                   title: str | None = None) -> None:
    """One legend for the figure outside the axes (`loc`: matplotlib's "outside …"), each label once, in at most
    `ncols` columns: fewer where that many would be wider than the figure (long labels), one at the least."""
    entries: dict[str, object] = {}
    for ax in axes:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            entries.setdefault(label, handle)
    for columns in range(ncols, 0, -1):
        legend = fig.legend(list(entries.values()), list(entries), loc=loc, ncols=columns, title=title)
        if columns == 1 or legend.get_window_extent(fig.canvas.get_renderer()).width <= fig.bbox.width:
            return
        legend.remove()


def save_figure(fig: Figure, path: Path, figure_format: str, dpi: float) -> None:
    """Write `fig` to `path` atomically (temp file + rename) as `figure_format` (FIGURE_FORMATS)
    at `dpi`, without a creation date in svg/pdf (a rebuild gives the same bytes)."""
    if figure_format not in FIGURE_FORMATS:
        raise ValueError(f"figure_format must be one of {', '.join(FIGURE_FORMATS)}, got {figure_format!r}")
    metadata = {"svg": {"Date": None}, "pdf": {"CreationDate": None}}.get(figure_format)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=figure_format, metadata=metadata)
