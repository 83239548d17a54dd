"""The closed loop's up-front duration check (issue 14, L3): steps, and memory against what is available."""

import os
import tracemalloc

import numpy as np
import pytest

import softcbf_mj.loops.loop
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter
from closedloop.step import ControlStep
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.contract.safety_filter import FilterContext
from scenarios.common import build_safe_set
from softcbf_mj.loops.loop import check_duration, run_closed_loop, series_bytes_needed
from softcbf_mj.physics.pcc_plant import PCCPlant

SAFE_SET = build_safe_set("paper", 11.16, 0.16, "paper")


def test_bytes_needed_covers_the_measured_peak_of_a_run_within_25_percent():
    """tracemalloc's peak over run_closed_loop (numpy reports its buffers to it) against the estimate. A short run first
    loads what a first run in a process loads once (numba's kernels, lazy imports, solver set-up): traced, those
    allocations exceeded the series' own when this test ran first in its process (alone, or on a pytest-xdist worker)."""
    robot = reference_robot()

    def plant_and_step():
        plant = PCCPlant(robot, SAFE_SET, control_dt=1e-3)
        controller = CBFFilter(robot, SAFE_SET, get_tuning("High"), dynamics=plant.dynamics)
        return plant, ControlStep(controller, SinusoidNominal.paper(2, 80.0, 0.01), FilterContext.for_robot(robot, SAFE_SET, 1e-3))

    run_closed_loop(*plant_and_step(), SAFE_SET, 0.05, np.zeros(2))
    plant, step = plant_and_step()
    n_steps = 2000
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        run_closed_loop(plant, step, SAFE_SET, n_steps * 1e-3, np.zeros(2))
        peak = tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()
    needed = series_bytes_needed(n_steps, 2, SAFE_SET)
    assert peak <= needed <= 1.25 * peak, (peak, needed)


def test_check_duration_counts_steps_and_names_duration():
    assert check_duration(0.5, 1e-3, 2, SAFE_SET) == 500
    assert check_duration(0.0015, 1e-3, 2, SAFE_SET) == 2  # rounded to the nearest period
    for bad in (float("inf"), float("nan"), 0.0, -1.0):
        with pytest.raises(ValueError, match="duration must be finite and > 0 s"):
            check_duration(bad, 1e-3, 2, SAFE_SET)
    with pytest.raises(ValueError, match=r"duration must cover at least one control period \(1000 s\), got 0.5 s"):
        check_duration(0.5, 1000.0, 2, SAFE_SET)


def test_check_duration_refuses_what_does_not_fit_in_the_available_memory(monkeypatch):
    per_step = series_bytes_needed(1, 2, SAFE_SET)
    monkeypatch.setattr(softcbf_mj.loops.loop, "available_memory_bytes", lambda: 1000 * per_step)
    assert check_duration(1.0, 1e-3, 2, SAFE_SET) == 1000
    with pytest.raises(ValueError, match=r"duration 1.001 s \(1001 steps of 0.001 s\) needs .* GiB for its time series, "
                                         r"more than the .* GiB of memory available"):
        check_duration(1.001, 1e-3, 2, SAFE_SET)


def test_available_memory_is_positive_and_at_most_the_machine():
    total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    assert 0 < softcbf_mj.loops.loop.available_memory_bytes() <= total
