"""Reports (softcbf_mj.outputs.report): plots of the expected size that are not blank, the Markdown
table, and the drawing helpers the recording shares (boundaries, arcs, predicted force)."""

import json
import math

import numpy as np
import pytest
from matplotlib.image import imread

from controllers.model.pcc import segment_ends
from controllers.model.safe_set import LinearStiffness
from softcbf_mj.outputs.report import (
    ARC_CHORDS,
    DPI,
    FIGURE_SIZES_IN,
    Scene,
    arm_polyline,
    boundary_segments,
    envelope,
    predicted_force,
    write_report,
    zoom_window,
)
from softcbf_mj.outputs.runio import RunFolderError, read_run_folder



def test_plots_have_the_stated_size_and_are_not_blank(run_dir):
    for name, (w_in, h_in) in FIGURE_SIZES_IN.items():
        image = imread(run_dir / "plots" / f"{name}.png")
        assert image.shape[:2] == (round(h_in * DPI), round(w_in * DPI)), name
        grey = image[..., :3].mean(axis=2)
        # drawn lines and text: at least 2 % of the pixels are clearly darker than the white background
        assert np.mean(grey < 0.8) > 0.02, name
        assert len(np.unique(grey)) > 20, name  # anti-aliased lines and text, not a few flat fills


def test_rebuilding_gives_the_same_files_without_touching_the_data(run_dir):
    summary = (run_dir / "summary.json").read_bytes()
    series = (run_dir / "timeseries" / "Low.npz").read_bytes()
    (run_dir / "report.md").unlink()
    for png in (run_dir / "plots").glob("*.png"):
        png.unlink()
    files = write_report(run_dir)
    assert set(files) == {*FIGURE_SIZES_IN, "report"} and all(p.is_file() for p in files.values())
    assert (run_dir / "summary.json").read_bytes() == summary
    assert (run_dir / "timeseries" / "Low.npz").read_bytes() == series
    assert not list(run_dir.rglob(".*tmp*"))


def test_markdown_table_holds_every_run_with_its_figures(run_dir):
    text = (run_dir / "report.md").read_text(encoding="utf-8")
    runs = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))["runs"]
    header = next(line for line in text.splitlines() if line.startswith("| tuning |"))
    assert "ρ_pred min" in header and "ρ_meas min" in header and "F peak [N]" in header
    for run in runs:
        row = next(line for line in text.splitlines() if line.startswith(f"| {run['tuning']} |"))
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert float(cells[2]) == pytest.approx(run["rho_min_meas"], abs=5e-5)
        assert float(cells[3]) == pytest.approx(run["force_max_N"], abs=5e-5)
    for name in FIGURE_SIZES_IN:
        assert f"(plots/{name}.png)" in text
    assert "| duration | `0.5` |" in text


def test_scene_is_read_back_as_written(run_dir):
    scene = Scene.of(read_run_folder(run_dir))
    assert scene.n_max == pytest.approx(0.16 / 11.16, rel=1e-15)
    np.testing.assert_array_equal(scene.facets_H, [[0.36, 1.0]])
    np.testing.assert_array_equal(scene.lengths, [0.122, 0.122])
    # Lemma 1, paper row scaling: h' = h + n_max·√(m² + 1)
    np.testing.assert_allclose(scene.P_h, [0.15 + scene.n_max * math.hypot(0.36, 1.0)], rtol=1e-14)
    assert scene.stiffness == LinearStiffness(11.16)


