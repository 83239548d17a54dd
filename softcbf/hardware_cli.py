"""`softcbf hardware`: run the controller on the arm (or on the emulator) and write a run folder.

    softcbf hardware CONFIG [--port PORT|emulated] [--camera SOURCE|virtual] [--tuning NAME]
                            [--filter SPEC] [--filter-param NAME=VALUE ...] [--f-max N] [--duration S] ...
                            [--dry-run] [--out DIR] [--overwrite] [--spawn]

CONFIG is a `hardware.config` file (TOML or JSON; examples/hardware_emulated.toml), or the name of a shipped one
(`hardware_emulated`: `softcbf.shipped.resolve`, which also finds examples/hardware_emulated.toml outside the
checkout, and names the shipped ones when CONFIG is neither); the
options override its `link.port`, `camera.source`, `control.tuning` and `run.dry_run`,
and every setting it shares with the simulations by the option `softcbf run` has for it
(`hardware.config.SHARED_KEYS`: `--f-max`, `--control-rate`, `--filter`, `--duration`,
`--frame-rate`, `--tau-p`, ...; `--filter-param` and `--nominal-param` add to the file's
tables, each NAME once (`scenarios.run.command_line_params`), a `--filter` other than the
file's starts from an empty table); a file named on the command line (`--robot`,
`--calibration`, `--camera`, and the FILE.py of `--filter` and `--nominal` FILE.py:Factory)
is relative to the working directory, one named in the file relative to the file's folder.
The filter and the nominal controller are built once at start-up to check them (an
unknown name or parameter is a usage error). `--port emulated --camera virtual` runs the whole hardware path against
`softcbf_mj.emulator.emulate.EmulatedHardware` (MuJoCo arm and plate behind a pty valve board,
rendered by a virtual camera); the two go together (a real camera cannot see the emulated
arm). A real run imports no MuJoCo: the emulator is imported only for emulated runs.

The run folder is the simulations' (docs/run-outputs.md, `softcbf_mj.outputs.runio`): config.json,
summary.json (scenario "hardware", the configuration as params, one row per run with
the run-output fields from `softcbf_mj.outputs.metrics.run_figures` at the control rate plus the
loop's counts), timeseries/<tuning>.npz (one row per control cycle, recorded by the
recorder every loop shares, `closedloop.record`: the control step's columns, the
filter's diagnostics and the hardware loop's own columns, all with units),
plots, report.md, recording.rrd and frames/<tuning>/ (a camera frame every
1/SAVED_FRAMES_HZ s of the run, JPEG, with its tag detections: `FrameKeeper`; the
recording shows them). `--spawn` streams the run to a rerun viewer while it runs
(softcbf_mj.outputs.recording.live_viewer; without a display it says so and streams nothing):
the controller's view (the estimated arm, the command, ρ_pred; no contact force) and
the kept frames as they are taken. Ground truth: on the emulator q, q̇, the segment
ends, the pressure acting and the plate force are the emulator's true values at each
cycle's time, and timeseries/<tuning>_emulator.npz holds its full 1 kHz record
(`softcbf_mj.emulator.valve_emulator.RECORD_UNITS`), from which `force_max_emulator_N` and
`t_violation_emulator_s` are taken; on the arm q, q̇ are the camera's estimate, the
pressure acting is the board's measured pressure (ACK) and the force is not measured
(NaN: ρ_meas and force_max_N are null).

Start-up. Everything that can fail before the loop runs is checked before the run folder
is made: the configuration (`hardware.config`), then the emulator, the camera
(`cv2.VideoCapture` of `camera.source`, a file resolved against the configuration's
folder; `--camera FILE` against the working directory) and the serial port
(`link.port`, opened at `link.baudrate`). A failure is one line on stderr naming the
setting (`StartupError`), exit code 2, and no folder (nor, with --overwrite, a replaced
one). A loop that then sees no complete frame within camera.startup_timeout_s vents and
ends the same way, removing the folder it had made.

Progress (`CycleProgress`, softcbf_mj.outputs.progress): an emulated run says first that its emulator
is starting (it takes seconds); from the first cycle on the progress line shows cycles done of
the run's, the run time, the real-time factor and an ETA, updated once per second of run. A
failed start-up of a real arm prints nothing but its one error line.

Exit codes as `softcbf`: 0 done, 1 a filter fault or an error of the control loop (the
filter or nominal raised or returned what the contract refuses: the loop held, then
vented and stopped; every cycle before is in the folder, summary.json's row has `fault`,
the traceback is in fault_<tuning>.log, or error.log for an error of the loop itself),
2 usage error (bad configuration or option, hardware that does not start, a filter file
that does not load), 130 interrupted (Ctrl-C: the loop vents within one cycle and the
folder is still written).

Mount: `register_command("hardware", HELP, add_arguments, run_command)` in softcbf/cli.py;
`python -m softcbf.hardware_cli` runs it alone.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import tempfile
import termios
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any, Callable

import cv2
import numpy as np

from controllers.model.pcc import segment_ends
from closedloop.monitor import SafeAction
from hardware.config import (
    EMULATED_PORT, SHARED_KEYS, VIRTUAL_CAMERA, ConfigError, HardwareConfig, camera_source_is_file,
)
from hardware.runner import HardwareLog, HardwareLoop, StartupError, controller_context
from hardware.transport import open_serial
from perception.capture import VideoCaptureSource
from scenarios.common import filter_enabled, scene_record
from scenarios.run import FILTER_FAULT, INTERRUPTED, USAGE_ERROR, command_line_params, option_name, option_type
from closedloop.record import TIMESERIES_UNITS
from closedloop.step import describe_fault, fault_log_name, write_fault_log
from controllers.registry import build_filter, build_nominal
from controllers.registry import label as run_label
from softcbf.shipped import UnknownShipped, resolve as shipped_or_file
from softcbf_mj.outputs.metrics import run_figures
from softcbf_mj.outputs.progress import Progress
from softcbf_mj.outputs.runio import (
    OutputDirError, SummaryWriter, frames_folder, prepare_out_dir, remove_if_unused, save_frames_index, save_timeseries,
)
from vocabulary.settings import setting

HELP = "run the controller on the valve board and camera (or --port emulated --camera virtual)"
SCENARIO = "hardware"
SAVED_FRAMES_HZ = 2.0  # camera frames kept for the recording, per second of the run
JPEG_QUALITY = 90
ERROR_LOG = "error.log"  # the run folder's traceback of an error of the control loop itself


PATH_SETTINGS = ("robot", "calibration")  # a file named on the command line is relative to the working directory
PLUGIN_SETTINGS = ("filter", "nominal")  # likewise the FILE.py of a FILE.py:Factory spec
TABLE_SETTINGS = {"filter_params": "--filter-param", "nominal_params": "--nominal-param"}  # tables, added to by NAME=VALUE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("config", type=Path, help="hardware configuration file (.toml or .json), or a shipped one's name "
                                                  "(hardware_emulated)")
    parser.add_argument("--port", help=f"valve board serial port, or {EMULATED_PORT!r} (overrides link.port)")
    parser.add_argument("--camera", help=f"camera device index, video file or URL, or {VIRTUAL_CAMERA!r} (overrides camera.source)")
    parser.add_argument("--tuning", help="CBF tuning (overrides control.tuning)")
    for name in SHARED_KEYS:  # the settings shared with `softcbf run`, by the same options
        if name in TABLE_SETTINGS:
            parser.add_argument(TABLE_SETTINGS[name], dest=f"{name}_items", action="append", default=[], metavar="NAME=VALUE",
                                help=f"one of {name} (repeatable; added to the file's {name})")
            continue
        doc = setting(name)
        unit = f" [{doc.unit}]" if doc.unit else ""
        parser.add_argument(option_name(name), dest=name, type=option_type(doc.flat_kind), metavar=doc.flat_kind.__name__.upper(),
                            help=f"{doc.meaning}{unit}; valid: {doc.valid_values} (overrides the file's {name})")
    parser.add_argument("--dry-run", action="store_true", help="run everything but send zero pressure")
    parser.add_argument("--out", type=Path, help="output folder (default runs/hardware-<time>)")
    parser.add_argument("--overwrite", action="store_true", help="replace the contents of an existing --out folder")
    parser.add_argument("--spawn", action="store_true", help="stream the run to a rerun viewer while it runs (needs a display)")


def _from_working_directory(spec: str) -> str:
    """A file named on the command line as an absolute path (the configuration's own are relative to its folder)."""
    path = Path(spec)
    return str(path.absolute()) if path.is_file() else spec


def _plugin_from_working_directory(spec: str) -> str:
    """A FILE.py:Factory spec named on the command line with FILE.py made absolute (names and modules unchanged)."""
    where, sep, name = spec.rpartition(":")
    return f"{Path(where).absolute()}:{name}" if sep and where.endswith(".py") else spec


def configure(args: argparse.Namespace) -> HardwareConfig:
    """The configuration file with the command line's overrides applied (in the file's shape)."""
    changes: dict[str, Any] = {"link": {}, "camera": {}, "control": {}, "run": {}}
    if args.port is not None:
        changes["link"]["port"] = args.port
    if args.camera is not None:
        source: int | str = int(args.camera) if args.camera.isdigit() else args.camera
        if camera_source_is_file(source):
            source = str(Path(source).absolute())  # a file named on the command line: relative to the working directory
        changes["camera"]["source"] = source
    if args.tuning is not None:
        changes["control"]["tuning"] = args.tuning
    if args.dry_run:
        changes["run"]["dry_run"] = True
    for name in SHARED_KEYS:
        value = getattr(args, name, None)
        if value is not None:
            if name in PATH_SETTINGS:
                value = _from_working_directory(value)
            elif name in PLUGIN_SETTINGS:
                value = _plugin_from_working_directory(value)
            changes[name] = value
    config = HardwareConfig.load(shipped_or_file("hardware", args.config))
    for name in ("filter", "nominal"):
        if getattr(args, name) is not None:
            changes[f"{name}_params"] = {}  # another controller: the file's parameters were for the file's
    for name, option in TABLE_SETTINGS.items():
        items = getattr(args, f"{name}_items")
        if items:
            try:
                extra = command_line_params([(option, item) for item in items])
            except ValueError as exc:
                raise ConfigError(str(exc)) from None
            changes[name] = {**changes.get(name, getattr(config.control, name)), **extra}
    config = config.with_overrides(changes)
    check_controller(config)
    return config


def check_controller(config: HardwareConfig) -> None:
    """Build the configured filter and nominal once; ConfigError naming the key if either is refused."""
    context = controller_context(config)
    ctl = config.control
    for key, build, spec, params in (("filter", build_filter, ctl.filter, ctl.filter_arguments()),
                                     ("nominal", build_nominal, ctl.nominal, ctl.nominal_arguments())):
        try:
            build(config.plugin_spec(spec), params, context)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{key}: {exc}") from None


def run_command(args: argparse.Namespace, extra: list[str] | None = None) -> int:
    """Handler of `softcbf hardware` (see the module docstring for the exit codes)."""
    out_dir = None
    try:
        config = configure(args)
        progress = CycleProgress(config)
        progress.start()
        with started_loop(config, on_cycle=progress) as (loop, emulation):
            out_dir = prepare_out_dir(args.out or Path("runs") / f"{SCENARIO}-{time.strftime('%Y%m%d-%H%M%S')}",
                                      args.overwrite)
            if args.spawn:
                from softcbf_mj.outputs.recording import live_viewer  # MuJoCo, rerun: 2.6 s (-X importtime), only with a viewer

                with live_viewer() as message:
                    print(message, file=sys.stderr)
                    row = run_loop(config, loop, emulation, out_dir, progress=progress)
            else:
                row = run_loop(config, loop, emulation, out_dir, progress=progress)
    except (ConfigError, UnknownShipped, StartupError, OutputDirError) as exc:
        if out_dir is not None:
            remove_if_unused(out_dir)  # made for a run that did not start
        print(f"error: {exc}", file=sys.stderr)
        return USAGE_ERROR
    except KeyboardInterrupt:  # outside the loop (which turns Ctrl-C into its vent cycle): start-up or writing
        print("\ninterrupted outside the control loop; a loop that had started vented the valves on its way out"
              + (f"; outputs so far in {out_dir}" if out_dir is not None else ""), file=sys.stderr)
        return INTERRUPTED
    print(result_line(row, config, out_dir))
    recording = out_dir / "recording.rrd"
    if recording.is_file():
        from softcbf_mj.outputs.recording import viewer_command  # MuJoCo, rerun: 2.6 s (-X importtime), only with a viewer

        print(f"view the recording with: {viewer_command(recording)}")
    if row.get("fault"):
        print(f"error: {describe_fault(row['fault'])}; the {row['cycles']} cycles up to the vent are in {out_dir} "
              f"(traceback: {fault_log_name(row['tuning'])})", file=sys.stderr)
        return FILTER_FAULT
    if row.get("error"):
        print(f"error: the control loop stopped: {row['error']}; the {row['cycles']} cycles before it are in "
              f"{out_dir} (traceback: {ERROR_LOG})", file=sys.stderr)
        return FILTER_FAULT
    return INTERRUPTED if row["interrupted"] else 0


def _figure(value: Any, fmt: str) -> str:
    return "n/a" if value is None else format(value, fmt)


def result_line(row: dict[str, Any], config: HardwareConfig, out_dir: Path) -> str:
    """The one line a hardware run ends with: cycles and actions, vents, link quality, the
    predicted margin and the force against F_max with a violation flag."""
    f_max = config.safe_set().f_max
    force = row.get("force_max_N")
    flag = "" if force is None else (" VIOLATION: above F_max" if force > f_max else " (within F_max)")
    return (f"hardware run ({row['tuning']}{', dry run' if config.run.dry_run else ''}): {row['cycles']} cycles "
            f"({row['cycles_run']} run / {row['cycles_hold']} hold / {row['cycles_vent']} vent, "
            f"{row['cycles_skipped']} skipped), board watchdog vents {row['watchdog_vents']}, link acknowledged "
            f"{row['link_acked_fraction']:.3f}, rho_min_pred {_figure(row.get('rho_min_pred'), '.3f')}, "
            f"force max {_figure(force, '.4f')} N of F_max {f_max:g} N{flag}; outputs in {out_dir}")


@contextlib.contextmanager
def _native_stderr_unless_failed() -> Iterator[None]:
    """Hold what native code (OpenCV, FFmpeg) writes to file descriptor 2 inside the block; pass it on
    when the block succeeds, drop it when it raises (the one-line StartupError says what failed)."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as held:
        os.dup2(held.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        held.seek(0)  # reached only when the block succeeded
        sys.stderr.write(held.read().decode("utf-8", "replace"))


def _start(setting: str, opener: Callable[[], Any]) -> Any:
    """`opener()`, with the errors of opening a device as a one-line StartupError naming `setting`."""
    try:
        return opener()
    except (OSError, ValueError, RuntimeError, termios.error) as exc:  # serial.SerialException is an OSError
        raise StartupError(f"{setting}: " + f"{type(exc).__name__}: {exc}".splitlines()[0]) from None


@contextlib.contextmanager
def started_loop(config: HardwareConfig, emulation: Any = None,
                 on_cycle: Callable[[int, float, SafeAction], None] | None = None) -> Iterator[tuple[HardwareLoop, Any]]:
    """(the loop of `config` with its emulator, camera and serial port open, the emulation or None); closes them after.

    Emulated runs (link.port "emulated", camera.source "virtual") use `emulation` (an
    `EmulatedHardware` of this config, e.g. one a test injects faults into) or start their
    own. What cannot be opened raises a one-line `StartupError` naming the setting.
    """
    with contextlib.ExitStack() as stack:
        if config.link.is_emulated:
            if emulation is None:
                from softcbf_mj.emulator.emulate import EmulatedHardware  # MuJoCo, 0.23 s (-X importtime): real runs load none

                emulation = stack.enter_context(_start("emulator", lambda: EmulatedHardware(config)))
            source, port, calibration = emulation.camera, emulation.port_name, emulation.calibration()
        else:
            with _native_stderr_unless_failed():
                source = _start(f"camera.source {config.camera.source!r}", lambda: VideoCaptureSource(config.camera_source()))
            stack.callback(source.close)
            port, calibration = config.link.port, None
        calibration = config.plane_calibration() or calibration
        transport = _start(f"link.port {port!r} (the valve board's serial port)",
                           lambda: open_serial(port, config.link.baudrate))
        stack.callback(transport.close)
        yield HardwareLoop.from_config(config, source, calibration, transport, on_cycle=on_cycle), emulation


def run_hardware(config: HardwareConfig, out_dir: Path, *, emulation: Any = None,
                 on_cycle: Callable[[int, float, SafeAction], None] | None = None, report: bool = True) -> dict[str, Any]:
    """Run `config` and write the run folder `out_dir` (existing, empty); return the summary row.

    `emulation`: as for `started_loop`. `on_cycle(k, t, action)` is called after every
    cycle (t: s since the start). `report` False skips the plots, report.md and
    recording.rrd (tests).
    """
    with started_loop(config, emulation, on_cycle) as (loop, emulation):
        return run_loop(config, loop, emulation, out_dir, report)


class CycleProgress:
    """The loop's `on_cycle` of the command: the progress line (`softcbf_mj.outputs.progress.Progress`: cycles done of
    the run's, simulated = run time, its ETA). `start()` says that an emulated run's emulator is starting (MuJoCo
    and the virtual camera: seconds before the first cycle; a real camera and port open at once, and a start-up
    that fails stays the one line of its error); the line's clock restarts at the first cycle (so the ETA and the
    real-time factor are the loop's), then the line is updated once per second of run (s since the first
    cycle), with the last cycle's safety action."""

    def __init__(self, config: HardwareConfig) -> None:
        self.period = config.control.period_s
        self.label = f"hardware {run_label(config.plugin_spec(config.control.filter), config.control.filter_arguments())}"
        self.total = max(1, int(round(config.run.duration / self.period)))
        self.emulated = config.link.is_emulated
        self.bar: Progress | None = None
        self.next_s = 0.0
        self.done = 0

    def start(self) -> None:
        """An emulated run's first line, before its emulator starts (class docstring)."""
        if self.emulated:
            Progress(self.label, self.total, unit_s=self.period).update(0, "starting the emulator (MuJoCo, virtual camera)")

    def __call__(self, k: int, t: float, action: SafeAction) -> None:
        self.done = k + 1  # k counts skipped cycles too: the run's schedule
        if self.bar is None:
            self.bar = Progress(self.label, self.total, unit_s=self.period)
            self.bar.start -= t  # the clock of the first cycle (t s ago)
        if t >= self.next_s:
            self.next_s = math.floor(t) + 1.0
            self.bar.update(self.done, f"last action {action.value}")

    def close(self) -> None:
        """The final line, at the last cycle the run reached (before the planned end when it stopped early)."""
        if self.bar is not None:
            self.bar.close(self.done)


