"""The rerun recording of a run folder (rerun-sdk 0.41), rebuilt from the folder alone.

`write_recording(DIR)` reads summary.json (its "scene"), config.json and the time series
of every finished run, logs them into one recording (application id `APP_ID`) with one
timeline, `sim_time` (a duration, s), and writes DIR/recording.rrd atomically (temp file
+ rename) together with a default blueprint. Open it with `viewer_command(path)`'s command
(`.venv/bin/rerun DIR/recording.rrd`, or `python -m rerun DIR/recording.rrd`).

Entities (`<run>` is the tuning label; "static" = no time, logged once):

| entity                          | archetype          | rate         | what                                      |
|---------------------------------|--------------------|--------------|-------------------------------------------|
| /scene                          | Transform3D        | static       | y mirrored, so +y points up in 2D views   |
| /scene/facets                   | LineStrips2D       | static       | the facets (boundary of N), m             |
| /scene/P                        | LineStrips2D       | static       | the boundary of the force-safe set P, m   |
| /legend                         | TextDocument       | static       | the colour legend (`legend_markdown`)     |
| /runs/<run>/scene               | Transform3D        | static       | y mirrored, as /scene                     |
| /runs/<run>/scene/arm           | LineStrips2D       | GEOMETRY_HZ  | the arm as PCC arcs of the true q, m      |
| /runs/<run>/scene/tags          | Points2D           | GEOMETRY_HZ  | base and segment ends ("tag 0".."tag N")  |
| /runs/<run>/scene/plate         | LineStrips2D       | GEOMETRY_HZ  | each plate moved by its displacement      |
| /runs/<run>/scene/tip           | Points2D           | GEOMETRY_HZ  | the tip r                                 |
| /runs/<run>/scene/tip_trace     | LineStrips2D       | static       | the tip's whole path (at GEOMETRY_HZ)     |
| /runs/<run>/u, /runs/<run>/u_nom| Scalars (N)        | every step   | commanded and nominal pressure, hPa       |
| /runs/<run>/rho                 | Scalars (2)        | every step   | [predicted, measured] ρ                   |
| /runs/<run>/force               | Scalars (3)        | every step   | [measured, predicted, F_max], N           |
| /runs/<run>/flags               | Scalars (3)        | every step   | [active, infeasible, recovery], 0/1 (*)   |
| /runs/<run>/plate_displacement  | Scalars (P)        | every step   | plate displacement along its normal, mm   |
| /runs/<run>/camera/image        | EncodedImage       | each frame   | camera images (runs with frames only)     |
| /runs/<run>/camera/image/detections | LineStrips2D   | each frame   | detected tag outlines, labelled "tag id"  |

(*) active and recovery are the paper filter's diagnostics; 0 for a filter without them.

Time series go in with the columnar API (`rr.send_columns`), one call per entity; the
geometry is decimated to GEOMETRY_HZ (every round(1/(GEOMETRY_HZ·Δt))-th control step;
the scalars keep every step). The arm is drawn as PCC arcs of the logged true q_i from
the logged base (report.arm_polyline); for the MuJoCo rod, whose loaded shape is not
exactly an arc, the tags sit at the rod's true segment ends. Predicted force and plate
displacement as in softcbf_mj.report. Camera frames: DIR/frames/<run>/frames.json
(format: softcbf_mj.runio); images are logged as encoded files, unchanged.

Colours (softcbf_mj.palette, shared with the report: Okabe–Ito, no black, legible on
rerun's dark theme): each run its colour, its second series (ρ_pred, F_pred) lighter,
u_nom, facets and plates grey, F_max and P vermillion. Scalar series are styled by
SERIES_STYLES: zoomed out, u and the flags keep each pixel column's min and max, so a
command or flag switching every step shows as a band instead of being averaged away.

Default blueprint: the 2D scene (and one view per camera) and the colour legend on the
left; on the right the time series ρ, force vs F_max, u vs u_nom and the flags, each with
every run. rerun draws plot legends inside the plot, so they are hidden (the legend view
and hovering name every line).

`live_viewer()` (the CLI's `--spawn`): while it is active and a display is present,
each `write_recording` also streams the runs it has not streamed yet to a spawned
viewer, so the viewer shows every tuning as soon as it finishes.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import uuid
from collections.abc import Iterator, Mapping, Sequence
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from softcbf_mj.palette import LIMIT_COLOR, rgb, run_color
from softcbf_mj.report import (
    FACET_COLOR,
    NOMINAL_COLOR,
    P_COLOR,
    PLATE_COLOR,
    Scene,
    arm_polyline,
    boundary_segments,
    plate_displacement,
    predicted_force,
    scene_box,
)
from softcbf_mj.runio import RunFolder, RunFolderError, atomic_path, frames_folder, read_run_folder

APP_ID = "softcbf_mj"
RECORDING_FILE = "recording.rrd"
TIMELINE = "sim_time"
GEOMETRY_HZ = 50.0
MEDIA_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg"}
MIRROR_Y = rr.Transform3D(scale=[1.0, -1.0, 1.0])
PLATE_HALF_LENGTH_M = 0.05  # half-length (m) of the plate surfaces drawn
LEGEND_ENTITY = "/legend"
# How rerun draws a scalar series when one pixel column holds many steps (zoomed out):
# "switching" (u) and "flag" keep each column's min and max (a switching signal shows as a
# band, never as its average: a flag switching every step is not a flat 0.5); "flag" also
# holds each value until the next step; "smooth" signals keep the column's mid-range
# (min + max)/2, so a lone spike still moves the line.
SERIES_STYLES: dict[str, dict] = {
    "switching": {"aggregation_policy": rr.components.AggregationPolicy.MinMax},
    "flag": {"aggregation_policy": rr.components.AggregationPolicy.MinMax,
             "interpolation_mode": rr.components.InterpolationMode.StepAfter},
    "smooth": {"aggregation_policy": rr.components.AggregationPolicy.MinMaxAverage},
}


def run_path(label: str) -> str:
    """Entity path prefix of run `label`."""
    return f"/runs/{rr.escape_entity_path_part(label)}"


def _decimation(t: np.ndarray) -> int:
    if len(t) < 2:
        return 1
    return max(1, int(round(1.0 / (GEOMETRY_HZ * float(t[1] - t[0])))))


def _log_scene(rec: rr.RecordingStream, scene: Scene, box: tuple[float, float, float, float]) -> None:
    rec.log("/scene", MIRROR_Y, static=True)
    rec.log("/scene/facets", rr.LineStrips2D(boundary_segments(scene.facets_H, scene.facets_h, box),
                                             colors=rgb(FACET_COLOR), radii=rr.Radius.ui_points(2.0)), static=True)
    rec.log("/scene/P", rr.LineStrips2D(boundary_segments(scene.P_H, scene.P_h, box),
                                        colors=rgb(P_COLOR), radii=rr.Radius.ui_points(1.5)), static=True)


def _shades(color: str, count: int) -> list[list[int]]:
    """`count` shades of one palette colour, from the colour itself towards white (≤ 45 %)."""
    return [rgb(color, lighten) for lighten in np.linspace(0.0, 0.45, count)] if count > 1 else [rgb(color)]


def _log_run(rec: rr.RecordingStream, scene: Scene, label: str, color: str, s: Mapping[str, np.ndarray],
             frames_dir: Path, frames: Sequence[Mapping]) -> None:
    root = run_path(label)
    t = np.asarray(s["t"], dtype=float)
    time = [rr.TimeColumn(TIMELINE, duration=t)]
    n, p = s["u"].shape[1], s["contact_force"].shape[1]
    light = rgb(color, 0.45)
    # name: (series names, values (T, K), colours (K), style); SERIES_STYLES explains the styles
    scalars = {
        "u": ([f"{label} u{j + 1}" for j in range(n)], s["u"], _shades(color, n), "switching"),
        "u_nom": ([f"{label} u_nom{j + 1}" for j in range(n)], s["u_nom"], _shades(NOMINAL_COLOR, n), "smooth"),
        "rho": ([f"{label} ρ_pred", f"{label} ρ_meas"], np.column_stack((s["rho_pred"], s["rho_meas"])),
                [light, rgb(color)], "smooth"),
        "force": ([f"{label} F_meas", f"{label} F_pred", "F_max"],
                  np.column_stack((np.max(s["contact_force"], axis=1), predicted_force(scene, s["rho_pred"]),
                                   np.full(len(t), scene.f_max))), [rgb(color), light, rgb(LIMIT_COLOR)], "smooth"),
        "flags": ([f"{label} active", f"{label} infeasible", f"{label} recovery"],
                  np.column_stack((np.any(s["active"], axis=1) if "active" in s else np.zeros(len(t)), s["infeasible"],
                                   s.get("recovery", np.zeros(len(t))))).astype(float),
                  _shades(color, 3), "flag"),
        "plate_displacement": ([f"{label} plate {i + 1} [mm]" for i in range(p)], 1e3 * plate_displacement(scene, s),
                               _shades(color, p), "smooth"),
    }
    for name, (names, values, colors, style) in scalars.items():
        rec.log(f"{root}/{name}", rr.SeriesLines(names=names, colors=colors, **SERIES_STYLES[style]), static=True)
        rec.send_columns(f"{root}/{name}", indexes=time, columns=rr.Scalars.columns(scalars=values))

    k = np.arange(0, len(t), _decimation(t))
    geo_time = [rr.TimeColumn(TIMELINE, duration=t[k])]
    ends = np.asarray(s["segment_ends"], dtype=float)[k]
    q = np.asarray(s["q"], dtype=float)[k]
    run_rgb = rgb(color)
    rec.log(f"{root}/scene", MIRROR_Y, static=True)
    rec.log(f"{root}/scene/arm", rr.LineStrips2D.from_fields(colors=run_rgb, radii=rr.Radius.ui_points(3.0)), static=True)
    arms = arm_polyline(q, scene.lengths, ends[:, 0])
    rec.send_columns(f"{root}/scene/arm", indexes=geo_time, columns=rr.LineStrips2D.columns(strips=arms))
    n_tags = ends.shape[1]
    rec.log(f"{root}/scene/tags", rr.Points2D.from_fields(colors=run_rgb, radii=rr.Radius.ui_points(5.0),
                                                         labels=[f"tag {i}" for i in range(n_tags)]), static=True)
    rec.send_columns(f"{root}/scene/tags", indexes=geo_time,
                     columns=rr.Points2D.columns(positions=ends.reshape(-1, 2)).partition([n_tags] * len(k)))
    rec.log(f"{root}/scene/tip", rr.Points2D.from_fields(colors=run_rgb, radii=rr.Radius.ui_points(4.0)), static=True)
    rec.send_columns(f"{root}/scene/tip", indexes=geo_time, columns=rr.Points2D.columns(positions=ends[:, -1]))
    rec.log(f"{root}/scene/tip_trace", rr.LineStrips2D([ends[:, -1]], colors=rgb(color, 0.4),
                                                      radii=rr.Radius.ui_points(1.0)), static=True)
    plates = _plate_strips(scene, s, k)
    rec.log(f"{root}/scene/plate", rr.LineStrips2D.from_fields(colors=rgb(PLATE_COLOR), radii=rr.Radius.ui_points(3.0)),
            static=True)
    rec.send_columns(f"{root}/scene/plate", indexes=geo_time,
                     columns=rr.LineStrips2D.columns(strips=plates.reshape(-1, 2, 2)).partition([plates.shape[1]] * len(k)))
    if frames:
        _log_frames(rec, root, frames_dir, frames)


def _plate_strips(scene: Scene, s: Mapping[str, np.ndarray], k: np.ndarray) -> np.ndarray:
    """(K, P, 2, 2): each plate's surface, PLATE_HALF_LENGTH_M either side of the point of
    its rest line nearest to the tip's deepest approach, moved by its displacement (m)."""
    norms = np.hypot(scene.plates_H[:, 0], scene.plates_H[:, 1])
    normals, offsets = scene.plates_H / norms[:, None], scene.plates_h / norms
    tangents = np.column_stack((-normals[:, 1], normals[:, 0]))
    tip = np.asarray(s["tip"], dtype=float)
    deepest = tip[np.argmax(tip @ normals.T - offsets, axis=0)]  # (P, 2)
    centres = deepest - (np.einsum("pi,pi->p", deepest, normals) - offsets)[:, None] * normals
    rest = np.stack((centres - PLATE_HALF_LENGTH_M * tangents, centres + PLATE_HALF_LENGTH_M * tangents), axis=1)
    shift = plate_displacement(scene, s)[k][:, :, None] * normals[None]  # (K, P, 2)
    return rest[None] + shift[:, :, None, :]


