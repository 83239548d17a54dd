"""Reference commands of the energy governors (e-erg, c-erg) and the quasi-static governor (qsg), for
tests/test_energy_governor_references.py: a change must not move what they command beyond the stated
tolerances (below), and one that does is measured and re-baselined.

Cases: the tools/bench_governors.py cases (the tests' PCC loop, tests/governor_loop.py: 1 kHz
exact state; 10 Hz camera timing with sinusoids and the worst step), the contact-aware
variant with the benchmark's plate bounds [0.9, 1.1] (softcbf/bench.py) on the PCC plant and
on a plate that pushes back, a random-steps run, a detected violation and its recovery, and
the scenario cases (SCENARIO_CASES): mujoco_contact at 1 kHz with the contact-aware e-erg, and
the filter benchmark's step case (softcbf/bench.py: paper_sim at 1 kHz, nominal "step", the
benchmark's plate bounds) for two seeds, where e-erg bisects at nearly every call; c-erg (with
the benchmark's plate bounds; the model's gain) pushing the plate at 10 Hz and 1 kHz, on the
sinusoid, recovering on the PCC plant, and on mujoco_contact. Stored per
case: every call's command (calls, N) hPa and action (an index into ACTIONS), and every DECIMATE-th tick's true tip
margin ρ and contact force (N); the scenario cases store the recorded column u, and rho_meas and contact_force
every DECIMATE-th step.

The stored file (REFERENCE_FILE) is a result, not a pin on floats: a change that moves the commands regenerates
it once, after measuring how far they moved (which goes to the CHANGELOG):

    python tests/references/eerg_references.py --reference tests/data/eerg_references.npz   # before: the movement, per case
    python tests/references/eerg_references.py --write tests/data/eerg_references.npz       # then: the new results

Without --write it compares the current tree with the stored file(s) (default: REFERENCE_FILE; several are
merged): prints each case's max |Δu| (hPa), the number of differing actions and the figures' differences; ends
with one JSON line; exit 1 when a difference exceeds the tolerances below (COMMAND_TOL_HPA, ...). --scale s < 1
runs every case over the first fraction s of its duration (the loops are causal, so a shorter run's calls are a
prefix of the stored ones); --cases runs only the named cases.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
REFERENCE_FILE = REPO / "tests" / "data" / "eerg_references.npz"
ACTIONS = ("free", "governed", "hold", "recover", "stale", "nominal", "backtrack", "rate_dropped", "vent", "")  # e-erg, qsg
DECIMATE = 10
"""ρ and the contact force are stored every DECIMATE-th tick (a prefix of a run's decimated series is the decimated
series of its prefix)."""
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
# name: (scenario, its run parameters; "duration" in s)
SCENARIO_CASES = {
    "mujoco_contact": ("mujoco_contact", dict(duration=1.5, filter="e-erg", filter_params=BENCH_PLATE,
                                              amplitude=150.0, frequency=0.25, t0=1.0)),
    "mujoco_contact c-erg": ("mujoco_contact", dict(duration=1.5, filter="c-erg", filter_params=BENCH_STIFFNESS,
                                                    amplitude=150.0, frequency=0.25, t0=1.0)),
    **{f"paper_sim step seed {seed}": ("paper_sim", dict(duration=2.0, filter="e-erg", filter_params=BENCH_PLATE,
                                                         nominal="step",
                                                         nominal_params={"seed": seed, "low_hPa": 60, "high_hPa": 300}))
       for seed in (0, 3)},
}


def _action_index(out) -> int:
    return ACTIONS.index(getattr(out, "action", ""))


def run_loop_case(name: str, scale: float = 1.0) -> dict[str, np.ndarray]:
    """Run one LOOP_CASES case over `scale` × its duration: {"u": (calls, N), "action": (calls,)}."""
    sys.path.insert(0, str(REPO / "tests"))
    from governor_loop import PushingPlatePlant, context, run_loop

    from controllers.governors.energy_governor import ContactEnergyGovernor, EnergyGovernor
    from controllers.model.params import reference_robot
    from controllers.governors.quasi_static_governor import QuasiStaticGovernor
    from controllers.model.safe_set import paper_safe_set

    factory, kwargs, period, delay, age, tau, nominal, duration, seed, k_true = LOOP_CASES[name]
    robot, safe = reference_robot(), paper_safe_set()
    gov = {"e-erg": EnergyGovernor, "c-erg": ContactEnergyGovernor, "qsg": QuasiStaticGovernor}[factory](context(robot, safe, period, delay, tau), **kwargs)
    plant = None if k_true is None else PushingPlatePlant(robot, safe, k_true, tau)
    rec = run_loop(gov, robot, safe, nominal, duration * scale, period, delay, age, tau_p=tau, seed=seed, plant=plant)
    return {"u": np.array(rec.commands), "action": np.array([_action_index(o) for o in rec.outputs]),
            "rho": np.asarray(rec.rho, dtype=float)[::DECIMATE],
            "force": np.asarray(rec.force, dtype=float)[::DECIMATE]}


def run_recovery_case() -> dict[str, np.ndarray]:
    """The detected-violation sequence of tests/test_energy_governor.py (ideal valve, 10 Hz, 20 ms delay)."""
    sys.path.insert(0, str(REPO / "tests"))
    from governor_loop import context

    from controllers.governors.energy_governor import EnergyGovernor
    from controllers.model.params import reference_robot
    from controllers.model.safe_set import paper_safe_set
    from controllers.contract.safety_filter import Estimate

    robot = reference_robot()
    gov = EnergyGovernor(context(robot, paper_safe_set(), 0.1, 0.02, 0.0))
    rest, push = np.zeros(2), np.array([150.0, 150.0])
    estimates = [Estimate(0.0, rest, rest, 0.0), Estimate(0.1, np.array([0.35, 0.8]), np.array([4.0, 4.0]), 0.1),
                 Estimate(0.2, np.array([0.3, 0.5]), rest, 0.2), Estimate(0.3, np.array([0.3, 0.5]), np.array([-1.0, 2.0]), 0.25)]
    outs = [gov(e, push) for e in estimates]
    return {"u": np.array([o.u for o in outs]), "action": np.array([_action_index(o) for o in outs])}


def run_scenario_case(name: str, scale: float = 1.0) -> dict[str, np.ndarray]:
    """One SCENARIO_CASES case over `scale` × its duration: the recorded columns u (steps, N) hPa, rho (steps,) and
    force (the contact_force column, N)."""
    from scenarios import get
    from scenarios.run_outputs import data_only
    from softcbf_mj.outputs.runio import load_timeseries

    scenario, params = SCENARIO_CASES[name]
    params = {**params, "duration": params["duration"] * scale}
    with tempfile.TemporaryDirectory() as tmp, data_only():
        summary = get(scenario).run(Path(tmp), progress=False, **params)
        (run,) = summary["runs"]
        series, _ = load_timeseries(Path(tmp) / run["timeseries"])
    return {"u": np.asarray(series["u"], dtype=float), "rho": np.asarray(series["rho_meas"], dtype=float)[::DECIMATE],
            "force": np.asarray(series["contact_force"], dtype=float)[::DECIMATE]}


CASES = (*LOOP_CASES, "recovery", *SCENARIO_CASES)


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


COMMAND_TOL_HPA = 1e-6
RHO_TOL = 1e-6
FORCE_TOL_N = 1e-6
"""The tolerances of the comparison (max |Δ| over a case's calls or ticks): commands (hPa), the true tip's margin ρ
(1) and the contact force (N); actions exactly. Rounding moves these loops, and a bisection decided on a margin
within rounding of ε can move a command by up to one bisection step (150 hPa / 2^12 at the defaults): the
tolerances sit far above rounding and far below the figures the docs report (ρ to 1e-3, forces to 1e-3 N,
commands to 0.1 hPa). CHANGELOG.md says by how much each re-baselining moved the results."""
TOLERANCES = {"u": COMMAND_TOL_HPA, "rho": RHO_TOL, "force": FORCE_TOL_N}


def load_references(files=(REFERENCE_FILE,)) -> dict[str, np.ndarray]:
    """The stored files' arrays, merged (each key in one file)."""
    merged = {}
    for file in files:
        with np.load(file) as stored:
            merged.update({key: stored[key] for key in stored.files})
    return merged


def compare(arrays: dict[str, np.ndarray], reference) -> dict[str, dict]:
    """Per case: the calls, max |Δ| of the commands (max_du_hPa), ρ (max_drho) and force (max_dforce_N) and the
    differing actions against the stored prefix (a column the reference lacks is left out; a shape that differs
    gives inf)."""
    names = {"u": "max_du_hPa", "rho": "max_drho", "force": "max_dforce_N"}
    result = {}
    for key, got in arrays.items():
        case, column = key.rsplit("/", 1)
        entry = result.setdefault(case, {})
        if column == "u":
            entry["calls"] = len(got)
        if key not in reference:
            continue
        expected = reference[key][: len(got)]
        if column == "action":
            entry["action_differences"] = int(np.sum(got != expected)) if got.shape == expected.shape else len(got)
        else:
            entry[names[column]] = float(np.max(np.abs(got - expected), initial=0.0)) if got.shape == expected.shape \
                else math.inf
    return result


def within_tolerances(result: dict[str, dict]) -> bool:
    """Whether every case of `compare`'s result is within COMMAND_TOL_HPA, RHO_TOL, FORCE_TOL_N with equal actions."""
    limits = {"max_du_hPa": COMMAND_TOL_HPA, "max_drho": RHO_TOL, "max_dforce_N": FORCE_TOL_N}
    return all(entry.get(name, 0.0) <= limit for entry in result.values() for name, limit in limits.items()) and \
        not any(entry.get("action_differences") for entry in result.values())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", metavar="FILE", help="store the current tree's commands in FILE (.npz)")
    parser.add_argument("--reference", nargs="+", default=[str(REFERENCE_FILE)], help="stored files to compare with")
    parser.add_argument("--scale", type=float, default=1.0, help="fraction of each case's duration (compare only)")
    parser.add_argument("--cases", default=",".join(CASES), help="comma list of the cases to run (default: all)")
    args = parser.parse_args()
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    if args.write:
        arrays = run_all(cases=cases)
        np.savez_compressed(args.write, **arrays)
        print(json.dumps({"file": args.write, "arrays": {k: list(v.shape) for k, v in arrays.items()}}))
        return 0
    result = compare(run_all(args.scale, cases), load_references(args.reference))
    worst = {name: max((entry.get(name, 0.0) for entry in result.values()), default=0.0)
             for name in ("max_du_hPa", "max_drho", "max_dforce_N")}
    for case, entry in result.items():
        print(f"{case:28s} calls {entry['calls']:6d}  max |du| {entry.get('max_du_hPa', 0.0):.3g} hPa  "
              f"|drho| {entry.get('max_drho', 0.0):.3g}  |dF| {entry.get('max_dforce_N', 0.0):.3g} N  "
              f"actions differing {entry.get('action_differences', 0)}")
    print(json.dumps({"reference": args.reference, "scale": args.scale, **worst, "cases": result}))
    return 0 if within_tolerances(result) else 1


if __name__ == "__main__":
    sys.exit(main())
