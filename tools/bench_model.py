"""Speed of the PCC model's one implementation (`controllers.model.pcc_model`) against a baseline tree, side by side.

Each figure is measured in a fresh worker process per tree (`--against DIR`, e.g. a worktree of
the earlier version, whose N = 2 paths were hand-unrolled Python and whose batch was numpy over N = 2), the
workers running one after the other, each the best of `--repeats` passes in CPU time of the
process (`time.process_time`, which other jobs on a shared machine disturb far less than wall time):

- model terms per state: `PCCDynamics.model_terms` at B = 1 (alternating states, so the memo
  never answers), and `BatchDynamics.terms` at B = 1, 256, 1024 (numpy per scalar operation
  in the baseline, the compiled kernel here);
- the serial plant: `PCCPlant.step` (ROS2, 1 ms) per control period;
- the batched plant: `PCCBatchPlant.step` at B = 1024 per simulation and period, N = 2 and
  (this tree only: the baseline raises) N = 3, with the rate per degree of freedom;
- the governors' state predictor: `StatePredictor.predict` over 20 ms (20 ROS2 steps, τ_p = 0.05 s);
- the kernels' start cost: a cold process's first call (compiling, with an empty
  NUMBA_CACHE_DIR) and a warm cache's first call, for this tree.

Usage: `python tools/bench_model.py --against ../pin [--repeats 3]`; prints a table and ends
with one line of JSON (figures in µs; ratios baseline / this tree, > 1: this tree is faster).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from timing import emit, per_call_us

HERE = Path(__file__).resolve().parents[1]


def worker(repeats: int) -> dict:
    """The figures of the tree on sys.path (only public interfaces both trees have)."""
    import numpy as np

    from controllers.model.dynamics import PCCDynamics
    from controllers.model.dynamics_batch import BatchDynamics
    from controllers.model.params import reference_robot, uniform_robot
    from controllers.model.safe_set import paper_safe_set
    from controllers.model.state_predictor import StatePredictor
    from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant
    from softcbf_mj.physics.pcc_plant import PCCPlant

    robot, safe = reference_robot(), paper_safe_set()
    rng = np.random.default_rng(0)
    out: dict = {}
    dyn = PCCDynamics(robot)
    states = [(rng.uniform(-1, 1, 2).tolist(), rng.normal(0, 2, 2).tolist()) for _ in range(64)]
    dyn.model_terms(*states[0])
    out["model_terms_B1_us"] = per_call_us(lambda i: dyn.model_terms(*states[i % 64]), 20000, repeats)
    for b in (1, 256, 1024):
        batch = BatchDynamics(robot)
        qs = [rng.uniform(-1, 1, (b, 2)) for _ in range(2)]
        qd = rng.normal(0, 2, (b, 2))
        batch.terms(qs[1], qd)
        count = max(20, 20000 // b)
        out[f"batch_terms_B{b}_us_per_state"] = per_call_us(lambda i: batch.terms(qs[i % 2], qd), count, repeats) / b
    plant = PCCPlant(robot, safe)
    plant.reset(np.array([0.2, 0.1]))
    u = np.array([150.0, 120.0])
    plant.step(u)
    out["serial_plant_step_us"] = per_call_us(lambda i: plant.step(u), 5000, repeats)
    for n in (2, 3):
        params = robot if n == 2 else uniform_robot(3)
        try:
            bp = PCCBatchPlant(params, safe, 1024)
        except ValueError:  # the baseline's batch plant is N = 2 only
            continue
        bp.reset(rng.normal(0.2, 0.05, (1024, n)))
        ub = np.full((1024, n), 100.0)
        bp.step(ub)
        per_sim = per_call_us(lambda i: bp.step(ub), 20, repeats) / 1024
        out[f"batch_plant_N{n}_B1024_us_per_sim"] = per_sim
        out[f"batch_plant_N{n}_B1024_us_per_dof"] = per_sim / n
    predictor = StatePredictor(PCCDynamics(robot), 0.05)
    for k in range(5):
        predictor.record(0.01 * k, np.array([100.0 + 10 * k, 50.0]))
    q0, qd0 = np.array([0.3, 0.2]), np.array([0.5, -0.5])
    predictor.predict(0.02, q0, qd0, 0.04)
    out["predict_20ms_us"] = per_call_us(lambda i: predictor.predict(0.02, q0, qd0, 0.04), 300, repeats)
    return out


def start_costs() -> dict:
    """First-call seconds of the kernels in a fresh process: cold (empty cache: compiling) and warm (cached)."""
    code = ("import time, numpy as np; t = time.perf_counter(); from controllers.model.params import reference_robot; "
            "from controllers.model.dynamics import PCCDynamics; from softcbf_mj.physics.pcc_plant import PCCPlant; "
            "from controllers.model.safe_set import paper_safe_set; p = PCCPlant(reference_robot(), paper_safe_set()); "
            "p.reset(np.zeros(2)); p.step(np.ones(2)); print(time.perf_counter() - t)")
    out = {}
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, PYTHONPATH=str(HERE), NUMBA_CACHE_DIR=cache)
        for label in ("cold_first_call_s", "warm_cache_first_call_s"):
            result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
            out[label] = float(result.stdout.strip())
    return out


def run_tree(tree: Path, repeats: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    result = subprocess.run([sys.executable, str(Path(__file__).resolve()), "--worker", "--repeats", str(repeats)],
                            env=env, capture_output=True, text=True, check=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, required=False, help="the baseline tree (a worktree of an older commit)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        emit(worker(args.repeats))
        return
    this = run_tree(HERE, args.repeats)
    base = run_tree(args.against, args.repeats) if args.against else {}
    report = {"this": this, "baseline": base, "baseline_tree": str(args.against) if args.against else None}
    print(f"{'figure (CPU µs)':42s} {'baseline':>12s} {'this tree':>12s} {'ratio':>8s}")
    ratios = {}
    for key, value in this.items():
        old = base.get(key)
        ratio = old / value if old else None
        ratios[key] = ratio
        print(f"{key:42s} {old if old is not None else float('nan'):12.3f} {value:12.3f} "
              f"{ratio if ratio is not None else float('nan'):8.2f}")
    report["ratio_baseline_over_this"] = ratios
    serial = this["serial_plant_step_us"]
    report["batch_plant_over_serial_per_sim"] = {f"N{n}": serial / this[f"batch_plant_N{n}_B1024_us_per_sim"]
                                                  for n in (2, 3) if f"batch_plant_N{n}_B1024_us_per_sim" in this}
    report["N3_rate_per_dof_over_N2"] = this["batch_plant_N2_B1024_us_per_dof"] / this["batch_plant_N3_B1024_us_per_dof"]
    report.update(start_costs())
    print(f"batched plant (B = 1024) per simulation vs this tree's serial plant: {report['batch_plant_over_serial_per_sim']}")
    print(f"N = 3 batch rate per degree of freedom / N = 2: {report['N3_rate_per_dof_over_N2']:.2f}")
    print(f"first call of the kernels: cold (compiling) {report['cold_first_call_s']:.2f} s, "
          f"warm cache {report['warm_cache_first_call_s']:.2f} s")
    emit(report)


if __name__ == "__main__":
    main()