def test_folder_without_scene_or_summary_is_refused_with_the_fix(tmp_path, run_dir):
    with pytest.raises(RunFolderError, match="no summary.json.*softcbf run"):
        write_report(tmp_path)
    summary = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    del summary["scene"]
    (tmp_path / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    with pytest.raises(RunFolderError, match="no 'scene'.*run the scenario again"):
        write_report(tmp_path)


def test_boundary_segments_clip_the_lines_to_the_box():
    box = (-1.0, 1.0, -1.0, 1.0)
    (edge,) = boundary_segments(np.array([[0.0, 1.0]]), np.array([0.1]), box)
    np.testing.assert_allclose(sorted(edge.tolist()), [[-1.0, 0.1], [1.0, 0.1]], atol=1e-15)
    # two facets meeting at (0.2, 0.3): y <= 0.3 and x <= 0.2, each edge ends at the corner and the box
    edges = boundary_segments(np.array([[0.0, 2.0], [1.0, 0.0]]), np.array([0.6, 0.2]), box)
    assert len(edges) == 2
    ends = {tuple(np.round(p, 12)) for e in edges for p in e}
    assert ends == {(0.2, 0.3), (-1.0, 0.3), (0.2, -1.0)}
    assert boundary_segments(np.array([[0.0, 1.0]]), np.array([-5.0]), box) == []  # the box is outside


def test_arm_polyline_is_the_pcc_arc():
    q, lengths, base = np.array([0.7, -0.4]), np.array([0.122, 0.1]), np.array([0.01, -0.02])
    points = arm_polyline(q, lengths, base)
    assert points.shape == (2 * ARC_CHORDS + 1, 2)
    np.testing.assert_allclose(points[::ARC_CHORDS], segment_ends(q, lengths) + base, atol=1e-15)
    # segment 1 is an arc of radius L/q about base + (0, L/q)
    centre = base + np.array([0.0, lengths[0] / q[0]])
    radii = np.hypot(*(points[: ARC_CHORDS + 1] - centre).T)
    np.testing.assert_allclose(radii, lengths[0] / q[0], rtol=1e-12)


def test_predicted_force_inverts_rho_through_psi(run_dir):
    scene = Scene.of(read_run_folder(run_dir))
    np.testing.assert_allclose(predicted_force(scene, np.array([1.0, 0.0, -1.0, 0.25])),
                               [0.0, 0.16, 0.32, 0.12], rtol=1e-13, atol=1e-16)


def test_every_figure_format_is_written_at_the_requested_dpi(run_dir):
    for figure_format, magic in (("svg", b"<?xml"), ("pdf", b"%PDF")):
        files = write_report(run_dir, figure_format=figure_format)
        for name in FIGURE_SIZES_IN:
            assert files[name].suffix == f".{figure_format}" and files[name].read_bytes().startswith(magic), name
        assert f"plots/rho.{figure_format}" in files["report"].read_text(encoding="utf-8")
    files = write_report(run_dir, dpi=150)
    for name, (w_in, h_in) in FIGURE_SIZES_IN.items():
        assert imread(files[name]).shape[:2] == (round(h_in * 150), round(w_in * 150)), name
    with pytest.raises(ValueError, match="figure_format must be one of png, svg, pdf, got 'jpg'"):
        write_report(run_dir, figure_format="jpg")
    with pytest.raises(ValueError, match="dpi must be > 0, got 0"):
        write_report(run_dir, dpi=0)
    write_report(run_dir)  # leave the default PNGs for the other tests


def test_envelope_keeps_the_extremes_of_a_switching_signal():
    t = np.arange(10_000) * 1e-3
    y = np.where(np.arange(10_000) % 2, 138.7, 80.0)  # alternates every step
    tm, lo, hi, mean = envelope(t, y, bins=100)
    assert len(tm) == 100 and np.all(np.diff(tm) > 0)
    np.testing.assert_array_equal(lo, 80.0)
    np.testing.assert_array_equal(hi, 138.7)
    np.testing.assert_allclose(mean, (80.0 + 138.7) / 2)
    short = envelope(t[:50], y[:50], bins=100)
    assert all(np.array_equal(a, b) for a, b in zip(short, (t[:50], y[:50], y[:50], y[:50])))


def test_zoom_window_centres_on_the_largest_correction():
    t = np.arange(1000) * 1e-3
    u_nom = np.zeros((1000, 2))
    u = u_nom.copy()
    u[700, 1] = -50.0
    run = {"t": t, "u": u, "u_nom": u_nom, "rho_meas": np.ones(1000)}
    assert zoom_window([run], 0.05) == pytest.approx((0.675, 0.725))
    u[700, 1] = 0.0
    u[995, 0] = 10.0  # near the end: the window is shifted inside the run
    assert zoom_window([run], 0.05) == pytest.approx((0.999 - 0.05, 0.999))
