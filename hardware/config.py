"""The hardware run's configuration: one validated file (TOML or JSON) with every setting.

One vocabulary. A setting the hardware run shares with the simulations has the name it
has everywhere (`vocabulary.settings`: the command line's `--f-max`, a run configuration's
`f_max`, a study's `fixed.f_max`) and sits at the top level of the file, with the same
unit, range and check (`vocabulary.settings.check_value`: "f_max must be > 0 N, got -1.0"):

    f_max = 0.16                 # N
    control_rate = 10.0          # Hz
    filter = "paper-cbf"
    duration = 60.0              # s
    [filter_params]
    slack_weight = 1e4

The emulator's ground truth takes every ground-truth setting of the vocabulary by its name
(`vocabulary.settings.ground_truth_settings`: the section `[emulator]` composes them), and the
emulator builds it with the simulations' one builder (`softcbf_mj.physics.ground_truth.build_truth`), so a
new ground-truth setting is a key of this file with no edit here.

Settings only the hardware run has stay in their sections (`[camera] source`, `[link]`,
`[safety] watchdog_s`, `[environment] H, h`, `[pressure]`, `[emulator] q0_rad`, ...).
Each section is a frozen dataclass made by `vocabulary.sections.setting_section` (the
machinery of the scenarios' sections): its shared settings are declared by name, their
type, default (`default(name, "hardware")`) and check come from the vocabulary, and its
hardware-only keys and rules are its own. `HardwareConfig.load(path)` reads a `.toml` or `.json` file (`vocabulary.files`);
`from_dict(data)` a mapping of the same shape; `with_overrides(changes)` applies changes of
that shape (command-line options); `to_dict()` gives it back (config.json of the run
folder, loadable again). Unknown keys, wrong types and out-of-range values raise
`ConfigError` naming the key, what was received and the fix.

Shared settings (top level; meaning, unit and range: docs/parameters.md):

| key                     | default          | unit   | hardware notes                                                  |
|-------------------------|------------------|--------|-----------------------------------------------------------------|
| robot                   | "reference"      | –      | "reference" (docs/model.md#rppr-dynamics) or a RobotParams JSON (RobotParams.save, tools/calibrate.py) |
| assumed_plate_stiffness | 11.16            | N/m    | the controller's ψ(n) = k n                                     |
| f_max                   | 0.16             | N      | force limit per facet                                           |
| row_scaling             | "paper"          | –      | P's row scaling ("paper" or "unit")                             |
| filter                  | "paper-cbf"      | –      | the safety filter (controllers.registry): a built-in name, a preset ("c-erg:recommended"), FILE.py:Factory (relative to this file) or package.module:Factory |
| filter_params           | {}               | –      | its parameters, a table {name = value} typed by the filter's declarations, over a preset's (`softcbf list` lists them) |
| nominal                 | "sinusoid"       | –      | the nominal controller (controllers.registry), likewise         |
| nominal_params          | {}               | –      | its parameters; the sinusoid's default to amplitude, frequency, control.phase_rad |
| control_rate            | 10.0             | Hz     | control loop rate (the paper's 10 Hz)                           |
| pressure_limits         | true             | –      | the filter's QP holds the pressure box                          |
| qp_backend              | "native"         | –      | controllers.cbf.qp backend                                          |
| amplitude               | 80.0             | hPa    | nominal u_nom,j = A sin(2π f t + φ) (scalar or per segment)     |
| frequency               | 0.01             | Hz     | its frequency                                                   |
| calibration             | none             | –      | PlaneCalibration JSON (tools/calibrate_camera.py); required unless camera.source is "virtual" |
| detector                | "opencv"         | –      | TagDetector backend: "opencv" or "pupil"                        |
| max_hold_s              | 0.3              | s      | an estimate older than this is stale (perception.estimator)     |
| qd_filter_tau           | 0.0              | s      | first-order low pass of q̇ (0: raw finite differences)           |
| frame_rate              | 12.8             | Hz     | virtual camera only: frame rate (docs/ground-truth.md: the hardware's ~12.8) |
| width, height           | 480, 270         | px     | virtual camera only: image size                                 |
| hold_s                  | 0.5              | s      | HOLD lasts this long before VENT (closedloop.monitor)           |
| duration                | 100.0            | s      | length of the run after the first estimate                      |
| plate_stiffness         | 11.16            | N/m    | emulator only: the emulated plate's true spring                 |
| tau_p                   | 0.05             | s      | emulator only: the valves' first-order time constant (docs/ground-truth.md) |
| links_per_segment       | 5                | –      | emulator only: rigid links per segment of the MuJoCo rod (simulations: 10) |
| physics_dt              | 2e-4             | s      | emulator only: MuJoCo step (simulations: 1e-4); 5 links at 0.2 ms run ≈ 9× real time, 10 at 0.1 ms ≈ 3× |
| every other ground-truth setting | the vocabulary's | – | emulator only: true_robot (relative to this file), the true_* scales, facet_offset, facet_angle, gravity, tip_friction, table_friction, plate and the sheet_* settings (`vocabulary.settings.ground_truth_settings`), as in the simulations |

Hardware-only settings (in their sections):

| key                                   | default          | unit   | what                                                            |
|---------------------------------------|------------------|--------|-----------------------------------------------------------------|
| camera.source                         | 0                | –      | OpenCV VideoCapture source (device index, video file, stream URL) or "virtual" (the emulator's MuJoCo camera) |
| camera.tag_size_m                     | 0.03             | m      | black square of the AprilTags                                   |
| camera.startup_timeout_s              | 5.0              | s      | wait at most this long for the first complete frame             |
| environment.H, environment.h          | [[0.36, 1]], [0.15] | –, m | facets of the free space H r ≤ h (the paper's plate)            |
| pressure.u_min_hPa, pressure.u_max_hPa | the robot's     | hPa    | pressure limits (scalar or one per segment); replace the robot's, so the filter, the laptop's clamp and the board read one value |
| control.tuning                        | "HW-High"        | –      | paper-cbf's tuning: None, Low, High, HW-Low, HW-High (controllers.cbf.barrier), or "custom" with filter_params a_E, b_E, gamma; filter_params.tuning wins |
| control.phase_rad                     | 0.0              | rad    | the nominal sinusoid's phase (scalar or per segment)            |
| safety.watchdog_s                     | 0.15             | s      | the board's watchdog (the emulated board's; the firmware's own on hardware) |
| link.port                             | "/dev/ttyACM0"   | –      | serial port of the valve board, or "emulated"                   |
| link.baudrate                         | 115200           | baud   | serial line rate                                                |
| link.ack_timeout_s, link.retries, link.lost_after | 0.02, 2, 1 | s, –, – | hardware.link                                              |
| run.dry_run                           | false            | –      | run everything but send zero pressure                           |
| emulator.q0_rad                       | 0.0              | rad    | the emulated arm's initial bend (scalar or per segment)         |

Former spellings. A file written before the one vocabulary (`environment.f_max_N`,
`control.rate_hz`, `camera.fps`, `run.duration_s`, ...: `LEGACY_KEYS`, the one table that
knows them) still loads, to the same configuration, with one warning line on stderr that
names the new keys; a setting given in both spellings is refused.

Plausibility bounds. A value beyond its bound is refused with the unit and the likely
unit mistake in the message ("safety.watchdog_s must be <= 5 s (a plausibility bound;
a value in ms? 150 ms = 0.15 s), got 150.0"): the shared settings' bounds are the
vocabulary's (duration <= 86400 s, tau_p <= 5 s, hold_s, max_hold_s, qd_filter_tau <= 10 s,
physics_dt <= 1e-3 s, control_rate <= 1e4 Hz, frame_rate <= 1000 Hz, amplitude within
±3276.7 hPa, the protocol's range); the hardware-only ones:

| key                                  | bound                | a value beyond it is likely  |
|--------------------------------------|----------------------|------------------------------|
| safety.watchdog_s                    | ≤ 5 s                | milliseconds                 |
| link.ack_timeout_s                   | ≤ 1 s                | milliseconds                 |
| camera.startup_timeout_s             | ≤ 600 s              | milliseconds                 |
| camera.tag_size_m                    | ≤ 0.5 m              | millimetres                  |
| pressure.*                           | within ±3276.7 hPa (the protocol's range, `hardware.protocol`) | pascals |
| emulator.q0_rad                      | within ±π rad        | degrees                      |
| environment.h[k] / ‖H[k]‖ (a facet's distance from the base) | ≤ 10 m | millimetres      |

width and height of the virtual camera are at most its render's framebuffer, the
vocabulary's declared width × height (1280 × 720 px, as the camera_loop scenario's bound).

Pressure limits must hold 0 hPa (u_min ≤ 0 ≤ u_max per segment): VENT, the safe action,
sets 0 hPa, and the emulated valves start there. physics_dt must divide the emulated
board's 2 ms command period.

Files. Relative paths in the file — robot, calibration and a camera.source that is a file
(not a device index, "virtual", a URL with "://" or a GStreamer pipeline with "!") — are
relative to the configuration file's folder (`base_dir`), so a configuration runs the same
from any working directory. robot and calibration are read, and the force-safe set built,
once, at load (a missing or malformed file is a ConfigError); `robot_params()`, `safe_set()`
and `plane_calibration()` hand out those objects (a changed copy, `with_overrides`, loads its own); the camera and the serial port are opened at start-up
(`softcbf.hardware_cli`).

Timing rules checked at load (period T = 1 / control_rate): the link's worst exchange
(1 + retries) · ack_timeout_s must end inside T, so that a safe action sent in a cycle
arrives in that cycle; the board's watchdog must exceed T (or it vents between commands)
and max_hold_s must exceed one frame period of the virtual camera; the nominal
sinusoid's frequency must stay below half the control rate; link.port "emulated" and
camera.source "virtual" go together.
"""

