"""Governors (docs/beyond-the-paper.md#filters-beyond-the-paper) on the PCC plant: per-call compute time and per-run figures.

Uses the tests' loop (tests/governor_loop.py: PCC plant at 1 ms ticks, zero-order hold,
the filter given the true state captured `age` s earlier, its command acting `delay` s
after the call, valve lag τ_p), so the figures are those of the tests' setting:
- 1 kHz, exact state, no delay, ideal valve: u_nom = 150 sin(2πt/8 s) hPa on both
  segments for 8 s (free far from the plate, governed near it): call time median/p99.
- 10 Hz camera timing (age 0.03–0.1 s, delay 20 ms, τ_p = 0.05 s): the same sinusoid
  (T = 8 s and 20 s, 1.5 T) and the worst step rest → (150, 150) hPa with τ_p = 0 and
  0.05 s (4 s): ρ_min, governor_figures.
- c-erg (the contact certificate, plate stiffness [0.9, 1.1] as the bench's) also pushes the
  plate that pushes back (tests/governor_loop.py PushingPlatePlant, the model's 11.16 N/m) with
  150 hPa on both segments for 6 s, at 1 kHz (exact state) and at 10 Hz with camera timing: its
  contact task, where its state predictor integrates the plate's push.
Call times: wall (filter_us_*, what the loop records) and process CPU time (cpu_us_*, less
sensitive to other processes on a shared machine), after a warm-up (`warm_up`: numba's first call
of each kernel in a process loads it, 5–100 ms once, which in these short runs would be the p99);
the table build time is separate (build_s).
--repeat R runs each case R times on the same governor (the loop resets it: the same calls and commands,
checked) and takes each call's least time over the R runs: on a loaded machine the scheduler and other
processes add milliseconds to a few calls, which in a camera case of 40–300 calls is the p99; the least
over repeats keeps what the call itself costs (CPU time counts a preempted virtual CPU's stolen time too).
Filters (--filters): qsg, e-erg, c-erg, c-erg-recommended, c-erg-learn-plate (the preset c-erg:learn-plate), and
"+delay" after a c-erg name: with the command delay interval 0–20 ms (DELAY_INTERVAL).
Prints one line per case and ends with one JSON line. Usage:
    PYTHONPATH=$PWD python tools/bench_governors.py [--quick] [--filters c-erg] [--repeat 5] [--against /path/to/other/tree]
--against TREE runs every case a second time, right after this tree's run, in a child process
whose controllers are TREE's (PYTHONPATH=TREE; the loop, cases and figures are this script's),
and prints the ratios this/TREE of the call-time medians and p99s: side by side on the same
load. A filter TREE does not have is reported as missing.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from governor_loop import PushingPlatePlant, context, run_loop  # noqa: E402

from controllers.contract.filter_metrics import governor_figures  # noqa: E402
from controllers.model.params import reference_robot  # noqa: E402
from controllers.model.safe_set import paper_safe_set  # noqa: E402
from controllers.contract.safety_filter import Estimate, EstimateBatch  # noqa: E402
from timing import emit  # noqa: E402

FILTER_NAMES = ("qsg", "e-erg", "c-erg", "c-erg-recommended", "c-erg-recommended+delay", "c-erg-learn-plate",
                "c-erg-learn-plate+delay")
DELAY_INTERVAL = {"command_delay_lo_s": 0.0, "command_delay_hi_s": 0.02}
"""The command delay interval of the "+delay" filters (s): 0–20 ms, a valve bus's (certified at 0, 10 and 20 ms)."""
PLATE_N_PER_M = 11.16
"""The pushing plate's stiffness (N/m): the model's (paper_safe_set)."""


