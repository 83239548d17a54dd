"""Throughput of batched closed loops against today's serial loop, on the same samples.

Two sample types, each a short closed-loop run (`--duration` s at 1 kHz) of the paper's
CBF with the paper's sinusoid started at its peak (so that short runs reach the facet):
- mujoco_contact-type: the MuJoCo rod (`--links`, `--physics-dt`, defaults those of the
  scenario) against the plate, HW-High, ±150 hPa; sample s has its own true arm and plate
  (stiffness and gain ×U(0.9, 1.1), plate stiffness 11.16·U(0.9, 1.1) N/m, a mismatch
  study's draw) and start q0 ~ N(0.2, 0.05) rad;
- paper_sim-type: the PCC plant (ROS2, 1 ms), Low, no pressure limits, the controller's
  model = the plant's, start q0 ~ N(0.2, 0.05) rad.
Serial: `softcbf_mj.loops.loop.run_closed_loop` (one `MujocoPlant` / `PCCPlant` per sample, the
`CBFFilter` called per step) over the first `--serial` samples. Batched:
`run_batch_closed_loop` over the first B samples in one batch, for B in `--batches`
(MuJoCo on 1 and 2 threads of `mujoco.batch`; PCC in numpy, one thread), then the same
batch replaying the commands it sent, without filter, nominal or figures: the batch's
physics ceiling; `control` is the CPU µs per simulation and period the loop adds to that
ceiling (the batched control step, the filter, the figures). Throughput is samples per hour = samples / wall s × 3600, each time the
best of `--repeats` runs; also per CPU-hour (samples / CPU s of this process, all its
threads, × 3600), which other jobs on a shared machine disturb far less than wall time:
the CPU ratios compare the work each way needs, the wall ratios what one gets now.
`ratio_vs_serial` = batched / serial samples per hour; `fraction_of_physics_ceiling`
= batched loop / its replay; the JSON line's headline figures are those of the largest
batch (PCC; MuJoCo on 1 and on 2 threads). The batched figures are checked against the serial ones
on the common samples (max |Δρ_meas|). Last, the control step alone (`--step-calls` calls, a
pass-through filter): CPU µs per call of `ControlStep`, of `BatchControlStep` at B = 1 and
per simulation at the largest PCC batch (`step_us` in the JSON); and for the largest batch of
each type on one thread, the loop split part by part (`split_us`: the control step without
its filter, the filter's `filter_batch`, the figures, the plant; CPU µs per simulation and
period) with the ceiling a loop of no step and figures would reach, plant / (plant + filter).

The machine may be shared: wall times then include other jobs' load, and two threads
may not get two cores. Ratios measured side by side in one run are the figures to
trust. Usage: `python tools/bench_batch.py [--duration 0.2] [--serial 8] [--batches 1,8,32,128]
[--pcc-batches 1,8,32,128,1024]`; prints tables and ends with one line of JSON.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os
import platform
import time
from typing import Callable

import mujoco
import numpy as np

from closedloop.step import BatchControlStep, ControlStep
from controllers.cbf.barrier import TUNINGS
from controllers.cbf.paper_filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from controllers.contract.capabilities import Capabilities
from controllers.contract.safety_filter import BatchOutput, Estimate, FilterContext
from softcbf_mj.loops.batch_loop import replay_commands, run_batch_closed_loop
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.outputs.metrics import RunningFigures, rho_meas, run_figures
from softcbf_mj.physics.mjcf import DEFAULT_LINKS_PER_SEGMENT, DEFAULT_PHYSICS_DT, PAPER_PLATE_STIFFNESS, ArmModelConfig
from softcbf_mj.physics.mujoco_batch_plant import MujocoBatchPlant
from softcbf_mj.physics.mujoco_plant import MujocoPlant
from softcbf_mj.physics.pcc_batch_plant import PCCBatchPlant
from softcbf_mj.physics.pcc_plant import PCCPlant
from timing import Timing, best_of, emit

PEAK = SinusoidNominal((80.0, 80.0), 0.01, (math.pi / 2, math.pi / 2))


def serial_log(plant, safety_filter, safe_set, pressure_limits: bool, duration: float, q0: np.ndarray) -> dict:
    """One sample's time series through the serial loop (the control step clips to the
    reference robot's limits when `pressure_limits`, as the batched loop given them)."""
    context = FilterContext.for_robot(reference_robot(), safe_set, plant.control_dt, pressure_limits)
    log, _ = run_closed_loop(plant, ControlStep(safety_filter, PEAK, context), safe_set, duration, q0)
    return log
