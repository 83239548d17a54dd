"""End to end against the emulator: the hardware loop (camera → perception → CBFFilter → safety →
pty link) drives the MuJoCo arm behind an emulated valve board, seen by a virtual camera.

Runs in real time (≈ 15 s of wall clock for the file). The arm is
examples/hardware_slow_arm_robot.json (the reference arm with 20× its damping) and the
nominal command the paper's sinusoid at 80 hPa and 0.05 Hz, so the arm meets the plate
within 3 s (examples/hardware_emulated.toml; why: docs/hardware.md). Safety is
asserted on the emulated board's record of applied pressures (`ValveBoard.applied()`).

A cycle's deadline is its slot t_0 + k·T plus the lateness the loop recorded for it (`late_s`, max(0, start − slot)):
on a loaded machine a cycle starts late, and what is checked is that the hold and the vent come at the first slot
after their condition, not how busy the machine was. The tests run one at a time on one pytest-xdist worker
(`xdist_group("realtime")`, with the suite's other wall-clock tests) and are `slow` (seconds of real time each).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rerun as rr

from hardware.config import HardwareConfig
from hardware.runner import ACTION_CODES
from closedloop.monitor import SafeAction
from hardware.transport import LineFaults
from softcbf_mj.emulator.emulate import EmulatedHardware
from softcbf.hardware_cli import SAVED_FRAMES_HZ, run_hardware
from softcbf_mj.outputs.runio import load_timeseries, read_run_folder

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "hardware_emulated.toml"
FAULT_AT_S = 1.0  # s after the start: blackout / cut
SCHEDULE_TOL_S = 0.03  # the signal's handling: the cut-short wait ends this soon after SIGINT (measured ≤ 10 ms)
FIXED_POINT_HPA = 0.05  # half a count of the protocol's 0.1 hPa fixed point
RUN, HOLD, VENT = (ACTION_CODES[a] for a in (SafeAction.RUN, SafeAction.HOLD, SafeAction.VENT))
pytestmark = [pytest.mark.xdist_group("realtime"), pytest.mark.slow]


def _config(**changes) -> HardwareConfig:
    return HardwareConfig.load(EXAMPLE).with_overrides(changes)


def _run(config: HardwareConfig, out: Path, fault=None, report: bool = False):
    """Run `config` against a fresh emulator; `fault(emulation)` is called once at FAULT_AT_S."""
    with EmulatedHardware(config) as emulation:
        done = []

        def on_cycle(k: int, t: float, action: SafeAction) -> None:
            if fault is not None and not done and t >= FAULT_AT_S:
                fault(emulation)
                done.append(t)

        out.mkdir()
        row = run_hardware(config, out, emulation=emulation, on_cycle=on_cycle, report=report)
    series, _ = load_timeseries(out / row["timeseries"])
    return row, series, emulation


def test_the_contact_governor_keeps_the_true_plate_force_below_f_max_and_writes_the_run_folder(tmp_path):
    # c-erg, whose certificate covers the sampled, delayed loop. paper-cbf High reached 0.13-0.16 N here from run to
    # run (the real-time loop's timing; 0.1608 and 0.1615 N > F_max in 2 of about 20 runs, before and now): this
    # arm's d/k = 1.4 s lies where docs/hardware_envelope.md's map has the paper's CBF violate at 10 Hz.
    config = _config(filter="c-erg", duration=7.0)
    row, series, emulation = _run(config, tmp_path / "run", report=True)
    truth = emulation.emulator.record()
    f_max = config.environment.f_max
    assert 0.03 < truth["contact_force"].max() < f_max  # the arm presses the plate, below F_max (measured 0.056-0.061 N)
    assert row["force_max_emulator_N"] == pytest.approx(truth["contact_force"].max(), rel=1e-12)
    assert row["t_violation_emulator_s"] == 0.0 and row["force_max_N"] < f_max
    # a late frame on the loaded machine may make a cycle HOLD (measured 0–1 of 70); nothing vents
    assert np.count_nonzero(series["action"] == HOLD) <= 3 and not np.any(series["action"] == VENT)
    assert set(row["flags"]) <= {"perception_stale"} and row["link_acked_fraction"] == 1.0
    # 70 scheduled cycles; a stall of the loaded machine skips cycles rather than bursting them
    assert row["cycles"] + row["cycles_skipped"] == 70 and row["cycles_skipped"] <= 3
    assert row["cycles_run"] + row["cycles_hold"] == row["cycles"] and row["final_vent_acked"]
    # the board applied what the loop sent (±half a fixed-point count), within the pressure limits
    t_applied, u_applied = emulation.board.applied_arrays()
    assert np.all(np.abs(u_applied) <= 150.0)
    for t, u in zip(series["t_clock"], series["u_sent"]):
        k = np.searchsorted(t_applied, t)  # the first output change after the cycle started: its SETPOINT
        np.testing.assert_allclose(u_applied[k], u, atol=FIXED_POINT_HPA)
    # the camera's estimate is the true bend at its capture time (16 px tags at 480 × 270: measured 0.034–0.060 rad max)
    assert np.max(np.abs(series["q_est"] - emulation.emulator.state_at(series["t_clock"] - series["est_age_s"])["q"])) < 0.1
    folder = read_run_folder(tmp_path / "run")
    assert folder.summary["scenario"] == "hardware" and folder.labels == ["c-erg"]
    for key in ("rho_min_pred", "rho_min_meas", "force_max_N", "t_violation_s", "infeasible_steps", "recovery_steps",
                "filter_us_median", "filter_us_p99", "wall_s", "sim_s"):
        assert key in row
    store = rr.chunk.RrdReader(str(tmp_path / "run" / "recording.rrd")).stream().collect()
    assert "/runs/c-erg/force" in {str(p) for p in store.schema().entity_paths()}
    # camera frames kept at SAVED_FRAMES_HZ over the 7 s run, each in the recording at its time
    frames = folder.frames("c-erg")
    times = np.array([f["t"] for f in frames])
    assert 7.0 * SAVED_FRAMES_HZ - 2 <= len(frames) <= 7.0 * SAVED_FRAMES_HZ + 1
    assert np.all(np.diff(times) >= 1.0 / SAVED_FRAMES_HZ) and all(len(f["detections"]) >= 1 for f in frames)
    images = [c for c in store.stream() if c.entity_path == "/runs/c-erg/camera/image"]
    logged = np.sort(np.concatenate([c.to_record_batch().column("sim_time").cast("int64").to_numpy() for c in images]))
    np.testing.assert_allclose(logged * 1e-9, times, atol=1e-9)


def test_perception_blackout_holds_within_one_cycle_then_vents(tmp_path):
    config = _config(max_hold_s=0.2, hold_s=0.3, duration=2.5)

    def blackout(emulation):
        emulation.camera.blackout = True

    row, s, emulation = _run(config, tmp_path / "run", blackout)
    period, t = config.control.period_s, s["t_clock"]
    stale = np.flatnonzero(s["est_stale"])
    first = stale[0]
    assert np.all(s["action"][:first] == RUN) and s["action"][first] == HOLD
    # stale at the first cycle after the last frame's estimate aged past max_hold_s
    t_last_frame = t[first] - s["est_age_s"][first]
    late = s["late_s"]
    assert t_last_frame + 0.2 < t[first] <= t_last_frame + 0.2 + period + late[first]
    # HOLD: the board keeps the last RUN command until the vent, which comes once the hold lasted hold_s
    vent_cycle = first + np.argmax(s["action"][first:] == VENT)
    assert np.all(s["action"][first:vent_cycle] == HOLD) and np.all(s["action"][vent_cycle:] == VENT)
    assert t[first] + 0.3 <= t[vent_cycle] <= t[first] + 0.3 + period + late[vent_cycle]
    log = emulation.board.applied()
    held = [a for a in log if t[first] <= a.t < t[vent_cycle]]
    assert held and all(a.reason == "setpoint" for a in held)
    np.testing.assert_allclose([a.u for a in held], np.tile(s["u"][first - 1], (len(held), 1)), atol=FIXED_POINT_HPA)
    vents = [a for a in log if a.t >= t[vent_cycle]]
    assert vents[0].reason == "vent" and vents[0].t - t[vent_cycle] < 0.02 and vents[0].u == (0.0, 0.0)
    assert all(a.u == (0.0, 0.0) for a in vents)


def test_link_cut_vents_the_board_by_its_watchdog_and_the_laptop_within_one_cycle(tmp_path):
    config = _config(duration=2.0)

    def cut(emulation):
        emulation.line.faults = LineFaults.cut()

    row, s, emulation = _run(config, tmp_path / "run", cut)
    t = s["t_clock"]
    failed = np.flatnonzero(~s["link_acked"])
    assert failed.size and t[failed[0]] - FAULT_AT_S >= 0 and np.all(s["action"][: failed[0] + 1] == RUN)
    # the laptop: the cycle after the first failed exchange vents, and every later one
    assert np.all(s["action"][failed[0] + 1:] == VENT)
    # the board: nothing arrives after the cut; its watchdog vents watchdog_s after the last SETPOINT
    log = emulation.board.applied()
    last_setpoint = max(a.t for a in log if a.reason == "setpoint")
    watchdog = [a for a in log if a.reason == "watchdog"]
    assert len(watchdog) == 1 and watchdog[0].u == (0.0, 0.0)
    assert 0.15 < watchdog[0].t - last_setpoint < 0.15 + 0.005  # 1 ms board tick, loaded machine
    assert last_setpoint < t[failed[0]] + 0.001 and not [a for a in log if a.t > watchdog[0].t]
    assert row["final_vent_acked"] is False


def test_ctrl_c_vents_within_one_cycle_and_exits_130(tmp_path):
    """SIGINT to a running `softcbf hardware` process: the next cycle vents, the board's
    outputs go to 0 hPa, the run folder is written and the exit code is 130."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "run"
    process = subprocess.Popen(
        [sys.executable, "-m", "softcbf.hardware_cli", str(EXAMPLE), "--duration", "30", "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "PYTHONPATH": str(EXAMPLE.parents[1])},
    )
    deadline = time.monotonic() + 60
    while not out.is_dir() and time.monotonic() < deadline and process.poll() is None:
        time.sleep(0.1)  # the folder appears when the command starts
    time.sleep(10.0)  # imports, the emulator and the first complete frame take ≈ 3–6 s here
    t_signal = time.monotonic()  # CLOCK_MONOTONIC: the same clock as the loop's t_clock
    process.send_signal(signal.SIGINT)
    output, _ = process.communicate(timeout=60)
    assert process.returncode == 130, output
    row = read_run_folder(out).summary["runs"][0]
    assert row["interrupted"] is True and row["final_vent_acked"] is True
    s, _ = load_timeseries(out / row["timeseries"])
    t = s["t_clock"]
    assert t[0] < t_signal  # the loop was running
    vent = np.flatnonzero(s["action"] == VENT)
    assert vent.size == 1 and vent[0] == len(t) - 1 and np.all(s["action"][:-1] != VENT)
    period = HardwareConfig.load(EXAMPLE).control.period_s
    assert t_signal <= t[-1] <= t_signal + SCHEDULE_TOL_S  # the wait is cut short: it vents at once
    assert t[-1] - t[-2] <= period + SCHEDULE_TOL_S
    truth, _ = load_timeseries(out / row["timeseries"].replace(".npz", "_emulator.npz"))
    after = truth["t"] > t[-1] + 0.02  # the board's record, 20 ms after the vent cycle
    assert np.any(after) and np.all(truth["u"][after] == 0.0)