def run_loop(config: HardwareConfig, loop: HardwareLoop, emulation: Any, out_dir: Path, report: bool = True,
             progress: CycleProgress | None = None) -> dict[str, Any]:
    """Run a started loop and write the run folder `out_dir`; return the summary row. `progress` (the loop's
    `on_cycle`, if it is one) prints its final line when the loop ends, before the folder is written.

    With `report`, camera frames are kept (`FrameKeeper`) for the recording, and while a
    live viewer is active (softcbf_mj.outputs.recording.live_viewer: `--spawn`) the run streams to
    it as it runs: the controller's view (the estimate's arm, no contact force) — the
    finished recording.rrd has the emulator's ground truth where there is one."""
    keeper = live = None
    if report:
        from softcbf_mj.outputs.recording import live_run  # MuJoCo, rerun: 2.6 s (-X importtime), only when recording

        label = run_label(config.plugin_spec(config.control.filter), config.control.filter_arguments())
        safe_set = loop.step.context.safe_set
        live = live_run(_scene(config, safe_set, emulation), label, 0, loop.period_s, camera=True,
                        complete=lambda rows: _series(config, rows, safe_set, None))
        loop.live = live
        keeper = loop.perception.frame_hook = FrameKeeper(out_dir, label, loop, live)
    start = time.perf_counter()
    log = loop.run()
    wall = time.perf_counter() - start
    if progress is not None:
        progress.close()
    if keeper is not None and keeper.saved:
        save_frames_index(out_dir, keeper.label, keeper.saved)
    return write_run(config, out_dir, log, loop, wall, emulation, report)


