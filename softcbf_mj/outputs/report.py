"""The report of a run folder: paper-style plots and a Markdown summary, rebuilt from the
folder alone (summary.json with its "scene", config.json, the time series).

`write_report(DIR, figure_format="png", dpi=DPI)` writes, each file atomically (temp file + rename):

| file                 | size (in; px at 200 dpi) | what                                                       |
|----------------------|--------------------------|------------------------------------------------------------|
| plots/overview.<fmt> | 7.16 × 7.5; 1432 × 1500  | the paper's Fig. 5 / Fig. 7 analogue on one time axis: tip |
|                      |                          | r_x(t), r_y(t) [m], measured force F(t) against F_max [N], |
|                      |                          | u_j(t) of every run against u_nom,j (dashed) [hPa]         |
| plots/rho.<fmt>      | 3.5 × 3.4; 700 × 680     | ρ_meas(t) (solid) and ρ_pred(t) (dashed) of every run,     |
|                      |                          | ρ = 0 (the paper's Fig. 6 / Fig. 8 analogues)              |
| plots/tip_path.<fmt> | 7.16 × 5; 1432 × 1000    | tip paths r(t), the facets (boundary of N), the boundary   |
|                      |                          | of P, the plates at rest when they differ from the facets, |
|                      |                          | the arm at t = 0 and at each run's minimum ρ_meas          |
| plots/force.<fmt>    | 3.5 × 4.2; 700 × 840     | per run: measured contact force, predicted force and F_max |
| plots/pressure.<fmt> | 7.16 × 4; 1432 × 800     | per segment: commanded u of every run and nominal u_nom;   |
|                      |                          | left the whole run, right a ZOOM_WINDOW_S zoom, each step  |
| report.md            |                          | the summary table, the plots, parameters, scene, versions  |

Sizes are a journal's (IEEE's two-column layout, softcbf_mj.outputs.plot_style): COLUMN_WIDTH_IN = 3.5 in for rho
and force, TEXT_WIDTH_IN = 7.16 in for the others, so that they are placed at 100 % and their
text (STYLE: 8 pt, ticks and legends 7 pt) reads as the paper's own.

`figure_format` is one of FIGURE_FORMATS (png, svg, pdf); `dpi` sets the raster
resolution (png pixels = inches × dpi; in svg/pdf it only scales embedded rasters). The
figures it rebuilds replace their copies in the other formats: after report.md is written,
plots/<name>.<other format> of each rebuilt name is removed (other files in plots/ are
left alone), so the folder never shows a stale overview.png beside a fresh overview.svg.

Signals (units as in the time series: s, m, N, hPa): ρ_meas, ρ_pred, the tip r and u, u_nom
(N,) are read directly. Measured force F = max_i contact_force_i (the most loaded facet);
predicted force F̂ = ψ(n_max (1 − ρ_pred)) with the controller's ψ and n_max from the
scene, i.e. the force the controller's own state estimate and model imply on its most
penetrated facet (ρ_pred = (n_max − n̂)/n_max).

Legibility: a time series longer than ENVELOPE_BINS samples is drawn as its min/max
envelope over ENVELOPE_BINS equal runs of samples (1.5 pixel columns each on a text-width
axis at 200 dpi; shaded) plus the mean of each run of samples (line), so a command that switches every 1 ms step
shows as a band around its mean instead of a solid block of vertical lines (`envelope`).
The zoom of plots/pressure is ZOOM_WINDOW_S wide, centred on the step with the largest
|u − u_nom| of any run (where the filter corrects most; without any correction, on the
first run's minimum ρ_meas), drawn step by step; its span is shaded in the left panels.
Legends sit outside the axes (right of the time series of full width, below the others) and each entry
once; a run's label in them is `softcbf_mj.outputs.palette.plot_labels` of the folder's labels (at most
LABEL_LIMIT characters, a longer one shortened with "…" and kept distinct: a filter's label with
every parameter, "c-erg(gain_lo_ratio=0.9,…)", never runs over the axes); report.md lists each
shortened label beside the full one. Colours: softcbf_mj.outputs.palette (Okabe–Ito), shared with the recording.

Plots follow softcbf_mj.outputs.plot_style (the project's one figure style: matplotlib's Agg canvas, no pyplot, the
STYLE rc parameters, the constrained layout, legends outside the axes), at fixed sizes (`FIGURE_SIZES_IN`,
inches): tests/test_report_figures.py renders every plot kind with the longest labels the project writes
with warnings as errors. `plot_force` is public: `softcbf demo` draws its figure with it.

The drawing helpers here (`scene_box`, `boundary_segments`, `arm_polyline`,
`predicted_force`, `plate_displacement`) are shared with softcbf_mj.outputs.recording, so the
report and the recording draw the same things.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from controllers.model.safe_set import StiffnessLaw
from softcbf_mj.outputs.metrics import format_table
from softcbf_mj.outputs.palette import LIMIT_COLOR, NEUTRAL_COLOR, plot_labels, run_color
from softcbf_mj.outputs.plot_style import (COLUMN_WIDTH_IN, FIGURE_FORMATS, GRID_ALPHA, STYLE, TEXT_WIDTH_IN, legend_outside,
                                  new_figure, save_figure, styled)
from softcbf_mj.outputs.runio import RunFolder, RunFolderError, atomic_path, read_run_folder, stiffness_from_json

DPI = 200
FIGURE_SIZES_IN: dict[str, tuple[float, float]] = {
    "overview": (TEXT_WIDTH_IN, 7.5),
    "rho": (COLUMN_WIDTH_IN, 3.4),
    "tip_path": (TEXT_WIDTH_IN, 5.0),
    "force": (COLUMN_WIDTH_IN, 4.2),
    "pressure": (TEXT_WIDTH_IN, 4.0),
}
PLOTS_DIR = "plots"
REPORT_FILE = "report.md"
BOX_MARGIN_M = 0.03  # margin (m) around everything the arm reached, for drawing the lines of N and P
ARC_CHORDS = 8  # chords per PCC segment when the arm is drawn as arcs
ENVELOPE_BINS = 800  # runs of samples per time axis (a text-width axis, ≈ 6 in, is 1200 px at 200 dpi: 1.5 px a run)
ZOOM_WINDOW_S = 0.05  # width (s) of the pressure zoom: 50 control steps at 1 kHz, each step visible
TIP_PATH_POINTS = 4000  # at most this many points of each tip path are drawn (the path is smooth)
FACET_COLOR, P_COLOR, PLATE_COLOR, NOMINAL_COLOR = NEUTRAL_COLOR, LIMIT_COLOR, NEUTRAL_COLOR, NEUTRAL_COLOR

SUMMARY_COLUMNS = (
    ("tuning", "tuning", ""),
    ("ρ_pred min", "rho_min_pred", ".4f"),
    ("ρ_meas min", "rho_min_meas", ".4f"),
    ("F peak [N]", "force_max_N", ".4f"),
    ("t_viol [s]", "t_violation_s", ".3f"),
    ("infeasible", "infeasible_steps", "d"),
    ("recovery", "recovery_steps", "d"),
    ("\\|u\\| peak [hPa]", "u_peak_abs_hPa", ".1f"),
    ("chatter [1/s]", "chatter_per_s", ".1f"),
    ("on/off [1/s]", "switches_per_s", ".1f"),
    ("u HF [%]", "u_hf_fraction", ".1f", 100.0),
    ("\\|u − u_nom\\| RMS [hPa]", "u_dev_rms_hPa", ".1f"),
    ("F err RMS [mN]", "force_err_rms_N", ".2f", 1e3),
    ("bias mean [mm]", "penetration_bias_mean_m", ".3f", 1e3),
    ("filter median [µs]", "filter_us_median", ".1f"),
    ("filter p99 [µs]", "filter_us_p99", ".1f"),
    ("sim [s]", "sim_s", ".1f"),
    ("wall [s]", "wall_s", ".1f"),
    ("RTF", "realtime_factor", ".2f"),
)


@dataclass(frozen=True)
class Scene:
    """summary.json's "scene" as arrays (format: softcbf_mj.outputs.runio)."""

    lengths: np.ndarray
    facets_H: np.ndarray
    facets_h: np.ndarray
    plates_H: np.ndarray
    plates_h: np.ndarray
    P_H: np.ndarray
    P_h: np.ndarray
    n_max: float
    f_max: float
    stiffness: StiffnessLaw
    plate_stiffness: float

    @classmethod
    def of(cls, folder: RunFolder) -> "Scene":
        data = folder.scene
        if data is None:
            raise RunFolderError(f"{folder.path / 'summary.json'} has no 'scene' (folders written before scenarios "
                                 "recorded it lack it): run the scenario again to get its report and recording")
        return cls.from_record(data)

    @classmethod
    def from_record(cls, data: Mapping[str, Any]) -> "Scene":
        """The scene of summary.json's "scene" record (`scenarios.common.scene_record`)."""
        arr = np.asarray
        return cls(arr(data["segment_lengths_m"], float), arr(data["facets"]["H"], float), arr(data["facets"]["h"], float),
                   arr(data["plates"]["H"], float), arr(data["plates"]["h"], float),
                   arr(data["force_safe_set"]["H_prime"], float), arr(data["force_safe_set"]["h_prime"], float),
                   float(data["n_max_m"]), float(data["f_max_N"]), stiffness_from_json(data["stiffness"]),
                   float(data["plate_stiffness_N_per_m"]))


