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
"""

from __future__ import annotations

ORANGE, SKY_BLUE, BLUISH_GREEN, YELLOW = "#E69F00", "#56B4E9", "#009E73", "#F0E442"
BLUE, VERMILLION, REDDISH_PURPLE = "#0072B2", "#D55E00", "#CC79A7"
OKABE_ITO = (ORANGE, SKY_BLUE, BLUISH_GREEN, YELLOW, BLUE, VERMILLION, REDDISH_PURPLE)

TUNING_COLORS = {"None": ORANGE, "Low": SKY_BLUE, "High": BLUISH_GREEN, "HW-Low": BLUE, "HW-High": REDDISH_PURPLE}
RUN_CYCLE = (SKY_BLUE, BLUISH_GREEN, BLUE, REDDISH_PURPLE, ORANGE, YELLOW)
LIMIT_COLOR = VERMILLION
NEUTRAL_COLOR = "#999999"


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