class FrameKeeper:
    """A `hardware.runner.PerceptionWorker.frame_hook` that keeps one camera frame every
    1/SAVED_FRAMES_HZ s of the run (JPEG, quality JPEG_QUALITY) in DIR/frames/<label>/ with
    its detections (`saved`: the entries of frames.json, `softcbf_mj.outputs.runio`; times s since
    the loop's first cycle), and sends each to `live` (a LiveRun) when there is one."""

    def __init__(self, out_dir: Path, label: str, loop: HardwareLoop, live: Any = None) -> None:
        self.folder, self.label, self.loop, self.live = frames_folder(out_dir, label), label, loop, live
        self.saved: list[dict[str, Any]] = []
        self._next_t = 0.0

    def __call__(self, t_capture: float, image: np.ndarray, detections: list) -> None:
        t0 = self.loop.t0
        if t0 is None or t_capture - t0 < self._next_t:
            return
        t = t_capture - t0
        self._next_t = t + 1.0 / SAVED_FRAMES_HZ
        ok, jpeg = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            return
        self.folder.mkdir(parents=True, exist_ok=True)
        name = f"frame_{len(self.saved):06d}.jpg"
        (self.folder / name).write_bytes(jpeg.tobytes())
        found = [{"id": d.tag_id, "corners": d.corners.tolist()} for d in detections]
        self.saved.append({"t": t, "file": name, "detections": found})
        if self.live is not None:
            self.live.frame(t, jpeg.tobytes(), "image/jpeg", found)