from __future__ import annotations

import dataclasses
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from controllers.cbf.barrier import get_tuning
from controllers.model.params import RobotParams, per_segment, reference_robot
from controllers.cbf.qp import available_backends
from controllers.contract.filter_parameters import Params, read_params
from controllers.registry import is_builtin, spec_file, typed_params
from controllers.model.safe_set import Environment, ForceSafeSet, LinearStiffness
from hardware.protocol import PRESSURE_RANGE_HPA, PressureLimits
from perception.plane import PlaneCalibration
from vocabulary.files import read_settings_file
from vocabulary.sections import setting_fields, setting_section
from vocabulary.settings import Bound, SettingError, check_number, ground_truth_settings, positive, setting

VIRTUAL_CAMERA = "virtual"
EMULATED_PORT = "emulated"
DETECTORS = ("opencv", "pupil")
ROW_SCALINGS = ("paper", "unit")
Scalars = float | tuple[float, ...]
EMULATOR_COMMAND_PERIOD_S = 2e-3  # s, the emulated board's command resolution (softcbf_mj.emulator.emulate)
NOUN = "hardware configuration"
MAX_FACET_DISTANCE_M = 10.0  # a facet's distance from the base, h_k / |H_k| (module docstring: plausibility bounds)

LEGACY_KEYS: dict[str, str] = {
    "robot.params": "robot",
    "environment.stiffness_N_per_m": "assumed_plate_stiffness",
    "environment.f_max_N": "f_max",
    "environment.row_scaling": "row_scaling",
    "control.filter": "filter",
    "control.filter_params": "filter_params",
    "control.nominal": "nominal",
    "control.nominal_params": "nominal_params",
    "control.rate_hz": "control_rate",
    "control.pressure_limits": "pressure_limits",
    "control.qp_backend": "qp_backend",
    "control.amplitude_hPa": "amplitude",
    "control.frequency_hz": "frequency",
    "camera.calibration": "calibration",
    "camera.detector": "detector",
    "camera.max_hold_s": "max_hold_s",
    "camera.qd_filter_tau_s": "qd_filter_tau",
    "camera.fps": "frame_rate",
    "camera.width": "width",
    "camera.height": "height",
    "safety.hold_s": "hold_s",
    "run.duration_s": "duration",
    "emulator.plate_stiffness_N_per_m": "plate_stiffness",
    "emulator.tau_p_s": "tau_p",
    "emulator.links_per_segment": "links_per_segment",
    "emulator.physics_dt_s": "physics_dt",
}
"""A former spelling, "section.key", → the setting's name (module docstring: Former spellings)."""


