"""Multi-fidelity against single-fidelity falsification: MuJoCo evaluations and wall time to the first violation.

    python tools/screen_measure.py --study studies/paper_low_plate_corner.toml [--seeds 1,2,3,4,5]
                                   [--budget 18] [--screen pcc_contact] [--screen-budget 12] [--confirm 6]
                                   [--workers 1] [--out DIR]

Per seed s: single-fidelity CMA-ES (`softcbf.study.falsify.falsify(study, budget, seed=s, baseline=0,
stop_on_violation=True)`, the box's vertices first) and the screened search (`softcbf.study.screen.
falsify_screened(study, screen=SCENARIO, budget=screen_budget, confirm=K, seed=s, stop_on_violation=True)`),
each into a fresh folder. Per run: the study scenario's evaluation at the first violation (counted from 1; none:
"> budget"), the study scenario's runs spent (the evaluations run, whole generations or confirmation chunks,
plus the worst case's replay) and the wall time of the whole call (s, both searches include the replay).
Medians count a run without a violation as +∞ (the direction that makes the claim harder). Prints a Markdown
table, the medians and their ratio; ends with one JSON line.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import tempfile
import time
from pathlib import Path

from softcbf.study.definition import load_study
from softcbf.study.falsify import falsify
from softcbf.study.screen import falsify_screened


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--study", default="studies/paper_low_plate_corner.toml")
    parser.add_argument("--seeds", default="1,2,3,4,5")
    parser.add_argument("--budget", type=int, default=18, help="single-fidelity evaluations (default 18)")
    parser.add_argument("--screen", default="pcc_contact")
    parser.add_argument("--screen-budget", type=int, default=12, help="evaluations of the screen (default 12)")
    parser.add_argument("--confirm", type=int, default=6, help="most confirmations (default 6)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args(argv)
    study = load_study(args.study)
    seeds = [int(s) for s in args.seeds.split(",")]
    out = args.out or Path(tempfile.mkdtemp(prefix="screen_measure_"))
    rows = []
    for seed in seeds:
        start = time.perf_counter()
        single = falsify(study, out / f"single_{seed}", budget=args.budget, seed=seed, baseline=0,
                         stop_on_violation=True, workers=args.workers, progress=False)
        single_wall = time.perf_counter() - start
        start = time.perf_counter()
        multi = falsify_screened(study, out / f"screened_{seed}", screen=args.screen, budget=args.screen_budget,
                                 confirm=args.confirm, seed=seed, stop_on_violation=True, workers=args.workers,
                                 progress=False)
        multi_wall = time.perf_counter() - start
        row = {"seed": seed, "single_first": single["first_violation"],
               "single_spent": single["evaluations"] + (single["worst"] is not None), "single_wall_s": single_wall,
               "screen_evaluations": multi["screen"]["evaluations"], "screen_first": multi["screen"]["first_violation"],
               "multi_first": multi["first_violation"], "multi_spent": multi["expensive_evaluations"],
               "multi_wall_s": multi_wall}
        rows.append(row)
        print(json.dumps(row), flush=True)

    def median(key: str) -> float:
        return statistics.median(math.inf if r[key] is None else r[key] for r in rows)

    print(f"\nstudy {study.name} ({study.scenario}); single: CMA-ES budget {args.budget}; screened: {args.screen} "
          f"budget {args.screen_budget}, confirm <= {args.confirm}; workers {args.workers}; folders in {out}\n")
    print("| seed | single: first violation | single: MuJoCo runs | single: wall [s] | screen: evaluations "
          "| screen: first violation there | screened: first violation on MuJoCo | screened: MuJoCo runs "
          "| screened: wall [s] |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['seed']} | {r['single_first'] or f'> {args.budget}'} | {r['single_spent']} | "
              f"{r['single_wall_s']:.0f} | {r['screen_evaluations']} | {r['screen_first'] or '–'} | "
              f"{r['multi_first'] or f'> {args.confirm}'} | {r['multi_spent']} | {r['multi_wall_s']:.0f} |")
    medians = {k: median(k) for k in ("single_first", "single_spent", "single_wall_s", "multi_first", "multi_spent",
                                      "multi_wall_s")}
    ratio = medians["single_first"] / medians["multi_first"] if medians["multi_first"] else math.nan
    print(f"\nmedians: {medians}; MuJoCo evaluations to the first violation, single / screened: {ratio:.2f} "
          f"(goal >= 3)")
    print(json.dumps({"study": study.name, "rows": rows, "medians": medians, "ratio_first": ratio}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
