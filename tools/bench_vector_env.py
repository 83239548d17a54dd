"""Steps per second of the vector environment on the batch plant against `SyncVectorEnv` of the single environment.

Both are made by Gymnasium from the same registered id with the same keywords (the
filter `--filter` with `--filter-params`, q0_std 0.05 rad):
- vector: `gymnasium.make_vec(id, num_envs=B, vectorization_mode="vector_entry_point",
  nthread=n)` (`softcbf_mj.env.vector.ArmVectorEnv`: one `MujocoBatchPlant` on n threads of
  `mujoco.batch`, one control step per arm, a filter with `filter_batch` called once per
  control period for all arms), for n in `--nthreads`;
- sync: `gymnasium.make_vec(id, num_envs=B, vectorization_mode="sync")`: B
  `gymnasium.make(id)` (GymArmEnv with Gymnasium's TimeLimit, OrderEnforcing and
  PassiveEnvChecker wrappers), stepped in turn.
Each is reset with seed 0 and then stepped `--steps` times with the same actions (uniform
in the action box, seeded; the first `--push` steps push segment 1 at its upper limit so
that the arm reaches the plate and the filter acts); autoresets happen as they come.
Steps per second = B · steps / wall s of the step loop (resets at construction and a
2-step warm-up run, which loads the compiled kernels, excluded), the best of `--repeats` runs, the two run in turn within each repeat so that the load of a
shared machine falls on both; also per CPU s of this process (all its threads). The
largest |Δ| between the two's observations, rewards and costs over the run is printed: the
vector environment must return what the single ones do. "physics" is the vector
environment's batch plant alone, from rest, each action sent unfiltered (MuJoCo clamps it
to the pressure box) for action_repeat control periods, on each thread count: about the
ceiling of the vector environment, whose arms cost at least their physics (not exactly:
the filter changes the commands, so the contacts differ). Last, per id, the vector
environment on the fewest threads split part by part (`split_us`: CPU µs per arm and env
step of the physics, the filter's `filter_batch`, the rest of the control periods and the
tasks' work), timed by wrapping those calls.

`--against TREE` (e.g. a worktree of an earlier commit) also runs `SyncVectorEnv` of TREE's
single environment and TREE's vector environment on the fewest threads, in a subprocess of
this script with TREE first on the path, once per repeat between this tree's runs: a change
of the single environment's speed shows (`ratio_against` = vector / TREE's sync steps per
second), and so does the vector environment's (`against_vector_steps_per_s`). The load
average is printed before and after: on a shared machine the wall figures move with it, the
per-CPU-s ones less.

Usage: `.venv/bin/python tools/bench_vector_env.py [--num-envs 32] [--ids softcbf_mj/SoftArm-v1,softcbf_mj/ForceRegulation-v0]
[--steps 200,4] [--nthreads 1,2] [--repeats 2] [--against TREE]`; prints a table per id and ends with one line of JSON
(`ratio` = vector / sync steps per second, `physics_ratio` = the physics ceiling / sync, per id and thread count).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import subprocess
import sys
import time
from typing import Any

import gymnasium
import numpy as np

import softcbf_mj.env  # noqa: F401 - registers the ids
from timing import emit


def run(env: Any, actions: np.ndarray) -> tuple[float, float, dict[str, list[np.ndarray]]]:
    """(wall s, CPU s) of stepping `env` through `actions` (T, B, N) after a seeded reset, and what it returned."""
    env.reset(seed=0)
    out: dict[str, list[np.ndarray]] = {"obs": [], "reward": [], "cost": []}
    wall, cpu = time.perf_counter(), time.process_time()
    for action in actions:
        observation, reward, _, _, info = env.step(action)
        out["obs"].append(np.concatenate([np.asarray(v, dtype=float).reshape(len(action), -1)
                                          for v in observation.values()], axis=1))
        out["reward"].append(reward)
        out["cost"].append(np.asarray(info["cost"], dtype=float))
    return time.perf_counter() - wall, time.process_time() - cpu, out


def max_difference(a: dict[str, list[np.ndarray]], b: dict[str, list[np.ndarray]]) -> float:
    return max(float(np.max(np.abs(np.array(a[key]) - np.array(b[key])))) for key in a)


def physics(env: Any, actions: np.ndarray) -> tuple[float, float]:
    """(wall s, CPU s) of the vector env's batch plant alone, each action (B, N) hPa held for action_repeat periods."""
    plant, repeat = env.unwrapped.plant, env.unwrapped.config.action_repeat
    plant.reset(np.zeros((plant.n_sims, plant.n_segments)))
    wall, cpu = time.perf_counter(), time.process_time()
    for action in actions:
        for _ in range(repeat):
            plant.step(action)
    return time.perf_counter() - wall, time.process_time() - cpu