class ConfigError(ValueError):
    """A configuration value is wrong; the message names the key, the value and the fix."""


def _require(ok: bool, key: str, message: str) -> None:
    if not ok:
        raise ConfigError(f"{key} {message}")


def _number(key: str, value: Any, bound: Bound, plausible: float | None = None, unit: str = "") -> float:
    """A hardware-only number checked like a setting (`vocabulary.settings.check_number`)."""
    try:
        return float(check_number(key, value, bound, plausible=plausible, unit=unit))
    except SettingError as exc:
        raise ConfigError(str(exc)) from None


def _numbers(key: str, value: Any, plausible: float | None = None, unit: str = "") -> Scalars:
    """A finite number or a non-empty list of them (one per segment), each within ±`plausible` when given."""
    if isinstance(value, (list, tuple)):
        _require(len(value) > 0, key, "must be a number or a non-empty list of numbers, got []")
        return tuple(_number(f"{key}[{i}]", v, Bound(), plausible, unit) for i, v in enumerate(value))
    return _number(key, value, Bound(), plausible, unit)


def _choice(key: str, value: Any, valid: tuple[str, ...]) -> str:
    _require(value in valid, key, f"must be one of {', '.join(map(repr, valid))}, got {value!r}")
    return value


def camera_source_is_file(source: int | str) -> bool:
    """Whether a camera source names a file: not a device index, "virtual", a URL ("://") or a GStreamer pipeline ("!")."""
    return isinstance(source, str) and source != VIRTUAL_CAMERA and "://" not in source and "!" not in source


