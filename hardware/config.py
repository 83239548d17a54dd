"""The hardware run's configuration: one validated file (TOML or JSON) with every setting.

`HardwareConfig.load(path)` reads a `.toml` (tomllib) or `.json` file whose top level
holds the sections below (every key optional, defaults in the table); unknown sections
or keys, wrong types and out-of-range values raise `ConfigError` naming the key
(`camera.fps`), what was received and the fix. `HardwareConfig.from_dict(data)` does the
same for a mapping; `with_overrides({section: {key: value}})` applies command-line options.

| key                                   | default          | unit   | what                                                            |
|---------------------------------------|------------------|--------|-----------------------------------------------------------------|
| camera.source                         | 0                | –      | OpenCV VideoCapture source (device index, video file, stream URL) or "virtual" (the emulator's MuJoCo camera) |
| camera.calibration                    | none             | –      | PlaneCalibration JSON (tools/calibrate_camera.py); required unless source is "virtual" |
| camera.tag_size_m                     | 0.03             | m      | black square of the AprilTags                                   |
| camera.detector                       | "opencv"         | –      | TagDetector backend: "opencv" or "pupil"                        |
| camera.max_hold_s                     | 0.3              | s      | an estimate older than this is stale (perception.estimator)     |
| camera.qd_filter_tau_s                | 0.0              | s      | first-order low pass of q̇ (0: raw finite differences)           |
| camera.startup_timeout_s              | 5.0              | s      | wait at most this long for the first complete frame             |
| camera.fps                            | 12.8             | 1/s    | virtual camera only: frame rate (docs/ground-truth.md: the hardware's ~12.8) |
| camera.width, camera.height           | 480, 270         | px     | virtual camera only: image size                                 |
| robot.params                          | "reference"      | –      | "reference" (docs/model.md#rppr-dynamics) or a RobotParams JSON (RobotParams.save, tools/calibrate.py) |
| environment.H, environment.h          | [[0.36, 1]], [0.15] | –, m | facets of the free space H r ≤ h (the paper's plate)            |
| environment.stiffness_N_per_m         | 11.16            | N/m    | the controller's ψ(n) = k n                                     |
| environment.f_max_N                   | 0.16             | N      | force limit per facet                                           |
| environment.row_scaling               | "paper"          | –      | P's row scaling ("paper" or "unit")                             |
| pressure.u_min_hPa, pressure.u_max_hPa | the robot's     | hPa    | pressure limits (scalar or one per segment); replace the robot's, so the filter, the laptop's clamp and the board read one value |
| control.filter                        | "paper-cbf"      | –      | the safety filter (controllers.registry): a built-in name, FILE.py:Factory (relative to this file) or package.module:Factory |
| control.filter_params                 | {}               | –      | its parameters, a table {name = value} (`softcbf list` lists them) |
| control.tuning                        | "HW-High"        | –      | paper-cbf's tuning: None, Low, High, HW-Low, HW-High (controllers.cbf), or "custom" with filter_params a_E, b_E, gamma; filter_params.tuning wins |
| control.nominal                       | "sinusoid"       | –      | the nominal controller (controllers.registry), likewise         |
| control.nominal_params                | {}               | –      | its parameters; the sinusoid's default to amplitude_hPa, frequency_hz, phase_rad below |
| control.rate_hz                       | 10.0             | 1/s    | control loop rate (the paper's 10 Hz)                           |
| control.pressure_limits               | true             | –      | the filter's QP holds the pressure box                          |
| control.qp_backend                    | "native"         | –      | controllers.qp backend                                          |
| control.amplitude_hPa                 | 80.0             | hPa    | nominal u_nom,j = A sin(2π f t + φ) (scalar or per segment)      |
| control.frequency_hz                  | 0.01             | 1/s    | its frequency                                                   |
| control.phase_rad                     | 0.0              | rad    | its phase (scalar or per segment)                               |
| safety.hold_s                         | 0.5              | s      | HOLD lasts this long before VENT (closedloop.monitor)              |
| safety.watchdog_s                     | 0.15             | s      | the board's watchdog (the emulated board's; the firmware's own on hardware) |
| link.port                             | "/dev/ttyACM0"   | –      | serial port of the valve board, or "emulated"                   |
| link.baudrate                         | 115200           | baud   | serial line rate                                                |
| link.ack_timeout_s, link.retries, link.lost_after | 0.02, 2, 1 | s, –, – | hardware.link                                              |
| run.duration_s                        | 100.0            | s      | length of the run after the first estimate                      |
| run.dry_run                           | false            | –      | run everything but send zero pressure                           |
| emulator.plate_stiffness_N_per_m      | 11.16            | N/m    | the emulated plate's true spring                                |
| emulator.tau_p_s                      | 0.05             | s      | the emulated valves' first-order time constant (docs/ground-truth.md)        |
| emulator.q0_rad                       | 0.0              | rad    | the emulated arm's initial bend (scalar or per segment)         |
| emulator.links_per_segment            | 5                | –      | rigid links per segment of the MuJoCo rod (simulations: 10)      |
| emulator.physics_dt_s                 | 2e-4             | s      | MuJoCo step (simulations: 1e-4); 5 links at 0.2 ms run ≈ 9× real time, 10 at 0.1 ms ≈ 3× |

Plausibility bounds. A value outside its bound is refused with the unit and the likely
unit mistake in the message ("safety.watchdog_s must be <= 5 s (a plausibility bound;
a time in ms? 150 ms = 0.15 s), got 150"):

| key                                  | bound                | a value beyond it is likely  |
|--------------------------------------|----------------------|------------------------------|
| safety.watchdog_s                    | ≤ 5 s                | milliseconds                 |
| safety.hold_s                        | ≤ 10 s               | milliseconds                 |
| link.ack_timeout_s                   | ≤ 1 s                | milliseconds                 |
| camera.max_hold_s, camera.qd_filter_tau_s | ≤ 10 s          | milliseconds                 |
| camera.startup_timeout_s             | ≤ 600 s              | milliseconds                 |
| camera.tag_size_m                    | ≤ 0.5 m              | millimetres                  |
| control.rate_hz                      | ≤ 1000 1/s           | a period in ms               |
| control.amplitude_hPa, pressure.*    | within ±3276.7 hPa (the protocol's range, `hardware.protocol`) | pascals |
| run.duration_s                       | ≤ 86400 s            | milliseconds                 |
| emulator.tau_p_s                     | ≤ 5 s                | milliseconds                 |
| emulator.physics_dt_s                | 1e-5 … 1e-3 s, dividing the emulated board's 2 ms command period | milliseconds |
| emulator.q0_rad                      | within ±π rad        | degrees                      |

Pressure limits must hold 0 hPa (u_min ≤ 0 ≤ u_max per segment): VENT, the safe action,
sets 0 hPa, and the emulated valves start there.

Files. Relative paths in the file — robot.params, camera.calibration and a camera.source
that is a file (not a device index, "virtual", a URL with "://" or a GStreamer pipeline
with "!") — are relative to the configuration file's folder (`base_dir`), so a
configuration runs the same from any working directory. robot.params and
camera.calibration are read at load (a missing or malformed file is a ConfigError); the
camera and the serial port are opened at start-up (`softcbf.hardware_cli`).

Timing rules checked at load (period T = 1 / control.rate_hz): the link's worst
exchange (1 + retries) · ack_timeout_s must end inside T, so that a safe action sent in
a cycle arrives in that cycle; the board's watchdog must exceed T (or it vents between
commands) and camera.max_hold_s must exceed one frame period of the virtual camera; the
nominal sinusoid's control.frequency_hz must stay below half the control rate;
link.port "emulated" and camera.source "virtual" go together.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from controllers.cbf import get_tuning
from controllers.params import RobotParams, per_segment, reference_robot
from controllers.qp import available_backends
from controllers.safe_set import Environment, ForceSafeSet, LinearStiffness
from hardware.protocol import PRESSURE_RANGE_HPA, PressureLimits
from perception.plane import PlaneCalibration

VIRTUAL_CAMERA = "virtual"
EMULATED_PORT = "emulated"
DETECTORS = ("opencv", "pupil")
ROW_SCALINGS = ("paper", "unit")
Scalars = float | tuple[float, ...]
EMULATOR_COMMAND_PERIOD_S = 2e-3  # s, the emulated board's command resolution (softcbf_mj.emulate)
# The unit mistake a value beyond a plausibility bound most likely is: unit → (wrong unit, factor to the right one).
_LIKELY_MISTAKE = {"s": ("ms", 1e-3), "hPa": ("Pa", 1e-2), "m": ("mm", 1e-3), "rad": ("°", math.pi / 180)}


class ConfigError(ValueError):
    """A configuration value is wrong; the message names the key, the value and the fix."""


def _require(ok: bool, key: str, message: str) -> None:
    if not ok:
        raise ConfigError(f"{key} {message}")


def _number(key: str, value: Any, low: float = -math.inf, *, above: bool = False, high: float | None = None,
            unit: str = "") -> float:
    """A finite real ≥ low (> low with `above`) and, when given, ≤ the plausibility bound `high` (in `unit`)."""
    _require(isinstance(value, (int, float)) and not isinstance(value, bool), key, f"must be a number, got {value!r}")
    _require(math.isfinite(value), key, f"must be finite, got {value!r}")
    _require(value > low if above else value >= low, key,
             f"must be {'>' if above else '>='} {low:g}{' ' + unit if unit else ''}, got {value!r}")
    if high is not None:
        _require(abs(value) <= high if low == -math.inf else value <= high, key,
                 f"must be {'within ±' if low == -math.inf else '<= '}{high:g} {unit} ({_plausibility_hint(value, unit)}), "
                 f"got {value!r}")
    return float(value)


def _plausibility_hint(value: float, unit: str) -> str:
    if unit not in _LIKELY_MISTAKE:
        return "a plausibility bound"
    wrong, factor = _LIKELY_MISTAKE[unit]
    return f"a plausibility bound; a value in {wrong}? {value:g} {wrong} = {value * factor:.4g} {unit}"


def _numbers(key: str, value: Any, *, high: float | None = None, unit: str = "") -> Scalars:
    """A finite number or a list of them (one per segment), each within ±`high` when given."""
    if isinstance(value, (list, tuple)):
        _require(len(value) > 0, key, "must be a number or a non-empty list of numbers, got []")
        return tuple(_number(f"{key}[{i}]", v, high=high, unit=unit) for i, v in enumerate(value))
    return _number(key, value, high=high, unit=unit)


def _choice(key: str, value: Any, valid: tuple[str, ...]) -> str:
    _require(value in valid, key, f"must be one of {', '.join(map(repr, valid))}, got {value!r}")
    return value


def camera_source_is_file(source: int | str) -> bool:
    """Whether a camera source names a file: not a device index, "virtual", a URL ("://") or a GStreamer pipeline ("!")."""
    return isinstance(source, str) and source != VIRTUAL_CAMERA and "://" not in source and "!" not in source


@dataclass(frozen=True)
class CameraConfig:
    source: int | str = 0
    calibration: str | None = None
    tag_size_m: float = 0.03
    detector: str = "opencv"
    max_hold_s: float = 0.3
    qd_filter_tau_s: float = 0.0
    startup_timeout_s: float = 5.0
    fps: float = 12.8
    width: int = 480
    height: int = 270

    def __post_init__(self) -> None:
        ok = (isinstance(self.source, int) and not isinstance(self.source, bool) and self.source >= 0) or (
            isinstance(self.source, str) and self.source != "")
        _require(ok, "camera.source", f'must be a device index >= 0, a video file, a stream URL or "virtual", got {self.source!r}')
        _require(self.calibration is None or (isinstance(self.calibration, str) and self.calibration != ""),
                 "camera.calibration", f"must be the path of a plane calibration JSON, got {self.calibration!r}")
        _require(self.is_virtual or self.calibration is not None, "camera.calibration",
                 "is required for a real camera: fit one with tools/calibrate_camera.py and give its JSON path")
        _number("camera.tag_size_m", self.tag_size_m, 0, above=True, high=0.5, unit="m")
        _choice("camera.detector", self.detector, DETECTORS)
        _number("camera.max_hold_s", self.max_hold_s, 0, above=True, high=10.0, unit="s")
        _number("camera.qd_filter_tau_s", self.qd_filter_tau_s, 0, high=10.0, unit="s")
        _number("camera.startup_timeout_s", self.startup_timeout_s, 0, above=True, high=600.0, unit="s")
        _number("camera.fps", self.fps, 0, above=True, high=1000.0, unit="1/s")
        for name in ("width", "height"):
            value = getattr(self, name)
            _require(isinstance(value, int) and not isinstance(value, bool) and value >= 8, f"camera.{name}",
                     f"must be an integer >= 8 px, got {value!r}")
        if self.is_virtual:
            _require(self.max_hold_s > 1.0 / self.fps, "camera.max_hold_s",
                     f"must exceed one frame period (1/fps = {1.0 / self.fps:.3g} s), got {self.max_hold_s}; "
                     "otherwise every estimate goes stale between frames")

    @property
    def is_virtual(self) -> bool:
        return self.source == VIRTUAL_CAMERA

    @property
    def is_file(self) -> bool:
        """Whether `source` names a file (a relative one is relative to the configuration's folder)."""
        return camera_source_is_file(self.source)


@dataclass(frozen=True)
class RobotConfig:
    params: str = "reference"

    def __post_init__(self) -> None:
        _require(isinstance(self.params, str) and self.params != "", "robot.params",
                 f'must be "reference" or the path of a RobotParams JSON, got {self.params!r}')


@dataclass(frozen=True)
class EnvironmentConfig:
    H: tuple[tuple[float, ...], ...] = ((0.36, 1.0),)
    h: tuple[float, ...] = (0.15,)
    stiffness_N_per_m: float = 11.16
    f_max_N: float = 0.16
    row_scaling: str = "paper"

    def __post_init__(self) -> None:
        try:
            Environment(np.asarray(self.H, dtype=float), np.asarray(self.h, dtype=float))
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"environment.H, environment.h must describe facets H r <= h (H: P rows of 2, h: P values, m): {exc}") from None
        object.__setattr__(self, "H", tuple(tuple(float(v) for v in row) for row in self.H))
        object.__setattr__(self, "h", tuple(float(v) for v in self.h))
        for k, value in enumerate(self.h):
            _require(value > 0, f"environment.h[{k}]", f"must be > 0 m: the arm's base (the origin) must lie inside the free "
                     f"space H r <= h, got {value:g}")
        _number("environment.stiffness_N_per_m", self.stiffness_N_per_m, 0, above=True)
        _number("environment.f_max_N", self.f_max_N, 0, above=True)
        _choice("environment.row_scaling", self.row_scaling, ROW_SCALINGS)


