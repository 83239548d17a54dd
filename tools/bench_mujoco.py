"""Speed of the MuJoCo ground truth: physics steps per second per arm resolution (links per
segment), and the real-time factor of the bare plant (`MujocoPlant.step`, no controller) at the
defaults.

Two load cases, each after a 0.3 s settling: `free` (u = (−100, 100) hPa, no contact)
and `contact` (u = (120, 120) hPa, the tip pressing the paper's plate). Each figure is timed
`--repeats` times in CPU time of the process (one thread; CPU time is far less disturbed than the
wall clock by other jobs on a shared machine; the wall-clock figures are recorded alongside) and
reported as the median (and the best) of them.

The constraint Jacobian is the model's own (`--jacobian model`: what `softcbf_mj.physics.mjcf`
writes, MuJoCo's `auto` — dense below nv = 60, sparse from there) unless `--jacobian` sets
`dense`, `sparse` or `auto`; every row records the option and what MuJoCo used (`mj_isSparse`).

Before/after comparisons (another MuJoCo, another tree) on a shared, noisy machine: run each
side as its own process, alternating, and append every run's JSON line to one file; then
`--compare FILE` prints, per side (MuJoCo version and Jacobian option) and resolution, the median
over the runs of each run's median, side by side with the first side. E.g. MuJoCo 4.0.0 with the
tree of the commit before against this tree:

    git archive <commit before> | tar -x -C /tmp/base     # with a venv of the old MuJoCo in OLD
    for i in 1 2 3 4 5 6; do
      PYTHONPATH=/tmp/base OLD/bin/python tools/bench_mujoco.py --repeats 3 --seconds 0.5 --append /tmp/mj.jsonl
      PYTHONPATH=$PWD .venv/bin/python tools/bench_mujoco.py --repeats 3 --seconds 0.5 --append /tmp/mj.jsonl
    done
    .venv/bin/python tools/bench_mujoco.py --compare /tmp/mj.jsonl

(the script is this tree's in both; `softcbf_mj` comes from PYTHONPATH). Usage:
`python tools/bench_mujoco.py [--links 5,10,20,40] [--repeats 5] [--seconds 1] [--jacobian model]
[--append FILE]`; prints a table and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import mujoco
import numpy as np

from softcbf_mj.physics.mjcf import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT, ArmModelConfig, build_spec
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from timing import emit, timed

LOADS = {"free": (-100.0, 100.0), "contact": (120.0, 120.0)}  # hPa
LINKS = (5, 10, 20, 40)
SETTLE_S = 0.3
JACOBIANS = ("model", "auto", "dense", "sparse")


def arm_model(n: int, jacobian: str) -> mujoco.MjModel:
    """The default scene with n links per segment; `jacobian` other than "model" overrides the option."""
    spec = build_spec(ArmModelConfig(links_per_segment=n))
    if jacobian != "model":
        spec.option.jacobian = mujoco.mjtJacobian.__members__[f"mjJAC_{jacobian.upper()}"]
    return spec.compile()


def jacobian_option(model: mujoco.MjModel) -> str:
    """The model's `jacobian` option as MJCF writes it: dense, sparse or auto."""
    return mujoco.mjtJacobian(model.opt.jacobian).name.removeprefix("mjJAC_").lower()


def summary(samples: list[tuple[float, float]]) -> dict[str, float]:
    """Median and best (largest) of (CPU, wall) rates measured in repeats; `wall_median` the wall clock's."""
    cpu = [rate for rate, _ in samples]
    return {"median": statistics.median(cpu), "best": max(cpu), "wall_median": statistics.median(w for _, w in samples)}


def steps_per_second(model: mujoco.MjModel, u: tuple[float, float], seconds: float, repeats: int) -> list[tuple[float, float]]:
    """Raw `mj_step` throughput of `model` per repeat (steps per CPU s, per wall s), after settling
    under the command u."""
    data = mujoco.MjData(model)
    data.ctrl[:] = u
    mujoco.mj_step(model, data, nstep=int(SETTLE_S / model.opt.timestep))
    steps = int(seconds / model.opt.timestep)
    rates = []
    for _ in range(repeats):
        _, took = timed(lambda: mujoco.mj_step(model, data, nstep=steps))
        rates.append((steps / took.cpu, steps / took.wall))
    return rates


def plant_real_time_factors(model: mujoco.MjModel, u: tuple[float, float], seconds: float, repeats: int) -> list[tuple[float, float]]:
    """Simulated s per CPU s and per wall s of `MujocoPlant.step` at 1 kHz per repeat, after settling."""
    plant = MujocoPlant(model)
    command = np.array(u)
    for _ in range(int(SETTLE_S / plant.control_dt)):
        plant.step(command)
    steps = int(seconds / plant.control_dt)
    def run() -> None:
        for _ in range(steps):
            plant.step(command)

    factors = []
    for _ in range(repeats):
        _, took = timed(run)
        factors.append((steps * plant.control_dt / took.cpu, steps * plant.control_dt / took.wall))
    return factors


