"""The hardware configuration file (hardware/config.py) and the controller identity of the hardware path."""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

from controllers.model.params import reference_robot
from hardware.config import ConfigError, HardwareConfig
from perception.plane import PlaneCalibration

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "hardware_emulated.toml"


def test_example_loads_and_builds_the_robot_safe_set_and_limits():
    config = HardwareConfig.load(EXAMPLE)
    assert config.link.is_emulated and config.camera.is_virtual
    assert (config.control.tuning, config.control.control_rate, config.control.period_s) == ("High", 10.0, 0.1)
    robot = config.robot_params()
    ref = reference_robot()
    assert robot.damping == pytest.approx(tuple(20 * d for d in ref.damping), rel=1e-9)
    assert robot.stiffness == ref.stiffness and robot.u_min == (-150.0, -150.0) and robot.u_max == (150.0, 150.0)
    safe_set = config.safe_set()
    assert safe_set.f_max == 0.16 and safe_set.n_max == pytest.approx(0.16 / 11.16, rel=1e-12)


def test_json_and_toml_give_the_same_config_and_limits_replace_the_robots(tmp_path):
    data = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))
    data["robot"] = str(EXAMPLE.parent / data["robot"])
    data["pressure"] = {"u_min_hPa": [-100.0, -120.0], "u_max_hPa": 90.0}
    path = tmp_path / "hw.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    config = HardwareConfig.load(path)
    assert config.robot_params().u_min == (-100.0, -120.0) and config.robot_params().u_max == (90.0, 90.0)
    example = HardwareConfig.load(EXAMPLE).to_dict()
    assert {k: v for k, v in config.to_dict().items() if k not in ("robot", "pressure")} == \
        {k: v for k, v in example.items() if k not in ("robot", "pressure")}
    assert HardwareConfig.from_dict(json.loads(json.dumps(example)), EXAMPLE.parent).to_dict() == example  # config.json reads back


def test_defaults_need_a_calibration_for_a_real_camera(tmp_path):
    with pytest.raises(ConfigError, match=r"calibration is required for a real camera: fit one with tools/calibrate_camera.py"):
        HardwareConfig()
    PlaneCalibration(np.eye(3)).save(tmp_path / "cal.json")
    config = HardwareConfig.from_dict({"calibration": "cal.json", "camera": {"source": 2}}, tmp_path)
    assert config.camera.source == 2 and config.link.port == "/dev/ttyACM0" and config.control.tuning == "HW-High"


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"frame_rate": -1}, r"frame_rate must be > 0 Hz, got -1.0"),
        ({"camera": {"frame_rate": 12.8}}, r"\[camera\] holds \['frame_rate'\]: settings shared with the simulations are top-level"),
        ({"camera": {"zoom": 2}}, r"\[camera\] has unknown key\(s\) \['zoom'\]; valid keys: source, tag_size_m, startup_timeout_s"),
        ({"cameras": {}}, r"unknown key\(s\) or section\(s\) \['cameras'\]"),
        ({"control": {"tuning": "Bogus"}}, r"control.tuning: unknown tuning 'Bogus'; valid: None, Low, High"),
        ({"control_rate": 20.0, "link": {"ack_timeout_s": 0.02, "retries": 2}},
         r"link.ack_timeout_s × \(1 \+ link.retries\) = 0.06 s must be shorter than the control period 0.05 s"),
        ({"safety": {"watchdog_s": 0.1}}, r"safety.watchdog_s must exceed the control period 0.1 s \(got 0.1 s\)"),
        ({"link": {"port": "/dev/ttyUSB0"}}, r'link.port "emulated" and camera.source "virtual" go together'),
        ({"pressure": {"u_min_hPa": 10.0, "u_max_hPa": 5.0}}, r"pressure limits: u_min\[0\] must be < u_max\[0\]"),
        ({"pressure": {"u_min_hPa": [1.0, 2.0, 3.0]}}, r"pressure.u_min_hPa must be a scalar or have 2 values"),
        ({"environment": {"h": [0.1, 0.2]}}, r"environment.H, environment.h must describe facets"),
        ({"robot": "missing.json"}, r"robot must be \"reference\" or a RobotParams JSON file, got 'missing.json'"),
        ({"max_hold_s": 0.05}, r"max_hold_s must exceed one frame period"),
        ({"run": {"dry_run": "yes"}}, r"run.dry_run must be true or false, got 'yes'"),
        ({"link": {"retries": 1.5}}, r"link.retries must be an integer >= 0, got 1.5"),
    ],
)
def test_bad_values_name_the_key_the_value_and_the_fix(changes, message):
    with pytest.raises(ConfigError, match=message):
        HardwareConfig.load(EXAMPLE).with_overrides(changes) if "cameras" not in changes else HardwareConfig.from_dict(changes)