def predicted_force(scene: Scene, rho_pred: np.ndarray) -> np.ndarray:
    """F̂ = ψ(n_max (1 − ρ_pred)) (N), shape of rho_pred."""
    return scene.stiffness.force(scene.n_max * (1.0 - np.asarray(rho_pred, dtype=float)))


def plate_displacement(scene: Scene, series: Mapping[str, np.ndarray]) -> np.ndarray:
    """Each plate's displacement along its outward normal (m), (T, P): the logged
    `plate_displacement_m` (MuJoCo) or, without it, contact_force / plate stiffness (the
    PCC plant's plate follows ψ of the true state)."""
    if "plate_displacement_m" in series:
        return np.asarray(series["plate_displacement_m"], dtype=float)
    return np.asarray(series["contact_force"], dtype=float) / scene.plate_stiffness


def scene_box(all_series: Sequence[Mapping[str, np.ndarray]]) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) (m): every segment end of every run, plus BOX_MARGIN_M."""
    points = np.concatenate([np.asarray(s["segment_ends"]).reshape(-1, 2) for s in all_series])
    lo, hi = points.min(axis=0) - BOX_MARGIN_M, points.max(axis=0) + BOX_MARGIN_M
    return float(lo[0]), float(hi[0]), float(lo[1]), float(hi[1])


def _clip(poly: np.ndarray, a: np.ndarray, b: float) -> np.ndarray:
    """Sutherland–Hodgman: the convex polygon `poly` (V, 2) ∩ {r | a·r ≤ b}."""
    out = []
    for p, q in zip(poly, np.roll(poly, -1, axis=0)):
        fp, fq = float(a @ p - b), float(a @ q - b)
        if fp <= 0:
            out.append(p)
        if fp * fq < 0:
            out.append(p + (q - p) * fp / (fp - fq))
    return np.array(out).reshape(-1, 2)


def boundary_segments(H: np.ndarray, h: np.ndarray, box: tuple[float, float, float, float]) -> list[np.ndarray]:
    """The boundary of {r | H r ≤ h} inside `box`: its edges that lie on a row's line, (2, 2) each (m)."""
    x0, x1, y0, y1 = box
    poly = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)
    for a, b in zip(H, h):
        poly = _clip(poly, a, b)
    edges = []
    for a, b in zip(H, h):
        tol = 1e-9 * float(np.hypot(*a))
        for p, q in zip(poly, np.roll(poly, -1, axis=0)):
            if abs(a @ p - b) <= tol and abs(a @ q - b) <= tol and np.any(p != q):
                edges.append(np.array([p, q]))
    return edges