def split(env: Any, actions: np.ndarray) -> dict[str, float]:
    """CPU µs per arm and env step of the vector environment's parts over `actions` (after a seeded reset):
    the batch plant's steps, the filter's `filter_batch` (0 without one), the rest of the control periods
    (the batched control step, the step statistics, the estimates) and everything else (the tasks'
    observations, rewards, costs and infos, the autoresets)."""
    vec = env.unwrapped
    spent = {"physics": 0.0, "filter": 0.0, "periods": 0.0}

    def timing(key: str, call: Any) -> Any:
        def timed(*a: Any) -> Any:
            start = time.process_time()
            try:
                return call(*a)
            finally:
                spent[key] += time.process_time() - start
        return timed

    vec.plant.step = timing("physics", vec.plant.step)
    vec.run_periods = timing("periods", vec.run_periods)
    shared = vec.shared_filter
    if shared is not None:
        shared.filter_batch = timing("filter", shared.filter_batch)
    try:
        env.reset(seed=0)
        start = time.process_time()
        for action in actions:
            env.step(action)
        total = time.process_time() - start
    finally:
        del vec.plant.step, vec.run_periods
        if shared is not None:
            del shared.filter_batch
    scale = 1e6 / (len(actions) * vec.num_envs)
    out = {"total": total * scale, "physics": spent["physics"] * scale, "filter": spent["filter"] * scale,
           "control_rest": (spent["periods"] - spent["physics"] - spent["filter"]) * scale,
           "task_and_rest": (total - spent["periods"]) * scale}
    print("  split (vector, 1 thread), CPU µs per arm and env step: "
          + ", ".join(f"{key} {value:.1f}" for key, value in out.items()))
    return out


def env_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    return {"filter": args.filter, "filter_params": dict(p.split("=", 1) for p in args.filter_params.split(";") if p),
            "q0_std": 0.05}


def bench_actions(space: Any, args: argparse.Namespace, steps: int) -> np.ndarray:
    """The actions (steps, B, N) of every run (module docstring)."""
    rng = np.random.default_rng(1)
    actions = rng.uniform(space.low, space.high, (steps, args.num_envs, space.shape[0]))
    actions[:args.push, :, 0] = space.high[0]
    return actions


def once(env_id: str, args: argparse.Namespace, steps: int) -> None:
    """`--once`: one run of `SyncVectorEnv` and one of the vector environment on the fewest threads, of the
    tree on the path; prints their (wall s, CPU s) as JSON."""
    kwargs = env_kwargs(args)
    envs = {"sync": gymnasium.make_vec(env_id, num_envs=args.num_envs, vectorization_mode="sync", **kwargs),
            "vector": gymnasium.make_vec(env_id, num_envs=args.num_envs, vectorization_mode="vector_entry_point",
                                         nthread=min(args.nthreads), **kwargs)}
    actions = bench_actions(envs["sync"].single_action_space, args, steps)
    out = {}
    for name, env in envs.items():
        run(env, actions[:2])  # warm-up: the first calls load the compiled kernels
        out[name] = run(env, actions)[:2]
        env.close()
    emit(out)


