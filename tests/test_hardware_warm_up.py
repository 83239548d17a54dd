"""The hardware loop's warm-up (hardware.runner): the filter's compiled kernels load before the real-time loop.

The first run of a fresh process, on a cold numba cache (NUMBA_CACHE_DIR an empty folder: every kernel compiles,
as on a fresh clone), keeps every cycle's filter call within the control period, through the arm's first contact
with the plate, and the board's watchdog never vents. Without the warm-up the first cycle compiled (tens of
seconds: the run skipped its cycles) and, from a warm cache, the first cycle and the first contact loaded kernels
(0.06–0.2 s; the 0.15 s watchdog vented). Run in a subprocess, in real time (`xdist_group("realtime")`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hardware.config import HardwareConfig
from hardware.runner import WARM_UP_MARGINS, controller_context, warm_up_states
from controllers.model.pcc import segment_ends

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "hardware_emulated.toml"
# c-erg for 7 s: the arm presses the plate from about 4 s on (the sinusoid peaks at 5 s). A link slow to
# acknowledge (a loaded machine: other tests, other jobs) would vent the arm before it gets there; what is checked
# is the filter, so the link waits longer (3 × 30 ms, within the 0.1 s period) and is lost after 3 failures.
OVERRIDES = {"filter": "c-erg", "duration": 7.0, "link": {"ack_timeout_s": 0.03, "lost_after": 3}}
# The first run of a process: the emulated hardware of EXAMPLE with c-erg; prints what the test checks.
DRIVER = """
import json, sys
from pathlib import Path
import numpy as np
from hardware.config import HardwareConfig
from softcbf_mj.emulator.emulate import EmulatedHardware
from softcbf.hardware_cli import run_hardware
from softcbf_mj.outputs.runio import load_timeseries
config = HardwareConfig.load(Path(sys.argv[1])).with_overrides(json.loads(sys.argv[3]))
out = Path(sys.argv[2])
with EmulatedHardware(config) as emulation:
    out.mkdir()
    row = run_hardware(config, out, emulation=emulation, report=False)
truth = emulation.emulator.record()
series, _ = load_timeseries(out / row["timeseries"])
touching = np.flatnonzero(truth["contact_force"] > 0.0)
print(json.dumps({"filter_us": series["filter_us"].tolist(), "t": series["t"].tolist(),
                  "watchdog_vents": row["watchdog_vents"],
                  "t_clock": series["t_clock"].tolist(),
                  "t_first_contact": float(truth["t"][touching[0]]) if touching.size else None}))
"""


@pytest.mark.slow
@pytest.mark.xdist_group("realtime")
def test_the_first_run_on_a_cold_cache_keeps_the_cycle_budget_through_the_first_contact(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "numba")}  # empty: every kernel compiles
    done = subprocess.run([sys.executable, "-c", DRIVER, str(EXAMPLE), str(tmp_path / "run"), json.dumps(OVERRIDES)],
                          env=env, cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout.splitlines()[-1])
    period_us = HardwareConfig.load(EXAMPLE).control.period_s * 1e6
    t, filter_us = np.array(result["t"]), np.array(result["filter_us"])
    slow = t[filter_us >= period_us]  # NaN (a HOLD cycle: no filter call) is not slow
    assert slow.size == 0, f"filter calls over the {period_us / 1e3:.0f} ms period at t = {slow} s"
    assert result["t_first_contact"] is not None and result["t_first_contact"] < result["t_clock"][-1], \
        "the arm never touched the plate"
    assert result["watchdog_vents"] == 0


def test_the_warm_up_states_reach_from_the_straight_arm_past_the_plate_moving_toward_it():
    config = HardwareConfig.load(EXAMPLE)
    context = controller_context(config)
    states = warm_up_states(context)
    lengths = np.array(context.robot.lengths)
    margins = np.array([float(context.safe_set.margin(segment_ends(q, lengths)[-1])) for q, _ in states])
    assert margins.max() == 1.0 and margins.min() <= WARM_UP_MARGINS[-1] + 0.05  # straight, and past the plate
    for level in WARM_UP_MARGINS:  # each margin of the list is met within the bisection's tolerance
        assert np.min(np.abs(margins - level)) < 0.05, level
    for q, qd in states:
        assert q.shape == qd.shape == (context.robot.n_segments,)
        assert np.all(qd == 0.0) or np.all(qd * q >= 0.0)  # at rest or bending further
