"""Hardware mode before the loop runs: one-line errors (exit 2) and no run folder for hardware that
does not start, paths relative to the configuration's folder, plausibility bounds with units,
and a property test over random configurations (hypothesis)."""

from __future__ import annotations

import json
import math
import re
import os
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from closedloop.monitor import SafetyMonitor
from controllers.model.params import per_segment
from hardware.config import EMULATOR_COMMAND_PERIOD_S, ConfigError, HardwareConfig
from hardware.protocol import PressureLimits
from perception.plane import PlaneCalibration
from softcbf.hardware_cli import main
from softcbf_mj.physics.mjcf import ArmModelConfig
from softcbf_mj.physics.plant import steps_per_control

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "hardware_emulated.toml"


@pytest.fixture
def real(tmp_path) -> Path:
    """A real-hardware configuration in its own folder: a 5-frame video without tags, its calibration."""
    folder = tmp_path / "config"
    folder.mkdir()
    writer = cv2.VideoWriter(str(folder / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    for _ in range(5):
        writer.write(np.full((48, 64, 3), 200, np.uint8))
    writer.release()
    PlaneCalibration(np.eye(3)).save(folder / "cal.json")
    (folder / "not_a_video.avi").write_text("no frames here", encoding="utf-8")
    (folder / "hw.toml").write_text('calibration = "cal.json"\n[camera]\nsource = "clip.avi"\nstartup_timeout_s = 0.3\n'
                                    '[link]\nport = "/dev/ttyNOPE"\n', encoding="utf-8")
    return folder / "hw.toml"


def _nested(changes: dict[str, object]) -> dict[str, object]:
    """{"section.key": value, "name": value} in the configuration file's shape."""
    out: dict[str, dict] = {}
    for key, value in changes.items():
        section, _, name = key.rpartition(".")
        (out.setdefault(section, {}) if section else out)[name] = value
    return out


def _emulated(tmp_path: Path, key: str, value: str) -> Path:
    """The emulated example with `key` ("section.key" or a top-level setting) set to the TOML value `value`, as JSON."""
    data = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))
    data["robot"] = str(EXAMPLE.parent / data["robot"])
    for section, table in _nested({key: tomllib.loads(f"v = {value}")["v"]}).items():
        if isinstance(table, dict):
            data[section].update(table)
        else:
            data[section] = table
    path = tmp_path / f"{key}.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    return path


def _run_cli(capfd, argv: list[str]) -> tuple[int, str]:
    code = main(argv)
    return code, capfd.readouterr().err


# -- H1: start-up failures ---------------------------------------------------------


@pytest.mark.parametrize(("options", "message"), [
    (["--port", "/dev/ttyNOPE"], "error: link.port '/dev/ttyNOPE' (the valve board's serial port): SerialException: "),
    (["--port", "/dev/null"], "error: link.port '/dev/null' (the valve board's serial port): SerialException: "
                              "Could not configure port"),
    (["--port", "{folder}/cal.json"], "error: link.port '{folder}/cal.json' (the valve board's serial port): "),
    (["--camera", "{folder}/not_a_video.avi"], "error: camera.source '{folder}/not_a_video.avi': OSError: "
                                                 "cv2.VideoCapture could not open"),
    (["--camera", "{folder}/missing.avi"], "error: camera.source '{folder}/missing.avi': OSError: "),
])
def test_hardware_that_does_not_open_is_one_line_exit_2_and_no_folder(real, tmp_path, capfd, options, message):
    folder = str(real.parent)
    out = tmp_path / "out"
    code, err = _run_cli(capfd, [str(real), *[o.format(folder=folder) for o in options], "--out", str(out)])
    assert (code, err.count("\n")) == (2, 1) and err.startswith(message.format(folder=folder))
    assert not out.exists()


@pytest.mark.parametrize(("key", "value", "message"), [
    ("pressure.u_max_hPa", "5000.0", r"pressure.u_max_hPa must be within ±3276.7 hPa .*got 5000.0"),
    ("pressure.u_min_hPa", "10.0", r"pressure limits must hold 0 hPa, the vented state .*u_min=10, u_max=150"),
    ("physics_dt", "0.5", r"physics_dt must be <= 0.001 s .*got 0.5"),
    ("physics_dt", "3e-4", r"physics_dt must divide the emulated board's command period"),
])
def test_settings_the_link_or_the_emulator_would_refuse_are_refused_at_load(tmp_path, capfd, key, value, message):
    out = tmp_path / "out"
    code, err = _run_cli(capfd, [str(_emulated(tmp_path, key, value)), "--out", str(out)])
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: ") and re.search(message, err)
    assert not out.exists()


def test_a_missing_calibration_file_is_refused_at_load(real, tmp_path, capfd):
    real.write_text(real.read_text(encoding="utf-8").replace('"cal.json"', '"nope.json"'), encoding="utf-8")
    code, err = _run_cli(capfd, [str(real), "--out", str(tmp_path / "out")])
    assert code == 2 and err == (f"error: calibration must be a plane calibration JSON file, got 'nope.json' "
                                 f"(no file {real.parent / 'nope.json'}; relative paths are relative to the "
                                 "configuration's folder)\n")
    assert not (tmp_path / "out").exists()