def _hardware_section(*names: str, per_segment: tuple[str, ...] = (), tables: tuple[str, ...] = ()) -> Any:
    """A hardware section (`vocabulary.sections.setting_section`) whose shared settings `names` (field = setting)
    follow its own fields, with the hardware file's defaults and ConfigError."""
    return setting_section(settings={name: name for name in names}, context="hardware", per_segment=per_segment,
                           tables=tables, error=ConfigError)


@_hardware_section("calibration", "detector", "max_hold_s", "qd_filter_tau", "frame_rate", "width", "height")
class CameraConfig:
    source: int | str = 0
    tag_size_m: float = 0.03
    startup_timeout_s: float = 5.0

    def check(self) -> None:
        ok = (isinstance(self.source, int) and not isinstance(self.source, bool) and self.source >= 0) or (
            isinstance(self.source, str) and self.source != "")
        _require(ok, "camera.source", f'must be a device index >= 0, a video file, a stream URL or "virtual", got {self.source!r}')
        _require(self.calibration is None or self.calibration != "",
                 "calibration", f"must be the path of a plane calibration JSON, got {self.calibration!r}")
        _require(self.is_virtual or self.calibration is not None, "calibration",
                 "is required for a real camera: fit one with tools/calibrate_camera.py and give its JSON path")
        _number("camera.tag_size_m", self.tag_size_m, positive("m"), 0.5, "m")
        _choice("detector", self.detector, DETECTORS)
        _number("camera.startup_timeout_s", self.startup_timeout_s, positive("s"), 600.0, "s")
        if self.is_virtual:
            for key in ("width", "height"):
                most = setting(key).default  # the virtual camera's framebuffer (module docstring)
                _require(getattr(self, key) <= most, key, f"must be <= {most} px for the virtual camera (its render's "
                         f"framebuffer), got {getattr(self, key)}")
            _require(self.max_hold_s > 1.0 / self.frame_rate, "max_hold_s",
                     f"must exceed one frame period (1/frame_rate = {1.0 / self.frame_rate:.3g} s), got {self.max_hold_s}; "
                     "otherwise every estimate goes stale between frames")

    @property
    def is_virtual(self) -> bool:
        return self.source == VIRTUAL_CAMERA

    @property
    def is_file(self) -> bool:
        """Whether `source` names a file (a relative one is relative to the configuration's folder)."""
        return camera_source_is_file(self.source)