def factory(name: str):
    """The filter class of `name` and its keyword arguments (c-erg: the bench's plate interval; c-erg-recommended:
    with `energy_governor.RECOMMENDED` too; c-erg-learn-plate: the preset c-erg:learn-plate; "+delay": with the
    command delay interval DELAY_INTERVAL). LookupError for a filter or parameter the controllers lack (--against
    an older tree)."""
    from controllers.governors import energy_governor, quasi_static_governor

    if name.endswith("+delay"):
        if "command_delay_lo_s" not in energy_governor.PARAMETERS:
            raise LookupError(name)
        cls, kwargs = factory(name[:-len("+delay")])
        return cls, {**kwargs, **DELAY_INTERVAL}
    if name == "c-erg-learn-plate":
        from controllers.governors.energy_governor import parameters

        if not hasattr(parameters, "LEARN_PLATE_SETTING"):
            raise LookupError(name)
        return energy_governor.ContactEnergyGovernor, dict(parameters.LEARN_PLATE_SETTING)

    if name == "qsg":
        return quasi_static_governor.QuasiStaticGovernor, {}
    if name == "e-erg":
        return energy_governor.EnergyGovernor, {}
    if name == "c-erg":
        if not hasattr(energy_governor, "ContactEnergyGovernor"):
            raise LookupError("c-erg")
        return energy_governor.ContactEnergyGovernor, {"stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1}
    if name == "c-erg-recommended":
        if not hasattr(energy_governor, "RECOMMENDED"):
            raise LookupError("c-erg-recommended")
        return energy_governor.ContactEnergyGovernor, {"stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1,
                                                       **energy_governor.RECOMMENDED}
    raise ValueError(f"filter must be one of {FILTER_NAMES}, got {name!r}")


def sinusoid(period_s: float):
    return lambda t: np.full(2, 150.0 * math.sin(2 * math.pi * t / period_s))


def push(t: float) -> np.ndarray:
    return np.array([150.0, 150.0])


def cases(names, quick: bool) -> dict[str, tuple]:
    """name → (filter, period s, delay s, age range s, τ_p s, u_nom, duration s, plate pushes back)."""
    out = {}
    for label in names:
        out[f"{label} 1 kHz sin T=8s"] = (label, 1e-3, 0.0, (0.0, 0.0), 0.0, sinusoid(8.0), 2.0 if quick else 8.0, False)
        for period_s in (8.0,) if quick else (8.0, 20.0):
            out[f"{label} 10 Hz camera sin T={period_s:g}s"] = (label, 0.1, 0.02, (0.03, 0.1), 0.05, sinusoid(period_s),
                                                               1.5 * period_s, False)
        for tau in (0.0, 0.05):
            out[f"{label} 10 Hz camera step 150/150 τ={tau:g}"] = (label, 0.1, 0.02, (0.03, 0.1), tau, push, 4.0, False)
        if label.startswith("c-erg"):
            out[f"{label} 1 kHz push 150/150 plate"] = (label, 1e-3, 0.0, (0.0, 0.0), 0.0, push, 2.0 if quick else 6.0, True)
            out[f"{label} 10 Hz camera push 150/150 plate"] = (label, 0.1, 0.02, (0.03, 0.1), 0.05, push,
                                                              3.0 if quick else 6.0, True)
    return out


def warm_up(gov, n: int) -> None:
    """Load the compiled kernels of every path (numba loads each on its first call in a process, ≈ 5 ms each,
    which in these short runs would be the p99): a step from rest towards 150 hPa, then a state beyond P moving
    outwards (the recovery); the loop resets the governor before its first call."""
    rest, push = np.zeros(n), np.full(n, 150.0)
    for estimate in (Estimate(0.0, rest, rest, 0.0), Estimate(0.1, np.full(n, 0.6), np.full(n, 4.0), 0.1)):
        gov(estimate, push)


def run_case(name: str, spec: tuple, repeat: int = 1) -> dict:
    """The case `name` run `repeat` times on one governor (reset by the loop before each run: the same calls,
    the same commands): each call's time is its least over the runs (`repeat` > 1: the scheduler's and other
    processes' share of a call, which on a loaded machine sets the p99, mostly removed; the call's own cost kept)."""
    label, period, delay, age, tau, nominal, duration, pushing = spec
    robot, safe = reference_robot(), paper_safe_set()
    cls, kwargs = factory(label)
    t0 = time.perf_counter()
    gov = cls(context(robot, safe, period, delay, tau), **kwargs)
    build_s = time.perf_counter() - t0
    warm_up(gov, robot.n_segments)
    runs = []
    for _ in range(repeat):
        plant = PushingPlatePlant(robot, safe, PLATE_N_PER_M, tau) if pushing else None
        runs.append(run_loop(gov, robot, safe, nominal, duration, period, delay, age, tau_p=tau, seed=0, plant=plant))
    rec = runs[0]
    if any(not np.array_equal(r.commands, rec.commands) for r in runs[1:]):
        raise RuntimeError(f"{name}: the repeated runs commanded differently")
    wall = np.min([r.call_us for r in runs], axis=0)
    cpu_us = np.min([r.call_cpu_us for r in runs], axis=0)
    t = (np.array(rec.apply_ticks) - int(round(delay / 1e-3))) * 1e-3
    u_nom = np.array([nominal(s) for s in t])
    figures = governor_figures(t, np.array(rec.commands), u_nom, wall)
    cpu = {"cpu_us_median": float(np.median(cpu_us)), "cpu_us_p99": float(np.percentile(cpu_us, 99))}
    return {"case": name, "rho_min": float(rec.rho.min()), "calls": len(wall), "build_s": build_s, "repeat": repeat,
            "u_max_abs_hPa": float(np.max(np.abs(rec.u))), **figures, **cpu}


class Recorder:
    """A governor that keeps every call's (estimate, u_nom): the inputs a batched replay hands `filter_batch`."""

    def __init__(self, governor) -> None:
        self.governor, self.calls = governor, []

    def reset(self) -> None:
        self.governor.reset()
        self.calls = []

    def __call__(self, estimate: Estimate, u_nom):
        self.calls.append((estimate, np.array(u_nom, dtype=float)))
        return self.governor(estimate, u_nom)


def batch_case(name: str, spec: tuple, rows: int, repeat: int) -> dict:
    """The case run as `rows` simulations (the loop's seeds 0..rows−1: different estimate ages at the camera
    rate), their calls recorded through scalar governors, then replayed per period two ways: `rows` governors
    called in turn (per simulation) and one governor's `filter_batch` over the rows; each period's time the
    least over `repeat` replays. The commands must agree bit for bit (the batch contract), so the replay is the
    closed loop either way."""
    label, period, delay, age, tau, nominal, duration, pushing = spec
    robot, safe = reference_robot(), paper_safe_set()
    cls, kwargs = factory(label)
    ctx = context(robot, safe, period, delay, tau)
    serial = [cls(ctx, **kwargs) for _ in range(rows)]
    calls = []
    for b, gov in enumerate(serial):
        warm_up(gov, robot.n_segments)
        recorder = Recorder(gov)
        plant = PushingPlatePlant(robot, safe, PLATE_N_PER_M, tau) if pushing else None
        run_loop(recorder, robot, safe, nominal, duration, period, delay, age, tau_p=tau, seed=b, plant=plant)
        calls.append(recorder.calls)
    periods = min(len(c) for c in calls)
    batched = cls(ctx, **kwargs)
    warm_up(batched, robot.n_segments)
    serial_us, batch_us = np.full(periods, np.inf), np.full(periods, np.inf)
    for _ in range(repeat):
        for gov in serial:
            gov.reset()
        batched.reset()
        for k in range(periods):
            inputs = [calls[b][k] for b in range(rows)]
            t0 = time.process_time()
            want = [gov(estimate, u_nom) for gov, (estimate, u_nom) in zip(serial, inputs)]
            t1 = time.process_time()
            estimates = EstimateBatch(np.array([e.t for e, _ in inputs]), np.array([e.q for e, _ in inputs]),
                                      np.array([e.qd for e, _ in inputs]), np.array([e.t_capture for e, _ in inputs]))
            t2 = time.process_time()
            out = batched.filter_batch(estimates, np.array([u for _, u in inputs]))
            t3 = time.process_time()
            if not np.array_equal(out.u, [w.u for w in want]) or out.action.tolist() != [w.action for w in want]:
                raise RuntimeError(f"{name}: filter_batch differs from the serial governors at period {k}")
            serial_us[k] = min(serial_us[k], (t1 - t0) * 1e6)
            batch_us[k] = min(batch_us[k], (t3 - t2) * 1e6)
    return {"case": name, "rows": rows, "periods": periods, "repeat": repeat,
            "serial_us_per_period_median": float(np.median(serial_us)),
            "batch_us_per_period_median": float(np.median(batch_us)),
            "serial_us_total": float(np.sum(serial_us)), "batch_us_total": float(np.sum(batch_us)),
            "batch_over_serial": float(np.sum(batch_us) / np.sum(serial_us))}


def show(result: dict, tag: str = "") -> None:
    print(f"{tag}{result['case']:40s} ρ_min {result['rho_min']:+.3f}  calls {result['calls']:5d}  "
          f"wall median/p99 {result['filter_us_median']:6.0f}/{result['filter_us_p99']:6.0f} µs  "
          f"CPU {result['cpu_us_median']:6.0f}/{result['cpu_us_p99']:6.0f} µs  "
          f"blocked {result['blocked_s']:.1f} s (longest {result['blocked_longest_s']:.1f} s)  "
          f"dev rms {result['u_dev_rms_hPa']:.1f} hPa  build {result['build_s']:.1f} s", flush=True)


def run_against(tree: str, name: str, quick: bool, repeat: int) -> dict | None:
    """The case `name` run by this script in a child process on TREE's controllers (None: TREE lacks the filter)."""
    env = {**os.environ, "PYTHONPATH": str(Path(tree).resolve())}
    command = [sys.executable, str(Path(__file__).resolve()), "--one", name, "--repeat", str(repeat)]
    command += ["--quick"] if quick else []
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    if done.returncode == 3:
        return None
    if done.returncode != 0:
        raise RuntimeError(f"--against {tree}: case {name!r} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="shorter runs (1 kHz: 2 s; sinusoids: T = 8 s only; pushes 2–3 s)")
    parser.add_argument("--filters", default=",".join(FILTER_NAMES), help=f"comma list of {', '.join(FILTER_NAMES)}")
    parser.add_argument("--cases", default="", help="only the cases whose name contains one of these comma-separated words")
    parser.add_argument("--against", metavar="TREE", help="also run every case on TREE's controllers (module docstring)")
    parser.add_argument("--repeat", type=int, default=1, help="run each case this many times; each call's time is "
                        "its least over the runs (run_case: the noise of a loaded machine removed)")
    parser.add_argument("--batch", type=int, default=0, metavar="B",
                        help="instead: each case as B simulations, B governors called per simulation against one "
                        "governor's filter_batch (batch_case; qsg has its own in tools/bench_batch_filters.py)")
    parser.add_argument("--one", metavar="CASE", help=argparse.SUPPRESS)  # the child of --against: one case, its JSON
    args = parser.parse_args()
    if args.repeat < 1:
        parser.error(f"--repeat must be >= 1, got {args.repeat}")
    names = [n.strip() for n in args.filters.split(",") if n.strip()]
    for n in names:
        if n not in FILTER_NAMES:
            parser.error(f"--filters: {n!r} is not one of {', '.join(FILTER_NAMES)}")
    table = cases(FILTER_NAMES if args.one else names, args.quick)
    if args.one:
        try:
            emit(run_case(args.one, table[args.one], args.repeat))
        except LookupError:
            return 3
        return 0
    words = [w.strip() for w in args.cases.split(",") if w.strip()]
    results = []
    if args.batch:
        for name, spec in table.items():
            if (words and not any(w in name for w in words)) or spec[0] == "qsg":
                continue
            result = batch_case(name, spec, args.batch, args.repeat)
            print(f"{name:40s} B = {args.batch}: per period serial {result['serial_us_per_period_median']:7.0f} µs, "
                  f"batched {result['batch_us_per_period_median']:7.0f} µs (medians); total batched/serial "
                  f"{result['batch_over_serial']:.2f}", flush=True)
            results.append(result)
        emit({"quick": args.quick, "batch": args.batch, "repeat": args.repeat,
              "load_1min": os.getloadavg()[0], "results": results})
        return 0
    for name, spec in table.items():
        if words and not any(w in name for w in words):
            continue
        result = run_case(name, spec, args.repeat)
        show(result)
        if args.against:
            before = run_against(args.against, name, args.quick, args.repeat)
            if before is None:
                print(f"  against {args.against}: no {spec[0]} there")
            else:
                show(before, "  against: ")
                result["against"] = before
                result["ratio_median"] = result["filter_us_median"] / before["filter_us_median"]
                result["ratio_p99"] = result["filter_us_p99"] / before["filter_us_p99"]
                result["ratio_cpu_median"] = result["cpu_us_median"] / before["cpu_us_median"]
                result["ratio_cpu_p99"] = result["cpu_us_p99"] / before["cpu_us_p99"]
                print(f"  this/against: wall median {result['ratio_median']:.2f}  p99 {result['ratio_p99']:.2f}  "
                      f"CPU median {result['ratio_cpu_median']:.2f}  p99 {result['ratio_cpu_p99']:.2f}", flush=True)
        results.append(result)
    emit({"quick": args.quick, "against": args.against, "repeat": args.repeat, "load_1min": os.getloadavg()[0], "results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