def test_a_failed_start_keeps_the_folder_that_overwrite_would_replace(real, tmp_path, capfd):
    out = tmp_path / "previous_run"
    out.mkdir()
    (out / "summary.json").write_text("{}", encoding="utf-8")
    code, _ = _run_cli(capfd, [str(real), "--out", str(out), "--overwrite"])
    assert code == 2 and (out / "summary.json").read_text(encoding="utf-8") == "{}"


def test_no_first_frame_vents_and_exits_2_removing_the_empty_folder(real, tmp_path, capfd):
    """A pty stands in for the board's port (nobody answers: the vent times out); the video has no tags."""
    master, slave = os.openpty()
    try:
        out = tmp_path / "out"
        code, err = _run_cli(capfd, [str(real), "--port", os.ttyname(slave), "--out", str(out)])
    finally:
        os.close(master)
        os.close(slave)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: no complete frame (every arm tag seen once) within 0.3 s")
    assert not out.exists()


def test_an_emulator_that_does_not_start_is_one_line_exit_2_and_no_folder(tmp_path, capfd, monkeypatch):
    import softcbf_mj.emulator.emulate

    def refuse(config):
        raise RuntimeError("the MuJoCo model did not compile\n(details on a second line)")

    monkeypatch.setattr(softcbf_mj.emulator.emulate, "EmulatedHardware", refuse)
    code, err = _run_cli(capfd, [str(EXAMPLE), "--out", str(tmp_path / "out")])
    *progress, error = err.splitlines()  # the emulated run's start line comes first (softcbf.hardware_cli.CycleProgress)
    assert (code, error) == (2, "error: emulator: RuntimeError: the MuJoCo model did not compile")
    assert [line.split("]")[0] for line in progress] == ["[hardware High"]
    assert not (tmp_path / "out").exists()


# -- H2: paths relative to the configuration's folder ----------------------------