@dataclass(frozen=True)
class PressureConfig:
    u_min_hPa: Scalars | None = None
    u_max_hPa: Scalars | None = None

    def __post_init__(self) -> None:
        for name in ("u_min_hPa", "u_max_hPa"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _numbers(f"pressure.{name}", getattr(self, name), high=PRESSURE_RANGE_HPA,
                                                        unit="hPa"))


@dataclass(frozen=True)
class ControlConfig:
    filter: str = "paper-cbf"
    filter_params: dict = field(default_factory=dict)
    tuning: str = "HW-High"
    rate_hz: float = 10.0
    pressure_limits: bool = True
    qp_backend: str = "native"
    amplitude_hPa: Scalars = 80.0
    frequency_hz: float = 0.01
    phase_rad: Scalars = 0.0
    nominal: str = "sinusoid"
    nominal_params: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        for key in ("filter", "nominal"):
            value = getattr(self, key)
            _require(isinstance(value, str) and value.strip() != "", f"control.{key}",
                     f"must be a name or FILE.py:Factory (softcbf list), got {value!r}")
        for key in ("filter_params", "nominal_params"):
            value = getattr(self, key)
            _require(isinstance(value, Mapping) and all(isinstance(k, str) for k in value), f"control.{key}",
                     f"must be a table of name = value, got {value!r}")
        _require(isinstance(self.tuning, str), "control.tuning", f"must be a tuning name or custom, got {self.tuning!r}")
        if self.filter == "paper-cbf" and self.tuning.strip().lower() != "custom":
            try:
                get_tuning(self.tuning)
            except ValueError as exc:
                raise ConfigError(f"control.tuning: {exc}") from None
        _number("control.rate_hz", self.rate_hz, 0, above=True, high=1000.0, unit="1/s")
        _require(isinstance(self.pressure_limits, bool), "control.pressure_limits", f"must be true or false, got {self.pressure_limits!r}")
        _choice("control.qp_backend", self.qp_backend, tuple(available_backends()))
        object.__setattr__(self, "amplitude_hPa", _numbers("control.amplitude_hPa", self.amplitude_hPa,
                                                           high=PRESSURE_RANGE_HPA, unit="hPa"))
        _number("control.frequency_hz", self.frequency_hz, 0, above=True)
        object.__setattr__(self, "phase_rad", _numbers("control.phase_rad", self.phase_rad))

    @property
    def period_s(self) -> float:
        return 1.0 / self.rate_hz

    def filter_arguments(self) -> dict[str, Any]:
        """The filter's parameters: for paper-cbf, tuning and qp_backend from this section unless filter_params set them."""
        if self.filter == "paper-cbf":
            return {"tuning": self.tuning, "qp_backend": self.qp_backend, **self.filter_params}
        return dict(self.filter_params)

    def nominal_arguments(self) -> dict[str, Any]:
        """The nominal's parameters: for the sinusoid, amplitude, frequency and phase from this section unless set."""
        if self.nominal == "sinusoid":
            return {"amplitude": self.amplitude_hPa, "frequency": self.frequency_hz, "phase": self.phase_rad,
                    **self.nominal_params}
        return dict(self.nominal_params)



