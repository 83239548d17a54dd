"""The serial MuJoCo loop's speed as a fraction of bare `mj_step`, optionally side by side with
another tree (the target: ≥ 0.8 on mujoco_contact for the unfiltered loop and the recommended filter, and
never slower than before).

A tuning is one of the paper CBF's (`controllers.cbf.barrier.TUNINGS`: None, the loop without a filter's action,
Low, High, …) or any other filter of the registry, run with its defaults (`filter=`; e.g. c-erg:recommended,
the recommended filter, whose own compute, ≈ 117 µs a call at 1 kHz by tools/bench_governors.py, bounds its
fraction by 199 / (199 + 117) ≈ 0.63 against bare mj_step's ≈ 199 µs, whatever the loop around it costs).

Per tree and tuning, in one process (after a warm-up call of the scenario):
- t_loop: CPU s of the closed loop of `mujoco_contact` as the scenario runs it (its
  `scenarios.common.run_closed_loop`, timed in place by `bench_loop_pair.LoopTimer`; data
  only), `--duration` s from `--t0` s (defaults 10 s from 15 s: the arm is in contact from
  ≈ 16 s to ≈ 45 s of the 100 s sinusoid, so the window is mostly contact); its wall s is
  the run's own `wall_s`;
- t_mj_step: CPU (and wall) s of bare `mj_step(nstep = control period / physics step)` over
  the commands u the loop sent, on the same model (`bench_mujoco_contact.replay_mj_step`);
- t_plant: the same commands through `MujocoPlant.step` (physics, `mj_forward`, the state;
  `bench_mujoco_contact.replay_plant`);
- t_plant_no_state: the same again with the plant's state read (`MujocoPlant.state`) replaced by
  handing back one state made before (`replay_without_state`): the step, its `mj_forward` and
  checks without the read;
- filter_us: the loop's mean filter time (µs, its own `filter_us` column: wall clock);
- the control step alone (`control_step_us`): CPU µs per call of `ControlStep` and of
  `BatchControlStep` at B = 1 with a pass-through filter (the step's own cost), min over the repeats.

Figures: fraction = t_mj_step / t_loop (the loop's speed as a fraction of bare mj_step's:
1 would be a loop that costs nothing beyond the physics; in CPU time, and in wall time in
brackets), and per control step (CPU µs) physics t_mj_step / T, plant overhead
(t_plant − t_mj_step) / T, of it the state read (t_plant − t_plant_no_state) / T, and controller
and loop (t_loop − t_plant) / T: the nominal, the filter, the control step, the recorder; the
filter's wall-clock share alongside.

Each measurement is a fresh process with its tree first on PYTHONPATH (this tree; with
`--against TREE`, e.g. an export of the commit before, also TREE): the trees' processes
alternate `--repeats` times and every time is the minimum over the repeats (CPU time, the
least disturbed by other jobs on a shared machine). With `--against`: speedup =
t_loop(TREE) / t_loop(this tree) per tuning, and whether both trees sent bit-identical
commands. Usage:

    git archive REV | tar -x -C /tmp/base     # REV: the commit to compare with
    .venv/bin/python tools/bench_serial_loop.py --against /tmp/base [--duration 10] [--tunings None,Low]

Prints a table and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import contextlib
import hashlib
import io
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from timing import emit

HERE = Path(__file__).resolve().parents[1]  # this tree
TARGET_FRACTION = 0.8  # the target: the serial loop at >= 0.8 of bare mj_step
TIMES = ("t_loop", "t_mj_step", "t_plant", "t_plant_no_state", "wall_loop", "wall_mj_step", "wall_plant")  # CPU s, wall s
STEP_TIMES = ("step_us", "batch_step_us_B1")  # CPU µs per control call of the step alone
STEP_CALLS = 20000


def control_step_us(calls: int = STEP_CALLS) -> dict[str, float]:
    """CPU µs per call of the control step alone (no plant, no recorder): the paper's two-segment
    robot and sinusoid, limits on, a pass-through filter (the step's own cost, not a filter's):
    `ControlStep` (what every serial loop calls) and `BatchControlStep` at B = 1."""
    import numpy as np
    from closedloop.step import BatchControlStep, ControlStep
    from controllers.nominal import SinusoidNominal
    from controllers.model.params import reference_robot
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import Estimate, FilterContext

    context = FilterContext.for_robot(reference_robot(), paper_safe_set(), 1e-3)
    nominal = SinusoidNominal((80.0, 80.0), 0.01, (math.pi / 2, math.pi / 2))

    def pass_through(estimate, u_nom):
        return u_nom

    def per_call_us(call, n: int) -> float:  # after a warm-up (a compiled kernel loads on its first call)
        call(0, 100)
        start = time.process_time()
        call(100, 100 + n)
        return (time.process_time() - start) / n * 1e6

    def scalar(first: int, last: int) -> None:
        for k in range(first, last):
            step(Estimate(k * 1e-3, q, q, k * 1e-3))

    def batched(first: int, last: int) -> None:
        for k in range(first, last):
            batch(np.full(1, k * 1e-3), qb, qb)

    step, q = ControlStep(pass_through, nominal, context), np.zeros(2)
    batch, qb = BatchControlStep([pass_through], [nominal], context, 1), np.zeros((1, 2))
    step.reset()
    batch.reset()
    return {"step_us": per_call_us(scalar, calls), "batch_step_us_B1": per_call_us(batched, calls)}


def replay_without_state(plant, u) -> float:
    """CPU s of `plant.step` over the commands u (T, N) from rest, its state read (`state`) replaced by handing
    back the state made at the reset: the step's physics, `mj_forward` and checks without the read."""
    import numpy as np

    made = plant.reset(np.zeros(plant.n_segments))
    plant.state = lambda: made  # an instance attribute: the class's `state` again once deleted
    try:
        start = time.process_time()
        for command in u:
            plant.step(command)
        return time.process_time() - start
    finally:
        del plant.state


