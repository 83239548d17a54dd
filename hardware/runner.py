"""The hardware loop: camera frames → perception → control step → valve-board link.

Two threads share one monotonic clock (s):

- perception (`PerceptionWorker`): reads frames from a `perception.capture.FrameSource` as
  they come (a camera paces itself; the virtual camera at its frame rate), detects the
  tags (`TagDetector`) and updates the `ArmAngleEstimator` with each frame's capture time;
- control (`HardwareLoop.run`): at t_k = t_0 + k·T (T = 1 / rate, absolute schedule), it

      1. takes the estimate at now = clock() (q, q̇ of the latest complete frame; stale when
         older than the estimator's max_hold_s),
      2. runs the control step the simulations run (`closedloop.step.ControlStep`, at
         t = now − t_0): u_nom = nominal(t, q, q̇), u = filter(estimate, u_nom) — any
         registered or user filter (`controllers.registry`, config `filter`) —,
         admission (clipped to the limits; non-finite or raised: command_nonfinite), and
         the safety monitor (`closedloop.monitor`) with flags perception_stale, link_lost
         (the previous exchange failed) and interrupted (Ctrl-C or `stop()`),
      3. sends its command in the same cycle: RUN/HOLD → `send_setpoints(u)` (zeros with
         `dry_run`), VENT → `vent()`; the link clamps to its limits and waits for the ACK.

  So a stale estimate, a lost link, a non-finite command or Ctrl-C changes what goes on
  the wire in the first cycle that sees it: HOLD the last RUN command, then VENT once the
  hold has lasted `hold_s` (`closedloop.monitor`); the board's own watchdog vents when
  commands stop arriving (a cut cable).

A cycle that ends past the next cycle's slot (a filter or link stall) skips the cycles whose
slots have passed (`cycles_skipped`) instead of firing them back to back. A filter fault
(closedloop.step: the filter or nominal raised or returned what the contract refuses) holds,
then vents, and the run ends at that vent cycle; an error of the loop itself ends it at
once (`HardwareLog.error`); either way every cycle before is kept and the valves vent.
The summary counts the loop's VENT cycles and the board's watchdog vents (`watchdog_vents`,
from its ACKs).

Warm-up: before the first frame is awaited, a second step of the same filter and nominal (`warm_up`, built by
`from_config` from the same settings and dropped after) is run on `warm_up_states(context)`: the arm's
uniform bends toward each side from straight to past the plate (tip margins ρ from 1 down to
WARM_UP_MARGINS' last), at rest and bending toward the plate, with estimates as old as a camera's, then a
stale estimate and a lost link (the monitor's HOLD and VENT). The filter's compiled kernels (numba:
loaded from its cache, or compiled on a cold one) and its one-time imports load there, outside the timed
loop: else the first cycle and the first contact of a process's first run stall by the load (about 0.2 s
from the cache, 5–50 s on a cold one) and the board's watchdog vents. The run's own filter has done nothing
yet, so no warm-up state enters its history.

Start: the loop waits (up to `startup_timeout_s`) for the first complete frame, so q is
finite from the first cycle on; without one it vents and raises `PerceptionStartupError`
(a `StartupError`, like a camera or port that does not open: one line naming the setting).
End: after `duration_s`, on `stop()` or Ctrl-C — the last cycle is a VENT (interrupted) —
and in every case a final `vent()` leaves the valves at 0 hPa. In the main thread `run()`
turns SIGINT into `stop()` for its duration, so Ctrl-C takes effect in the next cycle
wherever it lands (elsewhere a KeyboardInterrupt inside a cycle does the same).

`HardwareLog.columns()` gives one row per control cycle, recorded by the recorder every loop
shares (`closedloop.record`; units: `HardwareLog.units()`); `summary()` the counts of
actions, flags, perception and link quality. Nothing here imports MuJoCo
or `softcbf_mj`: the emulator (softcbf_mj.emulator.emulate) only provides the frame source and
the serial port.
"""

from __future__ import annotations

import logging
import math
import signal
import threading
import time
import traceback
from collections import Counter
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from closedloop.monitor import SafeAction, SafetyFlags, SafetyMonitor
from closedloop.record import LiveRows, Recorder
from closedloop.step import ACTION_CODES, ControlStep, FilterFault
from controllers.model.pcc import segment_ends
from controllers.registry import build_filter, build_nominal
from controllers.contract.safety_filter import Estimate, FilterContext
from hardware.config import HardwareConfig
from hardware.link import LinkResult, ValveBoardLink
from hardware.transport import ByteTransport
from perception.capture import FrameSource
from perception.detect import Detection, TagDetector
from perception.estimator import ArmAngleEstimator, ArmEstimate
from perception.plane import PlaneCalibration
from perception.tags import arm_tag_ids