@dataclass(frozen=True)
class SafetyConfig:
    hold_s: float = 0.5
    watchdog_s: float = 0.15

    def __post_init__(self) -> None:
        _number("safety.hold_s", self.hold_s, 0, high=10.0, unit="s")
        _number("safety.watchdog_s", self.watchdog_s, 0, above=True, high=5.0, unit="s")


@dataclass(frozen=True)
class LinkConfig:
    port: str = "/dev/ttyACM0"
    baudrate: int = 115200
    ack_timeout_s: float = 0.02
    retries: int = 2
    lost_after: int = 1

    def __post_init__(self) -> None:
        _require(isinstance(self.port, str) and self.port != "", "link.port",
                 f'must be a serial port (e.g. /dev/ttyACM0) or "emulated", got {self.port!r}')
        for name, low in (("baudrate", 1), ("retries", 0), ("lost_after", 1)):
            value = getattr(self, name)
            _require(isinstance(value, int) and not isinstance(value, bool) and value >= low, f"link.{name}",
                     f"must be an integer >= {low}, got {value!r}")
        _number("link.ack_timeout_s", self.ack_timeout_s, 0, above=True, high=1.0, unit="s")

    @property
    def is_emulated(self) -> bool:
        return self.port == EMULATED_PORT

    @property
    def worst_exchange_s(self) -> float:
        return (1 + self.retries) * self.ack_timeout_s