@_hardware_section("robot")
class RobotConfig:
    def check(self) -> None:
        _require(self.robot != "", "robot", f'must be "reference" or the path of a RobotParams JSON, got {self.robot!r}')


@_hardware_section("assumed_plate_stiffness", "f_max", "row_scaling")
class EnvironmentConfig:
    H: tuple[tuple[float, ...], ...] = ((0.36, 1.0),)
    h: tuple[float, ...] = (0.15,)

    def check(self) -> None:
        try:
            Environment(np.asarray(self.H, dtype=float), np.asarray(self.h, dtype=float))
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"environment.H, environment.h must describe facets H r <= h (H: P rows of 2, h: P values, m): {exc}") from None
        object.__setattr__(self, "H", tuple(tuple(float(v) for v in row) for row in self.H))
        object.__setattr__(self, "h", tuple(float(v) for v in self.h))
        for k, value in enumerate(self.h):
            _require(value > 0, f"environment.h[{k}]", f"must be > 0 m: the arm's base (the origin) must lie inside the free "
                     f"space H r <= h, got {value:g}")
            distance = value / math.hypot(*self.H[k])
            _require(distance <= MAX_FACET_DISTANCE_M, f"environment.h[{k}]",
                     f"must put facet {k} within {MAX_FACET_DISTANCE_M:g} m of the arm's base (h[{k}] / |H[{k}]| <= "
                     f"{MAX_FACET_DISTANCE_M:g} m; a value in millimetres?), got {distance:g} m")
        _choice("row_scaling", self.row_scaling, ROW_SCALINGS)


@dataclass(frozen=True)
class PressureConfig:
    u_min_hPa: Scalars | None = None
    u_max_hPa: Scalars | None = None

    def __post_init__(self) -> None:
        for name in ("u_min_hPa", "u_max_hPa"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, _numbers(f"pressure.{name}", getattr(self, name), PRESSURE_RANGE_HPA, "hPa"))


@_hardware_section("filter", "filter_params", "control_rate", "pressure_limits", "qp_backend", "amplitude", "frequency",
                   "nominal", "nominal_params", per_segment=("amplitude",), tables=("filter_params", "nominal_params"))
class ControlConfig:
    tuning: str = "HW-High"
    phase_rad: Scalars = 0.0

    def check(self) -> None:
        for key in ("filter", "nominal"):
            _require(getattr(self, key).strip() != "", key, f"must be a name or FILE.py:Factory (softcbf list), got {getattr(self, key)!r}")
        _require(isinstance(self.tuning, str), "control.tuning", f"must be a tuning name or custom, got {self.tuning!r}")
        if self.filter == "paper-cbf" and self.tuning.strip().lower() != "custom":
            try:
                get_tuning(self.tuning)
            except ValueError as exc:
                raise ConfigError(f"control.tuning: {exc}") from None
        _choice("qp_backend", self.qp_backend, tuple(available_backends()))
        object.__setattr__(self, "phase_rad", _numbers("control.phase_rad", self.phase_rad))
        try:
            self.filter_arguments()
        except ValueError as exc:
            raise ConfigError(f"control.filter_params: {exc}") from None

    @property
    def period_s(self) -> float:
        return 1.0 / self.control_rate

    def filter_arguments(self) -> Params:
        """The filter's parameters: for paper-cbf, tuning and qp_backend from this section unless filter_params set
        them; typed by the filter's declarations (`controllers.registry.typed_params`, a preset's merged under
        them) for a built-in or a preset, a file's plug-in's when it is built (`build_filter`)."""
        given = self.filter_params
        if self.filter == "paper-cbf":
            given = {"tuning": self.tuning, "qp_backend": self.qp_backend, **self.filter_params}
        return typed_params(self.filter, given) if is_builtin(self.filter) else read_params(given)

    def nominal_arguments(self) -> dict[str, Any]:
        """The nominal's parameters: for the sinusoid, amplitude, frequency and phase from this section unless set."""
        if self.nominal == "sinusoid":
            return {"amplitude": self.amplitude, "frequency": self.frequency, "phase": self.phase_rad,
                    **self.nominal_params}
        return dict(self.nominal_params)


