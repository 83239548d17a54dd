"""Reference commands of the energy governors (e-erg, c-erg) and the quasi-static governor (qsg), for
tests/test_energy_governor_references.py: speed-ups of any must not change what it commands.

Cases: the tools/bench_governors.py cases (the tests' PCC loop, tests/governor_loop.py: 1 kHz
exact state; 10 Hz camera timing with sinusoids and the worst step), the contact-aware
variant with the benchmark's plate bounds [0.9, 1.1] (softcbf/bench.py) on the PCC plant and
on a plate that pushes back, a random-steps run, a detected violation and its recovery, and
the scenario cases (SCENARIO_CASES): mujoco_contact at 1 kHz with the contact-aware e-erg, and
the filter benchmark's step case (softcbf/bench.py: paper_sim at 1 kHz, nominal "step", the
benchmark's plate bounds) for two seeds, where e-erg bisects at nearly every call; c-erg (with
the benchmark's plate bounds; the model's gain) pushing the plate at 10 Hz and 1 kHz, on the
sinusoid, recovering on the PCC plant, and on mujoco_contact. Stored per
case: every call's command (calls, N) hPa and action (an index into ACTIONS); the scenario
cases store the recorded command column u. The stored files (each named
after the commit it was generated from, REV below): every case but the step cases from the tree
before the first speed-ups, the step cases from the tree of the first speed-ups (before the
second), the c-erg cases (contact certificate; CERG_CASES) from the tree before the gain interval
and the camera-rate speed-ups, each with this script on a copy of that commit:

    git archive REV | tar -x -C /tmp/eerg_ref
    PYTHONPATH=/tmp/eerg_ref python tools/eerg_references.py --write tests/data/eerg_references_REV.npz
    python tools/eerg_references.py --cases "paper_sim step seed 0,paper_sim step seed 3" \
        --write tests/data/eerg_references_step_REV.npz    # this script on REV's controllers
    git archive REV | tar -x -C /tmp/cerg_ref
    PYTHONPATH=/tmp/cerg_ref python tools/eerg_references.py --cases "$(python tools/eerg_references.py --list-cerg)" \
        --write tests/data/eerg_references_cerg_REV.npz     # this script on REV's controllers

Without --write it compares the current tree with the stored files (default: REFERENCE_FILES,
merged): prints each case's max |Δu| (hPa) and the number of differing actions; ends with
one JSON line. --scale s < 1 runs every case over the first fraction s of its duration (the
loops are causal, so a shorter run's calls are a prefix of the stored ones); --cases runs
only the named cases.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REFERENCE_FILES = (REPO / "tests" / "data" / "eerg_references_45eacd9.npz",
                   REPO / "tests" / "data" / "eerg_references_step_266e431.npz",
                   REPO / "tests" / "data" / "eerg_references_cerg_a6cdc5c.npz")
ACTIONS = ("free", "governed", "hold", "recover", "stale", "nominal", "backtrack", "rate_dropped", "vent", "")  # e-erg, qsg
BENCH_PLATE = {"contact_aware": True, "stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1}
BENCH_STIFFNESS = {"stiffness_lo_ratio": 0.9, "stiffness_hi_ratio": 1.1}  # c-erg is contact-aware by default


def _sinusoid(period_s: float):
    return lambda t: np.full(2, 150.0 * math.sin(2 * math.pi * t / period_s))


def _step(t: float) -> np.ndarray:
    return np.array([150.0, 150.0])


# name: (factory, kwargs, period s, delay s, age range s, tau_p s, u_nom, duration s, seed, plate k_true N/m or None)
LOOP_CASES = {
    "e-erg 1kHz sin8": ("e-erg", {}, 1e-3, 0.0, (0.0, 0.0), 0.0, _sinusoid(8.0), 8.0, 0, None),
    "e-erg cam sin8": ("e-erg", {}, 0.1, 0.02, (0.03, 0.1), 0.05, _sinusoid(8.0), 12.0, 0, None),
    "e-erg cam sin20": ("e-erg", {}, 0.1, 0.02, (0.03, 0.1), 0.05, _sinusoid(20.0), 30.0, 0, None),
    "e-erg cam step tau0": ("e-erg", {}, 0.1, 0.02, (0.03, 0.1), 0.0, _step, 4.0, 0, None),
    "e-erg cam step tau05": ("e-erg", {}, 0.1, 0.02, (0.03, 0.1), 0.05, _step, 4.0, 0, None),
    "e-erg cam random": ("e-erg", {}, 0.1, 0.02, (0.03, 0.1), 0.05, lambda t: np.array([95.0, 240.0]), 2.0, 7, None),
    "e-erg aware cam sin8": ("e-erg", BENCH_PLATE, 0.1, 0.02, (0.03, 0.1), 0.05, _sinusoid(8.0), 12.0, 0, None),
    "e-erg aware cam pushing": ("e-erg", BENCH_PLATE, 0.1, 0.02, (0.03, 0.1), 0.05, _step, 3.0, 2, 11.16 * 1.05),
    "e-erg aware 1kHz sin8": ("e-erg", BENCH_PLATE, 1e-3, 0.0, (0.0, 0.0), 0.0, _sinusoid(8.0), 4.0, 0, None),
    "c-erg cam pushing": ("c-erg", BENCH_STIFFNESS, 0.1, 0.02, (0.03, 0.1), 0.05, _step, 4.0, 2, 11.16 * 1.05),
    "c-erg cam pushing exact": ("c-erg", {}, 0.1, 0.02, (0.03, 0.1), 0.05, _step, 4.0, 5, 11.16),
    "c-erg 1kHz pushing": ("c-erg", BENCH_STIFFNESS, 1e-3, 0.0, (0.0, 0.0), 0.0, _step, 1.0, 0, 11.16 * 0.95),
    "c-erg cam sin8": ("c-erg", BENCH_STIFFNESS, 0.1, 0.02, (0.03, 0.1), 0.05, _sinusoid(8.0), 12.0, 0, 11.16),
    # the PCC plant's plate does not push back (outside the contact-aware certificate): recoveries (step 4)
    "c-erg cam step recovering": ("c-erg", BENCH_STIFFNESS, 0.1, 0.02, (0.03, 0.1), 0.05, _step, 4.0, 0, None),
    "qsg 1kHz sin8": ("qsg", {}, 1e-3, 0.0, (0.0, 0.0), 0.0, _sinusoid(8.0), 4.0, 0, None),
    "qsg cam sin8": ("qsg", {}, 0.1, 0.02, (0.03, 0.1), 0.05, _sinusoid(8.0), 12.0, 0, None),
}
BENCH_PLATE_PARAMS = "contact_aware=true;stiffness_lo_ratio=0.9;stiffness_hi_ratio=1.1"
# name: (scenario, its run parameters; "duration" in s)
SCENARIO_CASES = {
    "mujoco_contact": ("mujoco_contact", dict(duration=1.5, filter="e-erg", filter_params=BENCH_PLATE_PARAMS,
                                              amplitude=150.0, frequency=0.25, t0=1.0)),
    "mujoco_contact c-erg": ("mujoco_contact", dict(duration=1.5, filter="c-erg",
                                                    filter_params="stiffness_lo_ratio=0.9;stiffness_hi_ratio=1.1",
                                                    amplitude=150.0, frequency=0.25, t0=1.0)),
    **{f"paper_sim step seed {seed}": ("paper_sim", dict(duration=2.0, filter="e-erg", filter_params=BENCH_PLATE_PARAMS,
                                                         nominal="step", nominal_params=f"seed={seed};low_hPa=60;high_hPa=300"))
       for seed in (0, 3)},
}


def _action_index(out) -> int:
    return ACTIONS.index(getattr(out, "action", ""))


def run_loop_case(name: str, scale: float = 1.0) -> dict[str, np.ndarray]:
    """Run one LOOP_CASES case over `scale` × its duration: {"u": (calls, N), "action": (calls,)}."""
    sys.path.insert(0, str(REPO / "tests"))
    from governor_loop import PushingPlatePlant, context, run_loop

    from controllers.energy_governor import ContactEnergyGovernor, EnergyGovernor
    from controllers.params import reference_robot
    from controllers.quasi_static_governor import QuasiStaticGovernor
    from controllers.safe_set import paper_safe_set

    factory, kwargs, period, delay, age, tau, nominal, duration, seed, k_true = LOOP_CASES[name]
    robot, safe = reference_robot(), paper_safe_set()
    gov = {"e-erg": EnergyGovernor, "c-erg": ContactEnergyGovernor, "qsg": QuasiStaticGovernor}[factory](context(robot, safe, period, delay, tau), **kwargs)
    plant = None if k_true is None else PushingPlatePlant(robot, safe, k_true, tau)
    rec = run_loop(gov, robot, safe, nominal, duration * scale, period, delay, age, tau_p=tau, seed=seed, plant=plant)
    return {"u": np.array(rec.commands), "action": np.array([_action_index(o) for o in rec.outputs])}


def run_recovery_case() -> dict[str, np.ndarray]:
    """The detected-violation sequence of tests/test_energy_governor.py (ideal valve, 10 Hz, 20 ms delay)."""
    sys.path.insert(0, str(REPO / "tests"))
    from governor_loop import context

    from controllers.energy_governor import EnergyGovernor
    from controllers.params import reference_robot
    from controllers.safe_set import paper_safe_set
    from controllers.safety_filter import Estimate

    robot = reference_robot()
    gov = EnergyGovernor(context(robot, paper_safe_set(), 0.1, 0.02, 0.0))
    rest, push = np.zeros(2), np.array([150.0, 150.0])
    estimates = [Estimate(0.0, rest, rest, 0.0), Estimate(0.1, np.array([0.35, 0.8]), np.array([4.0, 4.0]), 0.1),
                 Estimate(0.2, np.array([0.3, 0.5]), rest, 0.2), Estimate(0.3, np.array([0.3, 0.5]), np.array([-1.0, 2.0]), 0.25)]
    outs = [gov(e, push) for e in estimates]
    return {"u": np.array([o.u for o in outs]), "action": np.array([_action_index(o) for o in outs])}


def run_scenario_case(name: str, scale: float = 1.0) -> dict[str, np.ndarray]:
    """One SCENARIO_CASES case over `scale` × its duration: {"u": the recorded command column (steps, N)}."""
    from scenarios import get
    from scenarios.common import data_only
    from softcbf_mj.runio import load_timeseries

    scenario, params = SCENARIO_CASES[name]
    params = {**params, "duration": params["duration"] * scale}
    with tempfile.TemporaryDirectory() as tmp, data_only():
        summary = get(scenario).run(Path(tmp), progress=False, **params)
        (run,) = summary["runs"]
        series, _ = load_timeseries(Path(tmp) / run["timeseries"])
    return {"u": np.asarray(series["u"], dtype=float)}


CASES = (*LOOP_CASES, "recovery", *SCENARIO_CASES)
CERG_CASES = tuple(name for name in CASES if "c-erg" in name)
"""The c-erg cases (stored from the tree before the gain interval)."""


def run_case(name: str, scale: float = 1.0) -> dict[str, np.ndarray]:
    """One case of CASES (the recovery case always in full)."""
    if name in LOOP_CASES:
        return run_loop_case(name, scale)
    if name in SCENARIO_CASES:
        return run_scenario_case(name, scale)
    if name == "recovery":
        return run_recovery_case()
    raise ValueError(f"case must be one of {list(CASES)}, got {name!r}")


def run_all(scale: float = 1.0, cases=CASES) -> dict[str, np.ndarray]:
    """The given cases: keys "<case>/u" and "<case>/action" (not for the scenario cases)."""
    return {f"{name}/{k}": v for name in cases for k, v in run_case(name, scale).items()}


def load_references(files=REFERENCE_FILES) -> dict[str, np.ndarray]:
    """The stored files' arrays, merged (each key in one file)."""
    merged = {}
    for file in files:
        with np.load(file) as stored:
            merged.update({key: stored[key] for key in stored.files})
    return merged


