"""The report of a run folder: paper-style PNG plots and a Markdown summary, rebuilt from
the folder alone (summary.json with its "scene", config.json, the time series).

`write_report(DIR)` writes, each file atomically (temp file + rename):

| file                  | size (px, at DPI = 100)  | what                                                        |
|-----------------------|--------------------------|-------------------------------------------------------------|
| plots/rho.png         | 900 × 400                | ρ_meas(t) (solid) and ρ_pred(t) (dashed) of every run, ρ = 0 |
|                       |                          | (the paper's Fig. 6 / Fig. 8 analogues)                     |
| plots/tip_path.png    | 700 × 600                | tip paths r(t), the facets (boundary of N), the boundary of |
|                       |                          | P, the plates at rest when they differ from the facets, the |
|                       |                          | arm at t = 0 and at each run's minimum ρ_meas               |
| plots/force.png       | 900 × 600                | per run: measured contact force, predicted force and F_max  |
| plots/pressure.png    | 900 × 600                | per segment: commanded u of every run and nominal u_nom     |
| report.md             |                          | the summary table, the plots, parameters, scene, versions   |

Signals (units as in the time series: s, m, N, hPa): ρ_meas, ρ_pred and u, u_nom (N,)
are read directly. Measured force F = max_i contact_force_i (the most loaded facet);
predicted force F̂ = ψ(n_max (1 − ρ_pred)) with the controller's ψ and n_max from the
scene, i.e. the force the controller's own state estimate and model imply on its most
penetrated facet (ρ_pred = (n_max − n̂)/n_max).

Plots use matplotlib's Agg canvas directly (`matplotlib.figure.Figure`, no pyplot, no
global backend change), fixed sizes (`FIGURE_SIZES_IN`, inches) at `DPI`.

The drawing helpers here (`run_color`, `scene_box`, `boundary_segments`, `arm_polyline`,
`predicted_force`, `plate_displacement`) are shared with softcbf_mj.recording, so the
report and the recording draw the same things.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from controllers.safe_set import StiffnessLaw
from softcbf_mj.metrics import format_table
from softcbf_mj.runio import RunFolder, RunFolderError, read_run_folder, stiffness_from_json

DPI = 100
FIGURE_SIZES_IN: dict[str, tuple[float, float]] = {
    "rho": (9.0, 4.0),
    "tip_path": (7.0, 6.0),
    "force": (9.0, 6.0),
    "pressure": (9.0, 6.0),
}
PLOTS_DIR = "plots"
REPORT_FILE = "report.md"
BOX_MARGIN_M = 0.03  # margin (m) around everything the arm reached, for drawing the lines of N and P
ARC_CHORDS = 8  # chords per PCC segment when the arm is drawn as arcs
# Colours by tuning name (the paper's: None black); other labels take TAB10 in order.
TUNING_COLORS = {"None": "#000000", "Low": "#1f77b4", "High": "#2ca02c", "HW-Low": "#ff7f0e", "HW-High": "#9467bd"}
TAB10 = ("#d62728", "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf")
FACET_COLOR, P_COLOR, PLATE_COLOR, NOMINAL_COLOR = "#000000", "#d62728", "#7f7f7f", "#7f7f7f"

SUMMARY_COLUMNS = (
    ("tuning", "tuning", ""),
    ("ρ_pred min", "rho_min_pred", ".4f"),
    ("ρ_meas min", "rho_min_meas", ".4f"),
    ("F max [N]", "force_max_N", ".4f"),
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


def run_color(label: str, index: int) -> str:
    """Hex colour of run `label` (the `index`-th run of its folder)."""
    return TUNING_COLORS.get(label, TAB10[index % len(TAB10)])


@dataclass(frozen=True)
class Scene:
    """summary.json's "scene" as arrays (format: softcbf_mj.runio)."""

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
    arc split this way is the same arc), and the PCC map of controllers.pcc applies to
    them: chord ℓ = (L_i/ARC_CHORDS)·sinc(q_i/(2·ARC_CHORDS)) along the heading at the
    sub-segment's middle (tested against `controllers.pcc.segment_ends`).
    """
    q = np.asarray(q, dtype=float)
    sub_q = np.repeat(q / ARC_CHORDS, ARC_CHORDS, axis=-1)
    sub_l = np.repeat(np.asarray(lengths, dtype=float) / ARC_CHORDS, ARC_CHORDS)
    heading = np.cumsum(sub_q, axis=-1) - sub_q / 2
    chord = sub_l * np.sinc(sub_q / (2 * np.pi))  # numpy's sinc(x) = sin(πx)/(πx)
    steps = np.stack((chord * np.cos(heading), chord * np.sin(heading)), axis=-1)
    start = np.zeros(q.shape[:-1] + (1, 2))
    return np.concatenate((start, np.cumsum(steps, axis=-2)), axis=-2) + np.asarray(base, dtype=float)[..., None, :]


def _figure(name: str) -> Figure:
    fig = Figure(figsize=FIGURE_SIZES_IN[name], dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> None:
    tmp = path.with_name(f".{path.stem}.tmp.png")
    fig.savefig(tmp, dpi=DPI, format="png")
    os.replace(tmp, path)


def _plot_rho(runs: Sequence[tuple[str, str, dict]], path: Path) -> None:
    fig = _figure("rho")
    ax = fig.add_subplot()
    for label, color, s in runs:
        ax.plot(s["t"], s["rho_meas"], color=color, lw=1.2, label=f"{label} measured")
        ax.plot(s["t"], s["rho_pred"], color=color, lw=1.0, ls="--", label=f"{label} predicted")
    ax.axhline(0.0, color="0.3", lw=0.8, ls=":")
    ax.set(xlabel="t [s]", ylabel="safety margin ρ", title="ρ(t): measured (solid) and predicted (dashed)")
    ax.legend(fontsize=8, ncol=len(runs), loc="lower left")
    ax.grid(alpha=0.3)
    _save(fig, path)


def _plot_tip_path(scene: Scene, runs: Sequence[tuple[str, str, dict]], path: Path) -> None:
    box = scene_box([s for _, _, s in runs])
    fig = _figure("tip_path")
    ax = fig.add_subplot()
    for k, edge in enumerate(boundary_segments(scene.facets_H, scene.facets_h, box)):
        ax.plot(*edge.T, color=FACET_COLOR, lw=2.0, label="facets (boundary of N)" if k == 0 else None)
    for k, edge in enumerate(boundary_segments(scene.P_H, scene.P_h, box)):
        ax.plot(*edge.T, color=P_COLOR, lw=1.5, ls="--", label="boundary of P" if k == 0 else None)
    if not (np.array_equal(scene.plates_H, scene.facets_H) and np.array_equal(scene.plates_h, scene.facets_h)):
        for k, edge in enumerate(boundary_segments(scene.plates_H, scene.plates_h, box)):
            ax.plot(*edge.T, color=PLATE_COLOR, lw=1.5, label="true plates at rest" if k == 0 else None)
    first = runs[0][2]
    ax.plot(*arm_polyline(first["q"][0], scene.lengths, first["segment_ends"][0, 0]).T, color="0.6", lw=3, label="arm at t = 0")
    for label, color, s in runs:
        ax.plot(s["tip"][:, 0], s["tip"][:, 1], color=color, lw=1.0, label=f"{label} tip")
        k = int(np.argmin(s["rho_meas"]))
        ax.plot(*arm_polyline(s["q"][k], scene.lengths, s["segment_ends"][k, 0]).T, color=color, lw=2, alpha=0.6,
                label=f"{label} arm at min ρ_meas (t = {s['t'][k]:.1f} s)")
    ax.set(xlim=box[:2], ylim=box[2:], xlabel="x [m]", ylabel="y [m]", title="tip path with N and P", aspect="equal")
    ax.legend(fontsize=7, loc="lower left")
    ax.grid(alpha=0.3)
    _save(fig, path)


def _plot_force(scene: Scene, runs: Sequence[tuple[str, str, dict]], path: Path) -> None:
    fig = _figure("force")
    axes = fig.subplots(len(runs), 1, sharex=True, squeeze=False)[:, 0]
    for ax, (label, color, s) in zip(axes, runs):
        ax.plot(s["t"], np.max(s["contact_force"], axis=1), color=color, lw=1.2, label="measured")
        ax.plot(s["t"], predicted_force(scene, s["rho_pred"]), color=color, lw=1.0, ls="--", label="predicted")
        ax.axhline(scene.f_max, color=P_COLOR, lw=1.0, ls=":", label="F_max")
        ax.set(ylabel="F [N]", title=label)
        ax.legend(fontsize=7, loc="upper right")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("contact force: measured vs predicted")
    _save(fig, path)


def _plot_pressure(runs: Sequence[tuple[str, str, dict]], path: Path) -> None:
    n = runs[0][2]["u"].shape[1]
    same_nominal = all(np.array_equal(s["u_nom"], runs[0][2]["u_nom"]) for _, _, s in runs)
    fig = _figure("pressure")
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    for j, ax in enumerate(axes):
        for label, color, s in runs:
            ax.plot(s["t"], s["u"][:, j], color=color, lw=1.0, label=f"{label} u")
            if not same_nominal:
                ax.plot(s["t"], s["u_nom"][:, j], color=color, lw=0.8, ls=":", label=f"{label} u_nom")
        if same_nominal:
            first = runs[0][2]
            ax.plot(first["t"], first["u_nom"][:, j], color=NOMINAL_COLOR, lw=1.0, ls="--", label="u_nom")
        ax.set(ylabel=f"u{j + 1} [hPa]")
        ax.legend(fontsize=7, ncol=len(runs) + 1, loc="upper right")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s]")
    fig.suptitle("commanded u vs nominal u_nom")
    _save(fig, path)


def _markdown(folder: RunFolder, scene: Scene, plots: Mapping[str, Path]) -> str:
    summary, config = folder.summary, folder.config or {}
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
        "(SPEC §8). t_viol: time with ρ_meas < 0.",
        "",
        "## Plots",
        "",
        *[f"![{name}]({path.relative_to(folder.path).as_posix()})" for name, path in plots.items()],
        "",
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


def write_report(run_dir: str | Path) -> dict[str, Path]:
    """Rebuild DIR/plots/*.png and DIR/report.md from the folder; return the files by name."""
    folder = read_run_folder(run_dir)
    if not folder.runs:
        raise RunFolderError(f"{folder.path} has no finished run to report")
    scene = Scene.of(folder)
    runs = [(label, run_color(label, i), folder.timeseries(label)[0]) for i, label in enumerate(folder.labels)]
    plots_dir = folder.path / PLOTS_DIR
    plots_dir.mkdir(exist_ok=True)
    plots = {name: plots_dir / f"{name}.png" for name in FIGURE_SIZES_IN}
    _plot_rho(runs, plots["rho"])
    _plot_tip_path(scene, runs, plots["tip_path"])
    _plot_force(scene, runs, plots["force"])
    _plot_pressure(runs, plots["pressure"])
    report = folder.path / REPORT_FILE
    tmp = report.with_name(f".{REPORT_FILE}.tmp")
    tmp.write_text(_markdown(folder, scene, plots), encoding="utf-8")
    os.replace(tmp, report)
    return {**plots, "report": report}