def _log_frames(rec: rr.RecordingStream, root: str, frames_dir: Path, frames: Sequence[Mapping]) -> None:
    """Camera images (encoded files, unchanged) and their tag detections at the frames' times."""
    t = [rr.TimeColumn(TIMELINE, duration=[float(f["t"]) for f in frames])]
    blobs, media = [], []
    for f in frames:
        path = frames_dir / f["file"]
        if path.suffix.lower() not in MEDIA_TYPES:
            raise RunFolderError(f"camera frame {path}: unsupported image type; use one of {', '.join(MEDIA_TYPES)}")
        blobs.append(path.read_bytes())
        media.append(MEDIA_TYPES[path.suffix.lower()])
    rec.send_columns(f"{root}/camera/image", indexes=t, columns=rr.EncodedImage.columns(blob=blobs, media_type=media))
    detections = [f.get("detections", []) for f in frames]
    counts = [len(d) for d in detections]
    if sum(counts):
        strips = [np.vstack((c, c[:1])) for d in detections for c in (np.asarray(x["corners"], dtype=float) for x in d)]
        labels = [f"tag {x['id']}" for d in detections for x in d]
        rec.send_columns(f"{root}/camera/image/detections", indexes=t,
                         columns=rr.LineStrips2D.columns(strips=strips, labels=labels).partition(counts))