def measure(links: list[int], jacobian: str, seconds: float, repeats: int) -> dict[str, object]:
    """One run: the JSON record (see the module docstring), printing its table on the way."""
    report: dict[str, object] = {
        "mujoco": mujoco.__version__, "jacobian": jacobian, "machine": platform.machine(), "cpus": os.cpu_count(),
        "physics_dt": DEFAULT_PHYSICS_DT, "default_links": DEFAULT_LINKS_PER_SEGMENT, "repeats": repeats,
        "seconds": seconds, "load_average": os.getloadavg()[0], "time": time.strftime("%Y-%m-%dT%H:%M:%S"),
    }
    print(f"MuJoCo {mujoco.__version__}, physics dt {DEFAULT_PHYSICS_DT:g} s, {repeats} repeats: median (best) steps per CPU s")
    print("  links/segment   nv  jacobian (used)   free steps/s         contact steps/s")
    rows = []
    for n in links:
        model = arm_model(n, jacobian)
        row: dict[str, object] = {"links": n, "nv": int(model.nv), "jacobian": jacobian_option(model),
                                  "sparse": bool(mujoco.mj_isSparse(model))}
        for load, u in LOADS.items():
            row[f"{load}_steps_per_s"] = summary(steps_per_second(model, u, seconds, repeats))
        rows.append(row)
        used = "sparse" if row["sparse"] else "dense"
        print(f"  {n:13d} {row['nv']:4d}  {row['jacobian']:>8s} ({used:6s})"
              + "".join(f" {row[f'{load}_steps_per_s']['median']:9.0f} ({row[f'{load}_steps_per_s']['best']:6.0f})"
                        for load in LOADS))
    report["steps_per_s"] = rows
    report["model_jacobian"] = rows[0]["jacobian"]
    print(f"bare plant at the defaults (n = {DEFAULT_LINKS_PER_SEGMENT}, control 1 kHz): median (best), CPU time")
    model = arm_model(DEFAULT_LINKS_PER_SEGMENT, jacobian)
    for load, u in LOADS.items():
        rtf = summary(plant_real_time_factors(model, u, seconds, repeats))
        report[f"plant_{load}"] = {"real_time_factor": rtf, "us_per_control_step": 1e3 / rtf["median"]}
        print(f"  {load:8s} real-time factor {rtf['median']:6.2f} ({rtf['best']:.2f})  "
              f"({1e3 / rtf['median']:7.1f} µs per control step)")
    return report


def compare(paths: list[Path]) -> dict[str, object]:
    """Medians over the runs in `paths` (JSON lines of `--append`), per side and resolution, printed
    side by side with the first side (in order of appearance) as the ratio side / first."""
    runs = [json.loads(line) for path in paths for line in path.read_text().splitlines() if line.strip()]
    if not runs:
        raise SystemExit(f"no runs in {', '.join(map(str, paths))}")
    sides: dict[str, list[dict]] = {}
    for run in runs:
        sides.setdefault(f"MuJoCo {run['mujoco']} + {run['model_jacobian']}", []).append(run)
    table: dict[str, dict[str, float]] = {}  # side -> figure -> median over the runs
    for side, side_runs in sides.items():
        figures: dict[str, list[float]] = {}
        for run in side_runs:
            for row in run["steps_per_s"]:
                for load in LOADS:
                    figures.setdefault(f"{load} n={row['links']} nv={row['nv']}", []).append(
                        row[f"{load}_steps_per_s"]["median"])
            for load in LOADS:
                figures.setdefault(f"plant {load} RTF", []).append(run[f"plant_{load}"]["real_time_factor"]["median"])
        table[side] = {figure: statistics.median(values) for figure, values in figures.items()}
    first = next(iter(table))
    names = list(table)
    print("median over runs of each run's median (steps per CPU s; plant: simulated s per CPU s); ratio to the first side")
    print(f"{'figure':26s}" + "".join(f"  {name:>24s}" for name in names))
    print(f"{'runs':26s}" + "".join(f"  {len(sides[name]):>24d}" for name in names))
    for figure, value in table[first].items():
        cells = [f"{value:24.0f}" if "RTF" not in figure else f"{value:24.2f}"]
        for name in names[1:]:
            other = table[name].get(figure, float("nan"))
            number = f"{other:.0f}" if "RTF" not in figure else f"{other:.2f}"
            cells.append(f"{number + f' ({other / value:.2f}x)':>24s}")
        print(f"{figure:26s}" + "".join(f"  {cell}" for cell in cells))
    return {"runs": {name: len(sides[name]) for name in names}, "medians": table}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--links", default=",".join(map(str, LINKS)),
                        help=f"links per segment, comma-separated (default {','.join(map(str, LINKS))})")
    parser.add_argument("--repeats", type=int, default=5, help="timings per figure (default 5)")
    parser.add_argument("--seconds", type=float, default=1.0, help="simulated seconds per timing (default 1)")
    parser.add_argument("--jacobian", choices=JACOBIANS, default="model",
                        help="the constraint Jacobian: the model's own (default) or dense, sparse, auto")
    parser.add_argument("--append", type=Path, default=None, help="append this run's JSON line to FILE")
    parser.add_argument("--compare", type=Path, nargs="+", default=None,
                        help="only compare the runs in these JSON-line files (see the docstring)")
    args = parser.parse_args()
    if args.compare is not None:
        missing = [str(path) for path in args.compare if not path.is_file()]
        if missing:
            parser.error(f"--compare: no such file {', '.join(missing)}")
        emit(compare(args.compare))
        return
    try:
        links = [int(part) for part in args.links.split(",")]
    except ValueError:
        parser.error(f"--links must be comma-separated integers, got {args.links!r}")
    if any(n < 1 for n in links) or args.repeats < 1 or args.seconds <= 0:
        parser.error("--links must be >= 1, --repeats >= 1 and --seconds > 0")
    report = measure(links, args.jacobian, args.seconds, args.repeats)
    line = json.dumps(report)
    if args.append is not None:
        with args.append.open("a") as out:
            out.write(line + "\n")
    emit(report)


if __name__ == "__main__":
    main()