def test_bad_files_are_refused(tmp_path):
    with pytest.raises(ConfigError, match=r"does not exist \(see examples/hardware_emulated.toml\)"):
        HardwareConfig.load(tmp_path / "none.toml")
    (tmp_path / "c.yaml").write_text("a: 1", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"must end in .toml or .json, got '.yaml'"):
        HardwareConfig.load(tmp_path / "c.yaml")
    (tmp_path / "c.toml").write_text("[camera\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"is not valid TOML"):
        HardwareConfig.load(tmp_path / "c.toml")


def test_hardware_path_runs_the_simulations_controller_module_without_mujoco():
    """hardware.*, perception.* and the CLI of a real run import no MuJoCo; the runner builds its filter with the scenarios' registry."""
    code = (
        "import sys, hardware.config, hardware.runner, hardware.board, hardware.link, hardware.transport, closedloop.monitor, "
        "perception.capture, perception.detect, perception.estimator, perception.plane, controllers.cbf.paper_filter, controllers.registry\n"
        "assert hardware.runner.build_filter is controllers.registry.build_filter\n"
        "bad = sorted(m for m in sys.modules if m == 'mujoco' or m.startswith(('mujoco.', 'softcbf_mj')))\n"
        "import softcbf.hardware_cli\n"
        "print(repr((bad, 'mujoco' in sys.modules, controllers.cbf.paper_filter.__file__)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True).stdout
    bad, mujoco_after_cli, filter_file = eval(out)
    assert bad == [] and mujoco_after_cli is False
    import controllers.cbf.paper_filter
    import controllers.registry
    import scenarios.common

    assert Path(filter_file) == Path(controllers.cbf.paper_filter.__file__)
    assert scenarios.common.build_filter is controllers.registry.build_filter


def test_cli_refuses_a_bad_configuration_with_exit_code_2(tmp_path, capsys):
    from softcbf.hardware_cli import main

    assert main([str(EXAMPLE), "--tuning", "Bogus", "--out", str(tmp_path / "out")]) == 2
    assert "control.tuning: unknown tuning 'Bogus'" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_emulator_defaults_are_the_camera_scenarios_rod():
    from hardware.config import EmulatorConfig
    from softcbf_mj.physics.mjcf import CAMERA_LINKS_PER_SEGMENT, CAMERA_PHYSICS_DT

    assert (EmulatorConfig().links_per_segment, EmulatorConfig().physics_dt) == (CAMERA_LINKS_PER_SEGMENT, CAMERA_PHYSICS_DT)


def test_the_robot_safe_set_and_calibration_are_read_once_at_load(tmp_path):
    """Parse once (issue 25): the files are read and the objects built when the configuration is loaded; the run
    takes those objects (a file changed or removed afterwards changes nothing), and a changed copy builds its own."""
    data = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))
    robot_file = tmp_path / "robot.json"
    robot_file.write_bytes((EXAMPLE.parent / data["robot"]).read_bytes())
    data["robot"] = "robot.json"
    path = tmp_path / "hw.json"
    path.write_text(json.dumps(data), encoding="utf-8")
    config = HardwareConfig.load(path)
    robot, safe_set = config.robot_params(), config.safe_set()
    robot_file.unlink()
    assert config.robot_params() is robot and config.safe_set() is safe_set and config.plane_calibration() is None
    with pytest.raises(ConfigError, match="no file"):  # a copy checks (and reads) again
        config.with_overrides({"f_max": 0.2})
    robot_file.write_bytes((EXAMPLE.parent / tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))["robot"]).read_bytes())
    changed = config.with_overrides({"f_max": 0.2})
    assert changed.safe_set().f_max == 0.2 and safe_set.f_max == 0.16 and changed.robot_params() == robot