def arm_polyline(q: np.ndarray, lengths: np.ndarray, base: np.ndarray) -> np.ndarray:
    """The arm as PCC arcs from base: q (..., N) rad, lengths (N,) m, base (..., 2) m →
    (..., N·ARC_CHORDS + 1, 2) m, vectorised over the leading axes (frames).

    Each segment is split into ARC_CHORDS equal sub-segments of angle q_i/ARC_CHORDS (a PCC
    arc split this way is the same arc), and the PCC map of controllers.model.pcc applies to
    them: chord ℓ = (L_i/ARC_CHORDS)·sinc(q_i/(2·ARC_CHORDS)) along the heading at the
    sub-segment's middle (tested against `controllers.model.pcc.segment_ends`).
    """
    q = np.asarray(q, dtype=float)
    sub_q = np.repeat(q / ARC_CHORDS, ARC_CHORDS, axis=-1)
    sub_l = np.repeat(np.asarray(lengths, dtype=float) / ARC_CHORDS, ARC_CHORDS)
    heading = np.cumsum(sub_q, axis=-1) - sub_q / 2
    chord = sub_l * np.sinc(sub_q / (2 * np.pi))  # numpy's sinc(x) = sin(πx)/(πx)
    steps = np.stack((chord * np.cos(heading), chord * np.sin(heading)), axis=-1)
    start = np.zeros(q.shape[:-1] + (1, 2))
    return np.concatenate((start, np.cumsum(steps, axis=-2)), axis=-2) + np.asarray(base, dtype=float)[..., None, :]