def legend_markdown(labels: Sequence[str]) -> str:
    """The recording's colour legend (Markdown): one line per run, plus the shared colours."""
    lines = ["**Colours** (Okabe–Ito; shades of a run's colour: its components in order)", ""]
    lines += [f"- `{run_color(label, i)}` {label}: u, ρ_meas, F_meas, arm; lighter: ρ_pred, F_pred"
              for i, label in enumerate(labels)]
    lines += [f"- `{NOMINAL_COLOR}` u_nom, the facets (boundary of N), the plates", f"- `{LIMIT_COLOR}` F_max, the boundary of P",
              "", "Zoomed out, u and the flags show each pixel column's min–max band (a switching command or flag is a "
              "filled band, not its average). Hover a line for its name."]
    return "\n".join(lines)


def _blueprint(labels: Sequence[str], cameras: Sequence[str], box: tuple[float, float, float, float]) -> rrb.Blueprint:
    roots = [run_path(label) for label in labels]
    scene = rrb.Spatial2DView(name="arm, plates, N and P", origin="/",
                              contents=["/scene/**", *[f"{r}/scene/**" for r in roots]],
                              visual_bounds=rrb.VisualBounds2D(x_range=box[:2], y_range=(-box[3], -box[2])))
    camera_views = [rrb.Spatial2DView(name=f"{label} camera", origin=f"{run_path(label)}/camera") for label in cameras]
    legend = rrb.TextDocumentView(name="colours", origin=LEGEND_ENTITY)

    def series(name: str, *entities: str) -> rrb.TimeSeriesView:
        # rerun draws legends inside the plot; hidden, so they cover no data (the "colours" view and hovering name the lines)
        return rrb.TimeSeriesView(name=name, origin="/runs", contents=[f"{r}/{e}" for r in roots for e in entities],
                                  plot_legend=rrb.PlotLegend(visible=False))

    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(scene, *camera_views, legend, row_shares=[4, *[3] * len(camera_views), 1]),
            rrb.Vertical(series("ρ: predicted (light) and measured", "rho"),
                         series("contact force: measured, predicted (light), F_max [N]", "force"),
                         series("u vs u_nom (grey) [hPa]", "u", "u_nom"),
                         series("active / infeasible / recovery (0/1)", "flags")),
            column_shares=[2, 3],
        ),
        collapse_panels=True,
    )