HOUR = 3600.0


def mujoco_samples(n: int, links: int, physics_dt: float, seed: int = 0) -> tuple[list[ArmModelConfig], np.ndarray]:
    """n mismatch draws (true arm and plate) and their starts q0 (n, 2) rad."""
    rng = np.random.default_rng(seed)
    ref = reference_robot()
    configs = []
    for k_scale, g_scale, plate in zip(rng.uniform(0.9, 1.1, n), rng.uniform(0.9, 1.1, n), rng.uniform(0.9, 1.1, n)):
        robot = dataclasses.replace(ref, stiffness=tuple(v * k_scale for v in ref.stiffness),
                                    gains=tuple(v * g_scale for v in ref.gains))
        configs.append(ArmModelConfig(robot=robot, plate_stiffness=PAPER_PLATE_STIFFNESS * plate, links_per_segment=links, physics_dt=physics_dt))
    return configs, rng.normal(0.2, 0.05, (n, 2))


def _row(b: int, nthread: int, loop: Timing, ceiling: Timing, serial: Timing, n_serial: int, periods: int) -> dict:
    """Samples per hour (wall and per CPU-hour) and the ratios of a batched run of b samples of `periods`
    control periods; `control_cpu_us` = (loop − ceiling) CPU µs per simulation and period: what the
    control side (the batched control step, the filter, the figures) adds to the physics."""
    rate, rate_cpu = b / loop.wall * HOUR, b / loop.cpu * HOUR
    serial_rate, serial_cpu = n_serial / serial.wall * HOUR, n_serial / serial.cpu * HOUR
    row = {"B": b, "threads": nthread, "samples_per_hour": rate, "samples_per_cpu_hour": rate_cpu,
           "control_cpu_us": (loop.cpu - ceiling.cpu) / (b * periods) * 1e6,
           "ratio_vs_serial": rate / serial_rate, "ratio_vs_serial_cpu": rate_cpu / serial_cpu,
           "ceiling_samples_per_hour": b / ceiling.wall * HOUR,
           "fraction_of_physics_ceiling": ceiling.wall / loop.wall, "fraction_of_physics_ceiling_cpu": ceiling.cpu / loop.cpu}
    print(f"  {b:5d} {nthread:8d} {rate:10.0f} {row['ratio_vs_serial']:8.2f} {row['ratio_vs_serial_cpu']:8.2f} "
          f"{row['ceiling_samples_per_hour']:12.0f} {row['fraction_of_physics_ceiling']:9.3f} "
          f"{row['fraction_of_physics_ceiling_cpu']:9.3f} {row['control_cpu_us']:9.2f}")
    return row


HEADER = ("      B  threads  samples/h  ×serial  ×serial   ceiling/h  fraction  fraction   control\n"
          "                             (wall)    (CPU)               (wall)     (CPU)  (CPU µs)")


def compare(title: str, args: argparse.Namespace, serial_pass, batches, safe_set, q0: np.ndarray) -> dict:
    """The serial pass, then each batched set-up of `batches` ((B, threads, plant, filter, pressure limits on)) on the
    first B samples: prints the table, returns the serial rates, the rows and max |Δρ_meas| against the
    serial runs they share."""
    serial_runs, serial = best_of(args.repeats, serial_pass)
    print(title)
    print(f"  serial ({args.serial} samples): {args.serial / serial.wall * HOUR:10.0f} samples/h, "
          f"{args.serial / serial.cpu * HOUR:10.0f} per CPU-hour")
    print(HEADER)
    rows, check = [], 0.0
    for b, nthread, plant, filt, pressure_limits in batches:
        context = FilterContext.for_robot(reference_robot(), safe_set, plant.control_dt, pressure_limits)
        run, loop = best_of(args.repeats, lambda: run_batch_closed_loop(
            plant, filt, PEAK, context, args.duration, q0[:b], record_commands=True))
        _, ceiling = best_of(args.repeats, lambda: replay_commands(plant, run.commands, q0[:b]))
        rows.append(_row(b, nthread, loop, ceiling, serial, args.serial, len(run.commands)))
        if nthread == 1 and b == max(args.batches if isinstance(plant, MujocoBatchPlant) else args.pcc_batches):
            rows[-1]["split_us"] = split(plant, filt, context, q0[:b], len(run.commands))
        check = max([check] + [abs(run.figures.rho_min_meas[s] - serial_runs[s]["rho_min_meas"]) for s in range(min(b, args.serial))])
    print(f"  max |Δρ_meas| batched vs serial on common samples: {check:.2e}")
    return {"serial_samples_per_hour": args.serial / serial.wall * HOUR,
            "serial_samples_per_cpu_hour": args.serial / serial.cpu * HOUR, "batched": rows, "max_abs_rho_meas_diff": check}


