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
displacement as in softcbf_mj.outputs.report. Camera frames: DIR/frames/<run>/frames.json
(format: softcbf_mj.outputs.runio); images are logged as encoded files, unchanged.

Colours (softcbf_mj.outputs.palette, shared with the report: Okabe–Ito, no black, legible on
rerun's dark theme): each run its colour, its second series (ρ_pred, F_pred) lighter,
u_nom, facets and plates grey, F_max and P vermillion. Scalar series are styled by
SERIES_STYLES: zoomed out, u and the flags keep each pixel column's min and max, so a
command or flag switching every step shows as a band instead of being averaged away.

Default blueprint: the 2D scene (and one view per camera) and the colour legend on the
left; on the right the time series ρ, force vs F_max, u vs u_nom and the flags, each with
every run. rerun draws plot legends inside the plot, so they are hidden (the legend view
and hovering name every line).

Live view. `live_viewer()` (the CLI's `--spawn`) spawns a viewer when a display is present
and makes its stream the live stream (`live_stream(stream)`: any sink, e.g. a memory
recording in the tests); without a display it says so and nothing is streamed. While a
live stream is active, `live_run(scene, label, index, control_dt)` gives the loops a
`LiveRun`: every LIVE_PERIOD_S of the loop's time the loop hands it the recorder, and it
sends the rows recorded since its last call, one `send_columns` per entity, with the
entities, styles, colours and geometry decimation of the finished recording (so the
viewer's time series grow while the run runs; camera frames go in through
`LiveRun.frame`). When the run is finished, `write_recording` streams to the live stream
what it still lacks: the tip's whole path and the saved camera frames of runs streamed
live, everything of runs that were not (each run's rows reach the stream once).
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import sys
import time
import uuid
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextvars import ContextVar
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from softcbf_mj.outputs.palette import LIMIT_COLOR, rgb, run_color
from closedloop.record import Recorder
from softcbf_mj.outputs.report import (
    BOX_MARGIN_M,
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
from softcbf_mj.outputs.runio import RunFolder, RunFolderError, atomic_path, frames_folder, read_run_folder

APP_ID = "softcbf_mj"
RECORDING_FILE = "recording.rrd"
TIMELINE = "sim_time"
GEOMETRY_HZ = 50.0
LIVE_PERIOD_S = 0.05  # a loop offers a LiveRun its new rows every LIVE_PERIOD_S of the loop's time (s)
LIVE_CPU_PERIOD_S = 0.25  # ... and the LiveRun sends them when this process has used LIVE_CPU_PERIOD_S of CPU time (s)
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
    """Every how many rows the geometry is drawn: GEOMETRY_HZ at the median row period (a hardware
    run's first cycles may be late; `LiveRun` uses the nominal period, which the median matches)."""
    if len(t) < 2:
        return 1
    return max(1, int(round(1.0 / (GEOMETRY_HZ * float(np.median(np.diff(t)))))))


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
    t = np.asarray(s["t"], dtype=float)
    _log_run_rows(rec, scene, label, color, s, np.arange(0, len(t), _decimation(t)), styles=True)
    _log_tip_trace(rec, label, color, s)
    if frames:
        _log_frames(rec, run_path(label), frames_dir, frames)


def _log_tip_trace(rec: rr.RecordingStream, label: str, color: str, s: Mapping[str, np.ndarray]) -> None:
    """The tip's whole path (static), at the geometry's rate."""
    t = np.asarray(s["t"], dtype=float)
    tips = np.asarray(s["segment_ends"], dtype=float)[:: _decimation(t), -1]
    rec.log(f"{run_path(label)}/scene/tip_trace", rr.LineStrips2D([tips], colors=rgb(color, 0.4),
                                                                 radii=rr.Radius.ui_points(1.0)), static=True)


def _log_run_rows(rec: rr.RecordingStream, scene: Scene, label: str, color: str, s: Mapping[str, np.ndarray],
                  k: np.ndarray, styles: bool) -> None:
    """Rows `s` of a run: every row's scalars, and the geometry of rows `k` (indices into `s`);
    with `styles`, also the entities' static styles (once per run and stream)."""
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
        if styles:
            rec.log(f"{root}/{name}", rr.SeriesLines(names=names, colors=colors, **SERIES_STYLES[style]), static=True)
        rec.send_columns(f"{root}/{name}", indexes=time, columns=rr.Scalars.columns(scalars=values))

    geo_time = [rr.TimeColumn(TIMELINE, duration=t[k])]
    ends = np.asarray(s["segment_ends"], dtype=float)[k]
    q = np.asarray(s["q"], dtype=float)[k]
    n_tags = ends.shape[1]
    plates = _plate_strips(scene, s, k)
    if styles:
        run_rgb = rgb(color)
        rec.log(f"{root}/scene", MIRROR_Y, static=True)
        rec.log(f"{root}/scene/arm", rr.LineStrips2D.from_fields(colors=run_rgb, radii=rr.Radius.ui_points(3.0)),
                static=True)
        rec.log(f"{root}/scene/tags", rr.Points2D.from_fields(colors=run_rgb, radii=rr.Radius.ui_points(5.0),
                                                             labels=[f"tag {i}" for i in range(n_tags)]), static=True)
        rec.log(f"{root}/scene/tip", rr.Points2D.from_fields(colors=run_rgb, radii=rr.Radius.ui_points(4.0)), static=True)
        rec.log(f"{root}/scene/plate",
                rr.LineStrips2D.from_fields(colors=rgb(PLATE_COLOR), radii=rr.Radius.ui_points(3.0)), static=True)
    if not len(k):
        return
    rec.send_columns(f"{root}/scene/arm", indexes=geo_time,
                     columns=rr.LineStrips2D.columns(strips=arm_polyline(q, scene.lengths, ends[:, 0])))
    rec.send_columns(f"{root}/scene/tags", indexes=geo_time,
                     columns=rr.Points2D.columns(positions=ends.reshape(-1, 2)).partition([n_tags] * len(k)))
    rec.send_columns(f"{root}/scene/tip", indexes=geo_time, columns=rr.Points2D.columns(positions=ends[:, -1]))
    rec.send_columns(f"{root}/scene/plate", indexes=geo_time,
                     columns=rr.LineStrips2D.columns(strips=plates.reshape(-1, 2, 2)).partition([plates.shape[1]] * len(k)))


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
    blobs, media = [], []
    for f in frames:
        path = frames_dir / f["file"]
        if path.suffix.lower() not in MEDIA_TYPES:
            raise RunFolderError(f"camera frame {path}: unsupported image type; use one of {', '.join(MEDIA_TYPES)}")
        blobs.append(path.read_bytes())
        media.append(MEDIA_TYPES[path.suffix.lower()])
    _log_images(rec, root, [float(f["t"]) for f in frames], blobs, media, [f.get("detections", []) for f in frames])


def _log_images(rec: rr.RecordingStream, root: str, times: Sequence[float], blobs: Sequence[bytes],
                media: Sequence[str], detections: Sequence[Sequence[Mapping]]) -> None:
    """Encoded images at `times` (s) and their detections ({"id", "corners"} each, as in frames.json)."""
    t = [rr.TimeColumn(TIMELINE, duration=times)]
    rec.send_columns(f"{root}/camera/image", indexes=t, columns=rr.EncodedImage.columns(blob=blobs, media_type=media))
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
    """The stream of a live viewer (`live_viewer`, `live_stream`): the runs finished in it
    (`write_recording` streamed them, or a `LiveRun` streamed them while they ran), the
    runs a `LiveRun` streamed while they ran and those whose camera frames it streamed."""

    stream: rr.RecordingStream
    sent: list[str] = field(default_factory=list)
    streamed_live: set[str] = field(default_factory=set)
    framed_live: set[str] = field(default_factory=set)


_LIVE: ContextVar[_Live | None] = ContextVar("softcbf_mj_live_viewer", default=None)


class LiveRun:
    """One run streamed to the live viewer while it runs, with the entities and styles of
    the finished recording (`_log_run_rows`: the scalars every row, the geometry every
    `_decimation`-th row of the run, counted from its first row).

    A loop calls `send(recorder, n_rows)` every `period_steps` rows (LIVE_PERIOD_S of the
    loop's time) and `send(recorder, n_rows, force=True)` at its end; a call sends the rows
    not sent yet, one `send_columns` per entity, if forced or this process has used
    LIVE_CPU_PERIOD_S of CPU time (`time.process_time`) since the last send. rerun takes
    ~0.2 ms of CPU per `send_columns` of few rows, so sending at every offer slowed a 1 kHz
    loop by 80 %; a CPU-time period bounds the cost to (CPU of one send) /
    LIVE_CPU_PERIOD_S of the loop's own CPU time whatever the machine's load
    (tools/bench_live.py). A loop with a core to itself refreshes the viewer
    1/LIVE_CPU_PERIOD_S times a second; on a busy machine, less often. The plates are
    drawn at the deepest tip approach of each batch (the finished recording: of the whole
    run). Camera frames go in through `frame` as they are taken; the tip's whole path (and
    the saved frames of a run that sent none through `frame`) follow when
    `write_recording` records the finished run.
    """

    def __init__(self, live: _Live, scene: Scene, label: str, color: str, control_dt: float, camera: bool = False,
                 complete: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None) -> None:
        if not (math.isfinite(control_dt) and control_dt > 0):
            raise ValueError(f"control_dt must be finite and > 0 s, got {control_dt}")
        self._live, self.scene, self.label, self.color, self.camera = live, scene, label, color, camera
        self.complete = complete
        self.period_steps = max(1, int(round(LIVE_PERIOD_S / control_dt)))
        self._decimation = max(1, int(round(1.0 / (GEOMETRY_HZ * control_dt))))
        self.rows_sent = 0
        self.sends = 0  # the sends so far, and the calling thread's CPU time they took (s)
        self.send_cpu_s = 0.0
        self._last_send = -math.inf
        live.streamed_live.add(label)

    def send(self, recorder: Recorder, n_rows: int, force: bool = False) -> None:
        """Stream rows rows_sent .. n_rows - 1 of `recorder` (the loop's rows so far), if
        `force` or this process has used LIVE_CPU_PERIOD_S of CPU time since the last send."""
        first = self.rows_sent
        now = time.process_time()
        if n_rows <= first or not (force or now - self._last_send >= LIVE_CPU_PERIOD_S):
            return
        self._last_send, start = now, time.thread_time()
        s = recorder.columns(n_rows, first)
        if self.complete is not None:
            s = self.complete(s)
        else:
            contact = np.asarray(s["contact_force"], dtype=float)
            s["tip"] = np.asarray(s["segment_ends"])[:, -1]
            s["rho_meas"] = np.min((self.scene.n_max - self.scene.stiffness.penetration(contact)) / self.scene.n_max, axis=-1)
        k = np.arange(-first % self._decimation, n_rows - first, self._decimation)
        stream = self._live.stream
        if first == 0:
            base, reach = np.asarray(s["segment_ends"])[0, 0], float(np.sum(self.scene.lengths)) + BOX_MARGIN_M
            box = (base[0] - reach, base[0] + reach, base[1] - reach, base[1] + reach)
            labels = [*self._live.sent, self.label]
            stream.send_blueprint(_blueprint(labels, [self.label] if self.camera else [], box))
            _log_scene(stream, self.scene, box)
            stream.log(LEGEND_ENTITY, rr.TextDocument(legend_markdown(labels), media_type=rr.MediaType.MARKDOWN), static=True)
        _log_run_rows(stream, self.scene, self.label, self.color, s, k, styles=first == 0)
        self.rows_sent = n_rows
        self.sends += 1
        self.send_cpu_s += time.thread_time() - start

    def frame(self, t: float, image: bytes, media_type: str, detections: Sequence[Mapping] = ()) -> None:
        """One encoded camera image (`media_type`, e.g. "image/jpeg") taken at the loop's time
        t (s), with its tag detections ({"id", "corners"} each, as in frames.json); sent at
        once. The finished run's saved frames are then not streamed again."""
        self._live.framed_live.add(self.label)
        _log_images(self._live.stream, run_path(self.label), [t], [image], [media_type], [list(detections)])


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
    """While active, runs stream to a spawned viewer as they run (`live_run`) and
    `write_recording` streams what they did not (`live_stream`); yields a one-line message
    saying whether the viewer was spawned (it is not without a display or a `rerun`
    executable; then nothing is streamed)."""
    executable = viewer_executable()
    if not display_available():
        yield ("viewer not spawned: no display (DISPLAY and WAYLAND_DISPLAY are unset); open the recording later with "
               f"`{viewer_command('DIR/' + RECORDING_FILE)}`")
        return
    if executable is None:
        yield "viewer not spawned: no `rerun` executable beside this Python or on PATH (pip install rerun-sdk)"
        return
    stream = rr.RecordingStream(APP_ID, recording_id=uuid.uuid4())
    rr.spawn(recording=stream, executable_path=executable)
    try:
        with live_stream(stream):
            yield "viewer spawned: each run streams to it while it runs"
    finally:
        stream.flush()
        stream.disconnect()


@contextlib.contextmanager
def live_stream(stream: rr.RecordingStream) -> Iterator[None]:
    """While active, `live_run` streams runs to `stream` as they run and `write_recording`
    streams each newly finished run's rest to it (any sink: a spawned viewer, a gRPC
    server, a binary stream)."""
    token = _LIVE.set(_Live(stream))
    try:
        yield
    finally:
        _LIVE.reset(token)


def live_run(scene_record: Mapping[str, Any] | None, label: str, index: int, control_dt: float,
             camera: bool = False, complete: Callable[[dict[str, np.ndarray]], dict[str, np.ndarray]] | None = None,
             ) -> LiveRun | None:
    """A `LiveRun` of run `label` (the `index`-th of its folder; its colour `run_color(label,
    index)`; with `camera`, a camera view for its `LiveRun.frame`s) in the scene of
    summary.json's "scene" record, if a live stream is active (`live_viewer`,
    `live_stream`) and the scene is known; else None. The recorder's rows must hold the
    simulated loops' columns (`softcbf_mj.loops.loop.plant_columns`), or `complete(rows)` must
    turn them into a run's time series (the hardware loop's: tip and rho_meas included)."""
    live = _LIVE.get()
    if live is None or scene_record is None:
        return None
    return LiveRun(live, Scene.from_record(scene_record), label, run_color(label, index), control_dt, camera, complete)


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
        whole = [label for label in new if label not in live.streamed_live]
        if whole:
            _log(live.stream, folder, scene, series, whole, box)
        for label in new:
            if label in live.streamed_live:  # its rows are there: the tip's path and the saved frames remain
                color = run_color(label, folder.labels.index(label))
                _log_tip_trace(live.stream, label, color, series[label])
                if folder.frames(label) and label not in live.framed_live:
                    _log_frames(live.stream, run_path(label), frames_folder(folder.path, label), folder.frames(label))
        live.stream.send_blueprint(blueprint)
        live.sent.extend(new)
    return path
