"""rerun recordings (softcbf_mj.outputs.recording), read back with rerun's own reader (docs/run-outputs.md):
entities, time steps, values, the camera-frame hook, the viewer switch."""

import collections
import math
import shutil

import cv2
import numpy as np
import pytest
import rerun as rr

from softcbf_mj.outputs import recording
from softcbf_mj.outputs.recording import GEOMETRY_HZ, RECORDING_FILE, live_viewer, write_recording
from softcbf_mj.outputs.runio import frames_folder, load_timeseries, save_frames_index

STEPS = 500  # 0.5 s at 1 kHz
SERIES = ("u", "u_nom", "rho", "force", "flags", "plate_displacement")
GEOMETRY = ("scene/arm", "scene/tags", "scene/tip", "scene/plate")
STATIC = ("scene", "scene/tip_trace")


def read(path):
    """(entity paths, time rows per entity, static entities, chunks) of the first recording in `path`."""
    store = rr.chunk.RrdReader(path).stream().collect()
    rows, static, chunks = collections.Counter(), set(), collections.defaultdict(list)
    for chunk in store.stream():
        if chunk.is_static:
            static.add(chunk.entity_path)
        else:
            rows[chunk.entity_path] += chunk.num_rows
            chunks[chunk.entity_path].append(chunk)
    return set(store.schema().entity_paths()), rows, static, chunks


def rows_by_time(chunks, name):
    """(times s, one value per row) of component `name` over an entity's chunks, sorted by time."""
    times, values = [], []
    for chunk in chunks:
        batch = chunk.to_record_batch()
        times.extend(batch.column("sim_time").cast("int64").to_numpy() * 1e-9)
        values.extend(batch.column(name).to_pylist())
    order = np.argsort(times, kind="stable")
    return np.array(times)[order], [values[i] for i in order]


def column(chunks, name):
    """`rows_by_time` with the values as a float array (T, k)."""
    times, values = rows_by_time(chunks, name)
    return times, np.array(values, dtype=float)


def test_recording_has_every_entity_and_time_step(run_dir):
    entities, rows, static, _ = read(run_dir / RECORDING_FILE)
    assert {"/scene", "/scene/facets", "/scene/P"} <= static
    geometry_rows = math.ceil(STEPS / round(1 / (GEOMETRY_HZ * 1e-3)))  # decimated to GEOMETRY_HZ
    for label in ("None", "Low"):
        for name in SERIES:
            assert rows[f"/runs/{label}/{name}"] == STEPS, (label, name)
        for name in GEOMETRY:
            assert rows[f"/runs/{label}/{name}"] == geometry_rows, (label, name)
        for name in STATIC:
            assert f"/runs/{label}/{name}" in static
    expected = {f"/runs/{lbl}/{n}" for lbl in ("None", "Low") for n in SERIES + GEOMETRY + STATIC}
    assert expected | {"/scene", "/scene/facets", "/scene/P"} <= entities
    reader = rr.chunk.RrdReader(run_dir / RECORDING_FILE)
    assert len(reader.recordings()) == 1 and len(reader.blueprints()) == 1


def test_time_series_values_are_the_saved_ones(run_dir):
    series, _ = load_timeseries(run_dir / "timeseries" / "Low.npz")
    _, _, _, chunks = read(run_dir / RECORDING_FILE)
    t, rho = column(chunks["/runs/Low/rho"], "Scalars:scalars")
    np.testing.assert_allclose(t, series["t"], atol=1e-9)  # the timeline holds whole nanoseconds
    np.testing.assert_array_equal(rho, np.column_stack((series["rho_pred"], series["rho_meas"])))
    _, u = column(chunks["/runs/Low/u"], "Scalars:scalars")
    np.testing.assert_array_equal(u, series["u"])
    t_geo, tip = column(chunks["/runs/Low/scene/tip"], "Points2D:positions")
    step = round(1 / (GEOMETRY_HZ * 1e-3))
    np.testing.assert_allclose(t_geo, series["t"][::step], atol=1e-9)
    np.testing.assert_allclose(tip.reshape(-1, 2), series["tip"][::step], rtol=1e-6)  # stored as float32


def test_rebuild_keeps_the_recording_id(own_run_dir):
    # A run written in its own folder (the id derives from the folder's path; run_dir is a copy: tests/conftest.py).
    first = rr.chunk.RrdReader(own_run_dir / RECORDING_FILE).recordings()[0].recording_id
    write_recording(own_run_dir)
    assert rr.chunk.RrdReader(own_run_dir / RECORDING_FILE).recordings()[0].recording_id == first
    assert not list(own_run_dir.glob(".*tmp"))


