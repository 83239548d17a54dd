"""How far forward invariance holds at 1 kHz zero-order hold, with and without ±150 hPa limits.

From random rest configurations inside P, random constant nominal commands push the
tip towards the facet for `--seconds` s each; the PCC plant integrates the model the
filter uses (no model mismatch), so any violation comes from the sampled-data loop,
the pressure limits or the fallback. Reports per case: the worst ρ (prediction =
truth here), the time with ρ < 0, and the infeasible and recovery steps. Prints a
table and ends with one JSON line.

    .venv/bin/python tools/invariance_study.py [--runs 20] [--seconds 3] [--seed 0]
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from closedloop.step import ControlStep
from controllers.contract.safety_filter import FilterContext
from controllers.cbf.barrier import get_tuning
from controllers.cbf.paper_filter import CBFFilter
from controllers.model.params import reference_robot
from controllers.model.pcc import tip_position
from controllers.model.safe_set import paper_safe_set
from softcbf_mj.loops.loop import run_closed_loop
from softcbf_mj.physics.pcc_plant import PCCPlant


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tunings", default="Low,High,HW-Low,HW-High")
    args = parser.parse_args()
    robot, safe = reference_robot(), paper_safe_set()
    lengths = robot.array("lengths")
    rng = np.random.default_rng(args.seed)
    starts, commands = [], []
    while len(starts) < args.runs:
        q0 = rng.uniform(-0.2, 0.45, 2)
        if np.all(safe.h_prime - safe.H_prime @ tip_position(q0, lengths) > 0.002):
            starts.append(q0)
            commands.append(rng.uniform(60, 300, 2))
    rows = []
    for name in args.tunings.split(","):
        for limits in (False, True):
            worst, t_viol, infeasible, recovery = np.inf, 0.0, 0, 0
            for q0, u_const in zip(starts, commands):
                filt = CBFFilter(robot, safe, get_tuning(name), pressure_limits=limits)
                step = ControlStep(filt, lambda t, q, qd, u=u_const: u, FilterContext.for_robot(robot, safe, 1e-3, limits))
                log, _ = run_closed_loop(PCCPlant(robot, safe), step, safe, args.seconds, q0)
                worst = min(worst, float(np.min(log["rho_meas"])))
                t_viol += float(np.count_nonzero(log["rho_meas"] < 0) * 1e-3)
                infeasible += int(np.count_nonzero(log["infeasible"]))
                recovery += int(np.count_nonzero(log["recovery"]))
            rows.append({"tuning": name, "pressure_limits": limits, "rho_min": worst, "t_violation_s": t_viol,
                         "infeasible_steps": infeasible, "recovery_steps": recovery, "runs": args.runs, "seconds_each": args.seconds})
    print(f"{args.runs} runs x {args.seconds:g} s, 1 kHz zero-order hold, constant u_nom in [60, 300] hPa")
    print(f"{'tuning':>8} {'limits':>7} {'rho_min':>9} {'t_viol [s]':>10} {'infeasible':>10} {'recovery':>9}")
    for r in rows:
        print(f"{r['tuning']:>8} {str(r['pressure_limits']):>7} {r['rho_min']:>9.4f} {r['t_violation_s']:>10.3f} {r['infeasible_steps']:>10d} {r['recovery_steps']:>9d}")
    print(json.dumps({"rows": rows}))


if __name__ == "__main__":
    main()