@_hardware_section("hold_s")
class SafetyConfig:
    watchdog_s: float = 0.15

    def check(self) -> None:
        _number("safety.watchdog_s", self.watchdog_s, positive("s"), 5.0, "s")


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
        _number("link.ack_timeout_s", self.ack_timeout_s, positive("s"), 1.0, "s")

    @property
    def is_emulated(self) -> bool:
        return self.port == EMULATED_PORT

    @property
    def worst_exchange_s(self) -> float:
        return (1 + self.retries) * self.ack_timeout_s


@_hardware_section("duration")
class RunConfig:
    dry_run: bool = False

    def check(self) -> None:
        _require(isinstance(self.dry_run, bool), "run.dry_run", f"must be true or false, got {self.dry_run!r}")


@_hardware_section(*ground_truth_settings())
class EmulatorConfig:
    """The emulator's ground truth: every ground-truth setting (`vocabulary.settings.ground_truth_settings`, top-level
    keys of the file) and its own `q0_rad`."""

    q0_rad: Scalars = 0.0

    def check(self) -> None:
        object.__setattr__(self, "q0_rad", _numbers("emulator.q0_rad", self.q0_rad, math.pi, "rad"))
        ratio = EMULATOR_COMMAND_PERIOD_S / self.physics_dt
        _require(abs(ratio - round(ratio)) <= 1e-9 * ratio, "physics_dt",
                 f"must divide the emulated board's command period {EMULATOR_COMMAND_PERIOD_S:g} s into whole steps "
                 f"(e.g. 1e-4, 2e-4, 5e-4, 1e-3 s), got {self.physics_dt!r}")


_SECTIONS = {
    "camera": CameraConfig, "robot": RobotConfig, "environment": EnvironmentConfig, "pressure": PressureConfig,
    "control": ControlConfig, "safety": SafetyConfig, "link": LinkConfig, "run": RunConfig, "emulator": EmulatorConfig,
}
SHARED_KEYS: dict[str, str] = {f: section for section, cls in _SECTIONS.items() for f in setting_fields(cls)}
"""The settings the hardware run shares with the simulations (top-level keys), each → the section that holds it."""


def _own_keys(section: str) -> list[str]:
    cls = _SECTIONS[section]
    return [f.name for f in dataclasses.fields(cls) if f.name not in setting_fields(cls)]


def default_values() -> dict[str, Any]:
    """Every key of the configuration with its default: shared settings by name, the others "section.key"."""
    out: dict[str, Any] = {}
    for name, cls in _SECTIONS.items():
        for f in dataclasses.fields(cls):
            out[f.name if f.name in SHARED_KEYS else f"{name}.{f.name}"] = (
                f.default_factory() if f.default is dataclasses.MISSING else f.default)
    return out