def against(tree: str, env_id: str, args: argparse.Namespace, steps: int) -> dict[str, tuple[float, float]]:
    """{"sync", "vector"}: (wall s, CPU s) of one run of each of the tree `tree` (this script with `--once`)."""
    command = [sys.executable, os.path.abspath(__file__), "--once", "--ids", env_id, "--steps", str(steps),
               "--num-envs", str(args.num_envs), "--push", str(args.push), "--filter", args.filter,
               "--filter-params", args.filter_params, "--nthreads", str(min(args.nthreads))]
    environ = {**os.environ, "PYTHONPATH": tree}
    out = subprocess.run(command, cwd=tree, env=environ, capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise SystemExit(f"--against {tree}: the run failed:\n{out.stderr[-2000:]}")
    return {name: tuple(figures) for name, figures in json.loads(out.stdout.strip().splitlines()[-1]).items()}


def bench(env_id: str, args: argparse.Namespace, steps: int) -> dict[str, Any]:
    kwargs = env_kwargs(args)
    sync = gymnasium.make_vec(env_id, num_envs=args.num_envs, vectorization_mode="sync", **kwargs)
    vectors = {n: gymnasium.make_vec(env_id, num_envs=args.num_envs, vectorization_mode="vector_entry_point",
                                     nthread=n, **kwargs) for n in args.nthreads}
    actions = bench_actions(sync.single_action_space, args, steps)
    for env in (sync, *vectors.values()):
        run(env, actions[:2])  # warm-up: the first calls load the compiled kernels
    best: dict[str, tuple[float, float]] = {}
    check = 0.0
    for _ in range(args.repeats):
        wall, cpu, reference = run(sync, actions)
        best["sync"] = min(best.get("sync", (wall, cpu)), (wall, cpu))
        if args.against:
            for name, figures in against(args.against, env_id, args, steps).items():
                best[f"against_{name}"] = min(best.get(f"against_{name}", (math.inf, math.inf)), figures)
        for n, env in vectors.items():
            wall, cpu, out = run(env, actions)
            best[f"vector_{n}"] = min(best.get(f"vector_{n}", (wall, cpu)), (wall, cpu))
            check = max(check, max_difference(out, reference))
            best[f"physics_{n}"] = min(best.get(f"physics_{n}", (math.inf, math.inf)), physics(env, actions))
    parts = split(vectors[min(vectors)], actions)
    sync.close()
    for env in vectors.values():
        env.close()
    total = steps * args.num_envs
    rates = {name: (total / wall, total / cpu) for name, (wall, cpu) in best.items()}
    print(f"{env_id} ({args.filter}, B = {args.num_envs}, {steps} steps of {sync.metadata['render_fps'] and 1.0 / sync.metadata['render_fps']:.3g} s):")
    print(f"  {'env':>10} {'threads':>7} {'steps/s':>10} {'steps/CPU-s':>12} {'ratio':>7} {'ratio/CPU':>9}")
    sync_rate, sync_cpu = rates["sync"]
    print(f"  {'sync':>10} {1:7d} {sync_rate:10.0f} {sync_cpu:12.0f} {1.0:7.2f} {1.0:9.2f}")
    against_rate, against_cpu = rates.get("against_sync", (math.nan, math.nan))
    old_rate, old_cpu = rates.get("against_vector", (math.nan, math.nan))
    if args.against:
        print(f"  {'sync@TREE':>10} {1:7d} {against_rate:10.0f} {against_cpu:12.0f} {against_rate / sync_rate:7.2f} "
              f"{against_cpu / sync_cpu:9.2f}   (TREE = {args.against})")
        print(f"  {'vector@TREE':>10} {min(args.nthreads):7d} {old_rate:10.0f} {old_cpu:12.0f} {old_rate / sync_rate:7.2f} "
              f"{old_cpu / sync_cpu:9.2f}   vs sync@TREE {old_rate / against_rate:.2f}, per CPU-s {old_cpu / against_cpu:.2f}")
    rows = []
    for n in args.nthreads:
        rate, cpu_rate = rates[f"vector_{n}"]
        ceiling, ceiling_cpu = rates[f"physics_{n}"]
        rows.append({"nthread": n, "steps_per_s": rate, "steps_per_cpu_s": cpu_rate, "ratio": rate / sync_rate,
                     "ratio_cpu": cpu_rate / sync_cpu, "physics_steps_per_s": ceiling,
                     "physics_steps_per_cpu_s": ceiling_cpu, "physics_ratio": ceiling / sync_rate,
                     "physics_ratio_cpu": ceiling_cpu / sync_cpu, "ratio_against": rate / against_rate,
                     "ratio_against_cpu": cpu_rate / against_cpu})
        print(f"  {'vector':>10} {n:7d} {rate:10.0f} {cpu_rate:12.0f} {rate / sync_rate:7.2f} {cpu_rate / sync_cpu:9.2f}"
              + (f"   vs sync@TREE {rate / against_rate:.2f}, per CPU-s {cpu_rate / against_cpu:.2f}" if args.against else ""))
        print(f"  {'physics':>10} {n:7d} {ceiling:10.0f} {ceiling_cpu:12.0f} {ceiling / sync_rate:7.2f} "
              f"{ceiling_cpu / sync_cpu:9.2f}")
    print(f"  max |Δ| vector vs sync (observations, rewards, costs): {check:.2e}")
    return {"id": env_id, "steps": steps, "sync_steps_per_s": sync_rate, "sync_steps_per_cpu_s": sync_cpu,
            "against_sync_steps_per_s": against_rate, "against_sync_steps_per_cpu_s": against_cpu,
            "against_vector_steps_per_s": old_rate, "against_vector_steps_per_cpu_s": old_cpu,
            "vector": rows, "max_abs_difference": check, "split_us": parts}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--num-envs", type=int, default=32)
    parser.add_argument("--ids", default="softcbf_mj/SoftArm-v1,softcbf_mj/ForceRegulation-v0")
    parser.add_argument("--steps", default="200,4", help="env steps per id (comma-separated, one per id)")
    parser.add_argument("--push", type=int, default=1, help="first steps that push segment 1 at its limit")
    parser.add_argument("--filter", default="paper-cbf")
    parser.add_argument("--filter-params", default="tuning=Low", help="name=value;name=value")
    parser.add_argument("--nthreads", default="1,2")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--against", default="", help="a tree whose SyncVectorEnv also runs (module docstring)")
    parser.add_argument("--once", action="store_true", help=argparse.SUPPRESS)  # the --against subprocess
    args = parser.parse_args()
    args.nthreads = [int(n) for n in args.nthreads.split(",")]
    ids, steps = args.ids.split(","), [int(s) for s in args.steps.split(",")]
    if len(steps) != len(ids):
        raise SystemExit(f"--steps must give one count per id ({len(ids)}), got {len(steps)}")
    if args.once:
        once(ids[0], args, steps[0])
        return
    if args.against and not os.path.isdir(os.path.join(args.against, "softcbf_mj", "env")):
        raise SystemExit(f"--against must be a tree with softcbf_mj/env, got {args.against!r}")
    load_before = os.getloadavg()
    print(f"load average before: {load_before[0]:.2f} (1 min), {load_before[1]:.2f} (5 min) on {os.cpu_count()} CPUs")
    results = [bench(env_id, args, n) for env_id, n in zip(ids, steps)]
    load_after = os.getloadavg()
    print(f"load average after: {load_after[0]:.2f} (1 min), {load_after[1]:.2f} (5 min)")
    emit({"bench": "vector_env", "num_envs": args.num_envs, "filter": args.filter,
          "filter_params": args.filter_params, "cpus": os.cpu_count(), "python": platform.python_version(),
          "against": args.against or None, "load_before": load_before[:2], "load_after": load_after[:2],
          "results": results})


if __name__ == "__main__":
    main()