def envelope(t: np.ndarray, y: np.ndarray, bins: int = ENVELOPE_BINS) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(t_mid, y_min, y_max, y_mean), (B,) each: y (T,) split into B = min(bins, T) runs of
    consecutive samples of (almost) equal length; t_mid is the time of each run's middle
    sample. With T ≤ bins every sample is its own run (t, y, y, y)."""
    if bins < 1:
        raise ValueError(f"bins must be >= 1, got {bins}")
    t, y = np.asarray(t, dtype=float), np.asarray(y, dtype=float)
    if len(y) <= bins:
        return t, y, y, y
    edges = np.linspace(0, len(y), bins + 1).astype(int)
    starts, counts = edges[:-1], np.diff(edges)
    return (t[starts + (counts - 1) // 2], np.minimum.reduceat(y, starts), np.maximum.reduceat(y, starts),
            np.add.reduceat(y, starts) / counts)


def _draw(ax, t: np.ndarray, y: np.ndarray, color: str, label: str | None, **line) -> None:
    """y(t) as its envelope plus mean (long series) or step by step (short ones)."""
    tm, lo, hi, mean = envelope(t, y)
    if len(tm) < len(t):
        ax.fill_between(tm, lo, hi, color=color, alpha=0.3, lw=0)
        ax.plot(tm, mean, color=color, label=label, **line)
    else:
        ax.plot(t, y, color=color, label=label, drawstyle="steps-post", **line)


def _figure(name: str, dpi: float) -> Figure:
    return new_figure(FIGURE_SIZES_IN[name], dpi)


def _legend_below(fig: Figure, axes) -> None:
    """The legend of a one-column figure: below the axes, two columns."""
    legend_outside(fig, axes, loc="outside lower center", ncols=2)


def _plot_overview(scene: Scene, runs: Sequence[tuple[str, str, dict]], path: Path, figure_format: str, dpi: float) -> None:
    n = runs[0][2]["u"].shape[1]
    fig = _figure("overview", dpi)
    axes = fig.subplots(3 + n, 1, sharex=True)
    for label, color, s in runs:
        _draw(axes[0], s["t"], s["tip"][:, 0], color, label, lw=1.2)
        _draw(axes[1], s["t"], s["tip"][:, 1], color, label, lw=1.2)
        _draw(axes[2], s["t"], np.max(s["contact_force"], axis=1), color, label, lw=1.2)
        for j in range(n):
            _draw(axes[3 + j], s["t"], s["u"][:, j], color, label, lw=1.0)
    axes[2].axhline(scene.f_max, color=LIMIT_COLOR, lw=1.2, ls="--", label=f"F_max = {scene.f_max:g} N")
    same_nominal = all(np.array_equal(s["u_nom"], runs[0][2]["u_nom"]) for _, _, s in runs)
    for j in range(n):
        for label, color, s in runs[:1] if same_nominal else runs:
            _draw(axes[3 + j], s["t"], s["u_nom"][:, j], NOMINAL_COLOR if same_nominal else color,
                  "u_nom" if same_nominal else f"{label} u_nom", lw=1.0, ls="--")
    for ax, ylabel in zip(axes, ["r_x [m]", "r_y [m]", "F [N]", *[f"u{j + 1} [hPa]" for j in range(n)]]):
        ax.set_ylabel(ylabel)
        ax.grid(alpha=GRID_ALPHA)
    axes[-1].set_xlabel("t [s]")
    axes[0].set_title("tip, measured force, command; shaded: the samples' min–max band")
    legend_outside(fig, axes)
    save_figure(fig, path, figure_format, dpi)


def _plot_rho(runs: Sequence[tuple[str, str, dict]], path: Path, figure_format: str, dpi: float) -> None:
    fig = _figure("rho", dpi)
    ax = fig.add_subplot()
    for label, color, s in runs:
        _draw(ax, s["t"], s["rho_meas"], color, f"{label} measured", lw=1.2)
        _draw(ax, s["t"], s["rho_pred"], color, f"{label} predicted", lw=1.0, ls="--")
    ax.axhline(0.0, color=LIMIT_COLOR, lw=1.0, ls="--", label="ρ = 0 (F = F_max)")
    ax.set(xlabel="t [s]", ylabel="safety margin ρ [-]", title="ρ: measured (solid), predicted (dashed)")
    ax.grid(alpha=GRID_ALPHA)
    _legend_below(fig, [ax])
    save_figure(fig, path, figure_format, dpi)


def _plot_tip_path(scene: Scene, runs: Sequence[tuple[str, str, dict]], path: Path, figure_format: str, dpi: float) -> None:
    box = scene_box([s for _, _, s in runs])
    fig = _figure("tip_path", dpi)
    ax = fig.add_subplot()
    for k, edge in enumerate(boundary_segments(scene.facets_H, scene.facets_h, box)):
        ax.plot(*edge.T, color=FACET_COLOR, lw=2.0, label="facets (boundary of N)" if k == 0 else None)
    for k, edge in enumerate(boundary_segments(scene.P_H, scene.P_h, box)):
        ax.plot(*edge.T, color=P_COLOR, lw=1.5, ls="--", label="boundary of P" if k == 0 else None)
    if not (np.array_equal(scene.plates_H, scene.facets_H) and np.array_equal(scene.plates_h, scene.facets_h)):
        for k, edge in enumerate(boundary_segments(scene.plates_H, scene.plates_h, box)):
            ax.plot(*edge.T, color=PLATE_COLOR, lw=1.5, ls=":", label="true plates at rest" if k == 0 else None)
    first = runs[0][2]
    ax.plot(*arm_polyline(first["q"][0], scene.lengths, first["segment_ends"][0, 0]).T, color=NEUTRAL_COLOR, lw=3,
            alpha=0.6, label="arm at t = 0")
    for label, color, s in runs:
        stride = max(1, -(-len(s["tip"]) // TIP_PATH_POINTS))
        ax.plot(s["tip"][::stride, 0], s["tip"][::stride, 1], color=color, lw=1.0, label=f"{label} tip")
        k = int(np.argmin(s["rho_meas"]))
        ax.plot(*arm_polyline(s["q"][k], scene.lengths, s["segment_ends"][k, 0]).T, color=color, lw=2, alpha=0.6,
                label=f"{label} arm at min ρ_meas (t = {s['t'][k]:.1f} s)")
    ax.set(xlim=box[:2], ylim=box[2:], xlabel="x [m]", ylabel="y [m]", title="tip path with N and P", aspect="equal")
    ax.grid(alpha=GRID_ALPHA)
    legend_outside(fig, [ax], loc="outside lower center", ncols=2)
    save_figure(fig, path, figure_format, dpi)


def plot_force(scene: Scene, runs: Sequence[tuple[str, str, Mapping[str, np.ndarray]]], path: Path,
               figure_format: str = "png", dpi: float = DPI) -> None:
    """plots/force: one panel per run (label, colour, time series) with its measured contact force (solid), the
    force its controller predicts (dashed) and F_max, sharing the time axis; written to `path` (`save_figure`)."""
    with styled():
        fig = _figure("force", dpi)
        axes = fig.subplots(len(runs), 1, sharex=True, sharey=True, squeeze=False)[:, 0]
        for ax, (label, color, s) in zip(axes, runs):
            _draw(ax, s["t"], np.max(s["contact_force"], axis=1), color, "measured", lw=1.2)
            _draw(ax, s["t"], predicted_force(scene, s["rho_pred"]), NEUTRAL_COLOR, "predicted", lw=1.0, ls="--")
            ax.axhline(scene.f_max, color=LIMIT_COLOR, lw=1.0, ls=":", label=f"F_max = {scene.f_max:g} N")
            ax.set(ylabel="F [N]", title=label)
            ax.grid(alpha=GRID_ALPHA)
        axes[-1].set_xlabel("t [s]")
        fig.suptitle("contact force, most loaded facet", fontsize=STYLE["axes.titlesize"])
        _legend_below(fig, axes)
        save_figure(fig, path, figure_format, dpi)


def zoom_window(runs: Sequence[Mapping[str, np.ndarray]], width_s: float = ZOOM_WINDOW_S) -> tuple[float, float]:
    """(t0, t1) (s): `width_s` wide, centred on the step with the largest |u − u_nom| of any run
    (the first run's minimum ρ_meas when no run corrects), shifted to lie inside the runs' span."""
    if not width_s > 0:
        raise ValueError(f"width_s must be > 0 s, got {width_s}")
    peaks = [float(np.max(np.abs(s["u"] - s["u_nom"]), initial=0.0)) for s in runs]
    worst = runs[int(np.argmax(peaks))]
    if max(peaks) > 0:
        centre = float(worst["t"][np.argmax(np.max(np.abs(worst["u"] - worst["u_nom"]), axis=1))])
    else:
        centre = float(runs[0]["t"][np.argmin(runs[0]["rho_meas"])])
    start = min(float(s["t"][0]) for s in runs)
    end = max(float(s["t"][-1]) for s in runs)
    t0 = min(max(centre - width_s / 2, start), max(end - width_s, start))
    return t0, t0 + width_s


def _plot_pressure(runs: Sequence[tuple[str, str, dict]], path: Path, figure_format: str, dpi: float) -> None:
    n = runs[0][2]["u"].shape[1]
    same_nominal = all(np.array_equal(s["u_nom"], runs[0][2]["u_nom"]) for _, _, s in runs)
    t0, t1 = zoom_window([s for _, _, s in runs])
    fig = _figure("pressure", dpi)
    axes = fig.subplots(n, 2, sharex="col", squeeze=False, width_ratios=(3, 1))
    for j in range(n):
        full, zoom = axes[j]
        for label, color, s in runs:
            inside = (s["t"] >= t0) & (s["t"] <= t1)
            _draw(full, s["t"], s["u"][:, j], color, f"{label} u", lw=1.0)
            _draw(zoom, s["t"][inside], s["u"][inside, j], color, f"{label} u", lw=1.0)
            if not same_nominal:
                _draw(full, s["t"], s["u_nom"][:, j], color, f"{label} u_nom", lw=0.8, ls=":")
                _draw(zoom, s["t"][inside], s["u_nom"][inside, j], color, f"{label} u_nom", lw=0.8, ls=":")
        if same_nominal:
            first = runs[0][2]
            inside = (first["t"] >= t0) & (first["t"] <= t1)
            _draw(full, first["t"], first["u_nom"][:, j], NOMINAL_COLOR, "u_nom", lw=1.0, ls="--")
            _draw(zoom, first["t"][inside], first["u_nom"][inside, j], NOMINAL_COLOR, "u_nom", lw=1.0, ls="--")
        full.axvspan(t0, t1, color=NEUTRAL_COLOR, alpha=0.25, lw=0)
        full.set(ylabel=f"u{j + 1} [hPa]")
        zoom.set(ylabel=f"u{j + 1} [hPa]")
        for ax in (full, zoom):
            ax.grid(alpha=GRID_ALPHA)
    axes[0, 0].set_title("u vs u_nom; shaded: the samples' min–max band; grey: zoom")
    axes[0, 1].set_title(f"zoom {t0:.3f}–{t1:.3f} s")
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("t [s]")
    legend_outside(fig, axes.ravel())
    save_figure(fig, path, figure_format, dpi)


def _markdown(folder: RunFolder, scene: Scene, plots: Mapping[str, Path], shown: Mapping[str, str]) -> str:
    summary, config = folder.summary, folder.config or {}
    key = [f"- {short}: `{full}`" for full, short in shown.items() if short != full]
    versions = summary.get("versions", {})
    columns = [c for c in SUMMARY_COLUMNS if any(run.get(c[1]) is not None for run in folder.runs)]
    lines = [
        f"# {summary['scenario']}: {folder.path.name}",
        "",
        f"Started {config.get('started', '?')}; command `{config.get('command', '?')}`; "
        f"softcbf_mj {versions.get('softcbf_mj')}, MuJoCo {versions.get('mujoco')}. "
        f"Finished runs: {len(folder.runs)} ({', '.join(folder.labels)}).",
        "",
        "## Results",
        "",
        format_table(folder.runs, columns, markdown=True),
        "",
        "ρ_pred: from the controller's state estimate and model; ρ_meas: from the measured contact force "
        "(docs/run-outputs.md). t_viol: time with ρ_meas < 0.",
        "",
        "## Plots",
        "",
        *[f"![{name}]({path.relative_to(folder.path).as_posix()})" for name, path in plots.items()],
        "",
        *(["Shortened run labels in the plots:", "", *key, ""] if key else []),
        "## Scene",
        "",
        f"- segment lengths: {', '.join(f'{v:.4g}' for v in scene.lengths)} m",
        f"- F_max {scene.f_max:g} N, n_max {scene.n_max * 1e3:.3f} mm, controller's ψ {summary['scene']['stiffness']}, "
        f"plate stiffness {scene.plate_stiffness:g} N/m",
        f"- facets H r ≤ h: H = {scene.facets_H.tolist()}, h = {scene.facets_h.tolist()} m",
        f"- P: H' = {np.round(scene.P_H, 6).tolist()}, h' = {np.round(scene.P_h, 6).tolist()} m",
        "",
        "## Parameters",
        "",
        "| parameter | value |",
        "|---|---|",
        *[f"| {k} | `{v}` |" for k, v in summary["params"].items()],
        "",
        "## Versions",
        "",
        *[f"- {k}: {v}" for k, v in versions.items()],
        "",
    ]
    return "\n".join(lines)


def write_report(run_dir: str | Path, figure_format: str = "png", dpi: float = DPI) -> dict[str, Path]:
    """Rebuild DIR/plots/*.<figure_format> (FIGURE_FORMATS; raster resolution `dpi`) and
    DIR/report.md from the folder; return the files by name."""
    if figure_format not in FIGURE_FORMATS:
        raise ValueError(f"figure_format must be one of {', '.join(FIGURE_FORMATS)}, got {figure_format!r}")
    if not dpi > 0:
        raise ValueError(f"dpi must be > 0, got {dpi}")
    folder = read_run_folder(run_dir)
    if not folder.runs:
        raise RunFolderError(f"{folder.path} has no finished run to report")
    scene = Scene.of(folder)
    shown = dict(zip(folder.labels, plot_labels(folder.labels)))
    runs = [(shown[label], run_color(label, i), folder.timeseries(label)[0]) for i, label in enumerate(folder.labels)]
    plots_dir = folder.path / PLOTS_DIR
    plots_dir.mkdir(exist_ok=True)
    plots = {name: plots_dir / f"{name}.{figure_format}" for name in FIGURE_SIZES_IN}
    with styled():
        _plot_overview(scene, runs, plots["overview"], figure_format, dpi)
        _plot_rho(runs, plots["rho"], figure_format, dpi)
        _plot_tip_path(scene, runs, plots["tip_path"], figure_format, dpi)
        plot_force(scene, runs, plots["force"], figure_format, dpi)
        _plot_pressure(runs, plots["pressure"], figure_format, dpi)
    report = folder.path / REPORT_FILE
    text = _markdown(folder, scene, plots, shown)
    with atomic_path(report) as tmp:
        tmp.write_text(text, encoding="utf-8")
    for name in plots:  # the rebuilt figures replace their copies in the other formats
        for other in FIGURE_FORMATS:
            if other != figure_format:
                (plots_dir / f"{name}.{other}").unlink(missing_ok=True)
    return {**plots, "report": report}