def _scene(config: HardwareConfig, safe_set, emulation: Any) -> dict[str, Any]:
    """summary.json's "scene" of a run: the plates' stiffness is the emulator's, or the configured environment's."""
    plate_k = config.emulator.plate_stiffness if emulation is not None else config.environment.assumed_plate_stiffness
    return scene_record(config.robot_params(), safe_set, plate_k)


def _series(config: HardwareConfig, c: dict[str, np.ndarray], safe_set, emulation: Any) -> dict[str, np.ndarray]:
    """The run's time series from the recorder's columns `c`: those plus the simulations' plant keys
    (TIMESERIES_UNITS) — the emulator's ground truth, or (emulation None) the estimate's arm, no contact force."""
    lengths = config.robot_params().array("lengths")
    series = dict(c)
    if emulation is not None:
        truth = emulation.emulator.state_at(c["t_clock"])
        series.update(q=truth["q"], qd=truth["qd"], segment_ends=truth["segment_ends"], u_applied=truth["u_applied"],
                      contact_force=truth["contact_force"], plate_displacement_m=truth["plate_displacement_m"])
    else:
        series.update(q=c["q_est"], qd=c["qd_est"], u_applied=c["u_measured"],
                      segment_ends=np.array([segment_ends(q, lengths) for q in c["q_est"]]).reshape(-1, len(lengths) + 1, 2),
                      contact_force=np.full((len(c["t"]), safe_set.n_facets), np.nan))
    series["tip"] = series["segment_ends"][:, -1]
    series["rho_meas"] = np.min(safe_set.margin_from_force(series["contact_force"]), axis=-1) if len(c["t"]) else np.zeros(0)
    return series