def bench_mujoco(args: argparse.Namespace) -> dict:
    params, safe_set = reference_robot(), paper_safe_set()
    tuning, limits = TUNINGS["HW-High"], True
    n_max = max(max(args.batches), args.serial)
    configs, q0 = mujoco_samples(n_max, args.links, args.physics_dt)

    def serial_pass() -> list[dict]:
        return [run_figures(serial_log(MujocoPlant.from_config(config), CBFFilter(params, safe_set, tuning), safe_set, True,
                                       args.duration, q), 1e-3, True, 0.0)
                for config, q in zip(configs[: args.serial], q0)]

    batches = ((b, nthread, MujocoBatchPlant.from_configs(configs[:b], nthread=nthread), CBFFilter(params, safe_set, tuning), limits)
               for nthread in (1, 2) for b in args.batches)
    return compare(f"mujoco_contact-type: {args.duration:g} s per sample, n = {args.links}, dt = {args.physics_dt:g} s, "
                   "HW-High, ±150 hPa", args, serial_pass, batches, safe_set, q0)


def bench_pcc(args: argparse.Namespace) -> dict:
    params, safe_set = reference_robot(), paper_safe_set()
    tuning = TUNINGS["Low"]
    n_max = max(max(args.pcc_batches), args.serial)
    q0 = np.random.default_rng(1).normal(0.2, 0.05, (n_max, 2))

    def serial_pass() -> list[dict]:
        runs = []
        for q in q0[: args.serial]:
            plant = PCCPlant(params, safe_set)
            controller = CBFFilter(params, safe_set, tuning, pressure_limits=False, dynamics=plant.dynamics)
            runs.append(run_figures(serial_log(plant, controller, safe_set, False, args.duration, q), 1e-3, True, 0.0))
        return runs

    def batches():
        for b in args.pcc_batches:
            plant = PCCBatchPlant(params, safe_set, b)
            yield b, 1, plant, CBFFilter(params, safe_set, tuning, pressure_limits=False, batch_dynamics=plant.dynamics), False

    return compare(f"\npaper_sim-type: {args.duration:g} s per sample, PCC ROS2 1 ms, Low, no pressure limits",
                   args, serial_pass, batches(), safe_set, q0)


def split(plant, safety_filter, context: FilterContext, q0: np.ndarray, periods: int) -> dict:
    """CPU µs per simulation and period of each part of the batched loop (`run_batch_closed_loop`'s
    body, timed part by part): the batched control step without its filter, the filter's
    `filter_batch`, the figures (`RunningFigures`) and the plant's step."""
    n_sims, spent = len(q0), {"filter": 0.0}
    filter_batch = safety_filter.filter_batch

    def timed(*args):
        start = time.process_time()
        try:
            return filter_batch(*args)
        finally:
            spent["filter"] += time.process_time() - start

    safety_filter.filter_batch = timed
    try:
        step = BatchControlStep(safety_filter, PEAK, context, n_sims)
        step.reset()
        figures, state = RunningFigures(n_sims, plant.control_dt), plant.reset(q0)
        parts = {"step": 0.0, "figures": 0.0, "plant": 0.0}
        for _ in range(periods):
            a = time.process_time()
            record = step(state.t, state.q, state.qd)
            b = time.process_time()
            figures.update(rho_meas(context.safe_set, state.contact_forces)[None], state.contact_forces[None],
                           record.u[None], record.rho_pred[None], record.infeasible[None], record.action[None])
            c = time.process_time()
            state = plant.step(record.u)
            parts["step"] += b - a
            parts["figures"] += c - b
            parts["plant"] += time.process_time() - c
    finally:
        del safety_filter.filter_batch  # the bound method again
    scale = 1e6 / (n_sims * periods)
    out = {"step_without_filter": (parts["step"] - spent["filter"]) * scale, "filter": spent["filter"] * scale,
           "figures": parts["figures"] * scale, "plant": parts["plant"] * scale}
    out["ceiling_without_step_and_figures"] = out["plant"] / (out["plant"] + out["filter"])
    print(f"  split, CPU µs per simulation and period (B = {n_sims}, {periods} periods): "
          + ", ".join(f"{key} {value:.2f}" for key, value in out.items()))
    return out


