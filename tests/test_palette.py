"""The shared palette (softcbf_mj.outputs.palette): used by the report's plots and the recording alike."""

import matplotlib.colors
import pytest

from softcbf_mj.outputs import palette, recording, report
from softcbf_mj.outputs.palette import LIMIT_COLOR, NEUTRAL_COLOR, OKABE_ITO, rgb, run_color


def test_runs_take_okabe_ito_colours_and_never_black():
    labels = ["None", "Low", "High", "HW-Low", "HW-High", "custom-a", "custom-b"]
    colors = [run_color(label, i) for i, label in enumerate(labels)]
    assert all(c in OKABE_ITO for c in colors)
    assert len(set(colors[:5])) == 5  # the paper's tunings are told apart
    for color in (*colors, LIMIT_COLOR, NEUTRAL_COLOR):
        # legible on rerun's dark background (~#121212): no colour darker than 30 % luminance
        r, g, b = matplotlib.colors.to_rgb(color)
        assert 0.2126 * r + 0.7152 * g + 0.0722 * b > 0.3, color


def test_plots_and_recording_share_the_palette():
    assert report.run_color is palette.run_color and recording.run_color is palette.run_color
    assert report.P_COLOR == recording.P_COLOR == LIMIT_COLOR
    assert report.FACET_COLOR == recording.FACET_COLOR == NEUTRAL_COLOR
    assert report.NOMINAL_COLOR == recording.NOMINAL_COLOR == NEUTRAL_COLOR


def test_rgb_converts_and_lightens():
    assert rgb("#D55E00") == [213, 94, 0]
    assert rgb("#000000", 1.0) == [255, 255, 255]
    assert rgb("#E69F00", 0.5) == [round(230 + 25 * 0.5), round(159 + 96 * 0.5), round(0 + 255 * 0.5)]
    with pytest.raises(ValueError, match="lighten must lie in \\[0, 1\\], got 2"):
        rgb("#000000", 2)
    with pytest.raises(ValueError, match="color must be '#rrggbb', got 'red'"):
        rgb("red")