@dataclass
class _Live:
    """A viewer spawned by `live_viewer` and the runs already streamed to it."""

    stream: rr.RecordingStream
    sent: set[str] = field(default_factory=set)


_LIVE: ContextVar[_Live | None] = ContextVar("softcbf_mj_live_viewer", default=None)


def display_available() -> bool:
    """Whether a viewer window can open here (DISPLAY or WAYLAND_DISPLAY is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def viewer_executable() -> str | None:
    """The `rerun` viewer beside this Python (a virtualenv's bin/) or on PATH; None if neither."""
    beside = Path(sys.executable).with_name("rerun")
    return str(beside) if beside.is_file() else shutil.which("rerun")


def viewer_command(recording: str | Path) -> str:
    """A shell command that opens `recording` in the viewer and works from any folder: the
    `rerun` executable found by `viewer_executable` (absolute path unless it is on PATH),
    else `<this python> -m rerun`."""
    executable = viewer_executable()
    if executable is None:
        program = f"{sys.executable} -m rerun"
    else:
        program = "rerun" if shutil.which("rerun") == executable else executable
    return f"{program} {recording}"


@contextlib.contextmanager
def live_viewer() -> Iterator[str]:
    """While active, `write_recording` also streams each newly finished run to a spawned
    viewer; yields a one-line message saying whether the viewer was spawned (it is not
    without a display or a `rerun` executable)."""
    executable = viewer_executable()
    if not display_available():
        yield "viewer not spawned: no display (DISPLAY and WAYLAND_DISPLAY are unset); open recording.rrd later with `python -m rerun`"
        return
    if executable is None:
        yield "viewer not spawned: no `rerun` executable beside this Python or on PATH (pip install rerun-sdk)"
        return
    stream = rr.RecordingStream(APP_ID, recording_id=uuid.uuid4())
    rr.spawn(recording=stream, executable_path=executable)
    token = _LIVE.set(_Live(stream))
    try:
        yield "viewer spawned: each tuning appears in it when it finishes"
    finally:
        _LIVE.reset(token)
        stream.flush()
        stream.disconnect()


def _recording_id(folder: RunFolder) -> uuid.UUID:
    """Stable per run folder: the same folder and start time give the same id on every rebuild."""
    started = (folder.config or {}).get("started", "")
    return uuid.uuid5(uuid.NAMESPACE_URL, f"softcbf_mj:{folder.path.resolve()}:{started}")


def _log(rec: rr.RecordingStream, folder: RunFolder, scene: Scene, series: Mapping[str, Mapping[str, np.ndarray]],
         labels: Sequence[str], box: tuple[float, float, float, float]) -> None:
    _log_scene(rec, scene, box)
    rec.log(LEGEND_ENTITY, rr.TextDocument(legend_markdown(folder.labels), media_type=rr.MediaType.MARKDOWN), static=True)
    for label in labels:
        index = folder.labels.index(label)
        _log_run(rec, scene, label, run_color(label, index), series[label], frames_folder(folder.path, label),
                 folder.frames(label))


def write_recording(run_dir: str | Path) -> Path:
    """Rebuild DIR/recording.rrd from the folder (and stream new runs to a live viewer, if one is active)."""
    folder = read_run_folder(run_dir)
    if not folder.runs:
        raise RunFolderError(f"{folder.path} has no finished run to record")
    scene = Scene.of(folder)
    series = {label: folder.timeseries(label)[0] for label in folder.labels}
    box = scene_box(list(series.values()))
    cameras = [label for label in folder.labels if folder.frames(label)]
    blueprint = _blueprint(folder.labels, cameras, box)
    path = folder.path / RECORDING_FILE
    with atomic_path(path) as tmp:
        rec = rr.RecordingStream(APP_ID, recording_id=_recording_id(folder))
        rec.save(tmp, default_blueprint=blueprint)
        try:
            rec.send_recording_name(f"{folder.summary['scenario']}: {folder.path.name}")
            _log(rec, folder, scene, series, folder.labels, box)
            rec.flush()
        finally:
            rec.disconnect()
    live = _LIVE.get()
    if live is not None:
        new = [label for label in folder.labels if label not in live.sent]
        _log(live.stream, folder, scene, series, new, box)
        live.stream.send_blueprint(blueprint)
        live.sent.update(new)
    return path
