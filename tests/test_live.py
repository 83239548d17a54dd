"""Live streaming of runs while they run (softcbf_mj.outputs.recording.LiveRun, live_stream): a sink
read in the middle of a run already holds that run's rows up to then, with the entities of
the finished recording; the finished run is not streamed twice."""

import collections

import numpy as np
import pytest
import rerun as rr

from closedloop.step import ControlStep
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import FilterContext
from scenarios import get
from scenarios.common import scene_record
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant
from softcbf_mj.outputs import recording
from softcbf_mj.outputs.recording import APP_ID, LIVE_PERIOD_S, RECORDING_FILE, live_stream

DT = 1e-3  # paper_sim's control period (s)
RUN = dict(duration=0.5, tunings="None,Low", amplitude=150.0, frequency=0.5, progress=False)


def sim_times(blobs: list[bytes], path) -> dict[str, np.ndarray]:
    """sim_time (s) of every temporal row per entity in the rrd byte strings `blobs` (each written to `path`)."""
    times = collections.defaultdict(list)
    for data in blobs:
        path.write_bytes(data)
        for chunk in rr.chunk.RrdReader(path).stream().collect().stream():
            if not chunk.is_static and "sim_time" in chunk.timeline_names:
                times[chunk.entity_path].extend(chunk.to_record_batch().column("sim_time").cast("int64").to_numpy() * 1e-9)
    return {entity: np.sort(t) for entity, t in times.items()}


def test_a_spawned_stream_carries_the_run_before_it_ends(monkeypatch, tmp_path):
    stream = rr.RecordingStream(APP_ID)
    sink = stream.memory_recording()
    midway = {}  # label -> what the sink held when the run had sent 0.25 s: rrd drains so far
    received: list[bytes] = []
    real_send = recording.LiveRun.send

    def send(self, recorder, n_rows, force=False):
        real_send(self, recorder, n_rows, force)
        if self.label not in midway and n_rows * DT >= 0.25:
            received.append(sink.drain_as_bytes())
            midway[self.label] = list(received)

    monkeypatch.setattr(recording.LiveRun, "send", send)
    monkeypatch.setattr(recording, "LIVE_CPU_PERIOD_S", 0.0)  # send at every offer (every LIVE_PERIOD_S of sim time)
    with live_stream(stream):
        (tmp_path / "run").mkdir()
        get("paper_sim").run(tmp_path / "run", **RUN)
        received.append(sink.drain_as_bytes())
    assert set(midway) == {"None", "Low"}
    period = round(LIVE_PERIOD_S / DT)
    for label in ("None", "Low"):
        seen = sim_times(midway[label], tmp_path / "mid.rrd")
        rho = seen[f"/runs/{label}/rho"]
        # every row up to the first send at or after 0.25 s, and none of the run's later rows
        assert len(rho) == len(np.unique(rho)) and rho[0] == 0.0
        assert 0.25 <= rho[-1] + DT < 0.25 + period * DT and rho[-1] < RUN["duration"] - DT
        assert np.allclose(np.diff(rho), DT)
        assert seen[f"/runs/{label}/scene/arm"][-1] <= rho[-1]
    # the whole stream: each run once (no row twice), every step, the same entities as the file
    final = sim_times(received, tmp_path / "all.rrd")
    saved = sim_times([(tmp_path / "run" / RECORDING_FILE).read_bytes()], tmp_path / "file.rrd")
    assert set(final) == set(saved)
    for entity, t in saved.items():
        assert np.array_equal(final[entity], t), entity


def test_no_stream_without_a_live_viewer(tmp_path):
    assert recording.live_run({"unused": 1}, "None", 0, DT) is None