def _current_spelling(data: Mapping[str, Any], source: str = NOUN) -> dict[str, Any]:
    """`data` with every former spelling (`LEGACY_KEYS`) moved to its setting's name at the top
    level, and one warning line on stderr naming them; ConfigError for a setting given twice."""
    out = {key: dict(value) if key in _SECTIONS and isinstance(value, Mapping) else value for key, value in data.items()}
    renamed = []
    for section in _SECTIONS:
        table = out.get(section)
        if not isinstance(table, dict):
            continue
        for key in [k for k in table if f"{section}.{k}" in LEGACY_KEYS]:
            name = LEGACY_KEYS[f"{section}.{key}"]
            given = name in out and not (name == section and isinstance(out[name], dict))  # [robot] params → robot
            _require(not given, name, f"is given twice: as {name} and as its former spelling {section}.{key}; keep {name}")
            out[name] = table.pop(key)
            renamed.append(f"{section}.{key} -> {name}")
    if renamed:
        print(f"warning: {source}: former key(s) {', '.join(renamed)}; the keys now have the names they have everywhere "
              "(top level, docs/parameters.md): rename them", file=sys.stderr)
    return out


def _sections(data: Mapping[str, Any]) -> dict[str, Any]:
    """The section objects of a configuration in the file's shape (module docstring)."""
    _require(isinstance(data, Mapping), "the configuration", f"must be a table of settings, got {type(data).__name__}")
    fields: dict[str, dict[str, Any]] = {}
    unknown = sorted(key for key in data if key not in SHARED_KEYS and key not in _SECTIONS)
    _require(not unknown, "the configuration", f"has unknown key(s) or section(s) {unknown}; settings: "
             f"{', '.join(SHARED_KEYS)} (docs/parameters.md); sections: {', '.join(_SECTIONS)}")
    for key, value in data.items():
        if key in SHARED_KEYS:
            fields.setdefault(SHARED_KEYS[key], {})[key] = value
            continue
        _require(isinstance(value, Mapping), f"[{key}]", f"must be a table of keys, got {value!r}")
        shared = sorted(set(value) & set(SHARED_KEYS))
        _require(not shared, f"[{key}]", f"holds {shared}: settings shared with the simulations are top-level keys")
        valid = _own_keys(key)
        unknown = sorted(set(value) - set(valid))
        _require(not unknown, f"[{key}]", f"has unknown key(s) {unknown}; valid keys: {', '.join(valid) or 'none'}")
        fields.setdefault(key, {}).update(value)
    return {name: _SECTIONS[name](**given) for name, given in fields.items()}


