"""Speed of the `mujoco_contact` scenario: real-time factor with the filter in the loop, and
what limits it.

1. Runs `mujoco_contact` (defaults unless overridden; `--duration` shorter than the
   scenario's 100 s samples only the start of the 100 s sinusoid: the arm is in
   contact from ≈ 16 s to ≈ 45 s, so a short run from t0 = 0 under-weights contact —
   use `--t0` to move the window) `--loop-repeats` times and takes each tuning's
   real-time factor RTF = simulated s / wall s of the fastest of its closed-loop runs
   (`realtime_factor` in summary.json).
2. Replays each tuning's logged command sequence u open-loop on the same model:
   through `MujocoPlant.step` (the bare plant: physics + `mj_forward` + state) and
   through bare `mj_step(nstep = control period / physics step)` (physics only), so
   all three timings follow the same trajectory. Per control step (µs): physics,
   plant overhead, filter (the loop's own timing) and the rest of the loop.
3. Sweeps the physics settings (links per segment n, physics step dt): the bare
   plant's RTF on the replayed `--replay-tuning` commands, its discretisation error
   against the default setting on that trajectory (max tip error, mm; max and peak
   plate-force error, mN), and the closed-loop RTF projected as
   1 / (1/RTF_plant(n, dt) + c), c = 1/RTF_loop − 1/RTF_plant(default) the
   controller's and loop's wall seconds per simulated second (measured in 1 and 2).

Timings are wall clock on one thread; a replay's time is the sum over blocks of 500
control steps of each block's best over `--repeats` replays (robust to other jobs on a
shared machine; the closed loop itself runs once). Usage:
`python tools/bench_mujoco_contact.py [--duration 100] [--tunings None,Low,High]`;
prints tables and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import os
import platform
import tempfile
import time
from pathlib import Path
from typing import Callable

import mujoco
import numpy as np

from scenarios.mujoco_contact import CONTROL_DT, mujoco_contact
from softcbf_mj.physics.mjcf import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.outputs.runio import load_timeseries
from timing import emit

TARGET_RTF = 10.0
BLOCK = 500  # control steps per timed block of a replay
SWEEP = ((10, 1e-4), (10, 2e-4), (10, 2.5e-4), (10, 5e-4), (10, 1e-3), (5, 2.5e-4), (5, 5e-4), (5, 1e-3))


def _plant(n: int, dt: float) -> MujocoPlant:
    return MujocoPlant.from_config(control_dt=CONTROL_DT, links_per_segment=n, physics_dt=dt)


def _blocks(steps: int, block: int) -> list[slice]:
    return [slice(k, min(k + block, steps)) for k in range(0, steps, block)]


def replay_plant(plant: MujocoPlant, u: np.ndarray, repeats: int, block: int = BLOCK,
                 clock: Callable[[], float] = time.perf_counter) -> tuple[float, np.ndarray, np.ndarray]:
    """(s, tip (T, 2) m, plate force (T, P) N) of `MujocoPlant.step` over the commands u (T, N).

    Time (`clock`, default wall): the sum over blocks of `block` steps of each block's best
    time over `repeats` identical replays (filters out other jobs' interference on a shared
    machine; `block` = T: the best whole replay).
    """
    blocks = _blocks(len(u), block)
    best = np.full(len(blocks), np.inf)
    tip, force = np.empty((len(u), 2)), np.empty((len(u), plant.n_facets))
    for _ in range(repeats):
        plant.reset(np.zeros(plant.n_segments))
        for b, steps in enumerate(blocks):
            start = clock()
            for k in range(steps.start, steps.stop):
                state = plant.step(u[k])
                tip[k], force[k] = state.segment_ends[-1], state.contact_forces
            best[b] = min(best[b], clock() - start)
    return float(best.sum()), tip, force


def replay_mj_step(plant: MujocoPlant, u: np.ndarray, repeats: int, block: int = BLOCK,
                   clock: Callable[[], float] = time.perf_counter) -> float:
    """s of bare `mj_step` (nstep per control period) over the commands u (T, N), timed as in `replay_plant`."""
    model, data = plant.model, mujoco.MjData(plant.model)
    if model.nu != u.shape[1]:
        raise ValueError(f"the model has {model.nu} actuators, the commands {u.shape[1]} columns")
    blocks = _blocks(len(u), block)
    best = np.full(len(blocks), np.inf)
    for _ in range(repeats):
        mujoco.mj_resetData(model, data)
        for b, steps in enumerate(blocks):
            start = clock()
            for command in u[steps]:
                data.ctrl[:] = command
                mujoco.mj_step(model, data, nstep=plant.steps_per_control)
            best[b] = min(best[b], clock() - start)
    return float(best.sum())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=100.0, help="simulated s per tuning (scenario default 100)")
    parser.add_argument("--t0", type=float, default=0.0, help="phase offset of the sinusoid (s)")
    parser.add_argument("--tunings", default="None,Low,High", help="tunings to run (scenario default None,Low,High)")
    parser.add_argument("--replay-tuning", default="Low", help="tuning whose commands the settings sweep replays")
    parser.add_argument("--loop-repeats", type=int, default=2, help="closed-loop runs per tuning; the fastest is kept")
    parser.add_argument("--repeats", type=int, default=3, help="replays per timing; each block's best is kept")
    args = parser.parse_args()
    tunings = [t.strip() for t in args.tunings.split(",")]
    if args.replay_tuning not in tunings:
        parser.error(f"--replay-tuning {args.replay_tuning!r} must be one of --tunings {tunings}")

    report: dict = {"mujoco": mujoco.__version__, "machine": platform.machine(), "cpus": os.cpu_count(),
                    "duration_s": args.duration, "t0_s": args.t0, "target_rtf": TARGET_RTF,
                    "default": {"links_per_segment": DEFAULT_LINKS_PER_SEGMENT, "physics_dt": DEFAULT_PHYSICS_DT}}
    walls: dict[str, list[float]] = {}
    for repeat in range(args.loop_repeats):
        with tempfile.TemporaryDirectory() as tmp:
            summary = mujoco_contact(Path(tmp), duration=args.duration, t0=args.t0, tunings=args.tunings, progress=False)
            for row in summary["runs"]:
                walls.setdefault(row["tuning"], []).append(row["wall_s"])
            if repeat == 0:  # the runs are deterministic: every repeat logs the same commands
                commands = {}
                for row in summary["runs"]:
                    log, _ = load_timeseries(Path(tmp) / row["timeseries"])
                    commands[row["tuning"]] = (log["u"], float(np.mean(log["filter_us"])))
    for row in summary["runs"]:
        row["wall_s"] = min(walls[row["tuning"]])

    default = _plant(DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT)
    print(f"\nclosed loop vs replays of the same commands (n = {DEFAULT_LINKS_PER_SEGMENT}, dt = {DEFAULT_PHYSICS_DT:g} s, "
          f"{default.steps_per_control} physics steps per 1 ms control step), µs per control step:")
    print("  tuning   RTF loop  RTF plant  RTF mj_step  loop/plant  loop/mj_step   physics  plant ovh  filter  loop rest")
    runs = []
    for row in summary["runs"]:
        u, filter_us = commands[row["tuning"]]
        steps = len(u)
        plant_s, _, _ = replay_plant(default, u, args.repeats)
        step_s = replay_mj_step(default, u, args.repeats)
        loop_us, plant_us, physics_us = row["wall_s"] / steps * 1e6, plant_s / steps * 1e6, step_s / steps * 1e6
        sim = steps * CONTROL_DT
        entry = {
            "tuning": row["tuning"], "rtf_loop": sim / row["wall_s"], "rtf_plant": sim / plant_s, "rtf_mj_step": sim / step_s,
            "us_physics": physics_us, "us_plant_overhead": plant_us - physics_us, "us_filter": filter_us,
            "us_loop_rest": loop_us - plant_us - filter_us, "t_contact_s": row["t_contact_s"],
        }
        entry["loop_over_plant"] = entry["rtf_loop"] / entry["rtf_plant"]
        entry["loop_over_mj_step"] = entry["rtf_loop"] / entry["rtf_mj_step"]
        runs.append(entry)
        print(f"  {entry['tuning']:7s} {entry['rtf_loop']:9.2f} {entry['rtf_plant']:10.2f} {entry['rtf_mj_step']:12.2f} "
              f"{entry['loop_over_plant']:11.2f} {entry['loop_over_mj_step']:13.2f} {physics_us:9.0f} "
              f"{entry['us_plant_overhead']:10.0f} {filter_us:7.0f} {entry['us_loop_rest']:10.0f}")
    total_sim = sum(r["sim_s"] for r in summary["runs"])
    total_wall = sum(r["wall_s"] for r in summary["runs"])
    report["runs"] = runs
    report["rtf_loop_all"] = total_sim / total_wall
    print(f"  all tunings: RTF {report['rtf_loop_all']:.2f} (target >= {TARGET_RTF:g}: "
          f"{'met' if report['rtf_loop_all'] >= TARGET_RTF else 'NOT met'})")

    replay = next(r for r in runs if r["tuning"] == args.replay_tuning)
    u = commands[args.replay_tuning][0]
    controller_s = 1.0 / replay["rtf_loop"] - 1.0 / replay["rtf_plant"]  # wall s per simulated s
    _, tip_ref, force_ref = replay_plant(default, u, 1)
    print(f"\nphysics settings, replaying {args.replay_tuning}'s commands (errors against n = {DEFAULT_LINKS_PER_SEGMENT}, "
          f"dt = {DEFAULT_PHYSICS_DT:g} s; projected loop RTF with the controller's {controller_s:.3f} s per simulated s):")
    print("    n   dt [s]  RTF plant  tip err [mm]  force err [mN]  peak err [mN]  RTF loop (projected)")
    sweep = []
    for n, dt in SWEEP:
        plant = _plant(n, dt)
        wall, tip, force = replay_plant(plant, u, args.repeats)
        rtf_plant = len(u) * CONTROL_DT / wall
        entry = {
            "links_per_segment": n, "physics_dt": dt, "rtf_plant": rtf_plant,
            "tip_err_mm": float(np.max(np.linalg.norm(tip - tip_ref, axis=1)) * 1e3),
            "force_err_mN": float(np.max(np.abs(force - force_ref)) * 1e3),
            "peak_force_err_mN": float(abs(force.max() - force_ref.max()) * 1e3),
            "rtf_loop_projected": 1.0 / (1.0 / rtf_plant + controller_s),
        }
        sweep.append(entry)
        print(f"  {n:3d} {dt:8.1e} {rtf_plant:10.2f} {entry['tip_err_mm']:13.4f} {entry['force_err_mN']:15.3f} "
              f"{entry['peak_force_err_mN']:14.3f} {entry['rtf_loop_projected']:21.2f}")
    report["controller_s_per_sim_s"] = controller_s
    report["rtf_loop_ceiling"] = 1.0 / controller_s  # with physics for free
    report["sweep"] = sweep
    print(f"\nceiling with free physics: RTF {report['rtf_loop_ceiling']:.2f} (controller and loop alone)")
    emit(report)


if __name__ == "__main__":
    main()