def compare(arrays: dict[str, np.ndarray], reference) -> dict[str, dict]:
    """Per case: max |Δu| (hPa) and differing actions against the stored prefix."""
    result = {}
    for key, got in arrays.items():
        case, column = key.rsplit("/", 1)
        expected = reference[key][: len(got)]
        entry = result.setdefault(case, {"calls": len(got)})
        if column == "u":
            entry["max_du_hPa"] = float(np.max(np.abs(got - expected))) if got.shape == expected.shape else math.inf
        else:
            entry["action_differences"] = int(np.sum(got != expected)) if got.shape == expected.shape else len(got)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", metavar="FILE", help="store the current tree's commands in FILE (.npz)")
    parser.add_argument("--reference", nargs="+", default=[str(f) for f in REFERENCE_FILES], help="stored files to compare with")
    parser.add_argument("--scale", type=float, default=1.0, help="fraction of each case's duration (compare only)")
    parser.add_argument("--cases", default=",".join(CASES), help="comma list of the cases to run (default: all)")
    parser.add_argument("--list-cerg", action="store_true", help="print the c-erg cases as a comma list and exit")
    args = parser.parse_args()
    if args.list_cerg:
        print(",".join(CERG_CASES))
        return 0
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    if args.write:
        arrays = run_all(cases=cases)
        np.savez_compressed(args.write, **arrays)
        print(json.dumps({"file": args.write, "arrays": {k: list(v.shape) for k, v in arrays.items()}}))
        return 0
    result = compare(run_all(args.scale, cases), load_references(args.reference))
    for case, entry in result.items():
        print(f"{case:28s} calls {entry['calls']:6d}  max |du| {entry['max_du_hPa']:.3g} hPa  "
              f"actions differing {entry.get('action_differences', 0)}")
    worst = max(entry["max_du_hPa"] for entry in result.values())
    print(json.dumps({"reference": args.reference, "scale": args.scale, "max_du_hPa": worst, "cases": result}))
    return 0 if worst <= 1e-9 and not any(e.get("action_differences") for e in result.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