def write_run(config: HardwareConfig, out_dir: Path, log: HardwareLog, loop: HardwareLoop, wall_s: float,
              emulation: Any, report: bool = True) -> dict[str, Any]:
    """summary.json, the time series, the report and the recording of one hardware run."""
    safe_set = loop.step.context.safe_set
    params = {**config.to_dict(), "emulated": emulation is not None}
    summary = SummaryWriter(out_dir, SCENARIO, params, _scene(config, safe_set, emulation))
    ctl = config.control
    label = run_label(config.plugin_spec(ctl.filter), ctl.filter_arguments())
    series = _series(config, log.columns(), safe_set, emulation)
    all_units = {**TIMESERIES_UNITS, **log.units(), "plate_displacement_m": "m"}
    units = {key: all_units[key] for key in series}
    counts = log.summary()
    row: dict[str, Any] = {"tuning": label, "filter": ctl.filter, "filter_params": ctl.filter_arguments(),
                           "nominal": ctl.nominal, "nominal_params": ctl.nominal_arguments()}
    if len(series["t"]):
        row.update(run_figures(series, loop.period_s, filter_enabled(loop.step), wall_s))
    link = counts["link"]
    row.update({k: v for k, v in counts.items() if k not in ("link", "perception")})
    row.update(link_acked_fraction=link["acked_fraction"], link_latency_median_ms=link["latency_median_s"] * 1e3,
               link_latency_p99_ms=link["latency_p99_s"] * 1e3, link=link, perception=counts["perception"],
               dry_run=config.run.dry_run)
    row["timeseries"] = str(save_timeseries(out_dir, label, series, units).relative_to(out_dir))
    if log.fault is not None:
        row.update(log.fault.row_fields())
        write_fault_log(out_dir, label, log.fault)
    if log.error is not None:
        row["error"] = log.error
        (out_dir / ERROR_LOG).write_text(log.error_traceback, encoding="utf-8")
    if emulation is not None:
        from softcbf_mj.emulator.valve_emulator import RECORD_UNITS  # MuJoCo, 0.44 s (-X importtime): emulated runs only

        record = emulation.emulator.record()
        force = record["contact_force"]
        rho = np.min(safe_set.margin_from_force(force), axis=-1)
        dt = emulation.emulator.plant.control_dt
        row.update(force_max_emulator_N=float(force.max(initial=0.0)),
                   t_violation_emulator_s=float(np.count_nonzero(rho < 0) * dt),
                   emulator_lag_max_s=emulation.emulator.lag_max_s, camera_frames_dropped=emulation.camera.dropped)
        row["timeseries_emulator"] = str(save_timeseries(out_dir, f"{label}_emulator", record, RECORD_UNITS).relative_to(out_dir))
    summary.add_run(row)
    if report and len(series["t"]) > 1:
        from softcbf_mj.outputs.recording import write_recording  # MuJoCo, rerun: 2.6 s (-X importtime), after the run
        from softcbf_mj.outputs.report import write_report  # matplotlib: 0.74 s more (-X importtime), after the run

        write_report(out_dir)
        write_recording(out_dir)
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="softcbf hardware", description=HELP)
    add_arguments(parser)
    return run_command(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