def test_sends_wait_for_the_cpu_period_and_the_end_is_sent(monkeypatch):
    robot, safe_set = reference_robot(), paper_safe_set()
    sent = []
    real_log_rows = recording._log_run_rows
    monkeypatch.setattr(recording, "_log_run_rows", lambda rec, scene, label, color, s, *a, **kw: (
        sent.append(s["t"].copy()), real_log_rows(rec, scene, label, color, s, *a, **kw)))
    stream = rr.RecordingStream(APP_ID)
    sink = stream.memory_recording()
    for cpu_period, expected_sends in ((1e9, 2), (0.0, 200 // round(LIVE_PERIOD_S / DT) + 1)):
        monkeypatch.setattr(recording, "LIVE_CPU_PERIOD_S", cpu_period)
        sent.clear()
        step = ControlStep(CBFFilter(robot, safe_set, get_tuning("Low")), SinusoidNominal.paper(robot.n_segments),
                           FilterContext.for_robot(robot, safe_set, DT, False))
        with live_stream(stream):
            live = recording.live_run(scene_record(robot, safe_set, 11.16), "Low", 0, DT)
            log, _ = run_closed_loop(PCCPlant(robot, safe_set), step, safe_set, 0.2, np.zeros(2), live=live)
        # the first row at once, then every offer the CPU-time period allows, the rest at the end: each row once
        assert len(sent) == expected_sends and len(sent[0]) == 1
        assert np.array_equal(np.concatenate(sent), log["t"])
        sink.drain_as_bytes()


def test_the_camera_loop_streams_its_frames_once_and_the_same_entities_as_its_recording(monkeypatch, tmp_path):
    stream = rr.RecordingStream(APP_ID)
    sink = stream.memory_recording()
    from_files = []  # the streams that got frames read back from the run folder
    real_log_frames = recording._log_frames
    monkeypatch.setattr(recording, "_log_frames", lambda rec, *a: (from_files.append(rec), real_log_frames(rec, *a)))
    out = tmp_path / "camera"
    out.mkdir()
    with live_stream(stream):
        get("camera_loop").run(out, duration=0.5, tunings="Low", width=640, height=360, saved_frames_hz=6.4,
                               progress=False)
    final = sim_times([sink.drain_as_bytes()], tmp_path / "all.rrd")
    saved = sim_times([(out / RECORDING_FILE).read_bytes()], tmp_path / "file.rrd")
    assert len(saved["/runs/Low/camera/image"]) >= 3  # 6.4 Hz of 12.8 fps for 0.5 s
    assert stream not in from_files and len(from_files) == 1  # the live stream got them as they were taken
    assert set(final) == set(saved)
    for entity, t in saved.items():
        assert np.array_equal(final[entity], t), entity


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_a_hardware_run_streams_its_cycles_and_frames_while_it_runs(monkeypatch, tmp_path):
    from pathlib import Path

    from hardware.config import HardwareConfig
    from softcbf.hardware_cli import run_hardware
    from softcbf_mj.emulator.emulate import EmulatedHardware

    config = HardwareConfig.load(Path(__file__).resolve().parents[1] / "examples" / "hardware_emulated.toml")
    config = config.with_overrides({"control": {"tuning": "High"}, "duration": 2.0})
    monkeypatch.setattr(recording, "LIVE_CPU_PERIOD_S", 0.0)  # send at every offer
    stream = rr.RecordingStream(APP_ID)
    sink = stream.memory_recording()
    midway: list[bytes] = []

    def on_cycle(k, t, action):
        if not midway and t >= 1.2:
            midway.append(sink.drain_as_bytes())

    out = tmp_path / "hw"
    out.mkdir()
    with live_stream(stream), EmulatedHardware(config) as emulation:
        run_hardware(config, out, emulation=emulation, on_cycle=on_cycle)
    seen = sim_times(midway, tmp_path / "mid.rrd")
    rho, images = seen["/runs/High/rho"], seen["/runs/High/camera/image"]
    # by 1.2 s of the run: its cycles up to the last offer (every max(LIVE_PERIOD_S, period) s: every 0.1 s cycle here),
    # and the frames kept so far (2 Hz)
    period = config.control.period_s
    assert 1.2 - 3 * period <= rho[-1] <= 1.2 and len(rho) >= 1.2 / period - 3
    assert len(images) >= 2 and images[-1] <= 1.2
    rest = sim_times([sink.drain_as_bytes()], tmp_path / "rest.rrd")
    saved = sim_times([(out / RECORDING_FILE).read_bytes()], tmp_path / "file.rrd")
    for entity in ("/runs/High/rho", "/runs/High/camera/image", "/runs/High/scene/arm"):
        np.testing.assert_allclose(np.sort(np.concatenate((seen[entity], rest.get(entity, [])))), saved[entity],
                                   atol=1e-9, err_msg=entity)


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")  # a real-time hardware loop: one at a time (the suite's addopts)
def test_softcbf_hardware_spawn_without_a_display_says_so_runs_and_names_the_viewer(monkeypatch, tmp_path, capsys):
    from pathlib import Path

    from softcbf.hardware_cli import main

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    spawned = []
    monkeypatch.setattr(recording.rr, "spawn", lambda **kw: spawned.append(kw))
    example = Path(__file__).resolve().parents[1] / "examples" / "hardware_emulated.toml"
    out = tmp_path / "hw"
    assert main([str(example), "--duration", "1", "--out", str(out), "--spawn"]) == 0
    captured = capsys.readouterr()
    assert "viewer not spawned: no display" in captured.err and spawned == []
    assert f"view the recording with: {recording.viewer_command(out / RECORDING_FILE)}" in captured.out
