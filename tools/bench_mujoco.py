"""Speed of the MuJoCo ground truth: physics steps per second vs links per segment, and
the real-time factor of the bare plant (`MujocoPlant.step`, no controller) at the defaults.

Two load cases, each after a 0.3 s settling: `free` (u = (−100, 100) hPa, no contact)
and `contact` (u = (120, 120) hPa, the tip pressing the paper's plate). Every figure is
the best of `--repeats` timings (wall clock, one thread). Usage:
`python tools/bench_mujoco.py [--repeats 3] [--seconds 1]`; prints a table and ends with
one line of JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import mujoco
import numpy as np

from softcbf_mj.model_builder import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT, ArmModelConfig, build_model
from softcbf_mj.mujoco_plant import MujocoPlant

LOADS = {"free": (-100.0, 100.0), "contact": (120.0, 120.0)}  # hPa
LINKS = (5, 10, 20, 40)
SETTLE_S = 0.3


def steps_per_second(n: int, u: tuple[float, float], seconds: float, repeats: int) -> float:
    """Raw `mj_step` throughput of the model with n links per segment at the default dt."""
    model = build_model(ArmModelConfig(links_per_segment=n))
    data = mujoco.MjData(model)
    data.ctrl[:] = u
    mujoco.mj_step(model, data, nstep=int(SETTLE_S / model.opt.timestep))
    steps = int(seconds / model.opt.timestep)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        mujoco.mj_step(model, data, nstep=steps)
        best = min(best, time.perf_counter() - t0)
    return steps / best


def plant_real_time_factor(u: tuple[float, float], seconds: float, repeats: int) -> tuple[float, float]:
    """(simulated s per wall s, wall µs per control step) of `MujocoPlant.step` at the defaults."""
    plant = MujocoPlant.from_config()
    command = np.array(u)
    for _ in range(int(SETTLE_S / plant.control_dt)):
        plant.step(command)
    steps = int(seconds / plant.control_dt)
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        for _ in range(steps):
            plant.step(command)
        best = min(best, time.perf_counter() - t0)
    return steps * plant.control_dt / best, best / steps * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="timings per figure; the best is kept (default 3)")
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per timing (default 1)")
    args = parser.parse_args()
    report: dict[str, object] = {
        "mujoco": mujoco.__version__, "machine": platform.machine(), "cpus": os.cpu_count(),
        "physics_dt": DEFAULT_PHYSICS_DT, "default_links": DEFAULT_LINKS_PER_SEGMENT,
    }
    print(f"MuJoCo {mujoco.__version__}, physics dt {DEFAULT_PHYSICS_DT:g} s, best of {args.repeats}")
    print("  links/segment   nv   free steps/s   contact steps/s")
    rows = []
    for n in LINKS:
        row = {"links": n, "nv": int(build_model(ArmModelConfig(links_per_segment=n)).nv)}
        for load, u in LOADS.items():
            row[f"{load}_steps_per_s"] = steps_per_second(n, u, args.seconds, args.repeats)
        rows.append(row)
        print(f"  {n:13d} {row['nv']:4d} {row['free_steps_per_s']:14.0f} {row['contact_steps_per_s']:17.0f}")
    report["steps_per_s"] = rows
    print(f"bare plant at the defaults (n = {DEFAULT_LINKS_PER_SEGMENT}, control 1 kHz):")
    for load, u in LOADS.items():
        rtf, us = plant_real_time_factor(u, args.seconds, args.repeats)
        report[f"plant_{load}"] = {"real_time_factor": rtf, "us_per_control_step": us}
        print(f"  {load:8s} real-time factor {rtf:6.2f}  ({us:7.1f} µs per control step)")
    print(json.dumps(report))


if __name__ == "__main__":
    main()
