"""Cost of the live view (softcbf_mj.outputs.recording.LiveRun) to the simulated closed loop.

The paper's loop (PCC plant, sinusoid into the facet, CBF filter with the Low tuning, 1 kHz)
runs `--duration` s, `--repeats` times each without a live stream and with one (a
LiveRun sending every LIVE_PERIOD_S to a rerun memory sink, drained after each run),
alternating, so drifting machine load biases neither. Times: the loop thread's CPU time
(`time.thread_time`: what slows the loop; other processes on a shared machine do not
count), this process's CPU time (`time.process_time`: also rerun's own encoder threads,
which run on another core where there is one) and the wall time. Prints the median of
each and the slowdown; the LiveRun's own count of its sends and of the loop thread's CPU
time in them (`LiveRun.send_cpu_s`), as a share of the loop's other CPU time: the
slowdown of a loop with a core to itself, which the whole-run times on a busy machine
are too noisy to resolve; then one line of JSON.

Usage: python tools/bench_live.py [--duration 10] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import rerun as rr

from closedloop.step import ControlStep
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.safety_filter import FilterContext
from scenarios.common import scene_record
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant
from softcbf_mj.outputs.recording import APP_ID, LIVE_PERIOD_S, live_run, live_stream
from timing import emit

PLATE_STIFFNESS = 11.16  # N/m, paper_sim's default
CLOCKS = ("thread_cpu", "process_cpu", "wall")  # the order of one_run's times


def one_run(duration: float, live: bool, sink_stream: rr.RecordingStream, sink) -> tuple[float, ...]:
    """(thread CPU s, process CPU s, wall s, bytes streamed, sends, the sends' CPU s) of one run."""
    robot, safe_set = reference_robot(), paper_safe_set()
    step = ControlStep(CBFFilter(robot, safe_set, get_tuning("Low")), SinusoidNominal.paper(robot.n_segments),
                       FilterContext.for_robot(robot, safe_set, 1e-3, False))
    plant = PCCPlant(robot, safe_set)
    thread, cpu, wall = time.thread_time(), time.process_time(), time.perf_counter()
    with live_stream(sink_stream):
        stream = live_run(scene_record(robot, safe_set, PLATE_STIFFNESS), "Low", 0, plant.control_dt) if live else None
        run_closed_loop(plant, step, safe_set, duration, np.zeros(robot.n_segments), live=stream)
        sink_stream.flush()
    thread, cpu, wall = time.thread_time() - thread, time.process_time() - cpu, time.perf_counter() - wall
    return thread, cpu, wall, len(sink.drain_as_bytes()), stream.sends if live else 0, stream.send_cpu_s if live else 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=10.0, help="simulated s per run")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    stream = rr.RecordingStream(APP_ID)
    sink = stream.memory_recording()
    results: dict[bool, list[tuple[float, ...]]] = {False: [], True: []}
    for _ in range(args.repeats):
        for live in (False, True):
            results[live].append(one_run(args.duration, live, stream, sink))
    figures = {}
    for live, runs in results.items():
        name = "live" if live else "plain"
        for i, clock in enumerate(CLOCKS):
            figures[f"{name}_{clock}_s"] = round(float(np.median([r[i] for r in runs])), 3)
    live_runs = results[True]
    figures["live_bytes_per_sim_s"] = round(float(np.median([r[3] for r in live_runs])) / args.duration)
    figures["sends_per_run"] = float(np.median([r[4] for r in live_runs]))
    figures["cpu_ms_per_send"] = round(1e3 * float(np.median([r[5] / r[4] for r in live_runs])), 2)
    # the loop thread's CPU in sends over its CPU without them: the slowdown of a loop with a core to itself
    figures["send_share_pct"] = round(100 * float(np.median([r[5] / (r[0] - r[5]) for r in live_runs])), 2)
    for clock in CLOCKS:
        figures[f"{clock}_slowdown_pct"] = round(100 * (figures[f"live_{clock}_s"] / figures[f"plain_{clock}_s"] - 1), 2)
    print(f"{args.duration:g} s simulated at 1 kHz, live period {LIVE_PERIOD_S * 1e3:g} ms, median of {args.repeats}:")
    for clock in CLOCKS:
        print(f"  {clock:12s} plain {figures[f'plain_{clock}_s']:.3f} s, live {figures[f'live_{clock}_s']:.3f} s "
              f"({figures[f'{clock}_slowdown_pct']:+.2f} %)")
    print(f"  streamed {figures['live_bytes_per_sim_s'] / 1e3:.1f} kB per simulated s in {figures['sends_per_run']:g} sends "
          f"of {figures['cpu_ms_per_send']:.2f} ms CPU each: {figures['send_share_pct']:.2f} % of the loop thread's CPU")
    emit({"duration_s": args.duration, "repeats": args.repeats, "live_period_s": LIVE_PERIOD_S, **figures})


if __name__ == "__main__":
    main()
