"""The benchmarks' shared timing (tools/timing.py), the serial-loop benchmark (tools/bench_serial_loop.py) and the
replays it shares with tools/bench_mujoco_contact.py: block timing, the figures by hand, argument checks."""

import importlib.util
import itertools
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from softcbf_mj.physics.mujoco_plant import MujocoPlant

TOOLS = Path(__file__).resolve().parents[1] / "tools"


def _tool(name: str):
    """The tool's module, loaded as `python tools/NAME.py` runs it: tools/ on sys.path (its sibling imports)."""
    if str(TOOLS) not in sys.path:
        sys.path.append(str(TOOLS))
    spec = importlib.util.spec_from_file_location(name, TOOLS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


contact_bench, serial_bench, timing = _tool("bench_mujoco_contact"), _tool("bench_serial_loop"), _tool("timing")


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


def test_the_replay_without_the_state_read_steps_the_plant_as_before():
    """`replay_without_state` takes the same physics as `MujocoPlant.step` with its state read, and the plant reads
    its state again afterwards."""
    plant = MujocoPlant.from_config(links_per_segment=2)
    u = np.full((30, 2), 150.0)
    assert serial_bench.replay_without_state(plant, u) >= 0.0
    qpos = plant.data.qpos.copy()
    plant.reset(np.zeros(2))
    for command in u:
        state = plant.step(command)
    assert plant.data.qpos.tobytes() == qpos.tobytes() and state.t == plant.data.time > 0.0


def test_figures_by_hand():
    """1000 steps: loop 0.4 s CPU (0.5 s wall), mj_step 0.2 s (0.25 s), plant 0.25 s (0.24 s without its state read)."""
    best = {"t_loop": 0.4, "t_mj_step": 0.2, "t_plant": 0.25, "t_plant_no_state": 0.24, "wall_loop": 0.5,
            "wall_mj_step": 0.25, "wall_plant": 0.3, "steps": 1000, "filter_us": 60.0}
    got = serial_bench.figures(best)
    assert got["fraction"] == pytest.approx(0.5) and got["fraction_wall"] == pytest.approx(0.5)
    assert got["us_loop"] == pytest.approx(400.0) and got["us_physics"] == pytest.approx(200.0)
    assert got["us_plant_overhead"] == pytest.approx(50.0) and got["us_state_read"] == pytest.approx(10.0)
    assert got["us_controller_and_loop"] == pytest.approx(150.0) and got["us_filter_wall"] == 60.0


@pytest.mark.parametrize("args, message", [(["--duration", "0"], "--duration must be finite and > 0"),
                                           (["--tunings", ","], "--tunings must name at least one tuning"),
                                           (["--repeats", "0"], "--repeats must be >= 1"),
                                           (["--against", "/nonexistent"], "--against must be a tree of this project")])
def test_bad_arguments_are_refused_by_name(args, message):
    done = subprocess.run([sys.executable, str(TOOLS / "bench_serial_loop.py"), *args], capture_output=True, text=True)
    assert done.returncode == 2 and message in done.stderr


def test_a_tuning_is_the_paper_cbfs_or_another_filter_with_its_defaults():
    assert [serial_bench.run_params(t) for t in ("None", "Low", "c-erg:recommended")] == [
        {"tunings": "None"}, {"tunings": "Low"}, {"filter": "c-erg:recommended"}]


def test_timing_summaries_match_numpy_and_refuse_what_they_do_not_know():
    times = list(np.random.default_rng(0).exponential(20.0, 501))
    got = timing.summary_us(times, ("median", "p99", "mean", "min", "max"), digits=9)
    assert got == pytest.approx({"median_us": np.median(times), "p99_us": np.percentile(times, 99), "mean_us": np.mean(times),
                                 "min_us": min(times), "max_us": max(times)}, abs=1e-9)
    assert timing.summary_us([1.0, 2.0]) == {"median_us": 1.5, "p99_us": 1.99}
    with pytest.raises(ValueError, match="unknown summary 'p95'; known: median, p99, mean, min, max"):
        timing.summary_us(times, ("p95",))
    with pytest.raises(ValueError, match="no times to summarise"):
        timing.summary_us([])
    with pytest.raises(ValueError, match="clock must be one of cpu, wall, got 'gpu'"):
        timing.call_us(lambda: None, "gpu")
    with pytest.raises(ValueError, match="repeats must be >= 1, got 0"):
        timing.best_of(0, lambda: None)


def test_best_of_keeps_each_clock_s_minimum_and_the_last_result():
    """Three runs, the second the longest: each minimum is the first or third run's, far below the second's."""
    calls = []

    def run():
        calls.append(len(calls))
        # Burn until both clocks have passed: the process's CPU time counts every thread's, so it may run ahead of
        # the wall clock when a library thread works beside this one.
        span = 0.05 if len(calls) == 2 else 0.005
        cpu_end, wall_end = timing.time.process_time() + span, timing.time.perf_counter() + span
        while timing.time.process_time() < cpu_end or timing.time.perf_counter() < wall_end:
            pass
        return len(calls)

    result, best = timing.best_of(3, run)
    assert result == 3 and calls == [0, 1, 2]
    assert 0.005 <= best.cpu < 0.05 and 0.005 <= best.wall < 0.05


def test_a_child_s_cpu_time_is_counted_and_a_failing_child_raises():
    burn = [sys.executable, "-c", "import time\nend = time.process_time() + 0.2\nwhile time.process_time() < end: pass"]
    took = timing.child_timing(burn)
    assert took.cpu >= 0.2 and took.wall >= 0.2
    with pytest.raises(subprocess.CalledProcessError):
        timing.child_timing([sys.executable, "-c", "raise SystemExit(3)"])


def test_per_call_and_per_call_clock_figures():
    assert timing.per_call_us(lambda i: None, 1000, repeats=2) < 100.0
    assert len(timing.calls_us(max, [(1, 2), (3, 4), (5, 6)], clock="cpu")) == 3
    value, us = timing.call_us(lambda: 7)
    assert value == 7 and us >= 0.0


def test_the_speed_record_plots_its_history_and_refuses_a_bad_line_or_benchmark(tmp_path):
    """tools/speed_record.py --plot on a history of two entries (the figures as the suite writes them)."""
    entry = {"commit": "0123456789ab", "dirty": False, "date": "2026-01-01T00:00:00Z", "python": "3.11", "mujoco": "4",
             "machine": {"machine": "x86_64", "processor": "cpu", "cpus": 2, "load_1min": 1.0, "load_1min_end": 1.2},
             "seconds": 300.0, "figures": {"mj_step_L10": 46000.0, "serial_fraction_None": 0.66}}
    later = {**entry, "commit": "89abcdef0123", "figures": {"mj_step_L10": 23000.0, "camera_rtf": 4.1}}
    history = tmp_path / "history.jsonl"
    history.write_text(json.dumps(entry) + "\n" + json.dumps(later) + "\n", encoding="utf-8")
    tool = [sys.executable, str(TOOLS / "speed_record.py")]
    done = subprocess.run([*tool, "--plot", "--history", str(history), "--figure", str(tmp_path / "f.png")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert json.loads(done.stdout.splitlines()[-1]) == {"figure": str(tmp_path / "f.png"), "entries": 2}
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    history.write_text(json.dumps(entry) + "\nnot json\n", encoding="utf-8")
    done = subprocess.run([*tool, "--plot", "--history", str(history)], capture_output=True, text=True)
    assert done.returncode == 2 and f"{history}:2: not a JSON line" in done.stderr
    done = subprocess.run([*tool, "--only", "mj_step,warp"], capture_output=True, text=True)
    assert done.returncode == 2 and "--only: 'warp' is not one of mj_step, serial_loop" in done.stderr