def test_camera_frames_are_logged_with_their_detections(run_dir, tmp_path):
    run = shutil.copytree(run_dir, tmp_path / "run")
    folder = frames_folder(run, "Low")
    folder.mkdir(parents=True)
    corners = [[10.0, 10.0], [30.0, 10.0], [30.0, 30.0], [10.0, 30.0]]
    detections = ([{"id": 2, "corners": corners}, {"id": 1, "corners": corners}], [{"id": 2, "corners": corners}], [])
    frames = []
    for i, (t, seen) in enumerate(zip((0.0, 0.078, 0.156), detections)):
        image = np.full((48, 64), 255, np.uint8)
        cv2.rectangle(image, (10, 10), (30, 30), 0, -1)
        cv2.imwrite(str(folder / f"{i:06d}.png"), image)
        frames.append({"t": t, "file": f"{i:06d}.png", "detections": seen})
    save_frames_index(run, "Low", frames)
    write_recording(run)
    _, rows, _, chunks = read(run / RECORDING_FILE)
    assert rows["/runs/Low/camera/image"] == 3 and rows["/runs/Low/camera/image/detections"] == 3
    assert "/runs/None/camera/image" not in rows
    _, labels = rows_by_time(chunks["/runs/Low/camera/image/detections"], "LineStrips2D:labels")
    assert labels == [["tag 2", "tag 1"], ["tag 2"], []]
    _, strips = rows_by_time(chunks["/runs/Low/camera/image/detections"], "LineStrips2D:strips")
    np.testing.assert_array_equal(strips[1][0], corners + corners[:1])  # closed outline, px
    _, blobs = rows_by_time(chunks["/runs/Low/camera/image"], "EncodedImage:blob")
    assert [bytes(b[0]) for b in blobs] == [(folder / f["file"]).read_bytes() for f in frames]


def test_frames_index_is_checked(tmp_path):
    folder = frames_folder(tmp_path, "None")
    folder.mkdir(parents=True)
    with pytest.raises(ValueError, match="does not exist; write it before the index"):
        save_frames_index(tmp_path, "None", [{"t": 0.0, "file": "missing.png", "detections": []}])
    cv2.imwrite(str(folder / "a.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(ValueError, match="ascending"):
        save_frames_index(tmp_path, "None", [{"t": 0.2, "file": "a.png"}, {"t": 0.1, "file": "a.png"}])
    with pytest.raises(ValueError, match=r"corners must be 4 \[x, y\] pairs, got shape \(3, 2\)"):
        save_frames_index(tmp_path, "None", [{"t": 0.0, "file": "a.png", "detections": [{"id": 0, "corners": [[0, 0]] * 3}]}])
    assert not (folder / "frames.json").exists()


def test_live_viewer_is_skipped_without_a_display(monkeypatch, run_dir):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    spawned = []
    monkeypatch.setattr(recording.rr, "spawn", lambda **kw: spawned.append(kw))
    with live_viewer() as message:
        assert message.startswith("viewer not spawned: no display")
        write_recording(run_dir)
    assert spawned == []


def test_live_viewer_spawns_and_streams_each_new_run_once(monkeypatch, run_dir):
    monkeypatch.setenv("DISPLAY", ":99")
    spawned, logged = [], []
    monkeypatch.setattr(recording.rr, "spawn", lambda **kw: spawned.append(kw))  # nothing is started
    real_log_run = recording._log_run

    def log_run(rec, scene, label, *args):
        logged.append((rec, label))
        real_log_run(rec, scene, label, *args)

    monkeypatch.setattr(recording, "_log_run", log_run)
    with live_viewer() as message:
        assert message.startswith("viewer spawned")
        write_recording(run_dir)
        write_recording(run_dir)  # nothing new: nothing more is streamed
    (call,) = spawned
    assert call["executable_path"].endswith("rerun")
    live = [label for rec, label in logged if rec is call["recording"]]
    assert live == ["None", "Low"]  # the file got both runs twice, the viewer once
    assert len(logged) == 6


def _static_components(path):
    """{entity: {component: values of its first static row}} of a recording."""
    store = rr.chunk.RrdReader(path).stream().collect()
    out = {}
    for chunk in store.stream():
        if chunk.is_static:
            batch = chunk.to_record_batch()
            out.setdefault(chunk.entity_path, {}).update(
                {n: batch.column(n).to_pylist()[0] for n in batch.schema.names if ":" in n})
    return out


def test_series_are_legible_on_the_dark_theme_and_switching_is_not_averaged(run_dir):
    static = _static_components(run_dir / RECORDING_FILE)
    for label in ("None", "Low"):
        for name in SERIES:
            style = static[f"/runs/{label}/{name}"]
            for packed in style["SeriesLines:colors"]:  # 0xRRGGBBAA; none black or near-black
                r, g, b = (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255
                assert 0.2126 * r + 0.7152 * g + 0.0722 * b > 0.3 * 255, (label, name, hex(packed))
        policy = rr.components.AggregationPolicy
        assert static[f"/runs/{label}/flags"]["SeriesLines:aggregation_policy"] == [policy.MinMax.value]
        assert static[f"/runs/{label}/flags"]["SeriesLines:interpolation_mode"] == [rr.components.InterpolationMode.StepAfter.value]
        assert static[f"/runs/{label}/u"]["SeriesLines:aggregation_policy"] == [policy.MinMax.value]
    from softcbf_mj.outputs.palette import run_color
    force_colors = static["/runs/None/force"]["SeriesLines:colors"]
    assert force_colors[0] >> 8 == int(run_color("None", 0)[1:], 16)  # the run's palette colour, as in the plots
    legend = static[recording.LEGEND_ENTITY]["TextDocument:text"][0]
    assert "None" in legend and "Low" in legend and run_color("Low", 1) in legend


def test_viewer_command_names_an_executable_that_exists(monkeypatch, tmp_path):
    command = recording.viewer_command("x.rrd")
    program = command[: -len(" x.rrd")]
    assert command.endswith(" x.rrd")
    assert shutil.which(program.split()[0]) is not None  # 'rerun' on PATH, an absolute path, or python -m rerun
    monkeypatch.setattr(recording, "viewer_executable", lambda: None)
    assert recording.viewer_command("x.rrd") == f"{recording.sys.executable} -m rerun x.rrd"