@dataclass(frozen=True)
class RunConfig:
    duration_s: float = 100.0
    dry_run: bool = False

    def __post_init__(self) -> None:
        _number("run.duration_s", self.duration_s, 0, above=True, high=86400.0, unit="s")
        _require(isinstance(self.dry_run, bool), "run.dry_run", f"must be true or false, got {self.dry_run!r}")


@dataclass(frozen=True)
class EmulatorConfig:
    plate_stiffness_N_per_m: float = 11.16
    tau_p_s: float = 0.05
    q0_rad: Scalars = 0.0
    links_per_segment: int = 5
    physics_dt_s: float = 2e-4

    def __post_init__(self) -> None:
        _number("emulator.plate_stiffness_N_per_m", self.plate_stiffness_N_per_m, 0, above=True)
        _number("emulator.tau_p_s", self.tau_p_s, 0, high=5.0, unit="s")
        object.__setattr__(self, "q0_rad", _numbers("emulator.q0_rad", self.q0_rad, high=math.pi, unit="rad"))
        _require(isinstance(self.links_per_segment, int) and not isinstance(self.links_per_segment, bool)
                 and self.links_per_segment >= 1, "emulator.links_per_segment",
                 f"must be an integer >= 1, got {self.links_per_segment!r}")
        _number("emulator.physics_dt_s", self.physics_dt_s, 1e-5, high=1e-3, unit="s")
        ratio = EMULATOR_COMMAND_PERIOD_S / self.physics_dt_s
        _require(abs(ratio - round(ratio)) <= 1e-9 * ratio, "emulator.physics_dt_s",
                 f"must divide the emulated board's command period {EMULATOR_COMMAND_PERIOD_S:g} s into whole steps "
                 f"(e.g. 1e-4, 2e-4, 5e-4, 1e-3 s), got {self.physics_dt_s!r}")


