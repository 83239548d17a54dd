"""Agreement of the PCC plant's integrators with the paper's forward Euler at 1e-5 s.

Runs the paper scenario (sinusoid into the paper facet, filter at 1 kHz, zero-order
hold, no pressure limits) with each integrator and compares the tip trajectory and
ρ_min with the forward-Euler reference. Prints a table and ends with one JSON line.

    .venv/bin/python tools/integrator_check.py [--duration 40] [--tunings None,Low,High] [--cases ros2:1e-3,...]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from closedloop.step import ControlStep
from controllers.contract.safety_filter import FilterContext
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter
from controllers.nominal import SinusoidNominal
from controllers.model.params import reference_robot
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant

REFERENCE = ("euler", 1e-5)
DEFAULT_CASES = "rk4:1e-4,ros2:1e-3,ros2:5e-4,ros2:2.5e-4"


def parse_cases(text: str) -> list[tuple[str, float]]:
    """'ros2:1e-3,rk4:1e-4' → [('ros2', 0.001), ('rk4', 0.0001)]."""
    cases = []
    for item in text.split(","):
        name, _, dt = item.partition(":")
        cases.append((name.strip(), float(dt)))
    return cases


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=40.0, help="s of the paper scenario (first contact near 12 s)")
    parser.add_argument("--tunings", default="None,Low,High")
    parser.add_argument("--cases", default=DEFAULT_CASES, help="integrator:physics_dt list compared with the reference")
    args = parser.parse_args()
    cases = [REFERENCE] + parse_cases(args.cases)
    robot, safe = reference_robot(), paper_safe_set()
    nominal = SinusoidNominal.paper(2)
    figures = []
    for tuning in [get_tuning(name) for name in args.tunings.split(",")]:
        logs = {}
        for integrator, dt in cases:
            plant = PCCPlant(robot, safe, integrator=integrator, physics_dt=dt)
            start = time.perf_counter()
            step = ControlStep(CBFFilter(robot, safe, tuning, pressure_limits=False), nominal,
                               FilterContext.for_robot(robot, safe, plant.control_dt, pressure_limits=False))
            logs[(integrator, dt)], _ = run_closed_loop(plant, step, safe, args.duration, np.zeros(2))
            logs[(integrator, dt)]["wall"] = time.perf_counter() - start
        ref = logs[REFERENCE]
        for integrator, dt in cases[1:]:
            log = logs[(integrator, dt)]
            figures.append({
                "tuning": tuning.name,
                "integrator": integrator,
                "physics_dt": dt,
                "tip_err_max_m": float(np.max(np.abs(log["tip"] - ref["tip"]))),
                "rho_min": float(np.min(log["rho_meas"])),
                "rho_min_ref": float(np.min(ref["rho_meas"])),
                "rho_min_err": float(abs(np.min(log["rho_meas"]) - np.min(ref["rho_meas"]))),
                "wall_s": float(log["wall"]),
                "wall_ref_s": float(ref["wall"]),
            })
    print(f"paper scenario, {args.duration:g} s, reference: forward Euler at 1e-5 s")
    print(f"{'tuning':>7} {'integrator':>10} {'dt [s]':>8} {'tip err max [m]':>16} {'rho_min':>9} {'rho_min ref':>11} {'|d rho_min|':>11} {'wall [s]':>9}")
    for f in figures:
        print(f"{f['tuning']:>7} {f['integrator']:>10} {f['physics_dt']:>8.0e} {f['tip_err_max_m']:>16.2e} {f['rho_min']:>9.5f} {f['rho_min_ref']:>11.5f} {f['rho_min_err']:>11.2e} {f['wall_s']:>9.1f}")
    print(json.dumps({"duration_s": args.duration, "cases": figures}))


if __name__ == "__main__":
    main()