def run_params(tuning: str) -> dict[str, str]:
    """The scenario's parameters for `tuning` (module docstring): a paper CBF tuning, or a filter with its defaults."""
    from controllers.cbf.barrier import TUNINGS

    return {"tunings": tuning} if tuning in TUNINGS else {"filter": tuning}


def measure(tunings: list[str], duration: float, t0: float) -> dict[str, dict[str, float | str]]:
    """In the measuring process: per tuning, t_loop, t_mj_step, t_plant (CPU s, and wall s as
    `wall_*`), steps, filter_us and the SHA-256 of the commands u (module docstring)."""
    import numpy as np
    from bench_loop_pair import LoopTimer
    from bench_mujoco_contact import replay_mj_step, replay_plant
    from scenarios import get
    from scenarios.common import data_only
    from scenarios.mujoco_contact import CONTROL_DT
    from softcbf_mj.physics.mjcf import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT
    from softcbf_mj.physics.mujoco_plant import MujocoPlant
    from softcbf_mj.outputs.runio import load_timeseries

    def timed(replay) -> tuple[float, float]:  # (CPU s, wall s) of one whole replay
        start = time.process_time()
        wall = replay()
        return time.process_time() - start, wall

    scenario = get("mujoco_contact")
    plant = MujocoPlant.from_config(control_dt=CONTROL_DT, links_per_segment=DEFAULT_LINKS_PER_SEGMENT,
                                    physics_dt=DEFAULT_PHYSICS_DT)
    out: dict[str, dict[str, float | str]] = {"step": control_step_us()}
    with tempfile.TemporaryDirectory() as tmp, data_only(), contextlib.redirect_stdout(io.StringIO()):
        for i, tuning in enumerate(tunings):
            (Path(tmp) / f"warm{i}").mkdir()
            scenario.run(Path(tmp) / f"warm{i}", duration=0.05, t0=t0, progress=False, **run_params(tuning))
        for i, tuning in enumerate(tunings):
            folder = Path(tmp) / f"run{i}"
            folder.mkdir()
            with LoopTimer() as loop:
                summary = scenario.run(folder, duration=duration, t0=t0, progress=False, **run_params(tuning))
            log, _ = load_timeseries(folder / summary["runs"][0]["timeseries"])
            u = np.ascontiguousarray(log["u"])
            steps = len(u)
            t_mj_step, wall_mj_step = timed(lambda: replay_mj_step(plant, u, 1, block=steps))
            t_plant, wall_plant = timed(lambda: replay_plant(plant, u, 1, block=steps)[0])
            t_plant_no_state = replay_without_state(plant, u)
            out[tuning] = {"t_loop": loop.cpu_s, "t_mj_step": t_mj_step, "t_plant": t_plant,
                           "t_plant_no_state": t_plant_no_state,
                           "wall_loop": summary["runs"][0]["wall_s"], "wall_mj_step": wall_mj_step,
                           "wall_plant": wall_plant, "steps": steps, "filter_us": float(np.nanmean(log["filter_us"])),
                           "u_sha256": hashlib.sha256(u.tobytes()).hexdigest()[:16]}
    return out


