"""The serial-loop benchmark (tools/bench_serial_loop.py) and the replays it shares with
tools/bench_mujoco_contact.py: block timing, the figures by hand, argument checks."""

import importlib.util
import itertools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from softcbf_mj.mujoco_plant import MujocoPlant

TOOLS = Path(__file__).resolve().parents[1] / "tools"


def _tool(name: str):
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


contact_bench, serial_bench = _tool("bench_mujoco_contact"), _tool("bench_serial_loop")


def ticks():
    """A clock that advances by 1 at every reading: a block's time is 1, whatever it runs."""
    return itertools.count().__next__


@pytest.mark.parametrize("block, blocks", [(3, 3), (7, 1), (1, 7)])
def test_replays_time_blocks_of_the_given_size_with_the_given_clock(block, blocks):
    plant = MujocoPlant.from_config(links_per_segment=2)
    u = np.full((7, 2), 100.0)
    assert contact_bench.replay_mj_step(plant, u, 2, block=block, clock=ticks()) == blocks
    seconds, tip, force = contact_bench.replay_plant(plant, u, 2, block=block, clock=ticks())
    assert seconds == blocks and tip.shape == (7, 2) and force.shape == (7, plant.n_facets)


def test_figures_by_hand():
    """1000 steps: loop 0.4 s CPU (0.5 s wall), mj_step 0.2 s (0.25 s), plant 0.25 s."""
    best = {"t_loop": 0.4, "t_mj_step": 0.2, "t_plant": 0.25, "wall_loop": 0.5, "wall_mj_step": 0.25,
            "wall_plant": 0.3, "steps": 1000, "filter_us": 60.0}
    got = serial_bench.figures(best)
    assert got["fraction"] == pytest.approx(0.5) and got["fraction_wall"] == pytest.approx(0.5)
    assert got["us_loop"] == pytest.approx(400.0) and got["us_physics"] == pytest.approx(200.0)
    assert got["us_plant_overhead"] == pytest.approx(50.0)
    assert got["us_controller_and_loop"] == pytest.approx(150.0) and got["us_filter_wall"] == 60.0


@pytest.mark.parametrize("args, message", [(["--duration", "0"], "--duration must be finite and > 0"),
                                           (["--tunings", ","], "--tunings must name at least one tuning"),
                                           (["--repeats", "0"], "--repeats must be >= 1"),
                                           (["--against", "/nonexistent"], "--against must be a tree of this project")])
def test_bad_arguments_are_refused_by_name(args, message):
    done = subprocess.run([sys.executable, str(TOOLS / "bench_serial_loop.py"), *args], capture_output=True, text=True)
    assert done.returncode == 2 and message in done.stderr