_SECTIONS = {
    "camera": CameraConfig, "robot": RobotConfig, "environment": EnvironmentConfig, "pressure": PressureConfig,
    "control": ControlConfig, "safety": SafetyConfig, "link": LinkConfig, "run": RunConfig, "emulator": EmulatorConfig,
}


def default_values() -> dict[str, Any]:
    """Every key of the configuration, "section.key", with its default (the module table)."""
    out: dict[str, Any] = {}
    for name, cls in _SECTIONS.items():
        for f in dataclasses.fields(cls):
            out[f"{name}.{f.name}"] = f.default_factory() if f.default is dataclasses.MISSING else f.default
    return out


def _section(name: str, data: Any) -> Any:
    cls = _SECTIONS[name]
    _require(isinstance(data, Mapping), f"[{name}]", f"must be a table of keys, got {data!r}")
    valid = [f.name for f in dataclasses.fields(cls)]
    unknown = sorted(set(data) - set(valid))
    _require(not unknown, f"[{name}]", f"has unknown key(s) {unknown}; valid keys: {', '.join(valid)}")
    return cls(**data)


@dataclass(frozen=True)
class HardwareConfig:
    """Every setting of a hardware run (see the module table); `base_dir` resolves relative file paths."""

    camera: CameraConfig = field(default_factory=CameraConfig)
    robot: RobotConfig = field(default_factory=RobotConfig)
    environment: EnvironmentConfig = field(default_factory=EnvironmentConfig)
    pressure: PressureConfig = field(default_factory=PressureConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    safety: SafetyConfig = field(default_factory=SafetyConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    run: RunConfig = field(default_factory=RunConfig)
    emulator: EmulatorConfig = field(default_factory=EmulatorConfig)
    base_dir: Path = Path(".")

    def __post_init__(self) -> None:
        for name, cls in _SECTIONS.items():
            _require(isinstance(getattr(self, name), cls), f"[{name}]", f"must be a {cls.__name__}, got {getattr(self, name)!r}")
        period = self.control.period_s
        _require(self.link.worst_exchange_s < period, "link.ack_timeout_s",
                 f"× (1 + link.retries) = {self.link.worst_exchange_s:g} s must be shorter than the control period "
                 f"{period:g} s, so that a safe action reaches the board in the cycle that sends it; "
                 "lower the timeout or the retries, or the rate")
        _require(self.safety.watchdog_s > period, "safety.watchdog_s",
                 f"must exceed the control period {period:g} s (got {self.safety.watchdog_s:g} s), "
                 "or the board vents between two commands; 1.5 periods is the default")
        _require(self.control.frequency_hz < self.control.rate_hz / 2, "control.frequency_hz",
                 f"must be below half the control rate ({self.control.rate_hz / 2:g} 1/s), got {self.control.frequency_hz:g}")
        _require(self.link.is_emulated == self.camera.is_virtual, "link.port",
                 f'"{EMULATED_PORT}" and camera.source "{VIRTUAL_CAMERA}" go together (the virtual camera renders the '
                 f"emulated arm; a real camera sees the real one), got port {self.link.port!r}, camera {self.camera.source!r}")
        n = self.robot_params().n_segments  # fail at load on a bad robot file or pressure limits
        for key, value in (("control.amplitude_hPa", self.control.amplitude_hPa), ("control.phase_rad", self.control.phase_rad),
                           ("emulator.q0_rad", self.emulator.q0_rad)):
            try:
                per_segment(value, n, key)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
        try:
            self.safe_set()
        except ValueError as exc:
            raise ConfigError(f"environment: {exc}") from None
        self.plane_calibration()  # fail at load on a missing or malformed calibration file

    # -- loading ------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], base_dir: str | Path = ".") -> "HardwareConfig":
        _require(isinstance(data, Mapping), "the configuration", f"must be a table of sections, got {type(data).__name__}")
        unknown = sorted(set(data) - set(_SECTIONS))
        _require(not unknown, "the configuration", f"has unknown section(s) {unknown}; valid: {', '.join(_SECTIONS)}")
        sections = {name: _section(name, data[name]) for name in _SECTIONS if name in data}
        return cls(**sections, base_dir=Path(base_dir))

    @classmethod
    def load(cls, path: str | Path) -> "HardwareConfig":
        """Read a .toml or .json file; relative paths inside it are relative to its folder."""
        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"configuration file {path} does not exist (see examples/hardware_emulated.toml)")
        text = path.read_text(encoding="utf-8")
        try:
            if path.suffix == ".toml":
                data = tomllib.loads(text)
            elif path.suffix == ".json":
                data = json.loads(text)
            else:
                raise ConfigError(f"configuration file {path} must end in .toml or .json, got {path.suffix!r}")
        except (tomllib.TOMLDecodeError, json.JSONDecodeError) as exc:
            raise ConfigError(f"{path} is not valid {path.suffix[1:].upper()}: {exc}") from None
        return cls.from_dict(data, path.parent)

    def with_overrides(self, changes: Mapping[str, Mapping[str, Any]]) -> "HardwareConfig":
        """A copy with fields changed, {section: {key: value}} (command-line options), validated again."""
        sections = {}
        for section, fields in changes.items():
            if section not in _SECTIONS:
                raise ConfigError(f"unknown section {section!r}; valid: {', '.join(_SECTIONS)}")
            sections[section] = _section(section, {**dataclasses.asdict(getattr(self, section)), **fields})
        return dataclasses.replace(self, **sections)

    def to_dict(self) -> dict[str, Any]:
        """The sections as plain data (for config.json of the run folder)."""
        return {name: dataclasses.asdict(getattr(self, name)) for name in _SECTIONS}

    def plugin_spec(self, spec: str) -> str:
        """A filter or nominal spec with its FILE.py made relative to this file's folder (names unchanged)."""
        where, sep, name = spec.rpartition(":")
        if sep and where.endswith(".py"):
            return f"{self.resolve(where)}:{name}"
        return spec

    def resolve(self, path: str) -> Path:
        """`path` relative to the configuration file's folder (unchanged when absolute)."""
        p = Path(path)
        return p if p.is_absolute() else self.base_dir / p

    def camera_source(self) -> int | str:
        """camera.source for `cv2.VideoCapture`: a file resolved against the configuration's folder, else as given."""
        source = self.camera.source
        return str(self.resolve(source)) if self.camera.is_file else source

    def plane_calibration(self) -> PlaneCalibration | None:
        """The camera.calibration file's image → plane map (None when none is configured)."""
        if self.camera.calibration is None:
            return None
        path = self.resolve(self.camera.calibration)
        if not path.is_file():
            raise ConfigError(f"camera.calibration must be a plane calibration JSON file, got {self.camera.calibration!r} "
                              f"(no file {path}; relative paths are relative to the configuration's folder)")
        try:
            return PlaneCalibration.load(path)
        except (ValueError, KeyError, TypeError, OSError) as exc:
            raise ConfigError(f"camera.calibration {path}: {type(exc).__name__}: {exc}".splitlines()[0]) from None

    # -- the objects the run needs --------------------------------------------------

    def robot_params(self) -> RobotParams:
        """The controller's robot with the configured pressure limits (their one source of truth)."""
        spec = self.robot.params
        if spec == "reference":
            robot = reference_robot()
        else:
            path = self.resolve(spec)
            if not path.is_file():
                raise ConfigError(f'robot.params must be "reference" or a RobotParams JSON file, got {spec!r} (no file {path})')
            try:
                robot = RobotParams.load(path)
            except (ValueError, KeyError) as exc:
                raise ConfigError(f"robot.params {path}: {exc}") from None
        n, changes = robot.n_segments, {}
        for name, key in (("u_min", "u_min_hPa"), ("u_max", "u_max_hPa")):
            value = getattr(self.pressure, key)
            if value is not None:
                try:
                    changes[name] = tuple(per_segment(value, n, f"pressure.{key}"))
                except ValueError as exc:
                    raise ConfigError(str(exc)) from None
        try:
            robot = robot.replace(**changes) if changes else robot
            PressureLimits.of(n, robot.u_min, robot.u_max)  # the link's and the board's limits
        except ValueError as exc:
            raise ConfigError(f"pressure limits: {exc}") from None
        for i, (low, high) in enumerate(zip(robot.u_min, robot.u_max)):
            _require(low <= 0.0 <= high, "pressure limits",
                     f"must hold 0 hPa, the vented state the safe action VENT sets, for every segment: got u_min={low:g}, "
                     f"u_max={high:g} hPa for segment {i} (pressure.u_min_hPa, pressure.u_max_hPa or the robot's)")
        return robot

    def safe_set(self) -> ForceSafeSet:
        env = self.environment
        return ForceSafeSet(Environment(np.array(env.H), np.array(env.h)), LinearStiffness(env.stiffness_N_per_m),
                            env.f_max_N, row_scaling=env.row_scaling)