def test_a_relative_camera_file_is_relative_to_the_configuration_folder(real, tmp_path, capfd, monkeypatch):
    """From another working directory the camera (clip.avi next to the file) opens: the run gets as far as the port."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    config = HardwareConfig.load(real)
    assert config.camera_source() == str(real.parent / "clip.avi")
    code, err = _run_cli(capfd, [str(real), "--out", str(tmp_path / "out")])
    assert code == 2 and err.startswith("error: link.port '/dev/ttyNOPE'")


def test_a_camera_file_on_the_command_line_is_relative_to_the_working_directory(real, tmp_path, capfd, monkeypatch):
    monkeypatch.chdir(real.parent)
    code, err = _run_cli(capfd, [str(real), "--camera", "not_a_video.avi", "--out", str(tmp_path / "out")])
    assert code == 2 and err.startswith(f"error: camera.source '{real.parent / 'not_a_video.avi'}': OSError")


def test_device_indices_urls_and_the_virtual_camera_are_not_paths(tmp_path):
    PlaneCalibration(np.eye(3)).save(tmp_path / "cal.json")
    for source in (0, "rtsp://host/stream", "v4l2src ! appsink"):
        config = HardwareConfig.from_dict({"calibration": "cal.json", "camera": {"source": source}}, tmp_path)
        assert config.camera_source() == source


# -- H3: plausibility bounds with units -----------------------------------------


@pytest.mark.parametrize(("key", "value", "message"), [
    ("safety.watchdog_s", 150, r"safety.watchdog_s must be <= 5 s \(a plausibility bound; a value in ms\? 150 ms = 0.15 s\), "
                               r"got 150.0"),
    ("hold_s", 500, r"hold_s must be <= 10 s \(.*500 ms = 0.5 s\)"),
    ("link.ack_timeout_s", 20, r"link.ack_timeout_s must be <= 1 s \(.*20 ms = 0.02 s\)"),
    ("max_hold_s", 300, r"max_hold_s must be <= 10 s"),
    ("camera.tag_size_m", 30, r"camera.tag_size_m must be <= 0.5 m \(.*a value in mm\? 30 mm = 0.03 m\)"),
    ("amplitude", 8000.0, r"amplitude must be within ±3276.7 hPa \(.*8000 Pa = 80 hPa\)"),
    ("amplitude", [80.0, 8000.0], r"amplitude\[1\] must be within ±3276.7 hPa"),
    ("control_rate", 1e6, r"control_rate must be <= 10000 Hz \(a plausibility bound\), got 1000000.0"),
    ("frequency", 6.0, r"frequency must be below half the control rate \(5 Hz\), got 6"),
    ("duration", 1e6, r"duration must be <= 86400 s"),
    ("tau_p", 50, r"tau_p must be <= 5 s \(.*50 ms = 0.05 s\)"),
    ("emulator.q0_rad", 30, r"emulator.q0_rad must be within ±3.14159 rad \(.*a value in °\? 30 ° = 0.5236 rad\)"),
])
def test_unit_mistakes_are_refused_with_the_unit(key, value, message):
    with pytest.raises(ConfigError, match=message):
        HardwareConfig.load(EXAMPLE).with_overrides(_nested({key: value}))


# -- property: random configurations ---------------------------------------------

junk = st.one_of(st.booleans(), st.text(max_size=6), st.floats(allow_nan=True, allow_infinity=True),
                 st.integers(-10**12, 10**12), st.lists(st.floats(-1e4, 1e4), max_size=3))


def mostly(good: st.SearchStrategy) -> st.SearchStrategy:
    return st.integers(0, 9).flatmap(lambda n: junk if n == 9 else good)


def seconds(low: float, high: float) -> st.SearchStrategy:
    return mostly(st.integers(0, 4).flatmap(lambda n: st.floats(low, 1000 * high) if n == 4 else st.floats(low, high)))


pressures = st.one_of(st.floats(-400, 400), st.lists(st.floats(-400, 400), min_size=1, max_size=3), st.floats(-6000, 6000))
KEYS = {  # "section.key" or a top-level setting → its values, mostly plausible
    "max_hold_s": seconds(0.0, 2.0), "qd_filter_tau": seconds(0.0, 1.0), "camera.startup_timeout_s": seconds(0.0, 10.0),
    "camera.tag_size_m": mostly(st.floats(0.0, 0.1)), "frame_rate": mostly(st.floats(0.0, 60.0)),
    "width": mostly(st.integers(0, 2000)), "detector": mostly(st.sampled_from(["opencv", "pupil", "x"])),
    "assumed_plate_stiffness": mostly(st.floats(-1.0, 50.0)), "f_max": mostly(st.floats(-0.1, 1.0)),
    "environment.h": mostly(st.lists(st.floats(-0.2, 0.4), min_size=1, max_size=2)),
    "pressure.u_min_hPa": mostly(pressures), "pressure.u_max_hPa": mostly(pressures),
    "control.tuning": mostly(st.sampled_from(["None", "Low", "High", "HW-Low", "HW-High", "Medium"])),
    "control_rate": mostly(st.floats(0.0, 2000.0)), "amplitude": mostly(pressures),
    "frequency": mostly(st.floats(0.0, 10.0)), "control.phase_rad": mostly(st.floats(-10.0, 10.0)),
    "hold_s": seconds(0.0, 2.0), "safety.watchdog_s": seconds(0.0, 1.0),
    "link.ack_timeout_s": seconds(0.0, 0.1), "link.retries": mostly(st.integers(-1, 5)), "link.lost_after": mostly(st.integers(0, 3)),
    "duration": seconds(0.0, 100.0), "run.dry_run": mostly(st.booleans()),
    "tau_p": seconds(0.0, 0.2), "emulator.q0_rad": mostly(st.one_of(st.floats(-4.0, 4.0), st.floats(-60, 60))),
    "physics_dt": mostly(st.sampled_from([1e-4, 2e-4, 3e-4, 5e-4, 1e-3, 2e-3, 0.5, 0.0])),
    "links_per_segment": mostly(st.integers(0, 12)), "plate_stiffness": mostly(st.floats(-1.0, 50.0)),
}
configs = st.lists(st.sampled_from(sorted(KEYS)), unique=True, max_size=6).flatmap(  # a few settings changed
    lambda names: st.fixed_dictionaries({name: KEYS[name] for name in names})).map(_nested)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(changes=configs)
def test_random_configurations_are_refused_with_config_error_or_run_ready(changes):
    """Every setting the run derives from a configuration that loads is accepted by what uses it:
    the link's and the board's pressure limits (holding 0 hPa), the control timing, the safety
    monitor, the nominal's per-segment values and the emulator's MuJoCo model and steps."""
    try:
        config = HardwareConfig.load(EXAMPLE).with_overrides(changes)
    except ConfigError as exc:
        assert "\n" not in str(exc)
        event("refused: " + str(exc).split(" ")[0])
        return
    event("loaded")
    robot = config.robot_params()
    n = robot.n_segments
    limits = PressureLimits.of(n, robot.u_min, robot.u_max)
    assert all(lo <= 0.0 <= hi for lo, hi in zip(limits.u_min, limits.u_max))
    period = config.control.period_s
    assert config.link.worst_exchange_s < period < config.safety.watchdog_s <= 5.0
    assert config.control.frequency < config.control.control_rate / 2 and config.run.duration / period >= 0
    SafetyMonitor(n, config.safety.hold_s)
    for value in (config.control.amplitude, config.control.phase_rad, config.emulator.q0_rad):
        assert np.all(np.isfinite(per_segment(value, n, "value")))
    assert config.safe_set().n_max > 0
    emu, env = config.emulator, config.environment
    ArmModelConfig(robot=robot, H=env.H, h=env.h, plate_stiffness=emu.plate_stiffness,
                   links_per_segment=emu.links_per_segment, tau_p=emu.tau_p, physics_dt=emu.physics_dt)
    assert steps_per_control(EMULATOR_COMMAND_PERIOD_S, emu.physics_dt) * emu.physics_dt == pytest.approx(
        EMULATOR_COMMAND_PERIOD_S, rel=1e-9)
    assert math.isfinite(config.camera.max_hold_s) and config.camera.max_hold_s > 1.0 / config.camera.frame_rate