log = logging.getLogger(__name__)

NO_FRAME_WAIT_S = 0.01  # pause after a source delivered no frame, s
WARM_UP_MARGINS = (1.0, 0.75, 0.5, 0.25, 0.1, 0.0, -0.25, -0.5, -1.0)  # tip margins ρ of the warm-up's bends
WARM_UP_BEND_STEP_RAD = 0.05  # the grid of uniform bends searched for them, rad per segment
WARM_UP_BEND_TOL_RAD = 1e-3  # the bisection's tolerance on the bend reaching a margin, rad per segment
WARM_UP_QD_RAD_S = 0.5  # the warm-up's bend rate toward the plate, rad/s per segment
WARM_UP_AGE_PERIODS = 0.5  # the warm-up estimates' age, control periods (a camera frame's is > 0: the filter predicts)
LOOP_COLUMNS = ("t", "t_clock", "q_est", "qd_est", "est_age_s", "u_sent", "u_measured", "link_latency_s", "late_s")
LOOP_FLAGS = ("est_stale", "link_acked", "link_lost")


def controller_context(config: HardwareConfig) -> FilterContext:
    """The loop's context: the robot model, P, the limits when pressure_limits, the period; its own copy of
    the config's robot and safe set (`FilterContext.copy`), whose pressure limits also set the link's. A plug-in
    is handed a copy of it in turn (`HardwareLoop.from_config`)."""
    return FilterContext.for_robot(config.robot_params(), config.safe_set(), config.control.period_s,
                                   config.control.pressure_limits).copy()


def warm_up_states(context: FilterContext) -> list[tuple[np.ndarray, np.ndarray]]:
    """(q, q̇) pairs (rad, rad/s, (N,) each) for the warm-up (module docstring): for each side, the uniform bends
    q = θ·1 (0 ≤ θ ≤ π/2 per segment) whose tip margin (`context.safe_set.margin`) first reaches each of
    WARM_UP_MARGINS (found on a grid of WARM_UP_BEND_STEP_RAD, then halved to WARM_UP_BEND_TOL_RAD; the last
    bend of the grid when the margin stays above), each at rest and bending toward the plate at
    WARM_UP_QD_RAD_S."""
    n, lengths, safe_set = context.robot.n_segments, np.array(context.robot.lengths, dtype=float), context.safe_set
    states = []
    for side in (1.0, -1.0):
        def margin(theta: float) -> float:
            return float(safe_set.margin(segment_ends(np.full(n, side * theta), lengths)[-1]))

        grid = np.arange(0.0, math.pi / 2, WARM_UP_BEND_STEP_RAD)
        margins = np.array([margin(theta) for theta in grid])
        bends = set()
        for level in WARM_UP_MARGINS:
            reached = np.flatnonzero(margins <= level)
            if reached.size == 0:
                bends.add(float(grid[-1]) if level < 1.0 else 0.0)
                continue
            hi = float(grid[reached[0]])
            lo = float(grid[max(reached[0] - 1, 0)])
            while hi - lo > WARM_UP_BEND_TOL_RAD:
                mid = 0.5 * (lo + hi)
                lo, hi = (lo, mid) if margin(mid) <= level else (mid, hi)
            bends.add(hi)
        for bend in sorted(bends):
            q = np.full(n, side * bend)
            states += [(q, np.zeros(n)), (q, np.full(n, side * WARM_UP_QD_RAD_S))]
    return states


def warm_up(step: ControlStep, context: FilterContext, stop: threading.Event | None = None) -> None:
    """Run `step` (a step built for the warm-up, not the run's) as the loop's cycles call it, one control period
    apart, each estimate WARM_UP_AGE_PERIODS old: on each of `warm_up_states(context)` with no flag raised, then
    on the last with a stale estimate (HOLD) and with the link lost (VENT) (module docstring). What it returns is
    dropped; a filter fault there is the warm-up step's own (the run's filter, its own instance, is first called
    in the loop). It ends early once `stop` is set (Ctrl-C: the run then vents in its first cycle)."""
    states = warm_up_states(context)
    flags = [SafetyFlags()] * len(states) + [SafetyFlags(perception_stale=True), SafetyFlags(link_lost=True)]
    states += states[-1:] * 2
    for k, ((q, qd), raised) in enumerate(zip(states, flags)):
        if stop is not None and stop.is_set():
            return
        t = k * context.control_dt
        step(Estimate(t, q, qd, t - WARM_UP_AGE_PERIODS * context.control_dt), raised)


