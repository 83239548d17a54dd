"""The whole hardware without hardware: emulated valve board on a pty, MuJoCo arm and plate, virtual camera.

`EmulatedHardware(config)` builds, from a `hardware.config.HardwareConfig`:

- the true arm and plates: `MujocoPlant` (2 ms command period) of the ground truth that
  `emulated_truth` builds with the simulations' one builder (`softcbf_mj.physics.ground_truth.build_truth`)
  from the hardware file's ground-truth settings (every one of them, `config.emulator`: the
  true_* scales and true_robot, facet_offset and facet_angle, gravity, friction, tau_p, the plate
  or the flexure sheet, ...), for `config.robot_params()` — the controller's robot, its pressure
  limits as the actuators' ctrlrange — and `config.environment`'s facets; at rest at
  `emulator.q0_rad`. Its rod: `links_per_segment` links per segment stepped at `physics_dt`,
  chosen for real time (the hardware file's defaults: 5 links at 0.2 ms run ≈ 9× real time here
  against ≈ 3× for the simulations' 10 at 0.1 ms, and hold (120, 120) hPa against the plate for
  1 s with a plate force 0.3 % below theirs, 0.5146 vs 0.5162 N);
- `ValveEmulator` running that plant in real time as the board's plant hook;
- `ValveBoard` (the firmware logic: clamp to the same limits, watchdog
  `safety.watchdog_s`) behind a `PtyBoardLine`: `port_name` is a pseudo-terminal the
  laptop side opens with pyserial, exactly as a USB serial port; `line.faults` injects
  link faults (`LineFaults.cut()`);
- `VirtualCamera` rendering the arm at `frame_rate`, `width` × `height`
  (`camera.blackout` covers the lens), with its exact plane calibration.

Everything runs on one monotonic clock (`time.monotonic` by default). Use it as a context
manager (or call `close()`): it stops the board thread, the plant thread and the camera.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Callable

from controllers.model.params import per_segment
from hardware.board import ValveBoard
from hardware.config import EMULATOR_COMMAND_PERIOD_S, HardwareConfig
from hardware.transport import PtyBoardLine
from perception.plane import PlaneCalibration
from softcbf_mj.physics.ground_truth import ROBOT_PRESETS, Truth, build_truth
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.emulator.valve_emulator import ValveEmulator
from softcbf_mj.emulator.virtual_camera import VirtualCamera
from vocabulary.run_sections import ground_truth_values
from vocabulary.settings import default

CONTROL_DT = EMULATOR_COMMAND_PERIOD_S  # s, the emulator's command resolution (board outputs act from the next 2 ms step)


def emulated_truth(config: HardwareConfig) -> Truth:
    """The emulator's ground truth (module docstring): `config.emulator`'s ground-truth settings, a `true_robot` file
    relative to the configuration's folder, built for the controller's robot and facets."""
    arm, plate = ground_truth_values(config.emulator)
    if arm.robot not in ("", "reference", *ROBOT_PRESETS):
        arm = dataclasses.replace(arm, robot=str(config.resolve(arm.robot)))
    return build_truth(arm, plate, config.robot_params(), config.safe_set().environment,
                       default("damping_scale", "hardware"))


class EmulatedHardware:
    """Emulated board + arm + camera for `config` (see the module docstring)."""

    def __init__(self, config: HardwareConfig, clock: Callable[[], float] = time.monotonic) -> None:
        robot = config.robot_params()
        plant = MujocoPlant.from_config(emulated_truth(config).config, CONTROL_DT)
        plant.reset(per_segment(config.emulator.q0_rad, plant.n_segments, "emulator.q0_rad"))
        self.config = config
        self.emulator = ValveEmulator(plant, clock)
        self.board = ValveBoard(plant.n_segments, robot.u_min, robot.u_max, watchdog_s=config.safety.watchdog_s,
                                plant_hook=self.emulator)
        self.camera = VirtualCamera(self.emulator, config.camera.frame_rate, config.camera.width, config.camera.height)
        self.emulator.start()
        self.line = PtyBoardLine(self.board, clock=clock)

    @property
    def port_name(self) -> str:
        return self.line.port_name

    def calibration(self) -> PlaneCalibration:
        return self.camera.calibration()

    def close(self) -> None:
        try:
            self.line.close()
        finally:
            self.camera.close()
            self.emulator.close()

    def __enter__(self) -> "EmulatedHardware":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