def bench_step(batch: int, calls: int, repeats: int) -> dict:
    """CPU µs per call of the control step alone (no plant), a pass-through filter with `filter_batch` and the
    paper's sinusoid at its peak, limits on: `ControlStep` (one run), `BatchControlStep` at B = 1, and
    `BatchControlStep` at B = `batch` per simulation; the best of `repeats` runs of `calls` calls each."""
    robot, safe_set = reference_robot(), paper_safe_set()
    context = FilterContext.for_robot(robot, safe_set, 1e-3)

    class PassThrough:
        capabilities = Capabilities(batched=True)

        def __call__(self, estimate, u_nom):
            return u_nom

        def filter_batch(self, states, u_nom):
            n = len(states)
            return BatchOutput(u_nom, np.array(["user"] * n), np.zeros(n, dtype=bool), np.full(n, math.nan))

    def scalar() -> None:
        step, q = ControlStep(PassThrough(), PEAK, context), np.zeros(2)
        step.reset()
        for k in range(calls):
            step(Estimate(k * 1e-3, q, q, k * 1e-3))

    def batched(b: int) -> Callable[[], None]:
        def run() -> None:
            step, q = BatchControlStep(PassThrough(), PEAK, context, b), np.zeros((b, 2))
            step.reset()
            for k in range(calls):
                step(np.full(b, k * 1e-3), q, q)
        return run

    out = {"ControlStep": best_of(repeats, scalar)[1].cpu / calls * 1e6,
           "BatchControlStep_B1": best_of(repeats, batched(1))[1].cpu / calls * 1e6,
           f"BatchControlStep_per_sim_B{batch}": best_of(repeats, batched(batch))[1].cpu / calls / batch * 1e6}
    print("\ncontrol step alone, CPU µs per call (per simulation at B > 1): "
          + ", ".join(f"{key} {value:.2f}" for key, value in out.items()))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=0.2, help="simulated s per sample")
    parser.add_argument("--serial", type=int, default=8, help="samples run serially")
    parser.add_argument("--batches", type=lambda s: [int(v) for v in s.split(",")], default=[1, 8, 32, 128])
    parser.add_argument("--pcc-batches", type=lambda s: [int(v) for v in s.split(",")], default=[1, 8, 32, 128, 1024])
    parser.add_argument("--links", type=int, default=DEFAULT_LINKS_PER_SEGMENT)
    parser.add_argument("--physics-dt", type=float, default=DEFAULT_PHYSICS_DT)
    parser.add_argument("--repeats", type=int, default=2, help="timings are the best of this many runs")
    parser.add_argument("--skip-mujoco", action="store_true")
    parser.add_argument("--step-calls", type=int, default=2000, help="calls of the control-step micro-benchmark")
    args = parser.parse_args()
    report: dict = {"duration_s": args.duration, "cpus": os.cpu_count(), "mujoco": mujoco.__version__,
                    "python": platform.python_version(), "machine_shared": True}
    pcc = bench_pcc(args)
    headline = {"pcc": max(pcc["batched"], key=lambda r: r["B"])}  # the largest batch: the setting a study would use
    report["pcc"] = pcc
    if not args.skip_mujoco:
        mj = bench_mujoco(args)
        report["mujoco_contact"] = mj
        largest = max(args.batches)
        for row in mj["batched"]:
            if row["B"] == largest:
                headline[f"mujoco_contact_{row['threads']}_thread"] = row
    report["step_us"] = bench_step(max(args.pcc_batches), args.step_calls, args.repeats)
    print()
    for name, row in headline.items():
        print(f"{name}: B = {row['B']}: {row['ratio_vs_serial']:.2f}× serial ({row['ratio_vs_serial_cpu']:.2f}× per CPU-hour), "
              f"{row['fraction_of_physics_ceiling']:.1%} of its physics ceiling ({row['fraction_of_physics_ceiling_cpu']:.1%} in CPU time)")
    ratio = {name: row["ratio_vs_serial"] for name, row in headline.items()}
    fraction = {name: row["fraction_of_physics_ceiling"] for name, row in headline.items()}
    ratio_cpu = {name: row["ratio_vs_serial_cpu"] for name, row in headline.items()}
    fraction_cpu = {name: row["fraction_of_physics_ceiling_cpu"] for name, row in headline.items()}
    report["ratio_vs_serial"] = ratio
    report["ratio_vs_serial_cpu"] = ratio_cpu
    report["fraction_of_physics_ceiling_cpu"] = fraction_cpu
    report["fraction_of_physics_ceiling"] = fraction
    emit(report)


if __name__ == "__main__":
    main()