class StartupError(RuntimeError):
    """The run could not start: a camera, serial port or emulator that does not open, or no first frame.
    The message is one line that names the setting to fix."""


class PerceptionStartupError(StartupError):
    """No complete frame arrived before the start-up timeout."""


FrameHook = Callable[[float, np.ndarray, list[Detection]], None]  # (capture time s, image, detections)


class PerceptionWorker:
    """Frames → detections → estimator, in a daemon thread; `query(now)` is the estimate at now.

    `frame_hook(t, image, detections)`, when set, sees every frame after its detection, in
    the perception thread (e.g. to save a few: softcbf.hardware_cli); None by default."""

    def __init__(self, source: FrameSource, detector: TagDetector, estimator: ArmAngleEstimator,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.source, self.detector, self.estimator, self.clock = source, detector, estimator, clock
        self.frame_hook: FrameHook | None = None
        self.frames = 0
        self.frames_complete = 0
        self.empty_reads = 0
        self.detect_s: list[float] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="perception", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                frame = self.source.read()
                if frame is None:
                    self.empty_reads += 1
                    self._stop.wait(NO_FRAME_WAIT_S)
                    continue
                start = time.perf_counter()
                detections = self.detector.detect(frame.image)
                self.detect_s.append(time.perf_counter() - start)
                with self._lock:
                    estimate = self.estimator.update(frame.t, detections)
                self.frames += 1
                self.frames_complete += estimate.valid and estimate.t == frame.t
                if self.frame_hook is not None:
                    self.frame_hook(frame.t, frame.image, detections)
        except BaseException as exc:  # the loop sees a stale estimate; close() re-raises
            self._error = exc

    def query(self) -> tuple[float, ArmEstimate]:
        """(now, the estimate at now), read under the lock so no newer frame lands between the two."""
        with self._lock:
            now = self.clock()
            return now, self.estimator.query(now)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.source.close()
        if self._error is not None:
            raise RuntimeError("the perception thread failed") from self._error

    def stats(self) -> dict[str, Any]:
        detect = np.array(self.detect_s) * 1e3 if self.detect_s else np.array([math.nan])
        return {"frames": self.frames, "frames_complete": self.frames_complete, "empty_reads": self.empty_reads,
                "detect_ms_median": float(np.median(detect)), "detect_ms_p99": float(np.percentile(detect, 99))}


@dataclass
class HardwareLog:
    """The rows of a hardware run (one per control cycle, `recorder`) and its counts."""

    recorder: Recorder
    cycles: int = 0
    reasons: Counter = field(default_factory=Counter)
    link_stats: dict[str, Any] = field(default_factory=dict)
    perception_stats: dict[str, Any] = field(default_factory=dict)
    final_vent_acked: bool | None = None
    interrupted: bool = False
    skipped: int = 0  # scheduled cycles skipped after a stall (`HardwareLoop._next_cycle`)
    fault: FilterFault | None = None  # the filter fault the run ended on (closedloop.step)
    error: str | None = None  # an error of the loop itself (one line); the rows before it are kept
    error_traceback: str = ""

    @classmethod
    def for_cycles(cls, n_cycles: int, n_segments: int) -> "HardwareLog":
        n = n_segments
        shapes = {"q_est": (n,), "qd_est": (n,), "u_sent": (n,), "u_measured": (n,)}
        return cls(Recorder(n_cycles, n, {key: shapes.get(key, ()) for key in LOOP_COLUMNS}, LOOP_FLAGS))

    def columns(self) -> dict[str, np.ndarray]:
        """Arrays by key (`units()`), first axis the cycle."""
        return self.recorder.columns(self.cycles)

    def units(self) -> dict[str, str]:
        return self.recorder.units()

    def summary(self) -> dict[str, Any]:
        c = self.columns()
        actions = Counter(c["action"].tolist())
        return {
            "cycles": self.cycles,
            **{f"cycles_{a.value}": actions.get(code, 0) for a, code in ACTION_CODES.items()},
            "cycles_skipped": self.skipped,
            "watchdog_vents": int(self.link_stats.get("watchdog_reports", 0)),
            "flags": dict(self.reasons),
            "cycle_late_max_s": float(c["late_s"].max()) if self.cycles else 0.0,
            "final_vent_acked": self.final_vent_acked,
            "interrupted": self.interrupted,
            "link": self.link_stats,
            "perception": self.perception_stats,
        }


class HardwareLoop:
    """The control loop of the module docstring; `run()` returns its `HardwareLog`.

    `live` (closedloop.record.LiveRows, e.g. softcbf_mj.outputs.recording.LiveRun), when set, is
    sent the recorder every `live.period_steps` cycles and at the end, in the control
    thread after the cycle's command went out; None by default. `t0` is the clock time of
    the first cycle (s; None before), the origin of the rows' t. `warm_up`: a second step of
    the same filter and nominal, run by `run()` on the warm-up states before it awaits the first
    frame, and dropped (module docstring; None: no warm-up).
    """

    def __init__(
        self,
        perception: PerceptionWorker,
        link: ValveBoardLink,
        step: ControlStep,
        period_s: float,
        duration_s: float,
        *,
        dry_run: bool = False,
        startup_timeout_s: float = 5.0,
        clock: Callable[[], float] = time.monotonic,
        on_cycle: Callable[[int, float, SafeAction], None] | None = None,
        warm_up: ControlStep | None = None,
    ) -> None:
        for name, value in (("period_s", period_s), ("duration_s", duration_s), ("startup_timeout_s", startup_timeout_s)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite time > 0 s, got {value}")
        n = step.n
        if warm_up is not None and warm_up.n != n:
            raise ValueError(f"segments disagree: controller {n}, warm-up step {warm_up.n}")
        if not (link.n_segments == perception.estimator.n_segments == n):
            raise ValueError(f"segments disagree: controller {n}, link {link.n_segments}, "
                             f"estimator {perception.estimator.n_segments}")
        self.perception, self.link, self.step = perception, link, step
        self.period_s, self.duration_s = float(period_s), float(duration_s)
        self.dry_run, self.startup_timeout_s, self.clock, self.on_cycle = dry_run, float(startup_timeout_s), clock, on_cycle
        self.warm_up_step = warm_up
        self.live: LiveRows | None = None
        self.t0: float | None = None
        self._stop = threading.Event()

    @classmethod
    def from_config(cls, config: HardwareConfig, source: FrameSource, calibration: PlaneCalibration,
                    transport: ByteTransport | str, *, clock: Callable[[], float] = time.monotonic,
                    on_cycle: Callable[[int, float, SafeAction], None] | None = None) -> "HardwareLoop":
        """The loop of `config` reading `source` (image → plane map `calibration`) and talking over
        `transport` (a ByteTransport, or a serial port name opened at `link.baudrate`)."""
        robot = config.robot_params()
        n, cam, ctl, lk = robot.n_segments, config.camera, config.control, config.link
        estimator = ArmAngleEstimator(n, calibration, cam.tag_size_m, max_hold_s=cam.max_hold_s,
                                      qd_filter_tau=cam.qd_filter_tau)
        perception = PerceptionWorker(source, TagDetector(cam.detector, arm_tag_ids(n)), estimator, clock)
        link = ValveBoardLink(transport, n, robot.u_min, robot.u_max, ack_timeout_s=lk.ack_timeout_s,
                              retries=lk.retries, clock=clock, lost_after=lk.lost_after, baudrate=lk.baudrate)
        context = controller_context(config)

        def control_step() -> ControlStep:
            return ControlStep(build_filter(config.plugin_spec(ctl.filter), ctl.filter_arguments(), context.copy()),
                               build_nominal(config.plugin_spec(ctl.nominal), ctl.nominal_arguments(), context.copy()),
                               context, SafetyMonitor(n, config.safety.hold_s))

        return cls(perception, link, control_step(), ctl.period_s, config.run.duration, dry_run=config.run.dry_run,
                   startup_timeout_s=cam.startup_timeout_s, clock=clock, on_cycle=on_cycle, warm_up=control_step())

    def stop(self) -> None:
        """Ask the loop to end: its next cycle vents (interrupted) and it returns."""
        self._stop.set()

    def _wait_for_perception(self) -> None:
        deadline = self.clock() + self.startup_timeout_s
        while self.clock() < deadline and not self._stop.is_set():
            _, estimate = self.perception.query()
            if estimate.valid and not estimate.stale:
                return
            time.sleep(0.01)
        if not self._stop.is_set():
            raise PerceptionStartupError(
                f"no complete frame (every arm tag seen once) within {self.startup_timeout_s:g} s "
                f"({self.perception.frames} frames read); check the camera source, its calibration and that the tags are in view")

    def run(self) -> HardwareLog:
        record = HardwareLog.for_cycles(int(round(self.duration_s / self.period_s)), self.step.n)
        # Ctrl-C (SIGINT) asks the loop to stop wherever it lands, like stop(): the next cycle
        # (at once, the wait is cut short) vents. Only the main thread may install handlers.
        in_main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGINT, lambda signum, frame: self.stop()) if in_main else None
        self.step.reset()
        self.perception.start()
        try:
            if self.warm_up_step is not None:  # once: a later run() finds the kernels loaded
                step, self.warm_up_step = self.warm_up_step, None
                warm_up(step, self.step.context, self._stop)
            self._wait_for_perception()
            t0 = self.t0 = self.clock()
            n_cycles = int(round(self.duration_s / self.period_s))
            k = 0
            while k < n_cycles:
                interrupted = self._stop.is_set()
                try:
                    delay = t0 + k * self.period_s - self.clock()
                    if delay > 0 and not interrupted:
                        self._stop.wait(delay)
                        interrupted = self._stop.is_set()
                    action = self._cycle(k, t0, interrupted, record)
                except KeyboardInterrupt:
                    interrupted = True
                    action = self._cycle(k, t0, True, record)
                if interrupted:
                    record.interrupted = True
                    break
                if self.step.stopped:  # a filter fault has vented: the run ends here (closedloop.step)
                    break
                if self.on_cycle is not None:
                    self.on_cycle(k, self.clock() - t0, action)
                if self.live is not None and (record.cycles - 1) % self.live.period_steps == 0:
                    self.live.send(record.recorder, record.cycles)
                k = self._next_cycle(k, t0, record)
            if self.live is not None:
                self.live.send(record.recorder, record.cycles, force=True)
        except StartupError:
            raise  # no first frame: nothing ran (the command's exit 2)
        except Exception as exc:  # noqa: BLE001 - kept with the rows so far; the valves vent below
            record.error = f"{type(exc).__name__}: {exc}".splitlines()[0]
            record.error_traceback = "".join(traceback.format_exception(exc))
        finally:
            if in_main:
                signal.signal(signal.SIGINT, previous)
            final = self.link.vent()
            record.final_vent_acked = final.ok
            record.link_stats = self.link.stats().to_dict()
            record.fault = self.step.fault
            try:
                self.perception.close()
            finally:
                record.perception_stats = self.perception.stats()
        return record

    def _next_cycle(self, k: int, t0: float, record: HardwareLog) -> int:
        """The cycle after k: k + 1, or, when the loop is already past that cycle's slot (a
        stall: a slow filter, a blocked link), the cycle whose slot it is in now; the cycles
        in between are skipped (counted in `cycles_skipped`), not fired back to back."""
        now_slot = math.floor((self.clock() - t0) / self.period_s)
        following = max(k + 1, now_slot)
        record.skipped += following - (k + 1)
        return following

    def _cycle(self, k: int, t0: float, interrupted: bool, record: HardwareLog) -> SafeAction:
        now, est = self.perception.query()
        t_run = now - t0
        flags = SafetyFlags(perception_stale=est.stale, link_lost=self.link.link_lost, interrupted=interrupted)
        step = self.step(Estimate(t_run, est.q, est.qd, est.t - t0), flags)
        if "command_nonfinite" in step.reasons:
            log.warning("cycle %d: the controller refused its input or returned a non-finite command; the safety "
                        "monitor holds", k)
        record.reasons.update(step.reasons)
        if step.action is SafeAction.VENT:
            sent: LinkResult = self.link.vent()
        else:
            sent = self.link.send_setpoints(np.zeros(self.step.n) if self.dry_run else step.u)
        measured = [math.nan] * self.step.n if sent.ack is None else np.asarray(sent.ack.measured, dtype=float).tolist()
        values = [t_run, now, *np.asarray(est.q, dtype=float).tolist(), *np.asarray(est.qd, dtype=float).tolist(),
                  est.age_s, *np.asarray(sent.sent, dtype=float).tolist(), *measured,
                  math.nan if sent.latency_s is None else sent.latency_s, max(0.0, now - (t0 + k * self.period_s))]
        record.recorder.record(record.cycles, step, True, values, [est.stale, sent.ok, sent.link_lost])
        record.cycles += 1
        return step.action