def run_child(tree: Path, tunings: list[str], duration: float, t0: float) -> dict:
    """`measure` in a fresh process with `tree` first on PYTHONPATH."""
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run([sys.executable, __file__, "--child", "--tunings", ",".join(tunings),
                           "--duration", str(duration), "--t0", str(t0)],
                          env=env, cwd=tree, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the measurement on {tree} failed (exit {done.returncode}):\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def figures(best: dict[str, float]) -> dict[str, float]:
    """The fractions and the per-step breakdown (CPU µs) of one tree's and tuning's best times."""
    steps = best["steps"]
    return {"fraction": best["t_mj_step"] / best["t_loop"], "fraction_wall": best["wall_mj_step"] / best["wall_loop"],
            "us_loop": best["t_loop"] / steps * 1e6, "us_physics": best["t_mj_step"] / steps * 1e6,
            "us_plant_overhead": (best["t_plant"] - best["t_mj_step"]) / steps * 1e6,
            "us_state_read": (best["t_plant"] - best["t_plant_no_state"]) / steps * 1e6,
            "us_controller_and_loop": (best["t_loop"] - best["t_plant"]) / steps * 1e6, "us_filter_wall": best["filter_us"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--duration", type=float, default=10.0, help="simulated s per tuning (> 0)")
    parser.add_argument("--t0", type=float, default=15.0, help="phase offset of the sinusoid (s)")
    parser.add_argument("--tunings", default="None,Low,c-erg:recommended",
                        help="comma-separated paper CBF tunings of mujoco_contact or other filters (module docstring)")
    parser.add_argument("--repeats", type=int, default=3, help="measuring processes per tree (>= 1); the minimum is kept")
    parser.add_argument("--against", type=Path, default=None, help="another tree (e.g. the commit before) to compare with")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    tunings = [t.strip() for t in args.tunings.split(",") if t.strip()]
    if not tunings:
        parser.error(f"--tunings must name at least one tuning, got {args.tunings!r}")
    if not (math.isfinite(args.duration) and args.duration > 0):
        parser.error(f"--duration must be finite and > 0 s, got {args.duration}")
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1, got {args.repeats}")
    if args.child:
        emit(measure(tunings, args.duration, args.t0))
        return
    trees = {"this": HERE}
    if args.against is not None:
        if not (args.against / "scenarios" / "mujoco_contact.py").is_file():
            parser.error(f"--against must be a tree of this project (with scenarios/mujoco_contact.py), got {args.against}")
        trees["against"] = args.against.resolve()

    best: dict[str, dict[str, dict]] = {name: {} for name in trees}
    steps: dict[str, dict[str, float]] = {}
    for _ in range(args.repeats):
        for name, tree in trees.items():
            child = run_child(tree, tunings, args.duration, args.t0)
            step = child.pop("step")
            steps[name] = {key: min(steps.get(name, step)[key], step[key]) for key in STEP_TIMES}
            for tuning, got in child.items():
                kept = best[name].setdefault(tuning, dict(got))
                for key in (*TIMES, "filter_us"):
                    kept[key] = min(kept[key], got[key])
                if got["u_sha256"] != kept["u_sha256"]:
                    raise RuntimeError(f"{name} tree, {tuning}: the commands differ between repeats")

    report: dict = {"duration_s": args.duration, "t0_s": args.t0, "repeats": args.repeats, "clock": "process CPU time",
                    "target_fraction": TARGET_FRACTION, "trees": {name: str(tree) for name, tree in trees.items()},
                    "runs": {}}
    print(f"mujoco_contact, {args.duration:g} s from t0 = {args.t0:g} s, CPU time, min of {args.repeats}; µs per control step")
    print("  tree     tuning             fraction (wall)  loop  physics  plant ovh (state)  controller+loop  (filter, wall)")
    for tuning in tunings:
        entry = {name: figures(best[name][tuning]) for name in trees}
        for name in trees:
            f = entry[name]
            print(f"  {name:8s} {tuning:17s} {f['fraction']:8.3f} ({f['fraction_wall']:.3f}) {f['us_loop']:5.0f} "
                  f"{f['us_physics']:8.0f} {f['us_plant_overhead']:10.0f} {f['us_state_read']:7.0f} "
                  f"{f['us_controller_and_loop']:16.0f} "
                  f"{f['us_filter_wall']:15.0f}")
        if "against" in trees:
            entry["speedup"] = best["against"][tuning]["t_loop"] / best["this"][tuning]["t_loop"]
            entry["commands_identical"] = best["against"][tuning]["u_sha256"] == best["this"][tuning]["u_sha256"]
            print(f"  {tuning}: loop speed-up {entry['speedup']:.3f}x against {trees['against']}; commands "
                  f"{'bit-identical' if entry['commands_identical'] else 'DIFFER'}")
        report["runs"][tuning] = entry
    report["control_step_us"] = steps
    print(f"  control step alone (pass-through filter, {STEP_CALLS} calls), CPU µs per call: "
          + "; ".join(f"{name}: ControlStep {steps[name]['step_us']:.2f}, BatchControlStep B = 1 "
                      f"{steps[name]['batch_step_us_B1']:.2f}" for name in trees))
    if "against" in trees:
        report["control_step_speedup"] = steps["against"]["step_us"] / steps["this"]["step_us"]
        print(f"  ControlStep speed-up {report['control_step_speedup']:.3f}x against {trees['against']}")
    worst = min(report["runs"][t]["this"]["fraction"] for t in tunings)
    report["fraction_min"] = worst
    print(f"  worst fraction {worst:.3f} (target >= {TARGET_FRACTION:g}: {'met' if worst >= TARGET_FRACTION else 'NOT met'})")
    emit(report)


if __name__ == "__main__":
    main()
