"""The one colour palette of reports and recordings: Okabe–Ito, safe for colour-blind readers
and legible on a white page (matplotlib) and on rerun's dark theme alike.

Okabe, M. and Ito, K., "Color Universal Design" (2002): eight colours that stay distinct
under protanopia, deuteranopia and tritanopia. Its black is left out (invisible on rerun's
dark background); neutral elements use a mid grey that reads on both backgrounds.

| role                                    | colour                         |
|-----------------------------------------|--------------------------------|
| run "None" / "Low" / "High"             | orange / sky blue / bluish green |
| run "HW-Low" / "HW-High"                | blue / reddish purple          |
| any other run label                     | RUN_CYCLE in order of the run's index |
| limits: boundary of P, F_max, ρ = 0     | LIMIT_COLOR (vermillion)       |
| the facets, the plates, u_nom           | NEUTRAL_COLOR (mid grey)       |

Colours are "#rrggbb" strings; `rgb` turns one into the [r, g, b] (0–255) rerun takes.

Labels. A run's label is its filter with every parameter (controllers.registry.label): the
recommended filter's is 137 characters, more than a figure's width. `short_label` keeps a label of
at most LABEL_LIMIT characters and cuts a longer one to LABEL_LIMIT − 1 characters and "…";
`plot_labels` does so for a folder's runs and keeps them distinct (a shortened label that two runs
share ends in " #k", the run's position, instead). The reports' legends and the progress lines use them.
"""

from __future__ import annotations

ORANGE, SKY_BLUE, BLUISH_GREEN, YELLOW = "#E69F00", "#56B4E9", "#009E73", "#F0E442"
BLUE, VERMILLION, REDDISH_PURPLE = "#0072B2", "#D55E00", "#CC79A7"
OKABE_ITO = (ORANGE, SKY_BLUE, BLUISH_GREEN, YELLOW, BLUE, VERMILLION, REDDISH_PURPLE)

TUNING_COLORS = {"None": ORANGE, "Low": SKY_BLUE, "High": BLUISH_GREEN, "HW-Low": BLUE, "HW-High": REDDISH_PURPLE}
RUN_CYCLE = (SKY_BLUE, BLUISH_GREEN, BLUE, REDDISH_PURPLE, ORANGE, YELLOW)
LIMIT_COLOR = VERMILLION
NEUTRAL_COLOR = "#999999"
LABEL_LIMIT = 24  # characters: a legend entry of 7 pt text about 1.3 in wide


def short_label(label: str, limit: int = LABEL_LIMIT) -> str:
    """`label` if it has at most `limit` characters, else its first `limit` − 1 and "…" (module docstring)."""
    if limit < 2:
        raise ValueError(f"limit must be >= 2 characters, got {limit}")
    return label if len(label) <= limit else label[: limit - 1] + "…"


def plot_labels(labels: list[str] | tuple[str, ...], limit: int = LABEL_LIMIT) -> list[str]:
    """`short_label` of each of `labels`, distinct: a shortened label that several runs share is cut further and
    ends in " #k" (k = 1 + the run's index) (module docstring)."""
    short = [short_label(label, limit) for label in labels]
    return [s if short.count(s) == 1 or s == label else short_label(label, limit - len(f" #{k + 1}")) + f" #{k + 1}"
            for k, (label, s) in enumerate(zip(labels, short))]


def run_color(label: str, index: int) -> str:
    """Colour of run `label`, the `index`-th run of its folder (index ≥ 0)."""
    if index < 0:
        raise ValueError(f"index must be >= 0, got {index}")
    return TUNING_COLORS.get(label, RUN_CYCLE[index % len(RUN_CYCLE)])


def rgb(color: str, lighten: float = 0.0) -> list[int]:
    """"#rrggbb" → [r, g, b] in 0–255, mixed with white by `lighten` ∈ [0, 1] (0: unchanged)."""
    if not 0.0 <= lighten <= 1.0:
        raise ValueError(f"lighten must lie in [0, 1], got {lighten}")
    if len(color) != 7 or color[0] != "#":
        raise ValueError(f"color must be '#rrggbb', got {color!r}")
    channels = [int(color[i : i + 2], 16) for i in (1, 3, 5)]
    return [int(round(c + (255 - c) * lighten)) for c in channels]