@dataclass(frozen=True)
class HardwareConfig:
    """Every setting of a hardware run (see the module tables); `base_dir` resolves relative file paths."""

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
        _require(self.control.frequency < self.control.control_rate / 2, "frequency",
                 f"must be below half the control rate ({self.control.control_rate / 2:g} Hz), got {self.control.frequency:g}")
        _require(self.link.is_emulated == self.camera.is_virtual, "link.port",
                 f'"{EMULATED_PORT}" and camera.source "{VIRTUAL_CAMERA}" go together (the virtual camera renders the '
                 f"emulated arm; a real camera sees the real one), got port {self.link.port!r}, camera {self.camera.source!r}")
        # Loaded once (parse once): a bad robot file or pressure limits, facets or calibration file fails
        # here, at load, and `robot_params`, `safe_set` and `plane_calibration` hand out these objects.
        object.__setattr__(self, "_robot", self._load_robot())
        n = self._robot.n_segments
        for key, value in (("amplitude", self.control.amplitude), ("control.phase_rad", self.control.phase_rad),
                           ("emulator.q0_rad", self.emulator.q0_rad)):
            try:
                per_segment(value, n, key)
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
        try:
            object.__setattr__(self, "_safe_set", self._build_safe_set())
        except ValueError as exc:
            raise ConfigError(f"environment: {exc}") from None
        object.__setattr__(self, "_calibration", self._load_calibration())

    # -- loading ------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], base_dir: str | Path = ".", source: str = NOUN) -> "HardwareConfig":
        """A configuration from a mapping in the file's shape (former spellings read, with a warning: `LEGACY_KEYS`)."""
        _require(isinstance(data, Mapping), "the configuration", f"must be a table of settings, got {type(data).__name__}")
        return cls(**_sections(_current_spelling(data, source)), base_dir=Path(base_dir))

    @classmethod
    def load(cls, path: str | Path) -> "HardwareConfig":
        """Read a .toml or .json file; relative paths inside it are relative to its folder."""
        path = Path(path)
        data = read_settings_file(path, NOUN, ConfigError, missing_hint="see examples/hardware_emulated.toml")
        return cls.from_dict(data, path.parent, f"{NOUN} {path}")

    def with_overrides(self, changes: Mapping[str, Any]) -> "HardwareConfig":
        """A copy with settings changed, `changes` in the file's shape ({"duration": 2.0, "link": {"port": ...}}:
        command-line options), validated again."""
        data = self.to_dict()
        for key, value in _current_spelling(changes, "the overrides").items():
            if key in _SECTIONS and isinstance(value, Mapping) and isinstance(data.get(key), Mapping):
                data[key] = {**data[key], **value}
            else:
                data[key] = value
        return type(self).from_dict(data, self.base_dir)

    def to_dict(self) -> dict[str, Any]:
        """The configuration in the file's shape: shared settings at the top level, then the sections'
        own keys (for config.json of the run folder; `from_dict` reads it back)."""
        out: dict[str, Any] = {}
        for name in _SECTIONS:
            values = dataclasses.asdict(getattr(self, name))
            out.update({key: value for key, value in values.items() if key in SHARED_KEYS})
        for name in _SECTIONS:
            own = {key: value for key, value in dataclasses.asdict(getattr(self, name)).items() if key not in SHARED_KEYS}
            if own:
                out[name] = own
        return out

    def plugin_spec(self, spec: str) -> str:
        """A filter or nominal spec with its FILE.py made relative to this file's folder (names unchanged)."""
        found = spec_file(spec)
        return spec if found is None else f"{self.resolve(str(found[0]))}:{found[1]}"

    def resolve(self, path: str) -> Path:
        """`path` relative to the configuration file's folder (unchanged when absolute)."""
        p = Path(path)
        return p if p.is_absolute() else self.base_dir / p

    def camera_source(self) -> int | str:
        """camera.source for `cv2.VideoCapture`: a file resolved against the configuration's folder, else as given."""
        source = self.camera.source
        return str(self.resolve(source)) if self.camera.is_file else source

    def plane_calibration(self) -> PlaneCalibration | None:
        """The calibration file's image → plane map (None when none is configured), read at load."""
        return self._calibration

    def _load_calibration(self) -> PlaneCalibration | None:
        if self.camera.calibration is None:
            return None
        path = self.resolve(self.camera.calibration)
        if not path.is_file():
            raise ConfigError(f"calibration must be a plane calibration JSON file, got {self.camera.calibration!r} "
                              f"(no file {path}; relative paths are relative to the configuration's folder)")
        try:
            return PlaneCalibration.load(path)
        except (ValueError, KeyError, TypeError, OSError) as exc:
            raise ConfigError(f"calibration {path}: {type(exc).__name__}: {exc}".splitlines()[0]) from None

    # -- the objects the run needs --------------------------------------------------

    def robot_params(self) -> RobotParams:
        """The controller's robot with the configured pressure limits (their one source of truth), read at load."""
        return self._robot

    def safe_set(self) -> ForceSafeSet:
        """The controller's force-safe set (the environment's facets, ψ(n) = assumed_plate_stiffness · n, F_max),
        built at load."""
        return self._safe_set

    def _load_robot(self) -> RobotParams:
        spec = self.robot.robot
        if spec == "reference":
            robot = reference_robot()
        else:
            path = self.resolve(spec)
            if not path.is_file():
                raise ConfigError(f'robot must be "reference" or a RobotParams JSON file, got {spec!r} (no file {path})')
            try:
                robot = RobotParams.load(path)
            except (ValueError, KeyError) as exc:
                raise ConfigError(f"robot {path}: {exc}") from None
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

    def _build_safe_set(self) -> ForceSafeSet:
        env = self.environment
        return ForceSafeSet(Environment(np.array(env.H), np.array(env.h)), LinearStiffness(env.assumed_plate_stiffness),
                            env.f_max, row_scaling=env.row_scaling)
